"""The leg stages (stages.py): plan_leg is their composition, the batched legs_* stages equal their one-leg
versions, a stop's way ends at the stop, unsafe reports are refused; candidates.py and multistop.py plan legs only
through stages.py (no stage module called directly, no Planner private)."""
import ast
from pathlib import Path

import numpy as np
import pytest
import torch
from _shot_scenes import GO_TO, TARGET, walled_target_scene
from hypothesis import given, settings, strategies as st
from hypothesis.extra import numpy as hnp

from cinenerf_ns.planner.corridor import corridor_options
from cinenerf_ns.planner.errors import UnsafeTrajectoryError
from cinenerf_ns.planner.scene.occupancy import OccupancyGrid
from cinenerf_ns.planner.shots import stages
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig

STARTS = np.array([[0.7, 0.5, 0.5], [0.8, -0.6, 0.4], [-0.6, 0.6, 0.5], [0.3, 0.7, 0.7]])


@pytest.fixture(scope="module")
def planner():
    pl = Planner(walled_target_scene(), PlannerConfig(grid_resolution=48))
    pl.prepare()
    return pl


def _legs(pl):
    """(start, goal, polyline to shortcut) of each start's leg to GO_TO."""
    cache = {}
    out = []
    for s in STARTS:
        goal, s_ijk = stages.leg_goal(pl.space, s, GO_TO, cache)
        out.append((s, goal, stages.leg_way(pl.space, s, s_ijk, goal)))
    return out


def test_plan_leg_is_the_composition_of_the_stages(planner):
    for s, goal, way in _legs(planner):
        short = stages.leg_shortcut(planner.space, way, goal)
        assert not stages.at_goal_already(short)
        corridor = stages.leg_corridor(planner.space, short, goal.known())
        traj = stages.leg_trajectory(planner.space, corridor, s, goal.point)
        shot = stages.leg_shot(planner.space, traj, corridor, TARGET, GO_TO)
        shot.safety = stages.leg_verify(planner.space, shot)
        leg = stages.plan_leg(planner.space, s, GO_TO, TARGET, {})
        np.testing.assert_array_equal(leg.positions, shot.positions)
        np.testing.assert_array_equal(leg.rotations, shot.rotations)
        assert leg.safety == shot.safety and np.array_equal(leg.goal_target, GO_TO)
        for key in ("goal_ms", "astar_ms", "shortcut_ms", "corridor_ms", "qp_ms", "timing_ms", "verify_ms", "plan_ms"):
            assert leg.timings[key] >= 0


def test_batched_stages_equal_the_one_leg_stages(planner):
    legs = _legs(planner)
    ways = stages.legs_shortcut(planner.space, [w for _, _, w in legs], [g for _, g, _ in legs])
    for (_, goal, way), w in zip(legs, ways):
        np.testing.assert_array_equal(w, stages.leg_shortcut(planner.space, way, goal))
    known = [p for _, g, _ in legs for p in g.known()][:1]
    corridors = stages.legs_corridor(planner.space, ways, known=known)
    shots = []
    for (s, goal, _), w, c in zip(legs, ways, corridors):
        one = stages.leg_corridor(planner.space, w, known)
        assert len(c) == len(one)
        np.testing.assert_allclose(c.waypoints.cpu().numpy(), one.waypoints.cpu().numpy(), rtol=0, atol=0)
        traj = stages.leg_trajectory(planner.space, one, s, goal.point)
        shots.append(stages.leg_shot(planner.space, traj, one, TARGET, GO_TO))
    for shot, rep in zip(shots, stages.legs_verify(planner.space, shots)):
        one = stages.leg_verify(planner.space, shot)
        for key in ("num_samples", "max_sample_spacing", "num_inconclusive", "safe"):
            assert rep[key] == one[key]
        assert (rep["min_exact_clearance"] is None) == (one["min_exact_clearance"] is None)
        if one["min_exact_clearance"] is not None:
            assert rep["min_exact_clearance"] == pytest.approx(one["min_exact_clearance"], abs=1e-12)


def test_stop_way_ends_at_the_stop_and_leg_way_as_the_goal_says(planner):
    s = STARTS[0]
    s_ijk, comp = stages.start_voxel(planner.space, s)
    stop = stages.component_goal(planner.space, np.array([-0.5, -0.5, 0.6]), comp)
    way = stages.stop_way(planner.space, s, s_ijk, stop)
    assert np.array_equal(way[0], s) and np.array_equal(way[-1], stop.point)
    goal = stages.component_goal(planner.space, GO_TO, comp)
    leg = stages.leg_way(planner.space, s, s_ijk, goal)
    assert np.array_equal(leg, goal.way_to_shortcut(s, stages.voxel_centres(planner.space, s_ijk, goal.voxel)))
    cache = {}
    assert stages.component_goal(planner.space, GO_TO, comp, cache) is cache[comp]
    assert stages.component_goal(planner.space, GO_TO, comp, cache) is cache[comp]  # found once per component


