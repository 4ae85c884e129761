"""One shot leg, stage by stage: start -> reachable goal -> voxel path -> line-of-sight shortcut -> safe corridor ->
Bezier QP -> timing + look-at orientation -> verified by exact clearance (paper Sec. IV).

The only place a leg is planned. ``plan_leg`` runs the whole leg for one start (Planner.plan); ranked candidates
(candidates.py) and multi-stop shots (multistop.py) compose the same stage functions, the ``legs_*`` ones batching a
stage across candidates (one call for all of them) or chaining legs across stops. Every function takes the prepared
planning space (space.py's PlanningSpace: the scene, its grids and its configuration), never the Planner."""
from __future__ import annotations

import time
from functools import partial
from typing import TYPE_CHECKING, List, Optional, Sequence, Tuple, Union

import numpy as np
import torch

from ..corridor.corridor_options import corridor_kwargs, use_grid_polytopes
from ..corridor.safe_corridor import Corridor, CorridorError, build_corridor, build_corridors
from ..errors import GoalUnreachableError, UnsafeTrajectoryError
from ..geometry.clearance_queries import clearance, points_free
from ..search.coarse_path import voxel_path
from ..search.corner_steps import detour_corner_steps
from ..search.reach import ReachableGoal, free_voxel_near, reachable_goal
from ..search.shortcut import shortcut_ways
from ..trajectory.dynamics import DynamicLimits
from ..trajectory.qp import solve_corridor_qp
from . import refine
from .safety import dense_samples, verify_shot
from .shot import Shot, retime_shot

if TYPE_CHECKING:
    from ..space import PlanningSpace
    from ..trajectory.bezier import BezierTrajectory


# ---------------------------------------------------------------- goal
def start_voxel(space: "PlanningSpace", start: np.ndarray) -> Tuple[np.ndarray, int]:
    """(the free voxel [3] a leg from ``start`` [3] begins its voxel path in, that voxel's free component)."""
    s_ijk = free_voxel_near(space, start, None)
    return s_ijk, int(space.prepared.astar_grid.labels[tuple(s_ijk)])


def component_goal(space: "PlanningSpace", target: np.ndarray, comp: int,
                   goal_cache: Optional[dict] = None) -> ReachableGoal:
    """The closest safe point to ``target`` [3] that free component ``comp`` reaches (reach.reachable_goal), found
    once per component when a ``goal_cache`` (component -> ReachableGoal, one target) is given."""
    if goal_cache is None:
        return reachable_goal(space, target, comp)
    if comp not in goal_cache:
        goal_cache[comp] = reachable_goal(space, target, comp)
    return goal_cache[comp]


def leg_goal(space: "PlanningSpace", start: np.ndarray, target: np.ndarray,
             goal_cache: dict) -> Tuple[ReachableGoal, np.ndarray]:
    """(where the leg ends, the free voxel [3] it starts in): the goal is found once per free component of the start
    (``goal_cache``: component -> ReachableGoal, shared by the candidates of one request)."""
    s_ijk, comp = start_voxel(space, start)
    return component_goal(space, target, comp, goal_cache), s_ijk


# ---------------------------------------------------------------- voxel path
CANDIDATE_DETOUR_EXPANSIONS = 20_000
"""Ranked candidates check a coarse detour against at most this many fine A* expansions (voxel_path's detour_budget),
one shot against the whole fine search: 32 candidates to one go-to in a pocket under the 1M grove's canopy paid
5-60 ms each for the whole search (docs/PLANNER_DEFAULTS.md)."""


def voxel_centres(space: "PlanningSpace", a_ijk: np.ndarray, b_ijk: np.ndarray,
                  detour_budget: Optional[int] = None) -> np.ndarray:
    """The world centres [K, 3] of the voxel path from voxel ``a_ijk`` to ``b_ijk`` (A* with the configured weight,
    hard cases on the coarse grid: coarse_path.voxel_path), with its corner-cutting steps detoured through free voxels
    where they can be (config.corner_detours, with grid polytopes: corner_steps.py). ``detour_budget``: voxel_path's."""
    prep = space.prepared
    path = voxel_path(prep.astar_grid, prep.coarse, a_ijk, b_ijk, astar_weight=space.config.astar_weight,
                      detour_budget=detour_budget)  # [K, 3]
    if prep.voxels is not None and prep.grid.device.type == "cpu":
        # OccupancyGrid.voxel_to_world's arithmetic in numpy (the same float64 operations, so the same centres)
        centres = prep.voxels.lo + (np.asarray(path).astype(np.float64) + 0.5) * prep.voxels.voxel_size
    else:
        centres = prep.grid.voxel_to_world(torch.as_tensor(path, device=prep.grid.device)).cpu().numpy()
    if space.config.corner_detours and prep.voxels is not None and use_grid_polytopes(space):
        centres = detour_corner_steps(prep.voxels.segments_free, centres)[0]
    return centres


