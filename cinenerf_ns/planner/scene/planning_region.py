"""The planning region: the box the occupancy grid covers and every path stays in. Its bounds from the scene and the
configuration, the checks a region must pass before any expensive work, and user points checked against it.
Pure functions of a scene, a PlannerConfig and the region's corners (Planner delegates to them)."""
from __future__ import annotations

from typing import TYPE_CHECKING, Sequence, Union

import numpy as np
import torch
from torch import Tensor

from ..errors import InvalidInputError

if TYPE_CHECKING:
    from ..shots.planner import PlannerConfig
    from ..trajectory.timing import TimingConfig
    from .ellipsoids import EllipsoidScene

ArrayLike = Union[Tensor, np.ndarray, Sequence[float]]

GRID_BYTES_PER_VOXEL = 80
"""Peak memory per grid voxel of prepare() + a plan (occupancy, components, distance transform, search workspaces),
rounded up from the measured peak (docs/PLANNER_DEFAULTS.md)."""

MAX_RADIUS_FRACTION = 0.1
"""The camera sphere's radius may be at most this fraction of the planning region's longest side."""


def format_point(p: np.ndarray) -> str:
    """A point for an error message: "(x, y, z)" with 3 significant digits."""
    return "(" + ", ".join(f"{v:.3g}" for v in np.asarray(p, dtype=np.float64).reshape(-1)) + ")"


