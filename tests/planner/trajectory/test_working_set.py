"""Working-set (constraint generation) corridor QP, Clarabel's path: the same optimum as the QP with all faces, every
control point inside every full polytope, re-solves when the first set misses active faces, infeasibility still
detected."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from test_qp import check_solution, random_corridor  # this folder is on sys.path (pytest rootdir-relative import)

from cinenerf_ns.planner.trajectory import working_set
from cinenerf_ns.planner.trajectory.qp import CorridorInfeasibleError, TrajectoryConfig, solve_corridor_qp
from cinenerf_ns.planner.trajectory.working_set import add_violated, face_norms, free_ranges, initial_faces, reach

# Control points of the working-set and all-faces solves may differ by more than rounding: both are Clarabel optima
# to a 1e-8 gap, and along flat directions of the cost (curvature lam) a gap g moves x by up to sqrt(2 g / lam).
# Measured on captured 1M / 200k-Gaussian requests: <= 3e-5 scene units (objectives within 4e-7 relative); the
# cvxpy comparison in test_qp.py allows 2e-4 for the same reason. 1e-4 x scale sits between them.
CP_TOL = 1e-4
OBJ_TOL = 1e-6


def assert_same_optimum(ws, full, polys):
    assert ws.info["objective"] == pytest.approx(full.info["objective"], rel=OBJ_TOL, abs=1e-9)
    scale = max(1.0, np.abs(full.control_points).max())
    np.testing.assert_allclose(ws.control_points, full.control_points, atol=CP_TOL * scale)
    # every control point (pinned ones included) inside every full, unshrunk polytope
    for k, (a, b) in enumerate(polys):
        assert np.all(ws.control_points[k] @ a.T <= b)


def narrow(monkeypatch, initial=0.0, near=0.0, rounds=None):
    """Start from the nearest face only (and add only violated faces), so active faces are missed."""
    monkeypatch.setattr(working_set, "INITIAL_DISTANCE", initial)
    monkeypatch.setattr(working_set, "NEAR_DISTANCE", near)
    if rounds is not None:
        monkeypatch.setattr(working_set, "MAX_ROUNDS", rounds)


@settings(max_examples=30, deadline=None)
@given(
    st.integers(0, 100_000),
    st.integers(1, 5),
    st.sampled_from([(5, 2, 3, 1), (6, 2, 3, 1), (5, 1, 2, 0), (7, 3, 3, 2)]),
    st.sampled_from([(0.0, 0.0), (0.1, 0.0), (0.4, 0.1)]),
    st.sampled_from([0.05, 0.3]),
)
def test_working_set_equals_all_faces(seed, m, shape, distances, pad):
    """Random corridors (a tight pad makes faces bind); with the first set cut down to the nearest face the loop must
    re-solve, and it still lands on the all-faces optimum."""
    degree, continuity, smooth, rest = shape
    cfg = TrajectoryConfig(solver="clarabel", degree=degree, continuity=continuity, smoothness_order=smooth,
                           rest_at_ends=rest)
    polys, wp = random_corridor(seed, m=m, faces=16, pad=pad)
    full = solve_corridor_qp(polys, wp, wp[0], wp[-1], replace(cfg, working_set=False))
    with pytest.MonkeyPatch.context() as mp:
        narrow(mp, *distances)
        ws = solve_corridor_qp(polys, wp, wp[0], wp[-1], cfg)
    check_solution(ws, polys, wp[0], wp[-1], cfg)
    assert_same_optimum(ws, full, polys)
    assert full.info["qp_rounds"] == 1 and full.info["num_inequalities"] == full.info["num_inequalities_full"]
    assert ws.info["num_inequalities"] <= ws.info["num_inequalities_full"] == full.info["num_inequalities"]


@pytest.mark.parametrize("seed", range(6))
def test_missed_faces_force_a_re_solve(seed, monkeypatch):
    """Thin L-shaped boxes plus far tilted faces: the nearest-face start cannot hold the curve, so the first relaxation
    leaves the corridor, the check finds it and a later round (with the violated faces) returns the full optimum."""
    polys, wp = random_corridor(seed, m=4, faces=14, pad=0.05)
    cfg = TrajectoryConfig(solver="clarabel")
    full = solve_corridor_qp(polys, wp, wp[0], wp[-1], replace(cfg, working_set=False))
    narrow(monkeypatch)
    ws = solve_corridor_qp(polys, wp, wp[0], wp[-1], cfg)
    assert ws.info["qp_rounds"] > 1
    assert ws.info["num_inequalities"] < ws.info["num_inequalities_full"]
    assert_same_optimum(ws, full, polys)
    check_solution(ws, polys, wp[0], wp[-1], cfg)


def test_first_relaxation_alone_would_leave_the_corridor(monkeypatch):
    """Guards the check itself: with one round and no fallback the nearest-face relaxation is infeasible for the full
    QP (so a loop that stopped there could not pass the tests above)."""
    polys, wp = random_corridor(1, m=4, faces=14, pad=0.05)
    cfg = TrajectoryConfig(solver="clarabel")
    pp = [(np.asarray(a), np.asarray(b)) for a, b in polys]
    npts = cfg.degree + 1
    from cinenerf_ns.planner.trajectory.qp_matrices import assemble_qp
    from cinenerf_ns.planner.trajectory.qp_solvers import solve_with_retry

    faces = initial_faces(pp, wp, np.zeros(len(pp)))
    x = solve_with_retry(assemble_qp(pp, wp, wp[0], wp[-1], cfg, faces), cfg)[0]
    free = free_ranges(len(pp), npts, cfg.rest_at_ends)
    grown, violated = add_violated(x.reshape(len(pp), npts, 3), pp, faces, cfg.margin, free, np.zeros(len(pp)))
    assert violated > 0 and sum(g.size for g in grown) > sum(f.size for f in faces)
    # the face norms solve_corridor_qp takes once and hands to every round: the same sets as computing them here
    norms = face_norms(pp)
    assert all(np.array_equal(f, g) for f, g in zip(faces, initial_faces(pp, wp, np.zeros(len(pp)), norms)))
    again, n = add_violated(x.reshape(len(pp), npts, 3), pp, faces, cfg.margin, free, np.zeros(len(pp)), norms)
    assert n == violated and all(np.array_equal(f, g) for f, g in zip(grown, again))


def test_max_rounds_falls_back_to_all_faces(monkeypatch):
    polys, wp = random_corridor(2, m=4, faces=14, pad=0.05)
    full = solve_corridor_qp(polys, wp, wp[0], wp[-1], TrajectoryConfig(solver="clarabel", working_set=False))
    narrow(monkeypatch, rounds=1)
    ws = solve_corridor_qp(polys, wp, wp[0], wp[-1], TrajectoryConfig(solver="clarabel"))
    assert ws.info["qp_rounds"] == 2 and ws.info["num_inequalities"] == ws.info["num_inequalities_full"]
    assert_same_optimum(ws, full, polys)


def test_add_violated_adds_only_missing_faces():
    a = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 2.0, 0], [0, -1.0, 0], [0, 0, 1.0]])
    b = np.array([1.0, 1.0, 2.0, 1.0, 1.0])  # box |x|, |y|, z <= 1 (face 2 scaled by 2)
    cps = np.array([[[0.0, 0, 0], [1.5, 0.0, 0.0], [0.0, 0.995, 0.0]]])  # x = 1.5 past face 0; y near face 2
    free = [(0, 3)]
    faces, n = add_violated(cps, [(a, b)], [np.array([3])], 1e-5, free, np.array([0.0]))
    assert n == 1 and faces[0].tolist() == [0, 3]
    faces, n = add_violated(cps, [(a, b)], [np.array([0, 3])], 1e-5, free, np.array([0.01]))
    assert n == 0 and faces[0].tolist() == [0, 2, 3]  # face 2 is 0.005 away (normalised): added as near
    # pinned points are not checked: the violating point outside the free range
    faces, n = add_violated(cps, [(a, b)], [np.array([3])], 1e-5, [(0, 1)], np.array([0.0]))
    assert n == 0 and faces[0].tolist() == [3]


def test_initial_faces_keep_the_nearest_and_those_within_reach():
    wp = np.array([[0.0, 0, 0], [1.0, 0, 0], [1.0, 3.0, 0]])
    np.testing.assert_allclose(reach(wp), [3.0, 3.0])
    box = (np.vstack([np.eye(3), -np.eye(3)]), np.array([1.5, 0.2, 0.4, 0.3, 0.2, 0.5]))
    got = initial_faces([box], wp[:2], np.array([0.0]))
    assert got[0].tolist() == [1]  # faces 1 and 4 at 0.2, none at 0: the nearest (first of them) only
    assert initial_faces([box], wp[:2], np.array([0.35]))[0].tolist() == [1, 3, 4]


def test_infeasible_corridor_still_raises_with_the_full_diagnostic(monkeypatch):
    """The nearest-face relaxation of two disjoint boxes is feasible; the loop adds the faces that separate them and
    the infeasible relaxation proves the full QP infeasible; the message names the full polytopes."""
    wp = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    box = lambda lo, hi: (np.vstack([np.eye(3), -np.eye(3)]), np.concatenate([hi, -np.asarray(lo)]))
    polys = [box([-0.1, -0.1, -0.1], [0.9, 0.1, 0.1]), box([1.1, -0.1, -0.1], [2.1, 0.1, 0.1])]
    for kw in ({}, {"initial": 0.0}):
        with monkeypatch.context() as mp:
            if kw:
                narrow(mp)
            for solver in ("clarabel", "osqp"):
                with pytest.raises(CorridorInfeasibleError, match="polytopes 0 and 1 do not overlap"):
                    solve_corridor_qp(polys, wp, wp[0], wp[-1], TrajectoryConfig(solver=solver))


def test_osqp_solves_with_all_faces(monkeypatch):
    """OSQP keeps one solve with every face (its ADMM answer moved by ~1e-3 with the face set; see TrajectoryConfig)."""
    polys, wp = random_corridor(2, m=5, faces=20, pad=0.1)
    narrow(monkeypatch)
    tr = solve_corridor_qp(polys, wp, wp[0], wp[-1], TrajectoryConfig(solver="osqp"))
    assert tr.info["qp_rounds"] == 1 and tr.info["num_inequalities"] == tr.info["num_inequalities_full"]
    check_solution(tr, polys, wp[0], wp[-1], TrajectoryConfig())
