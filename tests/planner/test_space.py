"""space.py: the prepared planning space that prepare() builds once and every module below shots/ takes (issue 35,
item 1): the Planner hands it down, and the search / geometry / corridor functions work on a space built without one."""
import numpy as np
import pytest

from cinenerf_ns.planner.corridor.corridor_options import corridor_kwargs
from cinenerf_ns.planner.geometry.clearance_queries import clearance, points_free
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.planning_region import grid_resolution_for
from cinenerf_ns.planner.scene.procedural import procedural_room
from cinenerf_ns.planner.search.starts import main_component
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig
from cinenerf_ns.planner.shots.prepared_scene import prepare_scene
from cinenerf_ns.planner.space import PlanningSpace


@pytest.fixture(scope="module")
def room():
    s = procedural_room(4000, seed=1)
    return EllipsoidScene.from_splat(s.means, s.quats, s.log_scales, s.opacity_logits)


def test_prepare_builds_the_space_once_and_hands_it_down(room):
    pl = Planner(room, PlannerConfig(grid_resolution=32, candidate_workers=0))
    prep = pl.prepare()
    sp = pl.space
    assert pl.space is sp  # built by prepare(), not per query
    assert sp.prepared is prep and sp.scene is pl.scene and sp.batch_scene is pl.batch_scene and sp.config is pl.config
    assert sp.grid is prep.grid and sp.index is prep.index
    assert all(np.array_equal(a, b) for a, b in zip(sp.region(), pl.region()))
    lo, hi = pl.region()
    outside = hi + 0.5 * (hi - lo).max()  # within far_limit: a forced start grows the region and prepares again
    pl.grow_region(outside)
    assert pl.space is not sp and pl.space.prepared is pl.prepared and pl.space.config is pl.config
    assert (pl.space.region()[1] > outside).all()


def test_a_space_built_without_a_planner_answers_as_the_planners(room):
    cfg = PlannerConfig(grid_resolution=32, candidate_workers=0)
    pl = Planner(room, cfg)
    pl.prepare()
    lo, hi = pl.planning_bounds()
    res = grid_resolution_for(cfg, float(room.camera_radius), lo.cpu().numpy(), hi.cpu().numpy())  # prepare()'s
    scene, prep = prepare_scene(room, res, lo, hi, mirror=False)
    sp = PlanningSpace(scene, scene, cfg, prep)
    rng = np.random.default_rng(0)
    rlo, rhi = sp.region()
    pts = rng.uniform(rlo, rhi, (64, 3))
    assert np.array_equal(points_free(sp, pts), points_free(pl.space, pts))
    assert np.array_equal(clearance(sp, pts, cap=0.1), pl.clearance(pts, cap=0.1))
    assert main_component(sp) == pl.main_component()
    assert corridor_kwargs(sp).keys() == corridor_kwargs(pl.space).keys()
