"""Batched candidates: verified safe, ranked by the documented score, views from the open side of a
walled-off target first; the batched scores equal score_shot's; the batched shortcut equals the
sequential one; seeded; specific errors."""
import functools
import math

import numpy as np
import pytest
import torch
from _shot_scenes import GO_TO, TARGET, TARGET_RADIUS, walled_target_scene

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.geometry.distance import clearance
from cinenerf_ns.planner.search.astar import shortcut
from cinenerf_ns.planner.search.shortcut import segments_free
from cinenerf_ns.planner.shots.candidates import batched_shortcut, plan_candidates
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig
from cinenerf_ns.planner.shots.scoring import ScoreConfig, score_shot
from cinenerf_ns.planner.trajectory.dynamics import DynamicLimits

STOP = TARGET_RADIUS + 0.03


@pytest.fixture(scope="module")
def planner():
    pl = Planner(walled_target_scene(),
                 PlannerConfig(grid_resolution=48, start_region=([-0.9, -0.9, 0.1], [0.9, 0.9, 0.9])))
    pl.prepare()
    return pl


@pytest.fixture(scope="module")
def ranked(planner):
    tm = {}
    r = plan_candidates(planner, GO_TO, TARGET, k=10, seed=3, object_radius=STOP, timings=tm)
    return r, tm


def test_open_side_ranks_first(ranked):
    r, _ = ranked
    assert [x.rank for x in r] == list(range(1, len(r) + 1))
    totals = [x.score.total for x in r]
    assert totals == sorted(totals)
    open_side = np.array([x.shot.start[0] > 0 for x in r])
    assert open_side.any() and (~open_side).any(), "the seed must give starts on both sides"
    assert open_side[0]
    ranks = np.arange(1, len(r) + 1)
    assert ranks[open_side].mean() < ranks[~open_side].mean()
    occ = np.array([x.score.terms["occluded_fraction"] for x in r])
    assert occ[open_side].mean() < occ[~open_side].mean()


def test_random_starts_keep_away_from_the_look_at(planner, ranked):
    r, _ = ranked
    side = 1.8  # the fixture's start region's longest side
    d = np.array([np.linalg.norm(x.shot.start - TARGET) for x in r])
    assert d.min() >= planner.config.start_look_distance * side - 1e-12


def test_candidates_are_safe_and_aim(planner, ranked):
    r, tm = ranked
    assert len(r) == 10
    for x in r:
        assert x.shot.safety["safe"]
        c = clearance(torch.as_tensor(x.shot.positions[::4]), planner.scene, planner.prepared.index)
        assert float(c.min()) >= 0
        assert np.max(x.shot.look_at_errors_deg()) < 0.01
        assert np.linalg.norm(x.shot.positions[-1] - x.shot.goal) < 1e-9
    for k in ("start_sample_ms", "astar_ms", "shortcut_ms", "corridor_ms", "qp_ms", "verify_ms", "score_ms",
              "total_ms"):
        assert tm[k] >= 0
    d = r[0].to_dict()
    assert d["rank"] == 1 and "terms" in d["score"] and d["verification"]["safe"]


def test_batched_scores_equal_single_scores(planner, ranked):
    r, _ = ranked
    cfg = ScoreConfig()
    for x in r[:3]:
        assert x.shot.clearance is None
        s = score_shot(x.shot, planner.scene, TARGET, cfg, index=planner.prepared.index, object_radius=STOP,
                       clearance_fn=planner.clearance)
        # score_shot takes every frame's clearance, the batched scorer the scored frames' only
        idx = x.score.tested_frame_index
        assert np.array_equal(s.tested_frame_index, idx)
        for k in ("occluded_fraction", "framing_size_error", "max_jerk", "mean_angular_rate_deg", "duration_s"):
            assert math.isclose(s.terms[k], x.score.terms[k], rel_tol=1e-12, abs_tol=1e-12)
        assert x.score.terms["min_clearance"] >= s.terms["min_clearance"] - 1e-12


def test_batched_shortcut_equals_sequential(planner):
    rng = np.random.default_rng(0)
    paths = [np.cumsum(rng.uniform(-0.08, 0.08, (n, 3)), 0) + np.array([0.5, 0.0, 0.5]) for n in (2, 3, 9, 14)]
    free = functools.partial(segments_free, planner.space)
    got = batched_shortcut(paths, free)
    for p, g in zip(paths, got):
        assert np.array_equal(g, shortcut(p, free))


def test_seeded_and_limits(planner):
    a = plan_candidates(planner, GO_TO, TARGET, k=3, seed=11, object_radius=STOP)
    lim = DynamicLimits(max_speed=0.3, max_acceleration=0.3, max_angular_rate_deg=25)
    b = plan_candidates(planner, GO_TO, TARGET, k=3, seed=11, object_radius=STOP, limits=lim)
    assert sorted(x.candidate for x in a) == sorted(x.candidate for x in b)
    sa = {x.candidate: x.shot.start for x in a}
    for x in b:
        assert np.allclose(sa[x.candidate], x.shot.start)
        assert x.shot.dynamics["peak_speed"] <= 0.3 and x.shot.dynamics["peak_angular_rate_deg"] <= 25
        assert x.shot.safety["safe"]


def test_bad_input(planner):
    with pytest.raises(InvalidInputError, match="candidates"):
        plan_candidates(planner, GO_TO, TARGET, k=0)
    with pytest.raises(InvalidInputError, match="go-to"):
        plan_candidates(planner, [0, np.nan, 0], TARGET, k=2)
    with pytest.raises(InvalidInputError, match="object_radius"):
        plan_candidates(planner, GO_TO, TARGET, k=2, object_radius=-1)


@pytest.mark.gpu
def test_gpu_scene_candidates_score_on_the_gpu_and_match_cpu(ranked):
    if not torch.cuda.is_available():
        pytest.skip("needs CUDA")
    pl = Planner(walled_target_scene().to("cuda"),
                 PlannerConfig(grid_resolution=48, start_region=([-0.9, -0.9, 0.1], [0.9, 0.9, 0.9])))
    pl.prepare()
    assert pl.scene.device.type == "cpu" and pl.prepared.batch_index.device.type == "cuda"
    r = plan_candidates(pl, GO_TO, TARGET, k=10, seed=3, object_radius=STOP)
    cpu, _ = ranked
    assert len(r) == len(cpu)
    assert all(x.shot.safety["safe"] for x in r)
    # same starts (seeded) and the same scores up to float rounding
    np.testing.assert_allclose(sorted(x.score.total for x in r), sorted(x.score.total for x in cpu), rtol=1e-4,
                               atol=1e-6)
