"""Projection of a point onto a polytope (cinenerf_ns/planner/search/projection.py) against exact float64 references;
the compiled projections (native/project.c) against the numpy ones."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings, strategies as st

from cinenerf_ns.planner import native
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.search.projection import (
    _project_clarabel,
    project_active_set,
    project_dual_active_set,
    project_onto_polytope,
)


def projection_reference(A: np.ndarray, b: np.ndarray, t: np.ndarray) -> float:
    """Exact (brute force, float64) distance from t to {x : A x <= b}: the projection lies in the relative interior
    of some face, i.e. it is t's projection onto the affine hull of 0 (t itself), 1, 2 or 3 independent planes; the
    answer is the nearest of those points that is feasible. Every subset of k planes at once (stacked numpy)."""
    from itertools import combinations

    best = 0.0 if (A @ t <= b + 1e-12).all() else np.inf
    for k in (1, 2, 3):
        S = np.array(list(combinations(range(len(b)), k)), dtype=np.int64).reshape(-1, k)  # [C, k]
        M = A[S]  # [C, k, 3]
        ok = np.linalg.matrix_rank(M, tol=1e-9) == k if len(S) else np.zeros(0, dtype=bool)
        M, S = M[ok], S[ok]
        if not len(S):
            continue
        Mt = M.transpose(0, 2, 1)
        lam = np.linalg.solve(M @ Mt, (M @ t - b[S])[..., None])  # [C, k, 1]
        x = t - (Mt @ lam)[..., 0]  # [C, 3]
        feas = (x @ A.T <= b + 1e-9).all(1)
        if feas.any():
            best = min(best, float(np.linalg.norm(x[feas] - t, axis=1).min()))
    return best


def _projection_reference_loop(A: np.ndarray, b: np.ndarray, t: np.ndarray) -> float:
    """projection_reference one subset at a time (the form it had); test_projection_reference_is_its_loop."""
    from itertools import combinations

    best = 0.0 if (A @ t <= b + 1e-12).all() else np.inf
    for k in (1, 2, 3):
        for S in combinations(range(len(b)), k):
            M = A[list(S)]
            if np.linalg.matrix_rank(M, tol=1e-9) < k:
                continue
            x = t - M.T @ np.linalg.solve(M @ M.T, M @ t - b[list(S)])
            if (A @ x <= b + 1e-9).all():
                best = min(best, float(np.linalg.norm(x - t)))
    return best


def random_polytope(rng, n_planes: int):
    """A [F, 3], b [F] of a bounded polytope holding the ball of radius 0.05 around c [3]: random unit normals at
    random offsets from c, plus a box; some planes repeated or through one vertex (degenerate cases)."""
    c = rng.normal(size=3)
    n = rng.normal(size=(n_planes, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    off = rng.uniform(0.05, 1.0, n_planes)
    if n_planes >= 4 and rng.random() < 0.3:  # a pyramid apex: 4 planes through the point c + v
        v = 0.5 * rng.normal(size=3)
        n[:4] = v / np.linalg.norm(v) + 0.3 * rng.normal(size=(4, 3))
        n[:4] /= np.linalg.norm(n[:4], axis=1, keepdims=True)
        off[:4] = n[:4] @ v
        keep = off[:4] > 0.05  # c stays strictly inside
        n, off = np.vstack([n[:4][keep], n[4:]]), np.concatenate([off[:4][keep], off[4:]])
    if len(n) and rng.random() < 0.3:  # a repeated plane
        n, off = np.vstack([n, n[:1]]), np.concatenate([off, off[:1]])
    box = np.vstack([np.eye(3), -np.eye(3)])
    A = np.vstack([n, box])
    b = np.concatenate([off + n @ c, np.full(6, 1.5) + box @ c])
    return A, b, c



def test_projection_reference_is_its_loop():
    """The stacked references against their one-subset-at-a-time forms: inside and outside points, apexes, repeated
    planes, planes through one line, cuts that empty the polytope (inf; negative vertex slack)."""
    got = []
    for seed, n_planes, n_line, n_cuts, far in [(0, 6, 2, 2, 2.0), (1, 6, 0, 2, 0.0), (2, 4, 3, 0, 0.05),
                                                 (3, 6, 2, 4, 1.0), (7, 0, 3, 3, 4.0)]:
        A, b, c, t = projection_case(seed, n_planes, n_line, n_cuts, far)
        want, ref = _projection_reference_loop(A, b, t), projection_reference(A, b, t)
        assert ref == want or abs(ref - want) <= 1e-12, (seed, ref, want)
        slack, slack_want = vertex_slack_reference(A, b), _vertex_slack_reference_loop(A, b)
        assert slack == slack_want or abs(slack - slack_want) <= 1e-12, (seed, slack, slack_want)
        got.append((ref, slack))
    assert any(r == 0.0 for r, _ in got) and any(0 < r < np.inf for r, _ in got)
    assert any(s < -1e-3 for _, s in got) and any(s > 1e-3 for _, s in got)  # empty; a vertex inside the rest
    assert _vertex_slack_reference_loop(np.eye(3)[:2], np.ones(2)) == vertex_slack_reference(np.eye(3)[:2], np.ones(2))


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n_planes=st.integers(0, 12), far=st.floats(0.0, 4.0))
@example(seed=1750, n_planes=2, far=2.75)  # a repeated plane blocked by rounding: singular working set
@example(seed=1749, n_planes=2, far=4.0)  # the same: the working set cycled until max_iter
def test_active_set_projection_is_the_exact_projection(seed, n_planes, far):
    rng = np.random.default_rng(seed)
    A, b, c = random_polytope(rng, n_planes)
    t = c + far * rng.normal(size=3)
    ref = projection_reference(A, b, t)
    x = project_active_set(A, b, t, c)
    assert x is not None
    assert (A @ x - b).max() <= 1e-12 * (1 + np.abs(b).max())
    assert np.linalg.norm(x - t) == pytest.approx(ref, abs=1e-9)
    # the projection onto a convex set is unique: Clarabel finds about the same point (its tolerances leave
    # ~1e-5 of position error: 2.7e-5 seen on the H100 host), never a closer one
    xc = _project_clarabel(A, b, t, c)
    assert np.linalg.norm(x - xc) < 1e-3
    assert np.linalg.norm(x - t) <= np.linalg.norm(xc - t) + 1e-9
    # the wrapper returns a point exactly inside, within rounding of the projection
    y = project_onto_polytope(A, b, t, interior=c)
    assert (A @ y <= b).all() and np.linalg.norm(y - x) < 1e-9


def vertex_slack_reference(A: np.ndarray, b: np.ndarray) -> float:
    """Brute force (float64): max over the vertices of the plane arrangement (3 independent planes) of the smallest
    slack b_f - A_f x of the OTHER planes (its own three hold it with slack 0; +inf when there are no others). A bounded
    {x : A x <= b} is non-empty iff one of its vertices is feasible: > 0 means a vertex strictly inside every other
    plane (non-empty, with an interior near that vertex), < 0 empty, ~0 degenerate (up to rounding). Every triple of
    planes at once (stacked numpy)."""
    from itertools import combinations

    S = np.array(list(combinations(range(len(b)), 3)), dtype=np.int64).reshape(-1, 3)  # [C, 3]
    M = A[S]  # [C, 3, 3]
    ok = np.abs(np.linalg.det(M)) >= 1e-9 if len(S) else np.zeros(0, dtype=bool)
    if not ok.any():
        return -np.inf
    x = np.linalg.solve(M[ok], b[S[ok]][..., None])[..., 0]  # [C', 3]
    slack = b - x @ A.T  # [C', F]
    np.put_along_axis(slack, S[ok], np.inf, axis=1)  # a vertex's own planes
    return float(slack.min(1).max())


def _vertex_slack_reference_loop(A: np.ndarray, b: np.ndarray) -> float:
    """vertex_slack_reference one triple at a time; test_projection_reference_is_its_loop."""
    from itertools import combinations

    best = -np.inf
    for S in combinations(range(len(b)), 3):
        M = A[list(S)]
        if abs(np.linalg.det(M)) < 1e-9:
            continue
        x = np.linalg.solve(M, b[list(S)])
        others = [f for f in range(len(b)) if f not in S]
        best = max(best, float((b[others] - A[others] @ x).min()) if others else np.inf)
    return best


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n_planes=st.integers(0, 10), n_cuts=st.integers(0, 6), far=st.floats(0.0, 4.0))
def test_dual_projection_is_the_exact_projection_or_proves_the_polytope_empty(seed, n_planes, n_cuts, far):
    """project_dual_active_set (no feasible start) against the brute-force references: the same distance as the exact
    projection when the polytope is non-empty, None when it is empty (cuts through the centre make ~1/4 empty)."""
    rng = np.random.default_rng(seed)
    A, b, c = random_polytope(rng, n_planes)
    n = rng.normal(size=(n_cuts, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    A, b = np.vstack([A, n]), np.concatenate([b, n @ c + rng.uniform(-0.8, 1.0, n_cuts)])
    t = c + far * rng.normal(size=3)
    x = project_dual_active_set(A, b, t)
    assert not isinstance(x, str)  # finishes on these (degenerate vertices and repeated planes included)
    slack = vertex_slack_reference(A, b)
    if x is None:
        assert slack < 1e-9
        return
    assert slack > -1e-9
    assert (A @ x - b).max() <= 1e-12 * (1 + np.abs(b).max())
    assert np.linalg.norm(x - t) == pytest.approx(projection_reference(A, b, t), abs=1e-9)
    # the wrapper (no interior point given): inside exactly, within its tightening of the projection
    y = project_onto_polytope(A, b, t)
    if slack > 1e-6:
        assert y is not None and (A @ y <= b).all() and np.linalg.norm(y - x) < 1e-6


def test_projection_without_interior_point_agrees_with_the_chebyshev_route():
    """project_onto_polytope without an interior point (dual method) gives the point the Chebyshev centre + primal
    method gave, and None exactly for the polytopes with no interior."""
    from cinenerf_ns.planner.corridor.polytope import chebyshev_center

    for seed in range(200):
        rng = np.random.default_rng(seed)
        A, b, c = random_polytope(rng, int(rng.integers(0, 10)))
        n = rng.normal(size=(4, 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        A, b = np.vstack([A, n]), np.concatenate([b, n @ c + rng.uniform(-0.8, 1.0, 4)])
        t = c + 3.0 * rng.normal(size=3)
        y = project_onto_polytope(A, b, t)
        cc, rad = chebyshev_center(A, b)
        if rad > 1e-6:
            z = project_onto_polytope(A, b, t, interior=cc)
            assert y is not None and (A @ y <= b).all() and np.linalg.norm(y - z) < 1e-6
        elif rad < -1e-6 or rad == -np.inf:
            assert y is None


def test_projection_falls_back_to_clarabel_when_the_active_set_does_not_finish():
    rng = np.random.default_rng(0)
    A, b, c = random_polytope(rng, 10)
    t = c + 3.0 * np.ones(3)
    assert project_active_set(A, b, t, c, max_iter=0) is None
    y = project_onto_polytope(A, b, t, interior=c)
    import cinenerf_ns.planner.search.projection as proj_mod

    real = proj_mod.project_active_set
    try:
        proj_mod.project_active_set = lambda *a, **k: None
        z = project_onto_polytope(A, b, t, interior=c)
    finally:
        proj_mod.project_active_set = real
    assert (A @ z <= b).all() and np.linalg.norm(z - y) < 1e-5


# ------------------------------------------------------------------ compiled projections (native/project.c)
def line_planes(rng, c: np.ndarray, n: int):
    """n planes through one line (normals perpendicular to its direction), c strictly inside each (degenerate: their
    normals span only a plane, so a working set can hold two of them at most)."""
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    q = c + rng.uniform(0.1, 0.8) * np.cross(d, rng.normal(size=3) + 1e-3)  # a point of the line, off c
    N = np.cross(d, rng.normal(size=(n, 3)))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    gap = N @ (q - c)
    N = np.where((gap > 0)[:, None], N, -N)  # c on the inner side of each plane
    keep = np.abs(gap) > 0.05
    return N[keep], (N @ q)[keep]


def projection_case(seed, n_planes, n_line, n_cuts, far, cut_lo=-0.8):
    """(A, b, c, t): random_polytope (box, random planes, apexes, repeated planes) with n_line planes through one line
    and n_cuts random planes at offsets from cut_lo to 1 of c (cut_lo < 0 can empty it); t at ~far from c."""
    rng = np.random.default_rng(seed)
    A, b, c = random_polytope(rng, n_planes)
    N, off = line_planes(rng, c, n_line)
    n = rng.normal(size=(n_cuts, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    A = np.vstack([A, N, n])
    b = np.concatenate([b, off, n @ c + rng.uniform(cut_lo, 1.0, n_cuts)])
    return A, b, c, c + far * rng.normal(size=3)


GENERIC = """With a small max_iter the tests compare how many steps the two backends take, on generic planes only (a box
and random cuts): at a degenerate vertex (an apex, planes through one line, a repeated plane) two faces can tie in a
ratio test to the last bit, numpy's BLAS and the C code round that tie differently, and each may take a different (as
valid) path of another length; both still end at the same projection."""


def projection_outcome(fn, *args, **kw):
    """fn's result, or the class of the error it raised (LinAlgError: a singular working set)."""
    try:
        return fn(*args, **kw)
    except (np.linalg.LinAlgError, ZeroDivisionError) as e:
        return type(e)


