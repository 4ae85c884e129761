"""Time parametrisation: speed/acceleration caps measured on the sampled frames (finite differences of
positions), arc length against a brute-force polyline, exact ends and frame spacing; the compiled arc length and
inversion (native/timing.c) against the numpy reference."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from hypothesis.extra import numpy as hnp

from cinenerf_ns.planner import native
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.trajectory.bezier import BezierTrajectory
from cinenerf_ns.planner.trajectory.timing import (
    TimingConfig,
    arc_length_table,
    curve_positions,
    invert_arc_length,
    time_parametrize,
)


def random_curve(seed: int, m: int = 3) -> BezierTrajectory:
    rng = np.random.default_rng(seed)
    cps = np.cumsum(rng.normal(size=(m, 6, 3)), axis=1)
    cps[1:, 0] = cps[:-1, -1]  # C0 joins
    return BezierTrajectory(cps, rng.uniform(0.5, 2.0, size=m))


def brute_length(traj: BezierTrajectory, n: int = 200_001) -> float:
    # include the join times: the random curves are only C0, and a chord across a corner cuts it
    t = np.union1d(np.linspace(0, traj.total_duration, n), np.cumsum(traj.durations)[:-1])
    pos = traj.evaluate(t)
    return float(np.linalg.norm(np.diff(pos, axis=0), axis=1).sum())


@pytest.mark.parametrize("seed", range(3))
def test_arc_length_table_matches_polyline(seed):
    traj = random_curve(seed)
    tau, s = arc_length_table(traj)
    assert np.all(np.diff(s) >= 0) and s[0] == 0 and tau[-1] == traj.total_duration
    assert s[-1] == pytest.approx(brute_length(traj), rel=1e-8)


def resting_curve(seed: int, m: int = 3) -> BezierTrajectory:
    """A curve that starts and ends at rest (first/last two control points equal), like every planned shot."""
    traj = random_curve(seed, m)
    cps = traj.control_points.copy()
    cps[0, 1], cps[-1, -2] = cps[0, 0], cps[-1, -1]
    return BezierTrajectory(cps, traj.durations)


def exact_arc_length(traj: BezierTrajectory, tau: np.ndarray) -> np.ndarray:
    """Arc length at curve times tau [T] from a 16x finer table plus a Gauss-Legendre piece (reference)."""
    t_tab, s_tab = arc_length_table(traj, 1024)
    nodes, weights = np.polynomial.legendre.leggauss(10)
    i = np.clip(np.searchsorted(t_tab, tau, side="right") - 1, 0, len(t_tab) - 2)
    half = 0.5 * (tau - t_tab[i])
    q = (t_tab[i] + half)[:, None] + half[:, None] * nodes[None, :]
    speed = np.linalg.norm(traj.derivative(q.ravel(), 1), axis=1).reshape(q.shape)
    return s_tab[i] + half * (speed @ weights)


@pytest.mark.parametrize("seed", range(4))
def test_frames_sit_at_their_arc_length_also_where_the_curve_rests(seed):
    """Every frame's curve time has the arc length the speed profile asks for, to ~1e-12, including the frames next
    to the ends where the curve is at rest (s(tau) quadratic there: Newton from a linear guess converged slowly and
    its 4-step cap left frame 1 ~1e-4 s of curve time off before the Hermite start)."""
    traj = resting_curve(seed)
    path = time_parametrize(traj, TimingConfig(max_speed=0.7, max_acceleration=0.4, fps=30))
    err = np.abs(exact_arc_length(traj, path.curve_times) - path.arc_length)
    assert err.max() <= 1e-10 * max(1.0, path.length)
    # the same inversion with and without the table's speeds (linear start, more Newton steps) agree where the
    # curve moves; the Hermite start is what makes the rest frames exact
    t_tab, s_tab, v_tab = arc_length_table(traj, with_speed=True)
    s = path.arc_length[2:-2]
    np.testing.assert_allclose(invert_arc_length(traj, t_tab, s_tab, s, v_tab),
                               invert_arc_length(traj, t_tab, s_tab, s),
                               atol=1e-6)


def test_arc_length_table_speeds_are_the_curve_speed():
    traj = random_curve(7)
    tau, s, v = arc_length_table(traj, with_speed=True)
    np.testing.assert_allclose(v, np.linalg.norm(traj.derivative(tau, 1), axis=1), rtol=0, atol=1e-12)
    t2, s2 = arc_length_table(traj)
    np.testing.assert_array_equal(t2, tau)
    np.testing.assert_allclose(s2, s, rtol=0, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(
    st.integers(0, 10_000),
    st.floats(0.2, 3.0),
    st.one_of(st.none(), st.floats(0.2, 5.0)),
    st.booleans(),
    st.sampled_from([24.0, 30.0, 60.0]),
)
def test_caps_hold_on_frames(seed, vmax, amax, ease, fps):
    traj = random_curve(seed)
    cfg = TimingConfig(max_speed=vmax, max_acceleration=amax, ease=ease, fps=fps)
    path = time_parametrize(traj, cfg)
    # exact ends and frame clock
    np.testing.assert_array_equal(path.positions[0], traj.start)
    np.testing.assert_allclose(path.positions[-1], traj.end, atol=1e-12)
    np.testing.assert_allclose(np.diff(path.times), 1.0 / fps, rtol=1e-9)
    assert path.duration == pytest.approx(path.times[-1])
    # chord speed between frames never above the cap (chord <= arc; Newton-refined inversion)
    chord = np.linalg.norm(np.diff(path.positions, axis=0), axis=1) * fps
    assert chord.max() <= vmax * (1 + 1e-7)
    # arc length is consistent with the positions (a sampled curve, not a different one)
    assert path.length == pytest.approx(brute_length(traj), rel=1e-6)
    # the shot is not needlessly slow: duration within one frame of length / vmax plus ramps
    slack = (math.pi / 2 if ease else 1.0) * vmax / amax if amax else 0.0
    assert path.duration <= path.length / vmax + slack + 1.0 / fps + 1e-9
    # tangential acceleration on the frames (second difference of arc length) below the cap
    if amax is not None:
        acc = np.diff(path.arc_length, 2) * fps**2
        assert np.abs(acc).max() <= amax * (1 + 1e-3) + 1e-9
        assert path.speed[0] == pytest.approx(0.0, abs=1e-12) and path.speed[-1] == pytest.approx(0.0, abs=1e-12)


def test_straight_line_profile_values():
    # a straight 4-unit line, Bezier-parametrised unevenly (tau is not arc length)
    cps = np.array([[[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [1.0, 0, 0], [3.0, 0, 0], [4.0, 0, 0]]], float)
    traj = BezierTrajectory(cps, [1.0])
    path = time_parametrize(traj, TimingConfig(max_speed=1.0, max_acceleration=None, fps=10))
    assert path.duration == pytest.approx(4.0)
    np.testing.assert_allclose(path.positions[:, 0], np.linspace(0, 4, 41), atol=1e-6)  # constant speed
    # with linear ramps at 1 unit/s^2: 1 s ramp (0.5 units) each side, 3 s cruise -> 5 s
    path = time_parametrize(traj, TimingConfig(max_speed=1.0, max_acceleration=1.0, ease=False, fps=10))
    assert path.duration == pytest.approx(5.0)
    np.testing.assert_allclose(path.arc_length[10], 0.5, atol=1e-9)
    # short path: peak speed lowered so both ramps meet (triangular profile, v_peak = sqrt(L a))
    short = BezierTrajectory(np.array([[[0, 0, 0], [0.5, 0, 0], [1.0, 0, 0]]], float), [1.0])
    path = time_parametrize(short, TimingConfig(max_speed=10.0, max_acceleration=1.0, ease=False, fps=100))
    assert path.duration == pytest.approx(2.0, abs=0.011)
    assert path.speed.max() == pytest.approx(1.0, rel=1e-2)


def test_ease_is_smooth():
    traj = random_curve(5)
    path = time_parametrize(traj, TimingConfig(max_speed=1.0, max_acceleration=1.0, ease=True, fps=60))
    acc = np.diff(path.arc_length, 2) * 60**2
    jerk = np.diff(acc) * 60
    # raised cosine: jerk bounded by pi^2 v / (2 T_r^2) = a^2 / v * pi / 2 ... ~1.6 (no step in acceleration)
    assert np.abs(jerk).max() < 3.0
    lin = time_parametrize(traj, TimingConfig(max_speed=1.0, max_acceleration=1.0, ease=False, fps=60))
    lin_jerk = np.diff(np.diff(lin.arc_length, 2) * 60**2) * 60
    assert np.abs(lin_jerk).max() > 20.0  # the linear ramp really has acceleration steps


def test_zero_length_curve():
    traj = BezierTrajectory(np.ones((1, 4, 3)), [1.0])
    path = time_parametrize(traj)
    assert path.length == 0.0 and len(path.times) == 2
    np.testing.assert_array_equal(path.positions, np.ones((2, 3)))


@pytest.mark.parametrize(
    "kwargs", [dict(max_speed=0.0), dict(max_speed=float("nan")), dict(max_acceleration=-1.0), dict(fps=0.0)]
)
def test_bad_config(kwargs):
    with pytest.raises(InvalidInputError):
        time_parametrize(random_curve(0), TimingConfig(**kwargs))


@settings(max_examples=100, deadline=None)
@given(hnp.arrays(np.float64, st.integers(1, 8), elements=st.floats(1e-3, 50.0)), st.integers(2, 80))
def test_arc_length_grid_matches_per_segment_loop(durations, n):
    """timing.arc_length_table's broadcast grid of curve times equals the former per-segment loop bit for bit."""
    cp = np.random.default_rng(n).normal(size=(len(durations), 4, 3))
    traj = BezierTrajectory(cp, durations)
    taus = [traj.segment_starts[k] + traj.durations[k] * np.linspace(0.0, 1.0, n + 1)[:-1]
            for k in range(traj.num_segments)]
    ref = np.concatenate(taus + [[traj.total_duration]])
    tau, _ = arc_length_table(traj, n)
    assert np.array_equal(ref.view(np.int64), tau.view(np.int64))


