"""coarse_path.voxel_path: every segment of the returned path lies in free (closed) fine voxels,
checked by brute force on dense samples; a path exists exactly when scipy's Dijkstra finds one."""
from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from scipy.sparse.csgraph import dijkstra
from test_astar import grid_graph

from cinenerf_ns.planner.errors import GoalUnreachableError
from cinenerf_ns.planner.search.astar import AStarGrid, SearchBudgetExhausted, astar
from cinenerf_ns.planner.search.coarse_path import COARSE_DETOUR, CoarseGrid, voxel_path

SETTINGS = dict(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def point_in_free_voxel(p: np.ndarray, occ: np.ndarray, tol: float = 1e-9) -> bool:
    """Brute force: is p (fine index units, voxel v spans v +- 0.5) in some free closed voxel?"""
    base = np.floor(p).astype(int)
    for d in itertools.product((0, 1), repeat=3):
        v = base + np.array(d)
        if (v < 0).any() or (v >= occ.shape).any() or occ[tuple(v)]:
            continue
        if (np.abs(p - v) <= 0.5 + tol).all():
            return True
    return False


def check_path_safe(path: np.ndarray, occ: np.ndarray, s, g, samples: int = 33):
    assert path.dtype == np.float64 and path.ndim == 2 and path.shape[1] == 3
    assert np.allclose(path[0], s) and np.allclose(path[-1], g)
    for a, b in zip(path[:-1], path[1:]):
        assert np.abs(b - a).max() <= 2.0 + 1e-12  # fine, fine-to-block-centre or block moves only
        for t in np.linspace(0, 1, samples):
            assert point_in_free_voxel(a + t * (b - a), occ), (a, b, t)


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), shape=st.tuples(st.integers(1, 12), st.integers(1, 12), st.integers(1, 10)),
       density=st.floats(0.0, 0.5), budget=st.sampled_from([0, 5, 2000]), window=st.sampled_from([1, 3, 6]),
       detour=st.sampled_from([None, 0, 50]))
def test_voxel_path_is_safe_and_complete(seed, shape, density, budget, window, detour):
    rng = np.random.default_rng(seed)
    occ = rng.random(shape) < density
    free = np.argwhere(~occ)
    if len(free) == 0:
        return
    s, g = free[rng.integers(len(free))], free[rng.integers(len(free))]
    dist = dijkstra(grid_graph(occ), indices=np.ravel_multi_index(tuple(s), shape))
    ref = dist[np.ravel_multi_index(tuple(g), shape)]
    ag = AStarGrid(occ)
    cg = CoarseGrid(ag)
    if not np.isfinite(ref):
        with pytest.raises(GoalUnreachableError):
            voxel_path(ag, cg, s, g, astar_budget=budget, window=window, detour_budget=detour)
        return
    path = voxel_path(ag, cg, s, g, astar_budget=budget, window=window, detour_budget=detour)
    check_path_safe(path, occ, s, g)
    # the path is a curve from s to g through free space: never shorter than the optimal grid path
    # (the grid metric's optimum is >= Euclidean length of any free curve only up to corner cuts, so
    # compare against the straight distance instead)
    assert np.linalg.norm(np.diff(path, axis=0), axis=1).sum() >= np.linalg.norm(g - s) - 1e-9


def test_coarse_blocks_are_conservative():
    rng = np.random.default_rng(0)
    occ = rng.random((7, 6, 5)) < 0.2
    cg = CoarseGrid(AStarGrid(occ))
    for I, J, K in np.argwhere(~cg.occupied):
        blk = occ[2 * I:2 * I + 2, 2 * J:2 * J + 2, 2 * K:2 * K + 2]
        assert blk.shape == (2, 2, 2) and not blk.any()  # free block: all 8 fine voxels exist and are free
    assert cg.occupied.shape == (4, 3, 3)


