"""voxel_traversal: the voxels a segment passes through, against an exact rational-arithmetic walk, and the grid
proof of segments against brute-force dense sampling."""
from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from cinenerf_ns.planner.geometry.voxel_traversal import EPS, segment_voxels, segments_in_free_voxels

SETTINGS = dict(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def exact_voxels(u0, u1) -> set:
    """Reference: every voxel whose closed cube holds a positive-length piece of the segment, in exact
    rationals (the floats are exact rationals): crossings t = (k - u0) / d, the voxel of each piece's midpoint."""
    a = [Fraction(float(x)) for x in u0]
    b = [Fraction(float(x)) for x in u1]
    d = [y - x for x, y in zip(a, b)]
    ts = {Fraction(0), Fraction(1)}
    for ax in range(3):
        if d[ax] == 0:
            continue
        lo, hi = min(a[ax], b[ax]), max(a[ax], b[ax])
        for k in range(math.floor(lo) + 1, math.ceil(hi)):
            ts.add((k - a[ax]) / d[ax])
    ts = sorted(ts)
    out = set()
    for t0, t1 in zip(ts[:-1], ts[1:]):
        tm = (t0 + t1) / 2
        out.add(tuple(math.floor(a[i] + tm * d[i]) for i in range(3)))
    if all(x == 0 for x in d):  # a point: its voxel
        out = {tuple(math.floor(x) for x in a)}
    return out


coord = st.floats(-6.0, 6.0, allow_nan=False, allow_infinity=False)
snapped = st.one_of(coord, st.integers(-6, 6).map(float), st.integers(-12, 12).map(lambda k: k / 2))  # faces, edges


@settings(**SETTINGS)
@given(st.lists(st.tuples(st.tuples(snapped, snapped, snapped), st.tuples(snapped, snapped, snapped)), min_size=1,
                max_size=6))
def test_pieces_are_the_exact_voxels(segs):
    u0 = np.array([s[0] for s in segs])
    u1 = np.array([s[1] for s in segs])
    owner, vox = segment_voxels(u0, u1)
    for i in range(len(segs)):
        got = {tuple(v) for v in vox[owner == i].tolist()}
        ref = exact_voxels(u0[i], u1[i])
        # every voxel holding a positive-length piece is found, however short the piece; the extra voxels are
        # within EPS of the segment (conservative)
        assert ref <= got, (u0[i], u1[i], ref - got)
        for v in got - ref:
            assert touches(u0[i], u1[i], v, slack=2 * EPS), (u0[i], u1[i], v)


def touches(u0, u1, v, slack: float = 0.0) -> bool:
    """Does the closed segment meet the closed cube v grown by ``slack`` (exact: clip the segment to the slabs)?"""
    t0, t1 = Fraction(0), Fraction(1)
    for ax in range(3):
        a, b = Fraction(float(u0[ax])), Fraction(float(u1[ax]))
        d = b - a
        lo, hi = Fraction(int(v[ax])) - Fraction(slack), Fraction(int(v[ax]) + 1) + Fraction(slack)
        if d == 0:
            if not (lo <= a <= hi):
                return False
            continue
        ta, tb = (lo - a) / d, (hi - a) / d
        t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
    return t0 <= t1


_OFFSETS = np.array([(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)])


def points_in_free_voxels(p, occ, tol=1e-9):
    """[M]: does each point of p [M, 3] lie in a free (in-grid, unoccupied) closed voxel grown by tol? Only the 27
    voxels around floor(p) can hold it."""
    base = np.floor(p).astype(int)
    v = base[:, None, :] + _OFFSETS[None]  # [M, 27, 3]
    inb = ((v >= 0) & (v < occ.shape)).all(-1)
    vc = np.where(inb[..., None], v, 0)
    free = inb & ~occ[vc[..., 0], vc[..., 1], vc[..., 2]]
    within = ((p[:, None, :] >= v - tol) & (p[:, None, :] <= v + 1 + tol)).all(-1)
    return (free & within).any(-1)


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), density=st.floats(0.0, 0.4), snap=st.booleans(),
       backend=st.sampled_from(["python", "auto"]))
