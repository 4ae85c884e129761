"""Candidates planned in forked worker processes (workers.py): the same shots, ranks and errors as in this
process; unsafe shots are still refused; the pool is recreated after prepare() and leaves no process behind;
config validation."""
import gc
import multiprocessing as mp

import numpy as np
import pytest
import torch
from _shot_scenes import GO_TO, TARGET, TARGET_RADIUS, walled_target_scene

import cinenerf_ns.planner.shots.candidates as candidates
import cinenerf_ns.planner.shots.stages as stages
from cinenerf_ns.planner.corridor.safe_corridor import CorridorError
from cinenerf_ns.planner.errors import GoalUnreachableError, InvalidInputError, UnsafeTrajectoryError
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.procedural import procedural_room
from cinenerf_ns.planner.shots.candidates import plan_candidates
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig
from cinenerf_ns.planner.shots.workers import fork_available
from cinenerf_ns.planner.trajectory.dynamics import DynamicLimits

pytestmark = pytest.mark.skipif(not fork_available(), reason="candidate workers need the 'fork' start method")

STOP = TARGET_RADIUS + 0.03
REGION = ([-0.9, -0.9, 0.1], [0.9, 0.9, 0.9])


def _planner(workers, scene=None, **kw):
    pl = Planner(scene if scene is not None else walled_target_scene(),
                 PlannerConfig(grid_resolution=48, start_region=REGION, candidate_workers=workers, **kw))
    pl.prepare()
    return pl


@pytest.fixture
def planners():
    a, b = _planner(0), _planner(2)
    yield a, b
    b.close()


def _assert_same(r0, r1):
    assert [x.candidate for x in r0] == [x.candidate for x in r1]
    assert [x.rank for x in r0] == [x.rank for x in r1]
    for x, y in zip(r0, r1):
        np.testing.assert_allclose(x.shot.positions, y.shot.positions, rtol=0, atol=1e-12)
        np.testing.assert_allclose(x.shot.times, y.shot.times, rtol=0, atol=1e-12)
        np.testing.assert_allclose(x.shot.rotations, y.shot.rotations, rtol=0, atol=1e-12)
        assert x.score.total == pytest.approx(y.score.total, rel=1e-12, abs=1e-12)
        assert x.shot.safety == y.shot.safety
        assert len(x.shot.corridor) == len(y.shot.corridor)


@pytest.mark.parametrize("worker_scoring", [True, False])
def test_workers_give_the_same_ranked_shots(planners, monkeypatch, worker_scoring):
    p0, p2 = planners
    p2.config.worker_scoring = worker_scoring
    t0, t2 = {}, {}
    r0 = plan_candidates(p0, GO_TO, TARGET, k=10, seed=3, object_radius=STOP, timings=t0)
    calls = []
    real = candidates.score_shots
    monkeypatch.setattr(candidates, "score_shots",
                        lambda pl, shots, *a: calls.append(len(shots)) or real(pl, shots, *a))
    r2 = plan_candidates(p2, GO_TO, TARGET, k=10, seed=3, object_radius=STOP, timings=t2)
    if worker_scoring:  # the workers computed every shot's score inputs: nothing is scored here
        assert calls == []
    else:  # shots that came back early were scored while the other workers ran (chunks of max(4, k // 4)),
        # the rest after
        assert len(calls) >= 2 and sum(calls) == 10 and calls[0] == 4
    assert len(r0) == 10
    _assert_same(r0, r2)
    assert all(x.shot.safety["safe"] for x in r2)
    assert "pool_ms" not in t0 and t2["workers"] == 2
    for k in ("goal_ms", "astar_ms", "shortcut_ms", "corridor_ms", "qp_ms", "timing_ms", "verify_ms", "pool_ms",
              "score_ms", "total_ms"):
        assert t2[k] >= 0
    assert t2["num_failed"] == t0["num_failed"] == 0


def test_workers_same_with_limits_on_a_procedural_room():
    room = procedural_room(20_000, seed=2)
    scene = EllipsoidScene.from_splat(room.means, room.quats, room.log_scales, room.opacity_logits)
    r = scene.camera_radius
    cfg = dict(grid_resolution=48, start_region=(room.free_lo + r, room.free_hi - r))
    lim = DynamicLimits(max_speed=0.5, max_acceleration=0.5, max_angular_rate_deg=40)
    goal, look = room.objects[0].center, room.objects[1].center
    out = []
    for w in (0, 2):
        pl = Planner(scene, PlannerConfig(candidate_workers=w, **cfg))
        pl.prepare()
        out.append(plan_candidates(pl, goal, look, k=6, seed=5, limits=lim))
        pl.close()
    _assert_same(*out)
    for x, y in zip(*out):
        assert x.shot.dynamics == y.shot.dynamics


