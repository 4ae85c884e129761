"""End-to-end plans through generated cluttered scenes: positive exact clearance, look-at error
near zero, goal reached; bad requests get specific errors."""
import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner.errors import InvalidInputError, PlanningError, StartInCollisionError
from cinenerf_ns.planner.geometry import clearance_queries
from cinenerf_ns.planner.geometry.distance import clearance
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.procedural import procedural_room
from cinenerf_ns.planner.search import shortcut as shortcut_module
from cinenerf_ns.planner.search.astar import shortcut
from cinenerf_ns.planner.search.reach import reachable_goal
from cinenerf_ns.planner.search.shortcut import shortcut_free, shortcut_free_any
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig


@pytest.fixture(scope="module")
def room():
    s = procedural_room(4000, seed=1)
    e = EllipsoidScene.from_splat(s.means, s.quats, s.log_scales, s.opacity_logits)
    pl = Planner(e, PlannerConfig(grid_resolution=64))
    pl.prepare()
    return s, e, pl


def _exact_min_clearance(scene, pl, shot, stride=3):
    pts = torch.as_tensor(shot.positions[::stride], dtype=torch.float64)
    return float(clearance(pts, scene, pl.prepared.index).min())


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_plans_are_safe_look_at_and_reach_goal(room, seed):
    s, e, pl = room
    goal = s.objects[0].center
    look = s.objects[1].center
    shots = pl.plan(goal, look, seed=seed)
    assert len(shots) == 1
    sh = shots[0]
    assert sh.safety["safe"]
    assert _exact_min_clearance(e, pl, sh) >= 0
    assert np.max(sh.look_at_errors_deg()) < 0.01
    # the goal is the closest reachable safe point: within the object's half-diagonal + camera radius + a voxel
    o = s.objects[0]
    tol = 0.5 * np.linalg.norm(o.size) + e.camera_radius + 2 * pl.prepared.grid.voxel_size
    assert np.linalg.norm(sh.positions[-1] - sh.goal) < 1e-6
    assert np.linalg.norm(sh.goal - goal) < tol
    for k in ("goal_ms", "astar_ms", "corridor_ms", "qp_ms", "verify_ms", "plan_ms"):
        assert sh.timings[k] >= 0


def test_seeded_candidates_are_reproducible_and_differ(room):
    s, e, pl = room
    g, l = s.objects[2].center, s.objects[3].center
    a = pl.plan(g, l, seed=5, n_candidates=3)
    b = pl.plan(g, l, seed=5, n_candidates=3)
    assert len(a) == 3
    for x, y in zip(a, b):
        assert np.allclose(x.start, y.start)
    starts = np.stack([x.start for x in a])
    assert np.min(np.linalg.norm(starts[:, None] - starts[None], axis=-1) + np.eye(3) * 9) > 1e-3


def test_given_start(room):
    s, e, pl = room
    start = np.array([0.0, 0.0, 0.7])
    sh = pl.plan(s.objects[0].center, s.objects[1].center, start=start)[0]
    assert np.allclose(sh.positions[0], start, atol=1e-6)


def test_random_starts_keep_away_from_the_look_at(room, monkeypatch):
    s, e, pl = room
    g = pl.prepared.grid
    side = float(g.voxel_size * max(g.shape))  # the start region: the grid's extent (start_region None)
    goal, look = s.objects[0].center, s.objects[1].center
    far = pl.plan(goal, look, seed=0, n_candidates=4)
    d_far = np.array([np.linalg.norm(x.start - look) for x in far])
    assert PlannerConfig().start_look_distance == pl.config.start_look_distance > 0
    assert (d_far >= pl.config.start_look_distance * side - 1e-12).all()
    monkeypatch.setattr(pl.config, "start_look_distance", 0.0)  # the paper's uniform starts
    near = pl.plan(goal, look, seed=0, n_candidates=4)
    d_near = np.array([np.linalg.norm(x.start - look) for x in near])
    assert (d_near < PlannerConfig().start_look_distance * side).any()  # the rule had starts to move
    # a given start is never moved, whatever the rule
    monkeypatch.setattr(pl.config, "start_look_distance", 0.9)
    start = np.array([0.0, 0.0, 0.7])
    assert np.allclose(pl.plan(goal, start + [0.01, 0, 0], start=start)[0].positions[0], start, atol=1e-6)
    for bad in (1.0, -0.1, float("nan"), True):
        with pytest.raises(InvalidInputError, match="start_look_distance"):
            Planner(e, PlannerConfig(start_look_distance=bad))