# ---------------------------------------------------------------- the compiled arc length (native/timing.c)
needs_native = pytest.mark.skipif(native.arc_length_table_c() is None or native.invert_arc_length_c() is None,
                                  reason=f"no compiled timing kernels: {native.native_status().get('timing')}")
NATIVE_SETTINGS = dict(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
# Tolerances, native against numpy. The C code repeats numpy's arithmetic in numpy's order, and on the CPU box the
# two are equal bit for bit. The order of two sums is numpy's and OpenBLAS's choice, though (the speed's 3 squares:
# einsum's SIMD lanes; the 5 quadrature terms: speed_q @ weights, a dgemv kernel), so another machine may round them
# otherwise. Both are sums of nonnegative terms, which bounds the difference relative to each value, also where the
# curve rests: speeds within a few ulp (rtol 1e-12), the table's s (a cumulative sum of <= 12 * 64 nonnegative
# pieces) within ~K ulp < 1e-12 relative. Newton's tau solves S(tau) = s, so a ~1e-16 relative change of S moves tau
# by ~1e-16 s / |p'|: TAU_TOL = 1e-12 of the duration leaves four orders of magnitude for that.
RTOL, TAU_TOL = 1e-12, 1e-12


@st.composite
def bezier_curves(draw) -> BezierTrajectory:
    """Random piecewise Bezier curves: degree 3-7, 1-12 segments, C0 joins (corners: the speed jumps at a join) or
    free ends (the curve jumps), durations even or very uneven, optionally at rest at both ends and with a segment
    that does not move."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    degree, m = draw(st.integers(3, 7)), draw(st.integers(1, 12))
    cps = np.cumsum(rng.normal(size=(m, degree + 1, 3)) * rng.choice([0.01, 1.0, 30.0]), axis=1)
    if draw(st.booleans()):
        cps[1:, 0] = cps[:-1, -1]  # C0 joins
    durations = {"even": lambda: rng.uniform(0.5, 2.0, m),
                 "uneven": lambda: 10.0 ** rng.uniform(-4, 2, m),
                 "one tiny": lambda: np.where(np.arange(m) == rng.integers(m), 1e-6, rng.uniform(0.5, 2.0, m))}[
        draw(st.sampled_from(["even", "uneven", "one tiny"]))]()
    if draw(st.booleans()):  # at rest at both ends, like every planned shot
        cps[0, 1], cps[-1, -2] = cps[0, 0], cps[-1, -1]
    if draw(st.booleans()):  # a segment of zero length (all its control points at the join)
        k = int(rng.integers(m))
        cps[k] = cps[k, 0]
        if k + 1 < m:
            cps[k + 1, 0] = cps[k, 0]
    return BezierTrajectory(cps, durations)


def _check_table(traj, tau, s, v):
    """The invariants of an arc-length table (test_arc_length_table_speeds_are_the_curve_speed and the monotone
    test above)."""
    assert tau[0] == 0.0 and tau[-1] == traj.total_duration and np.all(np.diff(tau) >= 0)
    assert s[0] == 0.0 and np.all(np.diff(s) >= 0)
    scale = np.abs(traj.control_points).max() / traj.durations.min() * traj.degree
    np.testing.assert_allclose(v, np.linalg.norm(traj.derivative(tau, 1), axis=1), rtol=1e-9, atol=1e-12 * scale)


@needs_native
@settings(**NATIVE_SETTINGS)
@given(traj=bezier_curves(), samples=st.sampled_from([2, 5, 64]))
def test_native_arc_length_table_is_the_numpy_one(traj, samples):
    ref = arc_length_table(traj, samples, with_speed=True, backend="python")
    got = arc_length_table(traj, samples, with_speed=True, backend="native")
    np.testing.assert_array_equal(got[0], ref[0])  # the same grid of curve times, bit for bit
    np.testing.assert_allclose(got[1], ref[1], rtol=RTOL, atol=0)
    np.testing.assert_allclose(got[2], ref[2], rtol=RTOL, atol=0)
    _check_table(traj, *got)
    tau2, s2 = arc_length_table(traj, samples, backend="native")  # without the speeds: the same table
    np.testing.assert_array_equal(tau2, got[0])
    np.testing.assert_array_equal(s2, got[1])


@needs_native
@settings(**NATIVE_SETTINGS)
@given(traj=bezier_curves(), n=st.integers(1, 400), ends=st.booleans())
def test_native_inversion_is_the_numpy_one(traj, n, ends):
    """Arc lengths all along the table, its own entries (ties of searchsorted), beyond both ends (clipped)."""
    tau_tab, s_tab, v_tab = arc_length_table(traj, 16, with_speed=True, backend="python")
    rng = np.random.default_rng(n)
    s = np.sort(rng.uniform(0, s_tab[-1], n))
    if ends:
        s = np.concatenate([[-1.0, 0.0], s, s_tab[rng.integers(len(s_tab), size=5)], [s_tab[-1], s_tab[-1] + 1]])
    ref = invert_arc_length(traj, tau_tab, s_tab, s, v_tab, backend="python")
    got = invert_arc_length(traj, tau_tab, s_tab, s, v_tab, backend="native")
    np.testing.assert_allclose(got, ref, rtol=0, atol=TAU_TOL * max(1.0, traj.total_duration))
    i = np.clip(np.searchsorted(s_tab, s, side="right") - 1, 0, len(s_tab) - 2)
    assert np.all(got >= tau_tab[i]) and np.all(got <= tau_tab[i + 1])  # inside the bracket, as numpy's


@needs_native
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(traj=bezier_curves(), vmax=st.floats(0.5, 20.0), amax=st.one_of(st.none(), st.floats(0.5, 20.0)),
       ease=st.booleans(), fps=st.sampled_from([24.0, 30.0, 60.0]))
def test_native_time_parametrize_is_the_numpy_one(traj, vmax, amax, ease, fps):
    cfg = TimingConfig(max_speed=vmax, max_acceleration=amax, ease=ease, fps=fps, max_frames=10**6)
    ref = time_parametrize(traj, cfg, backend="python")
    got = time_parametrize(traj, cfg, backend="native")
    assert len(got.times) == len(ref.times)
    scale = max(1.0, float(np.abs(traj.control_points).max()))
    np.testing.assert_allclose(got.positions, ref.positions, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(got.curve_times, ref.curve_times, rtol=0,
                               atol=TAU_TOL * max(1.0, traj.total_duration))
    np.testing.assert_allclose(got.arc_length, ref.arc_length, rtol=RTOL, atol=0)
    # the invariants of test_caps_hold_on_frames, on the compiled path
    np.testing.assert_array_equal(got.positions[0], traj.start)
    np.testing.assert_allclose(got.positions[-1], traj.end, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(np.diff(got.times), 1.0 / fps, rtol=1e-9)
    if got.length > 0 and np.array_equal(traj.control_points[1:, 0], traj.control_points[:-1, -1]):  # no jumps
        # the speed cap as well as the reference keeps it: on these extreme curves (control points ~100 apart, near
        # cusps) the 5-point Gauss-Legendre table is not exact for |p'|, and both backends can exceed the cap by
        # ~4e-5 relative (falsifying example of 2026-11-26); test_caps_hold_on_frames holds it on planner-like curves
        chord = np.linalg.norm(np.diff(got.positions, axis=0), axis=1) * fps
        ref_chord = np.linalg.norm(np.diff(ref.positions, axis=0), axis=1) * fps
        assert chord.max() <= max(vmax * (1 + 1e-7), ref_chord.max() * (1 + 1e-9)) + 1e-9 * scale


@needs_native
@settings(**NATIVE_SETTINGS)
@given(traj=bezier_curves(), n=st.integers(0, 300))
def test_native_curve_positions_are_evaluate(traj, n):
    """curve_positions on the compiled path is traj.evaluate: at random curve times, every join (the later segment),
    both ends and beyond them (clamped). Equal bit for bit on the CPU box (the header of native/timing.c); rounding of
    einsum's sum on another build is allowed."""
    rng = np.random.default_rng(n)
    tau = np.concatenate([rng.uniform(0, traj.total_duration, n), traj.segment_starts,
                          [0.0, traj.total_duration, -1.0, traj.total_duration * 1.5]])
    ref = traj.evaluate(tau)
    got = curve_positions(traj, tau, backend="native")
    scale = max(1.0, float(np.abs(traj.control_points).max()))
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-13 * scale)
    np.testing.assert_array_equal(curve_positions(traj, tau, backend="python"), ref)
    assert curve_positions(traj, tau[:0], backend="native").shape == (0, 3)


