"""Bezier evaluation against de Casteljau (an independent reference) and derivatives against
both the hodograph (de Casteljau on differences) and central finite differences."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.trajectory.bezier import BezierTrajectory, bernstein_basis


def de_casteljau(points: np.ndarray, u: float) -> np.ndarray:
    """Reference: repeated linear interpolation, points [D+1, 3] -> [3]."""
    pts = points.copy()
    while len(pts) > 1:
        pts = (1 - u) * pts[:-1] + u * pts[1:]
    return pts[0]


def ref_eval(cps: np.ndarray, durs: np.ndarray, t: float) -> np.ndarray:
    starts = np.concatenate([[0.0], np.cumsum(durs)])
    k = min(int(np.searchsorted(starts, t, side="right")) - 1, len(durs) - 1)
    u = (t - starts[k]) / durs[k]
    return de_casteljau(cps[k], u)


def ref_derivative(cps: np.ndarray, durs: np.ndarray, t: float, order: int) -> np.ndarray:
    """Hodograph by repeated differencing then de Casteljau."""
    starts = np.concatenate([[0.0], np.cumsum(durs)])
    k = min(int(np.searchsorted(starts, t, side="right")) - 1, len(durs) - 1)
    u = (t - starts[k]) / durs[k]
    pts = cps[k].copy()
    for _ in range(order):
        n = len(pts) - 1
        if n == 0:
            return np.zeros(3)
        pts = n * (pts[1:] - pts[:-1]) / durs[k]
    return de_casteljau(pts, u)


curves = st.builds(
    lambda m, d, seed: (
        np.random.default_rng(seed).normal(size=(m, d + 1, 3)),
        np.random.default_rng(seed + 1).uniform(0.2, 3.0, size=m),
    ),
    st.integers(1, 5),
    st.integers(1, 7),
    st.integers(0, 10_000),
)


def test_bernstein_partition_of_unity_and_ends():
    u = np.linspace(0, 1, 11)
    for d in range(0, 8):
        b = bernstein_basis(d, u)
        np.testing.assert_allclose(b.sum(1), 1.0, atol=1e-14)
        assert b[0, 0] == 1.0 and b[-1, -1] == 1.0


@settings(max_examples=100, deadline=None)
@given(curves, st.floats(0.0, 1.0))
def test_evaluate_matches_de_casteljau(curve, frac):
    cps, durs = curve
    traj = BezierTrajectory(cps, durs)
    t = frac * traj.total_duration
    np.testing.assert_allclose(traj.evaluate(np.array([t]))[0], ref_eval(cps, durs, t), atol=1e-10)


@settings(max_examples=100, deadline=None)
@given(curves, st.floats(0.0, 1.0), st.integers(1, 4))
def test_derivative_matches_hodograph(curve, frac, order):
    cps, durs = curve
    traj = BezierTrajectory(cps, durs)
    t = frac * traj.total_duration
    np.testing.assert_allclose(
        traj.derivative(np.array([t]), order)[0], ref_derivative(cps, durs, t, order), atol=1e-8, rtol=1e-8
    )


def test_derivative_matches_finite_differences():
    rng = np.random.default_rng(0)
    traj = BezierTrajectory(rng.normal(size=(3, 6, 3)), np.array([0.7, 1.3, 2.0]))
    # interior times of each segment (away from joins where the curve is only piecewise smooth)
    t = np.array([0.3, 1.2, 2.9])
    h = 1e-5
    for order in (1, 2):
        lo = traj.derivative(t - h, order - 1)
        hi = traj.derivative(t + h, order - 1)
        np.testing.assert_allclose(traj.derivative(t, order), (hi - lo) / (2 * h), rtol=1e-6, atol=1e-6)


def test_end_points_and_segment_of():
    rng = np.random.default_rng(1)
    cps = rng.normal(size=(3, 4, 3))
    traj = BezierTrajectory(cps, [1.0, 2.0, 0.5])
    assert traj.total_duration == pytest.approx(3.5)
    np.testing.assert_array_equal(traj.evaluate([0.0])[0], cps[0, 0])
    np.testing.assert_array_equal(traj.evaluate([3.5])[0], cps[-1, -1])
    seg, u = traj.segment_of([0.0, 0.5, 1.0, 2.0, 3.0, 3.5, 10.0, -1.0])
    assert seg.tolist() == [0, 0, 1, 1, 2, 2, 2, 0]
    np.testing.assert_allclose(u, [0, 0.5, 0, 0.5, 0, 1, 1, 0])
    # start of segment 1 = end point of segment 1's first control point
    np.testing.assert_array_equal(traj.evaluate([1.0])[0], cps[1, 0])


def test_sample_and_torch_roundtrip():
    rng = np.random.default_rng(2)
    traj = BezierTrajectory(rng.normal(size=(2, 6, 3)), [1.0, 1.0])
    times, pos = traj.sample(5)
    assert times.shape == (5,) and pos.shape == (5, 3)
    np.testing.assert_allclose(times, [0, 0.5, 1, 1.5, 2])
    out = traj.evaluate(torch.tensor(times))
    assert isinstance(out, torch.Tensor) and out.dtype == torch.float64
    np.testing.assert_allclose(out.numpy(), pos)
    again = BezierTrajectory.from_dict(traj.to_dict())
    np.testing.assert_array_equal(again.control_points, traj.control_points)


def test_derivative_above_degree_is_zero():
    traj = BezierTrajectory(np.random.default_rng(3).normal(size=(1, 3, 3)), [1.0])
    np.testing.assert_array_equal(traj.derivative([0.3, 0.6], 3), np.zeros((2, 3)))


@pytest.mark.parametrize(
    "cps,durs",
    [
        (np.zeros((2, 1, 3)), [1.0, 1.0]),  # degree 0
        (np.zeros((2, 4, 3)), [1.0]),  # wrong number of durations
        (np.zeros((2, 4, 3)), [1.0, 0.0]),  # zero duration
        (np.full((1, 4, 3), np.nan), [1.0]),
    ],
)
def test_bad_input_raises(cps, durs):
    with pytest.raises(InvalidInputError):
        BezierTrajectory(cps, durs)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), m=st.integers(1, 6), degree=st.integers(1, 7),
       scale=st.sampled_from([1e-3, 1.0, 50.0]))
def test_speed_is_the_norm_of_the_first_derivative(seed, m, degree, scale):
    """BezierTrajectory.speed (Horner on power coefficients) against |derivative(t, 1)| (Bernstein basis), in float64,
    at random times, joins and both ends."""
    rng = np.random.default_rng(seed)
    traj = BezierTrajectory(scale * rng.normal(size=(m, degree + 1, 3)), rng.uniform(0.05, 2.0, m))
    t = np.concatenate([rng.uniform(0, traj.total_duration, 50), traj.segment_starts, [traj.total_duration]])
    want = np.linalg.norm(traj.derivative(t, 1), axis=1)
    bound = 1e-12 * max(1.0, float(np.abs(traj._derivative_points(1)).max()))
    assert np.abs(traj.speed(t) - want).max() <= bound
