"""grid_polytope: exact segment-cube closest points against a float64 brute force, the surface mask against its
definition, and grid polytopes against an LP (no occupied cube meets the polytope) and dense sampling (every point
of the polytope lies in a free voxel)."""
from __future__ import annotations

import itertools

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings, strategies as st
from scipy.optimize import linprog

from cinenerf_ns.planner.corridor import corridor_options
from cinenerf_ns.planner.corridor.grid_polytope import (
    VoxelObstacles,
    grid_polytope_planes,
    segment_box_closest,
    surface_voxels,
)
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.geometry.voxel_traversal import segments_in_free_voxels

SETTINGS = dict(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
coord = st.floats(-4.0, 4.0, allow_nan=False, allow_infinity=False)
point = st.tuples(coord, coord, coord).map(np.array)


def brute_segment_cube_distance(u0, u1, v) -> float:
    """Reference: min over t of dist(u0 + t d, cube [v, v + 1]) in float64: a dense grid of t, then golden-section
    refinement around the best sample (the distance is convex in t)."""
    d = u1 - u0

    def f(t):
        q = u0 + np.multiply.outer(t, d)
        return np.linalg.norm(q - np.clip(q, v, v + 1.0), axis=-1)

    t = np.linspace(0.0, 1.0, 4001)
    k = int(np.argmin(f(t)))
    lo, hi = t[max(k - 1, 0)], t[min(k + 1, len(t) - 1)]
    g = (5 ** 0.5 - 1) / 2
    for _ in range(80):
        a, b = hi - g * (hi - lo), lo + g * (hi - lo)
        if f(np.array(a)) <= f(np.array(b)):
            hi = b
        else:
            lo = a
    return float(min(f(np.array(0.5 * (lo + hi))), f(t).min()))


@settings(**SETTINGS)
@given(point, point, st.lists(st.tuples(*[st.integers(-4, 3)] * 3), min_size=1, max_size=6),
       st.sampled_from(["free", "axis", "point"]))
def test_segment_box_closest_is_exact(u0, u1, cubes, kind):
    if kind == "axis":  # segment parallel to an axis (d_a = 0 on two axes): divisions by zero in the breakpoints
        u1 = u0.copy()
        u1[0] += 2.5
    elif kind == "point":
        u1 = u0.copy()
    v = np.array(cubes, dtype=np.float64)
    q, p, dist = segment_box_closest(u0, u1, v)
    for k in range(len(v)):
        ref = brute_segment_cube_distance(u0, u1, v[k])
        assert dist[k] <= ref + 1e-12  # never farther than the true minimum
        assert dist[k] >= ref - 1e-9  # and it is the minimum
        # q on the segment, p in the cube, dist = |q - p|
        assert np.all(p[k] >= v[k] - 1e-12) and np.all(p[k] <= v[k] + 1 + 1e-12)
        # q on the segment: |q - u0| + |q - u1| = |u1 - u0|
        assert np.linalg.norm(q[k] - u0) + np.linalg.norm(q[k] - u1) <= np.linalg.norm(u1 - u0) + 1e-9
        assert abs(np.linalg.norm(q[k] - p[k]) - dist[k]) < 1e-12


def test_surface_voxels_match_definition():
    rng = np.random.default_rng(3)
    occ = rng.random((7, 6, 5)) < 0.55
    sur = surface_voxels(occ)
    for i, j, k in itertools.product(*map(range, occ.shape)):
        nb = occ[max(i - 1, 0):i + 2, max(j - 1, 0):j + 2, max(k - 1, 0):k + 2]
        assert sur[i, j, k] == (occ[i, j, k] and bool((~nb).any()))


def _max_slack_in_cube(A, b, v) -> float:
    """max s such that A x + s <= b for some x in the closed cube [v, v + 1] (LP; < 0: the cube misses the
    polytope by at least -s in every face's direction)."""
    r = linprog(np.r_[0.0, 0.0, 0.0, -1.0], A_ub=np.c_[A, np.ones(len(b))], b_ub=b,
                bounds=[(v[i], v[i] + 1) for i in range(3)] + [(None, None)], method="highs")
    assert r.status == 0
    return -float(r.fun)


def _random_case(seed: int, fill: float, shape=(10, 9, 8)):
    rng = np.random.default_rng(seed)
    occ = rng.random(shape) < fill
    free = np.argwhere(~occ)
    if len(free) < 2:
        return None
    a = free[rng.integers(len(free))] + rng.random(3)
    c = free[rng.integers(len(free))] + rng.random(3)
    if rng.random() < 0.3:  # short segments inside one voxel / to a neighbour
        c = a + rng.normal(size=3) * 0.7
    return occ, a, c, rng.uniform(0.3, 3.0)


def _extent(A, b, axis, sgn) -> float:
    """max (sgn = 1) or min (sgn = -1) of x[axis] over A x <= b (LP)."""
    cobj = np.zeros(3)
    cobj[axis] = -sgn
    r = linprog(cobj, A_ub=A, b_ub=b, bounds=[(None, None)] * 3, method="highs")
    assert r.status == 0
    return float(r.x[axis])


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10_000), st.sampled_from([0.1, 0.25, 0.4]), st.sampled_from(["python", "auto"]))
def test_grid_polytope_holds_the_segment_and_meets_no_occupied_voxel(seed, fill, backend):
    """Both the Python construction and (auto) the compiled one (native/gridpoly.c), which must give the same
    planes."""
    case = _random_case(seed, fill)
    if case is None:
        return
    occ, a, c, margin_box = case
    if not segments_in_free_voxels(occ, np.zeros(3), 1.0, a[None], c[None])[0]:
        return  # callers only ask for segments the voxel walk proves to lie in free voxels
    planes = grid_polytope_planes(surface_voxels(occ), a, c, np.minimum(a, c) - margin_box,
                                  np.maximum(a, c) + margin_box, 1e-9, backend=backend)
    ref = grid_polytope_planes(surface_voxels(occ), a, c, np.minimum(a, c) - margin_box,
                               np.maximum(a, c) + margin_box, 1e-9, backend="python")
    assert (planes is None) == (ref is None)
    if planes is not None:
        assert planes[0].shape == ref[0].shape
        np.testing.assert_allclose(planes[0], ref[0], atol=1e-12)
        np.testing.assert_allclose(planes[1], ref[1], atol=1e-12)
    if planes is None:  # allowed only when the segment comes within the margin of a surface cube
        _, _, dist = segment_box_closest(a, c, np.argwhere(surface_voxels(occ)).astype(float))
        assert dist.min() <= 1e-9
        return
    A, b = planes
    assert np.allclose(np.linalg.norm(A, axis=1), 1.0)
    assert (A @ a <= b).all() and (A @ c <= b).all()
    # every occupied voxel of the grid (interior ones too) misses the polytope by the margin: max slack < -0.5e-9. The
    # slack is at most b_i - min over the cube of A_i x for any one face i, so a face with that bound below -0.5e-9
    # (by 1e-12: its float64 rounding is ~1e-15) proves it exactly; the LP decides the cubes no single face clears.
    vox = np.argwhere(occ).astype(np.float64)
    face_bound = b - (vox @ A.T + np.minimum(A, 0.0).sum(1))  # [V, F]: b_i - min_{x in [v, v+1]} A_i x
    for v in vox[~(face_bound < -0.5e-9 - 1e-12).any(1)]:
        assert _max_slack_in_cube(A, b, v) < -0.5e-9
    for axis in range(3):  # and the polytope stays inside the grid
        assert _extent(A, b, axis, -1) >= -1e-9
        assert _extent(A, b, axis, 1) <= occ.shape[axis] + 1e-9


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10_000))
def test_points_of_grid_polytopes_lie_in_free_voxels(seed):
    """Brute force: dense random points of the polytope (rejection in its box) are all in free voxels."""
    case = _random_case(seed, 0.3)
    if case is None:
        return
    occ, a, c, m = case
    if not segments_in_free_voxels(occ, np.zeros(3), 1.0, a[None], c[None])[0]:
        return
    planes = grid_polytope_planes(surface_voxels(occ), a, c, np.minimum(a, c) - m, np.maximum(a, c) + m, 1e-9)
    assert planes is not None  # a segment in free voxels always gets one (up to the 1e-9 margin)
    A, b = planes
    rng = np.random.default_rng(seed)
    lo, hi = np.maximum(np.minimum(a, c) - m, 0), np.minimum(np.maximum(a, c) + m, occ.shape)
    x = rng.uniform(lo, hi, (20000, 3))
    x = x[(x @ A.T <= b).all(1)]
    x = np.concatenate([x, a[None], c[None], 0.5 * (a + c)[None]])
    ijk = np.floor(x).astype(int)
    assert ((ijk >= 0) & (ijk < occ.shape)).all()
    assert not occ[ijk[:, 0], ijk[:, 1], ijk[:, 2]].any()


