"""Goal points and start sampling (cinenerf_ns/planner/search/goal.py) against exact float64 references."""
from __future__ import annotations

import functools
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings, strategies as st

from cinenerf_ns.planner import native
from cinenerf_ns.planner.errors import GoalUnreachableError, InvalidInputError, StartInCollisionError
from cinenerf_ns.planner.geometry import clearance_queries
from cinenerf_ns.planner.search.goal import (
    NoFreeStartError,
    closest_safe_point,
    points_clearance_lower,
    sample_free_starts,
)

sys.path.insert(0, str(Path(__file__).parents[1]))
from _corridor_refs import clearance, make_scene, point_ellipsoid_distance, random_scene  # noqa: E402


@dataclass
class Grid:
    """Duck-typed occupancy grid (voxel i covers lo + [i, i+1) * voxel_size)."""

    occupied: np.ndarray
    lo: torch.Tensor
    voxel_size: float


def conservative_grid(scene, lo=-1.0, res=16, size=2.0) -> Grid:
    """Occupied iff the voxel centre's exact clearance < half the voxel diagonal (so every point of a
    free voxel has clearance >= 0: clearance is 1-Lipschitz)."""
    vs = size / res
    idx = np.stack(np.meshgrid(*[np.arange(res)] * 3, indexing="ij"), -1).reshape(-1, 3)
    centres = lo + (idx + 0.5) * vs
    radii = scene.radii.numpy()
    if np.allclose(radii, radii[:, :1]):  # spheres: exact distance in closed form (fast)
        d = np.linalg.norm(centres[:, None] - scene.means.numpy()[None], axis=-1) - radii[None, :, 0]
        cl = d.min(1) - scene.camera_radius
    else:
        cl = clearance(centres, scene)
    occ = cl < 0.5 * vs * np.sqrt(3)
    return Grid(occ.reshape(res, res, res), torch.full((3,), lo, dtype=torch.float64), vs)



def test_free_target_is_returned_unchanged():
    scene = make_scene([[0.0, 0, 0]], np.eye(3)[None], [[0.2, 0.2, 0.2]], 0.05)
    t = torch.tensor([0.5, 0.1, 0.0], dtype=torch.float64)
    assert torch.equal(closest_safe_point(t, scene), t)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), rad=st.floats(0.05, 0.5), r=st.sampled_from([0.0, 0.03, 0.1]))
def test_target_inside_sphere_projects_to_the_inflated_surface(seed, rad, r):
    """For one sphere, the closest safe point is c + (R + r) * dir: the Prop-2 polytope finds it."""
    rng = np.random.default_rng(seed)
    c = rng.uniform(-0.5, 0.5, 3)
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    target = c + d * rad * rng.uniform(0.05, 0.95)
    scene = make_scene([c], np.eye(3)[None], [[rad] * 3], r)
    x = closest_safe_point(target, scene, box_half=1.0).numpy()
    expect = c + d * (rad + r)
    assert np.linalg.norm(x - expect) < 1e-5
    assert clearance(x[None], scene)[0] >= 0


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 12))
def test_goal_is_safe_in_random_scenes(seed, n):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, n, amax=0.3, camera_radius=0.03)
    target = scene.means[rng.integers(n)].numpy() + rng.normal(size=3) * 0.05  # usually inside
    try:
        x = closest_safe_point(target, scene, None, None, box_half=0.4)
    except GoalUnreachableError:
        return  # polytope empty and no grid: allowed (the fallback is tested below)
    assert clearance(x.numpy()[None], scene)[0] >= -1e-9
    if clearance(target[None], scene)[0] >= 1e-6:
        assert np.allclose(x.numpy(), target)


def buried_scene(r=0.03):
    """Target at the origin inside two big overlapping spheres whose Prop-2 planes contradict."""
    return make_scene([[-0.1, 0, 0], [0.1, 0, 0]], np.tile(np.eye(3), (2, 1, 1)), [[0.3] * 3] * 2, r)


def test_buried_target_uses_the_free_voxel_fallback():
    scene = buried_scene()
    with pytest.raises(GoalUnreachableError, match="no occupancy grid"):
        closest_safe_point([0.0, 0, 0], scene, None, None)
    grid = conservative_grid(scene)
    x = closest_safe_point([0.0, 0, 0], scene, None, grid)
    assert clearance(x.numpy()[None], scene)[0] >= 0
    ijk = np.floor((x.numpy() - grid.lo.numpy()) / grid.voxel_size).astype(int)
    assert not grid.occupied[tuple(ijk)]
    # it is the nearest free voxel centre (the grid's free voxels hold no mean here)
    free = np.argwhere(~grid.occupied)
    centres = grid.lo.numpy() + (free + 0.5) * grid.voxel_size
    assert np.linalg.norm(x.numpy()) == pytest.approx(np.linalg.norm(centres, axis=1).min())


