"""The corridor QP's matrices (the problem is stated in qp.py's module docstring): segment durations, the cost's
Hessians and factors, the equalities (pins, C^c joins) and the corridor inequalities, assembled as scipy CSC
(``assemble_qp``, straight from cached sparsity patterns; ``assemble_qp_reference``, plain COO triplets, is what it is
tested against); ``checked_qp_input`` turns a corridor into float64 numpy and refuses bad ones."""
from __future__ import annotations

import functools
import math
from typing import Any, List, NamedTuple, Sequence, Tuple

import numpy as np
import scipy.sparse as sp

from ..errors import CorridorInfeasibleError, InvalidInputError
from .bezier import difference_matrix, to_numpy
from .qp_config import TrajectoryConfig


# ---------------------------------------------------------------------------------------------- helpers
@functools.lru_cache(maxsize=None)
def bernstein_gram(n: int) -> np.ndarray:
    """G_{jl} = integral_0^1 B_{j,n}(u) B_{l,n}(u) du, [n+1, n+1] (cached, read-only)."""
    j = np.arange(n + 1)
    cj = np.array([math.comb(n, k) for k in j], dtype=np.float64)
    c2 = np.array([math.comb(2 * n, k) for k in range(2 * n + 1)], dtype=np.float64)
    g = np.outer(cj, cj) / ((2 * n + 1) * c2[j[:, None] + j[None, :]])
    g.flags.writeable = False
    return g


@functools.lru_cache(maxsize=None)
def _difference(degree: int, order: int) -> np.ndarray:
    diff = difference_matrix(degree, order)
    diff.flags.writeable = False
    return diff


@functools.lru_cache(maxsize=None)
def _unit_hessians(degree: int, order: int) -> Tuple[np.ndarray, np.ndarray]:
    """(c_r^2 Delta_r^T G Delta_r, Delta_1^T Delta_1): smoothness Hessian for d = 1 and the length Hessian."""
    c_r = math.factorial(degree) / math.factorial(degree - order)
    diff = _difference(degree, order)
    smooth = c_r**2 * diff.T @ bernstein_gram(degree - order) @ diff
    d1 = _difference(degree, 1)
    length = d1.T @ d1
    smooth.flags.writeable = False
    length.flags.writeable = False
    return smooth, length


def segment_hessians(degree: int, durations: np.ndarray, config: TrajectoryConfig) -> np.ndarray:
    """H_k with cost_k = sum_c P_{k,:,c}^T H_k P_{k,:,c}: durations [M] -> [M, D+1, D+1] (symmetric PSD).

    Smoothness scales as 1/d^(2r-1): d^r/dt^r brings d^-r twice and dt = d du brings d once.
    """
    r = config.smoothness_order
    smooth, length = _unit_hessians(degree, r)
    w = config.smoothness_weight / np.asarray(durations, dtype=np.float64) ** (2 * r - 1)  # [M]
    return w[:, None, None] * smooth + config.length_weight * length


@functools.lru_cache(maxsize=None)
def _unit_factors(degree: int, order: int) -> Tuple[np.ndarray, np.ndarray]:
    """(F_s [D+1-r, D+1], F_l [D, D+1]) with F_s^T F_s and F_l^T F_l the two unit Hessians of ``_unit_hessians``:
    c_r L_G^T Delta_r (G = L_G L_G^T, the Bernstein Gram matrix) and Delta_1."""
    c_r = math.factorial(degree) / math.factorial(degree - order)
    smooth = c_r * np.linalg.cholesky(bernstein_gram(degree - order)).T @ _difference(degree, order)
    length = _difference(degree, 1).copy()
    smooth.flags.writeable = False
    length.flags.writeable = False
    return smooth, length


