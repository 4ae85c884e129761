"""Time parametrisation of a planned curve: arc length, a speed profile, resampling at fps.

The QP's Bezier time (tau) only shapes the curve. The shot's clock t is set here:
  1. arc length s(tau) tabulated on a dense grid (composite Gauss-Legendre per table interval, so the
     table is exact to ~1e-12 for these polynomials);
  2. a speed profile v(t) along the path: cruise at max_speed, with ramps at both ends whose tangential
     acceleration stays <= max_acceleration. ease=True uses raised-cosine ramps (continuous acceleration,
     "ease in/out"), ease=False linear ramps (trapezoidal profile). If the path is too short to reach
     max_speed the peak speed is lowered so the two ramps meet;
  3. frames at t_j = j / fps; s(t_j) from the profile, tau(s) by inverting the monotone arc-length table,
     positions = curve(tau).
The total duration is rounded up to a whole number of frames (the profile is slowed by that factor,
< 1/(fps * duration) relative), so the frames are exactly 1/fps apart and the last frame is the goal.

Approximation said plainly: max_acceleration bounds the tangential acceleration only; the normal
(centripetal) acceleration v^2 * curvature is not limited here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..errors import InvalidInputError
from .bezier import BezierTrajectory

_GL5 = np.polynomial.legendre.leggauss(5)  # 5-point Gauss-Legendre nodes/weights on [-1, 1]


MIN_FPS, MAX_FPS = 1.0, 240.0  # frame rates a camera path may ask for


def check_frame_count(duration_s: float, fps: float, max_frames: int, what: str = "the shot") -> int:
    """Frame intervals of a ``duration_s`` shot at ``fps``; InvalidInputError when its frames would exceed
    ``max_frames`` (before any frame is made)."""
    n_int = max(1, math.ceil(duration_s * fps - 1e-9))
    if n_int + 1 > max_frames:
        raise InvalidInputError(
            f"{what} would need {n_int + 1} frames ({duration_s:.4g} s at {fps:g} fps), more than max_frames "
            f"{max_frames}: raise --max-speed or lower --fps")
    return n_int


@dataclass
class TimingConfig:
    """How fast the camera flies along the planned curve and how it is sampled."""

    max_speed: float = 0.5
    """Cruise speed cap in scene units per second; the camera never exceeds it."""
    max_acceleration: Optional[float] = 0.5
    """Cap on the tangential acceleration of the start/stop ramps (units/s^2); None: start and stop at full speed."""
    ease: bool = True
    """Raised-cosine ramps (smooth acceleration) instead of linear ramps (piecewise constant acceleration)."""
    fps: float = 30.0
    """Frames per second of the sampled shot."""
    table_samples_per_segment: int = 64
    """Intervals per Bezier segment of the arc-length table (each integrated with 5-point Gauss-Legendre)."""
    max_frames: int = 18_000
    """Most frames a shot may have (10 min at 30 fps): a bound on memory, checked before frames are made."""

    def validate(self) -> None:
        if not (self.max_speed > 0 and math.isfinite(self.max_speed)):
            raise InvalidInputError(f"max_speed must be positive, got {self.max_speed}.")
        if self.max_acceleration is not None and not (self.max_acceleration > 0
                                                      and math.isfinite(self.max_acceleration)):
            raise InvalidInputError(f"max_acceleration must be positive or None, got {self.max_acceleration}.")
        if not (MIN_FPS <= self.fps <= MAX_FPS):
            raise InvalidInputError(f"fps must be in [{MIN_FPS:g}, {MAX_FPS:g}] frames per second, got {self.fps}.")
        if not (isinstance(self.max_frames, int) and self.max_frames >= 2):
            raise InvalidInputError(f"max_frames must be an integer >= 2, got {self.max_frames!r}.")
        if self.table_samples_per_segment < 2:
            raise InvalidInputError("table_samples_per_segment must be >= 2.")


@dataclass
class TimedPath:
    """The curve sampled on the shot's clock."""

    times: np.ndarray  # [T] seconds, j / fps
    positions: np.ndarray  # [T, 3]
    curve_times: np.ndarray  # [T] the BezierTrajectory's own time tau at each frame
    arc_length: np.ndarray  # [T] distance travelled at each frame
    speed: np.ndarray  # [T] profile speed ds/dt at each frame
    length: float  # total path length
    duration: float  # times[-1]
    fps: float


def _native_curve(traj: BezierTrajectory) -> tuple:
    """(the curve arguments native/timing.c's entry points start with, the arrays they point into: keep them)."""
    coef, starts, durations = traj.speed_coefficients(), traj.segment_starts, np.ascontiguousarray(traj.durations)
    return (coef.ctypes.data, coef.shape[0], coef.shape[1], starts.ctypes.data, durations.ctypes.data,
            traj.total_duration), (coef, starts, durations)


