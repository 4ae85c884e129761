"""Fewer segments and rows for the corridor QP, the same safe polytopes (issue 37: the 1M grove's finer grid gave the
QP ~20 short segments a request).

``merged_pieces``: consecutive corridor pieces (polytope, w_m, w_{m+1}) become one piece (P, w_m, w_{m+2}) when one of
their two polytopes holds both outer ends with at least ``tol`` of room; a polytope is convex, so it then holds the
whole straight segment w_m -> w_{m+2}, which is all a corridor asks of a piece. No polytope is built, cut or changed:
the pieces keep only polytopes the corridor had, each still proven safe, so the guarantee is the same; the QP gets
fewer segments (fewer variables, joins and face rows) and the dropped waypoint no longer bends its durations.

``region_rows``: the planning region's six faces that a polytope does not already imply. Corridor.constraints() adds
them to every polytope, but a polytope whose own box face is the same axis row (a == +-e_i exactly) with an offset at or
inside the region's implies that face: every point that meets its row meets the region's. Such faces only cost the QP
rows (6 of ~18 a polytope on the grove); the feasible set, so the QP's optimum, is unchanged."""
from __future__ import annotations

from typing import List, Sequence, Tuple

import numpy as np

MERGE_ROOM = 1e-3
"""Scene units: merged_pieces merges two pieces only when the polytope it keeps holds the other piece's far end this
far inside every face (build_corridor's default min_overlap: the junction with the next piece keeps room for the
joins)."""

TABLE_MIN_SEGMENTS = 6
"""Corridors of at least this many segments take the array paths (merging, the slack table, region_rows); shorter
ones keep the per-segment loops they had, which cost less below it (CPU box: ~20-40 us of fixed array set-up against a
few segments' loops; the procedural room's corridors have 2-5 segments) and merge nothing."""

REGION_A = np.vstack([np.eye(3), -np.eye(3)])  # [6, 3] the region box's outward normals: x <= hi, -x <= -lo
REGION_A.flags.writeable = False


def region_rows(planes: Sequence[Tuple[np.ndarray, np.ndarray]], lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """bool [M, 6]: which of the region box's faces (REGION_A x <= [hi, -lo]) polytope m (A [F, 3], b [F] float64)
    must still get: False where one of its own rows equals that face's normal exactly and its offset is <= the
    region's (so the region's face is implied)."""
    m = len(planes)
    need = np.ones((m, 6), dtype=bool)
    if m == 0:
        return need
    counts = np.array([a.shape[0] for a, _ in planes])
    if (counts == 0).any():  # an empty row set implies nothing (and reduceat needs >= 1 row per polytope)
        return need
    a = np.concatenate([a for a, _ in planes])  # [F_all, 3]
    b = np.concatenate([b for _, b in planes])  # [F_all]
    box_b = np.concatenate([hi, -lo])  # [6]
    # row == +-e_i exactly: two zero components and +-1 in the third (REGION_A's order: +x, +y, +z, -x, -y, -z)
    axis = (a == 0.0).sum(1) == 2  # [F_all]
    implies = np.concatenate([a == 1.0, a == -1.0], axis=1) & axis[:, None] & (b[:, None] <= box_b[None])
    starts = np.zeros(m, dtype=np.int64)
    np.cumsum(counts[:-1], out=starts[1:])
    return ~np.logical_or.reduceat(implies, starts, axis=0)


def slack_table(planes: Sequence[Tuple[np.ndarray, np.ndarray]], w: np.ndarray):
    """[M, K] float64: the distance min_f (b_f - a_f . w_j) / |a_f| of waypoint w_j (w [K, 3]) inside polytope i
    (planes[i] = (A [F, 3], b [F]); negative: outside), one product of all faces with all waypoints; None when a
    polytope has no face (never from a corridor)."""
    counts = np.array([a.shape[0] for a, _ in planes])
    if len(planes) == 0 or (counts == 0).any():  # reduceat needs >= 1 row per polytope
        return None
    a = np.concatenate([a for a, _ in planes]).astype(np.float64, copy=False)  # [F_all, 3]
    b = np.concatenate([b for _, b in planes]).astype(np.float64, copy=False)
    dist = (b[:, None] - a @ w.T) / np.sqrt(np.einsum("ij,ij->i", a, a))[:, None]  # [F_all, K]
    starts = np.zeros(len(planes), dtype=np.int64)
    np.cumsum(counts[:-1], out=starts[1:])
    return np.minimum.reduceat(dist, starts, axis=0)


def merged_runs(slack: np.ndarray, tol: float) -> List[Tuple[int, int, int]]:
    """The pieces k (waypoints k -> k + 1, polytope k) of slack_table's slack [M, M+1] merged greedily from the start
    (module docstring): [(polytope, first waypoint, last waypoint)] in order. A merge keeps the current polytope when
    it holds the next piece's end with ``tol`` of room, else the next piece's polytope when that holds the current
    start with ``tol`` of room (> 0: the junction with the next piece keeps room too)."""
    holds = (slack >= tol).tolist()  # [M][M+1]
    runs = [[0, 0, 1]]
    for k in range(1, slack.shape[0]):
        run = runs[-1]
        if holds[run[0]][k + 1]:
            run[2] = k + 1
        elif holds[k][run[1]]:
            run[0], run[2] = k, k + 1
        else:
            runs.append([k, k, k + 1])
    return [tuple(r) for r in runs]


def merged_pieces(pieces: list, planes: List[Tuple[np.ndarray, np.ndarray]], tol: float) -> Tuple[list, list]:
    """(pieces, planes) with consecutive pieces merged (merged_runs), in order: pieces [(polytope, p0 [3], p1 [3])]
    (p1 of one is p0 of the next), planes[i] = pieces[i]'s polytope as float64 (A [F, 3], b [F])."""
    if len(pieces) < 2:
        return list(pieces), list(planes)
    w = np.stack([pieces[0][1]] + [p1 for _, _, p1 in pieces])  # [M+1, 3]
    slack = slack_table(planes, w)
    if slack is None:
        return list(pieces), list(planes)
    runs = merged_runs(slack, tol)
    return [(pieces[i][0], pieces[s][1], pieces[e - 1][2]) for i, s, e in runs], [planes[i] for i, _, _ in runs]