def test_surface_needs_26_neighbours():
    """A diagonal free step next to an occupied voxel that touches the free region only along an edge: the
    polytope must also keep out of that voxel (a 6-neighbour surface would miss it)."""
    occ = np.ones((5, 5, 3), dtype=bool)
    occ[1:4, 1:4, :] = False  # a free 3x3 hole through z
    occ[2, 2, :] = True  # a pillar in the middle: its free neighbours touch it on faces
    occ[3, 3, :] = True  # an occupied corner voxel: touches free voxel (2, 3) on a face, (2, 2) is occupied
    a = np.array([1.2, 3.5, 1.5])
    c = np.array([1.5, 1.2, 1.5])
    assert segments_in_free_voxels(occ, np.zeros(3), 1.0, a[None], c[None])[0]
    A, b = grid_polytope_planes(surface_voxels(occ), a, c, np.zeros(3), np.array([5.0, 5.0, 3.0]), 1e-9)
    for v in np.argwhere(occ):
        assert _max_slack_in_cube(A, b, v) < 0


def test_voxel_obstacles_world_units_and_refusals():
    occ = np.zeros((8, 8, 8), dtype=bool)
    occ[4, :, :] = True  # a wall at x in [4, 5] voxels
    lo, vs = np.array([-1.0, 2.0, 0.5]), 0.25
    vo = VoxelObstacles.from_occupied(occ, lo, vs)
    a = lo + vs * np.array([1.5, 2.0, 2.0])
    c = lo + vs * np.array([3.0, 6.0, 5.0])
    P = vo.polytope(a, c, box_margin=0.5)
    assert P is not None and P.A.dtype == torch.float64
    assert bool(P.contains(torch.as_tensor(a))) and bool(P.contains(torch.as_tensor(c)))
    # world points just short of the wall are inside or not, but nothing at the wall's voxel is
    wall_x = lo[0] + 4 * vs
    ys = np.linspace(lo[1], lo[1] + 8 * vs, 30)
    zs = np.linspace(lo[2], lo[2] + 8 * vs, 30)
    pts = np.array([[wall_x + dx, y, z] for dx in (0.0, 0.1 * vs, 0.9 * vs) for y in ys for z in zs])
    assert not bool(P.contains(torch.as_tensor(pts)).any())
    # a segment through the wall: no grid polytope (the caller builds an exact one)
    assert vo.polytope(a, lo + vs * np.array([6.0, 2.0, 2.0]), box_margin=0.5) is None
    # box planes clipped to the grid: the polytope never leaves the grid
    far = vo.polytope(a, c, box_margin=100.0)
    hi = lo + vs * 8
    for axis in range(3):
        assert _extent(far.A.numpy(), far.b.numpy(), axis, -1) >= lo[axis] - 1e-9
        assert _extent(far.A.numpy(), far.b.numpy(), axis, 1) <= hi[axis] + 1e-9


