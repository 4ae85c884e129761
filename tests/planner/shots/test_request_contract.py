"""The planner's input contract: points near the scene, the planning region, a sign-only start check, bounded grids,
frames and candidates, and goals that are never moved without saying why."""
import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner.corridor.polytope import Polytope
from cinenerf_ns.planner.corridor.safe_corridor import Corridor
from cinenerf_ns.planner.errors import InvalidInputError, StartInCollisionError
from cinenerf_ns.planner.geometry import clearance_queries
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.procedural import procedural_room
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.shots.candidates import plan_candidates
from cinenerf_ns.planner.shots.planner import GRID_BYTES_PER_VOXEL, Planner, PlannerConfig
from cinenerf_ns.planner.trajectory.timing import TimingConfig


def _scene(radius=0.03):
    s = procedural_room(4000, seed=1)
    return s, EllipsoidScene.from_splat(s.means, s.quats, s.log_scales, s.opacity_logits,
                                        SceneConfig(camera_radius=radius))


@pytest.fixture(scope="module")
def room():
    s, e = _scene()
    region = (s.free_lo + 0.05, s.free_hi - 0.05)  # a capture's cameras: inside the room
    pl = Planner(e, PlannerConfig(grid_resolution=64, start_region=region, candidate_workers=0))
    pl.prepare()
    return s, e, pl


def _inside(pl, pts, tol=1e-9):
    lo, hi = pl.region()
    return bool(((pts >= lo - tol) & (pts <= hi + tol)).all())


def test_region_holds_the_start_region_and_stays_within_the_scene_box(room):
    s, e, pl = room
    lo, hi = pl.region()
    slo, shi = pl.config.start_region
    assert (lo <= slo).all() and (hi >= shi).all()
    robust = Planner(e, PlannerConfig(grid_resolution=64, region_rule="robust")).planning_bounds()  # the box cut to
    vs = float(pl.prepared.grid.voxel_size)  # the grid rounds its box up to whole voxels
    assert (lo >= robust[0].numpy() - 1e-9).all() and (hi <= robust[1].numpy() + vs + 1e-9).all()


@pytest.mark.parametrize("bad", [[np.nan, 0, 0], [0, np.inf, 0], [1e30, 0, 0], [50, 50, 50], [1, 2]])
def test_far_or_malformed_points_are_errors(room, bad):
    _, _, pl = room
    with pytest.raises(InvalidInputError, match="go-to point"):
        pl.plan(np.array(bad, dtype=float), np.zeros(3))


def test_far_point_message_names_the_distance_and_the_region(room):
    _, _, pl = room
    with pytest.raises(InvalidInputError, match=r"units outside the planning region .* within [0-9.]+ units"):
        pl.plan(np.array([50.0, 50, 50]), np.zeros(3))


def test_goal_outside_region_ends_inside_and_says_why(room):
    s, _, pl = room
    lo, hi = pl.region()
    target = np.array([hi[0] + 0.3, 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])])  # near, but outside
    shot = pl.plan(target, s.objects[0].center, seed=0)[0]
    assert shot.safety["safe"] and _inside(pl, shot.positions)
    mv = pl.explain_goal(target, shot.goal)
    assert mv is not None and mv["distance"] >= 0.3 - 1e-6 and "outside the planning region" in mv["why"]
    assert np.allclose(mv["from"], target) and np.allclose(mv["to"], shot.goal)


def test_goal_inside_an_object_says_the_camera_does_not_fit(room):
    s, e, pl = room
    lo, hi = pl.region()
    m = e.means.double().numpy()
    ok = ((m > lo + 0.2) & (m < hi - 0.2)).all(1)
    target = m[np.flatnonzero(ok)[int(torch.argmax(e.radii[torch.as_tensor(ok)].min(-1).values))]]  # deep inside one
    assert not clearance_queries.points_free(pl.space, target[None])[0]
    shot = pl.plan(target, s.objects[1].center, seed=0)[0]
    mv = pl.explain_goal(target, shot.goal)
    assert mv is not None and mv["distance"] > 0 and "does not fit" in mv["why"]


def test_goal_met_is_not_reported_as_moved(room):
    _, _, pl = room
    assert pl.explain_goal(np.zeros(3), np.zeros(3) + 1e-9) is None


def test_start_outside_region_is_an_error_unless_forced():
    s, e = _scene()
    region = (s.free_lo + 0.3, s.free_hi - 0.3)
    pl = Planner(e, PlannerConfig(grid_resolution=48, start_region=region, candidate_workers=0))
    pl.prepare()
    lo, hi = pl.region()
    start = np.array([lo[0] - 0.1, 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])])
    assert not clearance_queries.in_free_voxel(pl.space, start[None])[0]
    with pytest.raises(InvalidInputError, match="outside the planning region.*force"):
        pl.plan(s.objects[0].center, s.objects[1].center, start=start)
    if not bool(clearance_queries.points_free(pl.space, start[None])[0]):
        pytest.skip("the chosen start is not free in this room")
    shot = pl.plan(s.objects[0].center, s.objects[1].center, start=start, force_start=True)[0]
    assert np.allclose(shot.positions[0], start) and shot.safety["safe"]
    assert _inside(pl, start[None]) and _inside(pl, shot.positions)


