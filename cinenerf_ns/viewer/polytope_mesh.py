"""Triangle mesh of a bounded convex polytope {x : A x <= b}, for drawing the safe corridor."""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np


def chebyshev_center(A: np.ndarray, b: np.ndarray) -> Tuple[np.ndarray, float]:
    """Centre [3] and radius of the largest ball inside {A x <= b} (LP); radius <= 0: empty/flat."""
    from scipy.optimize import linprog

    A = np.asarray(A, np.float64)
    b = np.asarray(b, np.float64)
    norms = np.linalg.norm(A, axis=1)
    # maximise r s.t. a_i.x + |a_i| r <= b_i
    res = linprog(
        c=[0, 0, 0, -1.0], A_ub=np.c_[A, norms], b_ub=b, bounds=[(None, None)] * 3 + [(0, None)], method="highs"
    )
    if not res.success:
        return np.zeros(3), -1.0
    return res.x[:3], float(res.x[3])


def polytope_mesh(
    A: np.ndarray,  # [F, 3]
    b: np.ndarray,  # [F]
    interior: Optional[np.ndarray] = None,  # [3] strictly inside, found by LP when None
) -> Optional[Tuple[np.ndarray, np.ndarray]]:
    """(vertices [V, 3], faces [M, 3] int, outward winding not guaranteed) or None when the
    polytope is empty, flat or unbounded (nothing sensible to draw)."""
    from scipy.spatial import ConvexHull, HalfspaceIntersection, QhullError

    A = np.asarray(A, np.float64).reshape(-1, 3)
    b = np.asarray(b, np.float64).reshape(-1)
    if interior is None or np.any(A @ np.asarray(interior, np.float64) >= b):
        interior, r = chebyshev_center(A, b)
        if r <= 1e-9:
            return None
    try:
        hs = HalfspaceIntersection(np.c_[A, -b], np.asarray(interior, np.float64))
        verts = hs.intersections
        if not np.all(np.isfinite(verts)):
            return None
        hull = ConvexHull(verts)
    except (QhullError, ValueError):
        return None
    return hull.points[hull.vertices], _reindex(hull.simplices, hull.vertices)


def _reindex(simplices: np.ndarray, used: np.ndarray) -> np.ndarray:
    remap = -np.ones(simplices.max() + 1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return remap[simplices].astype(np.uint32)
