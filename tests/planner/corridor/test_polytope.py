"""Safe polytopes (cinenerf_ns/planner/corridor/polytope.py) against float64 exact references."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings, strategies as st
from scipy.spatial import HalfspaceIntersection

from cinenerf_ns.planner.corridor.polytope import (
    Polytope,
    PolytopeOptions,
    SeedNotFreeError,
    chebyshev_center,
    safe_polytope,
)
from cinenerf_ns.planner.corridor.polytope_planes import argmax_k, k_sphere
from cinenerf_ns.planner.errors import InvalidInputError

sys.path.insert(0, str(Path(__file__).parents[1]))  # our float64 references live beside the tests
from _corridor_refs import (  # noqa: E402
    clearance,
    make_scene,
    min_distance,
    point_ellipsoid_distance,
    polytope_min_distance,
    random_rotations,
    random_scene,
)

SETTINGS = dict(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


class BoxIndex:
    """Brute-force index with the GridIndex.query_box contract (ids whose AABB meets the box)."""

    def __init__(self, scene):
        self.lo, self.hi = scene.aabb()
        self.calls = 0

    def query_box(self, lo, hi):
        self.calls += 1
        return torch.nonzero(((self.lo <= hi) & (self.hi >= lo)).all(-1)).squeeze(-1)


def vertices_and_interior(P: Polytope, rng: np.random.Generator, n_interior: int = 60) -> np.ndarray:
    A, b = P.to_numpy()
    c, rad = chebyshev_center(A, b)
    assert rad > 0
    hs = HalfspaceIntersection(np.hstack([A, -b[:, None]]), c)
    V = hs.intersections  # [Nv, 3]
    w = rng.dirichlet(np.ones(len(V)) * 0.3, size=n_interior)  # convex combinations, spread out
    return np.vstack([V, w @ V, c[None]])


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 12), r=st.sampled_from([0.0, 0.03, 0.1]),
       normal=st.sampled_from(["auto", "prop2", "closest", "mahalanobis"]), n_seeds=st.sampled_from([1, 2]))
def test_polytope_contains_seeds_and_is_safe(seed, n, r, normal, n_seeds):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, n, camera_radius=r)
    seeds = rng.uniform(-0.8, 0.8, size=(n_seeds, 3))
    if n_seeds == 2:
        seeds[1] = seeds[0] + rng.normal(size=3) * 0.15
    box_lo, box_hi = seeds.min(0) - 0.4, seeds.max(0) + 0.4
    try:
        P = safe_polytope(seeds, scene, None, box_lo, box_hi, normal=normal)
    except SeedNotFreeError:
        # only allowed when some seed really is close: for a point seed the exact closest-point
        # normal ("auto"/"closest") loses nothing, so the seed must be within r of an ellipsoid.
        if n_seeds == 1 and normal in ("auto", "closest"):
            assert clearance(seeds, scene).min() < 1e-6
        return
    assert bool(P.contains(seeds).all())
    assert P.num_faces <= 6 + n
    # every vertex / interior point: exact distance >= r to every ellipsoid
    pts = vertices_and_interior(P, rng)
    assert (pts >= box_lo - 1e-9).all() and (pts <= box_hi + 1e-9).all()
    d = point_ellipsoid_distance(pts, scene)
    assert d.min() >= r - 1e-9, d.min()


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 10), prune=st.booleans())
def test_whole_polytope_is_safe_socp(seed, n, prune):
    """Exact min distance over the WHOLE polytope (SOCP) to each ellipsoid >= r, pruned or not."""
    rng = np.random.default_rng(seed)
    r = 0.05
    scene = random_scene(rng, n, camera_radius=r)
    x0 = rng.uniform(-0.8, 0.8, size=(1, 3))
    try:
        P = safe_polytope(x0, scene, None, x0[0] - 0.5, x0[0] + 0.5, prune=prune)
    except SeedNotFreeError:
        return
    A, b = P.to_numpy()
    dmin = polytope_min_distance(A, b, scene)
    assert dmin.min() >= r - 1e-6, dmin


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 15))
def test_pruning_keeps_a_superset_and_safety(seed, n):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, n, camera_radius=0.03)
    x0 = rng.uniform(-0.8, 0.8, size=(1, 3))
    try:
        full = safe_polytope(x0, scene, None, x0[0] - 0.5, x0[0] + 0.5, prune=False)
    except SeedNotFreeError:
        return
    pruned = safe_polytope(x0, scene, None, x0[0] - 0.5, x0[0] + 0.5, prune=True)
    assert pruned.num_faces <= full.num_faces
    # the pruned polytope contains the full one (its planes are a subset)
    pts = vertices_and_interior(full, rng, 20)
    assert bool(pruned.contains(pts, tol=1e-9).all())
    # and is itself safe
    pts = vertices_and_interior(pruned, rng, 40)
    assert clearance(pts, scene).min() >= -1e-9


def test_pruning_removes_hidden_obstacles():
    """A wall of 100 small spheres on the plane x = 0.5 seen from x = 0: few planes survive."""
    yy, zz = np.meshgrid(np.linspace(-0.45, 0.45, 10), np.linspace(-0.45, 0.45, 10))
    wall = np.stack([np.full(100, 0.5), yy.ravel(), zz.ravel()], -1)
    behind = wall + np.array([0.2, 0.0, 0.0])  # a second wall hidden behind the first
    means = np.vstack([wall, behind])
    scene = make_scene(means, np.tile(np.eye(3), (200, 1, 1)), np.full((200, 3), 0.06), 0.03)
    full = safe_polytope([[0.0, 0, 0]], scene, None, [-1, -1, -1], [1, 1, 1], prune=False)
    pruned = safe_polytope([[0.0, 0, 0]], scene, None, [-1, -1, -1], [1, 1, 1], prune=True)
    assert full.num_faces == 206
    assert pruned.num_faces <= 6 + 30, pruned.num_faces
    assert not set(pruned.ellipsoid_ids.tolist()) & set(range(100, 200))  # the hidden wall needs no plane


def test_index_is_used_and_matches_no_index():
    rng = np.random.default_rng(3)
    scene = random_scene(rng, 60, lo=-2, hi=2, amax=0.2, camera_radius=0.03)
    idx = BoxIndex(scene)
    for _ in range(10):
        x0 = rng.uniform(-1.5, 1.5, size=(1, 3))
        try:
            P0 = safe_polytope(x0, scene, None, x0[0] - 0.4, x0[0] + 0.4)
        except SeedNotFreeError:
            with pytest.raises(SeedNotFreeError):
                safe_polytope(x0, scene, idx, x0[0] - 0.4, x0[0] + 0.4)
            continue
        P1 = safe_polytope(x0, scene, idx, x0[0] - 0.4, x0[0] + 0.4)
        # the index may hand back a different superset of candidates: same guarantees, similar size
        assert bool(P1.contains(x0).all())
        assert clearance(vertices_and_interior(P1, rng, 20), scene).min() >= -1e-9
        assert abs(P0.num_faces - P1.num_faces) <= 3
    assert idx.calls == 10


def test_seed_in_collision_raises_with_ids():
    scene = make_scene([[0.0, 0, 0]], np.eye(3)[None], [[0.2, 0.1, 0.1]], 0.05)
    with pytest.raises(SeedNotFreeError) as e:
        safe_polytope([[0.22, 0, 0]], scene, None, [-1, -1, -1], [1, 1, 1])
    assert e.value.ellipsoid_ids.tolist() == [0]
    # a segment passing through the ellipsoid, endpoints free
    with pytest.raises(SeedNotFreeError):
        safe_polytope([[-0.5, 0.0, 0], [0.5, 0.0, 0.0]], scene, None, [-1, -1, -1], [1, 1, 1])
    # without the requirement the polytope comes back and excludes the seed
    P = safe_polytope([[0.22, 0, 0]], scene, None, [-1, -1, -1], [1, 1, 1], require_seed_inside=False)
    assert not bool(P.contains(torch.tensor([[0.22, 0, 0]])).any())


def test_segment_tangent_to_elongated_ellipsoid():
    """A segment running along a long thin ellipsoid at distance > r: the Mahalanobis normal at the
    segment's metric-closest point keeps the whole segment (the point normal would cut it)."""
    scene = make_scene([[0.0, 0, 0]], np.eye(3)[None], [[0.5, 0.02, 0.02]], 0.03)
    seg = np.array([[-0.45, 0.07, 0.0], [0.45, 0.07, 0.0]])
    P = safe_polytope(seg, scene, None, seg.min(0) - 0.2, seg.max(0) + 0.2)
    assert bool(P.contains(seg).all())
    ts = np.linspace(0, 1, 50)[:, None]
    assert clearance(seg[0] + ts * (seg[1] - seg[0]), scene).min() > 0


