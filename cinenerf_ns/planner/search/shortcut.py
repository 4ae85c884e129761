"""The line-of-sight shortcut of a voxel path: which segments may join two waypoints (proven collision-free for the
camera ball, conservative), and which of two shortcuts gives the cheaper corridor. Functions of a prepared Planner."""
from __future__ import annotations

from typing import TYPE_CHECKING, Optional

import numpy as np

from ..geometry.collision import points_collide_arrays
from ..geometry.ranges import group_ranks
from .astar import batched_shortcut

if TYPE_CHECKING:
    from ..shots.planner import Planner

CLASSIC_SHORTCUT_AFTER = 1
"""shortcut_way also runs the classic shortcut when the grid rule's leaves more than this many segments off the grid."""

OFF_GRID_SEGMENT_COST = 8.0
"""choose_way: what a corridor segment off the grid costs, in grid segments (a Prop-2 polytope costs several times a
grid polytope: docs/PLANNER_DEFAULTS.md)."""


def segments_free(planner: "Planner", p0, p1) -> np.ndarray:
    """bool [P]: segment p0[i] -> p1[i] proven collision-free for the camera ball (conservative).

    First the occupancy grid: a segment whose every point lies in a free voxel is proven clear with no
    distance query (voxel_traversal.py: exact voxel walk). The rest are cut into pieces no longer than the
    camera radius; a piece lies inside the ball of radius r + |piece|/2 around its midpoint, so proving
    those balls clear (Cor. 1, batched in one call) proves the segment clear. A piece that is not proven
    clear marks its segment as colliding."""
    prep = planner.ready()
    a = np.asarray(p0, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(p1, dtype=np.float64).reshape(-1, 3)
    ok = prep.voxels.segments_free(a, b)
    rest = np.flatnonzero(~ok)
    if rest.size:
        ok[rest] = segments_free_by_pieces(planner, a[rest], b[rest])
    return ok


def segments_free_by_pieces(planner: "Planner", a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """segments_free's Corollary-1 proof (pieces no longer than the camera radius), for float64 [P, 3] ends."""
    prep = planner.ready()
    r = planner.scene.camera_radius
    piece = max(r, 0.5 * prep.grid.voxel_size)
    L = np.linalg.norm(b - a, axis=1)  # [P]
    n = np.maximum(1, np.ceil(L / piece).astype(np.int64))  # [P]
    owner, k = group_ranks(n)
    frac = (k + 0.5) / n[owner]  # (k + 1/2) / n per piece
    mids = a[owner] + frac[:, None] * (b - a)[owner]  # float64: no rounding of the pieces
    half = 0.5 * L[owner] / n[owner]
    hit = points_collide_arrays(mids, planner.scene, prep.index, r + half)  # [pieces]
    bad = np.zeros(len(a), dtype=bool)
    bad[owner[hit]] = True
    return ~bad


class FreeVoxels:
    """Planner.in_free_voxel as flat arrays, built once per prepared scene (free_voxels): the shortcut asks it for
    thousands of samples per request, a few hundred at a time, where the per-call array set-up and clipping cost
    more than the lookups. Same answers: the voxel floor((x - lo) / voxel_size), False outside the grid."""

    def __init__(self, occupied: np.ndarray, lo: np.ndarray, voxel_size: float) -> None:
        self.occupied = occupied  # [X, Y, Z] bool (kept to tell whether the cache is current)
        self.free = ~np.ascontiguousarray(occupied, dtype=bool).reshape(-1)  # [X * Y * Z]
        self.shape = np.asarray(occupied.shape, dtype=np.int64)
        self.strides = np.array([occupied.shape[1] * occupied.shape[2], occupied.shape[2], 1], dtype=np.int64)
        self.lo = np.asarray(lo, dtype=np.float64).reshape(3)
        self.voxel_size = float(voxel_size)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """bool [P]: world point [P, 3] (float64) lies in a free voxel."""
        ijk = np.floor((points - self.lo) / self.voxel_size).astype(np.int64)  # [P, 3]
        inside = ((ijk >= 0) & (ijk < self.shape)).all(1)
        lin = ijk @ self.strides
        lin[~inside] = 0
        return inside & self.free[lin]


def free_voxels(planner: "Planner") -> FreeVoxels:
    """The prepared scene's FreeVoxels (built on first use, kept on the PreparedScene)."""
    prep = planner.ready()
    occ = prep.astar_grid._occ
    fv = getattr(prep, "_shortcut_free_voxels", None)
    if fv is None or fv.occupied is not occ:
        fv = FreeVoxels(occ, prep.grid.lo.detach().cpu().double().numpy(), float(prep.grid.voxel_size))
        prep._shortcut_free_voxels = fv
    return fv


def grid_sight(planner: "Planner", p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """bool [P]: every sample (spacing <= half a voxel) of segment p0[i] -> p1[i] farther than one
    voxel from both ends lies in a free voxel of the occupancy grid. Only a cheap pre-filter for
    the shortcut: refusing a segment is always safe (it just keeps the voxel path there)."""
    fv = free_voxels(planner)
    vs = fv.voxel_size
    L = np.linalg.norm(p1 - p0, axis=1)  # [P]
    n = np.maximum(2, np.ceil(L / (0.5 * vs)).astype(np.int64) + 1)  # samples per segment
    owner, k = group_ranks(n)
    frac = k / (n[owner] - 1)  # [S] in [0, 1]
    far = np.minimum(frac, 1 - frac) * L[owner] > vs  # only samples farther than a voxel from both ends count
    owner, frac = owner[far], frac[far]
    pts = p0[owner] + frac[:, None] * (p1 - p0)[owner]
    bad = np.zeros(len(p0), dtype=bool)
    bad[owner[~fv.contains(pts)]] = True
    return ~bad


def shortcut_free(planner: "Planner", p0, p1) -> np.ndarray:
    """bool [P] for the shortcut: grid line of sight (cheap filter), then the conservative segments_free test on the
    survivors (so every accepted segment is proven free).

    With config.grid_polytopes a segment whose two ends lie in free voxels is accepted only when the segment lies in
    free voxels too (the exact voxel walk): its corridor polytope then comes from the grid (grid_polytope.py), far
    cheaper than a Prop-2 one. Only segments with an end outside the free voxels (a goal next to an object, a start
    the user placed there) may be proven by Corollary-1 pieces. shortcut_ways decides between this rule and
    shortcut_free_any's."""
    return shortcut_test(planner, p0, p1, grid_rule=planner.use_grid_polytopes())


def shortcut_free_any(planner: "Planner", p0, p1) -> np.ndarray:
    """shortcut_free without the grid rule: every segment may be proven by Corollary-1 pieces (longer jumps, fewer
    segments, but each one that leaves the free voxels needs a Prop-2 polytope)."""
    return shortcut_test(planner, p0, p1, grid_rule=False)


def shortcut_test(planner: "Planner", p0, p1, grid_rule: bool) -> np.ndarray:
    """bool [P]: the shortcut's answer for segments p0[i] -> p1[i] (shortcut_free with or without the grid rule).

    The same answer as grid sight AND (grid rule: the exact voxel walk for segments whose ends are both free, else
    segments_free), asked in the cheapest order: the compiled voxel walk first for every segment (a segment it proves
    free has every sample in a free voxel, so grid sight holds too), then grid sight and the Corollary-1 pieces only
    for the segments the walk refused and the grid rule leaves open."""
    a = np.asarray(p0, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(p1, dtype=np.float64).reshape(-1, 3)
    out = planner.ready().voxels.segments_free(a, b)  # [P]
    rest = np.flatnonzero(~out)
    if grid_rule and rest.size:
        fv = free_voxels(planner)
        rest = rest[~(fv.contains(a[rest]) & fv.contains(b[rest]))]  # both ends free: only the walk may accept
    if rest.size:
        rest = rest[grid_sight(planner, a[rest], b[rest])]
    if rest.size:
        out[rest] = segments_free_by_pieces(planner, a[rest], b[rest])
    return out


def segments_off_grid(planner: "Planner", way: np.ndarray) -> int:
    """How many segments of a polyline [K, 3] do not lie in free voxels (each needs a Prop-2 polytope unless a
    known one holds it)."""
    w = np.asarray(way, dtype=np.float64)
    return int((~planner.ready().voxels.segments_free(w[:-1], w[1:])).sum()) if len(w) > 1 else 0


def choose_way(planner: "Planner", grid_way: np.ndarray, any_way: Optional[np.ndarray]) -> np.ndarray:
    """The cheaper corridor of two shortcuts of one path: ``grid_way`` (the grid rule) or ``any_way`` (without
    it; None: not computed). Cost = segments + OFF_GRID_SEGMENT_COST x segments off the grid. In rooms the
    grid rule wins (a Prop-2 polytope only at the goal); in a real capture with floaters and a coarse grid
    the voxel path cuts corners past occupied voxels so often that the grid rule keeps many short off-grid
    segments, and the classic shortcut's fewer, longer segments are cheaper."""
    if any_way is None:
        return grid_way
    cost = lambda w: (len(w) - 1) + OFF_GRID_SEGMENT_COST * segments_off_grid(planner, w)  # noqa: E731
    return any_way if cost(any_way) < cost(grid_way) else grid_way


def shortcut_ways(planner: "Planner", ways: list) -> list:
    """shortcut_way for several polylines, each rule as one lock-step batched_shortcut (the same result as
    astar.shortcut path by path)."""
    a = batched_shortcut(ways, lambda p0, p1: shortcut_free(planner, p0, p1))
    if not planner.use_grid_polytopes():
        return a
    redo = [i for i, w in enumerate(a) if segments_off_grid(planner, w) > CLASSIC_SHORTCUT_AFTER]
    if redo:
        b = batched_shortcut([ways[i] for i in redo], lambda p0, p1: shortcut_free_any(planner, p0, p1))
        for i, w in zip(redo, b):
            a[i] = choose_way(planner, a[i], w)
    return a