def leg_way(space: "PlanningSpace", start: np.ndarray, s_ijk: np.ndarray, goal: ReachableGoal,
            detour_budget: Optional[int] = None) -> np.ndarray:
    """The polyline [K, 3] the shortcut prunes: the start, the voxel path's centres, and the goal point unless the
    goal's polytope holds the last segment (ReachableGoal.way_to_shortcut). ``detour_budget``: voxel_path's (None
    for one shot: a coarse detour is always checked against the whole fine search)."""
    return goal.way_to_shortcut(start, voxel_centres(space, s_ijk, goal.voxel, detour_budget))


def stop_way(space: "PlanningSpace", start: np.ndarray, s_ijk: np.ndarray, stop: ReachableGoal) -> np.ndarray:
    """The polyline [K, 3] of a leg that ends at an intermediate stop of a multi-stop shot: the start, the voxel path's
    centres and the stop's point. Never shortened at the stop (the curve passes through it with continuous
    derivatives, and the goal's projection puts a point on a face of its polytope, which leaves such a junction
    little room)."""
    centres = voxel_centres(space, s_ijk, stop.voxel)
    return np.concatenate([start[None], centres, np.asarray(stop.point, np.float64)[None]])


# ---------------------------------------------------------------- shortcut
def legs_shortcut(space: "PlanningSpace", ways: Sequence[np.ndarray],
                  goals: Sequence[Optional[ReachableGoal]]) -> List[np.ndarray]:
    """The shortcuts of several polylines [K, 3] in one batched call (Planner.shortcut_ways), each completed by its
    goal (ReachableGoal.shortcut_ends; None: a leg to an intermediate stop, see stop_way)."""
    short = shortcut_ways(space, list(ways))
    return [w if g is None else g.shortcut_ends(w) for w, g in zip(short, goals)]


def leg_shortcut(space: "PlanningSpace", way: np.ndarray, goal: ReachableGoal) -> np.ndarray:
    """The shortcut of one leg's polyline [K, 3] (legs_shortcut of one)."""
    return legs_shortcut(space, [way], [goal])[0]


def at_goal_already(way: np.ndarray) -> bool:
    """The shortcut polyline [K, 3] ends where it starts: there is no leg to plan."""
    return bool(np.linalg.norm(way[-1] - way[0]) < 1e-9)


# ---------------------------------------------------------------- corridor
def leg_corridor(space: "PlanningSpace", way: np.ndarray, known=()) -> Corridor:
    """Safe polytopes along a shortcut polyline [K, 3] (corridor.build_corridor with the planner's box margin, backend,
    grid polytopes and planning region); ``known``: the goal's polytope (ReachableGoal.known())."""
    return build_corridor(way, space.scene, space.prepared.index, known=known, **corridor_kwargs(space))


def legs_corridor(space: "PlanningSpace", ways: Sequence[np.ndarray], known=()) -> List[Union[Corridor, CorridorError]]:
    """leg_corridor of several polylines [K, 3] in ONE batched computation (corridor.build_corridors: the batched
    backend's polytopes of every leg at once); a leg whose corridor fails gets its CorridorError in its place."""
    return build_corridors(list(ways), space.scene, space.prepared.index, known=known,
                           **corridor_kwargs(space, many=True))


# ---------------------------------------------------------------- QP, timing + orientation
def leg_trajectory(space: "PlanningSpace", corridor: Corridor, start: np.ndarray,
                   goal: np.ndarray) -> "BezierTrajectory":
    """The Bezier QP of one corridor from ``start`` [3] to ``goal`` [3] (control points inside the polytopes)."""
    return solve_corridor_qp(corridor.constraints(), corridor.waypoints.cpu().numpy(), start, goal,
                             space.config.trajectory)


def leg_shot(space: "PlanningSpace", traj: "BezierTrajectory", corridor: Corridor, look_at: np.ndarray,
             target: np.ndarray, limits: Optional[DynamicLimits] = None, timings: Optional[dict] = None) -> Shot:
    """The frames of a trajectory: timed with the planner's TimingConfig (retimed under ``limits`` when given,
    shot.retime_shot) and aimed at ``look_at`` [3]; ``target`` [3]: the go-to point asked for (shot.goal_target).
    ``timings``: the leg's stage times so far (Shot.from_trajectory adds timing_ms / orientation_ms)."""
    cfg = space.config
    shot = Shot.from_trajectory(traj, look_at, timing=cfg.timing, up=cfg.up, corridor=corridor, timings=timings)
    if limits is not None:
        shot = retime_shot(shot, limits, up=cfg.up)
    shot.goal_target = target
    return shot