def test_proven_empty_polytope_skips_the_projection(monkeypatch):
    """A buried target's polytope proven empty (stop_when_empty) goes straight to the voxel fallback: the same goal
    as when the projection runs and answers None, without running it."""
    from cinenerf_ns.planner.corridor import polytope as poly_mod
    from cinenerf_ns.planner.native import safe_polytope_c
    from cinenerf_ns.planner.scene.spatial_index import GridIndex
    from cinenerf_ns.planner.search import goal as goal_mod

    if safe_polytope_c() is None:
        pytest.skip("no C compiler: the compiled polytope (which proves emptiness here) is not built")
    scene = buried_scene()
    index = GridIndex.build(scene)
    grid = conservative_grid(scene)
    built = []
    real_sp = goal_mod.aabb_polytope
    monkeypatch.setattr(goal_mod, "aabb_polytope", lambda *a, **k: built.append(real_sp(*a, **k)) or built[-1])
    calls = []
    real_proj = goal_mod.project_onto_polytope
    monkeypatch.setattr(goal_mod, "project_onto_polytope", lambda *a, **k: calls.append(1) or real_proj(*a, **k))
    x = closest_safe_point([0.0, 0, 0], scene, index, grid).numpy()
    assert built and built[-1].proven_empty and not calls
    monkeypatch.setattr(poly_mod.Polytope, "proven_empty", property(lambda self: False))
    y = closest_safe_point([0.0, 0, 0], scene, index, grid).numpy()
    assert calls and np.array_equal(x, y)


@settings(max_examples=200, deadline=None)
@given(d=st.lists(st.integers(0, 6), min_size=0, max_size=120), limit=st.integers(0, 130), chunk=st.integers(1, 20))
def test_nearest_chunks_are_the_stable_sort_in_chunks(d, limit, chunk):
    """_nearest_chunks (partition for the first chunk) against a full stable argsort cut into chunks; many ties."""
    from cinenerf_ns.planner.search.goal import _nearest_chunks

    d = np.asarray(d, dtype=np.float64) * 0.5
    centres = np.arange(3 * len(d), dtype=np.float64).reshape(-1, 3)  # row i holds 3i, 3i+1, 3i+2: identifies i
    order = np.argsort(d, kind="stable")[:min(limit, len(d))]
    want = [(k, centres[order[k:k + chunk]]) for k in range(0, len(order), chunk)]
    got = list(_nearest_chunks(centres, d, limit, chunk))
    assert [k for k, _ in got] == [k for k, _ in want]
    for (_, a), (_, b) in zip(got, want):
        assert np.array_equal(a.numpy(), b)


def test_fallback_skips_voxels_holding_a_mean_and_respects_reachable():
    # a tiny Gaussian (r = 0: it only blocks its own point) sits in the nearest free voxel
    scene = buried_scene(r=0.0)
    grid = conservative_grid(scene)
    x0 = closest_safe_point([0.0, 0, 0], scene, None, grid).numpy()
    tiny = make_scene(
        np.vstack([scene.means.numpy(), x0[None]]), np.tile(np.eye(3), (3, 1, 1)),
        np.vstack([scene.radii.numpy(), [[1e-4] * 3]]), 0.0,
    )
    x1 = closest_safe_point([0.0, 0, 0], tiny, None, grid).numpy()
    ijk0 = np.floor((x0 - grid.lo.numpy()) / grid.voxel_size)
    ijk1 = np.floor((x1 - grid.lo.numpy()) / grid.voxel_size)
    assert not np.array_equal(ijk0, ijk1)
    # only allow voxels with i >= 12: the answer moves there
    reach = np.zeros_like(grid.occupied)
    reach[12:] = True
    x2 = closest_safe_point([0.0, 0, 0], scene, None, grid, reachable=reach).numpy()
    assert np.floor((x2[0] + 1.0) / grid.voxel_size) >= 12
    # nothing reachable at all
    with pytest.raises(GoalUnreachableError):
        closest_safe_point([0.0, 0, 0], scene, None, grid, reachable=np.zeros_like(grid.occupied))


