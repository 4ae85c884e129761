"""K candidate shots for one go-to / look-at, planned in one call with batched stages, scored and ranked.

The same leg stages as Planner.plan (stages.py; every returned shot is verified safe), with the expensive collision
work done once for all K candidates instead of K times:

  start sampling   one sample_free_starts call for K (+ spares) starts
  goal             one closest-safe-point search per free component (cached), not per candidate
  A*               per candidate (a sequential graph search on the CPU voxel grid)
  shortcut         lock-step line-of-sight pruning: each round tests ALL candidates' segments in one call
  corridor         per polytope (two-pass safe_polytope), or the grid's polytopes (corridor/grid_polytope.py)
  QP               back to back; the constant per-degree matrices are cached (trajectory/bezier.py)
  timing           per candidate, optionally retimed under DynamicLimits (dynamics.py)
  verification     dense samples of all K curves in ONE conservative call, exact clearance of the inconclusive
                   samples in one call (stages.legs_verify: the rule of safety.verify_shot)
  scoring          sight lines (or a subject's visibility) and exact clearance of all K x scored frames in one
                   call each, then score_terms per candidate (scoring.py, candidate_scores.py)

Planning runs on the planner's request device (a CPU mirror of a GPU scene); scoring on the scene's own device.

A request runs in rounds, each planning as many unused starts as shots are still missing (spares replace failed
candidates), by one of three strategies (_round_strategy):
  _round_in_process     the stages above, batched across the round's candidates, in this process;
  _round_in_workers     whole candidates in forked worker processes (PlannerConfig.candidate_workers, workers.py),
                        one per task on one thread: parallel over CPUs, per candidate rather than lock-step;
  _round_two_phase      when this process builds batched corridors (a CUDA scene, grid polytopes off): workers
                        find the ways, this process builds every corridor of the round at once, workers finish.
The workers are forked after prepare() and share its CPU state copy-on-write (fork only: on macOS / Windows
candidates are planned in this process); CUDA is never used in a worker. With PlannerConfig.worker_scoring (the
default) each worker also computes its shot's score inputs on the CPU copy (score_parts, compiled searches) and this
process combines them, adding a subject's visibility for the whole round in one threaded call; otherwise this process
scores, shots that come back early in chunks (EARLY_SCORE_MIN). Results equal the in-process path's (same starts,
shots and ranks; on a GPU scene score terms agree to rounding). With workers, ``timings``' stage keys are sums of the
workers' wall times (they overlap) and ``pool_ms`` is this process's wall time waiting for them.
"""
from __future__ import annotations

import functools
import math
import time
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional

import numpy as np
import torch

from ..config import MAX_CANDIDATES
from ..corridor.corridor_options import corridor_backend, use_grid_polytopes
from ..corridor.safe_corridor import CorridorError
from ..errors import GoalUnreachableError, InvalidInputError, PlanningError, StartInCollisionError
from ..geometry.visibility import SubjectSamples
from ..search.astar import batched_shortcut  # noqa: F401 (re-exported: part of the candidates API)
from ..search.starts import random_starts
from ..trajectory.dynamics import DynamicLimits
from . import stages
from .candidate_scores import score_from_parts, score_parts, score_shots, with_visibility
from .planner import Planner
from .scoring import ScoreConfig, ShotScore
from .shot import Shot
from .workers import BrokenProcessPool, CandidatePool


@dataclass
class RankedShot:
    """One candidate: its rank (1 = best, lowest score total), the shot and its score."""

    rank: int
    shot: Shot
    score: ShotScore
    candidate: int  # index of the candidate's start among the sampled starts (stable across scorings)

    def to_dict(self, include_frames: bool = False) -> Dict[str, Any]:
        """Shot.to_dict with the rank, the candidate, the score and the shot's dynamics / verification."""
        d = self.shot.to_dict(include_frames)
        d.update({"rank": self.rank, "candidate": self.candidate, "score": self.score.to_dict()})
        if self.shot.dynamics is not None:
            d["dynamics"] = self.shot.dynamics
        if self.shot.safety is not None:
            d["verification"] = self.shot.safety
        return d


