"""How a Planner builds, once per scene and planning region, what requests read (``prepare_scene``: space.py's
``PreparedScene``: spatial index, occupancy grid, free-space components, coarse grid, surface voxels, mean voxels,
distance transform). Every request only reads it; the one-time cost is reported in ``timings_ms``, apart from
per-plan cost."""
from __future__ import annotations

import time
from typing import Optional, Tuple

from torch import Tensor

from .. import native
from ..corridor.grid_polytope import VoxelObstacles
from ..corridor.polytope import prepare_native as prepare_native_polytope
from ..errors import GoalUnreachableError, InvalidInputError
from ..geometry.clearance_queries import free_distance_transform
from ..scene.ellipsoids import EllipsoidScene
from ..scene.occupancy import build_occupancy
from ..scene.spatial_index import GridIndex
from ..search.astar import AStarGrid
from ..search.coarse_path import CoarseGrid
from ..search.goal import mean_voxel_mask
from ..space import PreparedScene


def preload_request_modules() -> None:
    """Import now what requests import lazily (the goal's QP, polytope centres, the corridor QP's solvers;
    scipy.optimize's import alone is a noticeable part of a first request), paid once per process instead of by the
    first request."""
    import scipy.optimize  # noqa: F401
    import scipy.sparse  # noqa: F401 - imported for its side effect (loaded once)

    for name in ("clarabel", "osqp"):
        try:
            __import__(name)
        except ImportError:  # optional solvers: the request reports what is missing
            pass


OVERSIZED_SPLAT = 1000  # a splat of at least this many Gaussians, most of them over half the region, is refused


def check_gaussian_sizes(scene: EllipsoidScene, lo: Tensor, hi: Tensor) -> None:
    """InvalidInputError when most of a splat's Gaussians (at least OVERSIZED_SPLAT of them) are over half the planning
    region [lo, hi] long: a file whose scales are wrong (rasterising them would take minutes, each covering most of
    the grid's columns). Checked before the index and the grid are built."""
    n, half = len(scene), 0.5 * float((hi - lo).max())
    big = int((scene.radii.max(-1).values >= half).sum())
    if n >= OVERSIZED_SPLAT and 2 * big > n:
        raise InvalidInputError(f"{big} of the scene's {n} Gaussians are larger than half the planning region (a "
                                f"semi-axis over {half:.3g} scene units): the splat's scales are wrong for this scene "
                                f"(a damaged or mis-scaled file?); it is not planned through")


def no_free_space(scene: EllipsoidScene, lo: Tensor, hi: Tensor) -> str:
    """Why a planning region [lo, hi] has no free voxel: Gaussians larger than the region (a scene file whose scales
    are wrong), else the camera sphere against the voxels."""
    longest = float((hi - lo).max())
    big = int((scene.radii.max(-1).values >= longest).sum())
    if big >= max(1, len(scene) // 2):
        return (f"the planning region has no free space: {big} of the scene's {len(scene)} Gaussians are larger "
                f"than the region itself (a semi-axis over its longest side, {longest:.3g} scene units): the splat's "
                f"scales are wrong for this scene (a damaged or mis-scaled file?)")
    return ("the occupancy grid has no free voxel: the camera sphere (--camera-radius + --safety-margin = "
            f"{scene.camera_radius:.3g}) leaves no room between the obstacles at this voxel size; lower "
            "--camera-radius or --safety-margin, raise --grid-resolution, or check --region")


def prepare_scene(scene: EllipsoidScene, grid_resolution: int, lo: Tensor, hi: Tensor,
                  mirror: bool, index: Optional[GridIndex] = None,
                  light: bool = False) -> Tuple[EllipsoidScene, PreparedScene]:
    """Build the spatial index and the occupancy grid of ``scene`` over [lo [3], hi [3]] (``grid_resolution`` voxels
    along the longest side) on the scene's device, then what requests need from them; with ``mirror``, scene, index
    and grid are mirrored to the CPU first. Returns (the scene requests query: ``scene`` or its CPU mirror, the
    PreparedScene). ``index``: the scene's spatial index when already built; ``light``: no coarse grid, compiled
    kernels or distance transform built now (refine.py's local fine grids: a request's own work, after a prepare()).
    GoalUnreachableError when the grid has no free voxel."""
    check_gaussian_sizes(scene, lo, hi)
    t0 = time.perf_counter()
    index = GridIndex.build(scene) if index is None else index
    t1 = time.perf_counter()
    grid = build_occupancy(scene, index, grid_resolution, bounds=(lo, hi))
    t2 = time.perf_counter()
    if not (~grid.occupied).any():
        raise GoalUnreachableError(no_free_space(scene, lo, hi))
    batch_index = index
    if mirror:
        scene = scene.to("cpu")
        index, grid = index.to("cpu"), grid.to("cpu")
    t3 = time.perf_counter()
    ag = AStarGrid(grid.numpy())
    _ = ag.labels  # free-space components, used for reachability of goals and starts
    coarse = None if light else CoarseGrid(ag)
    t4 = time.perf_counter()
    voxels = VoxelObstacles.from_occupied(ag._occ, grid.lo.detach().cpu().double().numpy(), grid.voxel_size)
    t5 = time.perf_counter()
    # compile / load a request's compiled kernels now (cached on disk after the first time), before candidate worker
    # processes fork: they inherit them instead of each loading them on first use. One function per library:
    # astar26, gridpoly, dual_qp, goalwindow, project, timing, orientation; polytope just below.
    loaders = (native.search26, native.grid_polytope_c, native.corridor_dual_c, native.goal_window_c,
               native.project_dual_c, native.arc_length_table_c, native.look_at_c)
    for loader in () if light else loaders:
        loader()
    if not light:
        prepare_native_polytope(scene, index)
        preload_request_modules()
    t6 = time.perf_counter()
    prepared = PreparedScene(
        index=index, grid=grid, astar_grid=ag, coarse=coarse, batch_index=batch_index, voxels=voxels,
        mean_voxels=mean_voxel_mask(scene, grid),
        timings_ms={"index_ms": 1e3 * (t1 - t0), "grid_ms": 1e3 * (t2 - t1),
                    "mirror_ms": 1e3 * (t3 - t2) if mirror else 0.0,
                    "components_ms": 1e3 * (t4 - t3), "surface_ms": 1e3 * (t5 - t4), "native_ms": 1e3 * (t6 - t5)},
    )
    if not light:
        free_distance_transform(prepared)  # once, off the request path (clearance_queries.clearance_lower_bound)
    prepared.timings_ms["warm_ms"] = 1e3 * (time.perf_counter() - t6)  # mean voxels + distance transform
    return scene, prepared
