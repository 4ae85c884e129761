"""A* and shortcutting (cinenerf_ns/planner/search/astar.py) against scipy's Dijkstra on the same graph."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings, strategies as st
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from cinenerf_ns.planner.errors import GoalUnreachableError, InvalidInputError, StartInCollisionError
from cinenerf_ns.planner.search.astar import AStarGrid, astar, path_cost, shortcut

SETTINGS = dict(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def grid_graph(occ: np.ndarray):
    """26-connected graph of free voxels, edge weights = step lengths (reference, plain loops)."""
    X, Y, Z = occ.shape
    rows, cols, w = [], [], []
    for i, j, k in np.argwhere(~occ):
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                for dk in (-1, 0, 1):
                    a, b, c = i + di, j + dj, k + dk
                    if (di or dj or dk) and 0 <= a < X and 0 <= b < Y and 0 <= c < Z and not occ[a, b, c]:
                        rows.append((i * Y + j) * Z + k)
                        cols.append((a * Y + b) * Z + c)
                        w.append(math.sqrt(di * di + dj * dj + dk * dk))
    return coo_matrix((np.asarray(w, float), (np.asarray(rows, int), np.asarray(cols, int))),
                      shape=(occ.size,) * 2).tocsr()


def random_case(seed, shape, density):
    """(occupancy, start, goal, Dijkstra's cost from start to goal (inf: not connected)) of a random grid, or
    None when the grid has no free voxel."""
    rng = np.random.default_rng(seed)
    occ = rng.random(shape) < density
    free = np.argwhere(~occ)
    if len(free) == 0:
        return None
    s, g = free[rng.integers(len(free))], free[rng.integers(len(free))]
    dist = dijkstra(grid_graph(occ), indices=np.ravel_multi_index(tuple(s), shape))
    ref = dist[np.ravel_multi_index(tuple(g), shape)]
    return occ, s, g, ref


def check_path(path, occ, s, g):
    assert path.dtype == np.int64 and path.shape[1] == 3
    assert tuple(path[0]) == tuple(s) and tuple(path[-1]) == tuple(g)
    assert not occ[tuple(path.T)].any()
    steps = np.abs(np.diff(path, axis=0))
    assert (steps.max(1) == 1).all()  # 26-connected unit moves


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), shape=st.tuples(st.integers(1, 9), st.integers(1, 9), st.integers(1, 9)),
       density=st.floats(0.0, 0.6))
def test_astar_is_optimal_vs_dijkstra(seed, shape, density):
    case = random_case(seed, shape, density)
    if case is None:
        return
    occ, s, g, ref = case
    if not np.isfinite(ref):
        with pytest.raises(GoalUnreachableError):
            astar(occ, s, g)
        with pytest.raises(GoalUnreachableError):  # also without the component shortcut: search exhausts
            astar(occ, s, g, check_components=False)
        return
    path = astar(occ, s, g)
    check_path(path, occ, s, g)
    assert path_cost(path) == pytest.approx(ref, abs=1e-9)
    path2 = astar(occ, s, g, check_components=False)
    assert path_cost(path2) == pytest.approx(ref, abs=1e-9)
    # weighted A*: a valid path within the weight's suboptimality bound
    path3 = astar(occ, s, g, heuristic_weight=1.5)
    check_path(path3, occ, s, g)
    assert ref - 1e-9 <= path_cost(path3) <= 1.5 * ref + 1e-9


def test_reuse_prepared_grid_and_open_space_line():
    occ = np.zeros((30, 30, 30), bool)
    G = AStarGrid(occ)
    p = astar(G, (0, 0, 0), (29, 10, 5))
    # exact octile cost: 5 sqrt3 + 5 sqrt2 + 19
    assert path_cost(p) == pytest.approx(5 * math.sqrt(3) + 5 * math.sqrt(2) + 19)
    assert len(p) == 30
    assert astar(G, (3, 3, 3), (3, 3, 3)).tolist() == [[3, 3, 3]]


def test_wall_with_hole():
    occ = np.zeros((20, 20, 20), bool)
    occ[10] = True
    occ[10, 15, 15] = False
    p = astar(occ, (0, 0, 0), (19, 0, 0))
    assert [10, 15, 15] in p.tolist()
    occ[10, 15, 15] = True
    with pytest.raises(GoalUnreachableError, match="not connected"):
        astar(occ, (0, 0, 0), (19, 0, 0))


def test_errors():
    occ = np.zeros((5, 5, 5), bool)
    occ[0, 0, 0] = occ[4, 4, 4] = True
    with pytest.raises(StartInCollisionError):
        astar(occ, (0, 0, 0), (2, 2, 2))
    with pytest.raises(GoalUnreachableError):
        astar(occ, (2, 2, 2), (4, 4, 4))
    with pytest.raises(InvalidInputError):
        astar(occ, (2, 2, 5), (1, 1, 1))
    with pytest.raises(InvalidInputError):
        astar(occ, (2, 2, 1.5), (1, 1, 1))
    with pytest.raises(InvalidInputError):
        astar(occ.astype(np.uint8), (2, 2, 2), (1, 1, 1))
    with pytest.raises(InvalidInputError):
        astar(occ, (2, 2, 2), (1, 1, 1), heuristic_weight=0.5)
    with pytest.raises(GoalUnreachableError, match="gave up"):
        astar(np.zeros((20, 20, 20), bool), (0, 0, 0), (19, 19, 19), max_expansions=5)


def sphere_free(center, radius):
    """Exact batched segment test against one ball obstacle (reference for shortcut)."""
    c = np.asarray(center, float)

    def free(p0, p1):
        p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
        d = p1 - p0
        t = np.clip(((c - p0) * d).sum(1) / np.maximum((d * d).sum(1), 1e-300), 0, 1)
        return np.linalg.norm(p0 + t[:, None] * d - c, axis=1) > radius

    return free


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_shortcut_segments_are_free_and_endpoints_kept(seed):
    rng = np.random.default_rng(seed)
    occ = np.zeros((25, 25, 25), bool)
    x = np.stack(np.meshgrid(*[np.arange(25)] * 3, indexing="ij"), -1)
    c = rng.uniform(8, 16, 3)
    rad = rng.uniform(2, 6)
    occ |= ((x - c) ** 2).sum(-1) <= (rad + 1.0) ** 2  # grid inflated by a voxel: centres path is free
    free = np.argwhere(~occ)
    s, g = free[rng.integers(len(free))], free[rng.integers(len(free))]
    path = astar(occ, s, g).astype(float)
    seg_free = sphere_free(c, rad)
    short = shortcut(path, seg_free)
    assert np.array_equal(short[0], path[0]) and np.array_equal(short[-1], path[-1])
    assert len(short) <= len(path)
    # every kept point is a path point, in order
    pos = [int(np.nonzero((path == q).all(1))[0][0]) for q in short]
    assert pos == sorted(pos)
    # each shortcut segment is free (adjacent path points are free by construction of the grid)
    assert seg_free(short[:-1], short[1:]).all()
    assert path_cost(short) <= path_cost(path) + 1e-9


def test_shortcut_torch_and_straight_line():
    pts = torch.tensor([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 1, 0], [4, 2, 0]])
    out = shortcut(pts, lambda a, b: torch.ones(a.shape[0], dtype=torch.bool))
    assert isinstance(out, torch.Tensor) and out.tolist() == [[0, 0, 0], [4, 2, 0]]
    calls = []

    def never(a, b):
        calls.append(len(a))
        return np.zeros(len(a), bool)

    out = shortcut(pts.numpy(), never)
    assert out.tolist() == pts.tolist()  # nothing can be skipped, path kept
    assert calls == [3, 2, 1]
    with pytest.raises(InvalidInputError):
        shortcut(pts, lambda a, b: np.ones(1, bool))