def test_wall_forces_coarse_route_and_fallback():
    # a wall with a hole 2 voxels wide (the coarse grid passes) and one 1 voxel wide (only the fine grid)
    occ = np.zeros((20, 20, 12), dtype=bool)
    occ[10, :, :] = True
    occ[10, 8:10, 4:6] = False  # aligned to blocks: coarse route exists
    ag, cg = AStarGrid(occ), CoarseGrid(AStarGrid(occ))
    with pytest.raises(SearchBudgetExhausted):
        astar(ag, (1, 1, 1), (18, 18, 10), max_expansions=5)
    p = voxel_path(ag, cg, (1, 1, 1), (18, 18, 10), astar_budget=5)
    check_path_safe(p, occ, (1, 1, 1), (18, 18, 10))
    assert (np.abs(p - np.round(p)) > 0.25).any()  # went through block centres
    occ2 = np.zeros((20, 20, 12), dtype=bool)
    occ2[10, :, :] = True
    occ2[10, 9, 5] = False  # one-voxel hole: no free block on it; one side escapes through it to the other's blocks
    ag2, cg2 = AStarGrid(occ2), CoarseGrid(AStarGrid(occ2))
    p2 = voxel_path(ag2, cg2, (1, 1, 1), (18, 18, 10), astar_budget=5, detour_budget=10**6)  # candidates' rule
    check_path_safe(p2, occ2, (1, 1, 1), (18, 18, 10))
    assert (np.abs(p2 - np.round(p2)) > 0.25).any() and (np.abs(p2 - (10, 9, 5)).max(1) < 1e-12).any()
    for budget in (None, 10**6):  # one shot: no escapes; or no escape target: the fine search answers
        cg2._escapes.clear()
        cg2._largest = -1 if budget else cg2._largest
        p3 = voxel_path(ag2, cg2, (1, 1, 1), (18, 18, 10), astar_budget=5, detour_budget=budget)
        check_path_safe(p3, occ2, (1, 1, 1), (18, 18, 10))
        assert np.allclose(p3, np.round(p3))  # fine voxels only


def _pocket_grid(tunnel: int) -> tuple:
    """A 24 x 16 x 12 room whose goal sits in a pocket of free blocks walled off from the rest at the coarse level:
    the pocket (fine x 16..19) opens to the room through a tunnel one fine voxel wide and ``tunnel`` voxels long."""
    occ = np.zeros((24, 16, 12), dtype=bool)
    occ[14:22, :, :] = True
    occ[16:20, 4:8, 4:8] = False  # the pocket: 2 x 2 x 2 free blocks
    occ[14:16, 5, 5] = False  # a one-voxel tunnel from the room (x < 14) into the pocket
    if tunnel > 2:
        occ[14:16, 5, 5] = True
        occ[16 - tunnel:16, 5, 5] = False
    return occ


@pytest.mark.parametrize("tunnel", [2, 9])
def test_a_goal_in_a_coarse_pocket_escapes_to_the_main_component(tunnel):
    occ = _pocket_grid(tunnel)
    ag = AStarGrid(occ)
    cg = CoarseGrid(ag)
    s, g = np.array([1, 1, 1]), np.array([17, 5, 5])
    assert cg.labels[tuple(s // 2)] != cg.labels[tuple(g // 2)]  # the pocket is its own coarse component
    p = cg.path(s, g, window=1)  # a window too small to join them: the pocket's end escapes
    assert p is not None
    check_path_safe(p, occ, s, g)
    assert cg.path(s, g, window=1, escape=False) is None
    for budget in (None, 10**6):
        q = voxel_path(ag, cg, s, g, astar_budget=5, window=1, detour_budget=budget)
        check_path_safe(q, occ, s, g)


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), density=st.floats(0.05, 0.45), window=st.sampled_from([0, 1, 3]))
def test_coarse_route_with_escapes_is_safe_and_found_when_components_join(seed, density, window):
    """CoarseGrid.path on random grids (brute-force safety of every segment); whenever it gives up, the fine grid
    still joins the ends (voxel_path's fallback) or they are not joined at all (scipy's Dijkstra decides)."""
    rng = np.random.default_rng(seed)
    shape = (12, 10, 8)
    occ = rng.random(shape) < density
    free = np.argwhere(~occ)
    if len(free) < 2:
        return
    s, g = free[rng.integers(len(free))], free[rng.integers(len(free))]
    cg = CoarseGrid(AStarGrid(occ))
    p = cg.path(s, g, window)
    if p is not None:
        check_path_safe(p, occ, s, g)
        dist = dijkstra(grid_graph(occ), indices=np.ravel_multi_index(tuple(s), shape))
        assert np.isfinite(dist[np.ravel_multi_index(tuple(g), shape)])


