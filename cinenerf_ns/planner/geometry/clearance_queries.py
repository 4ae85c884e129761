"""How clear the camera ball is at camera centres, in a prepared planning space: the occupancy grid's proofs first
(free voxels, the distance transform's lower bound), exact distance queries only where the grid cannot decide.
Functions of a PlanningSpace (space.py)."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Optional

import numpy as np
import torch

from .collision import points_collide_arrays
from .distance import clearance as exact_clearance

if TYPE_CHECKING:
    from torch import Tensor

    from ..space import PlanningSpace, PreparedScene


def _grid_voxels(grid, points) -> tuple[np.ndarray, np.ndarray]:
    """(points [P, 3] float64, their voxel indices [P, 3] int64; may lie outside the grid)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, vs = grid.lo.detach().cpu().double().numpy(), float(grid.voxel_size)
    return pts, np.floor((pts - lo) / vs).astype(np.int64)


def in_free_voxel(space: "PlanningSpace", points) -> np.ndarray:
    """bool [P]: the point [P, 3] lies in a free voxel of the (conservative) occupancy grid; False outside the grid."""
    prep = space.prepared
    occ = prep.astar_grid._occ  # [X, Y, Z] bool
    _, ijk = _grid_voxels(prep.grid, points)
    shape = np.array(occ.shape)
    inside = ((ijk >= 0) & (ijk < shape)).all(1)
    c = np.clip(ijk, 0, shape - 1)
    return inside & ~occ[c[:, 0], c[:, 1], c[:, 2]]


def points_free(space: "PlanningSpace", points) -> np.ndarray:
    """bool [P]: camera ball at each point [P, 3] proven clear. Points in a free voxel of the occupancy grid are
    proven by the grid (occupancy.py: every point of a free voxel keeps the ball clear, with slack for rounding); the
    rest by the conservative Cor. 1 test. Both are conservative, never optimistic."""
    prep = space.prepared
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    free = in_free_voxel(space, pts)
    todo = np.flatnonzero(~free)
    if todo.size:  # (points_collide_arrays: points_collide's answers without the torch round trip on a CPU scene)
        free[todo] = ~points_collide_arrays(pts[todo], space.scene, prep.index, float(space.scene.camera_radius))
    return free


def free_test(space: "PlanningSpace", points: "Tensor") -> "Tensor":
    """points_free of a tensor [P, 3], as a bool tensor (the acceptance test of goals and random starts)."""
    # goal/start acceptance only needs a proof of freedom: the conservative test is exact enough
    return torch.as_tensor(points_free(space, points.detach().cpu().numpy()))


def free_distance_transform(prep: "PreparedScene") -> np.ndarray:
    """[X+2, Y+2, Z+2] distance (scene units) from each voxel centre of the grid padded by one ring to the nearest
    occupied voxel centre (the ring outside the grid counts as occupied); computed once per prepared scene and kept
    in ``prep.free_edt``."""
    if prep.free_edt is None:
        from scipy import ndimage

        free = np.pad(~prep.astar_grid._occ, 1, constant_values=False)  # the ring outside the grid: occupied
        prep.free_edt = ndimage.distance_transform_edt(free) * float(prep.grid.voxel_size)
    return prep.free_edt


def free_voxel_grid(space: "PlanningSpace") -> tuple:
    """(occupancy uint8 [X, Y, Z] C order, grid lo float64 [3], voxel size, dims int64 [3]) of the prepared scene, for
    the compiled sight-line test's free-voxel proof (occlusion.sight_lines_blocked's free_grid); kept in
    ``prep.free_voxels``."""
    prep = space.prepared
    if prep.free_voxels is None:
        occ = np.ascontiguousarray(prep.astar_grid._occ, dtype=np.uint8)
        lo = np.ascontiguousarray(prep.grid.lo.detach().cpu().double().numpy())
        prep.free_voxels = (occ, lo, float(prep.grid.voxel_size), np.ascontiguousarray(occ.shape, dtype=np.int64))
    return prep.free_voxels


def clearance_lower_bound(space: "PlanningSpace", points) -> np.ndarray:
    """A lower bound [P] of the clearance of camera centres [P, 3] from the occupancy grid alone (no
    distance query). Every point of a free voxel keeps the camera ball clear (occupancy.py), so if the
    ball B(p, D) lies in free voxels, the obstacles are >= D + radius away: clearance(p) >= D. With E the
    distance from p's voxel centre to the nearest occupied voxel centre (Euclidean distance transform;
    outside the grid counts as occupied) and h half a voxel diagonal, D = E - 2h (p and the nearest
    occupied point each lie within h of their voxel centres); max(D, 0) in free voxels (their points are
    proven clear); -inf (no information) in occupied voxels and outside the grid."""
    prep = space.prepared
    grid = prep.grid
    edt = free_distance_transform(prep)  # [X+2, Y+2, Z+2]
    vs = float(grid.voxel_size)
    _, ijk = _grid_voxels(grid, points)
    inside = ((ijk >= 0) & (ijk < np.array(grid.shape))).all(1)
    c = np.clip(ijk, 0, np.array(grid.shape) - 1) + 1  # into the padded array
    e = edt[c[:, 0], c[:, 1], c[:, 2]]
    # (1 + 1e-9): the transform is float64 and the bound must never be optimistic
    d = e - math.sqrt(3.0) * vs * (1 + 1e-9)
    return np.where(inside & (e > 0), np.maximum(d, 0.0), -np.inf)