def test_bad_input():
    scene = make_scene([[0.0, 0, 0]], np.eye(3)[None], [[0.2, 0.1, 0.1]], 0.05)
    with pytest.raises(InvalidInputError):
        safe_polytope([[np.nan, 0, 0]], scene, None, [-1, -1, -1], [1, 1, 1])
    with pytest.raises(InvalidInputError):
        safe_polytope([[0.5, 0, 0]], scene, None, [1, 1, 1], [-1, -1, -1])
    with pytest.raises(InvalidInputError):
        safe_polytope([[5.0, 0, 0]], scene, None, [-1, -1, -1], [1, 1, 1])


def test_options_object_and_keyword_fields_agree():
    """PolytopeOptions and the keyword shorthand give the same polytope; keywords override the options' fields;
    unknown names and unknown normal rules are refused."""
    rng = np.random.default_rng(4)
    scene = random_scene(rng, 40, camera_radius=0.03)
    x0, lo, hi = [[0.0, 0, 0]], [-0.6, -0.6, -0.6], [0.6, 0.6, 0.6]
    kw = dict(margin=1e-3, normal="mahalanobis", chunk=4, require_seed_inside=False)
    a = safe_polytope(x0, scene, None, lo, hi, **kw)
    b = safe_polytope(x0, scene, None, lo, hi, options=PolytopeOptions(**kw))
    c = safe_polytope(x0, scene, None, lo, hi, options=PolytopeOptions(**dict(kw, margin=0.5)), margin=1e-3)
    for P in (b, c):
        assert torch.equal(a.A, P.A) and torch.equal(a.b, P.b) and torch.equal(a.ellipsoid_ids, P.ellipsoid_ids)
    with pytest.raises(TypeError):
        safe_polytope(x0, scene, None, lo, hi, margn=1e-3)
    with pytest.raises(InvalidInputError):
        PolytopeOptions(normal="nearest")
    with pytest.raises(InvalidInputError):
        safe_polytope(x0, scene, None, lo, hi, normal="nearest")


