"""Corridors (cinenerf_ns/planner/corridor/safe_corridor.py): coverage, safety, overlap, splitting."""
from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings, strategies as st

import cinenerf_ns.planner.corridor.safe_corridor as corridor_mod
from cinenerf_ns.planner.corridor.corridor_trim import TABLE_MIN_SEGMENTS
from cinenerf_ns.planner.corridor.polytope import SeedNotFreeError, chebyshev_center, safe_polytope
from cinenerf_ns.planner.corridor.safe_corridor import Corridor, CorridorError, build_corridor, build_corridors
from cinenerf_ns.planner.errors import InvalidInputError

sys.path.insert(0, str(Path(__file__).parents[1]))
from _corridor_refs import clearance, make_scene, random_scene  # noqa: E402
from test_polytope import vertices_and_interior  # noqa: E402


def free_polyline(rng, scene, k, step=0.4, tries=200):
    """Random polyline of k points whose segments keep exact clearance > 0.01 everywhere."""
    pts = []
    for _ in range(tries):
        p = rng.uniform(-0.9, 0.9, 3)
        if clearance(p[None], scene)[0] > 0.005:
            pts = [p]
            break
    if not pts:
        return None
    while len(pts) < k:
        for _ in range(tries):
            q = pts[-1] + rng.normal(size=3) * step
            # clearance is 1-Lipschitz: samples <= 0.02 apart all > 0.02 => the whole segment > 0.01
            ts = np.linspace(0, 1, int(np.ceil(np.linalg.norm(q - pts[-1]) / 0.02)) + 1)[:, None]
            if clearance(pts[-1] + ts * (q - pts[-1]), scene).min() > 0.02:
                pts.append(q)
                break
        else:
            return None
    return np.asarray(pts)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 10), k=st.integers(2, 5),
       box=st.sampled_from(["aabb", "oriented"]))
def test_corridor_covers_path_and_is_safe(seed, n, k, box):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, n, amax=0.25, camera_radius=0.03)
    wps = free_polyline(rng, scene, k)
    if wps is None:
        return
    # every segment keeps clearance > 0.01 (Lipschitz-dense check), so exact-offset planes plus at most 4
    # midpoint splits must cover it: a CorridorError here is a failure
    cor = build_corridor(wps, scene, None, box_margin=0.15, min_overlap=0.0, exact_overlap=True, box=box)
    assert isinstance(cor, Corridor)
    assert len(cor) == cor.waypoints.shape[0] - 1 >= k - 1
    assert torch.allclose(cor.waypoints[0], torch.as_tensor(wps[0]))
    assert torch.allclose(cor.waypoints[-1], torch.as_tensor(wps[-1]))
    for m, P in enumerate(cor.polytopes):
        seg = cor.waypoints[m:m + 2]
        assert bool(P.contains(seg).all())
        pts = vertices_and_interior(P, rng, 15)
        assert clearance(pts, scene).min() >= -1e-9
    # overlaps: positive, and the reported value is the LP's Chebyshev radius (exact_overlap=True)
    assert cor.overlap_radius.shape == (len(cor) - 1,)
    for m in range(len(cor) - 1):
        A = torch.cat([cor.polytopes[m].A, cor.polytopes[m + 1].A])
        b = torch.cat([cor.polytopes[m].b, cor.polytopes[m + 1].b])
        _, rad = chebyshev_center(A, b)
        assert rad > 0
        assert float(cor.overlap_radius[m]) == pytest.approx(rad, rel=1e-6, abs=1e-9)
    As = cor.constraints()
    assert len(As) == len(cor) and all(a.shape[1] == 3 and a.shape[0] == bb.shape[0] for a, bb in As)


def test_overlap_lower_bound_is_below_lp():
    rng = np.random.default_rng(5)
    scene = random_scene(rng, 8, amax=0.2, camera_radius=0.03)
    wps = free_polyline(rng, scene, 5)
    fast = build_corridor(wps, scene, None, 0.15, min_overlap=0.0)
    exact = build_corridor(wps, scene, None, 0.15, min_overlap=0.0, exact_overlap=True)
    assert (fast.overlap_radius <= exact.overlap_radius + 1e-9).all()
    assert (fast.overlap_radius > 0).all()


