"""One request -> ranked shots, the same way for ``cinesplat-plan`` and both viewers.

A request is the go-to points (the end poses of shot_targets.py, or the go-to point itself), a look-at point, an
optional start, and how many candidates. The rule:

* a given start: one shot from it (Planner.plan), retimed to the limits when there are any, and scored;
* no start: ``candidates`` random starts planned as ranked candidates (plan_candidates), scored and ranked, one
  candidate included (a single random-start shot is scored as any other).

Every shot is scored by the same ScoreConfig and, with a subject, by its visibility (scoring.py). Multi-stop shots
(cinesplat-plan --then-go-to) are not a request of this kind.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, List, Optional

import numpy as np

from cinenerf_ns.planner.geometry.visibility import SubjectSamples
from cinenerf_ns.planner.shots.candidates import RankedShot, plan_candidates, score_shots
from cinenerf_ns.planner.shots.planner import Planner
from cinenerf_ns.planner.shots.score_config import ScoreConfig
from cinenerf_ns.planner.shots.shot import retime_shot
from cinenerf_ns.planner.trajectory.dynamics import DynamicLimits


@dataclass
class ShotRequest:
    """What to plan (module docstring)."""

    goals: np.ndarray  # [P, 3] the go-to points: end poses (candidate i plans to goals[i % P]) or the go-to point
    look_at: np.ndarray  # [3]
    start: Optional[np.ndarray] = None  # [3] a given start; None: random starts
    candidates: int = 1  # random starts planned (ignored with a given start: one shot)
    seed: int = 0
    subject: Optional[SubjectSamples] = None  # the look-at object's samples: scores by its visibility
    score: Optional[ScoreConfig] = None  # None: ScoreConfig()
    limits: Optional[DynamicLimits] = None  # speed / acceleration limits the shots are retimed to
    object_radius: float = 0.1  # sight lines stop this far before a look-at point (no subject)
    time_budget_s: Optional[float] = None  # plan_candidates' time budget
    force_start: bool = False  # a given start outside the start region is kept (Planner.plan's force_start)


def plan_request(planner: Planner, req: ShotRequest, timings: Optional[Dict[str, float]] = None) -> List[RankedShot]:
    """The request's shots, best first (module docstring); ``timings`` gets plan_candidates' stage times."""
    goals = np.asarray(req.goals, np.float64).reshape(-1, 3)
    look = np.asarray(req.look_at, np.float64).reshape(3)
    score = req.score or ScoreConfig()
    if req.start is not None:
        shots = planner.plan(goals[0], look, start=np.asarray(req.start, np.float64).reshape(3), seed=req.seed,
                             n_candidates=1, force_start=req.force_start)
        if req.limits is not None:
            shots = [retime_shot(sh, req.limits, up=planner.config.up) for sh in shots]
        scores = score_shots(planner, shots, look, score, object_radius=req.object_radius, subject=req.subject)
        return [RankedShot(rank=i + 1, shot=sh, score=sc, candidate=i) for i, (sh, sc) in enumerate(zip(shots, scores))]
    return plan_candidates(planner, goals if len(goals) > 1 else goals[0], look, k=int(req.candidates), seed=req.seed,
                           score_config=score, limits=req.limits, object_radius=req.object_radius, timings=timings,
                           time_budget_s=req.time_budget_s, subject=req.subject)