def as_point(x: ArrayLike, what: str) -> np.ndarray:
    """A user point [3] as float64; InvalidInputError naming ``what`` unless it is 3 finite numbers."""
    try:
        p = np.asarray(x.detach().cpu() if isinstance(x, Tensor) else x, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as e:
        raise InvalidInputError(f"{what} must be 3 numbers, got {x!r}") from e
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise InvalidInputError(f"{what} must be 3 finite numbers, got {p.tolist()}")
    return p


def planning_bounds(scene: "EllipsoidScene", cfg: "PlannerConfig") -> tuple[Tensor, Tensor]:
    """(lo [3], hi [3]) float64 on the scene's device: config.bounds when given, else the robust box of the Gaussian
    means (config.robust_bounds_quantile, grown by 10% + the camera radius), cut to the start region grown by
    config.region_padding when there is one (a capture's cameras: the region that matters)."""
    dev = scene.device
    if cfg.bounds is not None:
        lo = torch.as_tensor(cfg.bounds[0], dtype=torch.float64, device=dev).reshape(3)
        hi = torch.as_tensor(cfg.bounds[1], dtype=torch.float64, device=dev).reshape(3)
        if not (torch.isfinite(lo).all() and torch.isfinite(hi).all() and (hi > lo).all()):
            raise InvalidInputError(f"planning bounds need finite lo < hi, got {lo.tolist()}, {hi.tolist()}")
        return lo, hi
    m = scene.means.double()  # [N, 3]
    q = cfg.robust_bounds_quantile
    if len(scene) > 1000 and q > 0:
        # torch.quantile has an input-size limit; a strided subsample is plenty for bounds
        sub = m[:: max(1, len(m) // 200_000)]
        lo = torch.quantile(sub, q, dim=0)
        hi = torch.quantile(sub, 1 - q, dim=0)
    else:
        lo, hi = m.min(0).values, m.max(0).values
    pad = 0.1 * (hi - lo).max() + scene.camera_radius
    lo, hi = lo - pad, hi + pad
    if cfg.start_region is not None:  # the capture's cameras: the region that matters
        slo, shi = (torch.as_tensor(np.asarray(v, dtype=np.float64), device=dev).reshape(3) for v in cfg.start_region)
        check_start_region(slo.cpu().numpy(), shi.cpu().numpy())
        grow = cfg.region_padding * float((shi - slo).max())
        inner = scene.camera_radius + 1e-6  # the start region itself always fits
        lo = torch.minimum(torch.maximum(lo, slo - grow), slo - inner)
        hi = torch.maximum(torch.minimum(hi, shi + grow), shi + inner)
    return lo, hi


def check_start_region(lo: np.ndarray, hi: np.ndarray) -> None:
    """InvalidInputError naming the cause when a start region (the training cameras' box) is not finite or is
    inverted (lo above hi on an axis): the planning region cut to it would be empty."""
    lo, hi = np.asarray(lo, dtype=np.float64).reshape(-1), np.asarray(hi, dtype=np.float64).reshape(-1)
    if lo.shape != (3,) or hi.shape != (3,) or not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        raise InvalidInputError(f"the start region (the training cameras' box) must be two finite points (lo, hi), "
                                f"got {lo.tolist()}, {hi.tolist()}")
    bad = np.flatnonzero(lo > hi)
    if bad.size:
        axes = ", ".join("xyz"[i] for i in bad)
        raise InvalidInputError(f"the start region (the training cameras' box) is inverted along {axes}: lo "
                                f"{format_point(lo)} is above hi {format_point(hi)} there (a damaged scene file?)")


def check_region(cfg: "PlannerConfig", camera_radius: float, lo: np.ndarray, hi: np.ndarray) -> None:
    """InvalidInputError when the camera sphere is too large for the planning region [lo, hi] or the voxel grid
    would not fit config.memory_budget_mb (both named by their options, with the allowed range)."""
    side = np.asarray(hi, dtype=np.float64) - np.asarray(lo, dtype=np.float64)
    longest = float(side.max())
    r = float(camera_radius)
    if r > MAX_RADIUS_FRACTION * longest:
        raise InvalidInputError(
            f"the camera sphere (--camera-radius + --safety-margin = {r:.4g}) is too large for this scene: its "
            f"radius may be at most {MAX_RADIUS_FRACTION:g} x the planning region's longest side "
            f"({longest:.4g} scene units), i.e. <= {MAX_RADIUS_FRACTION * longest:.4g}")
    res = int(cfg.grid_resolution)
    voxels = float(np.prod(np.ceil(side / (longest / res))))
    need = voxels * GRID_BYTES_PER_VOXEL / 2**20
    budget = float(cfg.memory_budget_mb)
    if need > budget:
        fits = int(res * (budget / need) ** (1 / 3))
        raise InvalidInputError(
            f"--grid-resolution {res} needs about {need:.0f} MB for its voxel grid ({voxels:.3g} voxels), more "
            f"than the memory budget {budget:g} MB (--memory-budget-mb); at most {fits} fits")


def check_timing(t: "TimingConfig", lo: np.ndarray, hi: np.ndarray) -> None:
    """InvalidInputError when a shot across the planning region [lo, hi] (its diagonal at t.max_speed) would need
    more than t.max_frames frames: refused before planning, not when the frames are made."""
    diag = float(np.linalg.norm(hi - lo))
    frames = diag / t.max_speed * t.fps
    if frames > t.max_frames:
        need = diag * t.fps / t.max_frames
        raise InvalidInputError(
            f"--max-speed {t.max_speed:g} is too slow for --fps {t.fps:g}: crossing the planning region "
            f"({diag:.3g} scene units) would take {frames:.3g} frames, more than max_frames {t.max_frames}; "
            f"use --max-speed >= {need:.3g} or a lower --fps")


def grid_region(grid) -> tuple[np.ndarray, np.ndarray]:
    """(lo [3], hi [3]) float64: the box an occupancy grid covers (the prepared planning region)."""
    lo = grid.lo.detach().cpu().double().numpy()
    return lo, lo + np.array(grid.shape, dtype=np.float64) * float(grid.voxel_size)


def distance_outside(lo: np.ndarray, hi: np.ndarray, point: np.ndarray) -> float:
    """Euclidean distance [scene units] from a point [3] to the box [lo, hi] (0 inside)."""
    d = np.maximum(np.maximum(lo - point, point - hi), 0.0)
    big = float(np.abs(d).max()) if d.size else 0.0
    return 0.0 if big == 0.0 else big * float(np.linalg.norm(d / big))  # scaled: 1e300 away is no overflow warning


def checked_point(point: ArrayLike, what: str, lo: np.ndarray, hi: np.ndarray, far_limit: float) -> np.ndarray:
    """A user point [3] as float64: finite and within ``far_limit`` region sizes of the region [lo, hi], else
    InvalidInputError naming ``what`` and the allowed range."""
    p = as_point(point, what)
    limit = far_limit * float((hi - lo).max())
    d = distance_outside(lo, hi, p)
    if d > limit:
        raise InvalidInputError(
            f"the {what} {format_point(p)} is {d:.3g} units outside the planning region {format_point(lo)}.."
            f"{format_point(hi)}; points must lie within {limit:.3g} units of it (scene units: a run's normalised "
            f"coordinates)")
    return p
