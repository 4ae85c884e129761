"""The corridor QP by elimination + dual active set (trajectory/dual_qp.py, native/dual_qp.c): the parametrisation spans
exactly the equality set, the reduced cost is the full cost, the optimum is Clarabel's and cvxpy's (test_qp.py), the
compiled path is the numpy reference's, and infeasible / unfinished / uncovered cases are handed to Clarabel."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import example, given, settings, strategies as st
from scipy.linalg import solve_triangular
from test_qp import check_solution, cvxpy_reference, random_corridor  # this folder is on sys.path

from cinenerf_ns.planner import native
from cinenerf_ns.planner.trajectory import dual_qp
from cinenerf_ns.planner.trajectory.qp import (
    CorridorInfeasibleError,
    TrajectoryConfig,
    build_corridor_qp,
    solve_corridor_qp,
)
from cinenerf_ns.planner.trajectory.qp_matrices import segment_durations, segment_factors, segment_hessians

needs_native = pytest.mark.skipif(native.corridor_dual_c() is None,
                                  reason=f"dual_qp.c did not load: {native.native_status().get('dual_qp')}")

SHAPES = [(5, 2, 3, 1), (6, 2, 3, 1), (5, 1, 2, 0), (7, 3, 3, 2), (3, 1, 2, 0), (4, 2, 3, 0), (2, 0, 1, 0),
          (3, 2, 3, 0)]  # (degree, continuity, smoothness order, rest_at_ends); the last two chain joined points


def _inputs(polys, wp, cfg):
    dur = segment_durations(wp, cfg)
    fac = segment_factors(cfg.degree, dur, cfg)
    shrunk = [(a, b - cfg.margin * np.linalg.norm(a, axis=1)) for a, b in polys]
    return dur, fac, shrunk


def stable_cost(x, fac):
    """sum_k P_k^T H_k P_k as sum_k |F_k P_k|^2 (qp.segment_factors): x^T H x cancels catastrophically when a 0.05 s
    segment's 1/d^5 weight meets a nearly polynomial curve; the squares of F x do not."""
    return float((np.einsum("kij,kjc->kic", fac, x) ** 2).sum())


def _config(shape):
    degree, continuity, smooth, rest = shape
    return TrajectoryConfig(degree=degree, continuity=continuity, smoothness_order=smooth, rest_at_ends=rest)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), m=st.integers(1, 6), shape=st.sampled_from(SHAPES))
def test_parametrisation_spans_exactly_the_equalities(seed, m, shape):
    """X = T Z + t meets qp.py's equalities (pins, C^c joins) for any Z, and T has the rank of their null space: every
    point of the equality set is some X (nothing is lost by the elimination)."""
    cfg = _config(shape)
    polys, wp = random_corridor(seed % 100_000, m=m)
    rng = np.random.default_rng(seed)
    wp = wp * rng.uniform(0.2, 3.0, size=(m + 1, 1))  # unequal durations
    dur, fac, _ = _inputs(polys, wp, cfg)
    red = dual_qp.reduce(dur, fac, cfg.degree, cfg.continuity, cfg.rest_at_ends, wp[0], wp[-1])
    if red is None:  # the goal's pins on joined points: the only configurations not covered
        assert m > 1 and cfg.degree - cfg.rest_at_ends <= cfg.continuity
        return
    big = (np.vstack([np.eye(3), -np.eye(3)]), np.full(6, 1e3))  # the equalities do not depend on the faces
    qp = build_corridor_qp([big] * m, wp, wp[0], wp[-1], cfg)
    z = rng.normal(size=(red.T.shape[1], 3))
    x = (red.T @ z + red.t).reshape(-1)
    scale = max(1.0, float(np.abs(x).max()))
    np.testing.assert_allclose(qp.eq_dense @ x, qp.b_eq, atol=1e-9 * scale * max(1.0, np.abs(qp.eq_dense).max()))
    n_points = m * (cfg.degree + 1)
    eq_rank = np.linalg.matrix_rank(qp.eq_dense) // 3  # per coordinate
    assert np.linalg.matrix_rank(red.T) == red.T.shape[1] == n_points - eq_rank


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), m=st.integers(1, 5), shape=st.sampled_from(SHAPES[:6]))
def test_reduced_cost_is_the_full_cost(seed, m, shape):
    """|Y - Y0|^2 differs from the full objective sum_k P_k^T H_k P_k by a constant: differences between two points
    agree (and Y0 is the unconstrained minimiser: no point of the equality set costs less)."""
    cfg = _config(shape)
    polys, wp = random_corridor(seed % 100_000, m=m)
    dur, fac, _ = _inputs(polys, wp, cfg)
    red = dual_qp.reduce(dur, fac, cfg.degree, cfg.continuity, cfg.rest_at_ends, wp[0], wp[-1])
    if red is None or red.L.shape[0] == 0:
        return
    rng = np.random.default_rng(seed)
    npts = cfg.degree + 1

    def full(y):
        return stable_cost(dual_qp.control_points(red, y).reshape(m, npts, 3), fac)

    y1, y2 = (red.y0 + rng.normal(size=red.y0.shape) for _ in range(2))
    reduced = lambda y: float(((y - red.y0) ** 2).sum())  # noqa: E731
    assert full(y1) - full(y2) == pytest.approx(reduced(y1) - reduced(y2), rel=1e-8, abs=1e-8 * full(y1))
    assert full(red.y0) <= min(full(y1), full(y2))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 100_000), m=st.integers(1, 5), shape=st.sampled_from(SHAPES[:6]),
       pad=st.sampled_from([0.03, 0.1, 0.3]))