def native_bezier(traj: BezierTrajectory) -> tuple:
    """(the curve arguments native/timing.c's position entry points start with: control points [M, D+1, 3], M, D+1,
    segment starts [M], durations [M], total duration; the arrays they point into: keep them). curve_positions' and
    shots/safety.py's dense samples'."""
    cp, starts, durations = (np.ascontiguousarray(a, dtype=np.float64) for a in (traj.control_points,
                                                                                 traj.segment_starts, traj.durations))
    return (cp.ctypes.data, cp.shape[0], cp.shape[1], starts.ctypes.data, durations.ctypes.data,
            traj.total_duration), (cp, starts, durations)


def arc_length_table(traj: BezierTrajectory, samples_per_segment: int = 64, with_speed: bool = False,
                     backend: str = "auto"):
    """(tau [K], s [K]): cumulative arc length at a dense grid of curve times (monotone, s[0] = 0).
    with_speed: also the speed |p'(tau)| [K] at the grid times (same derivative evaluation; for invert_arc_length).
    backend: "auto" (native/timing.c's cn_arc_length_table, the same arithmetic, when it loads), "native" or
    "python" (arc_length_table_reference)."""
    from ..native import arc_length_table_c, choose

    nodes, weights = _GL5
    fn = choose(backend, arc_length_table_c, "timing", "arc-length table")
    if fn is not None:
        S = int(samples_per_segment)
        if S < 0:  # numpy's linspace refuses these too (but for -1)
            raise ValueError(f"samples_per_segment must be >= 0, got {S}")
        K = traj.num_segments * S + 1
        tau, s, v = np.empty(K), np.empty(K), (np.empty(K) if with_speed else None)
        args, _keep = _native_curve(traj)
        fn(*args, S, nodes.ctypes.data, weights.ctypes.data, tau.ctypes.data, s.ctypes.data,
           None if v is None else v.ctypes.data)
        return (tau, s, v) if with_speed else (tau, s)
    return arc_length_table_reference(traj, samples_per_segment, with_speed)


def arc_length_table_reference(traj: BezierTrajectory, samples_per_segment: int = 64, with_speed: bool = False):
    """arc_length_table in numpy: the reference of native/timing.c's cn_arc_length_table (the same arithmetic)."""
    nodes, weights = _GL5
    lin = np.linspace(0.0, 1.0, samples_per_segment + 1)[:-1]
    # per segment start + duration * lin, all segments in one broadcast (the same float64 operations)
    grid = traj.segment_starts[:, None] + traj.durations[:, None] * lin[None, :]  # [M, samples]
    tau = np.concatenate([grid.ravel(), [traj.total_duration]])  # [K]
    a, b = tau[:-1], tau[1:]
    half = 0.5 * (b - a)  # [K-1]
    q = (0.5 * (a + b))[:, None] + half[:, None] * nodes[None, :]  # [K-1, 5] quadrature points
    # evaluate each quadrature point inside the segment its interval belongs to (no join ambiguity)
    pts = np.concatenate([q.ravel(), tau]) if with_speed else q.ravel()
    speed_all = traj.speed(pts)
    speed = speed_all[: q.size].reshape(q.shape)  # [K-1, 5]
    ds = half * (speed @ weights)  # [K-1]
    s = np.concatenate([[0.0], np.cumsum(ds)])
    return (tau, s, speed_all[q.size:]) if with_speed else (tau, s)


def _hermite_guess(tau_tab: np.ndarray, s_tab: np.ndarray, v_tab: np.ndarray, i: np.ndarray,
                   s: np.ndarray) -> np.ndarray:
    """tau [T] where the cubic Hermite model of s(tau) on table interval i [T] (values s_tab, slopes v_tab)
    reaches s [T].

    Why: the curve rests at its ends (speed 0), where s(tau) is quadratic and a linear table guess sends Newton on
    S(tau) into slow, linear convergence (4 steps left frame 1 ~1e-4 s of curve time off). The cubic has the right
    shape there; a few Newton steps on it (cheap [T] arithmetic, no curve evaluation) give a start that the real
    Newton finishes in one or two steps."""
    t0, h = tau_tab[i], tau_tab[i + 1] - tau_tab[i]
    s0, s1 = s_tab[i], s_tab[i + 1]
    m0, m1 = v_tab[i] * h, v_tab[i + 1] * h  # slopes in the unit parameter u
    ds = s1 - s0
    u = np.clip(np.where(ds > 0, (s - s0) / np.where(ds > 0, ds, 1.0), 0.0), 0.0, 1.0)
    # H(u) = s0 + m0 u + (3 ds - 2 m0 - m1) u^2 + (m0 + m1 - 2 ds) u^3
    c2, c3 = 3 * ds - 2 * m0 - m1, m0 + m1 - 2 * ds
    for _ in range(6):
        f = s0 + u * (m0 + u * (c2 + u * c3)) - s
        df = m0 + u * (2 * c2 + 3 * u * c3)
        u = np.clip(u - np.where(df > 1e-300, f / np.where(df > 1e-300, df, 1.0), 0.0), 0.0, 1.0)
    return t0 + u * h