def test_goal_bad_input():
    scene = buried_scene()
    with pytest.raises(InvalidInputError):
        closest_safe_point([0.0, np.nan, 0], scene)
    with pytest.raises(InvalidInputError):
        closest_safe_point([0.0, 0], scene)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_points_clearance_lower_is_a_tight_lower_bound(seed):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, 6, amax=0.3, camera_radius=0.03)
    pts = np.vstack([rng.uniform(-1, 1, size=(10, 3)), scene.means.numpy() + rng.normal(size=(6, 3)) * 0.15])
    got = points_clearance_lower(torch.as_tensor(pts), scene).numpy()
    ref = clearance(pts, scene)
    # the sign is right: never "free" when the exact clearance is negative, and vice versa
    assert ((got >= 0) == (ref >= 0)).all() or np.abs(ref[(got >= 0) != (ref >= 0)]).max() < 1e-9
    # where it is negative (and not inside), it is the exact value from below
    neg = (got < 0) & (got > -np.inf)
    assert (got[neg] <= ref[neg] + 1e-12).all() and np.allclose(got[neg], ref[neg], atol=1e-9)
    # -inf exactly inside an ellipsoid
    assert (ref[got == -np.inf] < 0).all()
    dist = point_ellipsoid_distance(pts, scene)
    assert ((got == -np.inf) == (dist.min(1) == -1)).all()


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_points_clearance_lower_exact_near_obstacles(seed):
    """Points within 2 camera radii of some ellipsoid surface: the value is the exact clearance."""
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, 4, amax=0.3, camera_radius=0.1)
    pts = scene.means.numpy() + rng.normal(size=(4, 3)) * 0.3
    got = points_clearance_lower(torch.as_tensor(pts), scene).numpy()
    ref = clearance(pts, scene)
    sel = (ref > -0.1 + 1e-6) & (ref < 0.0)  # outside every ellipsoid, within r of one
    assert np.allclose(got[sel], ref[sel], atol=1e-9)


def test_sample_free_starts_seeded_safe_and_in_region():
    rng = np.random.default_rng(0)
    scene = random_scene(rng, 10, amax=0.3, camera_radius=0.03)
    grid = conservative_grid(scene, res=8)
    a = sample_free_starts(12, scene, None, grid, generator=7, region_lo=[-0.8, -0.8, -0.5], region_hi=[0.8, 0.8, 0.5])
    b = sample_free_starts(12, scene, None, grid, generator=torch.Generator().manual_seed(7),
                           region_lo=[-0.8, -0.8, -0.5], region_hi=[0.8, 0.8, 0.5])
    assert a.shape == (12, 3) and a.dtype == torch.float64
    assert torch.equal(a, b)
    c = sample_free_starts(12, scene, None, grid, generator=8)
    assert not torch.equal(a, c)
    assert (a[:, 2] >= -0.5).all() and (a[:, 2] <= 0.5).all()
    assert clearance(a.numpy(), scene).min() >= 0
    assert clearance(c.numpy(), scene).min() >= 0
    # without a grid: exact test only, region from the scene bounds
    d = sample_free_starts(5, scene, None, None, generator=1)
    assert clearance(d.numpy(), scene).min() >= 0


def test_sample_free_starts_errors():
    scene = make_scene([[0.0, 0, 0]], np.eye(3)[None], [[0.5, 0.5, 0.5]], 0.03)
    with pytest.raises(NoFreeStartError, match="found only 0 of 3"):
        sample_free_starts(3, scene, None, None, 0, [-0.1] * 3, [0.1] * 3, max_tries=3)
    with pytest.raises(StartInCollisionError):  # NoFreeStartError is one
        sample_free_starts(3, scene, None, None, 0, [-0.1] * 3, [0.1] * 3, max_tries=3)
    with pytest.raises(InvalidInputError):
        sample_free_starts(0, scene)
    with pytest.raises(InvalidInputError):
        sample_free_starts(2, scene, None, None, 0, [1.0] * 3, [0.0] * 3)