def test_thin_slot_reports_thin_joint():
    """Two walls leave a 4 mm slab of camera centres: the junction has little room."""
    r, half_gap = 0.03, 0.002
    walls = [[0.0, r + half_gap + 0.05, 0.0], [0.0, -(r + half_gap + 0.05), 0.0]]
    scene = make_scene(walls, np.tile(np.eye(3), (2, 1, 1)), [[1.0, 0.05, 1.0]] * 2, r)
    wps = np.array([[-0.5, 0.0, 0.0], [0.0, 0.001, 0.0], [0.5, 0.0, 0.0]])
    with pytest.warns(UserWarning, match="little room"):
        cor = build_corridor(wps, scene, None, 0.1, min_overlap=0.01)
    assert cor.thin_joints == [0]
    assert 0 < float(cor.overlap_radius[0]) < 0.0025
    pts = np.vstack([vertices_and_interior(P, np.random.default_rng(0), 20) for P in cor.polytopes])
    assert clearance(pts, scene).min() >= -1e-9


def test_segment_through_obstacle_raises_corridor_error():
    scene = make_scene([[0.0, 0, 0]], np.eye(3)[None], [[0.2, 0.2, 0.2]], 0.03)
    with pytest.raises(CorridorError, match="segment 0"):
        build_corridor([[-0.5, 0.0, 0.0], [0.5, 0.0, 0.0]], scene, None, 0.1, max_split_depth=3)


def test_split_logic_with_a_length_limited_polytope(monkeypatch):
    """Splitting: a fake polytope builder refusing segments longer than 0.3 forces midpoint splits."""
    calls = []

    def fake(seg, scene, index, lo, hi, **kw):
        calls.append(float(np.linalg.norm(seg[1] - seg[0])))
        if calls[-1] > 0.3:
            raise SeedNotFreeError("too long", min_slack=-1.0)
        return safe_polytope(seg, scene, index, lo, hi, **kw)

    monkeypatch.setattr(corridor_mod, "aabb_polytope", fake)
    scene = make_scene([[5.0, 5, 5]], np.eye(3)[None], [[0.2, 0.2, 0.2]], 0.03)
    cor = build_corridor([[0.0, 0, 0], [1.0, 0, 0], [1.0, 0.2, 0]], scene, None, 0.1)
    # [0,0,0]->[1,0,0] (length 1) needs 2 levels: 4 pieces of 0.25; the short one none
    assert len(cor) == 5 and cor.n_splits == 3
    xs = cor.waypoints[:, 0].tolist()
    assert xs == pytest.approx([0.0, 0.25, 0.5, 0.75, 1.0, 1.0])
    with pytest.raises(CorridorError):
        build_corridor([[0.0, 0, 0], [1.0, 0, 0]], scene, None, 0.1, max_split_depth=1)


def test_bad_waypoints():
    scene = make_scene([[5.0, 5, 5]], np.eye(3)[None], [[0.2, 0.2, 0.2]], 0.03)
    with pytest.raises(InvalidInputError):
        build_corridor([[0.0, 0, 0]], scene)
    with pytest.raises(InvalidInputError):
        build_corridor([[0.0, 0, 0], [np.nan, 0, 0]], scene)
    with pytest.raises(InvalidInputError):
        build_corridor([[0.0, 0, 0], [0.0, 0, 0]], scene)
    with pytest.raises(InvalidInputError):
        build_corridor([[0.0, 0, 0], [1.0, 0, 0]], scene, box="sphere")
    with pytest.raises(InvalidInputError, match="of numbers"):
        build_corridor([[0.0, 0, 0], [1.0, 0]], scene)  # ragged
    for bad in (0.0, -0.1, np.nan, np.inf):  # box_margin: a finite length, or the boxes are not boxes
        with pytest.raises(InvalidInputError, match="box_margin must be a finite length > 0"):
            build_corridor([[0.0, 0, 0], [1.0, 0, 0]], scene, box_margin=bad)
    for bad in (0.0, -0.1, np.nan, np.inf):  # split_long: a length, or bisection would run to its depth limit
        with pytest.raises(InvalidInputError, match="split_long"):
            build_corridor([[0.0, 0, 0], [1.0, 0, 0]], scene, split_long=bad)
        with pytest.raises(InvalidInputError, match="split_long"):
            build_corridors([[[0.0, 0, 0], [1.0, 0, 0]]], scene, split_long=bad)
    # duplicates are dropped
    cor = build_corridor([[0.0, 0, 0], [0.0, 0, 0], [0.5, 0, 0]], scene)
    assert len(cor) == 1


