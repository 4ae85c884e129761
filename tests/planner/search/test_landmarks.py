"""Landmark tables (search/landmarks.py) and the compiled A* that reads them (native/astar26.c: dist26,
search26_ws_lm), against float64 Dijkstra references: exact distances, admissible bounds, minimum-cost paths, and
fewer expansions round a wall."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.sparse.csgraph import dijkstra

from cinenerf_ns.planner.native import dist26
from cinenerf_ns.planner.search.astar import AStarGrid, SearchBudgetExhausted, astar, path_cost
from cinenerf_ns.planner.search.landmarks import distances, landmark_tables

sys.path.insert(0, str(Path(__file__).parent))
from test_astar import SETTINGS, check_path, grid_graph, random_case  # noqa: E402

pytestmark = pytest.mark.skipif(dist26() is None, reason="the compiled search does not load here")


def padded_to_grid(G: AStarGrid, table: np.ndarray) -> np.ndarray:
    """A padded-layout table [padded voxels] as [X, Y, Z] (the ring dropped)."""
    return table.reshape(G.padded_shape)[1:-1, 1:-1, 1:-1]


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), shape=st.tuples(st.integers(1, 8), st.integers(1, 8), st.integers(1, 8)),
       density=st.floats(0.0, 0.6))
def test_distances_are_dijkstras(seed, shape, density):
    case = random_case(seed, shape, density)
    if case is None:
        return
    occ, s, _, _ = case
    G = AStarGrid(occ)
    got = padded_to_grid(G, distances(G, G.flat(tuple(s))))
    ref = dijkstra(grid_graph(occ), indices=np.ravel_multi_index(tuple(s), occ.shape)).reshape(occ.shape)
    assert np.array_equal(np.isfinite(got), np.isfinite(ref))
    fin = np.isfinite(ref)
    np.testing.assert_allclose(got[fin], ref[fin], rtol=2.0 ** -23, atol=0)  # float32 of the float64 distance
    assert np.isinf(distances(G, 0)).all() or occ.size == 0  # padded ring voxel: occupied, reaches nothing


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), shape=st.tuples(st.integers(2, 9), st.integers(2, 9), st.integers(1, 9)),
       density=st.floats(0.0, 0.5), count=st.integers(1, 6), weight=st.sampled_from([1.0, 1.5]))
def test_landmark_astar_is_optimal_and_bounds_are_admissible(seed, shape, density, count, weight):
    case = random_case(seed, shape, density)
    if case is None or not np.isfinite(case[3]):
        return
    occ, s, g, ref = case
    G = AStarGrid(occ)
    G.landmarks = landmark_tables(G, count)
    if G.landmarks is None:  # only when the largest free component is a single voxel
        assert np.bincount(G.labels.ravel())[1:].max() == 1
        return
    assert 1 <= G.landmarks.shape[0] <= count
    path = astar(G, s, g, heuristic_weight=weight)
    check_path(path, occ, s, g)
    if weight == 1.0:
        assert path_cost(path) == pytest.approx(ref, abs=1e-9)
    else:
        assert ref - 1e-9 <= path_cost(path) <= weight * ref + 1e-9
    # the bound the search adds, |D_l(g) - D_l(n)| less the float32 slack, never exceeds the true distance to g
    to_g = dijkstra(grid_graph(occ), indices=np.ravel_multi_index(tuple(g), occ.shape)).reshape(-1)
    lg = G.landmarks[:, G.flat(tuple(g))].astype(np.float64)  # [L]
    free = np.flatnonzero(np.isfinite(to_g))
    cells = G.flat_many(np.stack(np.unravel_index(free, occ.shape), 1))
    for l_, dg in enumerate(lg):
        if not np.isfinite(dg):
            continue
        dn = G.landmarks[l_, cells].astype(np.float64)
        bound = np.abs(dg - dn) - (dg + dn) * 2.0 ** -23
        assert (bound <= to_g[free] + 1e-12).all()


def test_landmarks_cut_expansions_round_a_wall():
    """A wall with one hole at its far end: plain A* floods the blocks in front of it; with landmarks the same
    minimum-cost path comes within an expansion budget the plain search exhausts (it needs 6718 expansions; 764
    with 8 landmarks)."""
    occ = np.zeros((24, 24, 24), bool)
    occ[12, :, :] = True
    occ[12, 22, 22] = False
    s, g = (8, 2, 2), (16, 2, 2)
    plain = AStarGrid(occ)
    ref = astar(plain, s, g)
    with pytest.raises(SearchBudgetExhausted):
        astar(plain, s, g, max_expansions=2000)
    G = AStarGrid(occ)
    G.landmarks = landmark_tables(G, 8)
    path = astar(G, s, g, max_expansions=2000)
    check_path(path, occ, s, g)
    assert path_cost(path) == pytest.approx(path_cost(ref), abs=1e-9)


def test_landmark_tables_spread_and_edge_cases():
    occ = np.zeros((10, 10, 10), bool)
    occ[5, :, :] = True  # two components, the larger one (x > 5) gets the landmarks
    occ[:2] = True
    G = AStarGrid(occ)
    T = landmark_tables(G, 4)
    assert T.shape == (4, G._blocked_np.size) and T.dtype == np.float32
    grid = np.stack([padded_to_grid(G, t) for t in T])  # [4, X, Y, Z]
    assert np.isfinite(grid[:, 6:]).all() and np.isinf(grid[:, :6]).all()
    assert len({int(np.argmin(t)) for t in T}) == 4  # distinct landmarks (each at distance 0 from itself)
    assert landmark_tables(AStarGrid(np.ones((3, 3, 3), bool))) is None  # no free voxel
    assert landmark_tables(AStarGrid(np.zeros((1, 1, 1), bool)), 8) is None  # one free voxel: nothing to bound
