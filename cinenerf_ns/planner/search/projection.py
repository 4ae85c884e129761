"""A point projected onto a convex polytope: argmin |x - target|^2 s.t. A x <= b (3 variables).

The goal stage's projection of a go-to target onto its Prop-2 safe polytope (goal.closest_safe_point) and the reach
stage's (reach.py). ``project_onto_polytope`` returns a point strictly inside or None when the polytope has no
interior: the dual active-set method (Goldfarb-Idnani, planner/dual_active_set.py) without a feasible start, the
primal active-set method from an interior point, Clarabel when neither finishes; both active-set methods are compiled
in native/project.c (``backend``), with the numpy code here as their reference.
"""
from __future__ import annotations

from typing import Optional, Union

import numpy as np

from ..corridor.polytope import chebyshev_center
from ..dual_active_set import add_face
from ..native import choose, project_dual_c, project_primal_c

INTERIOR_RADIUS = 1e-9
"""project_onto_polytope: a polytope counts as empty unless a ball of this radius (scene units) fits inside."""


def _native_projection_args(A: np.ndarray, b: np.ndarray, target: np.ndarray) -> tuple:
    """(A [F, 3], b [F], target [3]) as C-contiguous float64 arrays for native/project.c (ValueError on other
    shapes: the compiled code would read past them)."""
    A = np.ascontiguousarray(A, dtype=np.float64)
    b = np.ascontiguousarray(b, dtype=np.float64)
    if A.ndim != 2 or A.shape[1] != 3 or b.shape != (A.shape[0],):
        raise ValueError(f"A must be [F, 3] and b [F], got {A.shape} and {b.shape}")
    return A, b, np.ascontiguousarray(target, dtype=np.float64).reshape(3)


def _native_projection_result(code: int, x: np.ndarray, outcomes: dict):
    """What a native/project.c return code means: x, or outcomes[code]; LinAlgError where numpy's solve raises it,
    ZeroDivisionError where the Python division by a one-face working set's |a|^2 does (only when it underflows)."""
    if code == 0:
        return x
    if code == -1:
        raise np.linalg.LinAlgError("Singular matrix")
    if code == -2:
        raise ZeroDivisionError("float division by zero")
    if code in outcomes:
        return outcomes[code]
    raise MemoryError("the compiled projection ran out of memory")


def project_active_set(A: np.ndarray, b: np.ndarray, target: np.ndarray, x0: np.ndarray,
                       max_iter: int = 60, backend: str = "auto") -> Optional[np.ndarray]:
    """argmin_x |x - target|^2 s.t. A x <= b (A [F, 3], b [F]) by the primal active-set method (Nocedal &
    Wright, Alg. 16.3, Hessian I) from the feasible point x0 [3] -> x [3], or None when it does not
    finish in ``max_iter`` steps (degenerate vertices can cycle; the caller then uses a QP solver).

    Why not a QP solver: in 3 variables the working set holds at most 3 independent faces, so each step is a
    3x3 solve, and the whole projection is a few steps of ~10 us where Clarabel's set-up and interior-point
    iterations cost ~1 ms per goal. Exact up to rounding (the multipliers prove optimality); rounding can leave
    A x - b at ~1e-16, which the caller removes.
    backend: "auto" (native/project.c's cn_project_primal, the same steps up to rounding, when it loads),
    "native" or "python" (project_active_set_reference); a singular working set raises np.linalg.LinAlgError on
    both.
    """
    fn = choose(backend, project_primal_c, "project", "active-set projection")
    if fn is not None:
        A, b, t = _native_projection_args(A, b, target)
        x0 = np.ascontiguousarray(x0, dtype=np.float64).reshape(3)
        x = np.empty(3)
        code = fn(A.ctypes.data, b.ctypes.data, A.shape[0], t.ctypes.data, x0.ctypes.data, int(max_iter),
                  x.ctypes.data)
        return _native_projection_result(code, x, {1: None})
    return project_active_set_reference(A, b, target, x0, max_iter)