def _lapper(tm: Dict[str, float]):
    """lap(name, t0): adds the ms since t0 to tm[name] and returns now (per-stage timings of a request or task)."""

    def lap(name, t0):
        tm[name] = tm.get(name, 0.0) + 1e3 * (time.perf_counter() - t0)
        return time.perf_counter()

    return lap


EARLY_SCORE_MIN = 4
"""Worker rounds score finished shots in chunks of max(this, k // 4) while other workers still run (a huge value:
score everything after the round)."""


def _merge_task_results(ids: List[int], results: List[Dict[str, Any]], tm: Dict[str, float],
                        cache_of: Callable[[int], Dict[int, Any]], errors: List[str]) -> List[tuple]:
    """Worker task results -> this request: their stage times added to tm, the goals they found to their candidate's
    goal cache (cache_of(id)), their failures to errors. Returns [(id, result)] of the tasks that succeeded, in
    order."""
    ok = []
    for i, res in zip(ids, results):
        for name, ms in res["timings"].items():
            tm[name] = tm.get(name, 0.0) + ms
        cache_of(i).update(res.get("goal_cache", {}))
        if res["error"] is not None:
            errors.append(res["error"])
        else:
            ok.append((i, res))
    return ok

def _candidate_way(planner: Planner, start: np.ndarray, goal_p: np.ndarray, goal_cache: Dict[int, Any], lap,
                   t: float):
    """Goal and voxel path of one candidate: (reach.ReachableGoal, polyline [K, 3] for the shortcut (its
    way_to_shortcut), t). The goal is found once per free component (goal_cache). Laps goal_ms and astar_ms.
    Raises GoalUnreachableError / StartInCollisionError. The leg's stages (stages.leg_goal, leg_way)."""
    goal, s_ijk = stages.leg_goal(planner.space, start, goal_p, goal_cache)
    t = lap("goal_ms", t)
    way = stages.leg_way(planner.space, start, s_ijk, goal, stages.CANDIDATE_DETOUR_EXPANSIONS)
    return goal, way, lap("astar_ms", t)


def _candidate_trajectory(planner: Planner, way: np.ndarray, start: np.ndarray, g: np.ndarray, lap, t: float,
                          known=()):
    """Corridor and Bezier QP of one shortcut polyline: (corridor, trajectory, t). Laps corridor_ms and qp_ms.
    known: the goal's polytope (ReachableGoal.known()). Raises CorridorError / PlanningError. The leg's stages
    (stages.leg_corridor: 'cpu' backend in a worker; stages.leg_trajectory)."""
    corridor = stages.leg_corridor(planner.space, way, known)
    t = lap("corridor_ms", t)
    return corridor, stages.leg_trajectory(planner.space, corridor, start, g), lap("qp_ms", t)


def _plan_candidate_task(planner: Planner, config, start: np.ndarray, goal_p: np.ndarray, look_p: np.ndarray,
                         goal_cache: Dict[int, Any], limits: Optional[DynamicLimits],
                         score: Optional[tuple] = None) -> Dict[str, Any]:
    """One candidate, whole, in a worker process (workers.py): the in-process rounds' stages for a single
    start, on the planner's CPU state only (never batch=True / batch_scene: no CUDA after fork).

    Returns {"shot": verified Shot (report in shot.safety) or None, "error": the failure message or None,
    "timings": per-stage ms, "goal_cache": goals found here for components the parent had not cached,
    "score_parts": the shot's score_parts entry (on the CPU copy) when ``score`` = (ScoreConfig, object_radius,
    object_samples, exclude, visibility_later) is given, else None; with visibility_later (a subject) the parent adds
    the visibility: candidate_scores.with_visibility}. The failures caught are exactly those the in-process path
    records and replaces with a spare; anything else propagates to the parent."""
    way = _candidate_way_task(planner, config, start, goal_p, goal_cache)  # sets the request's config
    out = {"shot": None, "error": way["error"], "timings": way["timings"], "goal_cache": way["goal_cache"]}
    if way["error"] is not None:
        return out
    t = time.perf_counter()
    try:  # the corridor here, in the worker ('cpu' backend: no CUDA after fork)
        corridor = stages.leg_corridor(planner.space, way["way"], way["known"])
    except (GoalUnreachableError, PlanningError) as e:  # CorridorError and the rest, as in-process
        out["error"] = str(e)
        return out
    _lapper(out["timings"])("corridor_ms", t)
    fin = _candidate_finish_task(planner, config, corridor, start, way["goal"], look_p, goal_p, limits)
    for name, ms in fin["timings"].items():
        out["timings"][name] = out["timings"].get(name, 0.0) + ms
    out.update(shot=fin["shot"], error=fin["error"], score_parts=None)
    _worker_score(planner, out, look_p, score)
    return out


