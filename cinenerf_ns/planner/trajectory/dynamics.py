"""Dynamic feasibility: retime a planned curve so the exported frames respect speed, acceleration and
view angular-rate limits, and report the peaks reached.

What is limited is what the exported shot shows, measured on the frames (dt = 1/fps) by finite
differences (``frame_peaks``):
    speed_j   = |p_{j+1} - p_j| / dt
    accel_j   = |p_{j+1} - 2 p_j + p_{j-1}| / dt^2
    angular_j = angle(view_j, view_{j+1}) / dt          (view = unit vector camera -> look-at)

Time allocation (``retime``). The curve's geometry is kept; only the time law s(t) along its arc length
changes (frames stay exact curve points, so the corridor's safety guarantee is untouched):
  1. on a dense arc-length grid s_i compute the curvature kappa(s) and the turn rate of the view
     direction per unit length |d view / ds| (both from the exact curve derivatives);
  2. speed ceiling per grid point: v <= max_speed, v <= max_angular_rate / |d view/ds|,
     v <= sqrt(a_n / kappa) (centripetal part a_n = max_acceleration / sqrt 2);
  3. forward/backward passes with tangential acceleration a_t = max_acceleration / sqrt 2
     (v_{i+1}^2 <= v_i^2 + 2 a_t ds), starting and ending at rest; |a| <= sqrt(a_t^2 + a_n^2) = a_max;
  4. t(s) = sum 2 ds / (v_i + v_{i+1}) (exact for piecewise-constant acceleration), stretched to a whole
     number of frames, frames at j / fps, s(t_j) -> curve time (exact arc-length inversion) -> positions;
  5. measure the frame peaks above; while one exceeds its limit (the dense-grid profile and the frame
     discretisation differ slightly), lower the scale of the violated limit by the excess and redo.
The loop stops only when every measured frame peak is <= its limit, so the exported frames never
exceed the limits (no tolerance is needed because step 5 checks exactly what the export contains);
after ``max_iterations`` without success a PlanningError is raised.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Dict, Optional, Sequence, Union

import numpy as np

from ..errors import InvalidInputError, PlanningError
from .bezier import BezierTrajectory
from .orientation import look_at_rotations
from .timing import MAX_FPS, MIN_FPS, TimingConfig, arc_length_table, check_frame_count, invert_arc_length

LookAt = Union[np.ndarray, Callable[[np.ndarray], np.ndarray]]


@dataclass
class DynamicLimits:
    """Limits on what the exported frames show (finite differences at the frame rate)."""

    max_speed: float = TimingConfig.max_speed
    """Camera speed cap, scene units per second."""
    max_acceleration: float = TimingConfig.max_acceleration
    """Cap on the magnitude of the camera's acceleration (tangential and centripetal), units/s^2."""
    max_angular_rate_deg: float = 60.0
    """Cap on how fast the view direction turns, degrees per second."""
    fps: float = TimingConfig.fps
    """Frame rate of the exported shot (the finite differences use dt = 1/fps)."""
    grid_per_unit: float = 400.0
    """Arc-length grid points per scene unit of the speed profile (at least 200 in total)."""
    max_iterations: int = 12
    """Retiming rounds (each lowers a violated limit's internal scale) before giving up."""

    def validate(self) -> None:
        for name in ("max_speed", "max_acceleration", "max_angular_rate_deg", "fps", "grid_per_unit"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidInputError(f"DynamicLimits.{name} must be a positive finite number, got {v!r}.")
        if not MIN_FPS <= self.fps <= MAX_FPS:
            raise InvalidInputError(f"DynamicLimits.fps must be in [{MIN_FPS:g}, {MAX_FPS:g}], got {self.fps!r}.")
        if int(self.max_iterations) < 1:
            raise InvalidInputError("DynamicLimits.max_iterations must be >= 1.")


@dataclass
class FramePeaks:
    """Peak values on sampled frames (finite differences)."""

    speed: float
    acceleration: float
    angular_rate_deg: float
    jerk: float
    mean_jerk: float
    mean_angular_rate_deg: float

    def to_dict(self) -> Dict[str, float]:
        return {k: float(v) for k, v in self.__dict__.items()}


def view_vectors(positions: np.ndarray, look_at: np.ndarray) -> np.ndarray:
    """Unit view directions [T, 3] from positions [T, 3] to look_at [3] or [T, 3]."""
    d = np.broadcast_to(look_at, positions.shape) - positions
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def frame_peaks(positions: np.ndarray, times: np.ndarray, views: np.ndarray) -> FramePeaks:
    """Finite-difference peaks of frames positions [T, 3] at times [T] with view directions [T, 3]."""
    p = np.asarray(positions, np.float64)
    t = np.asarray(times, np.float64)
    if len(p) < 2:
        return FramePeaks(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    dt = np.diff(t)  # [T-1]
    vel = np.diff(p, axis=0) / dt[:, None]  # [T-1, 3]
    speed = np.linalg.norm(vel, axis=1)
    acc = np.diff(vel, axis=0) / (0.5 * (dt[1:] + dt[:-1]))[:, None] if len(p) > 2 else np.zeros((1, 3))
    jerk = np.diff(acc, axis=0) / dt[1:-1, None] if len(p) > 3 else np.zeros((1, 3))
    cosang = np.clip((views[1:] * views[:-1]).sum(1), -1.0, 1.0)
    sinang = np.linalg.norm(np.cross(views[:-1], views[1:]), axis=1)
    ang = np.degrees(np.arctan2(sinang, cosang)) / dt  # [T-1]
    jn = np.linalg.norm(jerk, axis=1)
    return FramePeaks(float(speed.max()), float(np.linalg.norm(acc, axis=1).max()), float(ang.max()),
                      float(jn.max()), float(jn.mean()), float(ang.mean()))


@dataclass
class RetimedFrames:
    """Frames of a retimed curve and the peaks they reach."""

    times: np.ndarray  # [T] j / fps
    positions: np.ndarray  # [T, 3] exact curve points
    curve_times: np.ndarray  # [T] the trajectory's own time at each frame
    look_at_points: np.ndarray  # [T, 3] what each frame looks at
    rotations: np.ndarray  # [T, 3, 3] camera-to-world, aimed at look_at_points
    peaks: FramePeaks
    iterations: int
    scales: Dict[str, float] = field(default_factory=dict)  # internal limit scales used (<= 1)


def _look_at_of(look_at: LookAt, frac: np.ndarray) -> np.ndarray:
    """Look-at points [K, 3] at arc-length fractions frac [K] (a fixed point or a callable of frac)."""
    if callable(look_at):
        out = np.asarray(look_at(frac), np.float64).reshape(-1, 3)
        if out.shape != (len(frac), 3) or not np.all(np.isfinite(out)):
            raise InvalidInputError("the look-at function must return finite points [K, 3].")
        return out
    p = np.asarray(look_at, np.float64).reshape(-1)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise InvalidInputError(f"look_at must be 3 finite numbers, got {p.tolist()}.")
    return np.broadcast_to(p, (len(frac), 3))


def _speed_ceiling(traj: BezierTrajectory, tau: np.ndarray, s: np.ndarray, look: np.ndarray, lim: DynamicLimits,
                   sc: Dict[str, float]) -> np.ndarray:
    """Speed ceiling [K] at curve times tau [K] (arc lengths s, look-at points [K, 3])."""
    d1 = traj.derivative(tau, 1)
    d2 = traj.derivative(tau, 2)
    sp = np.maximum(np.linalg.norm(d1, axis=1), 1e-12)
    kappa = np.linalg.norm(np.cross(d1, d2), axis=1) / sp**3  # [K] curvature
    pos = traj.evaluate(tau)
    view = view_vectors(pos, look)
    dv = np.gradient(view, s, axis=0) if len(s) > 2 else np.zeros_like(view)  # d view / ds, smooth in s
    turn = np.linalg.norm(dv, axis=1)  # [K] radians per unit length
    a_part = lim.max_acceleration * sc["acceleration"] / math.sqrt(2.0)
    v = np.full(len(s), lim.max_speed * sc["speed"])
    v = np.minimum(v, math.radians(lim.max_angular_rate_deg) * sc["angular"] / np.maximum(turn, 1e-12))
    v = np.minimum(v, np.sqrt(a_part / np.maximum(kappa, 1e-12)))
    return v


def retime(traj: BezierTrajectory, look_at: LookAt, limits: Optional[DynamicLimits] = None,
           up: Sequence[float] = (0.0, 0.0, 1.0)) -> RetimedFrames:
    """Frames of ``traj`` at limits.fps whose finite-difference speed, acceleration and view angular
    rate stay <= the limits (see the module docstring). look_at: [3], or a callable mapping the
    arc-length fraction in [0, 1] (array [K]) to look-at points [K, 3] (multi-stop shots)."""
    lim = limits or DynamicLimits()
    lim.validate()
    tau_tab, s_tab, v_tab = arc_length_table(traj, with_speed=True)
    length = float(s_tab[-1])
    if length <= 1e-12:
        raise InvalidInputError("the trajectory does not move (zero length); nothing to retime.")
    K = max(200, int(math.ceil(length * lim.grid_per_unit)))
    s = np.linspace(0.0, length, K + 1)  # [K+1]
    tau = invert_arc_length(traj, tau_tab, s_tab, s, v_tab)
    tau[-1] = traj.total_duration
    look = _look_at_of(look_at, s / length)
    sc = {"speed": 1.0, "acceleration": 1.0, "angular": 1.0}
    ds = np.diff(s)
    for it in range(1, int(lim.max_iterations) + 1):
        vmax = _speed_ceiling(traj, tau, s, look, lim, sc)
        a_t = lim.max_acceleration * sc["acceleration"] / math.sqrt(2.0)
        v = vmax.copy()
        v[0] = v[-1] = 0.0
        for i in range(1, K + 1):  # forward: accelerate at most a_t
            v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2 * a_t * ds[i - 1]))
        for i in range(K - 1, -1, -1):  # backward: brake at most a_t
            v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2 * a_t * ds[i]))
        t_grid = np.concatenate([[0.0], np.cumsum(2 * ds / np.maximum(v[1:] + v[:-1], 1e-300))])  # [K+1]
        dur = float(t_grid[-1])
        n_int = check_frame_count(dur, lim.fps, TimingConfig.max_frames, "the retimed shot")
        slow = n_int / lim.fps / dur  # >= 1: whole number of frames, only slower
        times = np.arange(n_int + 1) / lim.fps
        s_f = np.interp(times / slow, t_grid, s)  # t(s) is monotone; piecewise-linear inverse
        s_f[-1] = length
        tau_f = invert_arc_length(traj, tau_tab, s_tab, s_f, v_tab)
        tau_f[-1] = traj.total_duration
        pos = traj.evaluate(tau_f)
        look_f = _look_at_of(look_at, s_f / length)
        views = view_vectors(pos, look_f)
        pk = frame_peaks(pos, times, views)
        excess = {
            "speed": pk.speed / lim.max_speed,
            "acceleration": pk.acceleration / lim.max_acceleration,
            "angular": pk.angular_rate_deg / lim.max_angular_rate_deg,
        }
        if all(e <= 1.0 for e in excess.values()):
            rot = look_at_rotations(pos, look_f, up=up)
            return RetimedFrames(times, pos, tau_f, np.ascontiguousarray(look_f), rot, pk, it, dict(sc))
        for k, e in excess.items():
            if e > 1.0:
                sc[k] *= 0.98 / e
    raise PlanningError(
        f"could not meet the dynamic limits in {lim.max_iterations} retiming rounds (last peaks: speed "
        f"{pk.speed:.3g}, acceleration {pk.acceleration:.3g}, angular rate {pk.angular_rate_deg:.3g} deg/s); "
        f"raise the limits or the frame rate"
    )


def dynamics_report(rf: RetimedFrames, limits: DynamicLimits) -> Dict[str, float]:
    """Peaks reached vs the limits, JSON-able."""
    return {
        "peak_speed": rf.peaks.speed, "max_speed": limits.max_speed,
        "peak_acceleration": rf.peaks.acceleration, "max_acceleration": limits.max_acceleration,
        "peak_angular_rate_deg": rf.peaks.angular_rate_deg, "max_angular_rate_deg": limits.max_angular_rate_deg,
        "duration_s": float(rf.times[-1]), "retime_iterations": rf.iterations,
    }