def assert_same_projection(xn, xp, A, b, t):
    """Both backends ended the same way (a point, None, "unfinished" or the same error); points within rounding."""
    if isinstance(xp, np.ndarray):
        assert isinstance(xn, np.ndarray) and xn.shape == (3,)
        assert np.abs(xn - xp).max() <= 1e-9 * (1.0 + np.abs(b).max(initial=0.0) + np.abs(t).max())
    else:
        assert not isinstance(xn, np.ndarray) and type(xn) is type(xp) and xn == xp, (xn, xp)


def assert_is_projection(x, A, b, t):
    """x is feasible and as close to t as the brute-force projection (KKT up to rounding)."""
    assert (A @ x - b).max() <= 1e-12 * (1 + np.abs(b).max())
    assert np.linalg.norm(x - t) == pytest.approx(projection_reference(A, b, t), abs=1e-9)


needs_project_c = pytest.mark.skipif(native.project_dual_c() is None,
                                     reason=f"no compiled projection: {native.native_status().get('project')}")


@needs_project_c
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n_planes=st.integers(0, 12), n_line=st.integers(0, 4),
       n_cuts=st.integers(0, 4), far=st.sampled_from([0.0, 0.05]) | st.floats(0.0, 4.0),
       max_iter=st.sampled_from([None, 0, 1, 2, 3, 5]))
