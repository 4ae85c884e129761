"""Where the viewer's camera starts and what highlights look like: pure geometry in scene units (z up).

* :func:`opening_view`: the first view, inside the captured region: a training camera's view when the scene has
  training cameras, else the centre of the planner's start region looking at the scene; never outside a closed room
  where the walls hide the path.
* :func:`overview_view`: a top-down view of the whole scene (the "Top-down overview" toggle).
* :func:`highlight_box`: the box a query's Gaussians are outlined with (robust to stray Gaussians).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Tuple

import numpy as np

from cinenerf_ns.planner.shots.camera_path import DEFAULT_FOV_DEG

UP = np.array([0.0, 0.0, 1.0])


@dataclass
class View:
    """A camera placement: ``position`` [3] looking at ``look_at`` [3] with ``up`` [3] up on screen, scene units."""

    position: np.ndarray
    look_at: np.ndarray
    up: np.ndarray = field(default_factory=lambda: UP.copy())


@dataclass
class TrainingCameras:
    """A capture's training cameras in the scene's coordinates: ``centres`` [F, 3] and, when the scene carries them,
    ``c2w`` [F, 3, 4] camera-to-world poses (nerfstudio / OpenGL convention: x right, y up, looking along -z).
    An older compact export stores only the centres."""

    centres: np.ndarray
    c2w: Optional[np.ndarray] = None

    @classmethod
    def of(cls, centres: Optional[np.ndarray], c2w: Optional[np.ndarray] = None) -> Optional["TrainingCameras"]:
        """The cameras of a loaded scene (poses give the centres when only they are known); None when there are none."""
        if c2w is not None:
            c2w = np.asarray(c2w, np.float64).reshape(-1, 3, 4)
            if len(c2w) == 0 or not np.isfinite(c2w).all():
                c2w = None
        if c2w is not None:
            return cls(c2w[:, :, 3].copy(), c2w)
        if centres is None:
            return None
        c = np.asarray(centres, np.float64).reshape(-1, 3)
        return cls(c) if len(c) and np.isfinite(c).all() else None

    def typical(self) -> int:
        """The camera the viewer opens at: the one nearest the cameras' (coordinate-wise) median position, a central
        viewpoint of the capture (the middle of a hand-held arc, the middle of a room), deterministic."""
        return int(np.argmin(np.linalg.norm(self.centres - np.median(self.centres, axis=0), axis=1)))


def scene_box(means: np.ndarray, pct: float = 2.0) -> Tuple[np.ndarray, np.ndarray]:
    """(lo [3], hi [3]): the 2nd..98th percentile box of the Gaussian means [N, 3] (stray Gaussians ignored)."""
    means = np.asarray(means, np.float64).reshape(-1, 3)
    return np.percentile(means, pct, axis=0), np.percentile(means, 100 - pct, axis=0)


def opening_view(means: np.ndarray, start_region: Optional[Tuple[np.ndarray, np.ndarray]] = None,
                 cameras: Optional[TrainingCameras] = None) -> View:
    """The first view, inside the captured region.

    * The scene has training cameras with poses (a run's config.yml / run folder, a compact export with
      ``camera_poses``): the pose of :meth:`TrainingCameras.typical` -- its position, its look direction (-z) and its
      up (+y). The orbit point lies along that direction where it passes closest to the splat's median Gaussian (where
      a capture's Gaussians concentrate: its subject), or 25% of the scene's size ahead when that point is under 10%
      ahead (the subject beside or behind the camera).
    * Only camera centres (older compact exports, the bundled demo room): that camera's position, looking at the
      median Gaussian (horizontally along the scene box's longer side when that is nearly straight below or above).
    * No training cameras (procedural rooms, the tiny demo, a .ply): no captured view to reuse, so the centre of
      ``start_region`` (lo [3], hi [3], where the planner starts shots: free space inside the scene), else the scene
      box's centre, looking at the box's centre; from (nearly) above or below it, one step back, looking horizontally
      along the box's longer side."""
    lo, hi = scene_box(means)
    centre = (lo + hi) / 2
    extent = float(np.linalg.norm(hi - lo)) or 1.0
    axis = np.zeros(3)
    axis[int(np.argmax((hi - lo)[:2]))] = 1.0  # the box's longer horizontal side
    if cameras is not None:
        subject = np.median(np.asarray(means, np.float64).reshape(-1, 3), axis=0)
        if cameras.c2w is not None:
            c2w = cameras.c2w[cameras.typical()]
            pos = c2w[:, 3].copy()
            forward = -c2w[:, 2] / (np.linalg.norm(c2w[:, 2]) or 1.0)
            up = c2w[:, 1] / (np.linalg.norm(c2w[:, 1]) or 1.0)
            ahead = float((subject - pos) @ forward)
            ahead = ahead if ahead >= 0.1 * extent else 0.25 * extent
            return View(pos, pos + forward * ahead, up)
        pos = cameras.centres[cameras.typical()].copy()
        if np.linalg.norm((subject - pos)[:2]) < 0.05 * extent:  # (nearly) above/below it: look sideways
            return View(pos, pos + axis * 0.35 * (hi - lo).max())
        return View(pos, subject)
    pos = centre.copy() if start_region is None else (np.asarray(start_region[0]) + np.asarray(start_region[1])) / 2
    target = centre.copy()
    if np.linalg.norm((target - pos)[:2]) < 0.05 * extent:  # (nearly) above/below the centre: step back, look sideways
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