def test_unsafe_reports_are_refused_with_the_curve_named():
    ok = {"safe": True, "min_exact_clearance": None}
    assert stages.refuse_unsafe(ok) is ok
    with pytest.raises(UnsafeTrajectoryError,
                       match=r"clearance -0\.001 < 0 on a candidate curve; this is a planner bug"):
        stages.refuse_unsafe({"safe": False, "min_exact_clearance": -1e-3}, "a candidate curve")


STAGE_INTERNALS = {
    "coarse_path": {"voxel_path"}, "corridor": {"build_corridor", "build_corridors"}, "safety": {"verify_shot"},
    "reach": {"reachable_goal", "free_voxel_near"}, "trajectory": {"solve_corridor_qp"}, "shot": {"retime_shot"},
}


@pytest.mark.parametrize("module", ["candidates.py", "multistop.py"])
def test_legs_are_planned_only_through_stages(module):
    """ONE shot pipeline: what a leg's stages call is reached through stages.py, and no Planner private is used."""
    tree = ast.parse((Path(stages.__file__).parent / module).read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module in STAGE_INTERNALS:
            assert not STAGE_INTERNALS[node.module] & {a.name for a in node.names}, (module, node.module)
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id == "planner":
            assert not node.attr.startswith("_"), (module, node.attr)


@settings(max_examples=100, deadline=None)
@given(hnp.arrays(np.int64, (st.integers(0, 30)), elements=st.integers(-3, 200)).map(lambda a: a.reshape(-1, 3) if
       a.size % 3 == 0 else a[: a.size - a.size % 3].reshape(-1, 3)),
       st.floats(-100, 100), st.floats(1e-3, 10.0))
def test_voxel_centres_numpy_matches_grid(path, lo0, vs):
    """stages.voxel_centres' numpy spelling of OccupancyGrid.voxel_to_world gives the same bits."""
    lo = np.array([lo0, -0.37 * lo0, 0.1 + lo0 / 7])
    grid = OccupancyGrid(torch.as_tensor(lo), vs, torch.zeros(2, 2, 2, dtype=torch.bool))
    ref = grid.voxel_to_world(torch.as_tensor(path)).cpu().numpy()
    new = lo + (path.astype(np.float64) + 0.5) * vs
    assert ref.shape == new.shape and np.array_equal(ref.view(np.int64), new.view(np.int64))


def test_corner_detours_leave_the_voxel_path_walk_free_where_they_can():
    """config.corner_detours: the voxel path's steps the walk refuses (Prop-2 corridor segments) mostly go; every
    point of the path A* found stays, in order; the shots planned either way are verified safe."""
    from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
    from cinenerf_ns.synthetic.blobs import blob_scene

    b = blob_scene(20000, seed=0)
    scene = EllipsoidScene.from_params(b.splat, device="cpu")
    r = float(scene.camera_radius)
    pl = Planner(scene, PlannerConfig(up=b.up, start_region=(b.free_lo + r, b.free_hi - r), grid_resolution=48))
    prep = pl.prepare()
    assert corridor_options.use_grid_polytopes(pl.space) and pl.config.corner_detours  # the default
    labels = prep.astar_grid.labels
    free = np.argwhere(labels == np.bincount(labels[labels > 0]).argmax())
    rng = np.random.default_rng(0)
    refused = {False: 0, True: 0}
    for _ in range(20):
        a, g = free[rng.integers(len(free))], free[rng.integers(len(free))]
        ways = {}
        for v in (False, True):
            pl.config.corner_detours = v
            ways[v] = stages.voxel_centres(pl.space, a, g)
            refused[v] += int((~prep.voxels.segments_free(ways[v][:-1], ways[v][1:])).sum())
        pos = [int(np.flatnonzero((ways[True] == p).all(1))[0]) for p in ways[False]]
        assert pos == sorted(pos) and pos[0] == 0 and pos[-1] == len(ways[True]) - 1
    assert refused[True] < refused[False] / 4, refused
    for v in (False, True):
        pl.config.corner_detours = v
        shot = pl.plan(b.blobs[0].center, b.blobs[1].center, n_candidates=1, seed=3)[0]
        assert shot.safety["safe"]
