"""Camera-path export checked with nerfstudio's own reader (get_path_from_json) and the viewer's own
keyframe/spline code (render_panel.CameraPath with a stand-in viser server)."""
from __future__ import annotations

import json
import os
from unittest import mock

import numpy as np
import pytest
from test_shot import make_shot  # tests/planner is on sys.path (pytest rootdir-relative import)

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.shots.camera_path import (
    camera_path_poses,
    keyframe_indices,
    read_camera_path,
    shot_to_camera_path,
    write_camera_path,
)


@pytest.fixture(scope="module")
def shot():
    return make_shot()


def test_nerfstudio_reads_our_poses(shot, tmp_path):
    from nerfstudio.cameras.camera_paths import get_path_from_json

    d = shot_to_camera_path(shot, fov_deg=50.0, width=640, height=360)
    path = write_camera_path(tmp_path / "camera_paths" / "shot.json", d)
    loaded = read_camera_path(path)
    cams = get_path_from_json(loaded)
    assert cams.camera_to_worlds.shape == (shot.num_frames, 3, 4)
    np.testing.assert_allclose(cams.camera_to_worlds.double().numpy(), shot.camera_to_worlds()[:, :3], atol=1e-6)
    assert int(cams.width[0]) == 640 and int(cams.height[0]) == 360
    f = 180.0 / np.tan(np.radians(50.0) / 2)  # vertical fov: (H/2) / tan(fov/2)
    np.testing.assert_allclose(cams.fx.numpy().ravel(), f, rtol=1e-6)
    # ns-render plays len(frames) / seconds fps: that is the shot's frame rate
    assert len(loaded["camera_path"]) / loaded["seconds"] == pytest.approx(shot.fps)
    # float64 round trip through JSON is exact
    np.testing.assert_array_equal(camera_path_poses(loaded), shot.camera_to_worlds())
    # camera convention: -z of every frame looks at the target
    view = -camera_path_poses(loaded)[:, :3, 2]
    to_target = shot.look_at - shot.positions
    cos = np.sum(view * to_target, 1) / np.linalg.norm(to_target, axis=1)
    assert cos.min() > 1 - 1e-9


def viewer_load(json_data: dict):
    """The viewer's Load Path handler (render_panel.populate_render_tab), line for line, into a real
    render_panel.CameraPath whose viser server is a stand-in."""
    import viser.transforms as tf
    from nerfstudio.viewer.render_panel import CameraPath, Keyframe
    from nerfstudio.viewer.viewer import VISER_NERFSTUDIO_SCALE_RATIO

    camera_path = CameraPath(mock.MagicMock(), mock.MagicMock())
    camera_path.tension = 0.0  # the render tab's slider default
    camera_path.default_fov = json_data["default_fov"] / 180.0 * np.pi
    camera_path.default_transition_sec = json_data.get("default_transition_sec", 0.5)
    for frame in json_data["keyframes"]:
        pose = tf.SE3.from_matrix(np.array(frame["matrix"]).reshape(4, 4))
        pose = tf.SE3.from_rotation_and_translation(pose.rotation() @ tf.SO3.from_x_radians(np.pi), pose.translation())
        camera_path.add_camera(
            Keyframe(
                position=pose.translation() * VISER_NERFSTUDIO_SCALE_RATIO,
                wxyz=pose.rotation().wxyz,
                override_fov_enabled=abs(frame["fov"] - json_data.get("default_fov", 0.0)) > 1e-3,
                override_fov_rad=frame["fov"] / 180.0 * np.pi,
                override_time_enabled=frame.get("override_time_enabled", False),
                override_time_val=frame.get("render_time", None),
                aspect=frame["aspect"],
                override_transition_enabled=frame.get("override_transition_enabled", None),
                override_transition_sec=frame.get("override_transition_sec", None),
            )
        )
    camera_path.update_spline()
    return camera_path


def viewer_keyframe_matrix(keyframe) -> np.ndarray:
    """The viewer's export of a keyframe ("Generate Command" handler)."""
    import viser.transforms as tf
    from nerfstudio.viewer.viewer import VISER_NERFSTUDIO_SCALE_RATIO

    pose = tf.SE3.from_rotation_and_translation(
        tf.SO3(keyframe.wxyz) @ tf.SO3.from_x_radians(np.pi), keyframe.position / VISER_NERFSTUDIO_SCALE_RATIO
    )
    return pose.as_matrix()