def test_oriented_boxes_follow_the_segment():
    scene = make_scene([[5.0, 5, 5]], np.eye(3)[None], [[0.2, 0.2, 0.2]], 0.03)
    wps = np.array([[0.0, 0, 0], [1.0, 1.0, 1.0]])
    cor = build_corridor(wps, scene, None, 0.1, box="oriented")
    P = cor.polytopes[0]
    V = vertices_and_interior(P, np.random.default_rng(0), 0)
    u = (wps[1] - wps[0]) / np.linalg.norm(wps[1] - wps[0])
    # every vertex within 0.1 * sqrt(2) of the segment's line and within the extended segment
    along = (V - wps[0]) @ u
    perp = np.linalg.norm((V - wps[0]) - along[:, None] * u, axis=1)
    assert along.min() >= -0.1 - 1e-9 and along.max() <= np.sqrt(3) + 0.1 + 1e-9
    assert perp.max() <= 0.1 * np.sqrt(2) + 1e-9


def test_build_corridors_equals_one_call_per_path():
    """build_corridors (one batched polytope computation for all paths) gives each path the corridor
    build_corridor gives it alone, and reports a path that cannot be covered as its CorridorError."""
    from cinenerf_ns.planner.corridor.safe_corridor import build_corridors

    scene, index, ways = _corridor_paths()
    for backend in ("batched", "cpu"):
        many = build_corridors(ways, scene, index, box_margin=0.1, backend=backend)
        for w, c in zip(ways, many):
            one = build_corridor(w, scene, index, box_margin=0.1, backend=backend)
            assert len(c) == len(one)
            for p, q in zip(c.polytopes, one.polytopes):
                assert torch.equal(p.A, q.A) and torch.equal(p.b, q.b)
            assert torch.equal(c.waypoints, one.waypoints)


def _corridor_paths(n_paths=5):
    """A cluttered random scene, its grid index, and a few free polylines through it."""
    from cinenerf_ns.planner.scene.spatial_index import GridIndex

    rng = np.random.default_rng(11)
    scene = random_scene(rng, 10, amax=0.25, camera_radius=0.03)
    ways = []
    while len(ways) < n_paths:
        w = free_polyline(rng, scene, 4)
        if w is not None:
            ways.append(w)
    return scene, GridIndex.build(scene), ways


def test_build_corridors_options_and_errors():
    """Unknown options and oriented boxes are refused; a blocked path comes back as its CorridorError while the
    others are built."""
    from cinenerf_ns.planner.corridor.safe_corridor import build_corridors

    scene, index, ways = _corridor_paths(2)
    with pytest.raises(InvalidInputError, match="unknown"):
        build_corridors(ways, scene, index, box_margn=0.1)
    with pytest.raises(InvalidInputError, match="aabb"):
        build_corridors(ways, scene, index, box="oriented")
    c = scene.means[0].double().numpy()
    blocked = np.stack([c - [0.01, 0, 0], c + [0.01, 0, 0]])  # through an ellipsoid's centre
    out = build_corridors([ways[0], blocked, ways[1]], scene, index, backend="batched")
    assert isinstance(out[0], Corridor) and isinstance(out[1], CorridorError) and isinstance(out[2], Corridor)


