"""Detours around the voxel path's corner-cutting steps.

A* moves between 26-adjacent free voxels, so a diagonal step may pass an occupied voxel at a shared edge or corner.
The step is safe (each half lies in its own closed free voxel: coarse_path.py), but the exact voxel walk refuses it
(it counts every voxel within EPS of the segment), so its corridor polytope must be a Prop-2 one, several times
the cost of a grid polytope (docs/PLANNER_DEFAULTS.md, corner_detours). Where the step's
neighbourhood has a route of axis-ordered moves through free voxels (the walk proves each of its segments), the
step is replaced by that route; the shortcut and the corridor then see only walk-free segments there. A step with no
such route stays as it is.

Routes of a step d (its nonzero axes moved one at a time or two at once): first the two-segment ones (for a
three-axis step: one axis, then the other two together, or the other way round), then the three-segment ones; the
first route, in that fixed order, whose every segment the walk proves free is taken. Route points take each
coordinate from one of the step's ends, so they are exact voxel (or coarse block) centres.
"""
from __future__ import annotations

from itertools import permutations

import numpy as np


def _route_table() -> np.ndarray:
    """bool [12, 4, 3]: the routes of a step over all three axes, as the axes moved so far at each of their 4 points
    (a two-segment route repeats its last point). Fewest segments first: one axis then the other two, or the two then
    the one (6), then one axis at a time (6). On a step that does not move along an axis, a route that moves it first
    or last has a repeated point and is the step itself or a shorter route."""
    routes = []
    for a in range(3):
        rest = [b for b in range(3) if b != a]
        routes += [[[a], rest], [rest, [a]]]
    routes += [[[a], [b], [c]] for a, b, c in permutations(range(3))]
    out = np.zeros((len(routes), 4, 3), dtype=bool)
    for r, route in enumerate(routes):
        for k, axes in enumerate(route, start=1):
            out[r, k:, axes] = True
    return out


ROUTES = _route_table()  # [12, 4, 3]


def detour_corner_steps(segments_free, way: np.ndarray) -> tuple:
    """(way' [K', 3] float64, steps detoured): ``way`` [K, 3] (float64 world points of a voxel path) with each step
    that ``segments_free`` (VoxelObstacles.segments_free: bool [P] for segment ends [P, 3], [P, 3]) refuses replaced
    by the first of its routes (ROUTES) whose segments it all accepts, if any (module docstring). Every point of
    ``way`` stays, in order; no two consecutive points of way' coincide unless they did in ``way``."""
    w = np.asarray(way, dtype=np.float64)
    if w.shape[0] < 2:
        return w, 0
    bad = np.flatnonzero(~segments_free(w[:-1], w[1:]))  # [B]
    if not bad.size:
        return w, 0
    p, q = w[bad], w[bad + 1]  # [B, 3]
    pts = np.where(ROUTES[None], q[:, None, None], p[:, None, None])  # [B, 12, 4, 3]
    ok = segments_free(pts[:, :, :-1].reshape(-1, 3), pts[:, :, 1:].reshape(-1, 3))  # one walk for all: [B * 12 * 3]
    ok = ok.reshape(len(bad), ROUTES.shape[0], 3).all(-1)  # [B, 12]
    found = ok.any(1)  # [B]
    if not found.any():
        return w, 0
    first = ok.argmax(1)  # [B] the first accepted route
    emit = np.repeat(w[1:, None], 3, axis=1)  # [K-1, 3, 3] points after each step (not detoured: its end, repeated)
    emit[bad[found]] = pts[found, first[found], 1:]
    prev = np.concatenate([w[:-1, None], emit[:, :-1]], axis=1)  # [K-1, 3, 3] the point before each emitted one
    keep = (emit != prev).any(-1)  # drop repeated points
    keep[:, 0] |= ~keep.any(1)  # a step whose ends coincide keeps its end, as the input had it
    return np.concatenate([w[:1], emit[keep]]), int(found.sum())