def test_curve_positions_refuses_an_unknown_backend():
    with pytest.raises(InvalidInputError, match="curve positions backend must be 'auto', 'native' or 'python'"):
        curve_positions(random_curve(0), np.zeros(1), backend="fast")


@needs_native
@pytest.mark.parametrize("seed", range(3))
def test_native_frames_sit_at_their_arc_length(seed):
    """test_frames_sit_at_their_arc_length_also_where_the_curve_rests on the compiled path."""
    traj = resting_curve(seed)
    path = time_parametrize(traj, TimingConfig(max_speed=0.7, max_acceleration=0.4, fps=30), backend="native")
    err = np.abs(exact_arc_length(traj, path.curve_times) - path.arc_length)
    assert err.max() <= 1e-10 * max(1.0, path.length)


def test_auto_uses_the_compiled_timing_when_it_loads(monkeypatch):
    """backend="auto" takes native/timing.c when it loads (and, for the inversion, when the table's speeds are
    given); "python" and the inversion without speeds never do; "native" without speeds is an error."""
    if native.arc_length_table_c() is None or native.invert_arc_length_c() is None:
        pytest.skip(f"no compiled timing kernels: {native.native_status().get('timing')}")
    calls = []
    for name in ("arc_length_table_c", "invert_arc_length_c", "bezier_positions_c"):
        fn = getattr(native, name)()
        monkeypatch.setattr(native, name, lambda fn=fn, name=name: calls.append(name) or fn)
    traj = resting_curve(1)
    time_parametrize(traj)
    assert calls == ["arc_length_table_c", "invert_arc_length_c", "bezier_positions_c"]
    calls.clear()
    time_parametrize(traj, backend="python")
    tau_tab, s_tab, v_tab = arc_length_table(traj, with_speed=True, backend="python")
    invert_arc_length(traj, tau_tab, s_tab, s_tab[1:-1], backend="auto")  # no speeds: numpy's linear start
    assert calls == []
    with pytest.raises(RuntimeError, match="v_tab"):
        invert_arc_length(traj, tau_tab, s_tab, s_tab[1:-1], backend="native")
    with pytest.raises(InvalidInputError, match="backend"):
        arc_length_table(traj, backend="fast")
