"""The planning region: the box the occupancy grid covers and every path stays in. Its bounds from the scene and the
configuration, the checks a region must pass before any expensive work, and user points checked against it.
Pure functions of a scene, a PlannerConfig and the region's corners (the Planner and the planning space call them)."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Optional, Sequence, Union

import numpy as np
import torch
from torch import Tensor

from ..config import REGION_RULES  # noqa: F401 (re-exported)
from ..errors import InvalidInputError
from .user_box import format_point, user_box

if TYPE_CHECKING:
    from ..config import PlannerConfig
    from ..trajectory.timing import TimingConfig
    from .ellipsoids import EllipsoidScene

ArrayLike = Union[Tensor, np.ndarray, Sequence[float]]

GRID_BYTES_PER_VOXEL = 80
"""Peak memory per grid voxel of prepare() + a plan (occupancy, components, distance transform, search workspaces),
rounded up from the measured peak (docs/PLANNER_DEFAULTS.md)."""

MAX_RADIUS_FRACTION = 0.1
"""The camera sphere's radius may be at most this fraction of the planning region's longest side."""


def as_point(x: ArrayLike, what: str) -> np.ndarray:
    """A user point [3] as float64; InvalidInputError naming ``what`` unless it is 3 finite numbers."""
    try:
        p = np.asarray(x.detach().cpu() if isinstance(x, Tensor) else x, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as e:
        raise InvalidInputError(f"{what} must be 3 numbers, got {x!r}") from e
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise InvalidInputError(f"{what} must be 3 finite numbers, got {p.tolist()}")
    return p


DENSE_BINS = 64
"""dense_content_box: histogram cells along the longest side of the means' robust box."""
DENSE_FLOOR = 0.05
"""dense_content_box: a cell is dense when its opacity mass is >= this x the mass-weighted mean cell mass (the density
where the opaque mass typically lies): far background shells, sky Gaussians and isolated floaters fall below it."""
DENSE_BRIDGE = 1
"""dense_content_box: dense cells up to 2 x this many empty cells apart belong to one group (parts of the content with
a small gap between them stay in; a background shell farther from the content does not: 2 already joined the grove's
far ring through its sparse outskirts)."""
DENSE_OUTER_QUANTILE = 0.001
"""dense_content_box bins the means inside their [q, 1 - q] quantile box (a few extreme outliers would otherwise make
the cells huge)."""