@example(seed=1750, n_planes=2, n_line=0, n_cuts=0, far=2.75, max_iter=None)
@example(seed=1749, n_planes=2, n_line=0, n_cuts=0, far=4.0, max_iter=None)
def test_native_primal_projection_is_the_python_one(seed, n_planes, n_line, n_cuts, far, max_iter):
    """project_active_set: cn_project_primal takes numpy's steps (the same result kind at every max_iter: a point or
    None) and both points are the exact projection (cuts keep the start c strictly inside)."""
    if max_iter is not None:  # step counts compared: generic planes only (see GENERIC)
        n_planes, n_line, n_cuts = 0, 0, n_planes + n_line + n_cuts
    A, b, c, t = projection_case(seed, n_planes, n_line, n_cuts, far, cut_lo=0.05)
    kw = {} if max_iter is None else {"max_iter": max_iter}
    xp = projection_outcome(project_active_set, A, b, t, c, backend="python", **kw)
    xn = projection_outcome(project_active_set, A, b, t, c, backend="native", **kw)
    assert_same_projection(xn, xp, A, b, t)
    if max_iter is None:
        assert isinstance(xp, np.ndarray)
        for x in (xn, xp):
            assert_is_projection(x, A, b, t)


@needs_project_c
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n_planes=st.integers(0, 10), n_line=st.integers(0, 4),
       n_cuts=st.integers(0, 6), far=st.sampled_from([0.0, 0.05]) | st.floats(0.0, 4.0),
       max_iter=st.sampled_from([None, None, 0, 1, 2, 4]))
