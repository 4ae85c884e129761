"""A small labelled demo scene for the standalone viewer (``--load-config demo``) and the camera
look-at rotation used by the viewer's tests. Planning on it uses the real planner."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List, Tuple

import numpy as np

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.splat_params import SplatParams, rgb_to_dc

UP = np.array([0.0, 0.0, 1.0])


@dataclass
class DemoScene:
    """The demo's Gaussians plus their ground-truth object labels."""

    splat: SplatParams
    labels: List[str]  # object names; label_of indexes this list, -1 = background
    label_of: np.ndarray  # [N] int


def demo_scene(seed: int = 0, floor_res: int = 30) -> DemoScene:
    """A floor with three named objects ('red box', 'green ball', 'blue pillar'), ~2.5k Gaussians."""
    rng = np.random.default_rng(seed)
    parts: List[Tuple[np.ndarray, np.ndarray, float, int]] = []  # (means, color, sigma, label)
    g = np.linspace(-1.2, 1.2, floor_res)
    fx, fy = np.meshgrid(g, g)
    floor = np.stack([fx.ravel(), fy.ravel(), np.zeros(fx.size)], -1)
    parts.append((floor, np.array([0.55, 0.55, 0.5]), 0.045, -1))
    box = rng.uniform(-0.12, 0.12, (400, 3)) + np.array([0.5, 0.45, 0.14])
    parts.append((box, np.array([0.85, 0.15, 0.1]), 0.02, 0))
    d = rng.normal(size=(400, 3))
    ball = 0.15 * d / np.linalg.norm(d, axis=1, keepdims=True) + np.array([-0.5, 0.35, 0.2])
    parts.append((ball, np.array([0.15, 0.75, 0.2]), 0.02, 1))
    ang, hz = rng.uniform(0, 2 * np.pi, 500), rng.uniform(0.0, 0.7, 500)
    pillar = np.stack([0.08 * np.cos(ang), 0.08 * np.sin(ang) - 0.6, hz], -1)
    parts.append((pillar, np.array([0.15, 0.25, 0.85]), 0.02, 2))
    means = np.concatenate([p[0] for p in parts]).astype(np.float32)
    n = len(means)
    colors = np.concatenate([np.tile(p[1], (len(p[0]), 1)) for p in parts]).astype(np.float32)
    colors = np.clip(colors + rng.normal(scale=0.03, size=colors.shape), 0, 1).astype(np.float32)
    sig = np.concatenate([np.full(len(p[0]), p[2]) for p in parts])
    log_scales = np.log(np.stack([sig, sig, sig], -1)).astype(np.float32)
    log_scales[: len(floor), 2] = math.log(0.004)  # flat floor tiles
    q = rng.normal(size=(n, 4))
    q[: len(floor)] = [1, 0, 0, 0]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return DemoScene(
        SplatParams(means, q.astype(np.float32), log_scales, np.full(n, 3.0, np.float32), colors_dc=rgb_to_dc(colors)),
        labels=["red box", "green ball", "blue pillar"],
        label_of=np.concatenate([np.full(len(p[0]), p[3]) for p in parts]),
    )


def look_at_rotation(position: np.ndarray, target: np.ndarray, up: np.ndarray = UP) -> np.ndarray:
    """nerfstudio camera-to-world rotation [3, 3] at ``position`` looking at ``target`` (-z forward,
    +y up, no roll). Straight up/down falls back to +y as the up hint."""
    f = np.asarray(target, np.float64) - np.asarray(position, np.float64)
    nf = np.linalg.norm(f)
    if nf < 1e-12:
        raise InvalidInputError("the camera cannot look at its own position")
    f = f / nf
    hint = up if abs(float(f @ up)) < 0.999 else np.array([0.0, 1.0, 0.0])
    x = np.cross(f, hint)
    x /= np.linalg.norm(x)
    y = np.cross(x, f)
    return np.stack([x, y, -f], axis=1)