def _worker_score(planner: Planner, out: Dict[str, Any], look_p: np.ndarray, score: Optional[tuple]) -> None:
    """In a worker: out["score_parts"] = the safe shot's score_parts entry on the CPU copy when ``score`` =
    (ScoreConfig, object_radius, object_samples, exclude, visibility_later) is given (_worker_score_args)."""
    if score is None or out.get("shot") is None or not out["shot"].safety["safe"]:
        return
    t = time.perf_counter()
    cfg, object_radius, object_samples, exclude, visibility_later = score
    out["score_parts"] = score_parts(planner, [out["shot"]], look_p, cfg, object_radius, object_samples, exclude,
                                     batch=False, visibility_later=visibility_later)[0]
    _lapper(out["timings"])("score_ms", t)


def _candidate_way_task(planner: Planner, config, start: np.ndarray, goal_p: np.ndarray,
                        goal_cache: Dict[int, Any]) -> Dict[str, Any]:
    """Phase 1 of a candidate in a worker when the parent builds the corridors (_round_two_phase): goal, voxel path,
    shortcut. Returns {"goal", "way" [K, 3], "known" (the goal's polytope, see ReachableGoal), "error", "timings",
    "goal_cache"} (error: the message of a failure the in-process path would record, else None)."""
    planner.config = config
    tm: Dict[str, float] = {}
    known = set(goal_cache)
    lap = _lapper(tm)

    def result(goal, way, error) -> Dict[str, Any]:
        new_goals = {c: v for c, v in goal_cache.items() if c not in known}
        return {"goal": None if goal is None else goal.point, "way": way, "known": [] if goal is None else goal.known(),
                "error": error, "timings": tm, "goal_cache": new_goals}

    t = time.perf_counter()
    try:
        goal, way, t = _candidate_way(planner, start, goal_p, goal_cache, lap, t)
    except (GoalUnreachableError, StartInCollisionError) as e:
        return result(None, None, str(e))
    way = stages.leg_shortcut(planner.space, way, goal)  # == stages.legs_shortcut on this path alone (tested)
    lap("shortcut_ms", t)
    if stages.at_goal_already(way):
        return result(None, None, "the start is already at the goal")
    return result(goal, way, None)


def _candidate_finish_task(planner: Planner, config, corridor, start: np.ndarray, g: np.ndarray, look_p: np.ndarray,
                           goal_p: np.ndarray, limits: Optional[DynamicLimits],
                           score: Optional[tuple] = None) -> Dict[str, Any]:
    """Phase 2 of a candidate in a worker: the QP in the parent's corridor, timing, dense verification, and the score
    parts when ``score`` is given (_worker_score). Returns {"shot" (report in shot.safety) or None, "error",
    "timings"[, "score_parts"]}."""
    planner.config = config
    tm: Dict[str, float] = {}
    lap = _lapper(tm)

    t = time.perf_counter()
    try:
        traj = stages.leg_trajectory(planner.space, corridor, start, g)
    except (GoalUnreachableError, PlanningError) as e:
        return {"shot": None, "error": str(e), "timings": tm}
    t = lap("qp_ms", t)
    sh = stages.leg_shot(planner.space, traj, corridor, look_p, goal_p, limits)
    t = lap("timing_ms", t)
    sh.safety = stages.legs_verify(planner.space, [sh])[0]  # the parent refuses unsafe shots (stages.refuse_unsafe)
    lap("verify_ms", t)
    out = {"shot": sh, "error": None, "timings": tm, "score_parts": None}
    _worker_score(planner, out, look_p, score)
    return out