@pytest.mark.parametrize("seed", [0, 1])
def test_grid_polytopes_of_a_planned_shot_are_safe_for_the_ellipsoids(seed):
    """End to end on a procedural room: the corridor's grid polytopes (and the goal's reused polytope) keep every
    sampled camera centre at non-negative exact clearance; with grid_polytopes=False none is prebuilt."""
    from cinenerf_ns.planner.geometry.distance import clearance
    from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
    from cinenerf_ns.planner.scene.procedural import procedural_room
    from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig

    room = procedural_room(6000, seed=seed)
    sc = EllipsoidScene.from_splat(room.means, room.quats, room.log_scales, room.opacity_logits)
    pl = Planner(sc, PlannerConfig(grid_resolution=40, grid_polytopes=True))  # 'auto' is off for voxels this coarse
    prep = pl.prepare()
    objs = room.objects
    shots = [pl.plan(objs[i].center, objs[(i + 1) % len(objs)].center, seed=seed * 10 + i)[0] for i in range(3)]
    assert sum(sh.corridor.n_grid_segments for sh in shots) > 0
    rng = np.random.default_rng(seed)
    for sh in shots:
        for P in sh.corridor.polytopes:
            A, b = P.to_numpy()
            lo, hi = -b[3:6], b[0:3]  # the first six rows are the box (+x, +y, +z, -x, -y, -z)
            x = rng.uniform(lo, hi, (4000, 3))
            x = x[(x @ A.T <= b).all(1)][:400]
            if len(x):
                c = clearance(torch.as_tensor(x), sc, prep.index)
                assert float(c.min()) >= 0.0
    pl0 = Planner(sc, PlannerConfig(grid_resolution=40, grid_polytopes=False))
    sh0 = pl0.plan(objs[0].center, objs[1].center, seed=seed * 10)[0]
    assert sh0.corridor.n_grid_segments == 0