def test_a_coarse_detour_round_a_wall_gives_way_to_the_fine_path_through_its_gap():
    """The coarse grid joins both sides of a wall only through a far opening, the fine grid through a one-voxel gap on
    the straight line: the coarse route (over COARSE_DETOUR x the straight distance) is checked against the fine one
    and the shorter kept."""
    occ = np.zeros((30, 40, 8), dtype=bool)
    occ[15, :, :] = True
    occ[15, 5, 3] = False  # the gap: on no free block
    occ[14:16, 36:40, :] = False  # the far opening, block aligned
    occ[14, :36, :] = True
    occ[14, 5, 3] = False
    s, g = np.array([2, 5, 3]), np.array([28, 5, 3])
    ag, cg = AStarGrid(occ), CoarseGrid(AStarGrid(occ))
    route = cg.path(s, g, 6)
    assert route is not None and np.linalg.norm(np.diff(route, axis=0), axis=1).sum() > COARSE_DETOUR * 26
    p = voxel_path(ag, cg, s, g, astar_budget=5)
    check_path_safe(p, occ, s, g)
    shape = occ.shape
    dist = dijkstra(grid_graph(occ), indices=np.ravel_multi_index(tuple(s), shape))
    ref = dist[np.ravel_multi_index(tuple(g), shape)]
    assert np.linalg.norm(np.diff(p, axis=0), axis=1).sum() <= ref + 1e-9


def test_one_shot_detour_check_is_bounded_and_keeps_the_coarse_route(monkeypatch):
    """Where a wall really imposes the detour, the one-shot check's fine A* stops after SHOT_DETOUR_EXPANSIONS and the
    (safe) coarse route is kept; with room for the whole fine search the shorter fine path wins, as before."""
    import cinenerf_ns.planner.search.coarse_path as cp

    occ = np.zeros((30, 40, 8), dtype=bool)
    occ[14:16, :36, :] = True  # a wall, its only opening far from the straight line (block aligned)
    s, g = np.array([2, 5, 3]), np.array([28, 5, 3])
    ag, cg = AStarGrid(occ), CoarseGrid(AStarGrid(occ))
    route = cg.path(s, g, 6)
    assert route is not None and np.linalg.norm(np.diff(route, axis=0), axis=1).sum() > COARSE_DETOUR * 26
    monkeypatch.setattr(cp, "SHOT_DETOUR_EXPANSIONS", 50)  # far fewer than the fine search round the wall needs
    p = voxel_path(ag, cg, s, g, astar_budget=5)
    check_path_safe(p, occ, s, g)
    np.testing.assert_array_equal(p, route)
    monkeypatch.setattr(cp, "SHOT_DETOUR_EXPANSIONS", 10**9)
    q = voxel_path(ag, cg, s, g, astar_budget=5)
    check_path_safe(q, occ, s, g)
    shape = occ.shape
    dist = dijkstra(grid_graph(occ), indices=np.ravel_multi_index(tuple(s), shape))
    ref = dist[np.ravel_multi_index(tuple(g), shape)]
    assert np.linalg.norm(np.diff(q, axis=0), axis=1).sum() <= ref + 1e-9
    assert np.linalg.norm(np.diff(q, axis=0), axis=1).sum() < np.linalg.norm(np.diff(p, axis=0), axis=1).sum()
