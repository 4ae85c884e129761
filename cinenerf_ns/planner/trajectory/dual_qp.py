"""The corridor QP (qp.py) solved exactly: equalities eliminated, then the dual active-set method of Goldfarb & Idnani.

Why: Clarabel (interior point) spent most of a QP stage on captured requests in set-up (docs/PLANNER_DEFAULTS.md), for
problems of ~40 free control points of which ~12 faces are active at the optimum. A dual active-set method touches
only the faces it adds; here it is a few small dense solves.

1. Equalities eliminated (``reduce``). The pins and the C^c joins fix some control points as affine functions of the
   others: segment 0's first q+1 points are the start, the last segment's last q+1 the goal, and at every join k-1|k
   the r-th derivative condition (r = 0..c; d^r p/dt^r = D!/(D-r)! d^-r Delta^r P, the factorial cancels) gives

       P_{k,r} = (d_k / d_{k-1})^r (Delta^r P_{k-1})(end) - sum_{i<r} (Delta^r)_{0,i} P_{k,i}

   ((Delta^r)_{0,r} = 1). Every other control point is a variable: X = T Z + t with X [N, 3] all control points,
   Z [n, 3] the variables, T [N, n] and t [N, 3] (from start and goal). The equalities then hold by construction, to
   rounding.
   Not covered (``reduce`` returns None, the caller uses Clarabel): the goal's pins on points a join determines
   (M >= 2 and D - q <= c).
2. Cost. sum_k sum_c P_{k,:,c}^T H_k P_{k,:,c} with H_k = F_k^T F_k (qp.segment_factors) is |F (T Z + t)|^2 summed
   over x/y/z, F = blockdiag(F_k). A QR factorisation F T = Q U (U [n, n] upper) gives, with Y = U Z, the cost
   |Y - Y0|^2 + const, Y0 = -(Q^T F t)[:n]: a projection of Y0 onto a polytope in 3n dimensions. Why QR and not a
   Cholesky factor of the normal matrix T^T H T: the 1/d^5 weights of short segments make that matrix's condition
   number the square of F T's (up to ~1e11 on captured requests, 1e16 with a 0.05 s segment between 25 s ones), and
   the optimum lost digits accordingly. U is nonsingular when the full QP is strictly convex where its equalities
   hold (working_set.py: its flat directions are fixed by the pins and C0 joins); a singular U or one whose diagonal
   spans more than CONDITION_LIMIT is "ill-conditioned" and the caller uses Clarabel.
3. Constraints. Control point p (every one not pinned) and face f of its segment's polytope: a_f . X_p <= b_f - margin
   |a_f|, i.e. <w_p a_f^T, Y> <= beta_pf with w_p = U^-T T[p]^T [n] and beta_pf = b_f - margin |a_f| - a_f . t_p.
4. Dual active set (planner/dual_active_set.py, Hessian I, as in search/goal.py's projection but in 3n dimensions):
   start at Y0, add the face farthest outside (distance (a_f . X_p - b'_f) / |a_f| in scene units, first index on
   ties), keep Y the projection of Y0 onto the working set's faces with nonnegative multipliers; a multiplier reaching
   0 drops its face. It ends when no face is outside by more than ``tol``: then Y satisfies the KKT conditions of the
   full QP (primal feasible to tol, multipliers >= 0, complementary), so it is its exact optimum (to rounding), not an
   approximation of it.
   Infeasible (Farkas): the face to add lies in the span of the working set's and no multiplier can shrink.
   Unfinished (the caller hands the QP to Clarabel, as it does every outcome but "ok"): max_iter steps, a full step
   that rounding left short (t2 < 0), or the face farthest outside already in the working set. The last comes after a
   face nearly in the span of the working set's (|z|^2 / |row|^2 ~ 1e-16, above the dependency test's 1e-18) took a
   step of ~violation / |z|^2 (1e16): its rounding leaves that face outside, and adding it again would drop and re-add
   it with multipliers growing ~1e7-fold per round until they overflow (a near-infeasible corridor: hypothesis found
   one, test_dual_qp.py).

``solve_reduced_reference`` is the numpy reference: dense matrices, every constraint row in Y-space formed explicitly.
native/dual_qp.c (``backend="auto"``) does the same steps with the structure (Gram entries (w_i . w_j)(a_i . a_j),
violations from X) and is tested against it. The caller (qp.solve_corridor_qp) still checks every control point
against the unshrunk polytopes.
"""
from __future__ import annotations

