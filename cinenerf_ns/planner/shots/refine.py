"""Free space at the resolution the obstacles need: a go-to that is free but whose free space is not
connected to the start's at the grid's resolution is not given up at once. The leg is planned again on a finer
occupancy grid over a box around the start and the go-to (a local fine search: the rest of the region stays coarse),
and that shot is kept when it ends closer to the go-to than the coarse leg would.

The fine grid is built by the same conservative rasteriser (scene/occupancy.py: a free voxel keeps the camera ball
clear of every ellipsoid, never optimistic) over the same scene and spatial index, and the leg is planned by the same
stages (stages.plan_leg on a planning space whose region is the box), so every shot is still verified by the
exact clearance check before it is returned."""
from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import TYPE_CHECKING, Optional, Tuple

import numpy as np
import torch

from ..corridor.safe_corridor import CorridorError
from ..errors import GoalUnreachableError, InvalidInputError
from ..geometry.clearance_queries import clearance
from ..scene.occupancy import occupancy_columns
from ..scene.planning_region import distance_outside
from ..space import PlanningSpace

if TYPE_CHECKING:
    from .shot import Shot

REFINE_VOXEL_RADII = 2 / math.sqrt(3)
"""The fine voxel is at most this many camera radii (its half diagonal, by which the conservative occupancy inflates
the camera ball, is then at most one camera radius) ..."""
REFINE_MAX_FACTOR = 4
"""... and at least 1 / this of the coarse voxel ..."""
REFINE_MIN_FACTOR = 2
"""... and at most 1 / this of it; no refinement when that would exceed REFINE_MAX_VOXELS."""
REFINE_MAX_VOXELS = 300_000
"""Most voxels of the fine grid (its build and search are a request's: bounded)."""
REFINE_MAX_COLUMNS = 300_000
"""No refinement when the fine grid's build would rasterise more voxel columns than this (occupancy.occupancy_columns:
its work): a request stays bounded; the goal is then moved as before."""
REFINE_MARGIN = 0.1
"""The box around start and go-to grows by this x their distance on every side (room to go around an obstacle) ..."""
REFINE_MIN_MARGIN_VOXELS = 3
"""... and by at least this many coarse voxels."""


def refine_box(space: "PlanningSpace", start: np.ndarray, target: np.ndarray) -> Optional[Tuple[np.ndarray, np.ndarray,
                                                                                           int]]:
    """(lo [3], hi [3], grid resolution) of the fine grid for a leg start -> target ([3] each), inside the planning
    region; None when it would exceed REFINE_MAX_VOXELS or REFINE_MAX_COLUMNS."""
    rlo, rhi = space.region()
    vs = float(space.prepared.grid.voxel_size)
    margin = max(REFINE_MARGIN * float(np.linalg.norm(target - start)), REFINE_MIN_MARGIN_VOXELS * vs)
    lo = np.maximum(np.minimum(start, target) - margin, rlo)
    hi = np.minimum(np.maximum(start, target) + margin, rhi)
    side = hi - lo
    want = int(math.ceil(vs / (REFINE_VOXEL_RADII * float(space.scene.camera_radius)) - 1e-9))
    factor = min(max(want, REFINE_MIN_FACTOR), REFINE_MAX_FACTOR)
    fine = vs / factor
    if float(np.prod(np.ceil(side / fine))) > REFINE_MAX_VOXELS:
        return None
    res = max(8, int(math.ceil(float(side.max()) / fine)))
    # the fine grid rounds its box up to whole voxels: shift it back inside the planning region where it would leave
    grid_side = np.ceil(side / (float(side.max()) / res) - 1e-9) * (float(side.max()) / res)
    lo = np.maximum(rlo, np.minimum(lo, rhi - grid_side))
    hi = lo + side
    dev = space.scene.device
    bounds = tuple(torch.as_tensor(v, dtype=torch.float64, device=dev) for v in (lo, hi))
    # only Gaussians whose mean is within their largest possible reach of the box can have columns in it
    sc = space.scene
    grow = float(sc.radii.detach().max()) + float(sc.camera_radius) + math.sqrt(3) * fine
    m = sc.means.detach().double()
    near = torch.nonzero(((m >= bounds[0] - grow) & (m <= bounds[1] + grow)).all(1)).squeeze(-1)
    if near.numel() and occupancy_columns(sc.subset(near), res, bounds) > REFINE_MAX_COLUMNS:
        return None
    return lo, hi, res


def refined_space(space: "PlanningSpace", lo: np.ndarray, hi: np.ndarray, resolution: int) -> PlanningSpace:
    """A prepared planning space over [lo, hi] at ``resolution``: the same scene (the request's, e.g. the CPU mirror),
    its spatial index reused, the configuration otherwise the same (no workers, no further refinement)."""
    from .prepared_scene import prepare_scene

    cfg = replace(space.config, bounds=(lo, hi), bounds_rule="local refinement", grid_resolution=int(resolution),
                  candidate_workers=0, refine_disconnected=False)
    cfg.validate()
    dev = space.scene.device
    scene, prepared = prepare_scene(
        space.scene, int(resolution), torch.as_tensor(lo, dtype=torch.float64, device=dev),
        torch.as_tensor(hi, dtype=torch.float64, device=dev), mirror=False, index=space.prepared.index,
        light=True)
    return PlanningSpace(scene, space.scene, cfg, prepared)


REFINE_MIN_MISS_VOXELS = 5
"""Only a coarse goal at least this many coarse voxels from the go-to is refined: a nearer miss is mostly a go-to
inside an object's shell (a finer grid cannot reach it; trying costs a fine grid's build), and it stays reported."""
ENCLOSED_BEYOND_VOXELS = 2
"""enclosed(): each ray runs through the target's pocket, at least ENCLOSED_REACH_VOXELS coarse voxels or the distance
to the coarse goal when shorter, and this many coarse voxels beyond (through a wall) ..."""
ENCLOSED_REACH_VOXELS = 10
ENCLOSED_MAX_VOXELS = 64
"""... and at most this many coarse voxels in all."""