def box_clearance_bound(space: "PlanningSpace", points, cap: float) -> np.ndarray:
    """A lower bound [P] of the clearance of camera centres [P, 3], tighter than clearance_lower_bound, valid where it
    reaches ``cap`` (returned as min(bound, cap); a point in an occupied voxel gets 0): the Euclidean distance from the
    point to the nearest occupied voxel BOX (outside the grid counts as occupied), not between voxel centres. Why: a
    point p in a free voxel keeps the camera ball clear, so its nearest ellipsoid point x is > r away; the point y of
    [p, x] at distance r from x is within r of an ellipsoid, so it lies in no free voxel: |p - x| - r (the clearance)
    = |p - y| >= the distance from p to the occupied boxes. Only voxels within ``cap`` are looked at (compiled:
    native/polytope.c's cn_box_distance); -inf (no information) without the compiled code."""
    from ..native import box_distance_c

    fn = box_distance_c()
    pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 3))
    if fn is None or len(pts) == 0:
        return np.full(len(pts), -np.inf)
    occ, lo, vs, dims = free_voxel_grid(space)
    reach = float(cap) * (1 + 1e-6) + 1e-9  # searched a little beyond the cap, so that the widened bound reaches it
    w = int(math.ceil(reach / vs)) + 1  # a voxel farther than w in some index axis is >= w * vs - vs >= reach away
    out = np.empty(len(pts))
    fn(occ.ctypes.data, lo.ctypes.data, vs, dims.ctypes.data, pts.ctypes.data, len(pts), w, reach, out.ctypes.data)
    # (1 - 1e-9) and - 1e-12: the box distances are float64 and the bound must never be optimistic
    return np.minimum(out * (1 - 1e-9) - 1e-12, cap)


def distance_estimate(space: "PlanningSpace", points: np.ndarray) -> np.ndarray:
    """An estimate [P] of each camera centre's distance to the nearest ellipsoid from the occupancy grid, for the
    exact clearance's first search box: clearance_lower_bound (which is ~2 half-diagonals below the grid's own
    estimate) + half a voxel diagonal + the camera radius; 0 where the grid knows nothing. Not a bound in either
    direction; it only changes how many search rounds and candidate pairs the exact answer takes (a full diagonal
    more takes fewer rounds but bigger boxes with more pairs; benchmarks/bench_clearance_start.py compares them)."""
    lb = clearance_lower_bound(space, points)
    vs = float(space.prepared.grid.voxel_size)
    est = lb + 0.5 * math.sqrt(3.0) * vs + float(space.scene.camera_radius)
    return np.where(np.isfinite(lb), est, 0.0)


def clearance(space: "PlanningSpace", points, cap: Optional[float] = None, batch: bool = False) -> np.ndarray:
    """Exact clearance [P] (camera radius included) of camera centres [P, 3]. ``cap``: clearances above it are not
    searched for and reported as ``cap`` (a lower bound; much cheaper far from everything: points that the occupancy
    grid already proves to be >= cap from every obstacle cost no distance query, see clearance_lower_bound).
    ``batch``: many points (e.g. every frame of a shot): run on the scene's own device (a GPU when there is one)
    instead of the request device."""
    prep = space.prepared
    scene, index = space.scene, prep.index
    if batch and prep.batch_index is not None:
        scene, index = space.batch_scene, prep.batch_index
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.empty(len(pts))
    todo = np.arange(len(pts))
    if cap is not None:
        far = clearance_lower_bound(space, pts) >= float(cap)
        out[far] = float(cap)
        todo = np.flatnonzero(~far)
        if todo.size:  # the voxel-box bound proves more of them; the value the exact search would give there
            boxed = todo[box_clearance_bound(space, pts[todo], float(cap)) >= float(cap)]
            r = float(scene.camera_radius)
            out[boxed] = (float(cap) + r) - r  # rounded as exact_clearance's (cap + r) - r, in float64
            todo = np.setdiff1d(todo, boxed)
    if todo.size:
        p = torch.as_tensor(pts[todo], device=scene.device)
        md = None if cap is None else float(cap) + float(scene.camera_radius)
        # capped queries start from the grid's estimate (far fewer search rounds); uncapped ones keep the small
        # default start: their far points would otherwise gather many more pairs
        start = None if cap is None else torch.as_tensor(distance_estimate(space, pts[todo]), device=scene.device)
        with space.request_threads():
            out[todo] = exact_clearance(p, scene, index, max_distance=md, start_radius=start).detach().cpu().numpy()
    return out