def test_sample_free_starts_away_from_keeps_the_distance_and_falls_back():
    rng = np.random.default_rng(1)
    scene = random_scene(rng, 10, amax=0.3, camera_radius=0.03)
    grid = conservative_grid(scene, res=8)
    lo, hi = [-0.8, -0.8, -0.5], [0.8, 0.8, 0.5]
    look = np.array([0.5, -0.4, 0.1])
    plain = sample_free_starts(40, scene, None, grid, generator=3, region_lo=lo, region_hi=hi)
    away = sample_free_starts(40, scene, None, grid, generator=3, region_lo=lo, region_hi=hi,
                              away_from=look, away_fraction=0.4)
    d_min = 0.4 * 1.6  # fraction x the region's longest side
    assert (np.linalg.norm(plain.numpy() - look, axis=1) < d_min).any()  # the rule has something to reject
    assert (np.linalg.norm(away.numpy() - look, axis=1) >= d_min).all()
    assert clearance(away.numpy(), scene).min() >= 0
    again = sample_free_starts(40, scene, None, grid, generator=3, region_lo=lo, region_hi=hi,
                               away_from=look, away_fraction=0.4)
    assert torch.equal(away, again)
    # 0 (or no point) leaves the sampling exactly as it was
    zero = sample_free_starts(40, scene, None, grid, generator=3, region_lo=lo, region_hi=hi, away_from=look,
                              away_fraction=0.0)
    assert torch.equal(zero, plain)
    # nowhere far enough (a small region around the point): still n free starts, drawn without the rule
    p = plain[0].numpy()  # a free start: the region around it has free starts, none 0.9 x 0.04 from p
    small = sample_free_starts(5, scene, None, grid, generator=3, region_lo=p - 0.02, region_hi=p + 0.02,
                               away_from=p, away_fraction=0.9, max_tries=4)
    assert small.shape == (5, 3) and clearance(small.numpy(), scene).min() >= 0
    assert (np.abs(small.numpy() - p) <= 0.02 + 1e-12).all()


def test_sample_free_starts_away_from_bad_input():
    scene = make_scene([[0.0, 0, 0]], np.eye(3)[None], [[0.1, 0.1, 0.1]], 0.03)
    for bad in (-0.1, 1.0, float("nan")):
        with pytest.raises(InvalidInputError, match="away_fraction"):
            sample_free_starts(2, scene, None, None, 0, [-1.0] * 3, [1.0] * 3, away_from=[0.5, 0, 0], away_fraction=bad)
    with pytest.raises(InvalidInputError, match="away_from"):
        sample_free_starts(2, scene, None, None, 0, [-1.0] * 3, [1.0] * 3, away_from=[np.inf, 0, 0], away_fraction=0.2)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    point=st.tuples(*[st.floats(-1.0, 1.0)] * 3),
    fraction=st.floats(0.0, 0.5),
    seed=st.integers(0, 2**16),
)
def test_sample_free_starts_away_from_property(point, fraction, seed):
    """Far starts exist whenever fraction <= 0.5 (a ball of radius side/2 leaves >= 47% of a cube): every start
    keeps the distance, is free (exact float64 clearance), and lies in the region."""
    scene = make_scene([[0.7, 0.7, 0.7]], np.eye(3)[None], [[0.1, 0.1, 0.1]], 0.03)
    grid = conservative_grid(scene, res=8)  # spans [-1, 1]^3: the region is the whole cube
    lo, hi = np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0])
    s = sample_free_starts(6, scene, None, grid, seed, lo, hi, away_from=point, away_fraction=fraction).numpy()
    assert (np.linalg.norm(s - np.asarray(point), axis=1) >= fraction * 2.0 - 1e-12).all()
    assert clearance(s, scene).min() >= 0
    assert ((s >= lo) & (s <= hi)).all()


def test_mean_voxel_mask_gives_the_same_goals_as_the_box_query():
    """closest_safe_point's fallback with the precomputed voxels-holding-a-mean mask picks exactly the goal the
    per-window box query picks (targets buried inside the volume blobs of synthetic/blobs.py), and the goal is free."""
    import numpy as np

    from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
    from cinenerf_ns.planner.search.goal import closest_safe_point, mean_voxel_mask
    from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig
    from cinenerf_ns.synthetic.blobs import blob_scene

    b = blob_scene(20_000, seed=1)
    scene = EllipsoidScene.from_params(b.splat)
    pl = Planner(scene, PlannerConfig(up=b.up, candidate_workers=0))
    prep = pl.prepare()
    mv = mean_voxel_mask(scene, prep.grid)
    assert prep.mean_voxels is not None and np.array_equal(prep.mean_voxels, mv) and mv.any()
    for blob in b.blobs[:4]:
        t = torch.as_tensor(blob.center, dtype=torch.float64)
        kw = dict(reachable=prep.astar_grid.labels > 0,
                  clearance_fn=functools.partial(clearance_queries.free_test, pl.space))
        a = closest_safe_point(t, scene, prep.index, prep.grid, **kw)
        m = closest_safe_point(t, scene, prep.index, prep.grid, mean_voxels=mv, **kw)
        assert torch.equal(a, m) and bool(clearance_queries.points_free(pl.space, m[None].numpy())[0])


