"""The compiled preview rasteriser (native/raster.c) against the pure-torch tiled renderer, and both against the
float64 reference of gsplat's classic rasterizer (method/render_reference.py)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings, strategies as st

from cinenerf_ns.method.render_reference import render_reference
from cinenerf_ns.preview import native
from cinenerf_ns.preview.raster_torch import make_scene, project, raster_reference

sys.path.insert(0, str(Path(__file__).parent))
from _scenes import intrinsics, random_gaussians, random_viewmat  # noqa: E402

SETTINGS = dict(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
needs_native = pytest.mark.skipif(native.render_fn("float64") is None or native.render_fn("float32") is None,
                                  reason=f"no compiled preview rasteriser: {native.native_status()}")


def _native(scene, V, intr, W, H, threads=2):
    rgb, alpha, stats = native.render_native(scene.means.numpy(), scene.cov3d.numpy(), scene.opacities.numpy(),
                                             scene.colors.numpy(), V, intr, W, H, threads=threads)
    return torch.from_numpy(rgb), torch.from_numpy(alpha), stats


@needs_native
@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(0, 120), W=st.integers(1, 70), H=st.integers(1, 50),
       spread=st.floats(0.05, 3.0), threads=st.integers(1, 4))
def test_native_is_the_torch_path_float64(seed, n, W, H, spread, threads):
    """Random scenes (Gaussians behind the camera, off-image, across tiles, huge and tiny) on multi-tile images:
    the compiled kernel and the torch tiled renderer composite the same Gaussians in the same order."""
    m, q, s, o, c = random_gaussians(seed, n, spread=spread)
    scene = make_scene(m, q, s, o, c, dtype=torch.float64)
    V, intr = random_viewmat(seed), intrinsics(W, H, 40 + seed % 60)
    rt, at = raster_reference(scene, torch.from_numpy(V), intr, W, H)
    rn, an, stats = _native(scene, V, intr, W, H, threads)
    assert rn.shape == (H, W, 3) and an.shape == (H, W, 1)
    assert torch.allclose(rn, rt, atol=1e-10, rtol=0) and torch.allclose(an, at, atol=1e-10, rtol=0)
    assert stats["visible"] == len(project(scene, torch.from_numpy(V), intr, W, H)["index"])


@needs_native
@pytest.mark.parametrize("seed", range(8))
def test_native_is_the_torch_path_float32(seed):
    """The float32 build (what previews use) against the torch path in float32."""
    m, q, s, o, c = random_gaussians(seed, 400, spread=1.0)
    scene = make_scene(m, q, s, o, c, dtype=torch.float32)
    W, H = 96, 54
    V, intr = random_viewmat(seed, jitter=0.1).astype(np.float32), intrinsics(W, H)
    rt, at = raster_reference(scene, torch.from_numpy(V), intr, W, H)
    rn, an, _ = _native(scene, V, intr, W, H)
    assert rn.dtype == torch.float32
    assert (rn - rt).abs().max() < 1e-4 and (an - at).abs().max() < 1e-4
    assert at.mean() > 0.2  # the scene covers a good part of the image


def _reference(m, q, s, o, c, V, intr, W, H):
    fx, fy, cx, cy = intr
    K = torch.tensor([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]], dtype=torch.float64)
    return render_reference(m, q, s, o, c, torch.from_numpy(V), K, W, H)


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 60), W=st.integers(1, 16), H=st.integers(1, 16),
       scale_hi=st.sampled_from([0.02, 0.1, 0.5]))
def test_single_tile_equals_reference(seed, n, W, H, scale_hi):
    """Single-tile images with every Gaussian projecting inside: both paths equal render_reference (float64)."""
    m, q, s, o, c = random_gaussians(seed, n, spread=0.5, scale=(0.005, scale_hi))
    V, intr = random_viewmat(seed, jitter=0.05), intrinsics(W, H, 60)
    fx, fy, cx, cy = intr
    mc = m @ torch.from_numpy(V[:3, :3]).T + torch.from_numpy(V[:3, 3])
    u, v = fx * mc[:, 0] / mc[:, 2] + cx, fy * mc[:, 1] / mc[:, 2] + cy
    inside = (mc[:, 2] > 0.1) & (u > 0) & (u < W) & (v > 0) & (v < H)
    m, q, s, o, c = (t[inside] for t in (m, q, s, o, c))
    ref_rgb, ref_a = _reference(m, q, s, o, c, V, intr, W, H)
    scene = make_scene(m, q, s, o, c, dtype=torch.float64)
    rt, at = raster_reference(scene, torch.from_numpy(V), intr, W, H)
    assert torch.allclose(rt, ref_rgb, atol=1e-9, rtol=0) and torch.allclose(at, ref_a, atol=1e-9, rtol=0)
    if native.render_fn("float64") is not None:
        rn, an, _ = _native(scene, V, intr, W, H)
        assert torch.allclose(rn, ref_rgb, atol=1e-9, rtol=0) and torch.allclose(an, ref_a, atol=1e-9, rtol=0)


@pytest.mark.parametrize("seed", range(4))
def test_multi_tile_equals_reference(seed):
    """gsplat 1.5.3's opacity-aware box only drops alpha < 1/255, so on multi-tile images too (Gaussians in front of
    the near plane) the tiled paths equal the every-pixel-sees-every-Gaussian reference."""
    m, q, s, o, c = random_gaussians(seed, 80, spread=0.8)
    W, H = 53, 37
    V, intr = random_viewmat(seed, jitter=0.1), intrinsics(W, H)
    ref_rgb, ref_a = _reference(m, q, s, o, c, V, intr, W, H)
    scene = make_scene(m, q, s, o, c, dtype=torch.float64)
    rt, at = raster_reference(scene, torch.from_numpy(V), intr, W, H)
    assert torch.allclose(rt, ref_rgb, atol=1e-9, rtol=0) and torch.allclose(at, ref_a, atol=1e-9, rtol=0)
    assert ref_a.mean() > 0.1


def test_culling_and_empty():
    """Behind the camera, beyond the image, or nothing at all: nothing drawn."""
    m, q, s, o, c = random_gaussians(0, 30, spread=0.2)
    W, H = 32, 20
    intr = intrinsics(W, H)
    behind = make_scene(m * torch.tensor([1, 1, -1.0], dtype=torch.float64), q, s, o, c, dtype=torch.float64)
    aside = make_scene(m + torch.tensor([50.0, 0, 0], dtype=torch.float64), q, s, o, c, dtype=torch.float64)
    empty = make_scene(m[:0], q[:0], s[:0], o[:0], c[:0], dtype=torch.float64)
    for scene in (behind, aside, empty):
        rgb, a = raster_reference(scene, torch.eye(4, dtype=torch.float64), intr, W, H)
        assert rgb.abs().max() == 0 and a.abs().max() == 0
        if native.render_fn("float64") is not None:
            rn, an, stats = _native(scene, np.eye(4), intr, W, H)
            assert rn.abs().max() == 0 and an.abs().max() == 0 and stats["visible"] == 0


def test_opaque_wall_stops_the_ray():
    """A wall of opaque Gaussians in front hides a red one behind it (transmittance stop), alpha ~ 1."""
    g = torch.linspace(-1, 1, 21, dtype=torch.float64)
    xy = torch.stack(torch.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    wall = torch.cat([xy, torch.full((len(xy), 1), 2.0, dtype=torch.float64)], 1)
    m = torch.cat([wall, torch.tensor([[0.0, 0.0, 4.0]], dtype=torch.float64)])
    n = len(m)
    q = torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64).repeat(n, 1)
    s = torch.full((n, 3), 0.08, dtype=torch.float64)
    s[-1] = 1.0
    o = torch.full((n,), 0.999, dtype=torch.float64)
    c = torch.zeros(n, 3, dtype=torch.float64)
    c[:-1, 1] = 1.0  # green wall
    c[-1, 0] = 1.0  # red blob behind
    scene = make_scene(m, q, s, o, c, dtype=torch.float64)
    W, H = 24, 24
    intr = intrinsics(W, H, 30)
    for rgb, a in [raster_reference(scene, torch.eye(4, dtype=torch.float64), intr, W, H)] + (
            [_native(scene, np.eye(4), intr, W, H)[:2]] if native.render_fn("float64") is not None else []):
        assert a.min() > 0.99 and rgb[..., 0].max() < 2e-3 and rgb[..., 1].min() > 0.98  # T stops near 1e-3
