"""Preview cameras are the cameras ns-render builds from a camera-path JSON (nerfstudio 1.1.5's
get_path_from_json and splatfacto's get_viewmat), first and last frames included."""
from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.shots.camera_path import camera_path_poses
from cinenerf_ns.preview.cameras import check_size, frame_indices, path_cameras, viewmat_from_c2w

sys.path.insert(0, str(Path(__file__).parent))
from _scenes import orbit_camera_path  # noqa: E402


def orbit_path(n=31, fps=30.0, fov=50.0, width=1280, height=720, seed=0):
    return orbit_camera_path(n=n, fps=fps, fov=fov, width=width, height=height, radius=2.0, seed=seed)


def test_viewmats_are_nerfstudio_get_viewmat():
    """Same c2w, focal, principal point as get_path_from_json and the same viewmat as splatfacto's get_viewmat,
    for the first and the last frame of the path (the preview renders at the path's own size here)."""
    sf = pytest.importorskip("nerfstudio.models.splatfacto")
    from nerfstudio.cameras.camera_paths import get_path_from_json

    d = orbit_path()
    cams = path_cameras(d, d["render_width"], d["render_height"], fps=d["fps"])
    ns = get_path_from_json(d)
    get_viewmat = getattr(sf.get_viewmat, "_torchdynamo_orig_callable", sf.get_viewmat)  # no torch.compile on CPU
    ns_view = get_viewmat(ns.camera_to_worlds.double()).numpy()  # [T, 4, 4]
    assert len(cams) == len(d["camera_path"]) and cams.frame_index.tolist() == list(range(len(d["camera_path"])))
    for i in (0, len(cams) - 1):
        assert np.allclose(cams.viewmats[i], ns_view[i], atol=1e-6)  # ns-render reads the JSON into float32
        fx, fy, cx, cy = cams.intrinsics[i]
        assert np.allclose([fx, fy, cx, cy], [ns.fx[i].item(), ns.fy[i].item(), ns.cx[i].item(), ns.cy[i].item()],
                           rtol=1e-6)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(2, 200), path_fps=st.sampled_from([24.0, 30.0, 60.0]), fps=st.floats(1, 120))
def test_first_and_last_frames_use_the_first_and_last_poses(n, path_fps, fps):
    d = orbit_path(n=n, fps=path_fps)
    poses = camera_path_poses(d)
    cams = path_cameras(d, 64, 36, fps)
    assert len(cams) == max(2, round(d["seconds"] * fps))
    assert cams.frame_index[0] == 0 and cams.frame_index[-1] == n - 1
    assert np.all(np.diff(cams.frame_index) >= 0)
    for k, i in ((0, 0), (-1, n - 1)):
        c2w_cv = np.linalg.inv(cams.viewmats[k])  # camera -> world, OpenCV axes
        assert np.allclose(c2w_cv[:3, 3], poses[i][:3, 3], atol=1e-9)  # same camera centre
        assert np.allclose(c2w_cv[:3, :3] * [1, -1, -1], poses[i][:3, :3], atol=1e-9)  # OpenGL axes flipped back


def test_viewmat_axes():
    """A point ahead of an OpenGL camera (-z) lands at +z, one above it (+y) at -y (OpenCV)."""
    c2w = np.eye(4)
    c2w[:3, 3] = [1.0, 2.0, 3.0]
    V = viewmat_from_c2w(c2w)
    assert np.allclose(V @ [1.0, 2.0, 1.0, 1.0], [0, 0, 2, 1])
    assert np.allclose(V @ [1.0, 3.0, 3.0, 1.0], [0, -1, 0, 1])


def test_focal_from_vertical_fov_at_preview_size():
    d = orbit_path(fov=60.0)
    cams = path_cameras(d, 480, 270, 15)
    f = 135.0 / math.tan(math.radians(30.0))
    assert np.allclose(cams.intrinsics[:, :2], f) and np.allclose(cams.intrinsics[:, 2:], [240.0, 135.0])


def test_frame_indices_single_frame_and_spread():
    assert frame_indices(1, 0.1, 15).tolist() == [0]
    assert frame_indices(150, 5.0, 30).tolist() == list(range(150))
    idx = frame_indices(155, 155 / 30, 15)
    assert len(idx) == 78 and idx[0] == 0 and idx[-1] == 154 and np.all(np.diff(idx) >= 1)


@pytest.mark.parametrize("w,h,fps,opt",
                         [(15, 100, 15, "--width"), (100, 4097, 15, "--height"), (100, 100, 0.5, "--fps"),
                                         (100, 100, 121, "--fps"), (100, 100, float("nan"), "--fps"),
                                         (100.5, 100, 15, "--width")])
def test_bad_sizes_name_the_option_and_range(w, h, fps, opt):
    with pytest.raises(InvalidInputError, match=opt):
        check_size(w, h, fps)


def test_non_perspective_path_is_refused():
    d = orbit_path()
    d["camera_type"] = "equirectangular"
    with pytest.raises(InvalidInputError, match="perspective"):
        path_cameras(d)