needs_goalwindow = pytest.mark.skipif(native.goal_window_c() is None,
                                      reason=f"goalwindow.c did not load: {native.native_status().get('goalwindow')}")


@needs_goalwindow
@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), dims=st.tuples(st.integers(1, 24), st.integers(1, 24), st.integers(1, 24)),
       fill=st.sampled_from([0.2, 0.6, 0.95]), mean_fill=st.sampled_from([0.0, 0.3, 0.9]),
       reach_kind=st.sampled_from(["none", "labels", "bool"]), pass_rate=st.sampled_from([0.0, 0.05, 0.5, 1.0]),
       limit=st.sampled_from([1, 5, 40, 256]), snap=st.booleans())
def test_native_goal_window_is_the_numpy_window(seed, dims, fill, mean_fill, reach_kind, pass_rate, limit, snap):
    """The fallback's windows by goalwindow.c and by numpy: the same candidates tested in the same order, so the same
    returned centre (or both give up), for any occupancy, reachable mask (component labels or bool), mean mask, target
    (a voxel centre when ``snap``: many exact distance ties) and exact-test outcome (a fixed random pass per voxel)."""
    from scipy import ndimage

    from cinenerf_ns.planner.scene.occupancy import OccupancyGrid
    from cinenerf_ns.planner.search.goal import ComponentMask, _nearest_free_voxel_centre

    rng = np.random.default_rng(seed)
    occ = rng.random(dims) < fill
    grid = OccupancyGrid(torch.tensor([-0.3, 0.1, -1.0], dtype=torch.float64), 0.07, torch.from_numpy(occ))
    mean = rng.random(dims) < mean_fill
    reach = None
    if reach_kind == "labels":
        labels, n = ndimage.label(~occ, structure=np.ones((3, 3, 3), dtype=bool))
        reach = ComponentMask(labels.astype(np.int32), int(rng.integers(0, n + 1)))
    elif reach_kind == "bool":
        reach = rng.random(dims) < 0.7
    t = grid.lo.numpy() + rng.uniform(-0.2, 1.2, 3) * np.asarray(dims) * grid.voxel_size
    if snap:
        t = grid.lo.numpy() + (np.floor(rng.uniform(0, 1, 3) * np.asarray(dims)) + 0.5) * grid.voxel_size
    passes = rng.random(dims) < pass_rate
    tested = {"python": [], "native": []}

    def clear_for(name):
        def clear(points):
            ijk = np.floor((points.numpy() - grid.lo.numpy()) / grid.voxel_size).astype(int)
            tested[name].append(points.numpy().copy())
            return torch.from_numpy(passes[ijk[:, 0], ijk[:, 1], ijk[:, 2]])
        return clear

    scene = type("S", (), {"means": torch.zeros(1, 3, dtype=torch.float64)})()
    out = {}
    for name in ("python", "native"):
        try:
            out[name] = _nearest_free_voxel_centre(torch.tensor(t), scene, None, grid, reach, clear_for(name), limit,
                                                   mean, backend=name).numpy()
        except GoalUnreachableError:
            out[name] = None
    assert (out["python"] is None) == (out["native"] is None)
    if out["python"] is not None:
        assert np.array_equal(out["python"], out["native"])
    assert len(tested["python"]) == len(tested["native"])
    for a, b in zip(tested["python"], tested["native"]):
        assert np.array_equal(a, b)


def test_goal_window_backend_choice():
    """auto uses the compiled window where it applies; "native" says what it needs where it does not."""
    from cinenerf_ns.planner.scene.occupancy import OccupancyGrid
    from cinenerf_ns.planner.search.goal import _nearest_free_voxel_centre

    grid = OccupancyGrid(torch.zeros(3, dtype=torch.float64), 0.1, torch.zeros(4, 4, 4, dtype=torch.bool))
    scene = type("S", (), {"means": torch.zeros(1, 3, dtype=torch.float64)})()
    ok = lambda p: torch.ones(len(p), dtype=torch.bool)  # noqa: E731
    with pytest.raises(RuntimeError, match="needs an OccupancyGrid, a mean-voxel mask"):
        _nearest_free_voxel_centre(torch.tensor([0.2, 0.2, 0.2]), scene, None, grid, None, ok, 16, None,
                                   backend="native")
    with pytest.raises(InvalidInputError, match="backend"):
        _nearest_free_voxel_centre(torch.tensor([0.2, 0.2, 0.2]), scene, None, grid, None, ok, 16,
                                   np.zeros((4, 4, 4), dtype=bool), backend="fast")