def test_grid_proof_is_never_optimistic_and_tight(seed, density, snap, backend):
    """Both the Python walk and (auto) the compiled one (native/gridpoly.c) where it loads."""
    rng = np.random.default_rng(seed)
    occ = rng.random((7, 6, 5)) < density
    lo, vs = np.array([-0.3, 0.2, 1.0]), 0.25
    P = 12
    u0 = rng.uniform(-0.5, [7.5, 6.5, 5.5], (P, 3))
    u1 = rng.uniform(-0.5, [7.5, 6.5, 5.5], (P, 3))
    if snap:  # segments along faces / through edges and corners
        u0 = np.round(u0 * 2) / 2
        u1 = np.round(u1 * 2) / 2
    p0, p1 = lo + vs * u0, lo + vs * u1
    got = segments_in_free_voxels(occ, lo, vs, p0, p1, backend=backend)
    assert (got == segments_in_free_voxels(occ, lo, vs, p0, p1, backend="python")).all()  # the same probes
    for i in range(P):
        ref_vox = exact_voxels(u0[i], u1[i])
        free_ref = all(all(0 <= v[k] < occ.shape[k] for k in range(3)) and not occ[v] for v in ref_vox)
        if got[i]:
            # never optimistic: dense samples all lie in free closed voxels
            t = np.linspace(0, 1, 257)
            ok = points_in_free_voxels(u0[i] + t[:, None] * (u1[i] - u0[i]), occ)
            assert ok.all(), (i, t[~ok])
            assert free_ref
        elif not snap:
            # tight on generic segments (no edge / corner crossings): refused only when a voxel it passes is not free
            assert not free_ref


def test_straight_lines_and_points():
    occ = np.zeros((4, 4, 4), bool)
    occ[2, 2, 2] = True
    lo, vs = np.zeros(3), 1.0
    # through the occupied voxel's centre, along an axis, diagonal, a point
    p0 = np.array([[0.5, 2.5, 2.5], [0.5, 0.5, 0.5], [0.5, 0.5, 0.5], [1.5, 1.5, 1.5], [2.5, 2.5, 2.5],
                   [0.5, 0.5, 0.5]])
    p1 = np.array([[3.5, 2.5, 2.5], [3.5, 0.5, 0.5], [3.5, 3.5, 3.5], [1.5, 1.5, 1.5], [2.5, 2.5, 2.5],
                   [4.5, 0.5, 0.5]])
    assert segments_in_free_voxels(occ, lo, vs, p0, p1).tolist() == [False, True, False, True, False, False]
    # along the occupied voxel's edge: every point also lies in a free closed voxel, but the walk refuses what
    # passes within EPS of an occupied voxel (conservative); 0.01 away it is proven
    assert segments_in_free_voxels(occ, lo, vs, [[2.0, 2.0, 0.5]], [[2.0, 2.0, 3.5]]).tolist() == [False]
    assert segments_in_free_voxels(occ, lo, vs, [[1.99, 1.99, 0.5]], [[1.99, 1.99, 3.5]]).tolist() == [True]
    assert segments_in_free_voxels(occ, lo, vs, np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), density=st.floats(0.0, 0.05), snap=st.booleans())
def test_compiled_walk_is_the_python_walk_on_long_segments(seed, density, snap):
    """native/gridpoly.c merges the three axes' crossings in order and stops at the first occupied probe: the same
    answers as the Python walk (all probes, sorted) on a sparse 40^3 grid with segments crossing many voxels, axis
    aligned ones, zero-length ones and ones leaving the grid."""
    from cinenerf_ns.planner.native import segments_free_c

    if segments_free_c() is None:
        pytest.skip("the compiled voxel walk did not load")
    rng = np.random.default_rng(seed)
    occ = rng.random((40, 40, 40)) < density
    lo, vs = rng.uniform(-1, 1, 3), 0.1
    u0 = rng.uniform(-2, 42, (64, 3))
    u1 = rng.uniform(-2, 42, (64, 3))
    u1[:8, 1:] = u0[:8, 1:]  # along x
    u1[8:12] = u0[8:12]  # points
    if snap:
        u0, u1 = np.round(u0 * 2) / 2, np.round(u1 * 2) / 2
    p0, p1 = lo + vs * u0, lo + vs * u1
    got = segments_in_free_voxels(occ, lo, vs, p0, p1, backend="native")
    assert np.array_equal(got, segments_in_free_voxels(occ, lo, vs, p0, p1, backend="python"))
