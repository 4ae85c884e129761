"""Where the viewer's camera starts and what highlights look like: pure geometry in scene units (z up).

* :func:`opening_view`: the first view, inside the captured region (a training camera's pose, else the centre of the
  planner's start region looking at the scene), never outside a closed room where the walls hide the path.
* :func:`overview_view`: a top-down view of the whole scene (the "Top-down overview" toggle).
* :func:`highlight_box`: the box a query's Gaussians are outlined with (robust to stray Gaussians).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

from cinenerf_ns.planner.shots.camera_path import DEFAULT_FOV_DEG

UP = np.array([0.0, 0.0, 1.0])


@dataclass
class View:
    """A camera placement: ``position`` [3] looking at ``look_at`` [3], scene units."""

    position: np.ndarray
    look_at: np.ndarray


def scene_box(means: np.ndarray, pct: float = 2.0) -> Tuple[np.ndarray, np.ndarray]:
    """(lo [3], hi [3]): the 2nd..98th percentile box of the Gaussian means [N, 3] (stray Gaussians ignored)."""
    means = np.asarray(means, np.float64).reshape(-1, 3)
    return np.percentile(means, pct, axis=0), np.percentile(means, 100 - pct, axis=0)


def opening_view(means: np.ndarray, start_region: Optional[Tuple[np.ndarray, np.ndarray]] = None,
                 camera_c2w: Optional[np.ndarray] = None) -> View:
    """The first view. ``camera_c2w`` [3, 4] (a training camera, nerfstudio convention: looks along -z): its pose.
    Else the centre of ``start_region`` (lo [3], hi [3], where the planner starts shots: free space inside the
    scene), else the scene box's centre, looking at the scene's centre; when the two nearly coincide, looking
    horizontally along the box's longest side."""
    lo, hi = scene_box(means)
    centre = (lo + hi) / 2
    extent = float(np.linalg.norm(hi - lo)) or 1.0
    if camera_c2w is not None:
        c2w = np.asarray(camera_c2w, np.float64).reshape(3, 4)
        return View(c2w[:, 3].copy(), c2w[:, 3] - c2w[:, 2] * 0.25 * extent)
    pos = centre.copy() if start_region is None else (np.asarray(start_region[0]) + np.asarray(start_region[1])) / 2
    target = centre.copy()
    if np.linalg.norm((target - pos)[:2]) < 0.05 * extent:  # (nearly) above/below the centre: look sideways
        axis = np.zeros(3)
        axis[int(np.argmax((hi - lo)[:2]))] = 1.0
        pos = pos - axis * 0.35 * (hi - lo).max()
        target = np.array([centre[0], centre[1], pos[2]]) + axis * 0.1 * (hi - lo).max()
    return View(np.asarray(pos, np.float64), np.asarray(target, np.float64))


def overview_view(means: np.ndarray, fov_deg: float = DEFAULT_FOV_DEG) -> View:
    """Top-down: above the scene box's centre, high enough that the box's footprint fits the vertical ``fov_deg``
    (a small tilt toward -y keeps the orbit controls' up vector defined)."""
    lo, hi = scene_box(means)
    centre = (lo + hi) / 2
    half = 0.5 * float(max(hi[0] - lo[0], hi[1] - lo[1]))
    height = half / np.tan(np.deg2rad(fov_deg) / 2) * 1.15
    pos = np.array([centre[0], centre[1] - 0.02 * half, hi[2] + height])
    return View(pos, centre)


def highlight_box(points: np.ndarray, pct: float = 5.0, pad: float = 0.02) -> Tuple[np.ndarray, np.ndarray]:
    """(centre [3], size [3]) of the box around ``points`` [M, 3] (``pct``..100-``pct`` percentiles, padded by
    ``pad`` of the box's diagonal so the outline sits just outside the object)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    if len(pts) == 0:
        raise ValueError("highlight_box needs at least one point")
    lo, hi = np.percentile(pts, pct, axis=0), np.percentile(pts, 100 - pct, axis=0)
    size = hi - lo
    size = size + pad * max(float(np.linalg.norm(size)), 1e-3)
    return (lo + hi) / 2, size