def _corridor_fails_left_of_wall(real):
    def build(way, *a, **kw):
        if float(way[0, 0]) < 0:  # deterministic: every start on the walled-off side fails
            raise CorridorError("test: no corridor from this side")
        return real(way, *a, **kw)

    return build


def test_failed_candidates_are_replaced_by_the_same_spares(monkeypatch):
    # patched before the pool forks: the workers inherit the patched module
    monkeypatch.setattr(stages, "build_corridor", _corridor_fails_left_of_wall(stages.build_corridor))  # the leg's
    out, tms = [], []
    for w in (0, 2):
        pl = _planner(w)
        tm = {}
        out.append(plan_candidates(pl, GO_TO, TARGET, k=6, seed=3, object_radius=STOP, spare_fraction=1.0, timings=tm))
        tms.append(tm)
        pl.close()
    _assert_same(*out)
    assert tms[0]["num_failed"] == tms[1]["num_failed"] > 0
    assert all(x.shot.start[0] > 0 for x in out[1])


@pytest.mark.parametrize("workers", [0, 2])
def test_unreachable_goal_errors_are_the_same(monkeypatch, workers):
    def no_path(*a, **kw):
        raise GoalUnreachableError("test: the goal is not connected to the start")

    monkeypatch.setattr(stages, "voxel_path", no_path)  # the leg's A* stage
    pl = _planner(workers)
    with pytest.raises(GoalUnreachableError, match=r"no safe candidate found from 6 start\(s\); last reason: test: "
                                                   r"the goal is not connected"):
        plan_candidates(pl, GO_TO, TARGET, k=4, seed=1, spare_fraction=0.5)
    pl.close()


@pytest.mark.parametrize("workers", [0, 2])
def test_an_unsafe_candidate_is_never_returned(monkeypatch, workers):
    real = stages.legs_verify

    def unsafe(planner, shots):
        reps = real(planner, shots)
        for r in reps:
            r.update(safe=False, min_exact_clearance=-1e-3)
        return reps

    monkeypatch.setattr(stages, "legs_verify", unsafe)  # the legs' batched verification
    pl = _planner(workers)
    with pytest.raises(UnsafeTrajectoryError, match="planner bug"):
        plan_candidates(pl, GO_TO, TARGET, k=3, seed=1)
    pl.close()


def test_pool_lifecycle_no_process_left_behind():
    assert mp.active_children() == []  # every test closes its planners
    pl = _planner(2)
    plan_candidates(pl, GO_TO, TARGET, k=3, seed=0)
    pool = pl.candidate_pool()
    assert pool is pl.candidate_pool() and pool.processes == 2
    assert len(mp.active_children()) == 2
    pl.prepare()  # workers hold the old prepared state: a new pool
    pool2 = pl.candidate_pool()
    assert pool2 is not pool and pool.closed
    assert len(mp.active_children()) == 2
    pl.close()
    assert pool2.closed and mp.active_children() == []
    pl.close()  # idempotent
    plan_candidates(pl, GO_TO, TARGET, k=2, seed=0)  # still usable: forks again
    assert len(mp.active_children()) == 2
    del pl, pool, pool2
    gc.collect()  # the finalizer terminates the workers of a collected planner
    assert mp.active_children() == []


def test_one_candidate_or_zero_workers_use_no_pool():
    pl = _planner(2)
    plan_candidates(pl, GO_TO, TARGET, k=1, seed=0)
    assert mp.active_children() == [] and pl._pool is None
    assert _planner(0).candidate_pool() is None


@pytest.mark.parametrize("bad", [-1, 1.5, "2", True])
def test_config_validation(bad):
    with pytest.raises(InvalidInputError, match="candidate_workers"):
        Planner(walled_target_scene(), PlannerConfig(candidate_workers=bad))
    pl = _planner(0)
    pl.config.candidate_workers = bad  # changed after construction: refused at the request
    with pytest.raises(InvalidInputError, match="candidate_workers"):
        plan_candidates(pl, GO_TO, TARGET, k=2, seed=0)


def test_auto_workers(monkeypatch):
    import cinenerf_ns.planner.shots.workers as workers

    monkeypatch.setattr(workers, "usable_cpus", lambda: 2)
    assert _planner(None).candidate_workers() == 0  # too few CPUs: in this process
    monkeypatch.setattr(workers, "usable_cpus", lambda: 16)
    assert _planner(None).candidate_workers() == 16
    monkeypatch.setattr(workers, "fork_available", lambda: False)
    assert _planner(None).candidate_workers() == 0