def test_native_dual_projection_is_the_python_one(seed, n_planes, n_line, n_cuts, far, max_iter):
    """project_dual_active_set: cn_project_dual ends as numpy does (a point, None for an empty polytope, "unfinished"
    at every max_iter) and both points are the exact projection; None only where the polytope is empty (cuts through
    the centre empty ~1/4 of them)."""
    if max_iter is not None:  # step counts compared: generic planes only (see GENERIC)
        n_planes, n_line, n_cuts = 0, 0, n_planes + n_line + n_cuts
    A, b, c, t = projection_case(seed, n_planes, n_line, n_cuts, far)
    xp = projection_outcome(project_dual_active_set, A, b, t, max_iter, backend="python")
    xn = projection_outcome(project_dual_active_set, A, b, t, max_iter, backend="native")
    assert_same_projection(xn, xp, A, b, t)
    if isinstance(xp, np.ndarray):
        for x in (xn, xp):
            assert_is_projection(x, A, b, t)
    elif xp is None:
        assert vertex_slack_reference(A, b) < 1e-9


@needs_project_c
def test_native_projection_edge_cases_are_pythons():
    """No faces, a zero face, an empty polytope with no feasible start, a face whose |a|^2 underflows to 0 (Python's
    ZeroDivisionError), and the LinAlgError of a singular working set (the wrapper's code -1)."""
    from cinenerf_ns.planner.search.projection import _native_projection_result

    t = np.array([0.3, -0.2, 0.1])
    cases = [
        (np.zeros((0, 3)), np.zeros(0), t),  # no face: t itself
        (np.zeros((1, 3)), np.array([-1.0]), t),  # 0 x <= -1: empty
        (np.zeros((1, 3)), np.array([1.0]), t),  # 0 x <= 1: everything
        (np.array([[1.0, 0, 0], [-1.0, 0, 0]]), np.array([-1.0, -1.0]), t),  # x <= -1 and x >= 1: empty
        (np.array([[1.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]]), np.array([0.0, 0.0, -1.0]), t),  # a repeated face
    ]
    for A, b, tt in cases:
        for max_iter in (None, 0, 1):
            assert_same_projection(project_dual_active_set(A, b, tt, max_iter, backend="native"),
                                   project_dual_active_set(A, b, tt, max_iter, backend="python"), A, b, tt)
    A = np.array([[1e-200, 0.0, 0.0], [0.0, 1.0, 0.0]])
    b = np.array([1e-201, 1.0])
    for backend in ("native", "python"):
        with pytest.raises(ZeroDivisionError):
            project_active_set(A, b, np.array([1.0, 0.0, 0.0]), np.zeros(3), backend=backend)
    with pytest.raises(np.linalg.LinAlgError):
        _native_projection_result(-1, np.zeros(3), {})
    with pytest.raises(ValueError, match=r"\[F, 3\]"):
        project_dual_active_set(np.zeros((2, 2)), np.zeros(2), t, backend="native")
    with pytest.raises(InvalidInputError, match="backend"):
        project_dual_active_set(np.zeros((0, 3)), np.zeros(0), t, backend="fast")


