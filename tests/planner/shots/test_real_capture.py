"""A real capture plans: the fox capture trained with ns-train cinesplat (open background, floaters, unbounded extent).

Seeded go-to / look-at pairs in the training cameras' box; every returned shot is verified safe by the planner and
by the capped exact clearance report, stays inside the planning region, and every reported clearance is finite."""
import numpy as np
import pytest

from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig
from cinenerf_ns.scenes import load_scene


@pytest.fixture(scope="module")
def fox_planner(fox_splat):
    with pytest.warns(UserWarning, match="splat repair"):  # a real splat has tiny axes; it is said, not hidden
        loaded = load_scene(str(fox_splat), SceneConfig(camera_radius=0.04))
    assert loaded.start_region is not None, "the export carries its training cameras"
    planner = Planner(loaded.scene, PlannerConfig(start_region=loaded.start_region, candidate_workers=0))
    planner.prepare()
    return loaded, planner


def test_planning_region_is_the_cameras_region_not_the_floaters(fox_planner):
    loaded, planner = fox_planner
    lo, hi = planner.region()
    slo, shi = loaded.start_region
    means = loaded.scene.means.numpy()
    far = np.abs(means).max()  # floaters out to ~6 units
    assert (lo <= slo).all() and (hi >= shi).all()
    assert (hi - lo).max() <= 2.0 * (shi - slo).max() + 0.2  # start region + region_padding, not the floaters
    assert far > 2 * np.abs(np.concatenate([lo, hi])).max()


def test_ten_seeded_pairs_plan_verified_safe(fox_planner):
    loaded, planner = fox_planner
    slo, shi = loaded.start_region
    lo, hi = planner.region()
    rng = np.random.default_rng(2026)
    planned = 0
    for i in range(10):
        goal, look = rng.uniform(slo, shi), rng.uniform(slo, shi)
        shot = planner.plan(goal, look, seed=i)[0]
        assert shot.safety["safe"]
        rep = planner.clearance_report(shot)
        assert np.isfinite(rep["clearance"]).all() and rep["min_clearance"] > 0 and rep["safe"]
        assert rep["lipschitz_lower_bound"] > 0
        assert ((shot.positions >= lo - 1e-9) & (shot.positions <= hi + 1e-9)).all(), "left the planning region"
        moved = planner.explain_goal(goal, shot.goal)
        assert moved is None or moved["why"]
        planned += 1
    assert planned == 10


def test_report_far_from_everything_is_capped_not_unbounded(fox_planner):
    _, planner = fox_planner
    lo, hi = planner.region()
    pts = np.array([[0.0, 0.0, 40.0], [25.0, -30.0, 5.0], 0.5 * (lo + hi)])  # far outside, and the middle
    c = planner.clearance(pts, cap=0.5)
    assert np.isfinite(c).all() and c[0] == 0.5 and c[1] == 0.5