def segment_factors(degree: int, durations: np.ndarray, config: TrajectoryConfig) -> np.ndarray:
    """F_k with F_k^T F_k = segment_hessians' H_k: durations [M] -> [M, 2 D + 1 - r, D+1] (the smoothness factor scaled
    by sqrt(weight / d^(2r-1)) over the length factor scaled by sqrt(length_weight)). Why: a cost written as |F P|^2
    is computed and factorised without squaring its condition number (dual_qp.py)."""
    r = config.smoothness_order
    smooth, length = _unit_factors(degree, r)
    w = np.sqrt(config.smoothness_weight / np.asarray(durations, dtype=np.float64) ** (2 * r - 1))  # [M]
    out = np.empty((w.size, smooth.shape[0] + length.shape[0], degree + 1))
    out[:, : smooth.shape[0]] = w[:, None, None] * smooth
    out[:, smooth.shape[0]:] = math.sqrt(config.length_weight) * length
    return out


def segment_durations(waypoints: np.ndarray, config: TrajectoryConfig) -> np.ndarray:
    """[M+1, 3] waypoints -> [M] durations (seconds)."""
    lengths = np.linalg.norm(np.diff(waypoints, axis=0), axis=1)
    return np.maximum(lengths / config.nominal_speed, config.min_segment_duration)


def as_polytopes(polytopes: Sequence[Any]) -> List[Tuple[np.ndarray, np.ndarray]]:
    """[(A [F, 3], b [F])] float64 numpy of (A, b) pairs or objects with .A / .b; InvalidInputError for a bad shape or a
    NaN / inf coefficient (one finiteness check over all of them: per polytope it cost more than the rest)."""
    out = []
    for k, poly in enumerate(polytopes):
        if (type(poly) is tuple and len(poly) == 2 and type(poly[0]) is np.ndarray and type(poly[1]) is np.ndarray
                and poly[0].dtype == np.float64 and poly[1].dtype == np.float64):
            a, b = poly[0], poly[1].reshape(-1)  # what Corridor.constraints gives: no conversion
        else:
            if hasattr(poly, "A") and hasattr(poly, "b"):
                a, b = poly.A, poly.b
            else:
                try:
                    a, b = poly
                except (TypeError, ValueError):
                    raise InvalidInputError(f"polytope {k} must be an (A, b) pair or have .A and .b") from None
            a = to_numpy(a)
            b = to_numpy(b).reshape(-1)
        if a.ndim != 2 or a.shape[1] != 3 or a.shape[0] != b.shape[0] or a.shape[0] == 0:
            raise InvalidInputError(
                f"polytope {k}: A must be [F, 3] and b [F] with F >= 1, got A {a.shape}, b {b.shape}."
            )
        out.append((a, b))
    if out and not (np.isfinite(np.concatenate([a.ravel() for a, _ in out])).all()
                    and np.isfinite(np.concatenate([b for _, b in out])).all()):
        k = next(k for k, (a, b) in enumerate(out) if not (np.isfinite(a).all() and np.isfinite(b).all()))
        raise InvalidInputError(f"polytope {k} has NaN or inf coefficients.")
    return out


def point_violation(a: np.ndarray, b: np.ndarray, x: np.ndarray) -> float:
    """Largest distance-normalised violation max_f (a_f.x - b_f)/|a_f| (<= 0 inside)."""
    return float(np.max((a @ x - b) / np.linalg.norm(a, axis=1)))