def test_bad_requests(room):
    s, e, pl = room
    g, l = s.objects[0].center, s.objects[1].center
    with pytest.raises(InvalidInputError):
        pl.plan([np.nan, 0, 0], l)
    with pytest.raises(InvalidInputError):
        pl.plan(g, [1, 2])
    with pytest.raises(InvalidInputError):
        pl.plan(g, l, n_candidates=0)
    # a start on the floor puts the camera inside the floor Gaussians
    with pytest.raises(StartInCollisionError):
        pl.plan(g, l, start=[0.0, 0.0, 0.0])


def test_errors_are_planning_errors():
    assert issubclass(StartInCollisionError, PlanningError)


def test_shortcut_filter_only_accepts_proven_free_segments(room):
    """shortcut_free (grid line of sight, then segments_free) accepts a subset of segments_free, and
    every accepted segment is free by the exact clearance on dense samples (brute force)."""
    s, e, pl = room
    rng = np.random.default_rng(0)
    lo, hi = pl.prepared.grid.lo.numpy(), pl.prepared.grid.hi.numpy()
    p0 = rng.uniform(lo, hi, (200, 3))
    p1 = p0 + rng.normal(size=(200, 3)) * 0.3
    fast, exact = shortcut_free(pl.space, p0, p1), shortcut_module.segments_free(pl.space, p0, p1)
    assert not (fast & ~exact).any()
    assert fast.any() and (exact & ~fast).any()  # the filter both passes and refuses some here
    t = np.linspace(0, 1, 200)
    for i in np.flatnonzero(fast)[:20]:
        pts = p0[i] + t[:, None] * (p1[i] - p0[i])
        assert float(clearance(torch.as_tensor(pts), e, pl.prepared.index).min()) > 0


def test_capped_clearance_is_exact_below_the_cap():
    from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
    from cinenerf_ns.planner.scene.procedural import procedural_room
    from cinenerf_ns.planner.scene.scene_config import SceneConfig
    from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig

    r = procedural_room(3000, seed=1)
    sc = EllipsoidScene.from_splat(r.means, r.quats, r.log_scales, r.opacity_logits, SceneConfig())
    pl = Planner(sc, PlannerConfig(grid_resolution=32))
    pl.prepare()
    rng = np.random.default_rng(0)
    pts = rng.uniform(r.free_lo, r.free_hi, size=(200, 3))
    exact = pl.clearance(pts)
    capped = pl.clearance(pts, cap=0.05)
    np.testing.assert_allclose(capped, np.minimum(exact, 0.05), rtol=0, atol=1e-9)
    assert (exact > 0.05).any() and (exact < 0.05).any()  # both regimes are exercised


def test_request_device_is_validated_and_cpu_scenes_are_not_mirrored(room):
    s, e, pl = room
    with pytest.raises(InvalidInputError, match="request_device"):
        Planner(e, PlannerConfig(request_device="gpu"))
    assert pl.scene is pl.batch_scene  # CPU scene: requests and batched scoring use the same tensors
    assert pl.prepared.batch_index is pl.prepared.index
    assert "mirror_ms" in pl.prepared.timings_ms and pl.prepared.timings_ms["mirror_ms"] == 0.0


@pytest.mark.gpu
def test_gpu_scene_requests_run_on_a_cpu_mirror_with_the_same_result():
    if not torch.cuda.is_available():
        pytest.skip("needs CUDA")
    s = procedural_room(4000, seed=1)
    e = EllipsoidScene.from_splat(s.means, s.quats, s.log_scales, s.opacity_logits).to("cuda")
    auto = Planner(e, PlannerConfig(grid_resolution=64))
    on_dev = Planner(e, PlannerConfig(grid_resolution=64, request_device="scene"))
    auto.prepare()
    on_dev.prepare()
    assert auto.scene.device.type == "cpu" and auto.batch_scene.device.type == "cuda"
    assert auto.prepared.index.device.type == "cpu" and auto.prepared.batch_index.device.type == "cuda"
    assert on_dev.scene.device.type == "cuda"
    # the grid is built once on the GPU, so both planners plan on the same occupancy
    assert torch.equal(auto.prepared.grid.occupied.cpu(), on_dev.prepared.grid.occupied.cpu())
    goal, look = s.objects[0].center, s.objects[1].center
    a = auto.plan(goal, look, seed=3)[0]
    b = on_dev.plan(goal, look, seed=3)[0]
    assert a.safety["safe"] and b.safety["safe"]
    assert _exact_min_clearance(e.to("cpu"), auto, a) >= 0
    np.testing.assert_allclose(a.positions[0], b.positions[0], atol=1e-6)  # same seeded start
    np.testing.assert_allclose(a.positions[-1], b.positions[-1], atol=1e-3)


