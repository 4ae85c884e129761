"""The general QP solvers of the corridor QP (qp_matrices.CorridorQP): Clarabel (interior point, retried once at a
looser tolerance when it stalls) and OSQP (ADMM + polishing), called with the matrices directly; and the projection
that makes a solver's point meet the equalities to rounding. qp.solve_corridor_qp and shots/multistop.py use them."""
from __future__ import annotations

from dataclasses import replace
from typing import NamedTuple, Tuple

import numpy as np
import scipy.sparse as sp
from scipy.linalg.lapack import dpotrf, dpotrs

from ..errors import TrajectorySolverError
from .qp_config import TrajectoryConfig
from .qp_matrices import CorridorQP


def _normalised(P: sp.csc_matrix) -> sp.csc_matrix:
    """P / max(diag P): same minimiser, objective of order one (the solvers' absolute tolerances then mean
    the same thing whatever the durations and weights)."""
    return P / max(float(P.diagonal().max()), 1e-300)


class _CscLists(NamedTuple):
    """A CSC matrix as Python lists, what clarabel.DefaultSolver gets. Why: its binding (pinned clarabel 0.11.1,
    src/python/cscmatrix_py.rs) reads ``data`` / ``indices`` / ``indptr`` / ``shape`` / ``has_canonical_format`` by
    attribute and extracts the arrays element by element, one numpy scalar per element; from lists that is ~80 us less
    of a ~300 us set-up (captured 1M-Gaussian QPs), the same matrix and the same solve."""

    data: list
    indices: list
    indptr: list
    shape: Tuple[int, int]
    has_canonical_format: bool

    @classmethod
    def of(cls, m: sp.csc_matrix) -> "_CscLists":
        return cls(m.data.tolist(), m.indices.tolist(), m.indptr.tolist(), m.shape, bool(m.has_canonical_format))


def solve_clarabel(qp: CorridorQP, config: TrajectoryConfig):
    import clarabel

    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.max_iter = config.max_iter
    settings.tol_feas = config.tolerance
    settings.tol_gap_abs = config.tolerance
    settings.tol_gap_rel = config.tolerance
    settings.iterative_refinement_enable = bool(config.iterative_refinement)
    cones = [clarabel.ZeroConeT(qp.n_eq)]
    if qp.n_in > 0:
        cones.append(clarabel.NonnegativeConeT(qp.n_in))
    solver = clarabel.DefaultSolver(_CscLists.of(qp.P_upper), [0.0] * qp.n, _CscLists.of(qp.A), qp.b.tolist(), cones,
                                    settings)
    sol = solver.solve()
    status = str(sol.status)
    if sol.status in (clarabel.SolverStatus.PrimalInfeasible, clarabel.SolverStatus.AlmostPrimalInfeasible):
        return None, status, sol.iterations, "infeasible"
    if sol.status not in (clarabel.SolverStatus.Solved, clarabel.SolverStatus.AlmostSolved):
        return None, status, sol.iterations, "failed"
    return np.asarray(sol.x, dtype=np.float64), status, sol.iterations, "ok"


def solve_osqp(qp: CorridorQP, config: TrajectoryConfig):
    import osqp

    lo = np.concatenate([qp.b_eq, np.full(qp.n_in, -np.inf)])
    hi = qp.b
    solver = osqp.OSQP()
    solver.setup(
        _normalised(qp.P_upper), np.zeros(qp.n), qp.A, lo, hi,
        verbose=False, polishing=True, eps_abs=config.osqp_tolerance, eps_rel=config.osqp_tolerance,
        max_iter=100 * config.max_iter,
    )
    res = solver.solve(raise_error=False)
    status = str(res.info.status)
    sv = res.info.status_val
    if sv in (osqp.SolverStatus.OSQP_PRIMAL_INFEASIBLE, osqp.SolverStatus.OSQP_PRIMAL_INFEASIBLE_INACCURATE):
        return None, status, res.info.iter, "infeasible"
    if sv not in (osqp.SolverStatus.OSQP_SOLVED, osqp.SolverStatus.OSQP_SOLVED_INACCURATE):
        return None, status, res.info.iter, "failed"
    return np.asarray(res.x, dtype=np.float64), status, res.info.iter, "ok"


def project_equalities(x: np.ndarray, qp: CorridorQP) -> np.ndarray:
    """Smallest correction making the equalities (ends, continuity) hold to rounding error.

    The solvers meet equalities only to their tolerance (OSQP ~1e-6); the correction is of that size, far
    below the corridor margin, and the corridor check after it still decides whether the result is kept.
    Dense: A_eq is [3 (2 (q+1) + (M-1)(c+1)), n], a few hundred rows for the longest corridors.
    """
    a = qp.eq_dense  # [n_eq, n]
    resid = a @ x - qp.b_eq
    if not np.isfinite(resid).all():
        raise TrajectorySolverError("the QP solver returned a non-finite point.")
    gram = a @ a.T  # [n_eq, n_eq] SPD when the equalities are independent
    # the LAPACK calls of scipy's cho_factor / cho_solve (upper factor), without their per-call input checks (~35 us)
    factor, info = dpotrf(gram, lower=0, clean=0)
    if info == 0:
        corr, info = dpotrs(factor, resid, lower=0)
    if info != 0 or not np.isfinite(corr).all():  # dependent equalities (unusual degree/continuity mixes)
        corr, *_ = np.linalg.lstsq(gram, resid, rcond=None)
    return x - a.T @ corr


RETRY_TOLERANCE = 1e-6  # Clarabel's tolerance for the one retry after a stalled solve (solve_corridor_qp)


def solve_with_retry(qp: CorridorQP, config: TrajectoryConfig):
    """(x, status, iterations, outcome, retry_tolerance) of the configured solver; Clarabel retried once if stalled."""
    solve = solve_clarabel if config.solver == "clarabel" else solve_osqp
    x, status, iters, outcome = solve(qp, config)
    retry_tolerance = None
    if outcome == "failed" and config.solver == "clarabel" and config.tolerance < RETRY_TOLERANCE:
        # Why: a very short segment makes the cost ill-conditioned (its 1/d^5 terms), and Clarabel can stall
        # (InsufficientProgress) short of 1e-8 on a QP that is plainly feasible (5 waypoints in a big box, one
        # segment 0.04 long). At 1e-6 it converges; the margin (1e-5) absorbs that tolerance, and every control point
        # is still verified against the true polytopes (solve_corridor_qp).
        retry_tolerance = RETRY_TOLERANCE
        x, status, iters, outcome = solve(qp, replace(config, tolerance=RETRY_TOLERANCE, iterative_refinement=True))
    return x, status, iters, outcome, retry_tolerance
