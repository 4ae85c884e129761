"""The prepared planning space: what every stage below the Planner reads (the role OMPL's ``SpaceInformation`` plays).

``PreparedScene`` is what ``Planner.prepare()`` builds once per scene and planning region (spatial index, occupancy
grid, free-space components, coarse grid, grid voxels, lazily filled caches); ``PlanningSpace`` bundles it with the
scenes it was built for and the ``PlannerConfig``. The search, geometry and corridor functions take a PlanningSpace
(or plain arrays), never the Planner: context flows down, nothing calls back up into shots/."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Optional

import numpy as np

from .blas_threads import request_threads
from .scene.planning_region import grid_region

if TYPE_CHECKING:
    from .config import PlannerConfig
    from .corridor.grid_polytope import VoxelObstacles
    from .scene.ellipsoids import EllipsoidScene
    from .scene.occupancy import OccupancyGrid
    from .scene.spatial_index import GridIndex
    from .search.astar import AStarGrid
    from .search.coarse_path import CoarseGrid


@dataclass
class PreparedScene:
    """What prepare() builds once per scene and planning region; every request reads it."""

    index: GridIndex  # on the request device (Planner.scene's)
    grid: OccupancyGrid
    astar_grid: AStarGrid
    timings_ms: dict
    coarse: Optional[CoarseGrid] = None  # 2x-coarse blocks for hard path searches (coarse_path.py)
    batch_index: Optional[GridIndex] = None  # the index on the scene's own device (Planner.batch_scene)
    free_edt: Optional[np.ndarray] = None  # [X+2, Y+2, Z+2] see clearance_queries.free_distance_transform (lazy)
    free_voxels: Optional[tuple] = None  # see clearance_queries.free_voxel_grid (lazy)
    voxels: Optional[VoxelObstacles] = None  # the grid's occupied + surface voxels for grid polytopes
    mean_voxels: Optional[np.ndarray] = None  # [X, Y, Z] bool voxels holding a Gaussian mean (goal.mean_voxel_mask)
    main_component_of: Optional[tuple] = None  # (start_region, component) cached by starts.main_component
    start_blocked_of: Optional[tuple] = None  # (labels, component, blocked mask) cached by starts.start_blocked
    volume: Optional[Any] = None  # geometry.visibility.SplatVolume of the region (end_pose.visibility_volume, lazy)
    component_boxes: Optional[list] = None  # ndimage.find_objects of the free components (refine.enclosed, lazy)


@dataclass(eq=False)
class PlanningSpace:
    """One prepared planning space: the scenes, the prepared grid and index (``prepared``) and the configuration.
    Built by ``Planner.prepare()`` (``Planner.space``); read-only for requests, except the PreparedScene's lazy caches.

    ``scene``: the scene requests query (a CPU mirror of a GPU scene with request_device 'auto');
    ``batch_scene``: the scene on its own device, for big batched queries (``prepared.batch_index`` indexes it)."""

    scene: "EllipsoidScene"
    batch_scene: "EllipsoidScene"
    config: "PlannerConfig"
    prepared: PreparedScene

    @property
    def grid(self) -> "OccupancyGrid":
        """The occupancy grid over the planning region."""
        return self.prepared.grid

    @property
    def index(self) -> "GridIndex":
        """The spatial index of ``scene``."""
        return self.prepared.index

    def region(self) -> tuple[np.ndarray, np.ndarray]:
        """The prepared planning region (lo [3], hi [3]) float64: the occupancy grid's box. Paths stay inside it."""
        return grid_region(self.prepared.grid)

    def obstacle_set(self) -> str:
        """The obstacle set shots are planned and verified against (config.obstacles_note, else every ellipsoid)."""
        return self.config.obstacles_note or f"all {len(self.scene)} ellipsoids of the scene"

    def request_threads(self):
        """Context: torch / BLAS threads = config.plan_cpu_threads while a request runs (blas_threads.request_threads;
        the requests' scene is on the CPU or mirrored there)."""
        on_cpu = self.scene.device.type == "cpu" or (self.config.request_device == "auto"
                                                     and self.batch_scene.device.type != "cpu")
        return request_threads(self.config.plan_cpu_threads, on_cpu)