def _directions() -> np.ndarray:
    """The 26 unit directions to a voxel's neighbours [26, 3]."""
    d = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if i or j or k], float)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def enclosed(space: "PlanningSpace", target: np.ndarray, coarse_goal: np.ndarray) -> bool:
    """The target [3] is walled in for the camera (e.g. the free inside of a hollow object): each of 26 rays from it,
    run through its coarse pocket (the box of its free component, or its voxel when occupied), at least as far as
    the coarse goal [3] (at most ENCLOSED_REACH_VOXELS voxels) and ENCLOSED_BEYOND_VOXELS voxels beyond, certainly
    collides (reach.segments_proven_blocked: a sample inside the
    camera radius of an ellipsoid). A finer grid cannot connect such a target, so it is not refined. False whenever
    the proof does not apply (then refinement is tried)."""
    from scipy import ndimage

    from ..search.reach import segments_proven_blocked

    prep = space.prepared
    grid, labels = prep.grid, prep.astar_grid.labels
    vs = float(grid.voxel_size)
    lo = grid.lo.detach().cpu().double().numpy()
    tv = grid.voxel_of(target)
    lab = int(labels[tuple(tv)])
    if lab > 0:
        if prep.component_boxes is None:
            prep.component_boxes = ndimage.find_objects(labels)
        sl = prep.component_boxes[lab - 1]
        blo = lo + np.array([s.start for s in sl]) * vs
        bhi = lo + np.array([s.stop for s in sl]) * vs
    else:
        blo, bhi = lo + tv * vs, lo + (tv + 1) * vs
    d = _directions()
    with np.errstate(divide="ignore", invalid="ignore"):
        exit_t = np.where(d > 0, (bhi - target) / d, np.where(d < 0, (blo - target) / d, np.inf)).min(axis=1)
    reach = min(float(np.linalg.norm(coarse_goal - target)), ENCLOSED_REACH_VOXELS * vs)
    length = np.minimum(np.maximum(exit_t, reach) + ENCLOSED_BEYOND_VOXELS * vs, ENCLOSED_MAX_VOXELS * vs)
    ends = target + length[:, None] * d
    return bool(segments_proven_blocked(space, np.asarray(target, np.float64), ends).all())


def _free(space: "PlanningSpace", p: np.ndarray) -> bool:
    """Exact clearance of the camera centre p [3] >= 0 (the compiled distance capped at the camera radius: inside an
    ellipsoid is NaN, not measured; Planner.clearance where the compiled search does not apply)."""
    from ..geometry.distance import native_capped_distance
    from ..geometry.native_scene import native_applies
    from ..native import points_distance_c

    scene, index = space.scene, space.prepared.index
    r = float(scene.camera_radius)
    fn = points_distance_c() if native_applies(scene, index) else None
    if fn is None:
        return bool(clearance(space, p[None], cap=r)[0] >= 0.0)
    d = float(native_capped_distance(fn, torch.from_numpy(p[None].copy()), scene, index, r)[0])
    return not math.isnan(d) and d >= r


def needs_refinement(space: "PlanningSpace", goal_point: np.ndarray, target: np.ndarray, tol: float = 1e-6) -> bool:
    """The coarse leg would end at least REFINE_MIN_MISS_VOXELS coarse voxels away from ``target`` [3] although the
    target is in the planning region, free (exact clearance >= 0) and not walled in (enclosed): its free space is
    not connected to the start's at the grid's resolution."""
    if not space.config.refine_disconnected or float(np.linalg.norm(goal_point - target)) <= tol:
        return False
    if float(np.linalg.norm(goal_point - target)) < REFINE_MIN_MISS_VOXELS * float(space.prepared.grid.voxel_size):
        return False
    if distance_outside(*space.region(), target) > 0:
        return False
    target = np.asarray(target, dtype=np.float64)
    if not _free(space, target):
        return False
    return not enclosed(space, target, np.asarray(goal_point, dtype=np.float64))


def refined_leg(space: "PlanningSpace", start: np.ndarray, target: np.ndarray, look_at: np.ndarray,
                coarse_goal: np.ndarray) -> Optional["Shot"]:
    """The leg start -> target planned on a fine grid over refine_box (stages.plan_leg on refined_space: verified
    by the exact check), when it ends closer to ``target`` than ``coarse_goal`` [3]; else None. Its timings get
    refine_ms (the fine grid's build + the leg) and its ``refinement`` says where and how fine."""
    from . import stages

    box = refine_box(space, start, target)
    if box is None:
        return None
    lo, hi, res = box
    t0 = time.perf_counter()
    try:
        sub = refined_space(space, lo, hi, res)
        t1 = time.perf_counter()
        shot = stages.plan_leg(sub, start, target, look_at, {})
    except (GoalUnreachableError, CorridorError, InvalidInputError):
        return None
    if np.linalg.norm(shot.goal - target) >= np.linalg.norm(coarse_goal - target) - 0.5 * sub.prepared.grid.voxel_size:
        return None  # not closer by half a fine voxel: the coarse leg stays
    shot.timings["refine_grid_ms"] = 1e3 * (t1 - t0)
    shot.timings["refine_ms"] = 1e3 * (time.perf_counter() - t0)
    shot.refinement = {"lo": lo.tolist(), "hi": hi.tolist(), "voxel_size": float(sub.prepared.grid.voxel_size),
                       "coarse_voxel_size": float(space.prepared.grid.voxel_size),
                       "grid_shape": list(sub.prepared.grid.shape)}
    return shot
