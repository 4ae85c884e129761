"""Shared helpers for the geometry tests: small random scenes as float64 tensors."""
from __future__ import annotations

import math

import torch

from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene, quat_wxyz_to_rotmat

# The test box has 2 cores shared by several jobs: multi-threaded torch ops stall waiting for busy
# threads (10-50x slower on small tensors). Geometry tests are small, so one thread.
torch.set_num_threads(1)


def random_scene(n: int, seed: int = 0, extent: float = 1.0, rmin: float = 0.01, rmax: float = 0.2,
                 camera_radius: float = 0.05, dtype=torch.float64, flat: bool = False) -> EllipsoidScene:
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g, dtype=dtype) * 2 - 1) * extent
    rot = quat_wxyz_to_rotmat(torch.randn(n, 4, generator=g, dtype=dtype))
    radii = rmin + (rmax - rmin) * torch.rand(n, 3, generator=g, dtype=dtype)
    if flat:
        radii[:, 2] = rmin * 1e-2
    return EllipsoidScene(means=means, rotations=rot, radii=radii, opacities=torch.ones(n, dtype=dtype),
                          camera_radius=camera_radius)


def surface_samples(radii: torch.Tensor, n: int = 200) -> torch.Tensor:
    """Dense points on an axis-aligned ellipsoid surface [n*2n, 3]."""
    th = torch.linspace(0, math.pi, n, dtype=torch.float64)
    ph = torch.linspace(0, 2 * math.pi, 2 * n, dtype=torch.float64)
    t, p = torch.meshgrid(th, ph, indexing="ij")
    a = radii.double()
    return torch.stack([a[0] * t.sin() * p.cos(), a[1] * t.sin() * p.sin(), a[2] * t.cos()], -1).reshape(-1, 3)
