"""Time parametrisation: speed/acceleration caps measured on the sampled frames (finite differences of
positions), arc length against a brute-force polyline, exact ends and frame spacing."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from hypothesis.extra import numpy as hnp

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.trajectory.bezier import BezierTrajectory
from cinenerf_ns.planner.trajectory.timing import TimingConfig, arc_length_table, invert_arc_length, time_parametrize


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
