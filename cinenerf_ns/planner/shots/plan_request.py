"""Planner.plan's request: ``n`` shots to one go-to / look-at, each a leg (stages.plan_leg) from a given start or a
seeded random one; a random start whose leg fails is replaced, up to config.max_attempts_per_candidate per shot."""
from __future__ import annotations

import time
from typing import TYPE_CHECKING, Optional

import numpy as np
import torch

from ..corridor.safe_corridor import CorridorError
from ..errors import GoalUnreachableError, InvalidInputError, StartInCollisionError
from ..scene.planning_region import ArrayLike
from ..search.starts import random_starts
from . import stages

if TYPE_CHECKING:
    from .planner import Planner
    from .shot import Shot

MAX_CANDIDATES = 64
"""Most candidates one request may ask for (each is a whole plan; more are better drawn as several requests)."""


def plan_request(planner: "Planner", goal: ArrayLike, look_at: ArrayLike, start: Optional[ArrayLike], seed: int,
                 n_candidates: int, force_start: bool) -> list["Shot"]:
    """The body of Planner.plan (which sets the request's thread count): the inputs checked, then shots planned leg
    by leg until ``n_candidates`` succeeded or the attempts ran out. Each shot's timings get request_total_ms (and
    start_check_ms for a given start)."""
    if int(n_candidates) != n_candidates or not 1 <= n_candidates <= MAX_CANDIDATES:
        raise InvalidInputError(f"number of candidates must be an integer in [1, {MAX_CANDIDATES}], got {n_candidates}")
    planner.ready()  # prepare on first use, before the request clock starts
    goal_p = planner.checked_point(goal, "go-to point")
    look_p = planner.checked_point(look_at, "look-at point")
    planner.check_timing()
    t_req = time.perf_counter()

    check_ms = None
    if start is not None:
        starts = [planner.checked_start(start, force=force_start)]
        check_ms = 1e3 * (time.perf_counter() - t_req)  # a given start's region + sign-of-clearance check
        n_candidates = 1
    else:
        starts = []
    gen = torch.Generator().manual_seed(int(seed))
    shots: list["Shot"] = []
    errors: list[str] = []
    goal_cache: dict = {}  # free component -> ReachableGoal (stages.leg_goal)
    attempts = 0
    max_attempts = n_candidates * planner.config.max_attempts_per_candidate
    pending = list(starts)
    while len(shots) < n_candidates and attempts < max_attempts:
        if not pending:
            k = n_candidates - len(shots)
            t0 = time.perf_counter()
            pts = random_starts(planner.space, k, gen, look_p)  # [k, 3]
            sample_ms = 1e3 * (time.perf_counter() - t0) / k
            pending = [(p.cpu().numpy(), sample_ms) for p in pts]
        item = pending.pop(0)
        s, sample_ms = (item, 0.0) if isinstance(item, np.ndarray) else item
        attempts += 1
        try:
            shots.append(stages.plan_leg(planner, s, goal_p, look_p, goal_cache, sample_ms))
        except (GoalUnreachableError, CorridorError, StartInCollisionError) as e:
            errors.append(str(e))
            if start is not None:
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