def test_reference_is_the_exact_optimum(seed, m, shape, pad):
    """The numpy reference against cvxpy's independent formulation (test_qp.cvxpy_reference, Clarabel at its 1e-8
    gap): it is feasible for the same shrunk faces and never costs more than cvxpy's optimum beyond that gap, and
    lands on the same control points."""
    cfg = _config(shape)
    polys, wp = random_corridor(seed, m=m, faces=14, pad=pad)
    dur, fac, shrunk = _inputs(polys, wp, cfg)
    res = dual_qp.solve_corridor_dual(dur, fac, shrunk, cfg.degree, cfg.continuity, cfg.rest_at_ends, wp[0], wp[-1],
                                      1e-12, backend="python")
    ref_x, ref_obj = cvxpy_reference(polys, wp, wp[0], wp[-1], cfg)
    assert res.outcome == "ok"
    x = res.points
    for k, (a, b) in enumerate(shrunk):
        lo = cfg.rest_at_ends + 1 if k == 0 else 0
        hi = cfg.degree - cfg.rest_at_ends if k == m - 1 else cfg.degree + 1
        assert np.all(x[k, lo:hi] @ a.T - b <= 1e-12 * np.linalg.norm(a, axis=1))
    assert stable_cost(x, fac) <= ref_obj * (1 + 1e-6) + 1e-9
    np.testing.assert_allclose(x, ref_x, atol=2e-4 * max(1.0, np.abs(ref_x).max()))


def _kkt_residual(red, shrunk, degree, x, tol):
    """Stationarity of the reduced problem at x with nonnegative multipliers on the faces it touches (NNLS): the
    gradient Y - Y0 is a nonnegative combination of the active faces' rows."""
    from scipy.optimize import nnls

    pts, a, b, inv = dual_qp.constraint_rows(red, shrunk, degree)
    Z = np.linalg.lstsq(red.T, x - red.t, rcond=None)[0]
    y = red.L.T @ Z
    active = (np.einsum("ki,ki->k", a, x[pts]) - b) * inv >= -1e-7
    W = solve_triangular(red.L, red.T.T, lower=True)
    rows = (W[:, pts[active]].T[:, :, None] * a[active][:, None, :]).reshape(int(active.sum()), -1)
    grad = (red.y0 - y).reshape(-1)  # -(Y - Y0): must be -sum u_i n_i, i.e. sum u_i n_i = Y0 - Y
    if rows.shape[0] == 0:
        return float(np.abs(grad).max())
    _, resid = nnls(rows.T, grad)
    return resid / max(1.0, float(np.abs(grad).max()))


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 100_000), m=st.integers(2, 5), pad=st.sampled_from([0.03, 0.1]))
def test_optimum_meets_the_kkt_conditions(seed, m, pad):
    """Not only close to Clarabel: the returned point is primal feasible and stationary with multipliers >= 0."""
    cfg = TrajectoryConfig()
    polys, wp = random_corridor(seed, m=m, faces=14, pad=pad)
    dur, fac, shrunk = _inputs(polys, wp, cfg)
    red = dual_qp.reduce(dur, fac, cfg.degree, cfg.continuity, cfg.rest_at_ends, wp[0], wp[-1])
    res = dual_qp.solve_reduced_reference(red, shrunk, cfg.degree, 1e-12)
    assert res.outcome == "ok"
    assert _kkt_residual(red, shrunk, cfg.degree, res.points, 1e-12) < 1e-7


