"""Smooth piecewise-Bezier trajectory through a corridor of convex polytopes: one sparse QP.

Problem (paper Sec. IV-C; the same QP is written in cvxpy in tests/planner/trajectory/test_qp.py):

Variables: all control points P_{k,i} (segment k = 0..M-1, i = 0..D), flattened as
    x[(k * (D+1) + i) * 3 + c],  c = x/y/z.
Segment k lasts d_k = max(|w_{k+1} - w_k| / nominal_speed, min_segment_duration) seconds (w = waypoints),
so derivatives are with respect to time and continuity at joins accounts for unequal durations.

Objective (exact, closed form in the control points):
    J = smoothness_weight * sum_k integral_0^{d_k} |d^r p_k / dt^r|^2 dt          (r = smoothness_order)
      + length_weight     * sum_k sum_{i<D} |P_{k,i+1} - P_{k,i}|^2                ("minimum length")
With n = D - r, c_r = D!/(D-r)! and the Bernstein Gram matrix G_{jl} = integral_0^1 B_{j,n} B_{l,n} du
= C(n,j) C(n,l) / ((2n+1) C(2n, j+l)), the first term of segment k is
    c_r^2 / d_k^(2r-1) * sum_c (Delta^r P_{k,:,c})^T G (Delta^r P_{k,:,c}).
The second term is the squared control polygon (a convex proxy of length: the control polygon bounds
the curve, and squared lengths spread points evenly instead of bunching them).

Constraints:
  * corridor: A_k P_{k,i} <= b_k - margin * |rows of A_k| for every control point of segment k that is
    not pinned below. By the convex-hull property of Bezier curves the whole segment then lies in
    polytope k. The margin (scene units) absorbs solver tolerance so a returned control point is never
    outside the true polytope; the result is checked against the unshrunk b before it is returned.
  * continuity C0..C_continuity at every join, in time: d^r p_k/dt^r(end) = d^r p_{k+1}/dt^r(start).
  * start/goal: P_{0,0} = start, P_{M-1,D} = goal; with rest_at_ends = q >= 1 also the first/last
    q derivatives vanish there, i.e. P_{0,0..q} = start and P_{M-1,D-q..D} = goal.
    Pinned points are checked against their polytope (unshrunk) up front instead of being constrained.

Solved by default with ``solver="active_set"``: the equalities eliminated, then an exact dual active-set method
(dual_qp.py); where it does not apply or fails numerically, Clarabel, and the trajectory's info says so ("fallback").
Otherwise with Clarabel (interior point) or OSQP (ADMM + polishing; qp_solvers.py), both called directly with the
matrices of qp_matrices.py (scipy CSC, upper triangle of P; the settings: qp_config.py). CPU numpy float64
throughout: the solvers are CPU libraries; torch inputs are accepted and converted.
"""
from __future__ import annotations

import functools
import time
from dataclasses import replace

import numpy as np

from ..errors import CorridorInfeasibleError, TrajectorySolverError
from .bezier import BezierTrajectory
from .dual_qp import solve_corridor_dual
from .qp_config import SOLVERS, TrajectoryConfig
from .qp_matrices import (
    CorridorQP,
    assemble_qp,
    build_corridor_qp,
    checked_qp_input,
    segment_durations,
    segment_factors,
)
from .qp_solvers import project_equalities, solve_with_retry
from .working_set import ARRAY_MIN_SEGMENTS, face_norms, free_ranges, solve_with_working_set

__all__ = ["CorridorInfeasibleError", "CorridorQP", "SOLVERS", "TrajectoryConfig", "TrajectorySolverError",
           "build_corridor_qp", "solve_corridor_qp"]


def _diagnose_infeasible(polys, margins) -> str:
    """Name the first empty polytope or non-overlapping consecutive pair (small LPs, error path only)."""
    from scipy.optimize import linprog

    def empty(a, b):
        res = linprog(np.zeros(3), A_ub=a, b_ub=b, bounds=[(None, None)] * 3, method="highs")
        return res.status == 2

    for k, ((a, b), m) in enumerate(zip(polys, margins)):
        if empty(a, b - m):
            return f"polytope {k} is empty (after shrinking by the margin)"
    for k in range(len(polys) - 1):
        a = np.vstack([polys[k][0], polys[k + 1][0]])
        b = np.concatenate([polys[k][1] - margins[k], polys[k + 1][1] - margins[k + 1]])
        if empty(a, b):
            return f"polytopes {k} and {k + 1} do not overlap"
    return "the corridor is too narrow for the requested continuity/degree"