def test_projection_uses_the_compiled_code_under_auto(monkeypatch):
    """With a C compiler, "auto" (the default, what project_onto_polytope uses) runs native/project.c: the dual
    method without an interior point, the primal one from it."""
    import os
    import shutil

    import cinenerf_ns.planner.search.projection as proj_mod

    if native.turned_off("project"):
        pytest.skip(f"compiled kernels turned off: {native.turned_off('project')}")
    if not (os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")):
        pytest.skip("no C compiler")
    assert native.project_dual_c() is not None and native.project_primal_c() is not None, native.native_status()
    calls = []

    def counted(loader, name):
        def wrapper(*args):
            calls.append(name)
            return loader()(*args)
        return lambda: wrapper

    monkeypatch.setattr(proj_mod, "project_dual_c", counted(native.project_dual_c, "dual"))
    monkeypatch.setattr(proj_mod, "project_primal_c", counted(native.project_primal_c, "primal"))
    A, b, c = random_polytope(np.random.default_rng(5), 8)
    t = c + np.array([3.0, 0.0, 0.0])
    y = project_onto_polytope(A, b, t)
    z = project_onto_polytope(A, b, t, interior=c)
    assert calls == ["dual", "primal"]
    assert (A @ y <= b).all() and (A @ z <= b).all() and np.linalg.norm(y - z) < 1e-6