def _with_request_threads(fn):
    """Run fn(planner, ...) under the planner's request thread setting (Planner.request_threads)."""

    @functools.wraps(fn)
    def wrapper(planner: Planner, *args, **kwargs):
        with planner.request_threads():
            return fn(planner, *args, **kwargs)

    return wrapper


@_with_request_threads
def plan_candidates(
    planner: Planner,
    goal: Any,
    look_at: Any,
    k: int = 16,
    seed: int = 0,
    score_config: Optional[ScoreConfig] = None,
    *,
    limits: Optional[DynamicLimits] = None,
    object_radius: float = 0.1,
    object_center: Optional[Any] = None,
    object_samples: Optional[Any] = None,
    exclude: Optional[torch.Tensor] = None,
    spare_fraction: float = 0.5,
    timings: Optional[Dict[str, float]] = None,
    time_budget_s: Optional[float] = None,
    subject: Optional[SubjectSamples] = None,
) -> List[RankedShot]:
    """Plan up to ``k`` verified-safe shots from different seeded random starts, all ending as close as
    safely possible to ``goal`` and looking at ``look_at``; score them (scoring.py) and return them ranked
    best first (rank 1 = lowest ScoreConfig total). ``goal``: one point [3], or P points [P, 3] (end poses,
    end_pose.py): the candidate of start i ends at goal[i % P].

    limits: retime every shot under DynamicLimits (peaks in ``shot.dynamics``); None: the planner's
    TimingConfig. object_radius / object_center / object_samples / exclude: the look-at object, see
    scoring.score_shot; ``subject``: samples of the look-at object's Gaussians (geometry/visibility.py): occlusion is
    then its visible fraction. spare_fraction: extra starts sampled to replace candidates that fail (unreachable
    goal from that start, corridor failure); fewer than k shots come back only if the spares run out.
    timings: optional dict filled with per-stage milliseconds (summed over candidates) and the total; with
    worker processes (PlannerConfig.candidate_workers, see the module docstring) also pool_ms (wall time of
    the parallel rounds), pool_start_ms (forking, first request only) and workers (their number).
    time_budget_s: once this much time has passed and at least one shot is planned, no further candidate is started
    (fewer come back; timings["budget_stopped"] = 1). None: no budget.
    Raises InvalidInputError (bad input) and GoalUnreachableError (no candidate could be planned)."""
    kw = dict(limits=limits, object_radius=object_radius, object_center=object_center, object_samples=object_samples,
              exclude=exclude, spare_fraction=spare_fraction, timings=timings, time_budget_s=time_budget_s,
              subject=subject)
    try:
        return _plan_candidates(planner, goal, look_at, k, seed, score_config, use_workers=True, **kw)
    except BrokenProcessPool:
        # a worker died (killed, out of memory): the request is deterministic, so plan it again here
        planner.close()
        warnings.warn("a candidate worker process died; this request was planned in-process (the next one forks new "
                      "workers; set PlannerConfig.candidate_workers=0 to stay in-process)", RuntimeWarning)
        return _plan_candidates(planner, goal, look_at, k, seed, score_config, use_workers=False, **kw)