import functools
from typing import List, NamedTuple, Optional, Sequence, Tuple

import numpy as np
from scipy.linalg import solve_triangular

from ..dual_active_set import add_face
from ..native import choose, corridor_dual_c
from .bezier import difference_matrix

FREE, START, GOAL, JOINED = 0, 1, 2, 3
"""Point kinds: a variable, pinned to the start, pinned to the goal, fixed by a join's continuity."""


class Reduction(NamedTuple):
    """The equality-free form of one corridor QP (module docstring, steps 1-3)."""

    T: np.ndarray  # [N, n] control points from variables
    t: np.ndarray  # [N, 3] control points from start / goal
    kind: np.ndarray  # [N] FREE / START / GOAL / JOINED
    L: np.ndarray  # [n, n] lower: U^T of F T = Q U (L L^T = T^T H T)
    y0: np.ndarray  # [n, 3] the unconstrained optimum in Y = L^T Z


@functools.lru_cache(maxsize=256)
def point_kinds(m: int, degree: int, continuity: int, rest_at_ends: int) -> Optional[np.ndarray]:
    """[M (D+1)] int64 kind of every control point (segment-major), or None when the goal's pins fall on joined points
    (cached per shape, read-only)."""
    npts = degree + 1
    kind = np.zeros((m, npts), dtype=np.int64)
    kind[1:, : continuity + 1] = JOINED
    if m > 1 and (kind[m - 1, degree - rest_at_ends:] == JOINED).any():
        return None
    kind[0, : rest_at_ends + 1] = START
    kind[m - 1, degree - rest_at_ends:] = GOAL
    kind = kind.ravel()
    kind.flags.writeable = False
    return kind


@functools.lru_cache(maxsize=64)
def _join_rows(degree: int, continuity: int) -> np.ndarray:
    """[c+1, 2, D+1]: per order r, (Delta^r)_{last} and (Delta^r)_0 padded to D+1, what dual_qp.c's joins read
    (cached, read-only)."""
    rows = np.zeros((continuity + 1, 2, degree + 1))
    for r in range(continuity + 1):
        d = difference_matrix(degree, r)
        rows[r, 0, : d.shape[1]] = d[-1]
        rows[r, 1, : d.shape[1]] = d[0]
    rows.flags.writeable = False
    return rows


def affine_map(durations: np.ndarray, degree: int, continuity: int, kind: np.ndarray) -> np.ndarray:
    """[N, n + 2]: every control point as a combination of the n variables, the start and the goal (last two
    columns), by forward substitution of the join equations (module docstring, step 1)."""
    m, npts = durations.size, degree + 1
    free = np.flatnonzero(kind == FREE)
    n = free.size
    rows = np.zeros((m * npts, n + 2))
    rows[free, np.arange(n)] = 1.0
    rows[kind == START, n] = 1.0
    rows[kind == GOAL, n + 1] = 1.0
    for k in range(1, m):
        prev, cur = rows[(k - 1) * npts: k * npts], rows[k * npts: (k + 1) * npts]
        for r in range(continuity + 1):
            diff = difference_matrix(degree, r)  # [D+1-r, D+1]
            ratio = (durations[k] / durations[k - 1]) ** r
            cur[r] = ratio * (diff[-1] @ prev) - diff[0, :r] @ cur[:r]
    return rows


def reduce(durations: np.ndarray, factors: np.ndarray, degree: int, continuity: int, rest_at_ends: int,
           start: np.ndarray, goal: np.ndarray) -> Optional[Reduction]:
    """Steps 1-2 of the module docstring: durations [M], factors [M, F, D+1] (qp.segment_factors: H_k = F_k^T F_k),
    start / goal [3] -> Reduction, or None when the parametrisation does not cover this configuration. Raises
    IllConditioned when the reduced cost is singular or too ill-conditioned to trust (CONDITION_LIMIT)."""
    m, npts = durations.size, degree + 1
    kind = point_kinds(m, degree, continuity, rest_at_ends)
    if kind is None:
        return None
    rows = affine_map(durations, degree, continuity, kind)
    n = rows.shape[1] - 2
    T = rows[:, :n]  # [N, n]
    t = rows[:, n, None] * start + rows[:, n + 1, None] * goal  # [N, 3]
    if n == 0:
        return Reduction(T, t, kind, np.zeros((0, 0)), np.zeros((0, 3)))
    F = np.zeros((m * factors.shape[1], m * npts))
    for k in range(m):
        F[k * factors.shape[1]: (k + 1) * factors.shape[1], k * npts: (k + 1) * npts] = factors[k]
    Q, U = np.linalg.qr(F @ T)  # [rows, n], [n, n]: F T = Q U, so R = T^T H T = U^T U
    _check_condition(np.diag(U))
    return Reduction(T, t, kind, U.T, -(Q.T @ (F @ t)))


