"""The CPU preview against gsplat's own CUDA rasterization of the same camera (needs CUDA; skipped without).

Tolerance: both are float32 classic 3DGS with the same culling, tile lists and stop rules, so frames differ only by
rounding (CUDA's __expf and fused multiply-adds vs the C library's expf, summation order). A rounding difference can
flip a Gaussian across alpha = 1/255 or a pixel across the 1e-4 transmittance stop, which moves that pixel by at most
about 1/255 * T or 1e-3; over a whole 480x270 frame this keeps the mean absolute error far below 1e-3 (in [0, 1])
and leaves at most 0.5 % of the pixels more than 2/255 apart.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from cinenerf_ns.method.checkpoint import load_splat
from cinenerf_ns.planner.trajectory.orientation import look_at_rotations
from cinenerf_ns.preview import native, path_cameras, preview_camera_path, scene_from_splat
from cinenerf_ns.preview.render import render_gsplat, render_premultiplied
from cinenerf_ns.scenes import DEMO_SCENE

sys.path.insert(0, str(Path(__file__).parent))
from _scenes import orbit_camera_path, random_splat  # noqa: E402

pytestmark = pytest.mark.gpu


def _room_path():
    """Two frames from a training camera of the bundled room, looking at the room's centre."""
    ck = load_splat(DEMO_SCENE)
    centres = np.asarray(ck.info["camera_centres"], dtype=np.float64)
    splat = ck.params
    target = torch.as_tensor(splat.means).double().median(0).values.numpy()
    pos = centres[:2]
    rot = look_at_rotations(pos, target)
    c2w = np.tile(np.eye(4), (2, 1, 1))
    c2w[:, :3, :3], c2w[:, :3, 3] = rot, pos
    frames = [{"camera_to_world": m.reshape(-1).tolist(), "fov": 60.0, "aspect": 16 / 9} for m in c2w]
    return splat, {"camera_type": "perspective", "render_width": 1920, "render_height": 1080, "seconds": 2 / 15,
                   "camera_path": frames}


@pytest.mark.parametrize("which", ["room", "random"])
def test_cpu_frame_matches_gsplat(which):
    if native.render_fn("float32") is None:
        pytest.skip(f"no compiled preview rasteriser: {native.native_status()}")
    splat, cam = _room_path() if which == "room" else (random_splat(7, n=3000, spread=1.5), orbit_camera_path(n=4))
    scene = scene_from_splat(splat)
    cams = path_cameras(cam, 480, 270, 15)
    rgb_c, a_c = render_premultiplied(scene, cams.viewmats[0], cams.intrinsics[0], 480, 270, backend="native")
    rgb_g, a_g = render_gsplat(scene, cams.viewmats[:1], cams.K(0)[None], 480, 270)
    rgb_g, a_g = rgb_g[0].float().cpu(), a_g[0].float().cpu()
    assert a_g.mean() > 0.2  # something is in view
    err = (rgb_c - rgb_g).abs()
    assert err.mean() < 1e-3 and (a_c - a_g).abs().mean() < 1e-3
    assert (err.max(-1).values > 2 / 255).float().mean() < 0.005


def test_preview_on_cuda_writes_the_mp4(tmp_path):
    splat, cam = random_splat(8, n=2000), orbit_camera_path(n=20)
    out = preview_camera_path(splat, cam, tmp_path, "gpu", width=64, height=48, fps=10, device="cuda", progress=False)
    assert out["backend"] == "gsplat" and Path(out["paths"]["mp4"]).stat().st_size > 0
    cpu = preview_camera_path(splat, cam, tmp_path, "cpu", width=64, height=48, fps=10, progress=False)
    assert cpu["frames"] == out["frames"] and torch.cuda.is_available()