@needs_native
@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 100_000), m=st.integers(1, 7), shape=st.sampled_from(SHAPES),
       pad=st.sampled_from([0.02, 0.05, 0.3]), faces=st.integers(6, 30), stretch=st.booleans())
@example(seed=75, m=5, shape=(3, 2, 3, 0), pad=0.05, faces=6, stretch=True)  # the reference refuses, C solves
@example(seed=7, m=7, shape=(3, 2, 3, 0), pad=0.02, faces=7, stretch=False)  # was infeasible / unfinished: see below
def test_native_matches_the_reference(seed, m, shape, pad, faces, stretch):
    """dual_qp.c against the numpy reference: the same outcome, and the same optimum to rounding (the optimum is
    unique; near-ties may order the steps differently). Two differences are allowed:
    - on a stretched corridor a step whose face is met to rounding (t2 ~ 0) may read as "unfinished" in one and not
      the other (their sums round differently); the request then goes to Clarabel, and the path that answered "ok"
      must give a true optimum (KKT conditions);
    - "infeasible" against "unfinished" (a near-infeasible corridor, where rounding decides which refusal comes
      first): neither is an answer, qp.solve_corridor_qp hands both to Clarabel, whose verdict the user gets
      (test_a_near_infeasible_corridor_is_refused_and_clarabel_decides)."""
    cfg = _config(shape)
    polys, wp = random_corridor(seed, m=m, faces=faces, pad=pad)
    if stretch:  # very unequal durations (a tiny segment: the 1/d^5 terms)
        wp = wp * np.random.default_rng(seed).choice([0.01, 1.0, 5.0], size=(m + 1, 1))
        polys, _ = random_corridor(seed, m=m, faces=faces, pad=pad)
        polys = [(a, b + np.abs(a) @ (np.abs(wp[k: k + 2]).max(0) + 1.0)) for k, (a, b) in enumerate(polys)]
    dur, fac, shrunk = _inputs(polys, wp, cfg)
    args = (dur, fac, shrunk, cfg.degree, cfg.continuity, cfg.rest_at_ends, wp[0], wp[-1], 1e-10)
    py = dual_qp.solve_corridor_dual(*args, backend="python")
    nat = dual_qp.solve_corridor_dual(*args, backend="native")
    if py is None:
        assert nat is None
        return
    if {nat.outcome, py.outcome} == {"infeasible", "unfinished"}:
        return
    if nat.outcome != py.outcome:
        assert stretch and {nat.outcome, py.outcome} == {"ok", "unfinished"}, (nat.outcome, py.outcome)
        ok = nat if nat.outcome == "ok" else py
        red = dual_qp.reduce(dur, fac, cfg.degree, cfg.continuity, cfg.rest_at_ends, wp[0], wp[-1])
        x = ok.points.reshape(-1, 3)
        pts, a, b, inv = dual_qp.constraint_rows(red, shrunk, cfg.degree)
        assert ((np.einsum("ki,ki->k", a, x[pts]) - b) * inv).max() <= 1e-9  # feasible
        assert _kkt_residual(red, shrunk, cfg.degree, x, 1e-10) < 1e-7  # and optimal
        return
    if py.outcome == "ok":
        assert stable_cost(nat.points, fac) == pytest.approx(stable_cost(py.points, fac), rel=1e-8)
        if not stretch:
            # (stretched: a 0.05 s segment beside 30 s ones gives the cost factor a condition number up to
            # CONDITION_LIMIT, and optima that agree in cost to 1e-9 may differ by ~1e-6 along its flattest directions)
            scale = max(1.0, float(np.abs(py.points).max()))
            np.testing.assert_allclose(nat.points, py.points, atol=1e-8 * scale, rtol=0)
            assert nat.active == py.active


