"""Multi-stop shots: "go to A, then B, then C", one continuous smooth trajectory through the stops.

Choice (documented): ONE QP over the concatenated corridor, the stops as interpolation constraints.
  1. start (given, or seeded random free start) and, per stop, the closest safe point to the requested
     go-to that the start's free component reaches (reach.reachable_goal, as for single shots);
  2. per leg (start -> stop 1, stop 1 -> stop 2, ...): A*, line-of-sight shortcut (all legs in one
     batched call), safe polytope corridor (stages.py, the single shot's leg stages);
  3. the legs' polytopes and waypoints are concatenated and the corridor QP of trajectory/qp.py is built once;
     for every interior stop j joining segments k-1 and k, the equality P_{k-1,D} = stop_j is added (the
     C0..C2 joins then carry the curve through it with continuous velocity and acceleration: the camera
     flies through the stop, it does not halt) and the two control points at the stop drop their polytope
     rows (they are pinned; the stop is checked to lie in both polytopes, like start and goal);
  4. every free control point is checked inside its (unshrunk) polytope, so the whole curve is safe by
     the convex-hull property; the frames are then verified densely (safety.verify_shot).
Look-at: each stop has its own look-at (or all share one). On the leg towards stop j the look-at point
moves from stop j-1's look-at to stop j's along the path, with a C2 "smootherstep" in the arc-length
fraction of the leg (the first leg keeps stop 1's look-at), so the camera arrives at stop j looking at
its look-at and the view turns smoothly. Timing: dynamics.retime (speed, acceleration and view angular
rate limits measured on the exported frames).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np
import scipy.sparse as sp
import torch

from ..errors import InvalidInputError
from ..search.starts import random_starts
from ..trajectory.bezier import BezierTrajectory
from ..trajectory.dynamics import DynamicLimits, dynamics_report, retime
from ..trajectory.qp import (
    CorridorInfeasibleError,
    CorridorQP,
    TrajectoryConfig,
    TrajectorySolverError,
    build_corridor_qp,
)
from ..trajectory.qp_matrices import point_violation
from ..trajectory.qp_solvers import project_equalities, solve_clarabel, solve_osqp
from ..trajectory.timing import arc_length_table
from . import stages
from .planner import Planner
from .shot import Shot


@dataclass
class MultiStopShot:
    """A shot through several stops. ``shot.look_at`` is the last stop's look-at; the per-frame look-at
    points are ``look_at_points`` (Shot.resampled would re-aim every frame at shot.look_at: use the frames
    as they are, or re-plan with another fps in DynamicLimits)."""

    shot: Shot
    stops: np.ndarray  # [S, 3] the safe points the curve passes through (closest safe points to the targets)
    stop_targets: np.ndarray  # [S, 3] the requested go-to points
    stop_look_ats: np.ndarray  # [S, 3] look-at of each stop
    stop_curve_times: np.ndarray  # [S] the trajectory's own time at each stop (exactly on the curve)
    stop_frame_times: np.ndarray  # [S] shot time at which the camera passes each stop
    look_at_points: np.ndarray  # [T, 3] what each frame looks at
    dynamics: Dict[str, float] = field(default_factory=dict)
    timings: Dict[str, float] = field(default_factory=dict)

    def to_dict(self, include_frames: bool = False) -> Dict[str, Any]:
        """Shot.to_dict with the stops, their look-ats and frame times, the dynamics and the verification (and the
        per-frame look-at points with include_frames)."""
        d = self.shot.to_dict(include_frames)
        # the generic look-at error assumes one look-at point; report the one against the per-frame points
        view = -self.shot.rotations[:, :, 2]
        to = self.look_at_points - self.shot.positions
        to = to / np.linalg.norm(to, axis=1, keepdims=True)
        d["max_look_at_error_deg"] = float(np.degrees(np.arccos(np.clip((view * to).sum(1), -1, 1))).max())
        d.update({
            "stops": self.stops.tolist(), "stop_targets": self.stop_targets.tolist(),
            "stop_look_ats": self.stop_look_ats.tolist(), "stop_frame_times": self.stop_frame_times.tolist(),
            "dynamics": self.dynamics, "verification": self.shot.safety,
        })
        if include_frames:
            d["frames"]["look_at_points"] = self.look_at_points.tolist()
        return d


def _smootherstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (x * (6 * x - 15) + 10)


def _with_stops(qp: CorridorQP, config: TrajectoryConfig, stop_segments: List[int], stops: np.ndarray) -> CorridorQP:
    """Add P_{k-1,D} = stop equalities and drop the polytope rows of the control points at each stop."""
    d, m = qp.degree, qp.num_segments
    npts = d + 1
    q = config.rest_at_ends
    pinned = np.zeros((m, npts), dtype=bool)
    pinned[0, : q + 1] = True
    pinned[m - 1, d - q :] = True
    row0 = np.zeros(m, dtype=np.int64)  # first inequality row of each segment
    acc = 0
    for k, (a, _) in enumerate(qp.polytopes):
        row0[k] = acc
        acc += int((~pinned[k]).sum()) * a.shape[0]
    drop = []
    rows_r, rows_c, rhs = [], [], []
    n = qp.n
    for j, (k, p) in enumerate(zip(stop_segments, stops)):
        for seg, i in ((k - 1, d), (k, 0)):
            a, b = qp.polytopes[seg]
            tol = 1e-9 * max(1.0, float(np.abs(p).max()))
            if point_violation(a, b, p) > tol:
                raise CorridorInfeasibleError(f"stop {j + 1} {np.round(p, 4).tolist()} lies outside its corridor "
                                              "polytope.")
            if not pinned[seg, i]:
                pos = int(np.flatnonzero(~pinned[seg]).tolist().index(i))
                f = a.shape[0]
                drop.extend(range(row0[seg] + pos * f, row0[seg] + (pos + 1) * f))
        base = ((k - 1) * npts + d) * 3
        for c in range(3):
            rows_r.append(len(rhs))
            rows_c.append(base + c)
            rhs.append(float(p[c]))
    keep = np.setdiff1d(np.arange(qp.A_in.shape[0]), np.asarray(drop, dtype=np.int64))
    extra = sp.csc_matrix((np.ones(len(rows_r)), (rows_r, rows_c)), shape=(len(rhs), n))
    return CorridorQP.from_matrices(
        P=qp.P, A_eq=sp.vstack([qp.A_eq, extra], format="csc"), b_eq=np.concatenate([qp.b_eq, rhs]),
        A_in=qp.A_in[keep], b_in=qp.b_in[keep], durations=qp.durations, degree=d, num_segments=m,
        polytopes=qp.polytopes,
    )


def solve_through_stops(polytopes, waypoints: np.ndarray, start: np.ndarray, goal: np.ndarray,
                        stop_segments: List[int], stops: np.ndarray, config: TrajectoryConfig) -> BezierTrajectory:
    """trajectory.solve_corridor_qp plus interpolation constraints: the curve passes exactly through
    stops [S, 3] at the start of segments stop_segments [S] (same checks: every free control point is
    verified inside its unshrunk polytope)."""
    t0 = time.perf_counter()
    qp = _with_stops(build_corridor_qp(polytopes, waypoints, start, goal, config), config, stop_segments, stops)
    t1 = time.perf_counter()
    # (the stops' interpolation rows are not in dual_qp's equality-free form: "active_set" is solved by Clarabel here)
    solver = "osqp" if config.solver == "osqp" else "clarabel"
    x, status, iters, outcome = (solve_osqp if solver == "osqp" else solve_clarabel)(qp, config)
    if outcome == "infeasible":
        raise CorridorInfeasibleError(
            "no smooth trajectory through the stops fits inside the safe corridor; try fewer stops (--then-go-to), "
            "stops with more free space around them, or a smaller --camera-radius / --safety-margin"
        )
    if outcome == "failed":
        raise TrajectorySolverError(f"the {solver} QP solver did not converge (status {status}).")
    m, npts = qp.num_segments, qp.degree + 1
    cps = project_equalities(x, qp).reshape(m, npts, 3).copy()
    cps[0, : config.rest_at_ends + 1] = start
    cps[-1, npts - 1 - config.rest_at_ends :] = goal
    exact = np.zeros((m, npts), dtype=bool)
    exact[0, : config.rest_at_ends + 1] = True
    exact[-1, npts - 1 - config.rest_at_ends :] = True
    for k, p in zip(stop_segments, stops):
        cps[k - 1, -1] = p
        cps[k, 0] = p
        exact[k - 1, -1] = exact[k, 0] = True
    worst = -np.inf
    for k, (a, b) in enumerate(qp.polytopes):
        free = ~exact[k]
        if free.any():
            worst = max(worst, float(np.max(cps[k, free] @ a.T - b)))
    if worst > 0:
        raise TrajectorySolverError(f"the {solver} solution leaves the corridor by {worst:.2e}.")
    traj = BezierTrajectory(cps, qp.durations)
    traj.info = {"solver": solver, "status": status, "iterations": int(iters), "build_ms": 1e3 * (t1 - t0),
                 "solve_ms": 1e3 * (time.perf_counter() - t1), "max_corridor_violation": worst,
                 "num_variables": qp.n}
    return traj


def _checked_stops(planner: Planner, stops: Sequence[Any], look_at: Any) -> Tuple[List[np.ndarray], np.ndarray]:
    """(the stops' go-to points [3] each, the look-at of each stop [S, 3]) checked against the planning region
    (Planner.checked_point), and the region against the timing (Planner.check_timing); InvalidInputError otherwise."""
    planner.ready()
    targets = [planner.checked_point(s, f"stop {i + 1}") for i, s in enumerate(stops)]
    if not targets:
        raise InvalidInputError("a multi-stop shot needs at least one stop.")
    la = np.asarray(look_at, dtype=np.float64)
    if la.shape == (3,):
        looks = np.tile(planner.checked_point(la, "look-at point"), (len(targets), 1))
    elif la.shape == (len(targets), 3):
        looks = np.stack([planner.checked_point(p, f"look-at of stop {i + 1}") for i, p in enumerate(la)])
    else:
        raise InvalidInputError(f"look_at must be one point [3] or one per stop [{len(targets)}, 3], got shape "
                                f"{la.shape}.")
    planner.check_timing()
    return targets, looks


def _stop_goals(planner: Planner, start: np.ndarray, targets: List[np.ndarray]) -> Tuple[list, list, list]:
    """The chain's points: (points [3] (the start, then the closest safe point to each stop that the start's free
    component reaches), their voxels [3], their ReachableGoals (None for the start)). InvalidInputError when a stop
    coincides with the point before it."""
    s_ijk, comp = stages.start_voxel(planner.space, start)
    pts, ijks, reached = [start], [s_ijk], [None]
    for g in targets:
        goal = stages.component_goal(planner.space, g, comp)
        pts.append(np.asarray(goal.point, np.float64))
        ijks.append(np.asarray(goal.voxel))
        reached.append(goal)
    for i in range(1, len(pts)):
        if np.linalg.norm(pts[i] - pts[i - 1]) < 1e-9:
            raise InvalidInputError(f"stop {i} coincides with the point before it; remove the repeated stop.")
    return pts, ijks, reached


def _chained_corridor(planner: Planner, ways: List[np.ndarray], pts: list,
                      known: list) -> Tuple[list, np.ndarray, List[int]]:
    """Every leg's corridor (stages.leg_corridor) concatenated: (polytopes, waypoints [M+1, 3] with the stops exactly
    at the legs' joins, the segment index each interior stop starts [S-1])."""
    polys, wps, stop_segments = [], [pts[0][None]], []
    for i, w in enumerate(ways):
        cor = stages.leg_corridor(planner.space, w, known)
        if i > 0:
            stop_segments.append(len(polys))
        polys.extend(cor.constraints())
        cw = cor.waypoints.cpu().numpy()  # [K, 3]
        cw[0], cw[-1] = pts[i], pts[i + 1]
        wps.append(cw[1:])
    return polys, np.concatenate(wps), stop_segments