@pytest.mark.gpu
def test_no_workers_for_cuda_requests():
    if not torch.cuda.is_available():
        pytest.skip("needs CUDA")
    pl = _planner(2, scene=walled_target_scene().to("cuda"), request_device="scene")
    assert pl.candidate_workers() == 0 and pl.candidate_pool() is None
    pl = _planner(2, scene=walled_target_scene().to("cuda"))  # auto: requests on the CPU mirror
    assert pl.candidate_workers() == 2
    r = plan_candidates(pl, GO_TO, TARGET, k=4, seed=3, object_radius=STOP)  # score inputs in the workers (CPU)
    assert all(x.shot.safety["safe"] for x in r)
    pl.config.worker_scoring = False
    r2 = plan_candidates(pl, GO_TO, TARGET, k=4, seed=3, object_radius=STOP)  # scoring on the GPU, in the parent
    assert [x.candidate for x in r] == [x.candidate for x in r2]
    for x, y in zip(r, r2):  # exact both ways: the capped clearances agree to rounding
        assert x.score.total == pytest.approx(y.score.total, rel=1e-9, abs=1e-9)
    pl.close()


def test_a_dead_worker_falls_back_to_this_process(planners):
    import os
    import signal
    import time

    p0, p2 = planners
    r0 = plan_candidates(p0, GO_TO, TARGET, k=4, seed=7, object_radius=STOP)
    pool = p2.candidate_pool()
    victim = mp.active_children()[0]
    os.kill(victim.pid, signal.SIGKILL)
    victim.join(5)
    time.sleep(0.2)  # the executor notices the dead worker and marks the pool broken
    with pytest.warns(RuntimeWarning, match="worker process died"):
        r2 = plan_candidates(p2, GO_TO, TARGET, k=4, seed=7, object_radius=STOP)
    _assert_same(r0, r2)
    assert pool.closed
    r2 = plan_candidates(p2, GO_TO, TARGET, k=4, seed=7, object_radius=STOP)  # a fresh pool
    _assert_same(r0, r2)
    assert p2.candidate_pool() is not pool


def test_two_phase_rounds_with_the_batched_corridor_give_the_same_shots(monkeypatch):
    """corridor_backend 'batched' (CPU tensors here; a CUDA scene in production): the workers find the ways, this
    process builds every corridor of the round in ONE build_corridors call, the workers solve and verify. Same
    ranked shots as in-process planning with the batched backend (one corridor per candidate)."""
    calls = []
    real = stages.build_corridors

    def spy(ways, *a, **kw):
        calls.append(len(ways))
        return real(ways, *a, **kw)

    monkeypatch.setattr(stages, "build_corridors", spy)  # the legs' batched corridor stage
    # grid polytopes off: with them (the default) whole candidates run in the workers (next test)
    kw = dict(corridor_backend="batched", grid_polytopes=False)
    p0, p2 = _planner(0, **kw), _planner(2, **kw)
    try:
        t2 = {}
        r0 = plan_candidates(p0, GO_TO, TARGET, k=8, seed=5, object_radius=STOP)
        r2 = plan_candidates(p2, GO_TO, TARGET, k=8, seed=5, object_radius=STOP, timings=t2)
    finally:
        p2.close()
    assert len(r0) == 8
    _assert_same(r0, r2)
    assert calls and calls[0] == 8  # one call for the whole first round
    assert t2["corridor_ms"] >= 0 and t2["workers"] == 2


def test_grid_polytopes_with_the_batched_backend_plan_whole_candidates_in_the_workers(monkeypatch):
    """With grid polytopes (the default) the batched backend's two-phase rounds are not used: the workers plan whole
    candidates (their corridors mostly from the grid and the goal's polytope); same ranked shots as in-process."""
    calls = []
    monkeypatch.setattr(stages, "build_corridors", lambda *a, **kw: calls.append(1))
    kw = dict(corridor_backend="batched", grid_polytopes=True)
    p0, p2 = _planner(0, **kw), _planner(2, **kw)
    try:
        r0 = plan_candidates(p0, GO_TO, TARGET, k=6, seed=7, object_radius=STOP)
        r2 = plan_candidates(p2, GO_TO, TARGET, k=6, seed=7, object_radius=STOP)
    finally:
        p2.close()
    assert not calls
    _assert_same(r0, r2)
    assert sum(r.shot.corridor.n_grid_segments for r in r2) > 0


def test_imap_unordered_returns_every_result_with_its_index():
    pl = _planner(2)
    try:
        pool = pl.candidate_pool()
        got = dict(pool.imap_unordered(isinstance, [(int,), (Planner,), (str,), (Planner,)]))
        assert got == {0: False, 1: True, 2: False, 3: True}
    finally:
        pl.close()


