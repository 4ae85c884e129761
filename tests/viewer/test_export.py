"""Camera-path export: the JSON nerfstudio's ns-render and Render tab read."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from viewer_fakes import line_shot

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.shots.shot import Shot
from cinenerf_ns.viewer.export import check_export_name, default_exporter, render_command, write_json_atomic

camera_path_from_shot = default_exporter()  # what the panel exports with (the planner's camera_path)


def test_camera_path_is_read_by_nerfstudio():
    from nerfstudio.cameras.camera_paths import get_path_from_json

    shot = line_shot([0, 0, 0.5], [1, 0, 0.5], [2, 1, 0], duration=2.0)
    data = camera_path_from_shot(shot, 60, 64, 48, 15)
    data = json.loads(json.dumps(data))  # JSON-clean
    cams = get_path_from_json(data)
    assert cams.camera_to_worlds.shape == (31, 3, 4)
    np.testing.assert_allclose(cams.camera_to_worlds[0].numpy(), np.c_[shot.rotations[0], shot.positions[0]], atol=1e-6)
    np.testing.assert_allclose(cams.camera_to_worlds[-1].numpy(), np.c_[shot.rotations[-1], shot.positions[-1]],
                               atol=1e-6)
    assert int(cams.width[0]) == 64 and int(cams.height[0]) == 48
    # Render tab "Load Path": keyframes with 4x4 matrices; the spline lasts the shot's duration
    k = data["keyframes"]
    assert len(k) >= 3 and all(len(f["matrix"]) == 16 for f in k)
    # the keyframe transitions add up to the shot's duration, so the Render tab's spline lasts as long
    assert sum(f["override_transition_sec"] for f in k[1:]) == pytest.approx(2.0)
    # what the Render tab's "Load Path" reads (nerfstudio/viewer/render_panel.py)
    import viser.transforms as tf
    from nerfstudio.viewer.render_panel import Keyframe

    for frame in k:
        pose = tf.SE3.from_matrix(np.array(frame["matrix"]).reshape(4, 4))
        pose = tf.SE3.from_rotation_and_translation(pose.rotation() @ tf.SO3.from_x_radians(np.pi), pose.translation())
        Keyframe(position=pose.translation() * 10, wxyz=pose.rotation().wxyz,
                 override_fov_enabled=abs(frame["fov"] - data.get("default_fov", 0.0)) > 1e-3,
                 override_fov_rad=frame["fov"] / 180.0 * np.pi,
                 override_time_enabled=frame.get("override_time_enabled", False),
                 override_time_val=frame.get("render_time", None), aspect=frame["aspect"],
                 override_transition_enabled=frame.get("override_transition_enabled", None),
                 override_transition_sec=frame.get("override_transition_sec", None))
    first = tf.SE3.from_matrix(np.array(k[0]["matrix"]).reshape(4, 4))
    np.testing.assert_allclose(first.translation(), shot.positions[0], atol=1e-9)


def test_camera_path_from_torch_shot():
    ref = line_shot([0, 0, 0.5], [1, 0, 0.5], [2, 1, 0])
    t = lambda a: torch.as_tensor(a, dtype=torch.float32)  # noqa: E731
    shot = Shot(times=t(ref.times), positions=t(ref.positions), rotations=t(ref.rotations), look_at=t(ref.look_at),
                goal=t(ref.goal), start=t(ref.start))
    data = camera_path_from_shot(shot, 50, 100, 100, 30)
    assert len(data["camera_path"]) == 31


def test_bad_inputs():
    shot = line_shot([0, 0, 0.5], [1, 0, 0.5], [2, 1, 0])
    with pytest.raises(InvalidInputError):
        camera_path_from_shot(shot, 0, 100, 100, 30)
    with pytest.raises(InvalidInputError):
        camera_path_from_shot(shot, 50, 100, 0, 30)
    with pytest.raises(InvalidInputError):  # a shot whose times go backwards cannot even be built
        Shot(times=shot.times[::-1].copy(), positions=shot.positions, rotations=shot.rotations, look_at=shot.look_at,
             goal=shot.goal, start=shot.start)


def test_names():
    assert check_export_name("take_1.v2") == "take_1.v2"
    assert check_export_name(" a.json ") == "a"
    for bad in ["", ".hidden", "a/b", "../x", "a b", "x" * 200]:
        with pytest.raises(InvalidInputError):
            check_export_name(bad)


def test_write_json_atomic(tmp_path):
    p = tmp_path / "camera_paths" / "a.json"
    good = camera_path_from_shot(line_shot([0, 0, 0.5], [1, 0, 0.5], [2, 1, 0]), 50, 100, 100, 30)
    write_json_atomic(p, good)
    assert json.loads(p.read_text()) == json.loads(json.dumps(good))
    bad = json.loads(json.dumps(good))
    bad["camera_path"][3]["camera_to_world"][0] = float("inf")
    with pytest.raises((ValueError, InvalidInputError)):
        write_json_atomic(p, bad)
    assert json.loads(p.read_text()) == json.loads(json.dumps(good))  # the previous file is untouched
    assert [q.name for q in p.parent.iterdir()] == ["a.json"]


def test_render_command(tmp_path):
    assert render_command(None, tmp_path / "x.json", "fox", "x") is None  # no run: no command with a placeholder
    cmd = render_command(tmp_path / "run" / "config.yml", tmp_path / "x.json", "fox", "x")
    assert cmd.startswith(f"ns-render camera-path --load-config {tmp_path / 'run' / 'config.yml'} ")
    assert cmd.endswith("--output-path renders/fox/x.mp4")


def test_same_name_from_many_threads_gives_as_many_files(tmp_path):
    """Two clients exporting one name at once: every export its own file, each whole (os.link never replaces)."""
    import threading

    from cinenerf_ns.viewer.export import write_json_unique

    data = camera_path_from_shot(line_shot([0, 0, 0], [1, 0, 0], [0, 1, 0]), 50.0, 64, 48, 30)
    paths, errors = [], []
    barrier = threading.Barrier(8)

    def work():
        barrier.wait()
        for _ in range(5):
            try:
                paths.append(write_json_unique(tmp_path, "take", data)[0])
            except Exception as e:  # noqa: BLE001
                errors.append(e)

    threads = [threading.Thread(target=work) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert errors == [] and len(set(paths)) == 40
    names = sorted(f.name for f in tmp_path.iterdir())
    assert len(names) == 40 and "take.json" in names and "take-40.json" in names  # no temporary file left
    assert all(json.loads(p.read_text()) == json.loads(json.dumps(data)) for p in paths)