def project_active_set_reference(A: np.ndarray, b: np.ndarray, target: np.ndarray, x0: np.ndarray,
                                 max_iter: int = 60) -> Optional[np.ndarray]:
    """project_active_set in numpy: the reference of native/project.c's cn_project_primal (the same steps)."""
    A = np.asarray(A, dtype=np.float64)  # [F, 3]
    b = np.asarray(b, dtype=np.float64)  # [F]
    t = np.asarray(target, dtype=np.float64).reshape(3)
    x = np.asarray(x0, dtype=np.float64).reshape(3).copy()
    scale = 1.0 + float(np.abs(t).max()) + float(np.abs(x).max())
    row_norm = np.sqrt(np.einsum("fi,fi->f", A, A))  # [F]
    slack = b - A @ x  # [F]
    W: list[int] = []  # working set: independent faces held with equality
    for _ in range(max_iter):
        r = t - x  # [3]
        if len(W) == 1:
            m = A[W[0]]
            lam = np.array([float(m @ r) / float(m @ m)])
            p = r - lam[0] * m
        elif W:
            M = A[W]  # [k, 3]
            lam = np.linalg.solve(M @ M.T, M @ r)  # [k]  the multipliers when the step below vanishes
            p = r - M.T @ lam if len(W) < 3 else np.zeros(3)  # 3 independent faces: a vertex
        else:
            p, lam = r, None
        if float(np.abs(p).max()) <= 1e-13 * scale:
            if lam is None or float(lam.min()) >= -1e-12 * scale:
                return x  # KKT: x - t + M^T lam = 0 with lam >= 0
            W.pop(int(np.argmin(lam)))  # a face that pulls the wrong way leaves the working set
            continue
        Ap = A @ p  # [F]
        block = Ap > 1e-14 * float(np.sqrt(p @ p)) * row_norm
        block[W] = False
        alpha, j = 1.0, -1
        ids = np.flatnonzero(block)
        if len(ids) and W:
            # a face whose normal lies in the span of the working set's (a repeated plane, or three planes through
            # one line) has A p = 0 in exact arithmetic; rounding must not let it block and make the set dependent
            M = A[W]  # [k, 3]
            off_span = A[ids] - (A[ids] @ M.T) @ np.linalg.solve(M @ M.T, M)  # [c, 3]
            ids = ids[np.sqrt(np.einsum("ci,ci->c", off_span, off_span)) > 1e-9 * row_norm[ids]]
        if len(ids):
            ratio = np.maximum(slack[ids], 0.0) / Ap[ids]
            k = int(np.argmin(ratio))
            if ratio[k] < 1.0:
                alpha, j = float(ratio[k]), int(ids[k])
        x = x + alpha * p
        slack = slack - alpha * Ap
        if j >= 0:
            W.append(j)
    return None


def project_dual_active_set(A: np.ndarray, b: np.ndarray, target: np.ndarray,
                            max_iter: Optional[int] = None, backend: str = "auto") -> Union[np.ndarray, None, str]:
    """argmin_x |x - target|^2 s.t. A x <= b (A [F, 3], b [F]) by the dual active-set method of Goldfarb & Idnani
    (Math. Programming 27, 1983; Hessian I) -> x [3], None when the polytope is empty, or "unfinished" when it does
    not finish in ``max_iter`` steps or a step is too ill-conditioned to trust (the caller then solves it another way).

    Why: it needs no feasible start, so the projection of a target onto a polytope that may exclude it (or be empty:
    closest_safe_point's target deep inside an object) costs a few 3x3 solves instead of an LP for the Chebyshev
    centre followed by the primal method. It starts at the target (the unconstrained minimum) and adds the most
    violated face at each step, keeping x the projection of the target onto the working set's faces with
    nonnegative multipliers (dual feasible); the objective only grows, so faces cannot cycle in exact arithmetic.
    Empty polytope: the violated face's normal lies in the span of the working set's and no multiplier can shrink
    (Farkas: a nonnegative combination of faces proves A x <= b infeasible). Rounding leaves A x - b at ~1e-16
    relative; callers tighten b when they need the point strictly inside.
    backend: "auto" (native/project.c's cn_project_dual, the same steps up to rounding, when it loads),
    "native" or "python" (project_dual_active_set_reference); a singular working set raises np.linalg.LinAlgError
    on both."""
    fn = choose(backend, project_dual_c, "project", "dual active-set projection")
    if fn is not None:
        A, b, t = _native_projection_args(A, b, target)
        x = np.empty(3)
        code = fn(A.ctypes.data, b.ctypes.data, A.shape[0], t.ctypes.data,
                  50 + 4 * A.shape[0] if max_iter is None else int(max_iter), x.ctypes.data)
        return _native_projection_result(code, x, {1: None, 2: "unfinished"})
    return project_dual_active_set_reference(A, b, target, max_iter)