# ---------------------------------------------------------------------------------------------- QP
class CorridorQP:
    """The assembled QP: minimise 1/2 x^T P x subject to A_eq x = b_eq, A_in x <= b_in.

    Stored in the forms the default path uses, so a plan pays for no scipy conversion it does not need (they took
    over half of the QP stage; ``assemble_qp`` writes A straight in CSC): ``P_upper`` (the upper triangle of P, what
    Clarabel reads), ``A`` (equalities stacked over inequalities) and ``eq_dense`` (A_eq as a dense array: the
    post-solve equality projection is a small dense solve). ``P``, ``A_eq`` and ``A_in`` are built from these on
    first use (OSQP, multi-stop, tests)."""

    def __init__(self, P_upper: sp.csc_matrix, A: sp.csc_matrix, b: np.ndarray, n_eq: int, eq_dense: np.ndarray,
                 durations: np.ndarray, degree: int, num_segments: int, polytopes: list):
        self.P_upper = P_upper  # [n, n] upper triangle (diagonal included)
        self.A = A  # [n_eq + n_in, n] CSC, equality rows first
        self.b = b  # [n_eq + n_in]
        self.n_eq = int(n_eq)
        self.eq_dense = eq_dense  # [n_eq, n]
        self.durations = durations  # [M]
        self.degree = degree
        self.num_segments = num_segments
        self.polytopes = polytopes  # [(A [F,3], b [F])] numpy float64, unshrunk
        self._cache: dict = {}

    @classmethod
    def from_matrices(cls, P, A_eq, b_eq, A_in, b_in, durations, degree, num_segments, polytopes) -> "CorridorQP":
        """From a full symmetric P and separate equality / inequality blocks (any scipy sparse format)."""
        A_eq = sp.csc_matrix(A_eq)
        qp = cls(sp.triu(P, format="csc"), sp.vstack([A_eq, sp.csc_matrix(A_in)], format="csc"),
                 np.concatenate([b_eq, b_in]), A_eq.shape[0], A_eq.toarray(), durations, degree, num_segments,
                 polytopes)
        qp._cache["P"] = sp.csc_matrix(P)
        return qp

    @property
    def n(self) -> int:
        return self.P_upper.shape[0]

    @property
    def P(self) -> sp.csc_matrix:
        """[n, n] full symmetric."""
        if "P" not in self._cache:
            u = self.P_upper
            self._cache["P"] = (u + u.T - sp.diags(u.diagonal())).tocsc()
        return self._cache["P"]

    @property
    def A_eq(self) -> sp.csc_matrix:
        if "A_eq" not in self._cache:
            self._cache["A_eq"] = sp.csc_matrix(self.eq_dense)
        return self._cache["A_eq"]

    @property
    def A_in(self) -> sp.csc_matrix:
        if "A_in" not in self._cache:
            self._cache["A_in"] = self.A[self.n_eq:].tocsc()
        return self._cache["A_in"]

    @property
    def b_eq(self) -> np.ndarray:
        return self.b[: self.n_eq]

    @property
    def b_in(self) -> np.ndarray:
        return self.b[self.n_eq:]

    @property
    def n_in(self) -> int:
        return self.A.shape[0] - self.n_eq

    def objective(self, x: np.ndarray) -> float:
        """1/2 x^T P x from the upper triangle (x^T P x = 2 x^T U x - sum diag(U) x^2)."""
        u = self.P_upper
        return float(x @ (u @ x) - 0.5 * (u.diagonal() * x * x).sum())


@functools.lru_cache(maxsize=None)
def _upper_block_pattern(npts: int) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """CSC pattern of the upper triangle of one segment's kron(H, I3) block: (rows [Z], i [Z], j [Z], indptr
    [3 npts + 1]) in column order (column j * 3 + c holds rows i * 3 + c for i = 0..j; value H[i, j])."""
    rows, ii, jj, ptr = [], [], [], [0]
    for j in range(npts):
        for c in range(3):
            for i in range(j + 1):
                rows.append(i * 3 + c)
                ii.append(i)
                jj.append(j)
            ptr.append(len(rows))
    return np.array(rows), np.array(ii), np.array(jj), np.array(ptr)


def build_corridor_qp(polytopes, waypoints, start, goal, config: TrajectoryConfig, faces=None) -> CorridorQP:
    """Assemble the sparse QP matrices (see the module docstring). Validates the input. faces: per polytope the
    indices of the faces that get inequality rows (None: all); ``polytopes`` keeps them all."""
    config.validate()
    return assemble_qp(*checked_qp_input(polytopes, waypoints, start, goal), config, faces)


