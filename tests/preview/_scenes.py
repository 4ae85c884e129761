"""Random small Gaussian scenes and cameras for the preview tests."""
from __future__ import annotations

import numpy as np
import torch


def random_gaussians(seed: int, n: int, spread: float = 0.6, depth: float = 3.0, scale=(0.01, 0.4)):
    """(means [N, 3], quats [N, 4], scales [N, 3] activated, opacities [N], colours [N, 3]) in front of the
    identity camera (OpenCV: +z forward), float64."""
    g = torch.Generator().manual_seed(seed)
    d = torch.float64
    means = (torch.rand(n, 3, generator=g, dtype=d) - 0.5) * 2 * spread + torch.tensor([0.0, 0.0, depth], dtype=d)
    quats = torch.randn(n, 4, generator=g, dtype=d)
    lo, hi = scale
    scales = torch.exp(torch.empty(n, 3, dtype=d).uniform_(np.log(lo), np.log(hi), generator=g))
    opac = torch.rand(n, generator=g, dtype=d) * 0.98 + 0.01
    cols = torch.rand(n, 3, generator=g, dtype=d)
    return means, quats, scales, opac, cols


def random_viewmat(seed: int, jitter: float = 0.3) -> np.ndarray:
    """[4, 4] world -> camera close to the identity (a small rotation and shift)."""
    rng = np.random.default_rng(seed)
    w = rng.normal(size=3) * jitter
    th = np.linalg.norm(w)
    k = w / (th + 1e-12)
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    R = np.eye(3) + np.sin(th) * Kx + (1 - np.cos(th)) * Kx @ Kx
    V = np.eye(4)
    V[:3, :3] = R
    V[:3, 3] = rng.normal(size=3) * 0.1
    return V


def intrinsics(width: int, height: int, fov_deg: float = 50.0):
    f = (height / 2.0) / np.tan(np.deg2rad(fov_deg) / 2.0)
    return (f, f, width / 2.0, height / 2.0)


def random_splat(seed: int = 0, n: int = 300, spread: float = 1.0):
    """A SplatParams (log scales, logit opacities, SH DC colour) around the origin."""
    from cinenerf_ns.planner.scene.splat_params import SH_C0, SplatParams

    m, q, s, o, c = random_gaussians(seed, n, spread=spread, depth=0.0, scale=(0.02, 0.2))
    return SplatParams.of(m.float(), q.float(), torch.log(s).float(), torch.logit(o.clamp(0.05, 0.99)).float(),
                          colors_dc=((c - 0.5) / SH_C0).float())


def orbit_camera_path(n: int = 31, fps: float = 30.0, fov: float = 50.0, width: int = 1280, height: int = 720,
                      radius: float = 3.0, seed: int = 0):
    """Camera-path dict of n frames on a wobbly orbit looking at the origin (the planner's Shot export)."""
    from cinenerf_ns.planner.shots.camera_path import shot_to_camera_path
    from cinenerf_ns.planner.shots.shot import Shot
    from cinenerf_ns.planner.trajectory.orientation import look_at_rotations

    rng = np.random.default_rng(seed)
    t = np.arange(n) / fps
    a = np.linspace(0, 1.5, n) + rng.normal(scale=0.01, size=n)
    pos = np.stack([radius * np.cos(a), radius * np.sin(a), 0.5 + 0.1 * np.sin(3 * a)], -1)
    rot = look_at_rotations(pos, np.zeros(3))
    shot = Shot(times=t, positions=pos, rotations=rot, look_at=np.zeros(3), goal=pos[-1], start=pos[0], fps=fps)
    return shot_to_camera_path(shot, fov_deg=fov, width=width, height=height)
