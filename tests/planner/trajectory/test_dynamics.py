"""Retiming under dynamic limits: the exported frames (finite differences at the frame rate) never
exceed max speed / acceleration / view angular rate; frames stay on the curve; specific errors."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.shots.shot import Shot, retime_shot
from cinenerf_ns.planner.trajectory.dynamics import DynamicLimits, frame_peaks, retime, view_vectors
from cinenerf_ns.planner.trajectory.qp import solve_corridor_qp

BOX = (np.vstack([np.eye(3), -np.eye(3)]), np.full(6, 10.0))


def _curve(seed, n_wp=5):
    rng = np.random.default_rng(seed)
    wp = np.cumsum(rng.uniform(-0.6, 0.6, (n_wp, 3)), 0)
    return solve_corridor_qp([BOX] * (n_wp - 1), wp, wp[0], wp[-1])


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 1000), vmax=st.floats(0.1, 3.0), amax=st.floats(0.1, 3.0), wmax=st.floats(5.0, 180.0),
       fps=st.sampled_from([24.0, 30.0, 60.0]))
def test_exported_frames_respect_limits(seed, vmax, amax, wmax, fps):
    tr = _curve(seed)
    look = np.array([0.3, -0.2, 0.1])
    lim = DynamicLimits(max_speed=vmax, max_acceleration=amax, max_angular_rate_deg=wmax, fps=fps)
    rf = retime(tr, look, lim)
    # independent re-measurement of the exported frames (no tolerance: retime checks the same quantities)
    pk = frame_peaks(rf.positions, rf.times, view_vectors(rf.positions, look))
    assert pk.speed <= vmax and pk.acceleration <= amax and pk.angular_rate_deg <= wmax
    assert np.allclose(np.diff(rf.times), 1 / fps)
    assert np.allclose(rf.positions, tr.evaluate(rf.curve_times), atol=1e-12)  # exact curve points
    assert np.allclose(rf.positions[0], tr.start) and np.allclose(rf.positions[-1], tr.end)
    # the camera looks at the target on every frame
    view = -rf.rotations[:, :, 2]
    assert np.allclose(view, view_vectors(rf.positions, look), atol=1e-9)


def test_tighter_limits_take_longer_and_peaks_are_reported():
    tr = _curve(3)
    look = np.zeros(3)
    fast = retime(tr, look, DynamicLimits(max_speed=2.0, max_acceleration=2.0, max_angular_rate_deg=180))
    slow = retime(tr, look, DynamicLimits(max_speed=0.2, max_acceleration=0.2, max_angular_rate_deg=10))
    assert slow.times[-1] > fast.times[-1]
    assert 0 < slow.peaks.speed <= 0.2


def test_retime_shot_and_moving_look_at():
    tr = _curve(7)
    sh = Shot.from_trajectory(tr, np.zeros(3))
    out = retime_shot(sh, DynamicLimits(max_speed=0.3, max_acceleration=0.3, max_angular_rate_deg=30))
    assert out.dynamics["peak_speed"] <= 0.3 and out.dynamics["peak_angular_rate_deg"] <= 30
    assert np.max(out.look_at_errors_deg()) < 1e-6
    a, b = np.array([1.0, 1, 0]), np.array([-1.0, 1, 0])
    moving = lambda f: a[None] + (b - a)[None] * f[:, None]  # noqa: E731
    rf = retime(tr, moving, DynamicLimits(max_angular_rate_deg=20))
    assert np.allclose(rf.look_at_points[0], a) and np.allclose(rf.look_at_points[-1], b)
    assert rf.peaks.angular_rate_deg <= 20


def test_bad_limits():
    tr = _curve(1)
    with pytest.raises(InvalidInputError, match="max_speed"):
        retime(tr, np.zeros(3), DynamicLimits(max_speed=0))
    with pytest.raises(InvalidInputError, match="max_angular_rate_deg"):
        retime(tr, np.zeros(3), DynamicLimits(max_angular_rate_deg=float("nan")))
    with pytest.raises(InvalidInputError, match="look_at"):
        retime(tr, np.zeros(2), DynamicLimits())
