"""Initial path: A* on the occupancy voxel grid, then line-of-sight shortcutting.

26-connected moves cost 1, sqrt(2), sqrt(3) (voxel units). The heuristic is the 3D octile distance
(the exact path cost on an obstacle-free 26-connected grid): it is >= the Euclidean distance yet
never above the true cost, so it is admissible and consistent, and it makes open-space searches
expand about one voxel per path step instead of a wide Euclidean "cone". A* with a consistent
heuristic and a closed set returns a minimum-cost path.

Two implementations of the same search (same costs, heuristic and tie-breaking, hence the same path):
the compiled one (native/astar26.c, built with the system C compiler on first use; much faster) when it
is available, else the pure-Python one below (``backend`` chooses; tests compare them). A grid with ``landmarks``
(landmarks.py; coarse_path.py sets them on its block grid) adds their bound in the compiled search only: the same
minimum cost, possibly another of several equal-cost paths.

Speed in pure Python: flat indices into a zero-padded occupancy (`bytes`: no bounds checks, the
border is occupied), precomputed neighbour offsets, heapq, dicts for g / parents (only touched
voxels cost memory), and connected components computed once per grid so an unreachable goal is
answered in O(1) instead of by flooding the whole free space.
"""
from __future__ import annotations

import heapq
import math
import sys
import threading
from typing import Callable, Optional, Sequence, Union

import numpy as np

from ..errors import GoalUnreachableError, InvalidInputError, StartInCollisionError
from ..native import (
    astar26 as native_astar26,
    native_status,
    search26 as native_search26,
    search26_ws as native_search26_ws,
    search26_ws_lm as native_search26_ws_lm,
    search26_wsr as native_search26_wsr,
)

_SQ2, _SQ3 = math.sqrt(2.0), math.sqrt(3.0)