def solve_corridor_qp(polytopes, waypoints, start, goal, config: TrajectoryConfig = None) -> BezierTrajectory:
    """Smoothest piecewise-Bezier curve from start to goal inside the corridor.

    polytopes: M polytopes, each an (A [F,3], b [F]) pair or an object with .A/.b (A x <= b);
    waypoints [M+1, 3]: the path the corridor was built around (sets the segment durations);
    start, goal [3]: must lie in the first / last polytope.
    Returns a BezierTrajectory with M segments of degree config.degree whose control points all satisfy
    their polytope's A x <= b (verified); `traj.info` holds solver, status, iterations, objective, timings.
    Raises CorridorInfeasibleError (a GoalUnreachableError) when no such curve exists and
    TrajectorySolverError on numerical failure.
    """
    config = config or TrajectoryConfig()
    config.validate()
    polys, wp, start, goal = checked_qp_input(polytopes, waypoints, start, goal)
    m, npts = len(polys), config.degree + 1
    free = free_ranges(m, npts, config.rest_at_ends)
    norms = face_norms(polys)  # once per QP: every working-set round and build uses them
    margin = config.effective_margin()
    fallback = None
    if config.solver == "active_set":
        traj, fallback = _solve_active_set(polys, wp, start, goal, config, free, norms)
        if traj is not None:
            return traj
        config = replace(config, solver="clarabel")
    build = functools.partial(assemble_qp, polys, wp, start, goal, config,
                              shrunk=[b - margin * norm for (_, b), norm in zip(polys, norms)])
    solve = functools.partial(solve_with_retry, config=config)
    qp, (x, status, iters, outcome, retry_tolerance), rounds = solve_with_working_set(
        polys, wp, margin, free, npts, build, solve, enabled=config.working_set and config.solver == "clarabel",
        norms=norms)
    if outcome == "infeasible":
        margins = [margin * norm for norm in norms]
        raise CorridorInfeasibleError(
            "No smooth trajectory fits inside the safe corridor: "
            f"{_diagnose_infeasible(polys, margins)}. The corridor's polytopes overlap too little for a smooth "
            "curve: try another start or target with more free space around the path, a smaller --camera-radius / "
            "--safety-margin, or a finer --grid-resolution (library callers: TrajectoryConfig.continuity / degree)."
        )
    if outcome == "failed":
        raise TrajectorySolverError(f"The {config.solver} QP solver did not converge (status {status}).")

    x = project_equalities(x, qp)
    cps = x.reshape(m, npts, 3).copy()
    # pinned points exactly (the solver meets equalities only to its tolerance)
    cps[0, : config.rest_at_ends + 1] = start
    cps[-1, npts - 1 - config.rest_at_ends :] = goal
    worst = _corridor_violation(cps, polys, free, config.solver)
    traj = BezierTrajectory(cps, qp.durations)
    traj.info = {
        "solver": config.solver,
        "status": status,
        "iterations": int(iters),
        "objective": qp.objective(x),
        "num_variables": qp.n,
        "num_inequalities": qp.n_in,  # of the last solve (working set: the faces it kept)
        "num_inequalities_full": _num_inequalities(polys, free),
        "qp_rounds": rounds["qp_rounds"],  # solves (working set: relaxations, the last one feasible for all faces)
        "num_equalities": qp.n_eq,
        "build_ms": 1e3 * rounds["build_s"],  # all rounds
        "solve_ms": 1e3 * rounds["solve_s"],
        "max_corridor_violation": worst,
        "retry_tolerance": retry_tolerance,  # None, or the looser tolerance a stalled first solve was retried with
        "fallback": fallback,  # None, or why the active-set solve handed this QP to Clarabel
    }
    return traj


def _num_inequalities(polys, free) -> int:
    """Inequality rows of the full QP: one per face of its segment and control point not pinned."""
    return sum((hi - lo) * a.shape[0] for (a, _), (lo, hi) in zip(polys, free) if hi > lo)


