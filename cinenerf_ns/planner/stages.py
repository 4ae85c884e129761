"""One shot leg, stage by stage: start -> reachable goal -> voxel path -> line-of-sight shortcut -> safe corridor ->
Bezier QP -> timing + look-at orientation -> verified by exact clearance (paper Sec. IV).

``plan_leg`` runs the whole leg for one start (Planner.plan); ranked candidates (candidates.py) and multi-stop shots
(multistop.py) run the same stage functions, batching some of them across candidates or chaining them across stops.
Every function takes a prepared Planner (planner.py) for the scene, its grids and its configuration."""
from __future__ import annotations

import time
from typing import TYPE_CHECKING, Tuple

import numpy as np
import torch

from .coarse_path import voxel_path
from .corridor import Corridor, build_corridor
from .errors import GoalUnreachableError, UnsafeTrajectoryError
from .reach import ReachableGoal, free_voxel_near, reachable_goal
from .safety import verify_shot
from .shot import Shot
from .trajectory import solve_corridor_qp

if TYPE_CHECKING:
    from .bezier import BezierTrajectory
    from .planner import Planner


def leg_goal(planner: "Planner", start: np.ndarray, target: np.ndarray, goal_cache: dict) -> Tuple[ReachableGoal, np.ndarray]:
    """(where the leg ends, the free voxel [3] it starts in): the goal is found once per free component of the start
    (``goal_cache``: component -> ReachableGoal, shared by the candidates of one request)."""
    s_ijk = free_voxel_near(planner, start, None)
    comp = int(planner.ready().astar_grid.labels[tuple(s_ijk)])
    if comp not in goal_cache:
        goal_cache[comp] = reachable_goal(planner, target, comp)
    return goal_cache[comp], s_ijk


def leg_way(planner: "Planner", start: np.ndarray, s_ijk: np.ndarray, goal: ReachableGoal) -> np.ndarray:
    """The polyline [K, 3] the shortcut prunes: the start, the voxel path's centres (A*, coarse_path.voxel_path), and
    the goal point unless the goal's polytope holds the last segment (ReachableGoal.way_to_shortcut)."""
    prep = planner.ready()
    path = voxel_path(prep.astar_grid, prep.coarse, s_ijk, goal.voxel, astar_weight=planner.config.astar_weight)  # [K, 3]
    centres = prep.grid.voxel_to_world(torch.as_tensor(path, device=prep.grid.device)).cpu().numpy()
    return goal.way_to_shortcut(start, centres)


def leg_corridor(planner: "Planner", way: np.ndarray, known=()) -> Corridor:
    """Safe polytopes along a shortcut polyline [K, 3] (corridor.build_corridor with the planner's box margin, backend,
    grid polytopes and planning region); ``known``: the goal's polytope (ReachableGoal.known())."""
    return build_corridor(torch.as_tensor(way, device=planner.scene.device), planner.scene, planner.ready().index,
                          known=known, **planner.corridor_kwargs())


def leg_trajectory(planner: "Planner", corridor: Corridor, start: np.ndarray, goal: np.ndarray) -> "BezierTrajectory":
    """The Bezier QP of one corridor from ``start`` [3] to ``goal`` [3] (control points inside the polytopes)."""
    return solve_corridor_qp(corridor.constraints(), corridor.waypoints.cpu().numpy(), start, goal,
                             planner.config.trajectory)


def leg_verify(planner: "Planner", shot: Shot) -> dict:
    """The exact-clearance verification of a shot (safety.verify_shot); UnsafeTrajectoryError when it fails, which
    cannot happen if the corridor and the QP are right: such a shot is never returned."""
    report = verify_shot(shot, planner.points_free, planner.clearance, max_spacing=planner.config.verify_spacing)
    if not report["safe"]:
        raise UnsafeTrajectoryError(
            f"verification found exact clearance {report['min_exact_clearance']:.3g} < 0 on the curve; this is a "
            f"planner bug, please report it with the scene and seed")
    return report


def plan_leg(planner: "Planner", start: np.ndarray, target: np.ndarray, look_at: np.ndarray, goal_cache: dict,
             sample_ms: float = 0.0) -> Shot:
    """One verified shot from ``start`` [3] to the closest safe point to ``target`` [3] the start reaches, every frame
    looking at ``look_at`` [3]. Each stage's milliseconds go to ``shot.timings`` (with ``sample_ms``, the time the
    start took to draw). Raises GoalUnreachableError, CorridorError, PlanningError."""
    cfg = planner.config
    tm: dict = {"start_sample_ms": sample_ms}
    t0 = time.perf_counter()
    goal, s_ijk = leg_goal(planner, start, target, goal_cache)
    t1 = time.perf_counter()
    tm["goal_ms"] = 1e3 * (t1 - t0)
    way = leg_way(planner, start, s_ijk, goal)
    t2 = time.perf_counter()
    tm["astar_ms"] = 1e3 * (t2 - t1)
    way = goal.shortcut_ends(planner.shortcut_way(way))
    t3 = time.perf_counter()
    tm["shortcut_ms"] = 1e3 * (t3 - t2)
    if np.linalg.norm(way[-1] - way[0]) < 1e-9:
        raise GoalUnreachableError("the start is already at the goal; pick another start")
    corridor = leg_corridor(planner, way, goal.known())
    t4 = time.perf_counter()
    tm["corridor_ms"] = 1e3 * (t4 - t3)
    traj = leg_trajectory(planner, corridor, start, goal.point)
    t5 = time.perf_counter()
    tm["qp_ms"] = 1e3 * (t5 - t4)
    shot = Shot.from_trajectory(traj, look_at, timing=cfg.timing, up=cfg.up, corridor=corridor, timings=tm)
    t6 = time.perf_counter()
    shot.safety = leg_verify(planner, shot)
    t7 = time.perf_counter()
    tm["verify_ms"] = 1e3 * (t7 - t6)
    shot.goal_target = target
    tm["plan_ms"] = 1e3 * (t7 - t0) + sample_ms
    shot.timings = {**shot.timings, **tm}  # keeps from_trajectory's timing_ms / orientation_ms
    return shot