def invert_arc_length(traj: BezierTrajectory, tau_tab: np.ndarray, s_tab: np.ndarray, s: np.ndarray,
                      v_tab: "np.ndarray | None" = None, backend: str = "auto") -> np.ndarray:
    """Curve times tau [T] with arc length s [T]: table bracket, then safeguarded Newton steps.

    Start: the cubic Hermite model of the table interval when the table's speeds v_tab [K] are given
    (arc_length_table(..., with_speed=True)), else linear interpolation (off by ~0.1% in local speed where
    |p'| varies fast, and converging slowly where the curve rests). Newton on
    S(tau) = s_tab[i] + integral_{tau_i}^{tau} |p'| (5-point Gauss-Legendre) brings it to ~1e-12.
    backend: "auto" (native/timing.c's cn_invert_arc_length, the same steps, when it loads and v_tab is given),
    "native" or "python" (invert_arc_length_reference).
    """
    from ..native import choose, invert_arc_length_c

    nodes, weights = _GL5
    fn = choose(backend, invert_arc_length_c, "timing", "arc-length inversion", applies=v_tab is not None,
                needs="the table's speeds v_tab")
    if fn is not None:
        tt, st, vt, sq = (np.ascontiguousarray(a, dtype=np.float64) for a in (tau_tab, s_tab, v_tab, s))
        if not (len(tt) == len(st) == len(vt) >= 2 and sq.ndim == 1):
            raise InvalidInputError("invert_arc_length needs tables of one length >= 2 and arc lengths s [T]")
        tau = np.empty(len(sq))
        args, _keep = _native_curve(traj)
        if fn(*args, nodes.ctypes.data, weights.ctypes.data, tt.ctypes.data, st.ctypes.data, vt.ctypes.data,
              len(tt), sq.ctypes.data, len(sq), 1e-11 * max(1.0, traj.total_duration), tau.ctypes.data) < 0:
            raise MemoryError("the compiled arc-length inversion ran out of memory")
        return tau
    return invert_arc_length_reference(traj, tau_tab, s_tab, s, v_tab)


def invert_arc_length_reference(traj: BezierTrajectory, tau_tab: np.ndarray, s_tab: np.ndarray, s: np.ndarray,
                                v_tab: "np.ndarray | None" = None) -> np.ndarray:
    """invert_arc_length in numpy: the reference of native/timing.c's cn_invert_arc_length (the same steps)."""
    nodes, weights = _GL5
    i = np.clip(np.searchsorted(s_tab, s, side="right") - 1, 0, len(s_tab) - 2)  # [T] bracket
    lo, hi = tau_tab[i], tau_tab[i + 1]
    tau = np.interp(s, s_tab, tau_tab) if v_tab is None else np.clip(_hermite_guess(tau_tab, s_tab, v_tab, i, s),
                                                                     lo, hi)
    tol = 1e-11 * max(1.0, traj.total_duration)
    n = tau.shape[0]
    for _ in range(8):
        half = 0.5 * (tau - lo)
        q = (lo + half)[:, None] + half[:, None] * nodes[None, :]  # [T, 5]
        # one derivative evaluation for the quadrature points and tau itself
        sq = traj.speed(np.concatenate([q.ravel(), tau]))  # [5T + T]
        speed_q, speed = sq[: 5 * n].reshape(q.shape), sq[5 * n:]
        s_here = s_tab[i] + half * (speed_q @ weights)
        step = np.where(speed > 1e-12, (s_here - s) / np.maximum(speed, 1e-12), 0.0)
        tau = np.clip(tau - step, lo, hi)
        if np.abs(step).max() <= tol:  # quadratic convergence from the Hermite start: usually 2 steps
            break
    return tau