def _random_polytope_at(rng, wj, n_planes, tight):
    """Polytope of a box around wj [3] and n_planes random unit planes, ``tight`` of them through wj (slack 0), the
    others with slack in (0, 0.05): wj is inside, on faces of the tight ones."""
    from cinenerf_ns.planner.corridor.polytope import Polytope

    n = rng.normal(size=(n_planes, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    slack = np.where(np.arange(n_planes) < tight, 0.0, rng.uniform(1e-4, 0.05, n_planes))
    A = np.vstack([np.eye(3), -np.eye(3), n])
    b = np.concatenate([wj + 0.2, 0.2 - wj, n @ wj + slack])
    return Polytope(torch.as_tensor(A), torch.as_tensor(b), torch.as_tensor(wj[None]))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n0=st.integers(1, 12), n1=st.integers(1, 12), tight=st.integers(0, 3),
       min_overlap=st.sampled_from([1e-3, 1e-2, 0.05]))
def test_probed_overlap_is_a_lower_bound_of_the_lp(seed, n0, n1, tight, min_overlap):
    """Junctions on faces of either polytope (the case that needed the LP): the probes that spare it
    (_probed_overlap) never exceed the LP's Chebyshev radius of P0 ∩ P1 (float64 HiGHS reference), and _assemble's
    thin joints are the LP's."""
    rng = np.random.default_rng(seed)
    wj = rng.uniform(-1, 1, 3)
    w_prev, w_next = wj + rng.normal(size=3) * 0.1, wj + rng.normal(size=3) * 0.1
    p0 = _random_polytope_at(rng, wj, n0, min(tight, n0))
    p1 = _random_polytope_at(rng, wj, n1, min(tight, n1))
    _, rad = chebyshev_center(torch.cat([p0.A, p1.A]), torch.cat([p0.b, p1.b]))
    w = [torch.as_tensor(x) for x in (w_prev, wj, w_next)]
    probe = corridor_mod._probed_overlap(p0, p1, *w, min_overlap)
    assert probe <= rad + 1e-12
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        wn = [x.numpy() for x in w]
        cor = corridor_mod._assemble([(p0, wn[0], wn[1]), (p1, wn[1], wn[2])], {"splits": 0}, min_overlap, False,
                                     "cpu")
    assert float(cor.overlap_radius[0]) <= rad + 1e-12
    assert cor.thin_joints == ([0] if rad < min_overlap else [])


def test_probed_overlap_spares_the_lp_at_a_face(monkeypatch):
    """The junction lies on a face of one polytope (slack 0) but the two overlap widely: no LP is solved, and the
    radius reported is a positive lower bound of the LP's."""
    from cinenerf_ns.planner.corridor.polytope import Polytope

    box = lambda lo, hi: Polytope(torch.as_tensor(np.vstack([np.eye(3), -np.eye(3)])),  # noqa: E731
                                  torch.as_tensor(np.concatenate([hi, -np.asarray(lo)])), torch.zeros(1, 3))
    p0, p1 = box([-1.0, -0.5, -0.5], [0.0, 0.5, 0.5]), box([-0.5, -0.5, -0.5], [1.0, 0.5, 0.5])
    w = [np.array(x, dtype=np.float64) for x in ([-0.8, 0, 0], [0.0, 0, 0], [0.8, 0, 0])]
    calls = []
    monkeypatch.setattr(corridor_mod, "chebyshev_center", lambda A, b: calls.append(1) or chebyshev_center(A, b))
    cor = corridor_mod._assemble([(p0, w[0], w[1]), (p1, w[1], w[2])], {"splits": 0}, 1e-3, False, "cpu")
    assert calls == [] and cor.thin_joints == []
    assert 1e-3 <= float(cor.overlap_radius[0]) <= 0.25 + 1e-12  # the LP's radius: 0.25


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), m=st.integers(1, 8), region=st.booleans(),
       dtype=st.sampled_from([torch.float32, torch.float64]))
def test_constraints_match_per_polytope_conversion(seed, m, region, dtype):
    """Corridor.constraints gives the per-polytope Polytope.to_numpy (+ the region's six faces stacked below, np.vstack,
    but, from TABLE_MIN_SEGMENTS polytopes up, those one of its own exact axis rows implies: corridor_trim.region_rows)
    bit for bit, float64 whatever the polytopes' dtype."""
    from cinenerf_ns.planner.corridor.polytope import Polytope

    g = torch.Generator().manual_seed(seed)
    polys = [Polytope(torch.randn(f, 3, generator=g, dtype=dtype), torch.randn(f, generator=g, dtype=dtype),
                      torch.zeros(1, 3, dtype=dtype)) for f in torch.randint(1, 20, (m,), generator=g).tolist()]
    box = (np.array([-1.0, -2.0, -3.0]), np.array([1.0, 2.5, 3.5])) if region else None
    cor = Corridor(polys, torch.zeros(m + 1, 3, dtype=torch.float64), region=box)
    ref = [p.to_numpy() for p in polys]
    if box is not None:
        box_a, box_b = np.vstack([np.eye(3), -np.eye(3)]), np.concatenate([box[1], -box[0]])
        keep = [[m < TABLE_MIN_SEGMENTS or not any((a[r] == box_a[f]).all() and b[r] <= box_b[f]
                                                   for r in range(len(b))) for f in range(6)] for a, b in ref]
        ref = [(np.vstack([a, box_a[k]]), np.concatenate([b, box_b[k]])) for (a, b), k in zip(ref, keep)]
    got = cor.constraints()
    assert len(got) == m
    for (a, b), (ra, rb) in zip(got, ref):
        assert a.dtype == ra.dtype == np.float64 and b.dtype == np.float64
        np.testing.assert_array_equal(a, ra)
        np.testing.assert_array_equal(b, rb)
