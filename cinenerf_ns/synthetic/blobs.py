"""A second procedural scene family for benchmarks that cannot flatter the planner: walls plus randomly
placed round blobs of Gaussians, y up, about [-1, 1]^3.

Different statistics from planner/scene/procedural.py's room (z up, thin surface discs, 6 furniture objects on a grid):
  - y is up: a floor at y = -1 and three walls (x = -1, x = +1, z = -1); the z = +1 side and the top are open, so the
    free space is not a closed room (the planner's component choice must rely on the start region);
  - blobs are volumes, not surfaces: each is a ball of Gaussians (70% in a noisy shell, 30% filling it) with random
    orientations and log-normal, mildly anisotropic sizes; blob radii log-uniform in [0.08, 0.25], centres random
    (not on a grid), some floating in mid-air, some touching each other or a wall;
  - wall discs are jittered off their plane (a trained splat's surfaces are not exact planes) with random sizes;
  - 0.5% floaters: tiny, faint Gaussians anywhere in the box (a real capture's noise).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.splat_params import SplatParams


@dataclass
class Blob:
    name: str
    center: np.ndarray  # [3]
    radius: float


@dataclass
class BlobScene:
    splat: SplatParams  # the Gaussians (no colour)
    blob_ids: np.ndarray  # [N] int64 index into blobs, -1 for walls and floaters
    blobs: list = field(default_factory=list)
    up: tuple = (0.0, 1.0, 0.0)

    @property
    def free_lo(self) -> np.ndarray:
        """[3] the inner box the walls enclose (the open sides end at the box's edge)."""
        return np.array([-1.0, -1.0, -1.0])

    @property
    def free_hi(self) -> np.ndarray:
        return np.array([1.0, 1.0, 1.0])


def _random_quats(n: int, rng: np.random.Generator) -> np.ndarray:
    """[n, 4] uniform random unit quaternions (wxyz)."""
    q = rng.normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _plane_quats(normal_axis: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """[n, 4] wxyz rotations taking the disc's thin local z axis onto world axis ``normal_axis``, random spin."""
    spin = rng.uniform(0, 2 * np.pi, n)
    qs = np.stack([np.cos(spin / 2), 0 * spin, 0 * spin, np.sin(spin / 2)], 1)  # about local z
    if normal_axis == 2:
        return qs
    # z -> x: rotate +90 deg about y; z -> y: rotate -90 deg about x
    h = math.sqrt(0.5)
    qa = np.array([h, 0.0, h, 0.0]) if normal_axis == 0 else np.array([h, -h, 0.0, 0.0])
    w1, x1, y1, z1 = qa
    w2, x2, y2, z2 = qs.T
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], 1)


def _place_blobs(n_blobs: int, rng: np.random.Generator) -> list:
    """Blob centres and radii: random, mostly apart (a few tries each), inside the walls."""
    blobs: list = []
    for i in range(n_blobs):
        for _ in range(50):
            r = float(np.exp(rng.uniform(np.log(0.08), np.log(0.25))))
            c = rng.uniform(-1 + r, 1 - r, 3)
            c[1] = rng.uniform(-1 + r, 0.6)  # some rest on the floor, some float
            if all(np.linalg.norm(c - b.center) > 0.8 * (r + b.radius) for b in blobs):
                break
        blobs.append(Blob(f"blob {i}", c, r))
    return blobs


def blob_scene(n_gaussians: int = 200_000, seed: int = 0, n_blobs: int = 12, wall_fraction: float = 0.4,
               floater_fraction: float = 0.005) -> BlobScene:
    """A seeded blob scene of exactly ``n_gaussians`` Gaussians (see the module docstring)."""
    if n_gaussians < 100:
        raise InvalidInputError(f"n_gaussians must be >= 100, got {n_gaussians}")
    if n_blobs < 2:
        raise InvalidInputError(f"n_blobs must be >= 2 (go-to and look-at targets), got {n_blobs}")
    rng = np.random.default_rng(seed)
    blobs = _place_blobs(n_blobs, rng)
    n_float = int(round(floater_fraction * n_gaussians))
    n_wall = int(round(wall_fraction * n_gaussians))
    n_blob = n_gaussians - n_wall - n_float
    means, quats, scales, ids = [], [], [], []

    # walls: floor y=-1 (normal axis 1), x=-1 and x=+1 (axis 0), z=-1 (axis 2); counts by area (all 4 units^2)
    wall_defs = [(1, -1.0), (0, -1.0), (0, 1.0), (2, -1.0)]
    per_wall = rng.multinomial(n_wall, np.full(4, 0.25))
    spacing = math.sqrt(4.0 / max(n_wall / 4, 1))
    for (ax, pos), c in zip(wall_defs, per_wall):
        p = rng.uniform(-1, 1, (c, 3))
        p[:, ax] = pos + rng.normal(0, 0.003, c)  # off-plane jitter
        s = spacing * np.exp(rng.normal(np.log(0.7), 0.35, c))
        means.append(p)
        scales.append(np.stack([s, s * rng.uniform(0.3, 1.0, c), 0.08 * s], 1))
        quats.append(_plane_quats(ax, c, rng))
        ids.append(np.full(c, -1))

    # blobs: Gaussians by volume^(2/3) (surface-ish weighting), shell 70% + interior 30%
    w = np.array([b.radius ** 2 for b in blobs])
    per_blob = rng.multinomial(n_blob, w / w.sum())
    for k, (b, c) in enumerate(zip(blobs, per_blob)):
        d = rng.normal(size=(c, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        shell = rng.uniform(0, 1, c) < 0.7
        rad = np.where(shell, b.radius * (1 + rng.normal(0, 0.04, c)), b.radius * rng.uniform(0, 1, c) ** (1 / 3))
        means.append(b.center + d * rad[:, None])
        sp = math.sqrt(4 * math.pi * b.radius ** 2 / max(c, 1))
        base = sp * np.exp(rng.normal(np.log(0.8), 0.4, c))
        scales.append(base[:, None] * rng.uniform(0.4, 1.0, (c, 3)))
        quats.append(_random_quats(c, rng))
        ids.append(np.full(c, k))

    # floaters
    means.append(rng.uniform(-1, 1, (n_float, 3)))
    scales.append(np.full((n_float, 3), 0.004) * rng.uniform(0.5, 1.5, (n_float, 3)))
    quats.append(_random_quats(n_float, rng))
    ids.append(np.full(n_float, -1))

    op = np.concatenate([np.clip(rng.beta(5, 1.2, n_gaussians - n_float), 0.06, 0.995),
                         rng.uniform(0.02, 0.3, n_float)])
    t = lambda a: torch.as_tensor(np.concatenate(a), dtype=torch.float32)  # noqa: E731
    return BlobScene(
        SplatParams.of(t(means), t(quats), torch.log(t(scales)), np.log(op / (1 - op))),
        blob_ids=np.concatenate(ids).astype(np.int64), blobs=blobs,
    )