def _is_tensor(v) -> bool:
    """``v`` is a torch tensor. torch is not imported for this (this module takes numpy and torch alike, and a process
    that plans on numpy grids, e.g. a compiled-kernel probe, need not load torch): a tensor exists only once torch is
    imported."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(v, torch.Tensor)


class SearchBudgetExhausted(GoalUnreachableError):
    """A* stopped after ``max_expansions`` without reaching the goal (the goal may still be reachable)."""


_C1, _C2 = _SQ2 - 1.0, _SQ3 - _SQ2  # octile: a + (sqrt2-1) b + (sqrt3-sqrt2) c for a >= b >= c


# grids with fewer padded voxels search with per-call arrays (a 13^3 window: calloc is cheaper than keeping one)
WORKSPACE_MIN_VOXELS = 32_768
RESUME_HEAP_ITEMS = 32_768
"""Open-list items a workspace keeps for a resumed search (786 kB): an A* stopped after its budget of expansions has at
most 26 per expansion (coarse_path.FINE_BUDGET = 800: 20,801); a larger open list is not kept (the next call starts
again: the same result)."""


class _SearchWorkspace:
    """The compiled search's per-voxel arrays, kept between calls (native/astar26.c, search26_ws): a voxel's
    stamp tells whether this call has seen it, so nothing is cleared per call."""

    def __init__(self, n: int):
        self.stamp = np.zeros(n, dtype=np.uint32)  # [N]
        self.g = np.empty(n, dtype=np.float64)  # [N] read only where this call's stamp is set
        self.parent = np.empty(n, dtype=np.int64)  # [N]
        self.out = np.empty(n, dtype=np.int64)  # [N] the path (a path never visits a voxel twice)
        self.gen = 1
        # search26_wsr: the open list of a search its budget stopped, kept for a later call of the same search
        self.heap = np.empty(3 * RESUME_HEAP_ITEMS)  # [items, (f, h, n)] float64, float64, int64 (24 bytes an item)
        self.state = np.zeros(2, dtype=np.int64)  # open-list size (0: nothing kept), expansions so far
        self.pending: Optional[tuple] = None  # (start, goal, weight, landmarks) of the kept search, gen not advanced

    def advance(self) -> None:
        self.pending = None
        self.state[0] = 0
        self.gen += 1
        if self.gen >= 2**31 - 1:  # stamps are uint32 (2 gen + 1): start over from cleared stamps
            self.stamp[:] = 0
            self.gen = 1


class AStarGrid:
    """An occupancy grid prepared for repeated A* queries (build once per grid, reuse per plan)."""

    def __init__(self, occupied: np.ndarray):
        occ = np.asarray(occupied)
        if occ.ndim != 3 or occ.dtype != bool:
            raise InvalidInputError(f"occupancy must be a bool array [X, Y, Z], got {occ.dtype} {occ.shape}")
        self.shape = tuple(int(s) for s in occ.shape)
        X, Y, Z = self.shape
        padded = np.ones((X + 2, Y + 2, Z + 2), dtype=np.uint8)
        padded[1:-1, 1:-1, 1:-1] = occ
        self.blocked = padded.tobytes()  # flat, C order
        self._blocked_np = padded.reshape(-1)  # the same bytes for the compiled search (native/astar26.c)
        self.padded_shape = (X + 2, Y + 2, Z + 2)
        self.sy = Z + 2
        self.sx = (Y + 2) * (Z + 2)
        self.neighbours = []  # (flat offset, cost, di, dj, dk)
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                for dk in (-1, 0, 1):
                    if di or dj or dk:
                        cost = math.sqrt(di * di + dj * dj + dk * dk)
                        self.neighbours.append((di * self.sx + dj * self.sy + dk, cost, di, dj, dk))
        self._occ = occ
        self._labels: Optional[np.ndarray] = None
        self._local = threading.local()  # one search workspace per thread (viewer callbacks run in threads)
        # float32 [L, padded voxels] landmark distance tables (search/landmarks.py) the compiled A* may use, or None
        self.landmarks: Optional[np.ndarray] = None

    def native_search(self, start: int, goal: int, target: Optional[np.ndarray] = None, weight: float = 1.0,
                      limit: int = -1) -> tuple[int, np.ndarray]:
        """One compiled search (native/astar26.c) between flat padded indices: A* to ``goal`` (guided by
        ``self.landmarks`` too when set: the same minimum cost, fewer expansions), or with ``target`` (uint8, the
        padded layout) Dijkstra to the nearest marked voxel. -> (k, out): k >= 0 path voxels out[:k] (flat, start
        first; valid until this thread's next search on this grid), else the C status. Needs the compiled library
        (callers check native.search26()).
        An A* that ``limit`` stopped (-2) is kept (search26_wsr), and the next call on this grid and thread for the
        same start, goal and weight resumes it, its expansions counted from the first call: the same result as a new
        search, without the first one's work again (coarse_path.voxel_path: the fine search after a budgeted one)."""
        tgt = None if target is None else target.ctypes.data
        args = (self._blocked_np.ctypes.data, *self.padded_shape, int(start), int(goal), tgt, float(weight), int(limit))
        use_lm = self.landmarks is not None and target is None
        lm_fn = native_search26_ws_lm() if use_lm else None
        ws_fn = native_search26_ws() if self._blocked_np.size >= WORKSPACE_MIN_VOXELS or lm_fn else None
        if ws_fn is None:
            out = np.empty(self._blocked_np.size, dtype=np.int64)
            return int(native_search26()(*args, out.ctypes.data, out.size)), out
        ws = getattr(self._local, "ws", None)
        if ws is None:
            ws = self._local.ws = _SearchWorkspace(self._blocked_np.size)
        # an A* (no target) the same as the one a budget stopped last on this grid and thread goes on from there
        key = None if target is not None else (int(start), int(goal), float(weight), use_lm)
        if ws.pending is not None and ws.pending != key:
            ws.advance()
        ws_args = (*args, ws.out.ctypes.data, ws.out.size, ws.stamp.ctypes.data, ws.gen, ws.g.ctypes.data,
                   ws.parent.ctypes.data)
        wsr_fn = native_search26_wsr() if key is not None else None
        if wsr_fn is not None:
            lm = (self.landmarks.ctypes.data, self.landmarks.shape[0]) if use_lm else (None, 0)
            k = int(wsr_fn(*ws_args, *lm, ws.heap.ctypes.data, RESUME_HEAP_ITEMS, ws.state.ctypes.data))
        elif lm_fn is not None:
            k = int(lm_fn(*ws_args, self.landmarks.ctypes.data, self.landmarks.shape[0]))
        else:
            k = int(ws_fn(*ws_args))
        if k == -2 and wsr_fn is not None and ws.state[0] > 0:
            ws.pending = key  # stamps, g, parent and the open list stay as they are (gen not advanced)
        else:
            ws.advance()
        return k, ws.out

    @property
    def labels(self) -> np.ndarray:
        """26-connected components of free voxels (0 = occupied), computed on first use."""
        if self._labels is None:
            from scipy import ndimage

            self._labels, _ = ndimage.label(~self._occ, structure=np.ones((3, 3, 3), dtype=bool))
        return self._labels

    def flat(self, ijk) -> int:
        i, j, k = ijk
        return (i + 1) * self.sx + (j + 1) * self.sy + (k + 1)

    def flat_many(self, ijk: np.ndarray) -> np.ndarray:
        """Flat padded indices int64 [K] of voxels [K, 3] (vectorised flat)."""
        return (np.asarray(ijk, dtype=np.int64).reshape(-1, 3) + 1) @ np.array([self.sx, self.sy, 1], dtype=np.int64)

    def unflat_many(self, f: np.ndarray) -> np.ndarray:
        """Voxels int64 [K, 3] of flat padded indices [K] (vectorised unflat)."""
        i, rem = np.divmod(np.asarray(f, dtype=np.int64), self.sx)
        j, k = np.divmod(rem, self.sy)
        return np.stack([i - 1, j - 1, k - 1], axis=1)

    def unflat(self, f: int) -> tuple[int, int, int]:
        i, rem = divmod(f, self.sx)
        j, k = divmod(rem, self.sy)
        return i - 1, j - 1, k - 1


def _as_ijk(v, shape, what: str) -> tuple[int, int, int]:
    a = np.asarray(v.cpu() if _is_tensor(v) else v).reshape(-1)
    if a.shape != (3,) or not np.all(np.isfinite(a.astype(float))) or np.any(a != np.round(a)):
        raise InvalidInputError(f"{what} voxel must be 3 integers, got {a.tolist()}")
    ijk = tuple(int(x) for x in a)
    if not all(0 <= x < s for x, s in zip(ijk, shape)):
        raise InvalidInputError(f"{what} voxel {ijk} is outside the grid {shape}")
    return ijk


def astar(
    occupied: Union[np.ndarray, AStarGrid],
    start_ijk: Sequence[int],
    goal_ijk: Sequence[int],
    *,
    max_expansions: Optional[int] = None,
    check_components: bool = True,
    heuristic_weight: float = 1.0,
    backend: str = "auto",
) -> np.ndarray:
    """Minimum-cost 26-connected voxel path from start to goal (both included) -> int64 [K, 3].

    occupied: bool [X, Y, Z] (True = the camera may not be centred there) or a prepared AStarGrid
    (reuse it across queries: padding and components are then not recomputed).
    heuristic_weight: 1 (default) gives a minimum-cost path; w > 1 is weighted A*: the cost is at most
    w times the minimum and far fewer voxels are expanded around large obstacles (the path is
    shortcut afterwards anyway).
    backend: "auto" (the compiled search when native.astar26() loads, else Python), "native" (error
    when it does not load) or "python".
    Raises StartInCollisionError (start voxel occupied), GoalUnreachableError (goal occupied, in
    another free component, or max_expansions exhausted).
    """
    if not (heuristic_weight >= 1.0 and math.isfinite(heuristic_weight)):
        raise InvalidInputError(f"heuristic_weight must be >= 1, got {heuristic_weight}")
    if backend not in ("auto", "native", "python"):
        raise InvalidInputError(f"A* backend must be 'auto', 'native' or 'python', got {backend!r}")
    grid = occupied if isinstance(occupied, AStarGrid) else AStarGrid(occupied)
    s = _as_ijk(start_ijk, grid.shape, "start")
    g_ = _as_ijk(goal_ijk, grid.shape, "goal")
    _check_endpoints(grid, s, g_, check_components)
    start, goal = grid.flat(s), grid.flat(g_)
    if start == goal:
        return np.asarray([s], dtype=np.int64)

    fn = None if backend == "python" else native_astar26()
    if backend == "native" and fn is None:
        raise RuntimeError(f"the compiled A* is not available: {native_status().get('astar26', 'not loaded')}")
    if fn is not None:
        return _astar_native(grid, start, goal, s, g_, max_expansions, float(heuristic_weight))
    return _astar_reference(grid, start, goal, s, g_, max_expansions, float(heuristic_weight))


def _check_endpoints(grid: AStarGrid, s: tuple, g_: tuple, check_components: bool) -> None:
    """Raise StartInCollisionError / GoalUnreachableError for an occupied start or goal voxel, or (with
    check_components) a goal in another free component than the start."""
    blocked = grid.blocked
    if blocked[grid.flat(s)]:
        raise StartInCollisionError(f"the start voxel {s} is occupied (too close to the scene); choose another start")
    if blocked[grid.flat(g_)]:
        raise GoalUnreachableError(f"the goal voxel {g_} is occupied (too close to the scene)")
    if check_components and s != g_:
        lab = grid.labels
        if lab[s] != lab[g_]:
            raise GoalUnreachableError(
                f"no collision-free path: the goal voxel {g_} is not connected to the start voxel {s} "
                f"through free space at this grid resolution"
            )


def _astar_reference(grid: AStarGrid, start: int, goal: int, s, g_, max_expansions, weight: float) -> np.ndarray:
    """astar() in pure Python (flat padded indices; the module docstring says why it is written this way)."""
    closed = bytearray(grid.blocked)  # occupied or closed: one lookup per neighbour
    gi, gj, gk = g_
    sx, sy = grid.sx, grid.sy
    nbrs = grid.neighbours
    g = {start: 0.0}
    parent = {start: -1}
    heap = [(0.0, 0.0, start)]
    push, pop = heapq.heappush, heapq.heappop
    expansions = 0
    limit = max_expansions if max_expansions is not None else 1 << 62
    g_get = g.get
    inf = math.inf
    c1, c2 = _C1, _C2
    if weight != 1.0:
        wgt = float(weight)
        c1, c2 = wgt * _C1, wgt * _C2
    else:
        wgt = 1.0
    while heap:
        _, _, cur = pop(heap)
        if closed[cur]:
            continue
        if cur == goal:
            break
        closed[cur] = 1
        expansions += 1
        if expansions > limit:
            raise SearchBudgetExhausted(f"A* gave up after {limit} expansions without reaching the goal {g_}")
        gc = g[cur]
        ci, rem = divmod(cur, sx)
        cj, ck = divmod(rem, sy)
        dgi, dgj, dgk = gi + 1 - ci, gj + 1 - cj, gk + 1 - ck  # goal - current (padded coords)
        for d, c, di, dj, dk in nbrs:
            n = cur + d
            if closed[n]:
                continue
            ng = gc + c
            if ng < g_get(n, inf):
                g[n] = ng
                parent[n] = cur
                a = abs(dgi - di)
                b = abs(dgj - dj)
                e = abs(dgk - dk)
                hi = max(a, b, e)
                lo = min(a, b, e)
                h = wgt * hi + c1 * (a + b + e - hi - lo) + c2 * lo  # (weighted) octile distance
                push(heap, (ng + h, h, n))
    else:
        raise GoalUnreachableError(f"no collision-free voxel path from {s} to {g_}")
    path = []
    f = goal
    while f != -1:
        path.append(grid.unflat(f))
        f = parent[f]
    return np.asarray(path[::-1], dtype=np.int64)


def _astar_native(grid: AStarGrid, start: int, goal: int, s, g_, max_expansions, weight: float) -> np.ndarray:
    """astar() through native/astar26.c (same search; see the module docstring)."""
    limit = -1 if max_expansions is None else int(max_expansions)
    k, out = grid.native_search(start, goal, None, weight, limit)
    if k == -2:
        raise SearchBudgetExhausted(f"A* gave up after {limit} expansions without reaching the goal {g_}")
    if k == -1:
        raise GoalUnreachableError(f"no collision-free voxel path from {s} to {g_}")
    if k < 0:
        raise MemoryError(f"the compiled A* failed (code {k}) on a grid of {grid.shape}")
    return grid.unflat_many(out[:k])


def path_cost(path_ijk: np.ndarray) -> float:
    """Sum of step lengths (voxel units) of a voxel path [K, 3]."""
    d = np.diff(np.asarray(path_ijk, dtype=np.float64), axis=0)
    return float(np.linalg.norm(d, axis=1).sum())


def shortcut(
    points,  # [K, 3] numpy or torch
    segment_free: Callable,
    *,
    max_lookahead: Optional[int] = None,
):
    """Greedy line-of-sight pruning of a polyline [K, 3] -> [K', 3] (same type as the input).

    From the current point, jump to the FARTHEST later point whose straight segment is free, then
    repeat. ``segment_free(p0 [P,3], p1 [P,3]) -> bool [P]`` is batched (one call per kept point,
    numpy or torch in, numpy/torch/list of bools out); it must be conservative (e.g. the swept-sphere
    test). Consecutive input points are always kept connectable: their segment came from the voxel
    path and is taken even if ``segment_free`` refuses it, so the output is never worse than the input.
    The first and last points are kept.
    """
    is_torch = _is_tensor(points)
    pts = points if is_torch else np.asarray(points, dtype=np.float64)
    K = int(pts.shape[0])
    if pts.ndim != 2 or pts.shape[-1] != 3:
        raise InvalidInputError(f"shortcut needs points [K, 3], got {tuple(pts.shape)}")
    if K <= 2:
        return pts
    keep = [0]
    i = 0
    while i < K - 1:
        hi = K - 1 if max_lookahead is None else min(K - 1, i + max_lookahead)
        js = list(range(i + 2, hi + 1))
        best = i + 1
        if js:
            p1 = pts[js]
            p0 = pts[[i] * len(js)]
            free = segment_free(p0, p1)
            free = free.detach().cpu().numpy() if _is_tensor(free) else np.asarray(free)
            free = free.reshape(-1).astype(bool)
            if free.shape[0] != len(js):
                raise InvalidInputError(f"segment_free returned {free.shape[0]} answers for {len(js)} segments")
            ok = np.nonzero(free)[0]
            if ok.size:
                best = js[int(ok[-1])]
        keep.append(best)
        i = best
    return pts[keep]


def batched_shortcut(paths: list, segments_free) -> list:
    """Greedy farthest-visible-point pruning (astar.shortcut's rule) of several polylines [K_i, 3] at once.

    Each round, every unfinished polyline proposes all segments from its current point to its later points
    (except the next one, always kept: it came from the voxel path); ONE segments_free(p0 [P,3], p1 [P,3])
    call answers them all; each jumps to its farthest free point."""
    cur = [0] * len(paths)
    keep = [[0] for _ in paths]
    while True:
        active = [i for i, pts in enumerate(paths) if cur[i] < len(pts) - 1]
        if not active:
            break
        owners, js, p0, p1 = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros((0, 3))], [np.zeros((0, 3))]
        for i in active:
            pts = paths[i]
            j = np.arange(cur[i] + 2, len(pts))
            owners.append(np.full(len(j), i))
            js.append(j)
            p0.append(np.repeat(pts[cur[i]][None], len(j), 0))
            p1.append(pts[j])
        own = np.concatenate(owners)
        jj = np.concatenate(js)
        free = np.zeros(0, dtype=bool)
        if len(own):
            free = np.asarray(segments_free(np.concatenate(p0), np.concatenate(p1)), dtype=bool).reshape(-1)
        for i in active:
            sel = np.flatnonzero((own == i) & free)
            nxt = int(jj[sel].max()) if sel.size else cur[i] + 1
            keep[i].append(nxt)
            cur[i] = nxt
    return [pts[k] for pts, k in zip(paths, keep)]