def _moving_look_at(traj: BezierTrajectory, stop_segments: List[int],
                    looks: np.ndarray) -> Tuple[Callable[[np.ndarray], np.ndarray], np.ndarray]:
    """(look_of(arc-length fractions [K]) -> look-at points [K, 3], the curve time of each stop [S]). On the leg
    towards stop j the look-at moves from stop j-1's look-at to stop j's with a smootherstep in the leg's arc-length
    fraction; the first leg keeps stop 1's."""
    tau_tab, s_tab = arc_length_table(traj)
    stop_tau = (np.concatenate([traj.segment_starts[stop_segments], [traj.total_duration]]) if stop_segments
                else np.array([traj.total_duration]))
    frac = np.interp(stop_tau, tau_tab, s_tab) / s_tab[-1]  # [S] (last = 1)
    bounds = np.concatenate([[0.0], frac])

    def look_of(f: np.ndarray) -> np.ndarray:
        f = np.asarray(f, np.float64)
        leg = np.clip(np.searchsorted(bounds, f, side="right") - 1, 0, len(looks) - 1)  # [K]
        x = (f - bounds[leg]) / np.maximum(bounds[leg + 1] - bounds[leg], 1e-12)
        prev = looks[np.maximum(leg - 1, 0)]
        w = np.where(leg == 0, 1.0, _smootherstep(x))[:, None]
        return prev + w * (looks[leg] - prev)

    return look_of, stop_tau