def assemble_qp(polys, wp, start, goal, config: TrajectoryConfig, faces=None, shrunk=None) -> CorridorQP:
    """The QP's matrices, A straight in CSC from cached patterns (``assemble_qp_reference`` is the plain construction
    it is tested against: the same arrays bit for bit). shrunk: per polytope b - margin * |rows of A| for all its
    faces (the working set passes it so the norms are taken once per request; None: computed here)."""
    m = len(polys)
    d = config.degree
    npts = d + 1
    n = m * npts * 3
    durations = segment_durations(wp, config)
    pat = _equality_pattern(m, d, config.rest_at_ends, config.continuity)
    pv = _join_factors(durations, config.continuity)[pat.factor] * pat.coef  # [E] point-level equality values
    if not pv.all():  # a join factor underflowed to 0 (absurd duration ratios): the COO path drops those entries
        return assemble_qp_reference(polys, wp, start, goal, config, faces)
    P_upper = _objective_upper(2.0 * segment_hessians(d, durations, config), n)
    margin = config.effective_margin()
    if shrunk is None:
        shrunk = [b - margin * np.linalg.norm(a, axis=1) for a, b in polys]
    if faces is None:
        in_polys = [(a, bs) for (a, _), bs in zip(polys, shrunk)]
    else:
        in_polys = [(a[f], bs[f]) for (a, _), bs, f in zip(polys, shrunk, faces)]
    n_faces = np.array([a.shape[0] for a, _ in in_polys])  # [M]
    counts = pat.eq_count + np.repeat(n_faces[:, None] * pat.free, 3)  # [n] entries per column
    indptr = np.zeros(n + 1, dtype=np.int32)
    np.cumsum(counts, out=indptr[1:])
    nnz = int(indptr[-1])
    data = np.empty(nnz)
    indices = np.empty(nnz, dtype=np.int32)
    eq_pos = indptr[pat.eq_col] + pat.eq_rank  # equality rows come first in every column
    eq_vals = pv[pat.eq_entry]
    data[eq_pos] = eq_vals
    indices[eq_pos] = pat.eq_row
    # inequalities, in column order: segment k, free point p, coordinate c, then its F_k faces (rows row0 + p F_k + j)
    vals, rows, b_in, row0 = [], [], [pat.b_eq(start, goal)], pat.n_eq
    for (a, bs), nf in zip(in_polys, pat.num_free):
        f = a.shape[0]
        if nf == 0 or f == 0:
            continue
        # (ndarray.repeat rather than np.tile / np.broadcast_to: a C call each, ~5x less overhead per segment)
        vals.append(a.T[None].repeat(nf, axis=0).ravel())  # [nf * 3 * F]
        rows.append(np.arange(row0, row0 + nf * f, dtype=np.int32).reshape(nf, 1, f).repeat(3, axis=1).ravel())
        b_in.append(bs[None].repeat(nf, axis=0).ravel())  # [nf * F]
        row0 += nf * f
    if vals:
        ineq = np.ones(nnz, dtype=bool)
        ineq[eq_pos] = False
        data[ineq] = np.concatenate(vals)
        indices[ineq] = np.concatenate(rows)
    A = sp.csc_matrix((data, indices, indptr), shape=(row0, n))
    eq_dense = np.zeros((pat.n_eq, n))
    eq_dense[pat.eq_row, pat.eq_col] = eq_vals
    return CorridorQP(P_upper, A, np.concatenate(b_in), pat.n_eq, eq_dense, durations, d, m, polys)


