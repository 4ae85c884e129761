"""A planned shot: the sampled camera poses plus everything that produced them.

Arrays are numpy float64 on the CPU (a shot is a few hundred frames, it is exported to JSON and
drawn; torch inputs are converted in __post_init__).
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Dict, Optional, Sequence

import numpy as np

from ..errors import InvalidInputError
from ..trajectory.bezier import BezierTrajectory, to_numpy
from ..trajectory.dynamics import DynamicLimits, dynamics_report, retime
from ..trajectory.orientation import look_at_error_deg, look_at_rotations
from ..trajectory.timing import TimingConfig, arc_length_table, check_frame_count, time_parametrize

if TYPE_CHECKING:
    from ..corridor.safe_corridor import Corridor


def _finite_or_none(x: Optional[float]) -> Optional[float]:
    return None if x is None or not math.isfinite(x) else float(x)


def _point(name: str, value: Any) -> np.ndarray:
    """Shot.<name> as a finite float [3] numpy point, else InvalidInputError."""
    v = to_numpy(value).reshape(-1)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise InvalidInputError(f"Shot.{name} must be a finite 3D point, got {v.tolist()}.")
    return v


@dataclass
class Shot:
    """One camera shot: frames at `times`, camera-to-world rotations in the nerfstudio convention."""

    times: np.ndarray  # [T] seconds, increasing
    positions: np.ndarray  # [T, 3] camera centres (world)
    rotations: np.ndarray  # [T, 3, 3] camera-to-world rotations, columns x right, y up, z back
    look_at: np.ndarray  # [3] the point every frame looks at
    goal: np.ndarray  # [3] where the camera ends (the closest safe point to the go-to target)
    start: np.ndarray  # [3] where the camera starts
    trajectory: Optional[BezierTrajectory] = None  # the smooth curve the frames sample
    corridor: Optional[Corridor] = None  # the safe corridor the curve lies in, if any
    clearance: Optional[np.ndarray] = None  # [T] exact clearance of each frame (camera radius included)
    timings: Dict[str, float] = field(default_factory=dict)  # stage -> milliseconds
    fps: Optional[float] = None  # frame rate of `times` (derived from times when None)
    curve_times: Optional[np.ndarray] = None  # [T] the trajectory's own time at each frame (dense resampling)
    safety: Optional[Dict[str, Any]] = None  # the planner's dense exact-clearance report (safety.safety_report)
    goal_target: Optional[np.ndarray] = None  # [3] the requested go-to point (goal is the closest safe point to it)
    # What a request adds to a planned shot (None until it does): read by the CLI's report and table and the viewer.
    score: Optional[float] = None  # the shot score's total (ranked candidates: lower is better)
    rank: Optional[int] = None  # 1 = the best of its request's candidates
    score_terms: Optional[Dict[str, Any]] = None  # ShotScore.to_dict() of the shot's score
    goal_moved: Optional[Dict[str, Any]] = None  # Planner.explain_goal: where the go-to moved and why
    dynamics: Optional[Dict[str, float]] = None  # peaks vs limits after retime_shot (trajectory/dynamics.py)
    refinement: Optional[Dict[str, Any]] = None  # the local fine grid a refined leg was planned on (refine.py)
    end_pose: Optional[Any] = None  # the end pose it ends at (shot_targets.ShotTargets.pose_of)
    subject_view: Optional[Dict[str, Any]] = None  # the look-at object seen from its last frame (view_report)
    end_pose_note: Optional[str] = None  # why it ends where it does (ShotTargets.note)

    def __post_init__(self) -> None:
        self.times = to_numpy(self.times).reshape(-1)
        self.positions = to_numpy(self.positions)
        self.rotations = to_numpy(self.rotations)
        self.look_at, self.goal, self.start = (_point(name, v) for name, v in (
            ("look_at", self.look_at), ("goal", self.goal), ("start", self.start)))
        t = len(self.times)
        if t < 1 or self.positions.shape != (t, 3) or self.rotations.shape != (t, 3, 3):
            raise InvalidInputError(
                f"Shot needs times [T], positions [T,3], rotations [T,3,3]; got {self.times.shape}, "
                f"{self.positions.shape}, {self.rotations.shape}."
            )
        if not (np.all(np.isfinite(self.times)) and np.all(np.isfinite(self.positions))
                and np.all(np.isfinite(self.rotations))):
            raise InvalidInputError("Shot frames contain NaN or inf.")
        if t > 1 and np.any(np.diff(self.times) <= 0):
            raise InvalidInputError("Shot times must be strictly increasing.")
        if self.clearance is not None:
            self.clearance = to_numpy(self.clearance).reshape(-1)
            if self.clearance.shape != (t,):
                raise InvalidInputError(f"Shot.clearance must have shape [{t}], got {self.clearance.shape}.")
        if self.curve_times is not None:
            self.curve_times = to_numpy(self.curve_times).reshape(-1)
            if self.curve_times.shape != (t,):
                raise InvalidInputError(f"Shot.curve_times must have shape [{t}], got {self.curve_times.shape}.")
        if self.fps is None:
            self.fps = float(1.0 / np.median(np.diff(self.times))) if t > 1 else 30.0

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_trajectory(
        cls,
        trajectory: BezierTrajectory,
        look_at: Any,
        timing: Optional[TimingConfig] = None,
        up: Sequence[float] = (0.0, 0.0, 1.0),
        corridor: Any = None,
        clearance_fn: Optional[Callable[[np.ndarray], Any]] = None,
        timings: Optional[Dict[str, float]] = None,
    ) -> "Shot":
        """Sample `trajectory` at timing.fps with the speed caps, aim every frame at `look_at`.

        clearance_fn(points [P,3]) -> [P], if given, fills `clearance` (e.g. the exact clearance of
        planner.distance). `timings` (stage -> ms) is copied and extended with "timing_ms"/"orientation_ms".
        """
        timings = dict(timings or {})
        t0 = time.perf_counter()
        path = time_parametrize(trajectory, timing)
        t1 = time.perf_counter()
        rot = look_at_rotations(path.positions, look_at, up=up)
        t2 = time.perf_counter()
        timings["timing_ms"] = 1e3 * (t1 - t0)
        timings["orientation_ms"] = 1e3 * (t2 - t1)
        clearance = None
        if clearance_fn is not None:
            clearance = to_numpy(clearance_fn(path.positions)).reshape(-1)
            timings["clearance_ms"] = 1e3 * (time.perf_counter() - t2)
        return cls(
            times=path.times,
            positions=path.positions,
            rotations=rot,
            look_at=to_numpy(look_at),
            goal=trajectory.end,
            start=trajectory.start,
            trajectory=trajectory,
            corridor=corridor,
            clearance=clearance,
            timings=timings,
            fps=path.fps,
            curve_times=path.curve_times,
        )

    # ------------------------------------------------------------------ derived values
    @property
    def num_frames(self) -> int:
        return len(self.times)

    @property
    def duration(self) -> float:
        return float(self.times[-1] - self.times[0])

    @property
    def length(self) -> float:
        """Path length: exact arc length of the trajectory if present, else the polyline of the frames."""
        if self.trajectory is not None:
            return float(arc_length_table(self.trajectory)[1][-1])
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum())

    def camera_to_worlds(self) -> np.ndarray:
        """[T, 4, 4] homogeneous camera-to-world matrices (nerfstudio / OpenGL camera convention)."""
        c2w = np.zeros((self.num_frames, 4, 4))
        c2w[:, :3, :3] = self.rotations
        c2w[:, :3, 3] = self.positions
        c2w[:, 3, 3] = 1.0
        return c2w

    def look_at_errors_deg(self) -> np.ndarray:
        """[T] angle between each frame's view direction and the direction to look_at."""
        return look_at_error_deg(self.positions, self.rotations, self.look_at)

    def frame_speeds(self) -> np.ndarray:
        """[T-1] chord speed between consecutive frames (units/s)."""
        return np.linalg.norm(np.diff(self.positions, axis=0), axis=1) / np.diff(self.times)

    def resampled(self, fps: float) -> "Shot":
        """The same motion sampled at another frame rate (same duration, frames j / fps).

        With a trajectory the new frames are exact points of the curve (its own time is interpolated
        between frames, which only re-times, never moves a point off the curve), so the convex-hull
        safety guarantee still holds. Without one, positions are linearly interpolated between frames
        (approximate: a chord between two frames). Rotations are re-aimed at look_at; the per-frame
        clearance is dropped (it described the old frames) and must be recomputed if needed.
        """
        fps = float(fps)
        if not (fps > 0 and math.isfinite(fps)):
            raise InvalidInputError(f"fps must be positive, got {fps}.")
        if math.isclose(fps, float(self.fps), rel_tol=1e-9):
            return self
        t0, dur = float(self.times[0]), self.duration
        n_int = check_frame_count(dur, fps, TimingConfig.max_frames, "the resampled shot")
        times = t0 + np.minimum(np.arange(n_int + 1) / fps, dur)  # [T']
        times[-1] = t0 + dur
        if np.any(np.diff(times) <= 0):  # duration shorter than one new frame
            times = np.array([t0, t0 + max(dur, 1.0 / fps)])
        curve_times = None
        if self.trajectory is not None and self.curve_times is not None:
            curve_times = np.interp(times, self.times, self.curve_times)  # [T']
            pos = self.trajectory.evaluate(curve_times)
        else:
            pos = np.stack([np.interp(times, self.times, self.positions[:, k]) for k in range(3)], axis=1)
        # keep the shot's own roll: interpolate the old right (x) axes, re-aim z exactly at look_at
        x_old = np.stack([np.interp(times, self.times, self.rotations[:, k, 0]) for k in range(3)], axis=1)
        back = pos - self.look_at[None]  # [T', 3] camera z points backwards, away from the target
        z = back / np.maximum(np.linalg.norm(back, axis=1, keepdims=True), 1e-12)
        x = x_old - (x_old * z).sum(1, keepdims=True) * z
        x = x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-12)
        rot = np.stack([x, np.cross(z, x), z], axis=2)  # [T', 3, 3] columns x, y, z
        return Shot(
            times=times - t0, positions=pos, rotations=rot, look_at=self.look_at, goal=self.goal, start=self.start,
            trajectory=self.trajectory, corridor=self.corridor, clearance=None, timings=dict(self.timings),
            fps=fps, curve_times=curve_times, safety=self.safety, goal_target=self.goal_target,
        )

    # ------------------------------------------------------------------ export
    def to_dict(self, include_frames: bool = False) -> dict:
        """JSON-serialisable summary (and the frames themselves with include_frames)."""
        err = self.look_at_errors_deg()
        speeds = self.frame_speeds() if self.num_frames > 1 else np.zeros(1)
        d = {
            "num_frames": self.num_frames,
            "fps": float(self.fps),
            "duration_s": self.duration,
            "length": self.length,
            "max_speed": float(speeds.max()),
            "start": self.start.tolist(),
            "goal": self.goal.tolist(),
            "look_at": self.look_at.tolist(),
            "max_look_at_error_deg": float(err.max()),
            "min_clearance": None,
            "mean_clearance": None,
            "argmin_clearance_time_s": None,
            "timings_ms": {k: float(v) for k, v in self.timings.items()},
        }
        if self.clearance is not None:
            i = int(np.argmin(self.clearance))
            d["min_clearance"] = _finite_or_none(float(self.clearance[i]))
            d["mean_clearance"] = _finite_or_none(float(self.clearance.mean()))
            d["argmin_clearance_time_s"] = float(self.times[i])
        if self.trajectory is not None:
            d["trajectory"] = {
                "segments": self.trajectory.num_segments,
                "degree": self.trajectory.degree,
                "duration_s": self.trajectory.total_duration,
                "solver": {
                    k: v
                    for k, v in self.trajectory.info.items()
                    if isinstance(v, str) or (isinstance(v, (int, float)) and math.isfinite(v))
                },
            }
        if include_frames:
            d["frames"] = {
                "times": self.times.tolist(),
                "positions": self.positions.tolist(),
                "rotations": self.rotations.tolist(),
                "clearance": None if self.clearance is None else self.clearance.tolist(),
            }
            if self.trajectory is not None:
                d["trajectory"]["bezier"] = self.trajectory.to_dict()
        return d

    def to_json(self, include_frames: bool = False, indent: int = 2) -> str:
        return json.dumps(self.to_dict(include_frames), indent=indent, allow_nan=False)


def retime_shot(shot: "Shot", limits: Optional[DynamicLimits] = None,
                up: Sequence[float] = (0.0, 0.0, 1.0)) -> "Shot":
    """A new Shot: ``shot``'s curve retimed under ``limits`` (its fixed look-at). The peaks reached are
    its ``dynamics`` (a JSON-able dict, see dynamics_report); per-frame clearance is dropped
    (it described the old frames). Here beside Shot: trajectory/dynamics.py retimes curves, not shots."""
    if shot.trajectory is None:
        raise InvalidInputError("retiming needs the shot's trajectory (curve); this shot has only frames.")
    rf = retime(shot.trajectory, shot.look_at, limits, up=up)
    out = Shot(
        times=rf.times, positions=rf.positions, rotations=rf.rotations, look_at=shot.look_at, goal=shot.goal,
        start=shot.start, trajectory=shot.trajectory, corridor=shot.corridor, clearance=None,
        timings=dict(shot.timings), fps=(limits or DynamicLimits()).fps, curve_times=rf.curve_times,
        safety=shot.safety, goal_target=shot.goal_target, dynamics=dynamics_report(rf, limits or DynamicLimits()),
    )
    return out
