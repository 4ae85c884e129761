"""corridor_trim.py: merged corridor pieces stay inside polytopes they came with; implied region faces are dropped
only where the feasible set stays the same. References: float64 brute force (per-face loops, sampled points)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch
from hypothesis import HealthCheck, given, settings, strategies as st

from cinenerf_ns.planner.corridor.corridor_trim import (
    MERGE_ROOM,
    REGION_A,
    TABLE_MIN_SEGMENTS,
    merged_pieces,
    region_rows,
    slack_table,
)
from cinenerf_ns.planner.corridor.polytope import Polytope
from cinenerf_ns.planner.corridor.safe_corridor import Corridor, build_corridor

sys.path.insert(0, str(Path(__file__).parents[1]))
sys.path.insert(0, str(Path(__file__).parent))
from _corridor_refs import clearance, random_scene  # noqa: E402
from test_polytope import vertices_and_interior  # noqa: E402
from test_safe_corridor import free_polyline  # noqa: E402

SETTINGS = dict(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def box_polytope(lo, hi, extra: int, rng) -> Polytope:
    """The box [lo, hi] (its six axis rows, in a random order) with ``extra`` random planes through points outside a
    shrunk copy of it (rows unit norm)."""
    a = [*np.eye(3), *-np.eye(3)]
    b = [*hi, *-np.asarray(lo)]
    c = 0.5 * (np.asarray(lo) + hi)
    for _ in range(extra):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        a.append(n)
        b.append(float(n @ c) + rng.uniform(0.05, 0.6))
    order = rng.permutation(len(a))
    return Polytope(torch.as_tensor(np.asarray(a)[order]), torch.as_tensor(np.asarray(b)[order]),
                    torch.as_tensor(c[None]))


def holds_ref(planes, x, tol) -> bool:
    """Per-face float64 loop: x at least tol inside every face."""
    a, b = planes
    return all(b[f] - a[f] @ x >= tol * np.linalg.norm(a[f]) for f in range(len(b)))


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), m=st.integers(1, 9))
def test_merged_pieces_keep_each_segment_in_its_polytope(seed, m):
    """Random chains of boxes: every merged piece's polytope is one of the input's, holds both its ends with
    MERGE_ROOM (brute force) and so the segment (sampled points: convexity); the waypoints are a subsequence with the
    same ends; a merge happens exactly where the greedy rule says (reference loop)."""
    rng = np.random.default_rng(seed)
    pts = np.cumsum(rng.normal(scale=0.2, size=(m + 1, 3)), axis=0)
    pieces, planes = [], []
    for k in range(m):
        lo = np.minimum(pts[k], pts[k + 1]) - rng.uniform(0.01, 0.4, 3)
        hi = np.maximum(pts[k], pts[k + 1]) + rng.uniform(0.01, 0.4, 3)
        p = box_polytope(lo, hi, int(rng.integers(0, 4)), rng)
        a, b = p.to_numpy()
        if not (holds_ref((a, b), pts[k], 0.0) and holds_ref((a, b), pts[k + 1], 0.0)):  # a plane cut an end off
            p = box_polytope(lo, hi, 0, rng)
            a, b = p.to_numpy()
        pieces.append((p, pts[k], pts[k + 1]))
        planes.append((a, b))
    out, out_planes = merged_pieces(pieces, planes, MERGE_ROOM)
    # reference: the same greedy rule with per-face loops
    ref = [(0, 0, 1)]  # (polytope index, start waypoint, end waypoint)
    for k in range(1, m):
        pi, s, _ = ref[-1]
        if holds_ref(planes[pi], pts[k + 1], MERGE_ROOM):
            ref[-1] = (pi, s, k + 1)
        elif holds_ref(planes[k], pts[s], MERGE_ROOM):
            ref[-1] = (k, s, k + 1)
        else:
            ref.append((k, k, k + 1))
    assert [next(i for i, q in enumerate(pieces) if q[0] is p) for p, _, _ in out] == [pi for pi, _, _ in ref]
    for (p, p0, p1), (pi, s, e) in zip(out, ref):
        np.testing.assert_array_equal(p0, pts[s])
        np.testing.assert_array_equal(p1, pts[e])
    for (p, p0, p1), pl in zip(out, out_planes):
        assert pl[0] is planes[next(i for i, q in enumerate(pieces) if q[0] is p)][0]
        assert holds_ref(pl, p0, 0.0) and holds_ref(pl, p1, 0.0)
        seg = p0 + np.linspace(0, 1, 33)[:, None] * (p1 - p0)
        assert (seg @ pl[0].T <= pl[1] + 1e-12).all()
    np.testing.assert_array_equal(out[0][1], pts[0])
    np.testing.assert_array_equal(out[-1][2], pts[-1])
    for q0, q1 in zip(out[:-1], out[1:]):
        np.testing.assert_array_equal(q0[2], q1[1])


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), m=st.integers(1, 6), shift=st.floats(-0.3, 0.3))
def test_region_rows_drop_only_implied_faces(seed, m, shift):
    """A region face is dropped only where the polytope has the same axis row with an offset inside the region's
    (per-face float64 loop); the constraints with and without the dropped faces accept the same sampled points."""
    rng = np.random.default_rng(seed)
    lo, hi = np.array([-1.0, -1.0, -0.5]), np.array([1.0, 1.2, 0.8])
    planes = []
    for _ in range(m):
        c = rng.uniform(lo, hi)
        p = box_polytope(c - rng.uniform(0.05, 0.8, 3) + shift, c + rng.uniform(0.05, 0.8, 3) + shift,
                         int(rng.integers(0, 4)), rng)
        a, b = p.to_numpy()
        if rng.uniform() < 0.3:  # a scaled axis row does not count (only exact +-e_i rows do)
            a = a.copy()
            a[0] *= 2.0
        planes.append((a, b))
    need = region_rows(planes, lo, hi)
    box_b = np.concatenate([hi, -lo])
    for (a, b), nd in zip(planes, need):
        for f in range(6):
            implied = any((a[r] == REGION_A[f]).all() and b[r] <= box_b[f] for r in range(len(b)))
            assert nd[f] == (not implied)
        x = rng.uniform(lo - 1.0, hi + 1.0, size=(400, 3))
        full = (x @ a.T <= b).all(1) & (x @ REGION_A.T <= box_b).all(1)
        trimmed = (x @ a.T <= b).all(1) & (x @ REGION_A[nd].T <= box_b[nd]).all(1)
        assert np.array_equal(full, trimmed)


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 10), k=st.integers(2, 12))
def test_merged_corridor_is_safe_and_covers_the_path(seed, n, k):
    """build_corridor(merge=True) on random scenes: its waypoints are a subsequence of the unmerged corridor's (same
    ends), each of its polytopes is one of that corridor's (the same planes) and holds its segment, and the exact
    clearance of points inside each polytope is >= 0 (float64 reference distance)."""
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, n, amax=0.25, camera_radius=0.03)
    wps = free_polyline(rng, scene, k, step=0.15)
    if wps is None:
        return
    plain = build_corridor(wps, scene, None, box_margin=0.15, min_overlap=0.0)
    cor = build_corridor(wps, scene, None, box_margin=0.15, min_overlap=0.0, merge=True)
    assert len(cor) + cor.n_merged == len(plain)
    pw, cw = plain.waypoints.numpy(), cor.waypoints.numpy()
    idx = [next(i for i in range(len(pw)) if np.array_equal(pw[i], w)) for w in cw]
    assert idx == sorted(idx) and idx[0] == 0 and idx[-1] == len(pw) - 1
    for m, P in enumerate(cor.polytopes):
        assert any(torch.equal(P.A, Q.A) and torch.equal(P.b, Q.b) for Q in plain.polytopes)
        assert bool(P.contains(cor.waypoints[m:m + 2]).all())
        pts = vertices_and_interior(P, rng, 10)
        assert clearance(pts, scene).min() >= -1e-9


def test_corridor_constraints_skip_implied_region_faces():
    """From TABLE_MIN_SEGMENTS polytopes up, a polytope inside the region keeps its own rows only and one that sticks
    out gets the region's face there; shorter corridors get all six faces on every polytope (cheaper than the test)."""
    rng = np.random.default_rng(0)
    inside = box_polytope([-0.5, -0.5, -0.5], [0.5, 0.5, 0.5], 2, rng)
    out = box_polytope([-0.5, -0.5, -0.5], [1.5, 0.5, 0.5], 0, rng)
    region = (np.full(3, -1.0), np.full(3, 1.0))
    m = TABLE_MIN_SEGMENTS
    cor = Corridor([out] + [inside] * (m - 1), torch.zeros(m + 1, 3, dtype=torch.float64), region=region)
    (a1, b1), (a0, b0), *_ = cor.constraints()
    np.testing.assert_array_equal(a0, inside.A.numpy())
    assert a1.shape[0] == out.A.shape[0] + 1
    np.testing.assert_array_equal(a1[-1], [1.0, 0.0, 0.0])
    assert b1[-1] == 1.0
    short = Corridor([out, inside], torch.zeros(3, 3, dtype=torch.float64), region=region).constraints()
    assert [a.shape[0] for a, _ in short] == [out.A.shape[0] + 6, inside.A.shape[0] + 6]


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), m=st.integers(1, 7), k=st.integers(1, 9))
def test_slack_table_is_the_per_face_distance(seed, m, k):
    """slack_table[i, j] = min over polytope i's faces of (b - a . w_j) / |a| (float64 loop), rows of any norm."""
    rng = np.random.default_rng(seed)
    planes = [(rng.normal(size=(f, 3)) * rng.uniform(0.2, 3.0, (f, 1)), rng.normal(size=f))
              for f in rng.integers(1, 12, m)]
    w = rng.normal(size=(k, 3))
    got = slack_table(planes, w)
    for i, (a, b) in enumerate(planes):
        for j in range(k):
            ref = min((b[f] - sum(a[f, c] * w[j, c] for c in range(3))) / np.sqrt(sum(a[f, c] ** 2 for c in range(3)))
                      for f in range(len(b)))
            assert abs(got[i, j] - ref) <= 1e-12 * (1 + abs(ref) + np.abs(w[j]).sum() * 10)
    assert slack_table(planes + [(np.zeros((0, 3)), np.zeros(0))], w) is None