def plan_multistop(planner: Planner, stops: Sequence[Any], look_at: Any, start: Optional[Any] = None, seed: int = 0,
                   limits: Optional[DynamicLimits] = None, force_start: bool = False) -> MultiStopShot:
    """One smooth verified-safe shot from ``start`` (or a seeded random free start) through the closest
    safe points to each go-to in ``stops`` [S, 3] (S >= 1), in order. look_at: one point [3] shared by all
    stops, or one per stop [S, 3]. limits: dynamic limits of the exported frames (default: the planner's
    max speed / acceleration / fps and 60 deg/s). Raises InvalidInputError, StartInCollisionError,
    GoalUnreachableError (a stop cannot be reached, or no smooth curve fits). A start outside the planning region
    is an error unless ``force_start`` (Planner.checked_start)."""
    targets, looks = _checked_stops(planner, stops, look_at)
    cfg = planner.config
    if limits is None:
        acc = cfg.timing.max_acceleration  # None (no timing cap): the exported frames' default cap
        limits = DynamicLimits(max_speed=cfg.timing.max_speed, fps=cfg.timing.fps,
                               max_acceleration=DynamicLimits.max_acceleration if acc is None else acc)
    tm: Dict[str, float] = {}
    t0 = time.perf_counter()
    if start is not None:
        s = planner.checked_start(start, force=force_start)  # may grow the region
    else:
        gen = torch.Generator().manual_seed(int(seed))
        s = random_starts(planner.space, 1, gen, looks[0])[0].detach().cpu().numpy()
    pts, ijks, reached = _stop_goals(planner, s, targets)
    tm["goal_ms"] = 1e3 * (time.perf_counter() - t0)
    t1 = time.perf_counter()
    last = len(targets) - 1  # legs i -> i + 1; the last one ends at the final stop like a single shot's leg
    ways = [stages.stop_way(planner.space, pts[i], ijks[i], reached[i + 1]) if i < last
            else stages.leg_way(planner.space, pts[i], ijks[i], reached[-1]) for i in range(len(targets))]
    tm["astar_ms"] = 1e3 * (time.perf_counter() - t1)
    t2 = time.perf_counter()
    # only the last way ends in its stop's polytope (ReachableGoal), reused below; see stages.stop_way for the others
    ways = stages.legs_shortcut(planner.space, ways, [None] * last + [reached[-1]])
    known = reached[-1].known()
    tm["shortcut_ms"] = 1e3 * (time.perf_counter() - t2)
    t3 = time.perf_counter()
    polys, waypoints, stop_segments = _chained_corridor(planner, ways, pts, known)
    tm["corridor_ms"] = 1e3 * (time.perf_counter() - t3)
    t4 = time.perf_counter()
    stop_pts = np.stack(pts[1:-1]) if len(pts) > 2 else np.zeros((0, 3))
    traj = solve_through_stops(polys, waypoints, pts[0], pts[-1], stop_segments, stop_pts, cfg.trajectory)
    tm["qp_ms"] = 1e3 * (time.perf_counter() - t4)
    t5 = time.perf_counter()
    look_of, stop_tau = _moving_look_at(traj, stop_segments, looks)
    rf = retime(traj, look_of, limits, up=cfg.up)
    tm["timing_ms"] = 1e3 * (time.perf_counter() - t5)
    shot = Shot(times=rf.times, positions=rf.positions, rotations=rf.rotations, look_at=looks[-1], goal=pts[-1],
                start=pts[0], trajectory=traj, fps=limits.fps, curve_times=rf.curve_times, goal_target=targets[-1])
    t6 = time.perf_counter()
    shot.safety = stages.leg_verify(planner.space, shot, "the multi-stop curve")
    tm["verify_ms"] = 1e3 * (time.perf_counter() - t6)
    tm["plan_ms"] = 1e3 * (time.perf_counter() - t0)
    shot.timings = dict(tm)
    stop_frame = np.interp(stop_tau, rf.curve_times, rf.times)
    return MultiStopShot(shot=shot, stops=np.stack(pts[1:]), stop_targets=np.stack(targets), stop_look_ats=looks,
                         stop_curve_times=stop_tau, stop_frame_times=stop_frame, look_at_points=rf.look_at_points,
                         dynamics=dynamics_report(rf, limits), timings=tm)
