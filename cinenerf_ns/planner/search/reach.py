"""Where a shot ends: the closest safe point to the go-to target that the start's free component reaches (paper:
closest safe point; here also when the target is walled in or outside the planning region), and the free voxels the
voxel path starts and ends in. Functions of a PlanningSpace (space.py)."""
from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING, Optional

import numpy as np
import torch
from torch import Tensor

from ..corridor.polytope import Polytope, aabb_polytope
from ..errors import GoalUnreachableError, PlanningError
from ..geometry.clearance_queries import free_test, points_free
from ..geometry.collision import segments_collide
from ..geometry.ranges import group_ranks
from ..scene.planning_region import distance_outside
from .goal import ComponentMask, closest_safe_point
from .projection import project_onto_polytope
from .shortcut import segments_free

if TYPE_CHECKING:
    from ..space import PlanningSpace

GOAL_FIRST_BOX_VOXELS = 2.0  # half-width of the goal's first polytope box (reachable_goal, step 2)


@dataclass
class ReachableGoal:
    """Where a shot ends: ``point`` [3] (the closest safe point to the go-to target that the component reaches),
    ``voxel`` [3] (the free voxel the voxel path ends in) and, when the point came from projecting the target onto
    a safe polytope seeded at that voxel's centre, that ``polytope`` (it holds the centre and the point).

    With a polytope the way ends ... -> voxel centre -> point: the shortcut runs up to the voxel centre only, and
    the last segment, inside the polytope, needs no corridor polytope of its own (``known()``). Without one the
    shortcut may join any waypoint to the point, as before."""

    point: np.ndarray
    voxel: np.ndarray
    polytope: Optional[Polytope] = None

    def way_to_shortcut(self, start: np.ndarray, centres: np.ndarray) -> np.ndarray:
        """The polyline [K, 3] the shortcut prunes: start, the voxel path's centres, and the point unless the last
        segment is fixed (then the path ends at the goal voxel's centre; shortcut_ends appends the point)."""
        tail = [] if self.polytope is not None else [self.point[None]]
        return np.concatenate([start[None], centres] + tail)

    def shortcut_ends(self, way: np.ndarray) -> np.ndarray:
        """The shortcut polyline completed with the point where way_to_shortcut left it out."""
        return way if self.polytope is None else np.concatenate([way, self.point[None]])

    def known(self) -> list:
        """Safe polytopes the corridor may reuse for any segment they contain (build_corridor's ``known``)."""
        return [] if self.polytope is None else [self.polytope]


def free_voxel_near(space: "PlanningSpace", p: np.ndarray, comp: Optional[int], max_window: int = 16) -> np.ndarray:
    """Voxel [3] near world point p whose centre joins p by a collision-free segment (and lies in
    free component ``comp`` when given), searched within ``max_window`` voxels."""
    prep = space.prepared
    grid, labels = prep.grid, prep.astar_grid.labels
    ijk = grid.voxel_of(p)  # [3] int64
    shape = np.array(grid.shape)
    if ((ijk >= 0) & (ijk < shape)).all():
        i, j, k = (int(v) for v in ijk)
        if labels[i, j, k] > 0 and (comp is None or labels[i, j, k] == comp):
            return np.array([i, j, k])
    # search growing windows for free voxels, nearest first, whose segment from p is free
    pt = torch.as_tensor(p, dtype=torch.float64, device=grid.device)
    c = np.clip(ijk, 0, shape - 1)
    for R in (r for r in (1, 2, 4, 8, 16) if r <= max_window):
        a = np.maximum(c - R, 0)
        e = np.minimum(c + R + 1, shape)
        sub = labels[a[0]:e[0], a[1]:e[1], a[2]:e[2]]
        ok = sub > 0 if comp is None else sub == comp
        cand = np.argwhere(ok) + a
        if len(cand) == 0:
            continue
        centres = grid.voxel_to_world(torch.as_tensor(cand, device=grid.device))
        order = torch.argsort((centres - pt).norm(dim=-1))[:64]
        for lo_, hi_ in ((0, 8), (8, 64)):  # the nearest few usually succeed: test them alone first
            cen = centres[order[lo_:hi_]]
            if cen.shape[0] == 0:
                break
            k = _first_free_segment(space, pt, cen)
            if k is not None:
                return cand[int(order[lo_ + k])]
    raise GoalUnreachableError(
        f"no free grid voxel can be reached in a straight line from {np.round(p, 4).tolist()}; the point is "
        f"walled in at this grid resolution (raise --grid-resolution)"
    )