# ---------------------------------------------------------------- verification
def refuse_unsafe(report: dict, curve: str = "the curve") -> dict:
    """``report`` (a verification) when it says safe; UnsafeTrajectoryError otherwise, which cannot happen if the
    corridor and the QP are right: such a shot is never returned. ``curve`` names the shot in the message."""
    if not report["safe"]:
        raise UnsafeTrajectoryError(
            f"verification found exact clearance {report['min_exact_clearance']:.3g} < 0 on {curve}; this is a "
            f"planner bug, please report it with the scene and seed")
    return report


def leg_verify(space: "PlanningSpace", shot: Shot, curve: str = "the curve") -> dict:
    """The exact-clearance verification of a shot (safety.verify_shot), refused when unsafe (refuse_unsafe)."""
    space = space
    report = verify_shot(shot, partial(points_free, space), partial(clearance, space),
                         max_spacing=space.config.verify_spacing)
    report["obstacles"] = space.obstacle_set()
    return refuse_unsafe(report, curve)


def legs_verify(space: "PlanningSpace", shots: Sequence[Shot]) -> List[dict]:
    """safety.verify_shot's rule for several shots with one conservative and one exact call for all of them. The
    reports are returned, not refused: the caller passes each through refuse_unsafe."""
    spacing = space.config.verify_spacing
    samples = [dense_samples(sh, None, spacing)[1] for sh in shots]  # [S_i, 3] each
    counts = [len(s) for s in samples]
    pts = np.concatenate(samples)  # [sum S_i, 3]
    ok = points_free(space, pts)
    bad = np.flatnonzero(~ok)
    exact = np.full(len(pts), np.inf)
    if bad.size:
        exact[bad] = clearance(space, pts[bad])
    out, o = [], 0
    for n in counts:
        e = exact[o : o + n]
        nb = int((~ok[o : o + n]).sum())
        mn = float(e.min()) if nb else None
        out.append({
            "num_samples": int(n), "max_sample_spacing": float(spacing), "num_inconclusive": nb,
            "min_exact_clearance": mn, "safe": bool(mn is None or mn >= 0.0),
            "method": "conservative test on every sample (occupancy grid, then Cor.1), exact distance where "
                      "inconclusive (batched over candidates)",
            "obstacles": space.obstacle_set(),
        })
        o += n
    return out


# ---------------------------------------------------------------- the whole leg
def plan_leg(space: "PlanningSpace", start: np.ndarray, target: np.ndarray, look_at: np.ndarray, goal_cache: dict,
             sample_ms: float = 0.0) -> Shot:
    """One verified shot from ``start`` [3] to the closest safe point to ``target`` [3] the start reaches, every frame
    looking at ``look_at`` [3]. Each stage's milliseconds go to ``shot.timings`` (with ``sample_ms``, the time the
    start took to draw). Raises GoalUnreachableError, CorridorError, PlanningError."""
    tm: dict = {"start_sample_ms": sample_ms}
    t0 = time.perf_counter()
    goal, s_ijk = leg_goal(space, start, target, goal_cache)
    t1 = time.perf_counter()
    tm["goal_ms"] = 1e3 * (t1 - t0)
    if refine.needs_refinement(space, goal.point, target):  # free but not connected here: a finer grid first
        shot = refine.refined_leg(space, start, target, look_at, goal.point)
        if shot is not None:
            shot.timings = {**shot.timings, "start_sample_ms": sample_ms, "goal_ms": tm["goal_ms"],
                            "plan_ms": 1e3 * (time.perf_counter() - t0) + sample_ms}
            return shot
    if not np.array_equal(goal.point, target):
        tm["refine_ms"] = 1e3 * (time.perf_counter() - t1)  # the check (and a refinement that did not help)
        t1 = time.perf_counter()
    way = leg_way(space, start, s_ijk, goal)
    t2 = time.perf_counter()
    tm["astar_ms"] = 1e3 * (t2 - t1)
    way = leg_shortcut(space, way, goal)
    t3 = time.perf_counter()
    tm["shortcut_ms"] = 1e3 * (t3 - t2)
    if at_goal_already(way):
        raise GoalUnreachableError("the start is already at the goal; pick another start")
    corridor = leg_corridor(space, way, goal.known())
    t4 = time.perf_counter()
    tm["corridor_ms"] = 1e3 * (t4 - t3)
    traj = leg_trajectory(space, corridor, start, goal.point)
    t5 = time.perf_counter()
    tm["qp_ms"] = 1e3 * (t5 - t4)
    shot = leg_shot(space, traj, corridor, look_at, target, timings=tm)
    t6 = time.perf_counter()
    shot.safety = leg_verify(space, shot)
    t7 = time.perf_counter()
    tm["verify_ms"] = 1e3 * (t7 - t6)
    tm["plan_ms"] = 1e3 * (t7 - t0) + sample_ms
    shot.timings = {**shot.timings, **tm}  # keeps from_trajectory's timing_ms / orientation_ms
    return shot
