"""The line-of-sight shortcut of a voxel path: which segments may join two waypoints (proven collision-free for the
camera ball, conservative), and which of two shortcuts gives the cheaper corridor.
Functions of a PlanningSpace (space.py)."""
from __future__ import annotations

from typing import TYPE_CHECKING, Optional

import numpy as np

from ..corridor.corridor_options import use_grid_polytopes
from ..geometry.collision import points_collide_arrays
from ..geometry.ranges import group_ranks
from ..geometry.voxel_traversal import EPS
from .astar import batched_shortcut

if TYPE_CHECKING:
    from ..space import PlanningSpace

CLASSIC_SHORTCUT_AFTER = 1
"""shortcut_way also runs the classic shortcut when the grid rule's leaves more than this many segments off the grid."""

OFF_GRID_SEGMENT_COST = 8.0
"""choose_way: what a corridor segment off the grid costs, in grid segments (a Prop-2 polytope costs several times a
grid polytope: docs/PLANNER_DEFAULTS.md)."""


def segments_free(space: "PlanningSpace", p0, p1) -> np.ndarray:
    """bool [P]: segment p0[i] -> p1[i] proven collision-free for the camera ball (conservative).

    First the occupancy grid: a segment whose every point lies in a free voxel is proven clear with no
    distance query (voxel_traversal.py: exact voxel walk). The rest are cut into pieces no longer than the
    camera radius; a piece lies inside the ball of radius r + |piece|/2 around its midpoint, so proving
    those balls clear (Cor. 1, batched in one call) proves the segment clear. A piece that is not proven
    clear marks its segment as colliding."""
    prep = space.prepared
    a = np.asarray(p0, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(p1, dtype=np.float64).reshape(-1, 3)
    ok = prep.voxels.segments_free(a, b)
    rest = np.flatnonzero(~ok)
    if rest.size:
        ok[rest] = segments_free_by_pieces(space, a[rest], b[rest])
    return ok


def segments_free_by_pieces(space: "PlanningSpace", a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """segments_free's Corollary-1 proof (pieces no longer than the camera radius), for float64 [P, 3] ends."""
    prep = space.prepared
    r = space.scene.camera_radius
    piece = max(r, 0.5 * prep.grid.voxel_size)
    d = b - a  # [P, 3]
    L = np.sqrt(np.add.reduce(d * d, axis=1))  # [P] (np.linalg.norm's arithmetic, without its checks)
    n = np.maximum(1, np.ceil(L / piece).astype(np.int64))  # [P]
    owner, k = group_ranks(n)
    n_o = n[owner]
    frac = (k + 0.5) / n_o  # (k + 1/2) / n per piece
    mids = a[owner] + frac[:, None] * d[owner]  # float64: no rounding of the pieces
    half = 0.5 * L[owner] / n_o
    hit = points_collide_arrays(mids, space.scene, prep.index, r + half)  # [pieces]
    bad = np.zeros(len(a), dtype=bool)
    bad[owner[hit]] = True
    return ~bad


class FreeVoxels:
    """clearance_queries.in_free_voxel as flat arrays, built once per prepared scene (free_voxels): the shortcut asks
    it for thousands of samples per request, a few hundred at a time, where the per-call array set-up and clipping cost
    more than the lookups. Same answers: the voxel floor((x - lo) / voxel_size), False outside the grid."""

    def __init__(self, occupied: np.ndarray, lo: np.ndarray, voxel_size: float) -> None:
        self.occupied = occupied  # [X, Y, Z] bool (kept to tell whether the cache is current)
        self.free = ~np.ascontiguousarray(occupied, dtype=bool).reshape(-1)  # [X * Y * Z]
        self.shape = np.asarray(occupied.shape, dtype=np.int64)
        self.strides = np.array([occupied.shape[1] * occupied.shape[2], occupied.shape[2], 1], dtype=np.int64)
        self.lo = np.ascontiguousarray(np.asarray(lo, dtype=np.float64).reshape(3))
        self.voxel_size = float(voxel_size)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """bool [P]: world point [P, 3] (float64) lies in a free voxel."""
        ijk = np.floor((points - self.lo) / self.voxel_size).astype(np.int64)  # [P, 3]
        inside = ((ijk >= 0) & (ijk < self.shape)).all(1)
        lin = ijk @ self.strides
        lin[~inside] = 0
        return inside & self.free[lin]


def free_voxels(space: "PlanningSpace") -> FreeVoxels:
    """The prepared scene's FreeVoxels (built on first use, kept on the PreparedScene)."""
    prep = space.prepared
    occ = prep.astar_grid._occ
    fv = getattr(prep, "_shortcut_free_voxels", None)
    if fv is None or fv.occupied is not occ:
        fv = FreeVoxels(occ, prep.grid.lo.detach().cpu().double().numpy(), float(prep.grid.voxel_size))
        prep._shortcut_free_voxels = fv
    return fv


def grid_sight(space: "PlanningSpace", p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """bool [P]: every sample (spacing <= half a voxel) of segment p0[i] -> p1[i] farther than one
    voxel from both ends lies in a free voxel of the occupancy grid. Only a cheap pre-filter for
    the shortcut: refusing a segment is always safe (it just keeps the voxel path there)."""
    fv = free_voxels(space)
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


def shortcut_free(space: "PlanningSpace", p0, p1) -> np.ndarray:
    """bool [P] for the shortcut: grid line of sight (cheap filter), then the conservative segments_free test on the
    survivors (so every accepted segment is proven free).

    With config.grid_polytopes a segment whose two ends lie in free voxels is accepted only when the segment lies in
    free voxels too (the exact voxel walk): its corridor polytope then comes from the grid (grid_polytope.py), far
    cheaper than a Prop-2 one. Only segments with an end outside the free voxels (a goal next to an object, a start
    the user placed there) may be proven by Corollary-1 pieces. shortcut_ways decides between this rule and
    shortcut_free_any's."""
    return shortcut_test(space, p0, p1, grid_rule=use_grid_polytopes(space))


def shortcut_free_any(space: "PlanningSpace", p0, p1) -> np.ndarray:
    """shortcut_free without the grid rule: every segment may be proven by Corollary-1 pieces (longer jumps, fewer
    segments, but each one that leaves the free voxels needs a Prop-2 polytope)."""
    return shortcut_test(space, p0, p1, grid_rule=False)


def shortcut_test(space: "PlanningSpace", p0, p1, grid_rule: bool) -> np.ndarray:
    """bool [P]: the shortcut's answer for segments p0[i] -> p1[i] (shortcut_free with or without the grid rule).

    The same answer as grid sight AND (grid rule: the exact voxel walk for segments whose ends are both free, else
    segments_free), asked in the cheapest order: the compiled voxel walk first for every segment (a segment it proves
    free has every sample in a free voxel, so grid sight holds too), then grid sight and the Corollary-1 pieces only
    for the segments the walk refused and the grid rule leaves open."""
    a = np.asarray(p0, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(p1, dtype=np.float64).reshape(-1, 3)
    out = space.prepared.voxels.segments_free(a, b)  # [P]
    rest = np.flatnonzero(~out)
    if grid_rule and rest.size:
        fv = free_voxels(space)
        rest = rest[~(fv.contains(a[rest]) & fv.contains(b[rest]))]  # both ends free: only the walk may accept
    if rest.size:
        rest = rest[grid_sight(space, a[rest], b[rest])]
    if rest.size:
        out[rest] = segments_free_by_pieces(space, a[rest], b[rest])
    return out


def segments_off_grid(space: "PlanningSpace", way: np.ndarray) -> int:
    """How many segments of a polyline [K, 3] do not lie in free voxels (each needs a Prop-2 polytope unless a
    known one holds it)."""
    w = np.asarray(way, dtype=np.float64)
    return int((~space.prepared.voxels.segments_free(w[:-1], w[1:])).sum()) if len(w) > 1 else 0


def choose_way(space: "PlanningSpace", grid_way: np.ndarray, any_way: Optional[np.ndarray]) -> np.ndarray:
    """The cheaper corridor of two shortcuts of one path: ``grid_way`` (the grid rule) or ``any_way`` (without
    it; None: not computed). Cost = segments + OFF_GRID_SEGMENT_COST x segments off the grid. In rooms the
    grid rule wins (a Prop-2 polytope only at the goal); in a real capture with floaters and a coarse grid
    the voxel path cuts corners past occupied voxels so often that the grid rule keeps many short off-grid
    segments, and the classic shortcut's fewer, longer segments are cheaper."""
    if any_way is None:
        return grid_way
    cost = lambda w: (len(w) - 1) + OFF_GRID_SEGMENT_COST * segments_off_grid(space, w)  # noqa: E731
    return any_way if cost(any_way) < cost(grid_way) else grid_way


def shortcut_pass(space: "PlanningSpace", ways: list, grid_rule: bool, backend: str = "auto") -> list:
    """batched_shortcut(ways, shortcut_test(space, ., ., grid_rule)): the same polylines, with the grid part of
    every round in one compiled call (gridpoly.c: cn_shortcut_rounds). A round asks its segments farthest first and
    stops at the first one the voxel walk accepts (nearer ones cannot change the farthest free point), so only the
    farther segments that grid sight lets through go to the Corollary-1 pieces, one segments_free_by_pieces call per
    round for all polylines. backend: "auto" (compiled when it loads), "native" or "python" (batched_shortcut)."""
    from ..native import choose, shortcut_rounds_c

    fn = choose(backend, shortcut_rounds_c, "gridpoly", "shortcut rounds")
    if fn is None or not ways or any(len(w) == 0 for w in ways):
        return batched_shortcut(ways, lambda p0, p1: shortcut_test(space, p0, p1, grid_rule))
    grid = _rounds_grid(space)
    pts = np.ascontiguousarray(np.concatenate([np.asarray(w, dtype=np.float64).reshape(-1, 3) for w in ways]))  # [N, 3]
    W, N = len(ways), len(pts)
    o_keep, o_cand, o_nkeep = W + 1, W + 1 + N, W + 1 + 2 * N  # one int64 buffer: off, keep, cand, nkeep, best, ncand
    o_best, o_ncand = o_nkeep + W, o_nkeep + 2 * W
    ibuf = np.zeros(o_ncand + W, dtype=np.int64)
    off, keep, cand = ibuf[:W + 1], ibuf[o_keep:o_cand], ibuf[o_cand:o_nkeep]
    nkeep, best, ncand = ibuf[o_nkeep:o_best], ibuf[o_best:o_ncand], ibuf[o_ncand:]
    off[1:] = np.cumsum([len(w) for w in ways])
    nkeep[:] = 1  # keep[off[w]] = 0: the start
    at = lambda o: ibuf.ctypes.data + ibuf.itemsize * o  # noqa: E731
    args = (*grid[0], int(grid_rule), pts.ctypes.data, at(0), W, at(o_keep), at(o_nkeep), at(o_best), at(o_cand),
            at(o_ncand))
    while True:
        fn(*args)
        stopped = np.flatnonzero(ncand)  # polylines whose round waits for the pieces
        if not stopped.size:
            break
        owner, rank = group_ranks(ncand[stopped])
        poly = stopped[owner]
        j = cand[off[poly] + rank]  # candidate ends, farthest first per polyline  [C]
        c = keep[off[poly] + nkeep[poly] - 1]  # their current points
        free = np.flatnonzero(segments_free_by_pieces(space, pts[off[poly] + c], pts[off[poly] + j]))
        for i in stopped:
            hit = free[poly[free] == i]
            keep[off[i] + nkeep[i]] = j[hit[0]] if hit.size else best[i]  # the farthest proven free, else best
            nkeep[i] += 1
    return [w[keep[off[i]:off[i] + nkeep[i]]] for i, w in enumerate(ways)]


def _rounds_grid(space: "PlanningSpace") -> tuple:
    """cn_shortcut_rounds' grid arguments (the walk's grid, EPS, the free-voxel grid) and the arrays they point into,
    built once per prepared scene (kept on the PreparedScene with the occupancy arrays they came from)."""
    prep = space.prepared
    vox, fv = prep.voxels, free_voxels(space)
    cached = getattr(prep, "_shortcut_rounds_grid", None)
    if cached is not None and cached[1][0] is vox and cached[1][1] is vox.occupied and cached[1][2] is fv:
        return cached
    walk_occ = np.ascontiguousarray(vox.occupied, dtype=bool).view(np.uint8)
    walk_shape = np.asarray(vox.occupied.shape, dtype=np.int64)
    walk_lo = np.ascontiguousarray(vox.lo, dtype=np.float64)
    free_occ = np.ascontiguousarray(fv.occupied, dtype=bool).view(np.uint8)
    keep = (vox, vox.occupied, fv, walk_occ, walk_shape, walk_lo, free_occ)
    args = (walk_occ.ctypes.data, walk_shape.ctypes.data, walk_lo.ctypes.data, float(vox.voxel_size), EPS,
            free_occ.ctypes.data, fv.shape.ctypes.data, fv.lo.ctypes.data, fv.voxel_size)
    prep._shortcut_rounds_grid = (args, keep)
    return prep._shortcut_rounds_grid


def shortcut_ways(space: "PlanningSpace", ways: list) -> list:
    """shortcut_way for several polylines, each rule as one lock-step pass (shortcut_pass: the same result as
    astar.shortcut path by path)."""
    a = shortcut_pass(space, ways, use_grid_polytopes(space))
    if not use_grid_polytopes(space):
        return a
    redo = [i for i, w in enumerate(a) if segments_off_grid(space, w) > CLASSIC_SHORTCUT_AFTER]
    if redo:
        b = shortcut_pass(space, [ways[i] for i in redo], False)
        for i, w in zip(redo, b):
            a[i] = choose_way(space, a[i], w)
    return a