def test_start_in_collision_is_refused_by_the_capped_check(room):
    s, e, pl = room
    inside = e.means[int(torch.argmax(e.radii.min(-1).values))].double().numpy()  # the fattest ellipsoid's centre
    with pytest.raises(StartInCollisionError, match="inside the scene"):
        pl.plan(s.objects[0].center, s.objects[1].center, start=inside)


def test_camera_radius_too_large_for_the_scene_fails_before_the_grid():
    _, e = _scene(radius=5.0)
    pl = Planner(e, PlannerConfig(grid_resolution=48))
    with pytest.raises(InvalidInputError, match=r"camera sphere .* too large .* <= "):
        pl.prepare()
    assert pl.prepared is None


@pytest.mark.parametrize("res", [0, 7, 1025, 2.5, True, "64"])
def test_grid_resolution_range(res):
    _, e = _scene()
    with pytest.raises(InvalidInputError, match=r"grid-resolution.*\[8, 1024\]"):
        Planner(e, PlannerConfig(grid_resolution=res))


def test_grid_over_the_memory_budget_names_what_fits():
    _, e = _scene()
    pl = Planner(e, PlannerConfig(grid_resolution=1000, memory_budget_mb=256))
    with pytest.raises(InvalidInputError, match=r"memory budget 256 MB .*at most (\d+) fits") as err:
        pl.prepare()
    fits = int(str(err.value).rsplit("at most ", 1)[1].split()[0])
    lo, hi = (t.numpy() for t in pl.planning_bounds())
    side = hi - lo
    need = np.prod(np.ceil(side / (side.max() / fits))) * GRID_BYTES_PER_VOXEL / 2**20
    assert need <= 256 * 1.05  # the resolution it offers does fit (to rounding of the cube root)


def test_frames_bounded_before_planning(room):
    s, e, _ = room
    with pytest.raises(InvalidInputError, match=r"fps must be in \[1, 240\]"):
        Planner(e, PlannerConfig(timing=TimingConfig(fps=100000)))
    pl = Planner(e, PlannerConfig(grid_resolution=48, timing=TimingConfig(max_speed=1e-6)))
    with pytest.raises(InvalidInputError, match=r"--max-speed 1e-06 is too slow .* use --max-speed >= "):
        pl.plan(s.objects[0].center, s.objects[1].center)


@pytest.mark.parametrize("k", [0, 65, 2.5])
def test_candidate_count_range(room, k):
    s, _, pl = room
    with pytest.raises(InvalidInputError, match=r"candidates.*\[1, 64\]"):
        plan_candidates(pl, s.objects[0].center, s.objects[1].center, k=k)


def test_candidates_time_budget_returns_fewer_and_says_so(room):
    s, _, pl = room
    tm = {}
    ranked = plan_candidates(pl, s.objects[0].center, s.objects[1].center, k=6, seed=3, timings=tm, time_budget_s=1e-6)
    assert 1 <= len(ranked) < 6 and tm["budget_stopped"] == 1.0
    with pytest.raises(InvalidInputError, match="time-budget"):
        plan_candidates(pl, s.objects[0].center, s.objects[1].center, k=2, time_budget_s=0.0)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=6, max_size=6))
def test_corridor_constraints_hold_the_region_box(v):
    lo = np.array(v[:3]) - 2.0
    hi = np.array(v[3:]) + 2.0
    a = np.array([[1.0, 0, 0]])
    poly = Polytope(torch.as_tensor(a), torch.as_tensor([5.0]), torch.zeros(1, 3, dtype=torch.float64))
    cor = Corridor([poly], torch.zeros(2, 3, dtype=torch.float64), region=(lo, hi))
    (A, b), = cor.constraints()
    rng = np.random.default_rng(0)
    pts = rng.uniform(-4, 4, size=(500, 3))
    inside_box = ((pts >= lo) & (pts <= hi)).all(1)
    ok = (pts @ A.T <= b + 1e-12).all(1)
    assert np.array_equal(ok, inside_box & (pts[:, 0] <= 5.0))


def test_plans_stay_in_the_region(room):
    s, _, pl = room
    rng = np.random.default_rng(7)
    lo, hi = pl.region()
    for i in range(4):
        goal, look = rng.uniform(lo, hi), rng.uniform(lo, hi)
        shot = pl.plan(goal, look, seed=i)[0]
        assert shot.safety["safe"] and _inside(pl, shot.positions)


@pytest.mark.parametrize("field,bad", [("region_padding", -0.1), ("region_padding", float("nan")), ("far_limit", 0.0),
                                       ("far_limit", float("inf")), ("far_limit", True)])
def test_region_options_are_checked(field, bad):
    _, e = _scene()
    with pytest.raises(InvalidInputError, match=f"{field} must be a finite number"):
        Planner(e, PlannerConfig(**{field: bad}))