def test_known_polytope_is_reused_only_where_it_holds_the_segment():
    from cinenerf_ns.planner.corridor.polytope import safe_polytope
    from cinenerf_ns.planner.corridor.safe_corridor import build_corridor
    from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
    from cinenerf_ns.planner.scene.procedural import procedural_room
    from cinenerf_ns.planner.scene.spatial_index import GridIndex

    room = procedural_room(3000, seed=2)
    sc = EllipsoidScene.from_splat(room.means, room.quats, room.log_scales, room.opacity_logits)
    idx = GridIndex.build(sc)
    c = torch.tensor([0.0, 0.0, 1.2], dtype=torch.float64)  # mid-air in the room
    P = safe_polytope(c[None], sc, idx, c - 0.2, c + 0.2)
    inside = c + torch.tensor([0.05, 0.0, 0.0], dtype=torch.float64)
    far = c + torch.tensor([0.0, 0.6, 0.0], dtype=torch.float64)
    cor = build_corridor(torch.stack([far, c, inside]), sc, idx, box_margin=0.1, known=[P])
    assert cor.n_known_segments == 1 and cor.polytopes[1] is P
    assert cor.polytopes[0] is not P  # far -> c leaves P: built on its own
    cor0 = build_corridor(torch.stack([far, c, inside]), sc, idx, box_margin=0.1)
    assert cor0.n_known_segments == 0


def test_auto_resolves_by_voxel_size_against_the_camera_radius():
    from cinenerf_ns.planner.errors import InvalidInputError
    from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
    from cinenerf_ns.planner.scene.procedural import procedural_room
    from cinenerf_ns.planner.shots.planner import GRID_POLYTOPE_MAX_VOXEL, Planner, PlannerConfig

    room = procedural_room(3000, seed=0)
    sc = EllipsoidScene.from_splat(room.means, room.quats, room.log_scales, room.opacity_logits)
    for res in (24, 96):
        pl = Planner(sc, PlannerConfig(grid_resolution=res))
        vs = pl.prepare().grid.voxel_size
        assert corridor_options.use_grid_polytopes(pl.space) == (vs <= GRID_POLYTOPE_MAX_VOXEL * sc.camera_radius)
        assert ("grid" in corridor_options.corridor_kwargs(pl.space)) == corridor_options.use_grid_polytopes(pl.space)
    on, off = (Planner(sc, PlannerConfig(grid_resolution=r, grid_polytopes=g)) for r, g in ((24, True), (96, False)))
    assert corridor_options.use_grid_polytopes(on.space)
    assert not corridor_options.use_grid_polytopes(off.space)
    with pytest.raises(InvalidInputError):
        Planner(sc, PlannerConfig(grid_polytopes="yes"))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10_000), st.sampled_from([0.03, 0.1, 0.25]), st.sampled_from([1.5, 4.0, 8.0]))
def test_compiled_planes_equal_pythons_with_many_cubes(seed, fill, margin_box):
    """Boxes holding hundreds of surface cubes, where native/gridpoly.c groups the cubes in buckets of their lower
    bound and sorts a bucket only when its scan reaches it: the same cubes in the same order as the Python
    construction's full stable sort, so the same normals bit for bit (the offsets' dot products round in another order
    in C: ~1e-16)."""
    case = _random_case(seed, fill, shape=(26, 22, 20))
    if case is None:
        return
    occ, a, c, _ = case
    if not segments_in_free_voxels(occ, np.zeros(3), 1.0, a[None], c[None])[0]:
        return
    lo, hi = np.minimum(a, c) - margin_box, np.maximum(a, c) + margin_box
    got = grid_polytope_planes(surface_voxels(occ), a, c, lo, hi, 1e-9, backend="native")
    ref = grid_polytope_planes(surface_voxels(occ), a, c, lo, hi, 1e-9, backend="python")
    assert (got is None) == (ref is None)
    if got is not None:
        assert np.array_equal(got[0], ref[0])
        np.testing.assert_allclose(got[1], ref[1], rtol=0, atol=1e-12)


