"""The shortcut's grid filters (cinenerf_ns/planner/search/shortcut.py) against per-point float64 references."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from hypothesis import example, given, settings, strategies as st

from cinenerf_ns.planner.search.shortcut import FreeVoxels, free_voxels, grid_sight


def in_free_voxel_reference(occ: np.ndarray, lo: np.ndarray, vs: float, p: np.ndarray) -> bool:
    """One point, plain Python: its voxel floor((p - lo) / vs) is in the grid and free (as
    clearance_queries.in_free_voxel)."""
    ijk = [math.floor((float(p[a]) - float(lo[a])) / vs) for a in range(3)]
    return all(0 <= ijk[a] < occ.shape[a] for a in range(3)) and not bool(occ[ijk[0], ijk[1], ijk[2]])


def grid_sight_reference(occ: np.ndarray, lo: np.ndarray, vs: float, p0: np.ndarray, p1: np.ndarray) -> bool:
    """One segment, sample by sample: every sample k / (n - 1) (n = max(2, ceil(L / (vs / 2)) + 1)) farther than one
    voxel from both ends lies in a free voxel. L in grid_sight's arithmetic, sqrt((dx^2 + dy^2) + dz^2): a 1-D
    np.linalg.norm rounds differently, and where L / (vs / 2) is a whole number that changes n (seed 3358664 below)."""
    d = [float(p1[a]) - float(p0[a]) for a in range(3)]
    L = math.sqrt((d[0] * d[0] + d[1] * d[1]) + d[2] * d[2])
    n = max(2, int(math.ceil(L / (0.5 * vs))) + 1)
    for k in range(n):
        frac = k / (n - 1)
        if min(frac, 1 - frac) * L > vs and not in_free_voxel_reference(occ, lo, vs, p0 + frac * (p1 - p0)):
            return False
    return True


def fake_space(occ: np.ndarray, lo: np.ndarray, vs: float):
    """What free_voxels reads of a planning space: the A* grid's occupancy and the grid's corner and voxel size."""
    prep = SimpleNamespace(astar_grid=SimpleNamespace(_occ=occ),
                           grid=SimpleNamespace(lo=torch.as_tensor(lo, dtype=torch.float64), voxel_size=vs))
    return SimpleNamespace(prepared=prep)


grids = st.tuples(st.integers(0, 2**31 - 1), st.integers(1, 9), st.integers(1, 9), st.integers(1, 9),
                  st.floats(0.0, 0.9), st.sampled_from([0.05, 0.1, 0.37]))


def make_grid(spec):
    seed, X, Y, Z, fill, vs = spec
    rng = np.random.default_rng(seed)
    occ = rng.random((X, Y, Z)) < fill
    lo = rng.uniform(-1, 1, 3)
    return rng, occ, lo, vs


@settings(max_examples=150, deadline=None)
@given(spec=grids, n=st.integers(0, 60))
def test_free_voxels_matches_the_per_point_reference(spec, n):
    """FreeVoxels.contains == the per-point reference, for points inside, outside and exactly on voxel faces."""
    rng, occ, lo, vs = make_grid(spec)
    ext = np.array(occ.shape) * vs
    pts = lo - 0.3 * ext + rng.random((n, 3)) * 1.6 * ext
    on_faces = lo + rng.integers(-1, max(occ.shape) + 2, (n, 3)) * vs  # exactly on faces, edges and corners
    pts = np.vstack([pts, on_faces])
    fv = FreeVoxels(occ, lo, vs)
    got = fv.contains(pts)
    assert got.dtype == bool and got.shape == (len(pts),)
    assert got.tolist() == [in_free_voxel_reference(occ, lo, vs, p) for p in pts]


@settings(max_examples=150, deadline=None)
@given(spec=grids, n=st.integers(1, 12), grid_aligned=st.booleans())
@example(spec=(3358664, 6, 6, 7, 0.5, 0.05), n=6, grid_aligned=True)  # L = 6 half-voxels, up to the last bit
def test_grid_sight_matches_the_sample_by_sample_reference(spec, n, grid_aligned):
    rng, occ, lo, vs = make_grid(spec)
    ext = np.array(occ.shape) * vs
    p0 = lo - 0.2 * ext + rng.random((n, 3)) * 1.4 * ext
    p1 = lo - 0.2 * ext + rng.random((n, 3)) * 1.4 * ext
    if grid_aligned:  # voxel centres and corners, as the voxel path gives; some segments of length 0
        p0 = lo + (rng.integers(0, max(occ.shape), (n, 3)) + 0.5 * rng.integers(0, 2, (n, 1))) * vs
        p1 = np.where(rng.random((n, 1)) < 0.2, p0, lo + (rng.integers(0, max(occ.shape), (n, 3)) + 0.5) * vs)
    sp = fake_space(occ, lo, vs)
    got = grid_sight(sp, p0, p1)
    assert got.tolist() == [grid_sight_reference(occ, lo, vs, a, b) for a, b in zip(p0, p1)]


def test_free_voxels_is_cached_per_grid():
    occ = np.zeros((3, 3, 3), dtype=bool)
    sp = fake_space(occ, np.zeros(3), 0.1)
    fv = free_voxels(sp)
    assert free_voxels(sp) is fv
    sp.prepared.astar_grid._occ = occ.copy()  # another grid: rebuilt
    assert free_voxels(sp) is not fv


def rounds_space(occ: np.ndarray, lo: np.ndarray, vs: float):
    """fake_space with the voxel walk's grid too (PreparedScene.voxels), as shortcut_pass reads it."""
    from cinenerf_ns.planner.corridor.grid_polytope import VoxelObstacles

    sp = fake_space(occ, lo, vs)
    sp.prepared.voxels = VoxelObstacles.from_occupied(occ, lo, vs)
    return sp