def test_empty_neighbourhood_gives_the_box():
    scene = make_scene([[5.0, 5, 5]], np.eye(3)[None], [[0.2, 0.1, 0.1]], 0.05)
    P = safe_polytope([[0.0, 0, 0]], scene, None, [-1, -1, -1], [1, 1, 1])
    assert P.num_faces == 6
    assert bool(P.contains(torch.tensor([[0.99, -0.99, 0.5]])).all())


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), r=st.sampled_from([0.0, 0.01, 0.1]))
def test_argmax_k_matches_dense_grid(seed, r):
    rng = np.random.default_rng(seed)
    w = torch.as_tensor(rng.normal(size=(8, 3)))
    lam = torch.as_tensor(rng.uniform(0.001, 0.3, size=(8, 3)))
    s = argmax_k((w**2).numpy(), lam.numpy(), r * r)
    grid = np.linspace(1e-6, 1 - 1e-6, 20001)
    dense = k_sphere((w**2).numpy(), lam.numpy(), r * r, np.broadcast_to(grid, (8, grid.size))).max(-1)
    got = k_sphere((w**2).numpy(), lam.numpy(), r * r, s[:, None])[:, 0]
    assert np.all(got >= dense * (1 - 1e-3) - 1e-12)  # golden section to ~1e-3 in s (normal only)


