"""Planner.plan's request: ``n`` shots to one go-to / look-at, each a leg (stages.plan_leg) from a given start or a
seeded random one; a random start whose leg fails is replaced, up to config.max_attempts_per_candidate per shot."""
from __future__ import annotations

import time
from typing import TYPE_CHECKING, Optional

import numpy as np
import torch

from ..config import MAX_CANDIDATES
from ..corridor.safe_corridor import CorridorError
from ..errors import GoalUnreachableError, InvalidInputError, StartInCollisionError
from ..search.starts import random_starts
from . import stages

if TYPE_CHECKING:
    from ..space import PlanningSpace
    from .shot import Shot


def check_candidates(n_candidates) -> None:
    """InvalidInputError unless ``n_candidates`` is an integer in [1, MAX_CANDIDATES]."""
    if int(n_candidates) != n_candidates or not 1 <= n_candidates <= MAX_CANDIDATES:
        raise InvalidInputError(f"number of candidates must be an integer in [1, {MAX_CANDIDATES}], got {n_candidates}")


def plan_request(space: "PlanningSpace", goal_p: np.ndarray, look_p: np.ndarray, starts: list, seed: int,
                 n_candidates: int, t_req: float, check_ms: Optional[float]) -> list["Shot"]:
    """The body of Planner.plan (which checks the inputs: ``goal_p`` / ``look_p`` [3] float64, ``starts`` [] or the
    one checked given start, and sets the request's thread count): shots planned leg by leg until ``n_candidates``
    succeeded or the attempts ran out. Each shot's timings get request_total_ms (from ``t_req``, perf_counter after
    the checks) and start_check_ms (``check_ms``, a given start's check) when given."""
    gen = torch.Generator().manual_seed(int(seed))
    shots: list["Shot"] = []
    errors: list[str] = []
    goal_cache: dict = {}  # free component -> ReachableGoal (stages.leg_goal)
    attempts = 0
    max_attempts = n_candidates * space.config.max_attempts_per_candidate
    pending = list(starts)
    while len(shots) < n_candidates and attempts < max_attempts:
        if not pending:
            k = n_candidates - len(shots)
            t0 = time.perf_counter()
            pts = random_starts(space, k, gen, look_p)  # [k, 3]
            sample_ms = 1e3 * (time.perf_counter() - t0) / k
            pending = [(p.cpu().numpy(), sample_ms) for p in pts]
        item = pending.pop(0)
        s, sample_ms = (item, 0.0) if isinstance(item, np.ndarray) else item
        attempts += 1
        try:
            shots.append(stages.plan_leg(space, s, goal_p, look_p, goal_cache, sample_ms))
        except (GoalUnreachableError, CorridorError, StartInCollisionError) as e:
            errors.append(str(e))
            if starts:
                raise
    if not shots:
        raise GoalUnreachableError(
            f"no safe shot found after {attempts} start(s); last reason: {errors[-1] if errors else 'unknown'}"
        )
    for sh in shots:
        sh.timings["request_total_ms"] = 1e3 * (time.perf_counter() - t_req)
        if check_ms is not None:
            sh.timings["start_check_ms"] = check_ms
    return shots
