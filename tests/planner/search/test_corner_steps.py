"""Detours around corner-cutting voxel-path steps (cinenerf_ns/planner/search/corner_steps.py) against a brute-force
enumeration of every axis-ordered route, with the Python voxel walk as the judge of each segment."""
from __future__ import annotations

from itertools import permutations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.geometry.voxel_traversal import segments_in_free_voxels
from cinenerf_ns.planner.search.corner_steps import ROUTES, detour_corner_steps


def walk(occ, lo, vs):
    """The judge: the Python voxel walk (the compiled one is tested against it in test_voxel_traversal.py)."""
    return lambda a, b: segments_in_free_voxels(occ, lo, vs, a, b, backend="python")


def ordered_partitions(axes: list) -> list:
    """Every ordered partition of ``axes`` into >= 2 non-empty blocks: the routes of a step that moves along them."""
    out = []
    for perm in permutations(axes):
        n = len(perm)
        for cuts in range(1, 2 ** (n - 1)):
            blocks, cur = [], [perm[0]]
            for k in range(1, n):
                if cuts >> (k - 1) & 1:
                    blocks.append(frozenset(cur))
                    cur = []
                cur.append(perm[k])
            blocks.append(frozenset(cur))
            out.append(tuple(blocks))
    return sorted(set(out), key=len)


def route_points(p, q, blocks) -> np.ndarray:
    moved, pts = set(), [p]
    for b in blocks:
        moved |= b
        pts.append(np.array([q[a] if a in moved else p[a] for a in range(3)]))
    return np.stack(pts)


def split_by_input(out: np.ndarray, way: np.ndarray) -> list:
    """The output's points between consecutive input points: [[p_i, inserted..., p_{i+1}]], asserting the input is a
    subsequence of the output that starts and ends it."""
    assert np.array_equal(out[0], way[0]) and np.array_equal(out[-1], way[-1])
    pieces, at = [], 0
    for i in range(1, len(way)):
        nxt = at + 1
        while not np.array_equal(out[nxt], way[i]):
            nxt += 1
        pieces.append(out[at:nxt + 1])
        at = nxt
    assert at == len(out) - 1
    return pieces


@st.composite
def grid_and_path(draw):
    shape = tuple(draw(st.integers(2, 5)) for _ in range(3))
    seed = draw(st.integers(0, 2 ** 31 - 1))
    rng = np.random.default_rng(seed)
    occ = rng.random(shape) < draw(st.sampled_from([0.15, 0.35, 0.55]))
    free = np.argwhere(~occ)
    if not len(free):
        occ[0, 0, 0] = False
        free = np.argwhere(~occ)
    ijk = [free[rng.integers(len(free))]]
    for _ in range(draw(st.integers(1, 12))):  # a 26-connected walk over free voxels (A*'s moves)
        steps = [d for d in np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1])).reshape(3, -1).T
                 if d.any() and all(0 <= ijk[-1][a] + d[a] < shape[a] for a in range(3))
                 and not occ[tuple(ijk[-1] + d)]]
        if not steps:
            break
        ijk.append(ijk[-1] + steps[rng.integers(len(steps))])
    lo = rng.uniform(-2, 2, 3)
    vs = float(draw(st.sampled_from([0.5, 0.0208, 1.0 / 3.0])))
    way = lo + (np.array(ijk, dtype=np.float64) + 0.5) * vs
    return occ, lo, vs, way


