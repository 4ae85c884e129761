"""Constraint generation for the corridor QP: solve with a working set of each polytope's faces, add what is violated.

A corridor polytope has tens of faces, of which only a few touch the optimal curve (captured 1M-Gaussian requests:
~134 faces per QP, ~11.5 active at the optimum). ``solve_with_working_set`` first keeps, per polytope, the faces
within ``INITIAL_DISTANCE`` of the segment between its two waypoints (always the nearest one), solves that
relaxation, checks every free control point against *all* shrunk faces, adds the violated ones (and those within
``NEAR_DISTANCE`` of being violated) and solves again, until no face is violated. The result is then the exact optimum
of the full QP: it is the optimum of a relaxation (fewer constraints, so its objective is <= the full optimum) and
feasible for the full problem (so its objective is >= it); the cost is strictly convex where the equalities hold
(its only flat directions, segment translations, are fixed by the pinned ends and C0 joins), so the minimiser is the
same. A relaxation that is infeasible proves the full QP infeasible (it has fewer constraints).
After ``MAX_ROUNDS`` relaxations, or when a relaxation fails numerically, the last round uses all faces. The module
knows nothing of the QP's matrices: the caller passes ``build(faces)`` and ``solve(qp)``.
"""
from __future__ import annotations

import time
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np

INITIAL_DISTANCE = 0.4
"""Faces of polytope k within this fraction of reach(k) of segment k start in the working set; reach(k) is the
longest of segments k-1, k, k+1 (a smooth curve cuts corners by a fraction of its neighbouring segments)."""
NEAR_DISTANCE = 0.1
"""On a re-solve, faces not yet in the set are added when a control point is within this fraction of reach(k)."""
MAX_ROUNDS = 4
"""Relaxations tried before one solve with all faces."""


def reach(waypoints: np.ndarray) -> np.ndarray:
    """[M+1, 3] waypoints -> [M]: per segment the longest of it and its neighbours."""
    lengths = np.linalg.norm(np.diff(waypoints, axis=0), axis=1)
    padded = np.concatenate([lengths[:1], lengths, lengths[-1:]])
    return np.maximum(np.maximum(padded[:-2], padded[1:-1]), padded[2:])


ARRAY_MIN_SEGMENTS = 6
"""face_norms and qp._corridor_violation work on all faces at once from this many segments up (the 1M grove's ~17),
per segment below it (the procedural room's 2-5), where the arrays' set-up costs more than the loop."""


def face_norms(polys: Sequence[Tuple[np.ndarray, np.ndarray]]) -> List[np.ndarray]:
    """Per polytope the [F] norms of its face normals (rows of A): taken once per QP, every round uses them (one
    computation over all rows, then views per polytope)."""
    if len(polys) < ARRAY_MIN_SEGMENTS:  # a few polytopes: per polytope is cheaper than the concatenation and split
        return [np.linalg.norm(a, axis=1) for a, _ in polys]
    a = np.concatenate([a for a, _ in polys])  # [F_all, 3]
    norms = np.linalg.norm(a, axis=1)  # (row by row: the same values as per polytope)
    return np.split(norms, np.cumsum([p[0].shape[0] for p in polys[:-1]]))


def initial_faces(polys: Sequence[Tuple[np.ndarray, np.ndarray]], waypoints: np.ndarray,
                  distance: np.ndarray, norms: Optional[List[np.ndarray]] = None) -> List[np.ndarray]:
    """Per polytope k, the indices of the faces within distance[k] of the segment waypoints[k] -> waypoints[k+1]
    (a face's distance to a segment inside it is the smaller of its ends' distances), always the nearest face.
    norms: face_norms(polys) (None: computed here)."""
    norms = face_norms(polys) if norms is None else norms
    faces = []
    for k, ((a, b), norm) in enumerate(zip(polys, norms)):
        slack = ((b - waypoints[k: k + 2] @ a.T) / norm).min(axis=0)  # [F]
        keep = slack <= distance[k]
        keep[np.argmin(slack)] = True
        faces.append(np.flatnonzero(keep))
    return faces