def pieces_oracle(space, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A stand-in for the Corollary-1 pieces: a fixed pseudo-random answer per segment (any per-segment rule will do:
    shortcut_pass must ask it the segments whose answer can matter and combine the answers as the reference does)."""
    h = np.sin(a @ [12.9898, 78.233, 37.719] + b @ [93.989, 67.345, 11.135]) * 43758.5453
    return (h - np.floor(h)) < 0.4


def random_polylines(rng, occ: np.ndarray, lo: np.ndarray, vs: float, n: int) -> list:
    """Voxel-path-like polylines (26-neighbour walks over voxel centres, free ones mostly), some with a start and an
    end off the centres (a user's start, a goal point), some with repeated points; lengths 1 to ~30."""
    steps = np.array([d for d in np.ndindex(3, 3, 3) if d != (1, 1, 1)]) - 1
    out = []
    for _ in range(n):
        v = rng.integers(0, occ.shape)
        path = [v]
        for _ in range(rng.integers(0, 30)):
            nxt = path[-1] + steps[rng.integers(len(steps))] * rng.integers(0, 2)
            if ((nxt >= 0) & (nxt < occ.shape)).all() and (not occ[tuple(nxt)] or rng.random() < 0.1):
                path.append(nxt)
        w = lo + (np.array(path) + 0.5) * vs
        if rng.random() < 0.5:
            w[0] += rng.uniform(-0.5, 0.5, 3) * vs
        if rng.random() < 0.5:
            w[-1] += rng.uniform(-1.5, 1.5, 3) * vs
        out.append(w if rng.random() < 0.8 else w.astype(np.float32))
    return out


@settings(max_examples=150, deadline=None)
@given(spec=grids, n=st.integers(1, 5), grid_rule=st.booleans())
def test_compiled_shortcut_pass_is_batched_shortcut_of_shortcut_test(spec, n, grid_rule):
    """shortcut_pass (gridpoly.c: cn_shortcut_rounds, farthest segment first, pieces only past the walk's answer) gives
    batched_shortcut with shortcut_test's answers (the plain reference: every segment of every round asked), for
    several polylines at once."""
    import cinenerf_ns.planner.search.shortcut as S
    from cinenerf_ns.planner import native
    from cinenerf_ns.planner.search.astar import batched_shortcut

    rng, occ, lo, vs = make_grid(spec)
    occ &= rng.random(occ.shape) < 0.5  # sparser: long free jumps happen
    sp = rounds_space(occ, lo, vs)
    ways = random_polylines(rng, occ, lo, vs, n)
    backends = ["python"] + (["native"] if native.shortcut_rounds_c() is not None else [])
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(S, "segments_free_by_pieces", pieces_oracle)
        want = batched_shortcut(ways, lambda p0, p1: S.shortcut_test(sp, p0, p1, grid_rule))
        for backend in backends:
            got = S.shortcut_pass(sp, ways, grid_rule, backend=backend)
            assert len(got) == len(want)
            for g, w, way in zip(got, want, ways):
                assert g.dtype == way.dtype and np.array_equal(g, w)


def test_shortcut_pass_edge_cases(monkeypatch):
    """No polylines, one-point and two-point polylines, and a polyline with all points equal."""
    import cinenerf_ns.planner.search.shortcut as S

    monkeypatch.setattr(S, "segments_free_by_pieces", pieces_oracle)
    occ = np.zeros((4, 4, 4), dtype=bool)
    sp = rounds_space(occ, np.zeros(3), 0.5)
    assert S.shortcut_pass(sp, [], True) == []
    ways = [np.array([[0.3, 0.3, 0.3]]), np.array([[0.3, 0.3, 0.3], [1.2, 1.2, 1.2]]), np.full((5, 3), 0.7),
            np.array([[0.25, 0.25, 0.25], [0.75, 0.75, 0.75], [1.25, 0.75, 0.75], [1.75, 1.75, 1.75]])]
    for grid_rule in (True, False):
        got = S.shortcut_pass(sp, ways, grid_rule)
        assert [g.tolist() for g in got] == [ways[0].tolist(), ways[1].tolist(), ways[2][[0, 4]].tolist(),
                                             ways[3][[0, 3]].tolist()]


def test_grid_sight_sample_exactly_one_voxel_from_an_end_does_not_count(monkeypatch):
    """Grid sight counts only samples farther than one voxel from both ends (strictly). Segment (0.5 -> 4.5) along x
    with voxel size 1: its samples are 0.5 apart, the one at x = 1.5 is exactly one voxel from the start, and voxel 1
    is occupied. The walk refuses the segment, grid sight must let it through to the pieces (here: all free), so both
    backends jump from the first point to the last; counting that sample would keep the middle point."""
    import cinenerf_ns.planner.search.shortcut as S
    from cinenerf_ns.planner import native
    from cinenerf_ns.planner.search.astar import batched_shortcut

    monkeypatch.setattr(S, "segments_free_by_pieces", lambda space, a, b: np.ones(len(a), dtype=bool))
    occ = np.zeros((6, 2, 2), dtype=bool)
    occ[1, 0, 0] = True
    sp = rounds_space(occ, np.zeros(3), 1.0)
    way = np.array([[0.5, 0.5, 0.5], [2.5, 0.5, 0.5], [4.5, 0.5, 0.5]])
    want = [way[[0, 2]].tolist()]
    assert [w.tolist() for w in batched_shortcut([way], lambda p0, p1: S.shortcut_test(sp, p0, p1, False))] == want
    for backend in ["python"] + (["native"] if native.shortcut_rounds_c() is not None else []):
        assert [w.tolist() for w in S.shortcut_pass(sp, [way], False, backend=backend)] == want
