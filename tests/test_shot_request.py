"""One request rule for cinesplat-plan and the viewers (shot_request.py): a given start gives one scored shot (retimed
to limits), random starts give ranked, scored candidates (one included); the CLI and the viewer backend both plan
through it."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.procedural import procedural_room
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig
from cinenerf_ns.planner.trajectory.dynamics import DynamicLimits
from cinenerf_ns.shot_request import ShotRequest, plan_request

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def room():
    r = procedural_room(2000, seed=0)
    scene = EllipsoidScene.from_splat(r.means, r.quats, r.log_scales, r.opacity_logits, SceneConfig())
    pl = Planner(scene, PlannerConfig(grid_resolution=48, start_region=(r.free_lo + 0.03, r.free_hi - 0.03),
                                      candidate_workers=0))
    pl.prepare()
    return r, pl


def test_a_given_start_gives_one_scored_shot_retimed_to_the_limits(room):
    r, pl = room
    goal, look = r.object("armchair").center, r.object("floor lamp").center
    start = pl.plan(goal, look, seed=1)[0].positions[0]  # a free, reachable start
    limits = DynamicLimits(max_speed=0.3)
    ranked = plan_request(pl, ShotRequest(goals=goal[None], look_at=look, start=start, candidates=8, limits=limits))
    assert len(ranked) == 1 and ranked[0].rank == 1 and ranked[0].candidate == 0
    shot = ranked[0].shot
    np.testing.assert_allclose(shot.positions[0], start, atol=1e-9)
    assert np.isfinite(ranked[0].score.total)
    speed = np.linalg.norm(np.diff(shot.positions, axis=0), axis=1) / np.diff(shot.times)
    assert speed.max() <= 0.3 * (1 + 1e-6)


@pytest.mark.parametrize("k", [1, 3])
def test_random_starts_are_ranked_and_scored_one_included(room, k):
    r, pl = room
    goal, look = r.object("armchair").center, r.object("floor lamp").center
    timings = {}
    ranked = plan_request(pl, ShotRequest(goals=goal[None], look_at=look, candidates=k, seed=2), timings)
    assert [x.rank for x in ranked] == list(range(1, len(ranked) + 1)) and 1 <= len(ranked) <= k
    totals = [x.score.total for x in ranked]
    assert totals == sorted(totals) and all(np.isfinite(totals))
    assert "total_ms" in timings


def test_the_cli_and_the_viewer_plan_through_it(room, monkeypatch):
    import cinenerf_ns.shot_request as sr
    from cinenerf_ns.viewer.planner_backend import PreparedPlanner

    r, pl = room
    calls = []
    real = sr.plan_request
    monkeypatch.setattr(sr, "plan_request", lambda planner, req, *a: calls.append(req) or real(planner, req, *a))
    pp = PreparedPlanner(pl.scene, pl.config).start(background=False)
    shots = pp.plan(r.object("armchair").center, r.object("floor lamp").center, seed=4, n_candidates=1)
    assert calls and calls[-1].candidates == 1 and calls[-1].start is None
    assert shots and shots[0].rank == 1 and np.isfinite(shots[0].score)  # one random-start shot is scored too
    import inspect

    import cinenerf_ns.cli.plan_run as cli_plan

    assert "plan_request(" in inspect.getsource(cli_plan._plan_shots)
