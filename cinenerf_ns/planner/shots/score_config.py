"""The shot score's weights and reference scales (shots/scoring.py computes the score), without torch: the command
lines check them before loading anything heavy."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

from ..errors import InvalidInputError
from .camera_path import DEFAULT_FOV_DEG


@dataclass
class ScoreConfig:
    """Weights and reference scales of the shot score (shots/scoring.py's docstring gives the formula)."""

    w_occlusion: float = 10.0
    """Weight of the occluded fraction of frames (0..1): the dominant term, a hidden subject ruins a shot."""
    w_last_visibility: float = 5.0
    """Weight of the hidden fraction of the subject in the last frame (what the shot ends on)."""
    w_framing_size: float = 1.0
    """Weight of the mean |log(fill / target_fill)| of the object's projected size."""
    w_framing_offset: float = 1.0
    """Weight of the mean off-centre angle of the object (in half-fov units)."""
    w_min_clearance: float = 2.0
    """Weight of relu(clearance_ref - min clearance) / clearance_ref."""
    w_mean_clearance: float = 1.0
    """Weight of the frame mean of relu(clearance_ref - clearance_t) / clearance_ref."""
    w_jerk: float = 0.5
    """Weight of mean jerk / jerk_ref."""
    w_angular_rate: float = 0.5
    """Weight of mean view angular rate / angular_rate_ref."""
    w_duration: float = 0.2
    """Weight of duration / duration_ref."""
    target_fill: float = 0.3
    """Wanted projected object diameter as a fraction of the frame height."""
    fov_deg: float = DEFAULT_FOV_DEG
    """Vertical field of view of the camera, degrees (the exported camera's fov)."""
    clearance_ref: float = 0.1
    """Clearance (scene units) above which the clearance terms cost nothing."""
    jerk_ref: float = 5.0
    """Jerk scale, units/s^3."""
    angular_rate_ref: float = 30.0
    """View angular rate scale, deg/s."""
    duration_ref: float = 5.0
    """Duration scale, seconds."""
    occlusion_frames: int = 64
    """At most this many evenly spaced frames are tested for occlusion (0: all frames)."""
    visibility_frames: int = 8
    """With a subject: at most this many of those frames (evenly spaced, first and last included) get the visible
    fraction of the subject (0: all of them)."""
    clearance_cap: Optional[float] = 0.1
    """Exact clearance is searched up to this (larger counts as the cap); >= clearance_ref leaves every cost unchanged
    and skips most of the distance work. None: uncapped."""

    def validate(self) -> None:
        for k, v in self.__dict__.items():
            if k == "clearance_cap" and v is None:
                continue
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise InvalidInputError(f"ScoreConfig.{k} must be a finite number, got {v!r}.")
            if k.startswith("w_") and v < 0:
                raise InvalidInputError(f"ScoreConfig.{k} must be >= 0, got {v}.")
        for k in ("target_fill", "fov_deg", "clearance_ref", "jerk_ref", "angular_rate_ref", "duration_ref"):
            if getattr(self, k) <= 0:
                raise InvalidInputError(f"ScoreConfig.{k} must be > 0, got {getattr(self, k)}.")
        if self.fov_deg >= 180:
            raise InvalidInputError(f"ScoreConfig.fov_deg must be < 180, got {self.fov_deg}.")
        if self.clearance_cap is not None and self.clearance_cap <= 0:
            raise InvalidInputError(f"ScoreConfig.clearance_cap must be > 0 or None, got {self.clearance_cap}.")
        if self.visibility_frames < 0:
            raise InvalidInputError("ScoreConfig.visibility_frames must be >= 0.")
        if self.occlusion_frames < 0:
            raise InvalidInputError("ScoreConfig.occlusion_frames must be >= 0.")