@dataclass
class _CandidateRequest:
    """One plan_candidates call while it runs: its checked inputs, the sampled starts [n_try, 3], what the rounds
    have planned so far (shots and their candidate ids, failures, goals per free component, early scores) and the
    per-stage milliseconds ``tm`` (laps of ``lap``)."""

    planner: Planner
    goal_p: np.ndarray  # [P, 3] the go-to points: candidate i ends at goal_p[i % P] (end poses, or one go-to)
    look_p: np.ndarray  # [3] the look-at point
    k: int
    limits: Optional[DynamicLimits]
    score_config: Optional[ScoreConfig]
    object_radius: float
    object_center: Optional[Any]
    object_samples: Optional[Any]
    exclude: Optional[torch.Tensor]
    time_budget_s: Optional[float]
    t_all: float  # when the request started (its time budget and total_ms)
    subject: Optional[SubjectSamples] = None  # samples of the look-at object: occlusion by visibility (scoring.py)
    pool: Optional[CandidatePool] = None  # None: every round in this process
    starts: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # [n_try, 3]
    tm: Dict[str, float] = field(default_factory=dict)
    errors: List[str] = field(default_factory=list)
    goal_caches: List[Dict[int, Any]] = field(default_factory=list)  # per go-to point: free component -> goal
    shots: List[Shot] = field(default_factory=list)
    cand_ids: List[int] = field(default_factory=list)  # the start index of each shot
    early_scores: Dict[int, Any] = field(default_factory=dict)  # candidate id -> ShotScore scored while workers ran

    def __post_init__(self) -> None:
        self.lap = _lapper(self.tm)
        self.goal_caches = [{} for _ in range(len(self.goal_p))]

    def goal_of(self, cand: int) -> np.ndarray:
        """The go-to point [3] of candidate ``cand`` (its start's index)."""
        return self.goal_p[cand % len(self.goal_p)]

    def cache_of(self, cand: int) -> Dict[int, Any]:
        """The goal cache (free component -> ReachableGoal) of candidate ``cand``'s go-to point."""
        return self.goal_caches[cand % len(self.goal_p)]

    def over_budget(self) -> bool:
        """The time budget is spent and a shot exists: start no further candidate (timings' budget_stopped)."""
        if self.time_budget_s is None or not self.shots or time.perf_counter() - self.t_all < self.time_budget_s:
            return False
        self.tm["budget_stopped"] = 1.0
        return True

    def add(self, cand: int, shot: Shot) -> None:
        self.shots.append(shot)
        self.cand_ids.append(cand)


def _round_in_process(req: _CandidateRequest, batch: List[int], t: float) -> float:
    """Plan the candidates of the starts ``batch`` in this process, each stage batched across them where it can be
    (one lock-step shortcut for all). Returns the time of the last lap."""
    planner, lap = req.planner, req.lap
    plans: List[Dict[str, Any]] = []  # start, goal, waypoints of each candidate of this round
    for ci in batch:
        s = req.starts[ci]
        try:
            goal, way, t = _candidate_way(planner, s, req.goal_of(ci), req.cache_of(ci), lap, t)
            plans.append({"cand": ci, "start": s, "reach": goal, "way": way})
        except (GoalUnreachableError, StartInCollisionError) as e:
            req.errors.append(str(e))
            t = time.perf_counter()
    ways = stages.legs_shortcut(planner.space, [p["way"] for p in plans], [p["reach"] for p in plans])
    t = lap("shortcut_ms", t)
    for p, way in zip(plans, ways):
        if req.over_budget():
            break
        if stages.at_goal_already(way):
            req.errors.append("the start is already at the goal")
            continue
        try:
            corridor, traj, t = _candidate_trajectory(planner, way, p["start"], p["reach"].point, lap, t,
                                                      known=p["reach"].known())
        except (GoalUnreachableError, CorridorError, PlanningError) as e:
            req.errors.append(str(e))
            t = time.perf_counter()
            continue
        req.add(p["cand"], stages.leg_shot(planner.space, traj, corridor, req.look_p, req.goal_of(p["cand"]),
                                           req.limits))
        t = lap("timing_ms", t)
    return t