@settings(max_examples=150, deadline=None)
@given(grid_and_path())
def test_detours_are_the_fewest_segment_routes_the_walk_accepts(case):
    occ, lo, vs, way = case
    free = walk(occ, lo, vs)
    out, n = detour_corner_steps(free, way)
    detoured = 0
    for piece, p, q in zip(split_by_input(out, way), way[:-1], way[1:]):
        if bool(free(p[None], q[None])[0]):
            assert len(piece) == 2  # an accepted step is left alone
            continue
        axes = [a for a in range(3) if p[a] != q[a]]
        routes = [route_points(p, q, r) for r in ordered_partitions(axes)]
        ok = [len(x) - 1 for x in routes if free(x[:-1], x[1:]).all()]
        if not ok:
            assert len(piece) == 2  # no route: the step stays
            continue
        detoured += 1
        assert len(piece) - 1 == min(ok)  # the fewest segments any accepted route has
        assert free(piece[:-1], piece[1:]).all()  # every segment proven by the walk
        # each point takes each coordinate from one end, switching from p's to q's once along the route
        from_q = (piece == q) & (p != q)
        assert ((piece == p) | (piece == q)).all()
        assert (np.diff(from_q.astype(int), axis=0) >= 0).all()
    assert n == detoured


def test_a_corner_step_goes_round_the_occupied_voxel():
    occ = np.zeros((3, 3, 3), dtype=bool)
    occ[1, 0, 0] = True  # beside the step (0,0,0) -> (1,1,0)
    lo, vs = np.zeros(3), 1.0
    way = np.array([[0.5, 0.5, 0.5], [1.5, 1.5, 0.5]])
    out, n = detour_corner_steps(walk(occ, lo, vs), way)
    assert n == 1
    np.testing.assert_array_equal(out, [[0.5, 0.5, 0.5], [0.5, 1.5, 0.5], [1.5, 1.5, 0.5]])


def test_a_pinched_step_stays():
    occ = np.zeros((3, 3, 3), dtype=bool)
    occ[1, 0, 0] = occ[0, 1, 0] = True  # both sides of the step (0,0,0) -> (1,1,0): only their edge joins them
    way = np.array([[0.5, 0.5, 0.5], [1.5, 1.5, 0.5], [2.5, 1.5, 0.5]])
    out, n = detour_corner_steps(walk(occ, np.zeros(3), 1.0), way)
    assert n == 0 and np.array_equal(out, way)


def test_a_three_axis_step_prefers_two_segments():
    occ = np.zeros((2, 2, 2), dtype=bool)
    occ[1, 0, 0] = occ[0, 1, 0] = occ[0, 0, 1] = True  # no axis move from (0,0,0) is free...
    occ[0, 1, 0] = False  # ...but one: then (0,1,0) -> (1,1,1) needs (1,1,0) and (0,1,1) free, which they are
    out, n = detour_corner_steps(walk(occ, np.zeros(3), 1.0), np.array([[0.5, 0.5, 0.5], [1.5, 1.5, 1.5]]))
    assert n == 1
    np.testing.assert_array_equal(out, [[0.5, 0.5, 0.5], [0.5, 1.5, 0.5], [1.5, 1.5, 1.5]])


def test_route_table_is_every_route_of_three_axes_once():
    routes = {tuple(frozenset(np.flatnonzero(r[k] & ~r[k - 1]).tolist()) for k in range(1, 4)
                    if (r[k] != r[k - 1]).any()) for r in ROUTES}
    assert routes == set(ordered_partitions([0, 1, 2]))
    assert len(ROUTES) == len(routes) == 12
    assert ROUTES[:, 0].sum() == 0 and ROUTES[:, -1].all()


def test_short_and_free_ways_come_back_unchanged():
    occ = np.zeros((2, 2, 2), dtype=bool)
    free = walk(occ, np.zeros(3), 1.0)
    one = np.array([[0.5, 0.5, 0.5]])
    assert detour_corner_steps(free, one)[1] == 0
    way = np.array([[0.5, 0.5, 0.5], [1.5, 1.5, 1.5]])
    out, n = detour_corner_steps(free, way)
    assert n == 0 and np.array_equal(out, way)


def test_config_refuses_a_non_boolean():
    from cinenerf_ns.planner.shots.planner import PlannerConfig

    with pytest.raises(InvalidInputError, match="corner_detours must be True or False"):
        PlannerConfig(corner_detours="yes").validate()