BLOCKED_PROOF_SPACING = 0.5
"""segments_proven_blocked: sample spacing along a segment, in camera radii."""


def segments_proven_blocked(space: "PlanningSpace", p: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """bool [K]: segment p -> ends[k] ([K, 3] float64) certainly collides: a sample point on it lies inside an
    ellipsoid or closer than the camera radius to one (the compiled exact distance, capped at the radius; a margin
    of 1e-9 relative keeps rounding out of the proof). All False where the compiled search does not apply."""
    from ..geometry.distance import native_capped_distance
    from ..geometry.native_scene import native_applies
    from ..native import points_distance_c

    scene, index = space.scene, space.prepared.index
    out = np.zeros(len(ends), dtype=bool)
    fn = points_distance_c() if native_applies(scene, index) else None
    if fn is None or not len(ends):
        return out
    r = float(scene.camera_radius)
    n = np.maximum(1, np.ceil(np.linalg.norm(ends - p, axis=1) / (BLOCKED_PROOF_SPACING * r)).astype(np.int64))
    owner, k = group_ranks(n)
    pts = p + ((k + 1) / n[owner])[:, None] * (ends[owner] - p)  # (k + 1) / n: the far end included, p not
    d = native_capped_distance(fn, torch.from_numpy(pts), scene, index, r).numpy()
    np.logical_or.at(out, owner, np.isnan(d) | (d < r * (1 - 1e-9)))  # NaN: inside an ellipsoid
    return out


def _first_free_segment(space: "PlanningSpace", p: Tensor, ends: Tensor) -> Optional[int]:
    """Index of the first segment p -> ends[k] ([K, 3], float64) that the swept-capsule test
    (collision.segments_collide) proves collision-free, or None; the same answer as that test on all K, cheaper.

    Two cheap tests bound its work: the conservative proof of shortcut.segments_free (the occupancy grid's voxel
    walk, then the compiled point tests of short pieces) accepts a segment (that one is returned when the capsule
    test accepts none before it: both are conservative, so it is collision-free either way), and a sample inside
    the camera radius of an ellipsoid rejects one for certain (segments_proven_blocked: the capsule test could
    not accept it either). The capsule test, a Python query of every segment's box, runs only on the segments
    before the first accepted one that are not rejected."""
    ends_np = ends.detach().cpu().numpy()
    p_np = p.detach().cpu().numpy()
    proven = np.flatnonzero(segments_free(space, np.broadcast_to(p_np, ends_np.shape), ends_np))
    first = int(proven[0]) if proven.size else ends.shape[0]
    todo = np.flatnonzero(~segments_proven_blocked(space, p_np, ends_np[:first]))
    if todo.size:
        # float64 ends (the test runs in float64): rounding them to a float32 scene's dtype
        # could move a segment by ~1e-7, more than the collision margin covers
        head = ends[torch.as_tensor(todo, device=ends.device)]
        coll = segments_collide(p.expand_as(head), head, space.scene, space.prepared.index)
        free = torch.nonzero(~coll).squeeze(-1)
        if free.numel():
            return int(todo[int(free[0])])
    return first if proven.size else None


def reachable_goal(space: "PlanningSpace", target: np.ndarray, comp: int) -> "ReachableGoal":
    """Closest safe point to ``target`` that the free component ``comp`` reaches, its voxel, and (step 2) the
    safe polytope it was projected onto, which also holds the voxel's centre: the way's last segment, voxel
    centre -> goal, lies in it, so the corridor reuses it instead of building one (see ReachableGoal).

    1. paper: closest_safe_point (target itself if free, else the projection of the target onto a
       Prop-2 polytope grown at the target, else the nearest free voxel); accepted if a free voxel
       of ``comp`` joins it by a straight collision-free segment.
    2. otherwise (e.g. the centroid of a hollow object is free but walled in): the nearest voxel of
       ``comp`` to the target, improved by projecting the target onto a safe polytope seeded at
       that voxel's centre; the polytope is convex and holds the centre, so the segment between
       them is safe and the goal stays reachable.
    """
    prep = space.prepared
    grid, labels = prep.grid, prep.astar_grid.labels
    rlo, rhi = space.region()
    half_voxel = 0.5 * float(grid.voxel_size)
    target = np.clip(target, rlo + half_voxel, rhi - half_voxel)  # paths never leave the planning region
    tv = grid.voxel_of(target)  # [3]
    inside = bool(((tv >= 0) & (tv < np.array(grid.shape))).all())
    # target in an occupied voxel or a free pocket of another component (e.g. inside a hollow
    # object): a straight way out is only looked for next to it (a wider search almost always
    # fails through the object's wall, at ~0.2 s on 200k Gaussians); the nearest voxel of
    # ``comp`` (step 2) is the usual answer
    walled_in = inside and labels[tuple(tv)] != comp
    try:
        g = closest_safe_point(
            target, space.scene, prep.index, grid, reachable=ComponentMask(labels, comp),
            clearance_fn=partial(free_test, space), mean_voxels=prep.mean_voxels,
        )
        g = g.detach().cpu().numpy()
        return ReachableGoal(g, free_voxel_near(space, g, comp, max_window=2 if walled_in else 16))
    except GoalUnreachableError:
        pass
    ijk = nearest_component_voxel(space, target, comp)  # [3] int64
    c_np = grid.centre_of(ijk)  # [3] float64
    vs = float(grid.voxel_size)
    full = np.maximum(np.abs(target - c_np), vs) + vs  # [3] half-widths of the box that reaches the target
    # First a box of GOAL_FIRST_BOX_VOXELS voxels around c: the goal is usually within a voxel or two of it (c is
    # the free voxel nearest to the target), and a smaller box gathers fewer ellipsoids (faster, the same goals:
    # docs/PLANNER_DEFAULTS.md). Only when the projection
    # ends on a face of that box, where the larger box could let it go further, is the polytope built again in
    # the full box. Every plane is safe either way; the full box's extra planes can only cut more.
    x = poly = None
    for half in (np.minimum(full, GOAL_FIRST_BOX_VOXELS * vs), full):
        try:
            blo = np.maximum(c_np - half, rlo)  # the box stays in the planning region
            bhi = np.minimum(c_np + half, rhi)
            poly = aabb_polytope(c_np[None], space.scene, prep.index, blo, bhi)
            A, b = poly.to_numpy()
            x = project_onto_polytope(A, b, target, interior=c_np)  # the seed: inside
        except PlanningError:
            x = None
        on_face = x is not None and bool((np.abs(np.abs(x - c_np) - half) <= 1e-9 * (1 + np.abs(x).max())).any())
        if x is None or not on_face or (half >= full).all():
            break
    if x is None:
        return ReachableGoal(c_np, ijk)
    return ReachableGoal(x, ijk, poly)


def nearest_component_voxel(space: "PlanningSpace", target: np.ndarray, comp: int) -> np.ndarray:
    """Voxel [3] of free component ``comp`` whose centre is nearest to world point ``target``
    (growing windows; exact: a voxel outside a window of radius R is more than R voxels away)."""
    prep = space.prepared
    grid, labels = prep.grid, prep.astar_grid.labels
    shape = np.array(grid.shape)
    lo, vs = grid.lo.detach().cpu().double().numpy(), float(grid.voxel_size)
    c = np.clip(np.floor((target - lo) / vs).astype(np.int64), 0, shape - 1)
    R = 2
    while True:
        a, e = np.maximum(c - R, 0), np.minimum(c + R + 1, shape)
        covers_all = bool((a == 0).all() and (e == shape).all())
        cand = np.argwhere(labels[a[0]:e[0], a[1]:e[1], a[2]:e[2]] == comp) + a  # [K, 3]
        if len(cand):
            d = np.linalg.norm(lo + (cand + 0.5) * vs - target, axis=1)
            k = int(np.argmin(d))
            if d[k] <= R * vs or covers_all:
                return cand[k]
        if covers_all:
            raise GoalUnreachableError(f"the free-space component {comp} has no voxel")
        R *= 2


def explain_goal(space: "PlanningSpace", target, reached, tol: float = 1e-6) -> Optional[dict]:
    """Why a shot ends away from its go-to target: None when ``reached`` [3] is within ``tol`` of ``target`` [3],
    else {"from", "to", "distance", "why"}, for the report, the CLI and the viewer (a moved goal is never silent)."""
    t, g = (np.asarray(v, dtype=np.float64).reshape(3) for v in (target, reached))
    d = float(np.linalg.norm(g - t))
    if d <= tol:
        return None
    if distance_outside(*space.region(), t) > 0:
        why = "the go-to point is outside the planning region; the shot ends at the nearest safe point inside it"
    elif not bool(points_free(space, t[None])[0]):
        why = ("the camera does not fit at the go-to point (inside an object or wall, or closer than the camera "
               "radius + safety margin); the shot ends at the nearest safe point")
    else:
        why = ("the go-to point is free but cannot be reached from the start (its free space is not connected "
               "to the start's at this grid resolution); the shot ends at the nearest reachable point")
    return {"from": t.tolist(), "to": g.tolist(), "distance": d, "why": why}