@needs_native
@pytest.mark.parametrize("backend", ["python", "native"])
def test_disjoint_boxes_are_infeasible(backend):
    wp = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    box = lambda lo, hi: (np.vstack([np.eye(3), -np.eye(3)]), np.concatenate([hi, -np.asarray(lo)]))  # noqa: E731
    polys = [box([-0.1, -0.1, -0.1], [0.9, 0.1, 0.1]), box([1.1, -0.1, -0.1], [2.1, 0.1, 0.1])]
    cfg = TrajectoryConfig()
    dur, fac, shrunk = _inputs(polys, wp, cfg)
    res = dual_qp.solve_corridor_dual(dur, fac, shrunk, 5, 2, 1, wp[0], wp[-1], 1e-10, backend=backend)
    assert res.outcome == "infeasible" and res.points is None


@needs_native
@pytest.mark.parametrize("backend", ["python", "native"])
def test_unfinished_and_singular_cost_are_reported(backend):
    polys, wp = random_corridor(3, m=4, faces=14, pad=0.03)
    cfg = TrajectoryConfig()
    dur, fac, shrunk = _inputs(polys, wp, cfg)
    args = (dur, fac, shrunk, 5, 2, 1, wp[0], wp[-1], 1e-10)
    full = dual_qp.solve_corridor_dual(*args, backend=backend)
    assert full.outcome == "ok" and full.iterations > 1
    assert dual_qp.solve_corridor_dual(*args, backend=backend, max_iter=1).outcome == "unfinished"
    zero = (dur, np.zeros_like(fac)) + args[2:]  # no cost at all: the reduced cost is 0, not positive definite
    assert dual_qp.solve_corridor_dual(*zero, backend=backend).outcome == "ill-conditioned"


def test_uncovered_configuration_and_failures_fall_back_to_clarabel(monkeypatch):
    """The goal's pins on joined points (degree 3, C2, rest 1: two segments) are not covered: Clarabel solves it and
    the info says why; so does an unfinished active-set solve; an infeasible corridor gets Clarabel's diagnosis."""
    polys, wp = random_corridor(1, m=2)
    cfg = TrajectoryConfig(degree=3, continuity=2, smoothness_order=2, rest_at_ends=1)
    tr = solve_corridor_qp(polys, wp, wp[0], wp[-1], cfg)
    assert tr.info["solver"] == "clarabel" and "pinned points fall on points the joins determine" in tr.info["fallback"]
    check_solution(tr, polys, wp[0], wp[-1], cfg)
    polys, wp = random_corridor(3, m=4, faces=14, pad=0.03)
    ok = solve_corridor_qp(polys, wp, wp[0], wp[-1])
    assert ok.info["solver"] == "active_set" and ok.info["fallback"] is None and ok.info["active_faces"] > 0
    real = dual_qp.solve_corridor_dual
    monkeypatch.setattr("cinenerf_ns.planner.trajectory.qp.solve_corridor_dual",
                        lambda *a, **k: real(*a, **k, max_iter=1))
    tr = solve_corridor_qp(polys, wp, wp[0], wp[-1])
    assert tr.info["solver"] == "clarabel" and tr.info["fallback"].startswith("active set: unfinished")
    np.testing.assert_allclose(tr.control_points, ok.control_points, atol=1e-4)
    assert tr.info["objective"] == pytest.approx(ok.info["objective"], rel=1e-6)
    monkeypatch.undo()
    wp = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    box = lambda lo, hi: (np.vstack([np.eye(3), -np.eye(3)]), np.concatenate([hi, -np.asarray(lo)]))  # noqa: E731
    with pytest.raises(CorridorInfeasibleError, match="polytopes 0 and 1 do not overlap"):
        solve_corridor_qp([box([-0.1] * 3, [0.9, 0.1, 0.1]), box([1.1, -0.1, -0.1], [2.1, 0.1, 0.1])], wp, wp[0],
                          wp[-1])