def test_float32_scene_and_device_roundtrip():
    rng = np.random.default_rng(0)
    scene64 = random_scene(rng, 20, camera_radius=0.03)
    scene32 = scene64.to(dtype=torch.float32)
    x0 = np.array([[0.9, 0.9, 0.9]])
    try:
        P = safe_polytope(x0, scene32, None, x0[0] - 0.3, x0[0] + 0.3)
    except SeedNotFreeError:
        pytest.skip("seed happens to be in collision")
    assert P.A.dtype == torch.float64
    pts = vertices_and_interior(P, rng, 20)
    assert clearance(pts, scene64).min() >= -1e-6  # float32 storage of the scene: rounding only


@pytest.mark.gpu
def test_cuda_matches_cpu():
    rng = np.random.default_rng(1)
    scene = random_scene(rng, 50, lo=-2, hi=2, amax=0.2, camera_radius=0.03)
    x0 = np.array([[0.1, 0.2, 0.3]])
    P0 = safe_polytope(x0, scene, None, x0[0] - 0.5, x0[0] + 0.5)
    P1 = safe_polytope(x0, scene.to("cuda"), None, x0[0] - 0.5, x0[0] + 0.5)
    assert P1.A.is_cuda
    assert torch.allclose(P0.A, P1.A.cpu(), atol=1e-9) and torch.allclose(P0.b, P1.b.cpu(), atol=1e-9)


def test_reference_distance_cross_check():
    """The vectorised bisection reference agrees with scalar brentq (and with spheres in closed form)."""
    from _corridor_refs import point_ellipsoid_distance_brentq

    rng = np.random.default_rng(11)
    scene = random_scene(rng, 7, amin=0.001, amax=0.5)
    pts = rng.uniform(-1.5, 1.5, size=(40, 3))
    assert np.allclose(point_ellipsoid_distance(pts, scene), point_ellipsoid_distance_brentq(pts, scene), atol=1e-10)
    sph = make_scene([[0.1, 0.2, 0.3]], random_rotations(rng, 1), [[0.4] * 3], 0.0)
    d = np.linalg.norm(pts - [0.1, 0.2, 0.3], axis=1) - 0.4
    got = point_ellipsoid_distance(pts, sph)[:, 0]
    assert np.allclose(got[d > 0], d[d > 0], atol=1e-12) and (got[d <= 0] == -1).all()



def test_min_distance_is_the_dense_minimum_bit_for_bit():
    """min_distance (the references' clearance; it bisects only the pairs its ball bounds cannot rule out) gives the
    dense reference's row minimum bit for bit: points inside, near and far, flat ellipsoids and float32 rotations
    (orthonormal only to ~1e-7)."""
    for seed in range(6):
        rng = np.random.default_rng(seed)
        scene = random_scene(rng, 100, amin=(0.001, 0.02)[seed % 2], amax=(0.12, 0.5)[seed % 2], camera_radius=0.03)
        if seed % 3 == 1:
            scene = scene.to(dtype=torch.float32).to(dtype=torch.float64)
        if seed % 3 == 2:
            radii = scene.radii.clone()
            radii[:, 2] *= 1e-3
            scene = make_scene(scene.means, scene.rotations, radii, 0.03)
        pts = rng.uniform(-1.3, 1.3, (100, 3))
        pts[:60] = scene.means.numpy()[:60] + rng.normal(size=(60, 3)) * 0.05
        pts[:10] = scene.means.numpy()[:10]  # centres: inside
        want = point_ellipsoid_distance(pts, scene).min(1)
        assert (want == -1).any() and (want > 0).any()
        assert np.array_equal(min_distance(pts, scene), want)
        assert np.array_equal(clearance(pts, scene), want - 0.03)