CONDITION_LIMIT = 1e7
"""The largest ratio of |diagonal| entries of the factor U accepted: a lower bound of U's condition number, and errors
in the optimum grow with it (~1e-16 times it, relative). Captured 1M-Gaussian requests reach 5e3 (median 3e2); of
random corridors whose durations differ 100-300x, 8 in 96 exceed it (those go to Clarabel)."""


class IllConditioned(np.linalg.LinAlgError):
    """The reduced cost is singular or its factor's condition exceeds CONDITION_LIMIT."""


def _check_condition(diag: np.ndarray) -> None:
    d = np.abs(diag)
    if not d.min() > 0 or d.max() > CONDITION_LIMIT * d.min():
        raise IllConditioned(f"reduced cost factor diagonal spans {d.min():.3g} .. {d.max():.3g}")


def control_points(red: Reduction, y: np.ndarray) -> np.ndarray:
    """[N, 3] control points X = T Z + t of Y [n, 3] (Z = L^-T Y)."""
    if red.L.shape[0] == 0:
        return red.t.copy()
    return red.T @ solve_triangular(red.L, y, lower=True, trans="T") + red.t


class DualResult(NamedTuple):
    """What solve_reduced_reference returns."""

    points: Optional[np.ndarray]  # [N, 3] control points (outcome "ok"), else None
    outcome: str  # "ok", "infeasible", "unfinished" (max_iter, or a step rounding cannot be trusted); from
    # solve_corridor_dual also "ill-conditioned" (reduce) and "failed" (a singular working set)
    iterations: int  # steps taken (adds and drops)
    active: int  # faces in the working set at the end