class _EqualityPattern(NamedTuple):
    """Where the equalities sit in the stacked CSC A (depends on M, D, rest_at_ends and continuity only)."""

    n_eq: int
    factor: np.ndarray  # [E] per point-level entry (sorted by column, then row): index into _join_factors
    coef: np.ndarray  # [E] its difference coefficient (sign included)
    eq_entry: np.ndarray  # [3E] per entry of A's equality block in CSC order: its point-level entry
    eq_row: np.ndarray  # [3E] its row
    eq_col: np.ndarray  # [3E] its column
    eq_rank: np.ndarray  # [3E] its position in the column
    eq_count: np.ndarray  # [n] equality entries per column
    free: np.ndarray  # [M, D+1] 1 where the control point gets inequality rows (not pinned)
    num_free: List[int]  # [M] free control points per segment
    pins: int  # rest_at_ends + 1

    def b_eq(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """[n_eq] right-hand side: the pinned points, then zeros for the joins."""
        out = np.zeros(self.n_eq)
        pins = out[: 6 * self.pins].reshape(2, self.pins, 3)
        pins[0] = start
        pins[1] = goal
        return out


@functools.lru_cache(maxsize=256)
def _equality_pattern(m: int, d: int, q: int, continuity: int) -> _EqualityPattern:
    """The equalities of ``_equalities`` as a pattern: the same point-level entries (pins, then per order r the end and
    start coefficients of every join, zeros dropped), their values as factor * coef, sorted into CSC order."""
    npts = d + 1
    pin_rows = 2 * (q + 1)
    rows = [np.arange(pin_rows)]
    cols = [np.concatenate([np.arange(q + 1), (m - 1) * npts + d - np.arange(q + 1)])]
    factor = [np.zeros(pin_rows, dtype=np.int64)]
    coef = [np.ones(pin_rows)]
    if m > 1:
        joins = np.arange(m - 1)
        for r in range(continuity + 1):
            diff = _difference(d, r)
            row_ids = np.repeat(pin_rows + joins * (continuity + 1) + r, npts)
            rows += [row_ids, row_ids]
            cols += [(joins[:, None] * npts + np.arange(npts)).ravel(),
                     ((joins[:, None] + 1) * npts + np.arange(npts)).ravel()]
            factor += [np.repeat(1 + 2 * r * (m - 1) + joins, npts), np.repeat(1 + (2 * r + 1) * (m - 1) + joins, npts)]
            coef += [np.tile(diff[-1], m - 1), np.tile(-diff[0], m - 1)]
    pr, pc, fi, cf = (np.concatenate(v) for v in (rows, cols, factor, coef))
    keep = cf != 0.0
    pr, pc, fi, cf = pr[keep], pc[keep], fi[keep], cf[keep]
    order = np.lexsort((pr, pc))
    pr, pc, fi, cf = pr[order], pc[order], fi[order], cf[order]
    per_point = np.bincount(pc, minlength=m * npts)  # [M (D+1)]
    start = np.concatenate([[0], np.cumsum(per_point)[:-1]])
    entry, row, col, rank = [], [], [], []
    for p in range(m * npts):
        e = np.arange(start[p], start[p] + per_point[p])
        for c in range(3):
            entry.append(e)
            row.append(pr[e] * 3 + c)
            col.append(np.full(e.size, p * 3 + c))
            rank.append(np.arange(e.size))
    free = np.ones((m, npts), dtype=np.int64)
    free[0, : q + 1] = 0
    free[m - 1, d - q:] = 0
    out = _EqualityPattern(
        3 * (pin_rows + (m - 1) * (continuity + 1)), fi, cf, *(np.concatenate(v) for v in (entry, row, col, rank)),
        np.repeat(per_point, 3), free, free.sum(axis=1).tolist(), q + 1)
    for v in out:
        if isinstance(v, np.ndarray):
            v.flags.writeable = False
    return out


def _join_factors(durations: np.ndarray, continuity: int) -> np.ndarray:
    """[1 + 2 (c+1) (M-1)]: 1 (pins), then per order r the end and start row scales of every join, as in
    ``_equalities`` (d^r/dt^r = c_r/d^r Delta^r; c_r cancels; rows scaled by min(d)^r)."""
    out = [np.ones(1)]
    for r in range(continuity + 1):
        scale = np.minimum(durations[:-1], durations[1:]) ** r  # [M-1]
        out += [scale / durations[:-1] ** r, scale / durations[1:] ** r]
    return np.concatenate(out)


def assemble_qp_reference(polys, wp, start, goal, config: TrajectoryConfig, faces=None) -> CorridorQP:
    """The plain construction (COO triplets -> scipy CSC): the reference ``assemble_qp`` is tested against."""
    m = len(polys)
    d = config.degree
    npts = d + 1
    n = m * npts * 3
    durations = segment_durations(wp, config)
    P_upper = _objective_upper(2.0 * segment_hessians(d, durations, config), n)
    eq_rows, eq_cols, eq_vals, b_eq = _equalities(m, d, config, durations, start, goal)
    n_eq = b_eq.size
    eq_dense = np.zeros((n_eq, n))
    eq_dense[eq_rows, eq_cols] = eq_vals
    # pinned control points are fixed by the equalities and get no inequality rows
    q = config.rest_at_ends
    pinned = np.zeros((m, npts), dtype=bool)
    pinned[0, : q + 1] = True
    pinned[m - 1, d - q :] = True
    in_polys = polys if faces is None else [(a[f], b[f]) for (a, b), f in zip(polys, faces)]
    in_rows, in_cols, in_vals, b_in, n_rows = _inequalities(in_polys, pinned, config.effective_margin(), n_eq)
    rows, cols = np.concatenate([eq_rows] + in_rows), np.concatenate([eq_cols] + in_cols)
    A = sp.csc_matrix((np.concatenate([eq_vals] + in_vals), (rows, cols)), shape=(n_rows, n))
    return CorridorQP(P_upper, A, np.concatenate([b_eq] + b_in), n_eq, eq_dense, durations, d, m, polys)


def checked_qp_input(polytopes, waypoints, start, goal):
    """(polytopes [(A, b)], waypoints [M+1, 3], start [3], goal [3]) as float64 numpy; InvalidInputError for bad
    shapes or values, CorridorInfeasibleError when start / goal (pinned by equality) lie outside their polytope."""
    polys = as_polytopes(polytopes)
    wp = to_numpy(waypoints)
    start = to_numpy(start).reshape(-1)
    goal = to_numpy(goal).reshape(-1)
    m = len(polys)
    if m == 0:
        raise InvalidInputError("the corridor has no polytopes.")
    if wp.ndim != 2 or wp.shape != (m + 1, 3):
        raise InvalidInputError(f"{m} polytopes need waypoints of shape [{m + 1}, 3], got {tuple(wp.shape)}.")
    if start.shape != (3,) or goal.shape != (3,):
        raise InvalidInputError("start and goal must be 3D points.")
    if not (np.isfinite(wp).all() and np.isfinite(start).all() and np.isfinite(goal).all()):
        raise InvalidInputError("waypoints, start and goal must be finite (found NaN or inf).")
    # pinned points are fixed by equality; check them against their polytope now (unshrunk, tiny tol)
    tol = 1e-9 * max(1.0, float(np.abs(wp).max()))
    if point_violation(*polys[0], start) > tol:
        raise CorridorInfeasibleError(
            f"the start point {np.round(start, 4).tolist()} lies outside the first corridor polytope."
        )
    if point_violation(*polys[-1], goal) > tol:
        raise CorridorInfeasibleError(
            f"the goal point {np.round(goal, 4).tolist()} lies outside the last corridor polytope."
        )
    return polys, wp, start, goal


def _objective_upper(hess: np.ndarray, n: int) -> sp.csc_matrix:
    """Upper triangle [n, n] of the block-diagonal objective 2 * kron(H_k, I3) (hess [M, D+1, D+1] already doubled,
    so that 1/2 x^T P x = sum_k cost_k), straight into CSC (the blocks are diagonal, columns in order): what
    Clarabel reads."""
    m, npts = hess.shape[0], hess.shape[1]
    _, u_i, u_j, _ = _upper_block_pattern(npts)
    indices, indptr = _objective_pattern(m, npts)
    return sp.csc_matrix((hess[:, u_i, u_j].ravel(), indices.copy(), indptr.copy()), shape=(n, n))


@functools.lru_cache(maxsize=256)
def _objective_pattern(m: int, npts: int) -> Tuple[np.ndarray, np.ndarray]:
    """(indices, indptr) int32 of ``_objective_upper``'s CSC for M segments (cached, read-only: callers copy)."""
    u_rows, _, _, u_ptr = _upper_block_pattern(npts)
    seg = np.arange(m)[:, None]
    indices = (seg * npts * 3 + u_rows[None]).ravel().astype(np.int32)
    indptr = np.concatenate([(seg * u_rows.size + u_ptr[None, :-1]).ravel(), [m * u_rows.size]]).astype(np.int32)
    indices.flags.writeable = False
    indptr.flags.writeable = False
    return indices, indptr


def _equalities(m: int, d: int, config: TrajectoryConfig, durations: np.ndarray, start: np.ndarray,
                goal: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(rows, cols, values, rhs [3 n_eq]) of the equalities: the pinned end points (rest_at_ends + 1 each), then the
    C^continuity joins, first on points (one row per point-equation), then expanded over x/y/z."""
    npts = d + 1
    q = config.rest_at_ends
    pin_rows = 2 * (q + 1)
    pt_rows = [np.arange(pin_rows)]
    pt_cols = [np.concatenate([np.arange(q + 1), (m - 1) * npts + d - np.arange(q + 1)])]
    pt_vals = [np.ones(pin_rows)]
    rhs_pts = np.concatenate([np.tile(start, (q + 1, 1)), np.tile(goal, (q + 1, 1))])  # [2(q+1), 3]
    n_join = (m - 1) * (config.continuity + 1)
    if m > 1:
        joins = np.arange(m - 1)
        for r in range(config.continuity + 1):
            diff = _difference(d, r)
            end_coef, start_coef = diff[-1], diff[0]  # Delta^r P at u=1 (last) and u=0 (first)
            # d^r/dt^r = c_r/d^r Delta^r; c_r cancels; rows scaled by min(d)^r for conditioning
            scale = np.minimum(durations[:-1], durations[1:]) ** r  # [M-1]
            a_end = np.outer(scale / durations[:-1] ** r, end_coef)  # [M-1, D+1]
            a_start = -np.outer(scale / durations[1:] ** r, start_coef)  # [M-1, D+1]
            row_ids = pin_rows + joins * (config.continuity + 1) + r  # [M-1]
            pt_rows += [np.repeat(row_ids, npts)] * 2
            pt_cols += [(joins[:, None] * npts + np.arange(npts)).ravel(),
                        ((joins[:, None] + 1) * npts + np.arange(npts)).ravel()]
            pt_vals += [a_end.ravel(), a_start.ravel()]
    pr, pc, pv = np.concatenate(pt_rows), np.concatenate(pt_cols), np.concatenate(pt_vals)
    keep = pv != 0.0
    pr, pc, pv = pr[keep], pc[keep], pv[keep]
    eq_rows = (pr[:, None] * 3 + np.arange(3)).ravel()
    eq_cols = (pc[:, None] * 3 + np.arange(3)).ravel()
    return eq_rows, eq_cols, np.repeat(pv, 3), np.concatenate([rhs_pts.ravel(), np.zeros(3 * n_join)])


def _inequalities(polys, pinned: np.ndarray, margin: float, row0: int):
    """Inequality blocks, vectorised per segment, one block of F_k rows per free control point (pinned [M, D+1]),
    rows from row0 on (they follow the equality rows in the stacked A) -> (rows, cols, values, rhs: lists of
    arrays; the row count of the stacked A). Faces are shrunk by ``margin``."""
    npts = pinned.shape[1]
    blocks_r, blocks_c, blocks_v, b_in = [], [], [], []
    for k, (a, b) in enumerate(polys):
        free = np.flatnonzero(~pinned[k])  # [nf]
        if free.size == 0 or a.shape[0] == 0:
            continue
        f = a.shape[0]
        b_shrunk = b - margin * np.linalg.norm(a, axis=1)  # [F]
        nf = free.size
        # row index for (point p, face j) = row0 + p*F + j ; columns var(k, free[p], c)
        rr = row0 + (np.arange(nf)[:, None, None] * f + np.arange(f)[None, :, None])  # [nf, F, 1]
        cc = ((k * npts + free)[:, None, None] * 3 + np.arange(3)[None, None, :])  # [nf, 1, 3]
        rr, cc = np.broadcast_arrays(rr, cc)
        blocks_r.append(rr.ravel())
        blocks_c.append(cc.ravel())
        blocks_v.append(np.broadcast_to(a[None], (nf, f, 3)).ravel())
        b_in.append(np.tile(b_shrunk, nf))
        row0 += nf * f
    # (no inequality row when every control point is pinned: one segment, 2(q+1) = D+1, the straight line)
    return blocks_r, blocks_c, blocks_v, b_in, row0