def _corridor_violation(cps: np.ndarray, polys, free, solver: str) -> float:
    """The largest a_f . P - b_f of a free control point against its true (unshrunk) polytope (-inf when none is free);
    TrajectorySolverError when it is > 0: a point outside the true polytope is never returned. From
    working_set.ARRAY_MIN_SEGMENTS segments up all faces at once: each face row against every control point of its
    segment, the pinned ones masked out."""
    if len(polys) < ARRAY_MIN_SEGMENTS:  # a few segments: the loop is cheaper than the gather
        worst = max((float(np.max(cps[k, lo:hi] @ a.T - b)) for k, ((a, b), (lo, hi)) in enumerate(zip(polys, free))
                     if hi > lo), default=-np.inf)
        return _refuse_outside(worst, solver)
    counts = np.array([a.shape[0] for a, _ in polys])
    seg = np.repeat(np.arange(len(polys)), counts)  # [F_all] segment of each face
    a = np.concatenate([a for a, _ in polys])  # [F_all, 3]
    b = np.concatenate([b for _, b in polys])
    lo, hi = np.array(free, dtype=np.int64).reshape(-1, 2).T  # [M] each
    idx = np.arange(cps.shape[1])
    vals = np.einsum("fc,fic->fi", a, cps[seg]) - b[:, None]  # [F_all, D+1]
    keep = (idx[None] >= lo[seg, None]) & (idx[None] < hi[seg, None])
    return _refuse_outside(float(vals[keep].max()) if keep.any() else -np.inf, solver)


def _refuse_outside(worst: float, solver: str) -> float:
    """``worst`` (the largest violation of a free control point), or TrajectorySolverError when it is > 0."""
    if worst > 0:
        raise TrajectorySolverError(
            f"The {solver} solution leaves the corridor by {worst:.2e}; increase TrajectoryConfig."
            f"{'osqp_margin' if solver == 'osqp' else 'margin'} or use the clarabel solver."
        )
    return worst


def _solve_active_set(polys, wp, start, goal, config: TrajectoryConfig, free, norms):
    """(the trajectory, None) by dual_qp.solve_corridor_dual, or (None, why) when it does not apply or does not finish:
    the caller then solves the QP with Clarabel. An infeasible verdict is also handed over, so Clarabel's verdict and
    its diagnosis (error path only) decide what the user is told."""
    t0 = time.perf_counter()
    m, d = len(polys), config.degree
    durations = segment_durations(wp, config)
    factors = segment_factors(d, durations, config)  # [M, 2D+1-r, D+1]
    margin = config.effective_margin()
    shrunk = [(a, b - margin * norm) for (a, b), norm in zip(polys, norms)]
    tol = config.active_set_tolerance * (1.0 + float(np.abs(wp).max()))
    res = solve_corridor_dual(durations, factors, shrunk, d, config.continuity, config.rest_at_ends, start, goal, tol)
    if res is None:
        return None, "the goal's pinned points fall on points the joins determine (degree - rest_at_ends <= continuity)"
    if res.outcome != "ok":
        return None, f"active set: {res.outcome} after {res.iterations} steps"
    cps = res.points
    worst = _corridor_violation(cps, polys, free, config.solver)
    traj = BezierTrajectory(cps, durations)
    n_eq = 3 * (2 * (config.rest_at_ends + 1) + (m - 1) * (config.continuity + 1))
    traj.info = {
        "solver": "active_set",
        "status": "Solved",
        "iterations": res.iterations,  # steps: faces added and dropped
        "objective": float((np.einsum("kij,kjc->kic", factors, cps) ** 2).sum()),  # = 1/2 x^T P x of CorridorQP
        "num_variables": cps.size,
        "num_inequalities": _num_inequalities(polys, free),  # all faces: the method adds only those it needs
        "num_inequalities_full": _num_inequalities(polys, free),
        "active_faces": res.active,  # faces in the working set at the optimum
        "qp_rounds": 1,
        "num_equalities": n_eq,
        "build_ms": 0.0,  # the elimination is part of the solve
        "solve_ms": 1e3 * (time.perf_counter() - t0),
        "max_corridor_violation": worst,
        "retry_tolerance": None,
        "fallback": None,
    }
    return traj, None