def constraint_rows(red: Reduction, polys: Sequence[Tuple[np.ndarray, np.ndarray]], degree: int
                    ) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every (point, face) pair of the QP's inequalities, points in order and their segment's faces in order:
    (point [K], face row a [K, 3], shrunk offset b' [K], 1 / |a| [K]). polys: per segment (A [F, 3], b' [F]) with
    b' already shrunk by the margin."""
    npts = degree + 1
    pts, a_rows, b_rows = [], [], []
    for p in np.flatnonzero((red.kind == FREE) | (red.kind == JOINED)):
        a, b = polys[p // npts]
        pts.append(np.full(a.shape[0], p))
        a_rows.append(a)
        b_rows.append(b)
    if not pts:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros(0), np.zeros(0)
    a = np.concatenate(a_rows)
    return np.concatenate(pts), a, np.concatenate(b_rows), 1.0 / np.linalg.norm(a, axis=1)


def solve_reduced_reference(red: Reduction, polys: Sequence[Tuple[np.ndarray, np.ndarray]], degree: int, tol: float,
                  max_iter: Optional[int] = None) -> DualResult:
    """Step 4 of the module docstring, in numpy (the reference): polys per segment (A [F, 3], b' [F]) shrunk by the
    margin; a face counts as met when its point is at most ``tol`` (scene units) outside. A singular working set
    raises np.linalg.LinAlgError."""
    pts, a, b, inv_norm = constraint_rows(red, polys, degree)
    n = red.L.shape[0]
    K = pts.size
    if max_iter is None:
        max_iter = 50 + 4 * K
    if n == 0 or K == 0:  # nothing to choose: the pinned curve (checked against its polytopes by the caller)
        return DualResult(control_points(red, red.y0), "ok", 0, 0)
    W_pts = solve_triangular(red.L, red.T.T, lower=True)  # [n, N]: column p is w_p
    # every constraint row in Y-space, flattened: N_all[i] = vec(w_p a_f^T) [3n], offsets beta
    N_all = (W_pts[:, pts].T[:, :, None] * a[:, None, :]).reshape(K, 3 * n)  # [K, 3n]
    beta = b - np.einsum("ki,ki->k", a, red.t[pts])  # [K]
    row2 = np.einsum("ki,ki->k", N_all, N_all)  # [K]
    y = red.y0.reshape(-1).copy()  # [3n]
    W: List[int] = []  # working set
    u = np.zeros(0)  # its multipliers, >= 0
    it = 0
    while True:
        x = control_points(red, y.reshape(n, 3))  # [N, 3]
        v = (np.einsum("ki,ki->k", a, x[pts]) - b) * inv_norm  # [K] distance outside each shrunk face
        p = int(np.argmax(v))
        if v[p] <= tol:
            return DualResult(x, "ok", it, len(W))
        if p in W:  # a face held with equality is outside by more than tol: rounding (a huge step), see below
            return DualResult(None, "unfinished", it, len(W))
        y, u, it, outcome = add_face(N_all, beta, row2, p, y, W, u, it, max_iter)
        if outcome is not None:
            return DualResult(None, outcome, it, len(W))


def solve_corridor_dual(durations: np.ndarray, factors: np.ndarray,
                        polys: Sequence[Tuple[np.ndarray, np.ndarray]], degree: int, continuity: int,
                        rest_at_ends: int, start: np.ndarray, goal: np.ndarray, tol: float, backend: str = "auto",
                        max_iter: Optional[int] = None) -> Optional[DualResult]:
    """The corridor QP by steps 1-4: durations [M], factors [M, F, D+1] (qp.segment_factors), polys per segment
    (A [F, 3], b' [F]) with b' shrunk by the margin, start / goal [3], tol (scene units) -> DualResult with points
    [M, D+1, 3]; None when the parametrisation does not cover the configuration. outcome "ill-conditioned" (reduce:
    IllConditioned) or "failed" (a singular working set): the caller solves it another way.
    backend: "auto" (native/dual_qp.c when it loads), "native" or "python" (this numpy code, the reference);
    max_iter: steps before "unfinished" (None: 50 + 4 K for K face rows)."""
    m, npts = durations.size, degree + 1
    fn = choose(backend, corridor_dual_c, "dual_qp", "corridor dual active-set QP")
    if fn is not None:
        return _solve_native(fn, durations, factors, polys, degree, continuity, rest_at_ends, start, goal, tol,
                             -1 if max_iter is None else int(max_iter))
    try:
        red = reduce(durations, factors, degree, continuity, rest_at_ends, start, goal)
        if red is None:
            return None
        res = solve_reduced_reference(red, polys, degree, tol, max_iter)
    except IllConditioned:
        return DualResult(None, "ill-conditioned", 0, 0)
    except np.linalg.LinAlgError:
        return DualResult(None, "failed", 0, 0)
    if res.points is not None:
        res = res._replace(points=res.points.reshape(m, npts, 3))
    return res


_NATIVE_OUTCOMES = {0: "ok", 1: "infeasible", 2: "unfinished", -1: "failed", -4: "ill-conditioned"}


def _solve_native(fn, durations, factors, polys, degree, continuity, rest_at_ends, start, goal, tol, max_iter):
    """solve_corridor_dual through native/dual_qp.c: the same inputs as float64 C arrays."""
    m, npts = durations.size, degree + 1
    kind = point_kinds(m, degree, continuity, rest_at_ends)
    if kind is None:
        return None
    diffs = _join_rows(degree, continuity)
    counts = np.array([a.shape[0] for a, _ in polys], dtype=np.int64)
    face_start = np.zeros(m + 1, dtype=np.int64)
    np.cumsum(counts, out=face_start[1:])
    a = np.ascontiguousarray(np.concatenate([p[0] for p in polys]), dtype=np.float64)
    b = np.ascontiguousarray(np.concatenate([p[1] for p in polys]), dtype=np.float64)
    dur = np.ascontiguousarray(durations, dtype=np.float64)
    fac = np.ascontiguousarray(factors, dtype=np.float64)
    ends = np.ascontiguousarray(np.stack([start, goal]), dtype=np.float64)
    out = np.empty((m * npts, 3))
    info = np.zeros(2, dtype=np.int64)
    code = fn(m, degree, continuity, fac.shape[1], dur.ctypes.data, fac.ctypes.data, diffs.ctypes.data,
              kind.ctypes.data, ends.ctypes.data, a.ctypes.data, b.ctypes.data, face_start.ctypes.data, float(tol),
              max_iter, out.ctypes.data, info.ctypes.data)
    if code == -3:
        raise MemoryError("native/dual_qp.c could not allocate its work arrays")
    outcome = _NATIVE_OUTCOMES[int(code)]
    return DualResult(out.reshape(m, npts, 3) if outcome == "ok" else None, outcome, int(info[0]), int(info[1]))