def test_grid_clearance_lower_bound_is_never_optimistic_and_capped_clearance_is_exact(room):
    from hypothesis import given, settings, strategies as st

    s, e, pl = room
    lo, hi = (t.cpu().numpy() for t in pl.planning_bounds())
    span = hi - lo

    @settings(max_examples=40, deadline=None)
    @given(st.lists(st.tuples(*[st.floats(-0.1, 1.1)] * 3), min_size=1, max_size=40))
    def check(fracs):
        pts = lo + np.asarray(fracs) * span  # inside the grid and a little outside it
        exact = clearance(torch.as_tensor(pts), e, None).numpy()  # float64 brute force over all ellipsoids
        lb = clearance_queries.clearance_lower_bound(pl.space, pts)
        assert (lb <= exact + 1e-12).all()
        assert ((lb >= 0) | (lb == -np.inf)).all()
        for cap in (0.05, 0.2):
            np.testing.assert_allclose(pl.clearance(pts, cap=cap), np.minimum(exact, cap), rtol=0, atol=1e-9)

    check()
    # the bound does skip work: in this room's open space it proves a large clearance for many points
    g = np.random.default_rng(0).uniform(lo, hi, size=(2000, 3))
    lb = clearance_queries.clearance_lower_bound(pl.space, g)
    assert (lb > 0.05).mean() > 0.1
    assert (lb <= clearance(torch.as_tensor(g), e, pl.prepared.index).numpy() + 1e-12).all()


@settings(max_examples=6, deadline=None)
@given(seed=st.integers(0, 100_000), res=st.sampled_from([24, 48]))
def test_points_free_grid_filter_is_never_optimistic(seed, res):
    """Planner.points_free decides points in free voxels of the occupancy grid without a distance test: against the
    float64 brute force, every point it calls free (grid or Cor. 1) has clearance >= 0, and the grid decides many."""
    from _corridor_refs import min_distance as exact_min_distance
    from _geom_helpers import random_scene

    sc = random_scene(60, seed, rmin=0.02, rmax=0.2, camera_radius=0.03)
    pl = Planner(sc, PlannerConfig(grid_resolution=res, bounds=((-1.4, -1.4, -1.4), (1.4, 1.4, 1.4))))
    pl.prepare()
    g = torch.Generator().manual_seed(seed)
    pts = (torch.rand(3000, 3, generator=g, dtype=torch.float64) * 2 - 1) * 1.5  # also outside the grid
    # and points just outside the inflated surfaces, where a wrong voxel test would show
    j = torch.randint(0, len(sc), (1000,), generator=g)
    d = torch.nn.functional.normalize(torch.randn(1000, 3, generator=g, dtype=torch.float64), dim=-1)
    near = sc.means[j].double() + d * (sc.radii[j].double().max(-1).values + 0.03 + 0.02
                                       * torch.rand(1000, generator=g, dtype=torch.float64))[:, None]
    pts = torch.cat([pts, near])
    # float64 brute force by the tests' own vectorised bisection (independent of the package; -1 inside, where only
    # the sign matters here)
    exact = torch.as_tensor(exact_min_distance(pts.numpy(), sc)) - 0.03
    grid_free = torch.as_tensor(clearance_queries.in_free_voxel(pl.space, pts.numpy()))
    free = torch.as_tensor(clearance_queries.points_free(pl.space, pts.numpy()))
    assert (exact[grid_free] >= 0).all()
    assert (exact[free] >= 0).all()
    assert (free | ~grid_free).all()  # grid-free points are reported free
    assert int(grid_free.sum()) > 0.2 * len(pts)  # the filter is exercised