def test_junction_bounds_match_the_per_junction_slacks():
    """_assemble's junction bounds from the slack table: the per-junction min of both polytopes' slacks at the shared
    waypoint (unit rows: the formula it replaced), with and without merging."""
    import cinenerf_ns.planner.corridor.safe_corridor as corridor_mod

    rng = np.random.default_rng(3)
    pts = np.cumsum(rng.normal(scale=0.2, size=(7, 3)), axis=0)
    pieces = [(box_polytope(np.minimum(pts[i], pts[i + 1]) - 0.05, np.maximum(pts[i], pts[i + 1]) + 0.3, 2, rng),
               pts[i], pts[i + 1]) for i in range(6)]
    pieces = [(p, a, c) for p, a, c in pieces if bool(p.contains(np.stack([a, c])).all())] or pieces[:1]
    for merge in (False, True):
        got, lbs = corridor_mod._host_junctions(list(pieces), [p.host_arrays() for p, _, _ in pieces], merge, {})
        for m in range(len(got) - 1):
            x = got[m][2]
            ref = min((got[m][0].b.numpy() - got[m][0].A.numpy() @ x).min(),
                      (got[m + 1][0].b.numpy() - got[m + 1][0].A.numpy() @ x).min())
            assert abs(lbs[m] - ref) <= 1e-12