def _lazy_modules_loaded(planner) -> list:
    import sys

    return [m in sys.modules for m in ("scipy.optimize", "scipy.optimize._linprog_highs", "scipy.linalg")]


def test_workers_inherit_the_lazily_imported_libraries(monkeypatch):
    """The pool loads scipy.optimize (HiGHS) etc. before it forks, so no worker pays the import in a request."""
    from cinenerf_ns.planner.shots import workers

    calls = []
    real = workers._preload
    monkeypatch.setattr(workers, "_preload", lambda: calls.append(len(mp.active_children())) or real())
    pl = _planner(2)
    try:
        before = len(mp.active_children())
        pool = pl.candidate_pool()
        assert calls == [before]  # once, before the workers were forked
        assert pool.map(_lazy_modules_loaded, [(), ()]) == [[True, True, True]] * 2
    finally:
        pl.close()


@pytest.mark.parametrize("worker_scoring", [True, False])
def test_workers_with_a_subject_give_the_same_visibility_and_get_no_subject(planners, monkeypatch, worker_scoring):
    """Scored by a subject's visibility: the same ranked shots and visible fractions as in this process; with
    worker_scoring the workers leave the visibility to this process (one call for the round) and their tasks carry
    no subject (its members and classes would be pickled to every worker)."""
    from cinenerf_ns.planner.geometry.visibility import SubjectSamples
    from cinenerf_ns.planner.shots.end_pose import visibility_volume

    p0, p2 = planners
    p2.config.worker_scoring = worker_scoring
    vol = visibility_volume(p0)
    near = np.flatnonzero(np.linalg.norm(vol.means - np.asarray(TARGET), axis=1) < 0.25)
    assert near.size > 0
    subject = SubjectSamples.of_members(vol, near, 16)
    r0 = plan_candidates(p0, GO_TO, TARGET, k=6, seed=5, object_radius=STOP, subject=subject)
    import cinenerf_ns.planner.shots.workers as workers

    sent = []
    real = workers._task
    monkeypatch.setattr(workers, "_task", lambda fn, a: sent.append(a) or real(fn, a))
    r2 = plan_candidates(p2, GO_TO, TARGET, k=6, seed=5, object_radius=STOP, subject=subject)
    assert sent, "no task went to the workers"
    _assert_same(r0, r2)
    for x, y in zip(r0, r2):
        np.testing.assert_array_equal(x.score.visibility, y.score.visibility)
        assert x.score.terms["visible_last"] == y.score.terms["visible_last"]
    for a in sent:  # the tasks the pool was handed
        assert not any(isinstance(v, SubjectSamples) for v in a)
        if worker_scoring:
            assert not any(isinstance(v, SubjectSamples) for v in a[-1]) and a[-1][-1] is True  # visibility_later


@pytest.mark.parametrize("with_subject", [False, True])
def test_two_phase_rounds_score_in_the_workers(monkeypatch, with_subject):
    """In two-phase rounds the workers also compute their shots' score parts (worker_scoring, on the CPU copy):
    nothing is scored by score_shots in this process, a subject's visibility is added here in one call, and the
    ranked shots and scores are those of in-process planning."""
    from cinenerf_ns.planner.geometry.visibility import SubjectSamples
    from cinenerf_ns.planner.shots.end_pose import visibility_volume

    kw = dict(corridor_backend="batched", grid_polytopes=False)
    p0, p2 = _planner(0, **kw), _planner(2, **kw)
    try:
        subject = None
        if with_subject:
            vol = visibility_volume(p0)
            subject = SubjectSamples.of_members(
                vol, np.flatnonzero(np.linalg.norm(vol.means - np.asarray(TARGET), axis=1) < 0.25), 16)
        r0 = plan_candidates(p0, GO_TO, TARGET, k=8, seed=5, object_radius=STOP, subject=subject)
        calls, strategies = [], []
        real_score, real_strategy = candidates.score_shots, candidates._round_strategy
        monkeypatch.setattr(candidates, "score_shots", lambda pl, shots, *a: calls.append(len(shots)) or
                            real_score(pl, shots, *a))
        monkeypatch.setattr(candidates, "_round_strategy", lambda req: strategies.append(real_strategy(req)) or
                            strategies[-1])
        r2 = plan_candidates(p2, GO_TO, TARGET, k=8, seed=5, object_radius=STOP, subject=subject)
    finally:
        p2.close()
    assert strategies and all(f is candidates._round_two_phase for f in strategies)
    assert calls == []  # every shot was scored from the workers' parts
    _assert_same(r0, r2)
    for x, y in zip(r0, r2):
        assert x.score.terms == pytest.approx(y.score.terms, rel=1e-12, abs=1e-12)