def test_ties_pick_the_same_cube_in_both_constructions():
    """Two walls at the same distance from a segment: every nearest cube has twins on the other wall and along the
    segment. The compiled construction must visit the cubes in the Python one's order (lower bound, then scan order;
    native/gridpoly.c sorts them itself) and so keep the same planes, ties included."""
    occ = np.zeros((12, 5, 5), dtype=bool)
    occ[:, 0, :] = True
    occ[:, 4, :] = True
    a, c = np.array([1.5, 2.5, 2.5]), np.array([10.5, 2.5, 2.5])
    for margin_box in (1.0, 2.5, 6.0):
        lo, hi = np.minimum(a, c) - margin_box, np.maximum(a, c) + margin_box
        got = grid_polytope_planes(surface_voxels(occ), a, c, lo, hi, 1e-9, backend="auto")
        ref = grid_polytope_planes(surface_voxels(occ), a, c, lo, hi, 1e-9, backend="python")
        assert got is not None and ref is not None
        assert np.array_equal(got[0], ref[0]) and np.array_equal(got[1], ref[1])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10_000), st.sampled_from([0.05, 0.2, 0.35]), st.sampled_from([0.1, 0.5, 2.0, 5.0]),
       st.booleans())
def test_one_compiled_call_gives_the_python_construction(seed, fill, box_margin, outside):
    """VoxelObstacles.polytope's compiled path (cn_grid_polytope_world: voxel walk, box, planes and world units in one
    call) against the Python construction (segments_in_free_voxels, grid_polytope_planes, numpy's conversion), None
    included: the same normals bit for bit, offsets within rounding of the conversion; segments that leave the grid
    (``outside``) give None on both; a pickled grid drops the compiled function it kept."""
    import pickle

    case = _random_case(seed, fill, shape=(14, 12, 10))
    if case is None:
        return
    occ, a, c, _ = case
    if outside:
        c = c + np.array([20.0, 0.0, 0.0])
    lo, vs = np.array([-0.3, 0.2, 1.0]), 0.25
    grid = VoxelObstacles.from_occupied(occ, lo, vs)
    if grid._compiled() is None:
        pytest.skip("no C compiler: the compiled grid kernels are not built")
    p, q = (grid.polytope(lo + a * vs, lo + c * vs, box_margin * vs, 1e-9, backend=b) for b in ("auto", "python"))
    assert (p is None) == (q is None)
    if p is not None:
        assert torch.equal(p.A, q.A) and torch.equal(p.seed, q.seed)
        np.testing.assert_allclose(p.b.numpy(), q.b.numpy(), rtol=0, atol=1e-12)
        # the segment itself satisfies every plane of the compiled polytope
        assert bool(p.contains(p.seed, tol=1e-12).all())
    assert "_compiled_args" not in pickle.loads(pickle.dumps(grid)).__dict__


@pytest.mark.parametrize("backend", ["auto", "python"])
def test_no_grid_polytope_inside_a_solid_block(backend):
    """A segment deep inside occupied voxels has no surface voxel in its box, yet it is not in free voxels: both paths
    must refuse it (the voxel walk decides, not the planes)."""
    occ = np.zeros((16, 16, 16), dtype=bool)
    occ[2:14, 2:14, 2:14] = True
    grid = VoxelObstacles.from_occupied(occ, np.zeros(3), 0.25)
    a, c = np.array([1.9, 2.0, 2.0]), np.array([2.1, 2.0, 2.0])  # voxels 7-8: surface voxels are 4+ voxels away
    assert grid.polytope(a, c, 0.3, 1e-9, backend=backend) is None


def test_a_full_output_buffer_is_retried_with_more_room(monkeypatch):
    """A polytope with more rows than the first buffer holds (FIRST_CAP made tiny) is built again with a larger one
    and equals the one built at once."""
    from cinenerf_ns.planner.corridor import grid_polytope as gp

    occ = np.zeros((12, 12, 12), dtype=bool)
    occ[[0, -1], :, :] = occ[:, [0, -1], :] = occ[:, :, [0, -1]] = True  # walls on every side: many planes
    grid = VoxelObstacles.from_occupied(occ, np.zeros(3), 0.25)
    a, c = np.array([1.1, 1.4, 1.5]), np.array([1.9, 1.6, 1.5])
    ref = grid.polytope(a, c, 2.0, 1e-9)
    assert ref is not None and ref.num_faces > 8
    monkeypatch.setattr(gp, "FIRST_CAP", 7)
    got = grid.polytope(a, c, 2.0, 1e-9)
    assert torch.equal(got.A, ref.A) and torch.equal(got.b, ref.b)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10_000), st.sampled_from([0.05, 0.2, 0.35]), st.integers(0, 6))