def _quantile_box(m: Tensor, q: float) -> tuple[Tensor, Tensor]:
    """(lo [3], hi [3]) the [q, 1 - q] per-axis quantiles of points m [N, 3] (min / max for q = 0 or N <= 1000)."""
    if len(m) > 1000 and q > 0:
        # torch.quantile has an input-size limit; a strided subsample is plenty for bounds
        sub = m[:: max(1, len(m) // 200_000)]
        return torch.quantile(sub, q, dim=0), torch.quantile(sub, 1 - q, dim=0)
    return m.min(0).values, m.max(0).values


def dense_content_box(means: Tensor, weights: Tensor, bins: int = DENSE_BINS,
                      floor: float = DENSE_FLOOR) -> tuple[np.ndarray, np.ndarray]:
    """(lo [3], hi [3]) float64: the box of the dense opaque content of points ``means`` [N, 3] with ``weights`` [N]
    (opacities). The means are binned (opacity-weighted) into cubic cells, ``bins`` along the longest side of their
    DENSE_OUTER_QUANTILE box; cells with mass >= ``floor`` x the mass-weighted mean cell mass are dense; the
    heaviest group of dense cells (26-connected, bridging gaps of DENSE_BRIDGE cells) is the connected core: a far
    background ring or dome, however heavy, is a group of its own. The box covers the core's cells."""
    from scipy import ndimage

    m = means.double()
    w = weights.double().reshape(-1)
    ok = torch.isfinite(m).all(1) & torch.isfinite(w) & (w > 0)
    m, w = m[ok], w[ok]
    if len(m) == 0:
        raise InvalidInputError("the scene has no finite Gaussian with positive opacity: no region to plan in")
    olo, ohi = _quantile_box(m, DENSE_OUTER_QUANTILE)
    side = (ohi - olo).clamp_min(1e-9)
    cell = float(side.max()) / bins
    dims = torch.clamp(torch.ceil(side / cell).long(), 1, bins)
    ijk = torch.floor((m - olo) / cell).long()
    inside = ((ijk >= 0) & (ijk < dims)).all(1)
    ijk, w = ijk[inside], w[inside]
    flat = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    mass = torch.bincount(flat, weights=w, minlength=int(dims.prod())).cpu().numpy()
    total = mass.sum()
    typical = float((mass * mass).sum() / total) if total > 0 else 0.0
    dense = (mass >= floor * typical) & (mass > 0)
    dense = dense.reshape(tuple(dims.tolist()))
    bridged = ndimage.binary_dilation(dense, np.ones((3, 3, 3), dtype=bool), iterations=DENSE_BRIDGE)
    labels, n = ndimage.label(bridged, structure=np.ones((3, 3, 3), dtype=bool))
    comp_mass = np.bincount(labels.reshape(-1), weights=mass, minlength=n + 1)
    comp_mass[0] = 0.0
    core = dense & (labels == int(np.argmax(comp_mass)))
    idx = np.argwhere(core)  # [K, 3]: at least the heaviest cell's group
    base = olo.cpu().numpy()
    return base + idx.min(0) * cell, base + (idx.max(0) + 1) * cell


DENSE_MIN_STRETCH = 1.5
"""The dense content's box replaces the robust box of all means only when the latter's longest side is at least this
many times the former's (far content stretches it: a background shell, sky) ..."""
DENSE_MIN_MASS = 0.5
"""... and the dense box holds at least this fraction of the opacity-weighted means (a sparse or evenly spread scene
has no dense core: its heaviest group of cells is a random few, and the robust box stays)."""


def dense_box_applies(robust_lo, robust_hi, dense_lo, dense_hi, means: Tensor, weights: Tensor) -> bool:
    """Whether the dense content's box is used instead of the robust box (DENSE_MIN_STRETCH, DENSE_MIN_MASS)."""
    r = float(np.max(np.asarray(robust_hi, dtype=np.float64) - np.asarray(robust_lo, dtype=np.float64)))
    d = float(np.max(np.asarray(dense_hi, dtype=np.float64) - np.asarray(dense_lo, dtype=np.float64)))
    if r < DENSE_MIN_STRETCH * d:
        return False
    m, w = means.double(), weights.double().reshape(-1)
    lo = torch.as_tensor(np.asarray(dense_lo, dtype=np.float64), device=m.device)
    hi = torch.as_tensor(np.asarray(dense_hi, dtype=np.float64), device=m.device)
    inside = ((m >= lo) & (m <= hi)).all(1)
    total = float(w.clamp_min(0).sum())
    return total > 0 and float(w[inside].clamp_min(0).sum()) >= DENSE_MIN_MASS * total


def region_rule(cfg: "PlannerConfig", scene: Optional["EllipsoidScene"] = None) -> str:
    """Which rule chooses the planning region under ``cfg`` (what the report and the CLI say): cfg.bounds_rule when
    bounds are given ('user box', ...), 'training cameras' with a start region, else 'dense content' when the far
    content stretches the robust box (dense_box_applies; needs ``scene``) or 'robust box of all means'."""
    if cfg.bounds is not None:
        return cfg.bounds_rule
    if cfg.start_region is not None:
        return "training cameras"
    if cfg.region_rule == "robust":
        return "robust box of all means"
    if scene is not None:
        m = scene.means.double()
        lo, hi = _quantile_box(m, cfg.robust_bounds_quantile)
        if not dense_box_applies(lo.cpu().numpy(), hi.cpu().numpy(), *dense_content_box(m, scene.opacities), m,
                                 scene.opacities):
            return "robust box of all means (no far content to leave out)"
    return "dense content"


MAX_USER_BOX_FACTOR = 10.0
"""A user box's longest side may be at most this many times the scene's (its Gaussian means' box)."""


def check_user_box(scene: "EllipsoidScene", lo: np.ndarray, hi: np.ndarray, what: str) -> None:
    """InvalidInputError when a user box misses the scene (no Gaussian mean in it or next to it) or is too thin
    for the camera (a side under 4 camera radii: no room to move)."""
    r = float(scene.camera_radius)
    thin = np.flatnonzero(hi - lo < 4 * r)
    if thin.size:
        raise InvalidInputError(
            f"{what} {format_point(lo)}..{format_point(hi)} is too small for the camera along "
            f"{', '.join('xyz'[i] for i in thin)}: each side must be at least 4 x (--camera-radius + --safety-margin) "
            f"= {4 * r:.4g} scene units")
    m = scene.means.detach()
    slo = m.min(0).values.double().cpu().numpy()
    shi = m.max(0).values.double().cpu().numpy()
    if (lo > shi).any() or (hi < slo).any():
        raise InvalidInputError(
            f"{what} {format_point(lo)}..{format_point(hi)} lies outside the scene, whose Gaussians span "
            f"{format_point(slo)}..{format_point(shi)} (scene units)")
    span = float(np.max(shi - slo))
    if float(np.max(hi - lo)) > MAX_USER_BOX_FACTOR * max(span, 4 * r):
        # the grid's voxels would be that much coarser than over the scene: nothing small would be free or seen
        raise InvalidInputError(
            f"{what} {format_point(lo)}..{format_point(hi)} is more than {MAX_USER_BOX_FACTOR:g} x larger than the "
            f"scene, whose Gaussians span {format_point(slo)}..{format_point(shi)} (longest side {span:.4g} scene "
            "units): give a box around the part of the scene to plan in")


def planning_bounds(scene: "EllipsoidScene", cfg: "PlannerConfig") -> tuple[Tensor, Tensor]:
    """(lo [3], hi [3]) float64 on the scene's device, by region_rule(cfg): config.bounds when given (checked:
    user_box, check_user_box); else with a start region (training cameras) the start region grown by
    config.region_padding, cut to the robust box of the means (config.robust_bounds_quantile, grown by 10% + the
    camera radius); else the dense content's box (dense_content_box, grown the same way) or, with region_rule
    'robust', the robust box."""
    dev = scene.device
    if cfg.bounds is not None:
        what = "the planning region (" + ("--region" if cfg.bounds_rule == "user box" else cfg.bounds_rule) + ")"
        blo, bhi = user_box(cfg.bounds, what)
        check_user_box(scene, blo, bhi, what)
        return (torch.as_tensor(blo, dtype=torch.float64, device=dev),
                torch.as_tensor(bhi, dtype=torch.float64, device=dev))
    m = scene.means.double()  # [N, 3]
    q = cfg.robust_bounds_quantile
    lo, hi = _quantile_box(m, q)
    if cfg.start_region is None and cfg.region_rule != "robust":
        dlo, dhi = dense_content_box(m, scene.opacities)
        if dense_box_applies(lo.cpu().numpy(), hi.cpu().numpy(), dlo, dhi, m, scene.opacities):
            lo = torch.as_tensor(dlo, dtype=torch.float64, device=dev)
            hi = torch.as_tensor(dhi, dtype=torch.float64, device=dev)
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


def starts_within(start_region, lo: np.ndarray, hi: np.ndarray) -> Optional[tuple]:
    """The start region (where random starts are drawn: the training cameras' box) cut to a given planning region [lo,
    hi]: their intersection, or None (starts anywhere in the region) when a user's box leaves the cameras out (no
    random start could be drawn otherwise)."""
    if start_region is None:
        return None
    slo, shi = (np.asarray(v, dtype=np.float64).reshape(3) for v in start_region)
    ilo = np.maximum(slo, np.asarray(lo, dtype=np.float64))
    ihi = np.minimum(shi, np.asarray(hi, dtype=np.float64))
    return (ilo, ihi) if (ihi > ilo).all() else None


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


AUTO_RESOLUTION_MAX = 192
"""PlannerConfig.max_voxel_radii raises the grid resolution up to this many voxels along the longest side (192^3 / 2 is
about 3.5M voxels, prepared in seconds)."""


def grid_resolution_for(cfg: "PlannerConfig", camera_radius: float, lo: np.ndarray, hi: np.ndarray) -> int:
    """The voxels along the longest side of [lo, hi] a planner prepares: cfg.grid_resolution, raised while a voxel
    would be longer than cfg.max_voxel_radii camera radii, up to AUTO_RESOLUTION_MAX and what cfg.memory_budget_mb
    holds (the raise is cut, never refused: check_region refuses only the grid_resolution asked for)."""
    res = int(cfg.grid_resolution)
    if cfg.max_voxel_radii is None or not camera_radius > 0:
        return res
    side = np.asarray(hi, dtype=np.float64) - np.asarray(lo, dtype=np.float64)
    longest = float(side.max())
    want = min(AUTO_RESOLUTION_MAX, int(math.ceil(longest / (float(cfg.max_voxel_radii) * float(camera_radius)))))
    if want <= res:
        return res
    def n_voxels(w: int) -> float:
        return float(np.prod(np.ceil(side / (longest / w))))

    budget_voxels = float(cfg.memory_budget_mb) * 2**20 / GRID_BYTES_PER_VOXEL
    if n_voxels(want) > budget_voxels:
        want = int(want * (budget_voxels / n_voxels(want)) ** (1 / 3))
        while want > res and n_voxels(want) > budget_voxels:  # the cube root ignores the sides' rounding up
            want -= 1
    return max(res, want)


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