def project_dual_active_set_reference(A: np.ndarray, b: np.ndarray, target: np.ndarray,
                                      max_iter: Optional[int] = None) -> Union[np.ndarray, None, str]:
    """project_dual_active_set in numpy: the reference of native/project.c's cn_project_dual (the same steps)."""
    A = np.asarray(A, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    x = np.asarray(target, dtype=np.float64).reshape(3).copy()
    F = A.shape[0]
    if max_iter is None:
        max_iter = 50 + 4 * F
    row2 = np.einsum("fi,fi->f", A, A)  # [F] squared row norms
    scale = 1.0 + float(np.abs(b).max(initial=0.0)) + float(np.abs(x).max())
    tol = 1e-13 * scale
    W: list = []  # working set (independent faces held with equality)
    u = np.zeros(0)  # their multipliers, >= 0
    it = 0
    while True:
        v = A @ x - b  # [F] violation
        p = int(np.argmax(v)) if F else -1
        if F == 0 or v[p] <= tol * max(1.0, float(np.sqrt(row2[p]))):
            return x
        x, u, it, outcome = add_face(A, b, row2, p, x, W, u, it, max_iter)
        if outcome == "infeasible":
            return None  # a nonnegative combination of the working set's faces and face p is infeasible
        if outcome is not None:
            return outcome


def project_onto_polytope(A: np.ndarray, b: np.ndarray, target: np.ndarray,
                           interior: Optional[np.ndarray] = None) -> Optional[np.ndarray]:
    """argmin |x - target|^2 s.t. A x <= b, returned strictly inside in floating point (A x <= b holds), or None when
    the polytope has no interior (its Chebyshev radius is at most INTERIOR_RADIUS).

    With ``interior`` strictly inside (e.g. the polytope's seed): ``project_active_set`` from it (Clarabel when that
    does not finish), then pulled exactly inside along the segment to it (ratio test). Without one:
    ``project_dual_active_set`` onto the polytope tightened by INTERIOR_RADIUS (b - INTERIOR_RADIUS |a_f|: non-empty
    exactly when a ball of that radius fits, the rule the Chebyshev centre applied; the point moves by ~that radius
    and keeps that slack), so no LP is solved; the Chebyshev centre and the primal method only when it does not
    finish."""
    A = np.asarray(A, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if interior is not None and float(np.min(b - A @ np.asarray(interior, dtype=np.float64))) > INTERIOR_RADIUS:
        c = np.asarray(interior, dtype=np.float64)
    else:
        try:
            y = project_dual_active_set(A, b - INTERIOR_RADIUS * np.sqrt(np.einsum("fi,fi->f", A, A)), target)
        except np.linalg.LinAlgError:  # a working set that rounding made singular: the LP and primal method instead
            y = "unfinished"
        if y is None:
            return None
        if not isinstance(y, str) and (A @ y <= b).all():
            return y
        c, rad = chebyshev_center(A, b)
        if not (rad > INTERIOR_RADIUS):
            return None
    target = np.asarray(target, dtype=np.float64)
    try:
        x = project_active_set(A, b, target, c)
    except np.linalg.LinAlgError:  # a working set that rounding made singular: the QP solver instead
        x = None
    if x is None:
        x = _project_clarabel(A, b, target, c)
    viol = A @ x - b
    if (viol > 0).any():
        ax, ac = A @ x, A @ c
        alpha = np.max(np.where(viol > 0, viol / np.maximum(ax - ac, 1e-300), 0.0))
        x = x + min(1.0, alpha * (1 + 1e-9) + 1e-12) * (c - x)
    return x if (A @ x <= b).all() else None


def _project_clarabel(A: np.ndarray, b: np.ndarray, target: np.ndarray, c: np.ndarray) -> np.ndarray:
    """argmin |x - target|^2 s.t. A x <= b with Clarabel (``c`` when it does not solve)."""
    import clarabel
    from scipy import sparse

    P = sparse.csc_matrix(2.0 * np.eye(3))
    q = -2.0 * target
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    solver = clarabel.DefaultSolver(P, q, sparse.csc_matrix(A), b, [clarabel.NonnegativeConeT(len(b))], settings)
    sol = solver.solve()
    return np.asarray(sol.x, dtype=np.float64) if str(sol.status) in ("Solved", "AlmostSolved") else c.copy()