def test_grid_segments_free_is_the_python_walk(seed, fill, n):
    """VoxelObstacles.segments_free (the compiled walk with the grid's kept pointers, both ends behind one pointer)
    answers as the Python voxel walk, for 0 to 6 segments, some leaving the grid; ends of different shapes are
    refused."""
    rng = np.random.default_rng(seed)
    occ = rng.random((14, 12, 10)) < fill
    lo, vs = np.array([-0.3, 0.2, 1.0]), 0.25
    grid = VoxelObstacles.from_occupied(occ, lo, vs)
    if grid._compiled() is None:
        pytest.skip("no C compiler: the compiled grid kernels are not built")
    a = lo + rng.uniform(-1, 15, (n, 3)) * vs
    b = a + rng.normal(size=(n, 3)) * rng.choice([0.1, 1.0, 5.0]) * vs
    got = grid.segments_free(a, b)
    ref = segments_in_free_voxels(occ, lo, vs, a, b, backend="python")
    assert got.dtype == bool and np.array_equal(got, ref)
    if n:
        with pytest.raises(InvalidInputError, match="one shape"):
            grid.segments_free(a, b[:-1])


def test_grid_polytope_refuses_an_unknown_backend():
    grid = VoxelObstacles.from_occupied(np.zeros((4, 4, 4), dtype=bool), np.zeros(3), 0.25)
    with pytest.raises(InvalidInputError, match="backend"):
        grid.polytope(np.full(3, 0.3), np.full(3, 0.6), 0.1, backend="fast")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 10_000), st.sampled_from([0.05, 0.2, 0.35]), st.integers(2, 9), st.sampled_from([7, 256]))
def test_a_polylines_grid_polytopes_in_one_call_are_the_per_segment_ones(seed, fill, k, first_cap):
    """VoxelObstacles.polytopes (one cn_grid_polytopes_world call for a polyline's segments, rows in one buffer, some
    segments skipped) gives each segment what polytope() gives it alone, bit for bit (None included, skipped segments
    None), and its Python path (polytope()'s Python construction per segment) the same None pattern and normals with
    offsets within rounding; a tiny first buffer (FIRST_CAP 7) is retried with more room."""
    from cinenerf_ns.planner.corridor import grid_polytope as gp

    rng = np.random.default_rng(seed)
    occ = rng.random((14, 12, 10)) < fill
    lo, vs = np.array([-0.3, 0.2, 1.0]), 0.25
    grid = VoxelObstacles.from_occupied(occ, lo, vs)
    if grid._compiled() is None or grid._compiled_many() is None:
        pytest.skip("no C compiler: the compiled grid kernels are not built")
    w = lo + rng.uniform(-0.5, 14.5, (k, 3)) * vs * rng.choice([0.3, 1.0])
    skip = rng.random(k - 1) < 0.25
    old = gp.FIRST_CAP
    gp.FIRST_CAP = first_cap
    try:
        got = grid.polytopes(w, 0.3, 1e-9, skip=skip)
    finally:
        gp.FIRST_CAP = old
    py = grid.polytopes(w, 0.3, 1e-9, skip=skip, backend="python")
    assert len(got) == len(py) == k - 1
    for i in range(k - 1):
        ref = None if skip[i] else grid.polytope(w[i], w[i + 1], 0.3, 1e-9)
        assert (got[i] is None) == (ref is None) == (py[i] is None)
        if ref is not None:
            assert torch.equal(got[i].A, ref.A) and torch.equal(got[i].b, ref.b) and torch.equal(got[i].seed, ref.seed)
            assert torch.equal(py[i].A, ref.A)
            np.testing.assert_allclose(py[i].b.numpy(), ref.b.numpy(), rtol=0, atol=1e-12)
    with pytest.raises(InvalidInputError, match="backend"):
        grid.polytopes(w, 0.3, backend="fast")