def test_astar_weight_config(room, monkeypatch):
    """Plain A* (1.0, default) and weighted A* (1.5, 3) both give verified-safe shots to the same goal, the configured
    weight reaches the voxel path search; bad weights are clear errors."""
    import cinenerf_ns.planner.shots.stages as stages_mod  # the leg's A* stage

    seen = []
    real = stages_mod.voxel_path

    def spy(*a, **kw):
        seen.append(kw.get("astar_weight"))
        return real(*a, **kw)

    monkeypatch.setattr(stages_mod, "voxel_path", spy)
    s, e, pl0 = room
    goal, look = s.objects[0].center, s.objects[1].center
    for w in (1.0, 1.5, 3.0):
        pl = Planner(e, PlannerConfig(grid_resolution=64, astar_weight=w))
        pl.prepared = pl0.prepared  # same scene, same grid: skip a second prepare
        shot = pl.plan(goal, look, seed=3)[0]
        assert shot.safety["safe"]
        assert seen[-1] == w
    assert PlannerConfig().astar_weight == 1.0
    for bad in (0.5, float("nan"), "2", True):
        with pytest.raises(InvalidInputError, match="astar_weight"):
            Planner(e, PlannerConfig(astar_weight=bad))


def _random_voxel_paths(pl, rng, n):
    """Polylines of free voxel centres (random walks over 26-neighbours, as a voxel path looks)."""
    grid, occ = pl.prepared.grid, pl.prepared.astar_grid._occ
    free = np.argwhere(~occ)
    steps = np.array([d for d in np.ndindex(3, 3, 3) if d != (1, 1, 1)]) - 1
    out = []
    for _ in range(n):
        v = free[rng.integers(len(free))]
        path = [v]
        for _ in range(rng.integers(2, 25)):
            nxt = path[-1] + steps[rng.integers(len(steps))]
            if ((nxt >= 0) & (nxt < occ.shape)).all() and not occ[tuple(nxt)]:
                path.append(nxt)
        out.append(grid.voxel_to_world(torch.as_tensor(np.array(path))).numpy())
    return out


@pytest.fixture
def grid_room(room):
    """The room planner with grid polytopes forced on (its voxels are too coarse for 'auto')."""
    s, e, pl = room
    old = pl.config.grid_polytopes
    pl.config.grid_polytopes = True
    yield s, e, pl
    pl.config.grid_polytopes = old


def test_shortcut_ways_equals_shortcut_way_per_path_and_choose_way_takes_the_cheaper(grid_room):
    s, e, pl = grid_room
    rng = np.random.default_rng(4)
    paths = [p for p in _random_voxel_paths(pl, rng, 12) if len(p) >= 2]
    got = shortcut_module.shortcut_ways(pl.space, paths)
    for p, g in zip(paths, got):
        assert np.array_equal(g, shortcut_module.shortcut_ways(pl.space, [p])[0])
    # choose_way: segments + OFF_GRID_SEGMENT_COST x off-grid segments, the cheaper wins
    from cinenerf_ns.planner.search.shortcut import OFF_GRID_SEGMENT_COST

    for p in paths:
        a = shortcut_module.shortcut_ways(pl.space, [p])[0]
        b = shortcut(p, lambda a, b: shortcut_free_any(pl.space, a, b))
        cost = lambda w: (len(w) - 1) + OFF_GRID_SEGMENT_COST * shortcut_module.segments_off_grid(pl.space, w)  # noqa: E731
        c = shortcut_module.choose_way(pl.space, a, b)
        assert cost(c) == min(cost(a), cost(b))
    assert shortcut_module.choose_way(pl.space, paths[0], None) is paths[0]


def test_grid_rule_shortcut_keeps_interior_segments_in_free_voxels(grid_room):
    s, e, pl = grid_room
    rng = np.random.default_rng(5)
    for p in _random_voxel_paths(pl, rng, 10):
        g = shortcut(p, lambda a, b: shortcut_free(pl.space, a, b))
        vox = pl.prepared.voxels
        # a segment the shortcut made (not a consecutive pair of the input) lies in free voxels
        idx = [int(np.flatnonzero((p == q).all(1))[0]) for q in g]
        for i in range(len(g) - 1):
            if idx[i + 1] - idx[i] > 1:
                assert vox.segments_free(g[i][None], g[i + 1][None])[0]


