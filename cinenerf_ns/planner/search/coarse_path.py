"""Fast collision-free voxel paths: budgeted A*, then a 2x-coarse grid, then compiled Dijkstra.

Pure-Python A* (astar.py) is fast when the straight line is nearly free (a few hundred expansions) but
floods large regions when the path must climb over a wall or round a big object (10^5 expansions).
This module keeps A* for the easy cases and answers the hard ones on a grid with 8x fewer
voxels, searched by a compiled Dijkstra / A* (native/astar26.c; scikit-image's ``MCP_Geometric`` when
no compiled kernel loads: 26-connected, step costs 1, sqrt 2, sqrt 3, i.e. the same metric as A*).
The budget stays the same with the compiled A*: searching the whole fine grid instead gives minimum-cost paths that
hug obstacles, and the shortcut and corridor after them cost more than the search saves (docs/PLANNER_DEFAULTS.md);
the coarse route keeps paths in wider free space.

Coarse grid (conservative): block (I, J, K) covers fine voxels 2I..2I+1 x 2J..2J+1 x 2K..2K+1 and is
FREE only if all 8 are free (fine voxels beyond the grid count as occupied). A free fine voxel is a
closed cube every point of which is safe for the camera (occupancy.py), so a free block is a closed
safe cube too. Segments used by a returned path, all safe:
  * between 26-adjacent free fine voxel centres, or 26-adjacent free block centres: each half of the
    segment lies in its own closed cube (the midpoint is on the shared face / edge / corner);
  * between a free fine voxel's centre and the centre of the free block that contains it: both in
    that block (convex).
Start and goal voxels inside an occupied block reach a free block by a short fine search in a
window around them. When the two blocks lie in different coarse components (a pocket of free blocks walled in at
the coarse level, e.g. under a grove's canopy, that the fine grid joins through gaps one voxel wide), an end outside
the largest coarse component escapes into it by a fine Dijkstra to the nearest fine voxel of one of its blocks
(cached per end: the candidates of a request share their go-to's). If anything still fails (no free block nearby, no
escape) the exact fine Dijkstra answers, so a path is found whenever the fine grid connects start and goal (same
guarantee as astar()).

Coordinates: paths are float64 [K, 3] in FINE voxel index units, fine voxel (i, j, k) has centre
(i, j, k) and block (I, J, K) has centre (2I + 0.5, 2J + 0.5, 2K + 0.5); world = lo + (p + 0.5) * voxel.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from ..errors import GoalUnreachableError
from ..native import search26 as native_search26
from .astar import AStarGrid, SearchBudgetExhausted, astar
from .landmarks import landmark_tables

FINE_BUDGET = 800  # fine A* expansions before the coarse route (see voxel_path)
COARSE_DETOUR = 1.5
"""voxel_path: a coarse route longer than this x the straight distance is checked against the fine search's path (the
shorter one is kept): blocks keep paths in wide free space, but where the fine grid passes between thin obstacles
(the grove's trunks) they can go round the whole group, twice the way (docs/PLANNER_DEFAULTS.md)."""
SHOT_DETOUR_EXPANSIONS = 5_000
"""voxel_path for one shot: that check's fine A* gives up after this many expansions and keeps the coarse route. A
pass between thin obstacles is found in a few hundred; where a wall really imposes the detour (random starts behind
the procedural room's furniture) an unbounded fine A* expands everything in front of it: 30-125 ms a request at 1M
(docs/PLANNER_DEFAULTS.md)."""


def _mcp_path(costs: np.ndarray, start, ends: np.ndarray, grid: Optional[AStarGrid] = None) -> Optional[np.ndarray]:
    """Shortest 26-connected path int64 [K, 3] from ``start`` to the nearest of ``ends`` [E, 3] over
    voxels with finite cost (compiled Dijkstra, stops at the first end reached); None if none is reached.
    Through native/astar26.c when it loads (skimage's MCP costs ~10 ms of set-up per call, even on 13^3
    voxels), else scikit-image's ``MCP_Geometric``. Same metric (step lengths 1, sqrt 2, sqrt 3); among
    paths of equal cost the two may pick different ones. ``grid``: the same grid prepared (``AStarGrid`` of
    ~isfinite(costs)), when the caller keeps one."""
    if len(ends) == 0:
        return None
    fn = native_search26()
    if fn is not None:
        g = grid if grid is not None else AStarGrid(~np.isfinite(costs))
        return _native_path(g, start, np.asarray(ends, dtype=np.int64).reshape(-1, 3))
    from skimage.graph import MCP_Geometric

    mcp = MCP_Geometric(costs, fully_connected=True)
    ends_t = [tuple(int(v) for v in e) for e in ends]
    cum, _ = mcp.find_costs([tuple(int(v) for v in start)], ends_t, find_all_ends=False)
    ce = cum[tuple(np.asarray(ends).T)]  # [E]
    k = int(np.argmin(ce))
    if not np.isfinite(ce[k]):
        return None
    return np.asarray(mcp.traceback(tuple(int(v) for v in ends[k])), dtype=np.int64).reshape(-1, 3)


def _native_path(grid: AStarGrid, start, ends: np.ndarray) -> Optional[np.ndarray]:
    """_mcp_path through the compiled search: A* for one end, Dijkstra to the nearest of several."""
    start_f = grid.flat(tuple(int(v) for v in np.asarray(start).reshape(3)))
    if grid._blocked_np[start_f]:
        return None
    target = None
    if len(ends) > 1:
        target = np.zeros_like(grid._blocked_np)
        target[grid.flat_many(ends)] = 1
    k, out = grid.native_search(start_f, grid.flat(tuple(ends[0].tolist())), target)
    if k == -1:
        return None
    if k < 0:
        raise MemoryError(f"the compiled path search failed (code {k}) on a grid of {grid.shape}")
    return grid.unflat_many(out[:k])


class CoarseGrid:
    """2x2x2 blocks of a fine occupancy grid (see module docstring), prepared once per grid."""

    def __init__(self, fine: AStarGrid):
        occ = fine._occ  # [X, Y, Z] bool
        X, Y, Z = occ.shape
        X2, Y2, Z2 = (X + 1) // 2, (Y + 1) // 2, (Z + 1) // 2
        padded = np.ones((2 * X2, 2 * Y2, 2 * Z2), dtype=bool)
        padded[:X, :Y, :Z] = occ
        self.fine = fine
        self.occupied = padded.reshape(X2, 2, Y2, 2, Z2, 2).any(axis=(1, 3, 5))  # [X2, Y2, Z2]
        self.fine_costs = np.where(occ, np.inf, 1.0)  # [X, Y, Z] MCP costs (inf = impassable)
        self.costs = np.where(self.occupied, np.inf, 1.0)  # [X2, Y2, Z2]
        self.block_grid = AStarGrid(self.occupied)  # padded once for the compiled block search
        self.labels = self.block_grid.labels  # 26-connected components of free blocks
        # landmark bounds for the block A* (landmarks.py: same minimum cost, far fewer expansions round walls)
        self.block_grid.landmarks = landmark_tables(self.block_grid)
        sizes = np.bincount(self.labels.ravel())
        self._largest = int(np.argmax(sizes[1:])) + 1 if len(sizes) > 1 else 0  # the main coarse component (0: none)
        self._label_masks: dict = {}  # coarse component -> uint8 mask of its fine voxels (padded fine layout)
        self._escapes: dict = {}  # (fine voxel, component) -> _escape's path: candidates share their go-to's

    def _to_free_block(self, v: np.ndarray, window: int, label: Optional[int] = None) -> Optional[np.ndarray]:
        """Fine path int64 [K, 3] from free fine voxel v to the nearest fine voxel (within ``window``
        voxels) whose block is free (and, with ``label``, in that coarse component); [v] when v's own block
        qualifies; None when there is none."""
        own = tuple(v // 2)
        if not self.occupied[own] and (label is None or self.labels[own] == label):
            return v[None].copy()
        shape = np.asarray(self.fine_costs.shape)
        a = np.maximum(v - window, 0)
        e = np.minimum(v + window + 1, shape)
        sub = self.fine_costs[a[0]:e[0], a[1]:e[1], a[2]:e[2]]
        ijk = np.argwhere(np.isfinite(sub))  # window-local free voxels
        blocks = tuple(((ijk + a) // 2).T)
        ok = ~self.occupied[blocks] if label is None else self.labels[blocks] == label  # labels: 0 = occupied
        p = _mcp_path(sub, v - a, ijk[ok])
        return None if p is None else p + a

    def _ends(self, s: np.ndarray, g: np.ndarray, window: int, escape: bool = True):
        """(head, tail): fine paths from s and from g to free blocks of ONE coarse component, or None. The nearest
        free block of an end may lie in a small pocket of the coarse grid (a few blocks walled in by occupied ones,
        e.g. under a canopy) while the fine grid joins it to the other end's component: within the window each end
        is tried in the other end's component, then (``escape``) each end outside the largest one escapes into it
        (_escaped_ends)."""
        head, tail = self._to_free_block(s, window), self._to_free_block(g, window)
        if head is None or tail is None:
            return None
        ls, lg = (int(self.labels[tuple(p[-1] // 2)]) for p in (head, tail))
        if ls == lg:
            return head, tail
        tail2 = self._to_free_block(g, window, label=ls)
        if tail2 is not None:
            return head, tail2
        head2 = self._to_free_block(s, window, label=lg)
        if head2 is not None:
            return head2, tail
        return self._escaped_ends(head, tail, ls, lg) if escape else None

    def _escaped_ends(self, head: np.ndarray, tail: np.ndarray, ls: int, lg: int):
        """_ends when no window joins the ends' coarse components ``ls`` (of head's block) and ``lg`` (of tail's):
        each end outside the largest coarse component escapes into it (_escape); None when one cannot (without the
        compiled search, or when the fine grid does not join them)."""
        big = self._largest
        if big <= 0:  # no free block at all
            return None
        if ls != big:
            head = self._escape(head[0], big)
        if lg != big and head is not None:
            tail = self._escape(tail[0], big)
        return None if head is None or tail is None else (head, tail)

    def _escape(self, v: np.ndarray, label: int) -> Optional[np.ndarray]:
        """Shortest fine path int64 [K, 3] from free fine voxel v to the nearest fine voxel whose block is free and in
        coarse component ``label`` (compiled Dijkstra over the whole fine grid), or None."""
        if native_search26() is None or label <= 0:
            return None
        key = (*(int(x) for x in v), int(label))
        cache = self._escapes
        if key in cache:
            return cache[key]
        masks = self._label_masks
        if label not in masks:
            if len(masks) >= 4:
                masks.clear()
            X, Y, Z = self.fine.shape
            fine = (self.labels == label).repeat(2, 0).repeat(2, 1).repeat(2, 2)[:X, :Y, :Z]
            m = np.zeros(self.fine.padded_shape, dtype=np.uint8)
            m[1:-1, 1:-1, 1:-1] = fine
            masks[label] = m.reshape(-1)
        g = self.fine
        k, out = g.native_search(g.flat(key[:3]), 0, masks[label])
        if len(cache) >= 64:
            cache.clear()
        cache[key] = g.unflat_many(out[:k]) if k > 0 else None
        return cache[key]

    def path(self, s, g, window: int = 6, escape: bool = True) -> Optional[np.ndarray]:
        """Path float64 [K, 3] (fine index units) from fine voxel s to fine voxel g through free
        blocks, or None when the coarse route does not exist (caller falls back to the fine grid). ``escape``: ends in
        coarse pockets may escape to the largest coarse component (_ends); False: such a route does not exist."""
        s, g = np.asarray(s, dtype=np.int64), np.asarray(g, dtype=np.int64)
        ends = self._ends(s, g, window, escape)
        if ends is None:
            return None
        head, tail = ends
        bs, bg = head[-1] // 2, tail[-1] // 2
        blocks = _mcp_path(self.costs, bs, bg[None], grid=self.block_grid)
        if blocks is None:
            return None
        mid = 2.0 * blocks + 0.5  # block centres in fine units
        return np.concatenate([head.astype(np.float64), mid, tail[::-1].astype(np.float64)])


def voxel_path(
    fine: AStarGrid, coarse: Optional[CoarseGrid], s, g, *, astar_budget: int = FINE_BUDGET, window: int = 6,
    astar_weight: float = 1.0, detour_budget: Optional[int] = None,
) -> np.ndarray:
    """Collision-free path float64 [K, 3] (fine voxel index units, s first, g last) between free fine
    voxels s and g: A* with ``astar_budget`` expansions, else the coarse route, else the fine search (also when the
    coarse route is over COARSE_DETOUR x the straight distance: the shorter of the two). ``detour_budget`` (ranked
    candidates, whose searches must stay cheap and share a go-to): the coarse route's ends may escape coarse pockets
    (CoarseGrid.path), and that check's fine A* gives up after this many expansions, keeping the coarse route; None
    (one shot): no escapes (an escape is paid by each request's own go-to, and its route is then mostly a detour the
    fine search replaces anyway), and the check's budget is SHOT_DETOUR_EXPANSIONS. Without a coarse route the fine
    search is whole.
    astar_weight: heuristic weight of the A* (1: minimum-cost path; w > 1: cost at most w x minimum, far fewer
    expansions; see PlannerConfig.astar_weight).
    astar_budget: fine A* expansions before the coarse route, the same with the compiled and the Python A* (the
    module docstring says why).

    Raises what astar() raises for occupied / disconnected ends (StartInCollisionError,
    GoalUnreachableError)."""
    try:
        return astar(fine, s, g, max_expansions=astar_budget, heuristic_weight=astar_weight).astype(np.float64)
    except SearchBudgetExhausted:
        pass
    route = coarse.path(s, g, window, escape=detour_budget is not None) if coarse is not None else None
    if route is not None and _length(route) <= COARSE_DETOUR * float(np.linalg.norm(np.subtract(g, s))):
        return route
    if route is not None:
        # the fine search for a shorter way than the coarse detour (between thin obstacles the blocks cannot pass),
        # bounded: where a wall really imposes the detour, the fine A* would expand everything in front of it too
        budget = detour_budget if detour_budget is not None else SHOT_DETOUR_EXPANSIONS
        try:
            p = astar(fine, s, g, max_expansions=budget).astype(np.float64)
        except SearchBudgetExhausted:
            return route
        return route if _length(route) <= _length(p) else p
    costs = coarse.fine_costs if coarse is not None else np.where(fine._occ, np.inf, 1.0)
    # the prepared fine grid (the same occupancy as costs): no padded copy and no new search workspace per call
    # (10.6 -> 7.3 ms a call on the 1M grove, whose canopy splits the coarse grid into two components)
    p = _mcp_path(costs, np.asarray(s), np.asarray(g, dtype=np.int64)[None], grid=fine)
    if p is None:  # cannot happen: astar() checked that s and g share a free component
        raise GoalUnreachableError(f"no collision-free voxel path from {tuple(s)} to {tuple(g)}")
    return p.astype(np.float64)


def _length(path: np.ndarray) -> float:
    """Length of a polyline [K, 3] (fine voxel units)."""
    return float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