def free_ranges(num_segments: int, npts: int, rest_at_ends: int) -> List[Tuple[int, int]]:
    """Per segment, the [lo, hi) range of control points that are not pinned to start / goal."""
    out = []
    for k in range(num_segments):
        lo = rest_at_ends + 1 if k == 0 else 0
        hi = npts - 1 - rest_at_ends if k == num_segments - 1 else npts
        out.append((lo, hi))
    return out


def add_violated(cps: np.ndarray, polys, faces: List[np.ndarray], margin: float, free: List[Tuple[int, int]],
                 near: np.ndarray, norms: Optional[List[np.ndarray]] = None) -> Tuple[List[np.ndarray], int]:
    """Check the free control points cps [M, D+1, 3] against every face shrunk by ``margin``: (faces with the violated
    ones, and those within near[k] of it, added; the number of violated faces, 0 when cps is feasible). norms:
    face_norms(polys) (None: computed here)."""
    norms = face_norms(polys) if norms is None else norms
    out, violated = [], 0
    for k, ((a, b), (lo, hi), norm) in enumerate(zip(polys, free, norms)):
        if hi <= lo:
            out.append(faces[k])
            continue
        excess = ((cps[k, lo:hi] @ a.T).max(axis=0) - b) / norm + margin  # [F] distance past the shrunk face
        outside = excess > 0
        outside[faces[k]] = False  # faces in the set hold to the solver's tolerance; not re-added
        violated += int(outside.sum())
        close = excess > -near[k]
        close[faces[k]] = False
        out.append(np.union1d(faces[k], np.flatnonzero(close | outside)) if close.any() or outside.any() else faces[k])
    return out, violated


def solve_with_working_set(polys, waypoints: np.ndarray, margin: float, free: List[Tuple[int, int]], npts: int,
                           build: Callable[[Optional[List[np.ndarray]]], object], solve: Callable,
                           enabled: bool = True, norms: Optional[List[np.ndarray]] = None):
    """Constraint generation (module docstring). ``build(faces)`` assembles the QP with only those faces per polytope
    (None: all), ``solve(qp)`` returns (x, status, iterations, outcome, retry_tolerance) with outcome "ok",
    "infeasible" or "failed". Returns (qp, solve's result, info: rounds, build and solve seconds). enabled=False: one
    solve with all faces. norms: face_norms(polys) when the caller has them."""
    if not enabled:
        faces = None
    else:
        norms = face_norms(polys) if norms is None else norms
        scale = reach(waypoints)
        faces = initial_faces(polys, waypoints, INITIAL_DISTANCE * scale, norms)
    info = {"qp_rounds": 0, "build_s": 0.0, "solve_s": 0.0}
    while True:
        if faces is not None and (info["qp_rounds"] >= MAX_ROUNDS
                                  or all(f.size == a.shape[0] for f, (a, _) in zip(faces, polys))):
            faces = None
        t0 = time.perf_counter()
        qp = build(faces)
        t1 = time.perf_counter()
        result = solve(qp)
        info["build_s"] += t1 - t0
        info["solve_s"] += time.perf_counter() - t1
        info["qp_rounds"] += 1
        x, outcome = result[0], result[3]
        if faces is None or outcome == "infeasible":  # a relaxation's infeasibility proves the full QP's
            return qp, result, info
        if outcome != "ok":  # a relaxation that failed numerically: one more try with all faces
            faces = None
            continue
        cps = x.reshape(len(polys), npts, 3)
        faces, violated = add_violated(cps, polys, faces, margin, free, NEAR_DISTANCE * scale, norms)
        if violated == 0:  # optimal for a relaxation and feasible for the full QP: its optimum
            return qp, result, info
