"""Where shots start: a user-given start checked against the planning region and the scene, or random free starts
drawn in the free component the capture's cameras see (the start region's, or a closed room's interior).
Functions of a PlanningSpace (space.py)."""
from __future__ import annotations

from functools import partial
from typing import TYPE_CHECKING

import numpy as np
import torch
from torch import Tensor

from ..errors import InvalidInputError, StartInCollisionError
from ..geometry.clearance_queries import clearance, free_test, points_free
from ..scene.planning_region import distance_outside
from ..scene.user_box import format_point
from .goal import grid_arrays, sample_free_starts

if TYPE_CHECKING:
    from ..space import PlanningSpace, PreparedScene

ENCLOSED_COMPONENT_FRACTION = 0.2  # an enclosed free component this large is taken for the capture's room


def preferred_component(labels: np.ndarray, counts: np.ndarray) -> int:
    """Free component random starts come from when no start region is known. labels [X, Y, Z] (0 occupied), counts
    [K+1] free voxels per label (counts[0] = 0). A component that touches the grid's faces is the space around the
    scene; the largest one that does not (a closed room's interior) is preferred when it holds at least
    ENCLOSED_COMPONENT_FRACTION of all free voxels: a room captured from inside is enclosed by its walls, floor and
    ceiling, and the shell between them and the padded planning box can hold more voxels than the room (synthetic
    room 2: starts outside the walls, shots under the floor). Smaller enclosed pockets (inside hollow objects) are
    never preferred; an open scene has no large enclosed component and keeps the largest."""
    faces = [labels[0], labels[-1], labels[:, 0], labels[:, -1], labels[:, :, 0], labels[:, :, -1]]
    touching = np.unique(np.concatenate([f.ravel() for f in faces]))
    enclosed = counts.copy()
    enclosed[touching[touching < len(enclosed)]] = 0
    if enclosed.max() > 0 and enclosed.max() >= ENCLOSED_COMPONENT_FRACTION * counts.sum():
        return int(np.argmax(enclosed))
    return int(np.argmax(counts))


def start_component(prep: "PreparedScene", start_region) -> int:
    """The free component random starts come from: the one with the most free voxels inside ``start_region``
    ((lo [3], hi [3]) or None) when it holds any, else preferred_component's choice."""
    labels = prep.astar_grid.labels  # [X, Y, Z] 0: occupied, k >= 1: free component k
    if start_region is not None:
        grid = prep.grid
        lo, hi = (torch.as_tensor(np.asarray(v, dtype=np.float64), device=grid.device) for v in start_region)
        a = grid.world_to_voxel(lo).cpu().numpy().clip(0, np.array(grid.shape) - 1)
        b = grid.world_to_voxel(hi).cpu().numpy().clip(0, np.array(grid.shape) - 1)
        sub = labels[a[0] : b[0] + 1, a[1] : b[1] + 1, a[2] : b[2] + 1]
        counts = np.bincount(sub.ravel(), minlength=int(labels.max()) + 1)
        counts[0] = 0
        if counts.max() > 0:
            return int(np.argmax(counts))
    counts = np.bincount(labels.ravel())
    counts[0] = 0
    return preferred_component(labels, counts)


def main_component(space: "PlanningSpace") -> int:
    """start_component of the prepared planning space and config.start_region. Constant per prepared scene and
    start region: computed once (kept in PreparedScene.main_component_of), not per request."""
    prep = space.prepared
    region = space.config.start_region
    cached = prep.main_component_of
    if cached is not None and cached[0] is region:
        return cached[1]
    comp = start_component(prep, region)
    prep.main_component_of = (region, comp)
    return comp


def random_starts(space: "PlanningSpace", n: int, generator: torch.Generator, look_at: np.ndarray) -> Tensor:
    """n random collision-free starts [n, 3] (goal.sample_free_starts) as every request draws them: in
    config.start_region, in the main free component, config.start_look_distance away from ``look_at`` [3] where
    the region allows."""
    prep = space.prepared
    lo, hi = space.config.start_region or (None, None)
    return sample_free_starts(
        n, space.scene, prep.index, prep.grid, generator=generator, region_lo=lo, region_hi=hi,
        blocked=start_blocked(space), clearance_fn=partial(free_test, space),
        away_from=look_at, away_fraction=space.config.start_look_distance,
    )


def start_blocked(space: "PlanningSpace") -> np.ndarray:
    """bool [X, Y, Z]: voxels no random start may lie in (occupied, or outside the main free component). Constant per
    prepared scene and start region like main_component: computed once (PreparedScene.start_blocked_of), where two
    passes over the whole grid per request cost about half a millisecond on the CPU box."""
    prep = space.prepared
    comp = main_component(space)
    cached = prep.start_blocked_of
    if cached is not None and cached[0] is prep.astar_grid.labels and cached[1] == comp:
        return cached[2]
    occ, _, _ = grid_arrays(prep.grid)
    blocked = occ | (prep.astar_grid.labels != comp)
    prep.start_blocked_of = (prep.astar_grid.labels, comp, blocked)
    return blocked


def check_start_inside(space: "PlanningSpace", s: np.ndarray) -> None:
    """InvalidInputError when a user-given start [3] (float64) lies outside the planning region (Planner.checked_start
    grows the region instead when the start is forced)."""
    lo, hi = space.region()
    if distance_outside(lo, hi, s) > 0:
        raise InvalidInputError(
            f"the start point {format_point(s)} is outside the planning region {format_point(lo)}.."
            f"{format_point(hi)} (the training cameras' box grown by region_padding, or the scene's box); pick a "
            f"start inside it or force it (cinesplat-plan --force-start: the region then grows to hold the start)")


def check_start_free(space: "PlanningSpace", s: np.ndarray) -> np.ndarray:
    """A user-given start [3] (float64, in the planning region) returned as is, or StartInCollisionError when the
    camera would be inside the scene. Only the sign of the clearance is needed: a proof from the grid, else a capped
    distance."""
    if bool(points_free(space, s[None])[0]):
        return s
    c = float(clearance(space, s[None], cap=float(space.prepared.grid.voxel_size))[0])
    if c < 0:
        raise StartInCollisionError(
            f"the start {np.round(s, 4).tolist()} puts the camera inside the scene (clearance {c:.4f}); "
            f"pick another start or use a random start"
        )
    return s