def _profile(length: float, cfg: TimingConfig):
    """Speed profile along the path: returns (duration, s_of_t callable, v_of_t callable)."""
    vmax = cfg.max_speed
    amax = cfg.max_acceleration
    if amax is None:
        dur = length / vmax
        return dur, (lambda t: np.clip(vmax * t, 0.0, length)), (lambda t: np.full_like(t, vmax))
    # ramp of duration T_r reaching speed v: raised cosine peaks at accel pi v / (2 T_r); linear at v / T_r
    k = math.pi / 2 if cfg.ease else 1.0
    ramp_len = lambda v: 0.5 * v * (k * v / amax)  # distance covered by one ramp to speed v
    v = vmax if 2 * ramp_len(vmax) <= length else math.sqrt(length * amax / k)
    t_r = k * v / amax
    cruise = max(length - 2 * ramp_len(v), 0.0) / v
    dur = 2 * t_r + cruise

    def ramp_s(t):  # distance after time t in [0, t_r] of an acceleration ramp
        if cfg.ease:
            return 0.5 * v * (t - t_r / math.pi * np.sin(math.pi * t / t_r))
        return 0.5 * v * t * t / t_r

    def ramp_v(t):
        if cfg.ease:
            return 0.5 * v * (1 - np.cos(math.pi * t / t_r))
        return v * t / t_r

    d_r = ramp_len(v)

    def s_of_t(t):
        t = np.clip(t, 0.0, dur)
        out = np.where(t < t_r, ramp_s(np.minimum(t, t_r)), d_r + v * (t - t_r))
        back = dur - t
        out = np.where(back < t_r, length - ramp_s(np.clip(back, 0.0, t_r)), out)
        return np.clip(out, 0.0, length)

    def v_of_t(t):
        t = np.clip(t, 0.0, dur)
        out = np.where(t < t_r, ramp_v(np.minimum(t, t_r)), v)
        back = dur - t
        return np.where(back < t_r, ramp_v(np.clip(back, 0.0, t_r)), out)

    return dur, s_of_t, v_of_t


def curve_positions(traj: BezierTrajectory, tau: np.ndarray, backend: str = "auto") -> np.ndarray:
    """traj.evaluate(tau) for curve times tau [T] -> [T, 3] float64. backend: "auto" (native/timing.c's
    cn_bezier_positions, the same arithmetic in numpy's order, when it loads), "native" or "python" (traj.evaluate):
    ~15 numpy calls for a shot's frames otherwise."""
    from ..native import bezier_positions_c, choose

    fn = choose(backend, bezier_positions_c, "timing", "curve positions")
    if fn is None:
        return traj.evaluate(tau)
    curve, _keep = native_bezier(traj)
    t = np.ascontiguousarray(tau, dtype=np.float64).reshape(-1)
    out = np.empty((t.shape[0], 3))
    if fn(*curve, t.ctypes.data, t.shape[0], out.ctypes.data) < 0:
        raise MemoryError("the compiled curve positions ran out of memory")
    return out


def time_parametrize(traj: BezierTrajectory, config: TimingConfig = None, backend: str = "auto") -> TimedPath:
    """Sample traj at config.fps with speed <= max_speed (see the module docstring). backend: arc_length_table's,
    invert_arc_length's and curve_positions' ("auto": native/timing.c when it loads)."""
    cfg = config or TimingConfig()
    cfg.validate()
    tau_tab, s_tab, v_tab = arc_length_table(traj, cfg.table_samples_per_segment, with_speed=True, backend=backend)
    length = float(s_tab[-1])
    if length <= 1e-12 * max(1.0, float(np.abs(traj.control_points).max())):
        # start == goal and the curve does not move: one still frame pair, 1/fps apart
        times = np.array([0.0, 1.0 / cfg.fps])
        pos = np.repeat(traj.start[None], 2, axis=0)
        zeros = np.zeros(2)
        return TimedPath(times, pos, np.array([0.0, traj.total_duration]), zeros, zeros, 0.0, float(times[-1]), cfg.fps)
    dur, s_of_t, v_of_t = _profile(length, cfg)
    n_int = check_frame_count(dur, cfg.fps, cfg.max_frames)  # frame intervals
    slow = n_int / cfg.fps / dur  # >= 1: stretch the profile to a whole number of frames
    times = np.arange(n_int + 1) / cfg.fps  # [T]
    s = s_of_t(times / slow)  # [T]
    s[-1] = length
    speed = v_of_t(times / slow) / slow
    tau = invert_arc_length(traj, tau_tab, s_tab, s, v_tab, backend=backend)
    tau[-1] = traj.total_duration
    pos = curve_positions(traj, tau, backend=backend)
    return TimedPath(times, pos, tau, s, speed, length, float(times[-1]), cfg.fps)
