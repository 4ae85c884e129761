"""A documented, configurable score of one shot (lower cost = better shot).

Terms (each reported raw in ``ShotScore.to_dict()``, and weighted in ``costs``):
  occluded_fraction   with a subject (its Gaussians, geometry/visibility.py): the fraction of visibility frames
                      in which less than half of the subject is seen through the splat (alpha-composited
                      transmittance to samples of its Gaussians, relative to the subject rendered alone); also
                      visible_mean (mean visible fraction), visible_last (the last frame's) and frames_visible_half
                      (1 - occluded_fraction). Without one: the fraction of evaluated frames (x target samples)
                      whose sight line to the look-at point is blocked by a scene ellipsoid (occlusion.py; exact
                      count); visible_last is then 0 or 1.
                      cost = w_occlusion * occluded_fraction + w_last_visibility * (1 - visible_last).
  framing_size_error  |log(fill / target_fill)| averaged over frames, fill = projected diameter of the
                      look-at object / frame height = 2 atan(object_radius / distance) / fov.
  framing_offset      mean angle between the view axis and the direction to the object's centre,
                      in units of the half field of view (0 = centred, 1 = at the frame edge).
  min_clearance       smallest exact clearance over the frames (camera radius included; values above
                      ScoreConfig.clearance_cap count as the cap);
                      cost = relu(clearance_ref - min_clearance) / clearance_ref.
  mean_clearance      mean exact clearance (reported); cost = mean over frames of
                      relu(clearance_ref - clearance_t) / clearance_ref (time spent close to obstacles).
  max_jerk, mean_jerk finite-difference jerk of the frame positions (units/s^3); cost = mean_jerk / jerk_ref.
  max_angular_rate_deg, mean_angular_rate_deg   turn rate of the view direction (deg/s);
                      cost = mean_angular_rate / angular_rate_ref.
  duration_s          cost = duration / duration_ref.

    total = sum_k weight_k * cost_k          (ShotScore.total; candidates are ranked by it, ascending)

Occlusion frames: at most ``occlusion_frames`` evenly spaced frames are tested (first and last included),
so the cost per shot is bounded on long shots; set it to 0 to test every frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Dict, Optional

import numpy as np
import torch

from ..errors import InvalidInputError
from ..geometry.occlusion import sight_lines_blocked
from ..scene.ellipsoids import EllipsoidScene
from ..trajectory.dynamics import frame_peaks, view_vectors
from .score_config import ScoreConfig


@dataclass
class ShotScore:
    """Every score term of one shot, the weighted costs and their sum (lower is better)."""

    terms: Dict[str, float]
    costs: Dict[str, float]
    total: float
    occluded_frames: Optional[np.ndarray] = field(default=None, repr=False)  # [T'] bool per tested frame
    tested_frame_index: Optional[np.ndarray] = field(default=None, repr=False)  # [T'] frame indices tested
    visibility: Optional[np.ndarray] = field(default=None, repr=False)  # [T_v] visible fraction of the subject
    visibility_frame_index: Optional[np.ndarray] = field(default=None, repr=False)  # [T_v] their frame indices

    def to_dict(self) -> Dict[str, Any]:
        return {"total": float(self.total), "terms": {k: float(v) for k, v in self.terms.items()},
                "costs": {k: float(v) for k, v in self.costs.items()}}


def scored_frames(num: int, cap: int) -> np.ndarray:
    """Indices [T'] of the frames a score tests among ``num``: all of them, or ``cap`` evenly spaced ones (first and
    last included) when there are more (ScoreConfig.occlusion_frames; cap <= 0: all)."""
    if cap <= 0 or num <= cap:
        return np.arange(num)
    return np.unique(np.round(np.linspace(0, num - 1, cap)).astype(np.int64))


def score_terms(shot, look_at: np.ndarray, occluded: np.ndarray, clearance: np.ndarray, object_radius: float,
                object_center: Optional[np.ndarray], config: ScoreConfig,
                visibility: Optional[np.ndarray] = None) -> ShotScore:
    """Combine precomputed per-frame quantities into a ShotScore (used by score_shot and the batched
    candidate scorer, so both give identical numbers). occluded [T', S] bool, clearance [T]; visibility [T_v]: the
    subject's visible fraction on the visibility frames (last frame last), which then decides occlusion."""
    pos = shot.positions
    centre = look_at if object_center is None else np.asarray(object_center, np.float64)
    dist = np.maximum(np.linalg.norm(centre[None] - pos, axis=1), 1e-9)  # [T]
    fov = math.radians(config.fov_deg)
    fill = 2 * np.arctan(max(object_radius, 1e-9) / dist) / fov
    size_err = float(np.mean(np.abs(np.log(fill / config.target_fill))))
    view = -shot.rotations[:, :, 2]
    to_c = (centre[None] - pos) / dist[:, None]
    off = np.arctan2(np.linalg.norm(np.cross(view, to_c), axis=1), (view * to_c).sum(1)) / (0.5 * fov)
    pk = frame_peaks(pos, shot.times, view_vectors(pos, look_at))
    occ = float(np.mean(occluded)) if occluded.size else 0.0
    if visibility is not None and len(visibility):
        vis = np.asarray(visibility, np.float64)
        occ = float(np.mean(vis < 0.5))
        last = float(vis[-1])
    else:
        last = 0.0 if occluded.size and bool(np.any(occluded[-1])) else 1.0
    if config.clearance_cap is not None:
        clearance = np.minimum(clearance, config.clearance_cap)
    terms = {
        "occluded_fraction": occ,
        "framing_fill_mean": float(np.mean(fill)),
        "framing_size_error": size_err,
        "framing_offset": float(np.mean(off)),
        "min_clearance": float(np.min(clearance)),
        "mean_clearance": float(np.mean(clearance)),
        "max_jerk": pk.jerk,
        "mean_jerk": pk.mean_jerk,
        "max_angular_rate_deg": pk.angular_rate_deg,
        "mean_angular_rate_deg": pk.mean_angular_rate_deg,
        "duration_s": float(shot.duration),
        "visible_last": last,
    }
    if visibility is not None and len(visibility):
        terms["visible_mean"] = float(np.mean(visibility))
        terms["frames_visible_half"] = 1.0 - occ
    c = config
    costs = {
        "occlusion": c.w_occlusion * occ,
        "last_visibility": c.w_last_visibility * (1.0 - last),
        "framing_size": c.w_framing_size * size_err,
        "framing_offset": c.w_framing_offset * terms["framing_offset"],
        "min_clearance": c.w_min_clearance * max(0.0, c.clearance_ref - terms["min_clearance"]) / c.clearance_ref,
        "mean_clearance": (c.w_mean_clearance * float(np.mean(np.maximum(0.0, c.clearance_ref - clearance)))
                           / c.clearance_ref),
        "jerk": c.w_jerk * pk.mean_jerk / c.jerk_ref,
        "angular_rate": c.w_angular_rate * pk.mean_angular_rate_deg / c.angular_rate_ref,
        "duration": c.w_duration * terms["duration_s"] / c.duration_ref,
    }
    occ_frames = occluded.any(-1) if occluded.ndim == 2 else occluded
    return ShotScore(terms, costs, float(sum(costs.values())), occ_frames)


def score_shot(
    shot,
    scene: EllipsoidScene,
    look_at: Any,
    config: Optional[ScoreConfig] = None,
    index=None,
    object_radius: float = 0.1,
    object_center: Optional[Any] = None,
    object_samples: Optional[Any] = None,
    exclude: Optional[torch.Tensor] = None,
    clearance_fn=None,
) -> ShotScore:
    """Score one shot (see the module docstring).

    look_at [3]: the point the frames aim at. object_radius: bounding-sphere radius of the look-at object
    (framing size, and the sight lines stop at that sphere so the object does not hide itself).
    object_center [3]: the object's centre for framing (default look_at). object_samples [S, 3]: extra
    target points of the object for occlusion (default: look_at only). exclude [N] bool: Gaussians that
    never occlude (the object's own). clearance_fn(points [P,3]) -> [P]: exact clearance (default
    distance.clearance with ``index``); the shot's own ``clearance`` is used when present.
    """
    cfg = config or ScoreConfig()
    cfg.validate()
    look = np.asarray(look_at, np.float64).reshape(-1)
    if look.shape != (3,) or not np.all(np.isfinite(look)):
        raise InvalidInputError(f"look_at must be 3 finite numbers, got {look.tolist()}.")
    if not (math.isfinite(object_radius) and object_radius >= 0):
        raise InvalidInputError(f"object_radius must be finite and >= 0, got {object_radius}.")
    from ..scene.spatial_index import GridIndex

    index = index if index is not None else GridIndex.build(scene)
    targets = look[None] if object_samples is None else np.asarray(object_samples, np.float64).reshape(-1, 3)
    idx = scored_frames(shot.num_frames, cfg.occlusion_frames)
    occ = sight_lines_blocked(shot.positions[idx], targets, scene, index, exclude=exclude,
                              stop_distance=object_radius).cpu().numpy()
    if shot.clearance is not None:
        clr = shot.clearance
    elif clearance_fn is not None:
        clr = np.asarray(clearance_fn(shot.positions), np.float64).reshape(-1)
    else:
        from ..geometry.distance import clearance

        cap = None if cfg.clearance_cap is None else cfg.clearance_cap + scene.camera_radius
        clr = clearance(torch.as_tensor(shot.positions, device=scene.device), scene, index,
                        max_distance=cap).cpu().numpy()
    out = score_terms(shot, look, occ, clr, object_radius, object_center, cfg)
    out.tested_frame_index = idx
    return out