@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 10), use_index=st.booleans())
def test_oriented_box_polytope(seed, n, use_index):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, n, amax=0.25, camera_radius=0.03)
    R = random_rotations(rng, 1)[0]
    x0 = rng.uniform(-0.8, 0.8, size=(1, 3))
    xb = x0 @ R  # seed in box coordinates
    lo, hi = xb[0] - rng.uniform(0.1, 0.5, 3), xb[0] + rng.uniform(0.1, 0.5, 3)
    try:
        P = safe_polytope(x0, scene, BoxIndex(scene) if use_index else None, lo, hi, box_rotation=R)
    except SeedNotFreeError:
        assert clearance(x0, scene)[0] < 1e-6
        return
    assert bool(P.contains(x0).all())
    pts = vertices_and_interior(P, rng, 30)
    pb = pts @ R
    assert (pb >= lo - 1e-9).all() and (pb <= hi + 1e-9).all()
    assert clearance(pts, scene).min() >= -1e-9
    with pytest.raises(InvalidInputError):
        safe_polytope(x0, scene, None, lo, hi, box_rotation=2 * R)
    bad = R.copy()
    bad[0, 0] = np.nan
    with pytest.raises(InvalidInputError, match="orthonormal"):
        safe_polytope(x0, scene, None, lo, hi, box_rotation=bad)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), flat=st.sampled_from([1e-3, 0.02, 1.0]), compiled=st.booleans())
def test_free_segment_near_one_flat_ellipsoid_always_gets_a_polytope(seed, flat, compiled):
    """Completeness vs brute force: a segment whose exact clearance to a single (possibly very flat)
    ellipsoid is positive must be contained in a safe polytope (a separating tangent plane exists);
    planes chosen at the metric-closest point alone used to cut such grazing segments. compiled: through
    native/polytope.c (with a grid index), where it loads."""
    rng = np.random.default_rng(seed)
    radii = rng.uniform(0.05, 0.3, size=(1, 3))
    radii[0, 2] *= flat
    scene = make_scene(np.zeros((1, 3)), random_rotations(rng, 1), radii, camera_radius=0.03)
    p0 = rng.uniform(-0.5, 0.5, 3)
    p1 = p0 + rng.normal(size=3) * rng.uniform(0.05, 0.8)
    t = np.linspace(0, 1, 801)
    pts = p0 + t[:, None] * (p1 - p0)
    c = clearance(pts, scene)
    spacing = np.linalg.norm(p1 - p0) / 800
    if c.min() - spacing / 2 <= 1e-4:  # not provably free by the brute-force Lipschitz bound
        return
    seg = torch.as_tensor(np.stack([p0, p1]))
    index = None
    if compiled:
        from cinenerf_ns.planner.native import safe_polytope_c
        from cinenerf_ns.planner.scene.spatial_index import GridIndex

        if safe_polytope_c() is None:
            return
        index = GridIndex.build(scene)
    P = safe_polytope(seg, scene, index, seg.min(0).values - 0.1, seg.max(0).values + 0.1,
                      backend="native" if compiled else "python")
    assert bool(P.contains(seg).all())
    assert np.all(polytope_min_distance(*P.to_numpy(), scene) >= scene.camera_radius - 1e-7)


def test_host_arrays_are_views_kept_while_the_planes_stay_and_not_pickled():
    """Polytope.host_arrays: numpy views of the CPU planes (bit for bit A and b), kept on the polytope, made again when
    A or b is replaced, None off the CPU; from_numpy's polytope starts with them; pickling leaves them out."""
    import pickle

    A, b = np.random.default_rng(0).normal(size=(7, 3)), np.arange(7.0)
    p = Polytope(torch.from_numpy(A.copy()), torch.from_numpy(b.copy()), torch.zeros(1, 3))
    a1, b1 = p.host_arrays()
    assert np.array_equal(a1, A) and np.array_equal(b1, b) and np.shares_memory(a1, p.A.numpy())
    assert p.host_arrays()[0] is a1  # kept
    p.A = torch.from_numpy(2 * A)
    assert np.array_equal(p.host_arrays()[0], 2 * A)  # replaced planes: new views
    q = Polytope.from_numpy(A, b, torch.zeros(1, 3))
    assert q.host_arrays()[0] is A and np.shares_memory(q.A.numpy(), A) and q.A.dtype == torch.float64
    r = pickle.loads(pickle.dumps(q))
    assert "_host" not in r.__getstate__() and "_host" not in pickle.loads(pickle.dumps(p)).__dict__
    assert torch.equal(r.A, q.A) and np.array_equal(r.host_arrays()[1], b)
    off = Polytope(torch.zeros(1, 3, device="meta"), torch.zeros(1, device="meta"), torch.zeros(1, 3))
    assert off.host_arrays() is None