def test_viewer_load_path_round_trip(shot):
    from nerfstudio.viewer.viewer import VISER_NERFSTUDIO_SCALE_RATIO

    d = json.loads(json.dumps(shot_to_camera_path(shot, fov_deg=40.0, width=800, height=600)))
    cp = viewer_load(d)
    kf_idx = keyframe_indices(shot.times, 0.5)
    keyframes = [k for k, _ in cp._keyframes.values()]
    assert len(keyframes) == len(kf_idx) == len(d["keyframes"])
    for k, i in zip(keyframes, kf_idx):
        # loaded keyframe sits at our frame (viser scene = 10x nerfstudio world) ...
        np.testing.assert_allclose(k.position, shot.positions[i] * VISER_NERFSTUDIO_SCALE_RATIO, atol=1e-9)
        # ... and the viewer writes back exactly our pose
        np.testing.assert_allclose(viewer_keyframe_matrix(k), shot.camera_to_worlds()[i], atol=1e-9)
        assert not k.override_fov_enabled and k.aspect == pytest.approx(800 / 600)
    # viewer duration = our duration (per-keyframe transition times)
    assert cp.compute_duration() == pytest.approx(shot.times[kf_idx[-1]] - shot.times[0])
    np.testing.assert_allclose(cp.compute_transition_times_cumsum(), shot.times[kf_idx] - shot.times[0])
    # the viewer's preview interpolates our frames closely (keyframe spline, not our exact curve)
    import viser.transforms as tf

    for j in range(0, shot.num_frames, 7):
        pose, fov = cp.interpolate_pose_and_fov_rad(shot.times[j] / shot.times[-1])
        pos = pose.translation() / VISER_NERFSTUDIO_SCALE_RATIO
        assert np.linalg.norm(pos - shot.positions[j]) < 0.02
        rot = (pose.rotation() @ tf.SO3.from_x_radians(np.pi)).as_matrix()
        ang = np.degrees(np.arccos(np.clip((np.trace(rot.T @ shot.rotations[j]) - 1) / 2, -1, 1)))
        assert ang < 2.0
        assert fov == pytest.approx(np.radians(40.0))


def test_keyframe_indices():
    t = np.arange(31) / 10.0  # 3 s at 10 fps
    idx = keyframe_indices(t, 0.5)
    np.testing.assert_array_equal(idx, [0, 5, 10, 15, 20, 25, 30])
    np.testing.assert_array_equal(keyframe_indices(t[:3], 10.0), [0, 2])


def test_atomic_write_keeps_old_file_on_failure(shot, tmp_path):
    target = tmp_path / "p.json"
    d = shot_to_camera_path(shot)
    write_camera_path(target, d)
    before = target.read_text()
    bad = dict(d)
    bad["camera_path"] = [dict(d["camera_path"][0], camera_to_world=[float("nan")] * 16)]
    with pytest.raises(InvalidInputError):
        write_camera_path(target, bad)
    # failure while writing (after validation): old file intact, no temp file left
    with mock.patch("cinenerf_ns.planner.atomic.os.fsync", side_effect=OSError("disk full")):  # the one writer
        with pytest.raises(OSError):
            write_camera_path(target, d)
    assert target.read_text() == before
    assert sorted(os.listdir(tmp_path)) == ["p.json"]


def test_read_errors(tmp_path):
    with pytest.raises(InvalidInputError, match="not found"):
        read_camera_path(tmp_path / "nope.json")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(InvalidInputError, match="not valid JSON"):
        read_camera_path(tmp_path / "bad.json")
    (tmp_path / "partial.json").write_text(json.dumps({"camera_path": []}))
    with pytest.raises(InvalidInputError, match="missing"):
        read_camera_path(tmp_path / "partial.json")


def test_bad_export_args(shot):
    with pytest.raises(InvalidInputError):
        shot_to_camera_path(shot, fov_deg=0.0)
    with pytest.raises(InvalidInputError):
        shot_to_camera_path(shot, width=0)
    with pytest.raises(InvalidInputError, match="frame rate"):
        shot_to_camera_path(shot, fps=60.0)
