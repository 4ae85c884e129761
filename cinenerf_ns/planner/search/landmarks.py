"""Landmark distance tables for the compiled A* on the coarse block grid (ALT: A*, landmarks, triangle inequality).

Why: with the octile distance alone, a search whose path must go round a wall expands every block in front of the
wall that looks closer to the goal than the detour (the octile distance ignores walls). On the procedural room at 1M
Gaussians with random starts the coarse A* was the planner's largest compiled cost (docs/PLANNER_DEFAULTS.md). The
exact distances D_l from a few landmark blocks bound the remaining cost from below by |D_l(goal) - D_l(n)| (triangle
inequality), which does see walls; the compiled search takes the larger of the two bounds (native/astar26.c,
search26_ws_lm) and still returns a minimum-cost path.

Landmarks are spread by farthest-point selection in the largest free component of the grid: each new one is the
block farthest (by path cost) from those chosen. Built once per prepared scene (a Dijkstra flood per landmark, off
the request path). Memory: LANDMARKS float32 tables of the padded block grid, 4 bytes per fine voxel for 8 landmarks
(inside planning_region.GRID_BYTES_PER_VOXEL's margin over the measured peak).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from ..native import dist26 as native_dist26
from .astar import AStarGrid

LANDMARKS = 8
"""Landmark tables per coarse grid (ALT papers find a handful enough on road networks; measured here:
docs/PLANNER_DEFAULTS.md)."""


def distances(grid: AStarGrid, source: int) -> Optional[np.ndarray]:
    """float32 [padded voxels]: the minimum 26-connected path cost (1, sqrt 2, sqrt 3 per step) from the flat padded
    voxel ``source`` to every voxel (+inf: occupied or unreachable); None when the compiled search does not load."""
    fn = native_dist26()
    if fn is None:
        return None
    out = np.empty(grid._blocked_np.size, dtype=np.float32)
    if int(fn(grid._blocked_np.ctypes.data, *grid.padded_shape, int(source), out.ctypes.data)) < 0:
        raise MemoryError(f"the compiled distance flood ran out of memory on a grid of {grid.shape}")
    return out


def landmark_tables(grid: AStarGrid, count: int = LANDMARKS) -> Optional[np.ndarray]:
    """float32 [L, padded voxels] (L <= count): distance tables of landmarks spread by farthest-point selection over
    the largest free component of ``grid``; None when there is no free voxel or the compiled search does not load."""
    labels = grid.labels  # [X, Y, Z] 0 = occupied
    sizes = np.bincount(labels.ravel())
    if sizes.size < 2:
        return None
    big = int(np.argmax(sizes[1:])) + 1
    seed = grid.flat(tuple(int(v) for v in np.argwhere(labels == big)[0]))
    d = distances(grid, seed)
    if d is None:
        return None
    tables: list = []
    nearest = d  # distance to the nearest chosen landmark (the seed only picks the first one)
    for _ in range(count):
        far = np.where(np.isfinite(nearest), nearest, -1.0)
        i = int(np.argmax(far))
        if far[i] <= 0.0:
            break  # every block of the component is a landmark already
        t = distances(grid, i)
        tables.append(t)
        nearest = t if len(tables) == 1 else np.minimum(nearest, t)
    return np.ascontiguousarray(np.stack(tables)) if tables else None