@needs_native
def test_a_near_infeasible_corridor_is_refused_and_clarabel_decides(monkeypatch):
    """The case hypothesis found (seed 7: degree 3, C2, 7 segments, 0.02 padding): no curve fits (Clarabel says
    infeasible). At step 39 a face nearly in the span of the working set (|z|^2 / |row|^2 = 6e-17) took a step of
    4e16; rounding left it outside. The reference then dropped and re-added it 80 times, multipliers growing 1e7-fold
    each round, and called the corridor "infeasible" only when they overflowed to inf; the C port stopped one step
    later ("unfinished": t2 < 0). Both now stop there ("unfinished": the face farthest outside is already in the
    working set), with no overflow, and qp.solve_corridor_qp hands the refusal to Clarabel, whose verdict is raised."""
    import warnings

    from cinenerf_ns.planner.trajectory import qp as qp_module

    cfg = _config((3, 2, 3, 0))
    polys, wp = random_corridor(7, m=7, faces=7, pad=0.02)
    dur, fac, shrunk = _inputs(polys, wp, cfg)
    args = (dur, fac, shrunk, cfg.degree, cfg.continuity, cfg.rest_at_ends, wp[0], wp[-1], 1e-10)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy's overflow warnings of the old loop
        for backend in ("python", "native"):
            res = dual_qp.solve_corridor_dual(*args, backend=backend)
            assert res.outcome == "unfinished" and res.iterations < 50, (backend, res)
    real, seen = dual_qp.solve_corridor_dual, []
    for backend in ("python", "native"):
        def spy(*a, backend=backend, **k):
            res = real(*a, **k, backend=backend)
            seen.append(res.outcome)
            return res

        monkeypatch.setattr(qp_module, "solve_corridor_dual", spy)
        with pytest.raises(CorridorInfeasibleError, match="No smooth trajectory fits inside the safe corridor"):
            solve_corridor_qp(polys, wp, wp[0], wp[-1], cfg)
    assert seen == ["unfinished", "unfinished"]  # the active set refused; the error is Clarabel's verdict
    with pytest.raises(CorridorInfeasibleError):
        solve_corridor_qp(polys, wp, wp[0], wp[-1], replace(cfg, solver="clarabel"))


def test_segment_factors_square_to_the_hessians():
    for degree, r in [(5, 3), (3, 2), (7, 3), (2, 1)]:
        cfg = TrajectoryConfig(degree=degree, continuity=0, smoothness_order=r, length_weight=0.3)
        dur = np.array([0.05, 1.0, 7.5])
        fac = segment_factors(degree, dur, cfg)
        hes = segment_hessians(degree, dur, cfg)
        np.testing.assert_allclose(np.swapaxes(fac, 1, 2) @ fac, hes, rtol=1e-12, atol=1e-12 * np.abs(hes).max())


def test_point_kinds():
    k = dual_qp.point_kinds(3, 5, 2, 1).reshape(3, 6)
    S, G, F, J = dual_qp.START, dual_qp.GOAL, dual_qp.FREE, dual_qp.JOINED
    assert k.tolist() == [[S, S, F, F, F, F], [J, J, J, F, F, F], [J, J, J, F, G, G]]
    assert dual_qp.point_kinds(1, 3, 2, 1).tolist() == [S, S, G, G]  # one segment: no join
    assert dual_qp.point_kinds(2, 3, 2, 1) is None  # the goal's pins on joined points


def test_active_set_tolerance_is_checked_against_the_margin():
    """The face tolerance must stay below the margin that absorbs it; other solvers do not read it."""
    from cinenerf_ns.planner.errors import InvalidInputError

    with pytest.raises(InvalidInputError, match="active_set_tolerance must be below the polytope margin"):
        TrajectoryConfig(margin=1e-12).validate()
    with pytest.raises(InvalidInputError, match="active_set_tolerance must be below the polytope margin"):
        TrajectoryConfig(active_set_tolerance=-1.0).validate()
    TrajectoryConfig(margin=0.0, active_set_tolerance=0.0).validate()
    TrajectoryConfig(solver="clarabel", margin=0.0).validate()


def test_unknown_backend_is_refused():
    from cinenerf_ns.planner.errors import InvalidInputError

    polys, wp = random_corridor(0, m=2)
    dur, fac, shrunk = _inputs(polys, wp, TrajectoryConfig())
    with pytest.raises(InvalidInputError, match="backend must be 'auto', 'native' or 'python'"):
        dual_qp.solve_corridor_dual(dur, fac, shrunk, 5, 2, 1, wp[0], wp[-1], 1e-10, backend="fast")