@pytest.mark.parametrize("first_box", [2.0, 0.25])
def test_goal_from_the_small_box_is_as_close_as_from_the_full_box(room, monkeypatch, first_box):
    """reach.reachable_goal builds the goal polytope in a box of GOAL_FIRST_BOX_VOXELS voxels first and in the
    full box only when the projection ends on that box's face. Against the full box alone (the reference, built
    here): never farther from the target, and safe. With a tiny first box (0.25 voxel) the second pass runs and the
    goal is the reference's."""
    import cinenerf_ns.planner.search.reach as reach_mod
    from cinenerf_ns.planner.corridor.polytope import safe_polytope
    from cinenerf_ns.planner.search.projection import project_onto_polytope

    s, e, pl = room
    monkeypatch.setattr(reach_mod, "GOAL_FIRST_BOX_VOXELS", first_box)
    grid = pl.prepared.grid
    vs = float(grid.voxel_size)
    comp = pl.main_component()
    rng = np.random.default_rng(0)
    n_second = 0
    for o in s.objects:
        for _ in range(3):
            target = o.center + rng.uniform(-0.25, 0.25, 3) * o.size
            goal = reachable_goal(pl.space, target, comp)
            if goal.polytope is None:  # step 1 answered (target free and reachable) or no polytope
                continue
            c = grid.voxel_to_world(torch.as_tensor(goal.voxel)).double()
            full = np.maximum(np.abs(target - c.numpy()), vs) + vs
            P = safe_polytope(c[None], e, pl.prepared.index, c - torch.as_tensor(full), c + torch.as_tensor(full))
            A, b = P.to_numpy()
            ref = project_onto_polytope(A, b, target, interior=c.numpy())
            assert np.linalg.norm(goal.point - target) <= np.linalg.norm(ref - target) + 1e-9
            assert float(clearance(torch.as_tensor(goal.point)[None], e, pl.prepared.index)[0]) >= 0
            if first_box < 1:
                n_second += 1
                np.testing.assert_allclose(goal.point, ref, atol=1e-9)
    if first_box < 1:
        assert n_second > 0


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), grid_rule=st.booleans(), n=st.integers(1, 40))
def test_shortcut_test_is_the_grid_sight_and_proof_rule(room, seed, grid_rule, n):
    """search.shortcut.shortcut_test asks in its cheapest order; its answer is the rule written plainly: grid sight AND
    (grid rule with both ends in free voxels: the exact voxel walk; otherwise segments_free)."""
    from cinenerf_ns.planner.search.shortcut import free_voxels, grid_sight, segments_free, shortcut_test

    s, e, pl = room
    rng = np.random.default_rng(seed)
    lo, hi = pl.region()
    a = rng.uniform(lo, hi, (n, 3))
    b = a + rng.normal(0, 0.4, (n, 3)) * rng.choice([0.1, 1.0], (n, 1))  # short and long segments
    sight = grid_sight(pl.space, a, b)
    fv = free_voxels(pl.space)
    walk = pl.ready().voxels.segments_free(a, b)
    proof = segments_free(pl.space, a, b)
    ends_free = fv.contains(a) & fv.contains(b)
    want = sight & np.where(grid_rule & ends_free, walk, proof)
    assert np.array_equal(shortcut_test(pl.space, a, b, grid_rule), want)


@pytest.mark.parametrize("grid_rule", [True, False])
def test_compiled_shortcut_pass_is_the_reference_on_a_scene(room, grid_rule):
    """search.shortcut.shortcut_pass with the compiled rounds and the real Corollary-1 pieces == batched_shortcut of
    shortcut_test (every segment of every round asked), for voxel paths with starts and ends off the voxel centres."""
    from cinenerf_ns.planner import native
    from cinenerf_ns.planner.search.astar import batched_shortcut
    from cinenerf_ns.planner.search.shortcut import shortcut_pass, shortcut_test

    if native.shortcut_rounds_c() is None:
        pytest.skip("the compiled shortcut rounds did not load")
    s, e, pl = room
    rng = np.random.default_rng(7)
    vs = float(pl.prepared.grid.voxel_size)
    ways = [p for p in _random_voxel_paths(pl, rng, 24) if len(p) >= 2]
    for w in ways[::2]:  # a start and a goal point off the centres, possibly in occupied voxels
        w[0] += rng.uniform(-0.5, 0.5, 3) * vs
        w[-1] += rng.uniform(-1.5, 1.5, 3) * vs
    want = batched_shortcut(ways, lambda p0, p1: shortcut_test(pl.space, p0, p1, grid_rule))
    for batch in (ways, ways[:1]):
        got = shortcut_pass(pl.space, batch, grid_rule, backend="native")
        assert all(np.array_equal(g, w) for g, w in zip(got, want))
    assert any(len(w) < len(p) for w, p in zip(want, ways))