def _round_in_workers(req: _CandidateRequest, batch: List[int], t: float) -> float:
    """Plan whole candidates of the starts ``batch`` in the worker pool; the *_ms stage keys are then sums of the
    workers' wall times per stage (they overlap), pool_ms is this process's wall time waiting for the round (scoring
    excluded). With worker_scoring each worker also computes its shot's score inputs (score_parts on the CPU copy,
    compiled searches) and this process only combines them; otherwise shots that come back early are scored here
    while the other workers still run (scores are per shot, so chunks give the same scores as one call); score_ms
    sums these calls."""
    cfg, lap = req.planner.config, req.lap
    results: List[Any] = [None] * len(batch)
    ready: List[int] = []  # positions in batch of finished, successful tasks not scored yet
    chunk = max(EARLY_SCORE_MIN, req.k // 4)
    score_cfg = req.score_config or ScoreConfig()
    score_cfg.validate()
    later = req.subject is not None
    score_args = _worker_score_args(req, score_cfg)
    tasks = [(cfg, req.starts[ci], req.goal_of(ci), req.look_p, req.cache_of(ci), req.limits, score_args)
             for ci in batch]
    waiting: List[int] = []  # positions in batch of shots whose parts wait for the subject's visibility
    for done, (i, res) in enumerate(req.pool.imap_unordered(_plan_candidate_task, tasks), 1):
        results[i] = res
        if res["error"] is None and res.get("score_parts") is not None and later:
            waiting.append(i)
            continue
        if res["error"] is None and res.get("score_parts") is not None:
            t_s = time.perf_counter()
            req.early_scores[batch[i]] = score_from_parts(res["shot"], res["score_parts"], req.look_p, score_cfg,
                                                          req.object_radius, req.object_center)
            lap("score_ms", t_s)
            t += time.perf_counter() - t_s  # not pool time
            continue
        if res["error"] is None:
            ready.append(i)
        if len(ready) >= chunk and done < len(batch):
            t_s = time.perf_counter()
            sc = score_shots(req.planner, [results[j]["shot"] for j in ready], req.look_p, req.score_config,
                             req.object_radius, req.object_center, req.object_samples, req.exclude, req.subject)
            req.early_scores.update({batch[j]: x for j, x in zip(ready, sc)})
            ready = []
            lap("score_ms", t_s)
            t += time.perf_counter() - t_s  # not pool time
    if waiting:
        t_s = time.perf_counter()
        _scores_of_parts(req, [(batch[j], results[j]) for j in waiting], score_cfg)
        lap("score_ms", t_s)
        t += time.perf_counter() - t_s  # not pool time
    for ci, res in _merge_task_results(batch, results, req.tm, req.cache_of, req.errors):
        req.add(ci, res["shot"])
    return lap("pool_ms", t)


def _worker_score_args(req: _CandidateRequest, score_cfg: ScoreConfig) -> Optional[tuple]:
    """What a worker needs to compute its shot's score parts (_worker_score), None without worker_scoring. A
    subject's visibility is added in this process for the whole round at once (_scores_of_parts): the workers get no
    subject to unpickle (its members and classes are O(K) and O(N) bytes, per task)."""
    if not req.planner.config.worker_scoring:
        return None
    return (score_cfg, req.object_radius, req.object_samples,
            None if req.exclude is None else torch.as_tensor(req.exclude).cpu(), req.subject is not None)


def _scores_of_parts(req: _CandidateRequest, done: List[tuple], score_cfg: ScoreConfig) -> None:
    """req.early_scores[ci] for each (ci, task result with score_parts) of ``done``, the subject's visibility added
    for all of them in one call first when the request has a subject."""
    shots = [res["shot"] for _, res in done]
    parts = [res["score_parts"] for _, res in done]
    if req.subject is not None and done:
        parts = with_visibility(req.planner, shots, parts, req.subject, score_cfg)
    for (ci, _), shot, part in zip(done, shots, parts):
        req.early_scores[ci] = score_from_parts(shot, part, req.look_p, score_cfg, req.object_radius,
                                                req.object_center)


def _round_two_phase(req: _CandidateRequest, batch: List[int], t: float) -> float:
    """Plan the candidates of the starts ``batch`` in two phases around ONE batched corridor computation for the
    whole round (this process can use the GPU, the workers cannot): workers find the ways, this process builds every
    corridor at once (stages.legs_corridor), the workers solve the QPs and verify. Same shots as in-process with the
    batched backend."""
    cfg, lap = req.planner.config, req.lap
    ph1 = req.pool.map(_candidate_way_task, [(cfg, req.starts[ci], req.goal_of(ci), req.cache_of(ci)) for ci in batch])
    ways = _merge_task_results(batch, ph1, req.tm, req.cache_of, req.errors)
    t = lap("pool_ms", t)
    if not ways:
        return t
    # the goals' polytopes, one per distinct goal (each task returns its own copy of its component's goal)
    known = list({tuple(r["goal"]): p for _, r in ways for p in r["known"]}.values())
    corridors = stages.legs_corridor(req.planner.space, [r["way"] for _, r in ways], known=known)
    t = lap("corridor_ms", t)
    todo = []
    for (ci, r), c in zip(ways, corridors):
        if isinstance(c, CorridorError):
            req.errors.append(str(c))
        else:
            todo.append((ci, r, c))
    score_cfg = req.score_config or ScoreConfig()
    score_cfg.validate()
    score_args = _worker_score_args(req, score_cfg)  # the workers score their shots (on the CPU copy) too
    ph2 = req.pool.map(_candidate_finish_task,
                       [(cfg, c, req.starts[ci], r["goal"], req.look_p, req.goal_of(ci), req.limits, score_args)
                        for ci, r, c in todo])
    t = lap("pool_ms", t)
    scored = [(ci, res) for (ci, _, _), res in zip(todo, ph2)
              if res["error"] is None and res.get("score_parts") is not None]
    if scored:
        _scores_of_parts(req, scored, score_cfg)
        t = lap("score_ms", t)
    for ci, res in _merge_task_results([ci for ci, _, _ in todo], ph2, req.tm, req.cache_of, req.errors):
        req.add(ci, res["shot"])
    return t


def _round_strategy(req: _CandidateRequest) -> Callable[[_CandidateRequest, List[int], float], float]:
    """How this request's rounds run: in this process without a pool; with one, in two phases when this process
    builds batched corridors without grid polytopes, else whole candidates in the workers."""
    planner = req.planner
    if req.pool is None:
        return _round_in_process
    if corridor_backend(planner.space, many=True) == "batched" and not use_grid_polytopes(planner.space):
        return _round_two_phase
    return _round_in_workers


def _checked_inputs(planner: Planner, goal: Any, look_at: Any, k: int, spare_fraction: float, object_radius: float,
                    time_budget_s: Optional[float]) -> tuple:
    """(k, go-to point [3], look-at point [3]) of a plan_candidates call; InvalidInputError for any input out of
    range, before any planning."""
    if int(k) != k or not 1 <= k <= MAX_CANDIDATES:
        raise InvalidInputError(f"number of candidates (--candidates) must be an integer in [1, {MAX_CANDIDATES}], got "
                                f"{k}")
    if time_budget_s is not None and not (math.isfinite(time_budget_s) and time_budget_s > 0):
        raise InvalidInputError("the time budget (--time-budget) must be a positive number of seconds, got "
                                f"{time_budget_s}")
    planner.ready()
    g = np.asarray(goal, dtype=np.float64)
    if g.ndim == 2 and (g.shape[0] < 1 or g.shape[0] > MAX_CANDIDATES):
        raise InvalidInputError(f"go-to points must be [3] or [P, 3] with 1 <= P <= {MAX_CANDIDATES}, got {g.shape}")
    goal_p = np.stack([planner.checked_point(p, "go-to point") for p in g.reshape(-1, 3)]) if g.ndim == 2 else \
        planner.checked_point(g, "go-to point")[None]
    look_p = planner.checked_point(look_at, "look-at point")
    planner.check_timing()
    if not (0 <= spare_fraction <= 4):
        raise InvalidInputError(f"spare_fraction must be in [0, 4], got {spare_fraction}")
    if not (math.isfinite(object_radius) and object_radius >= 0):  # before any planning (scoring needs it)
        raise InvalidInputError(f"object_radius must be finite and >= 0, got {object_radius}.")
    return int(k), goal_p, look_p


def _ranked(req: _CandidateRequest, t: float, timings: Optional[Dict[str, float]]) -> List[RankedShot]:
    """The request's shots verified (in this process unless the workers did), refused if unsafe, scored (the scores
    of shots scored early kept) and ranked best first; timings filled."""
    planner, lap, shots, cand_ids = req.planner, req.lap, req.shots, req.cand_ids
    if not shots:
        raise GoalUnreachableError(
            f"no safe candidate found from {len(req.starts)} start(s); last reason: "
            f"{req.errors[-1] if req.errors else 'unknown'}"
        )
    if req.pool is not None:
        reports = [sh.safety for sh in shots]  # verified in the workers (same rule, CPU state)
    else:
        reports = stages.legs_verify(planner.space, shots)
        t = lap("verify_ms", t)
    for sh, rep in zip(shots, reports):
        sh.safety = stages.refuse_unsafe(rep, "a candidate curve")
    late = [i for i, ci in enumerate(cand_ids) if ci not in req.early_scores]
    late_scores = score_shots(planner, [shots[i] for i in late], req.look_p, req.score_config, req.object_radius,
                              req.object_center, req.object_samples, req.exclude, req.subject) if late else []
    by_pos = dict(zip(late, late_scores))
    scores = [req.early_scores[ci] if ci in req.early_scores else by_pos[i] for i, ci in enumerate(cand_ids)]
    t = lap("score_ms", t)
    tm = req.tm
    tm["total_ms"] = 1e3 * (time.perf_counter() - req.t_all)
    tm["num_failed"] = float(len(req.errors))
    for sh in shots:
        sh.timings = {**{f"batch_{kk}": v for kk, v in tm.items()}}
    order = sorted(range(len(shots)), key=lambda i: (scores[i].total, cand_ids[i]))
    if timings is not None:
        timings.update(tm)
    return [RankedShot(rank=r + 1, shot=shots[i], score=scores[i], candidate=cand_ids[i]) for r, i in enumerate(order)]


def _plan_candidates(
    planner: Planner,
    goal: Any,
    look_at: Any,
    k: int,
    seed: int,
    score_config: Optional[ScoreConfig],
    *,
    use_workers: bool,
    limits: Optional[DynamicLimits],
    object_radius: float,
    object_center: Optional[Any],
    object_samples: Optional[Any],
    exclude: Optional[torch.Tensor],
    spare_fraction: float,
    timings: Optional[Dict[str, float]],
    time_budget_s: Optional[float] = None,
    subject: Optional[SubjectSamples] = None,
) -> List[RankedShot]:
    """The body of plan_candidates (use_workers: allow the planner's worker pool): starts sampled, rounds of the
    strategy _round_strategy picks until k shots exist, the starts run out or the time budget is spent, then
    verified, scored and ranked (_ranked)."""
    k, goal_p, look_p = _checked_inputs(planner, goal, look_at, k, spare_fraction, object_radius, time_budget_s)
    req = _CandidateRequest(planner, goal_p, look_p, k, limits, score_config, object_radius, object_center,
                            object_samples, exclude, time_budget_s, t_all=time.perf_counter(), subject=subject)
    t = time.perf_counter()
    n_try = k + int(math.ceil(spare_fraction * k))
    starts = random_starts(planner.space, n_try, torch.Generator().manual_seed(int(seed)), look_p)
    req.starts = starts.detach().cpu().numpy()  # [n_try, 3]
    t = req.lap("start_sample_ms", t)
    req.pool = planner.candidate_pool() if k > 1 and use_workers else None
    if req.pool is not None:
        t = req.lap("pool_start_ms", t)  # forking the workers: first request after prepare() only
        req.tm["workers"] = float(req.pool.processes)
        # the main component's goal once here (inherited by every task) instead of once per worker
        for g, cache in zip(req.goal_p, req.goal_caches):
            try:
                stages.component_goal(planner.space, g, planner.main_component(), cache)
            except GoalUnreachableError:
                pass  # each candidate then fails with this error in its worker, as in the in-process path
        t = req.lap("goal_ms", t)
    plan_round = _round_strategy(req)
    nxt = 0  # next unused start; spares are only planned to replace failed candidates
    while len(req.shots) < k and nxt < len(req.starts) and not req.over_budget():
        batch = list(range(nxt, min(len(req.starts), nxt + k - len(req.shots))))
        nxt = batch[-1] + 1
        t = plan_round(req, batch, t)
    return _ranked(req, t, timings)
