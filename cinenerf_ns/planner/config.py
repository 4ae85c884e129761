"""The planner's configuration (``PlannerConfig``: everything besides the scene and the request) and its range checks.
Below the shots package: the prepared planning space (space.py) carries it down to the search, geometry and corridor
modules, which read its fields only."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional, Union

import numpy as np

from .errors import InvalidInputError
from .host_pool import fork_available
from .trajectory.qp_config import TrajectoryConfig
from .trajectory.timing import TimingConfig

REGION_RULES = ("auto", "dense", "robust")
"""PlannerConfig.region_rule: without bounds and training cameras, the region follows the dense content ('auto',
'dense': planning_region.dense_content_box) or the robust box of all means ('robust': the rule before issue 37)."""

MAX_CANDIDATES = 64
"""Most candidates one request may ask for (each is a whole plan; more are better drawn as several requests)."""

GRID_RESOLUTION_RANGE = (8, 1024)
"""Allowed PlannerConfig.grid_resolution (voxels along the planning region's longest side)."""


@dataclass
class PlannerConfig:
    """Everything the planner needs besides the scene and the request."""

    grid_resolution: int = 96
    """Voxels along the longest side of the planning bounds (A* grid; conservative occupancy)."""
    max_voxel_radii: Optional[float] = 1.9
    """The grid is made finer than grid_resolution where its voxel would be longer than this many camera radii (a wide
    open region: gaps between thin obstacles stay open, corridors take grid polytopes), up to AUTO_RESOLUTION_MAX
    voxels and the memory budget (planning_region.grid_resolution_for); None: exactly grid_resolution."""
    bounds: Optional[tuple] = None
    """(lo[3], hi[3]) planning region in scene units (cinesplat-plan --region); None: chosen by the rules of
    planning_region.planning_bounds (training cameras, else the dense content)."""
    bounds_rule: str = "user box"
    """What chose ``bounds`` when they are given, for the report ('user box', 'stored in the export', ...)."""
    region_rule: str = "auto"
    """Without bounds and a start region: 'auto' / 'dense': the box of the dense opaque content
    (planning_region.dense_content_box: far background, sky and floaters do not stretch it); 'robust': the robust box
    of all means (robust_bounds_quantile)."""
    start_region: Optional[tuple] = None
    """(lo[3], hi[3]) where random starts are drawn (a capture's training-camera box); None: the planning bounds,
    preferring an enclosed free component (starts.preferred_component: a room's interior, not its outer shell)."""
    start_look_distance: float = 0.25
    """Random starts keep this fraction of the start region's longest side from the look-at point when they can:
    aim error from an off centre grows as asin(e / range) up close. 0: anywhere (the paper's); given starts stay."""
    up: tuple = (0.0, 0.0, 1.0)
    """World up direction: cameras keep their y axis as close to it as possible."""
    astar_weight: float = 1.0
    """A* heuristic weight of the seed voxel path (w > 1: cost <= w x minimum, fewer expansions); 1.0 because longer
    seed paths cost as much in shortcut + corridor as a weighted search saves."""
    box_margin: float = 0.15
    """Each corridor polytope lives in its segment's bounding box grown by this (scene units)."""
    trajectory: TrajectoryConfig = field(default_factory=TrajectoryConfig)
    """Bezier degree, continuity, cost and solver of the corridor QP."""
    timing: TimingConfig = field(default_factory=TimingConfig)
    """Speed cap, ramps and frame rate."""
    verify_spacing: float = 0.005
    """Max distance between clearance samples when verifying a trajectory (scene units)."""
    robust_bounds_quantile: float = 0.01
    """With bounds=None the grid spans these quantiles of the Gaussian means (floaters far away
    would otherwise blow up the grid) grown by 10%."""
    region_padding: float = 0.5
    """With bounds=None and a start_region: the planning region is the start region grown by this fraction of its
    longest side, cut to the robust box, so far floaters and background do not stretch the grid."""
    memory_budget_mb: float = 4096.0
    """Memory the voxel grid and its companions may take (MB); a finer --grid-resolution is refused, not swapped."""
    far_limit: float = 1.0
    """Targets and starts farther than this x the planning region's longest side from the region are errors (a typo
    or a point in other units, never something to move silently)."""
    max_attempts_per_candidate: int = 4
    """Random starts tried per requested candidate before giving up on it."""
    plan_cpu_threads: Optional[int] = 1
    """torch intra-op and BLAS threads while a request runs (restored afterwards; None: untouched); 1 because
    a request's thousands of small ops lose more to thread hand-offs than they gain."""
    request_device: str = "auto"
    """Where a request's small queries run. 'auto': on prepare()'s CPU mirror of a GPU scene (tiny kernels cost more
    to launch than to run); 'scene': on the scene's device. Batched scoring always uses ``Planner.batch_scene``."""
    grid_polytopes: Union[bool, str] = "auto"
    """Polytopes from the occupancy grid for segments in free voxels (grid_polytope.py: same guarantee, cheaper);
    False: Prop-2 for all (the paper's). 'auto': on for voxels <= GRID_POLYTOPE_MAX_VOXEL x camera radius."""
    obstacles_note: Optional[str] = None
    """What the scene's obstacles are, when not every Gaussian (e.g. floaters ignored: scene/floaters.py); every shot's
    verification states it (Planner.obstacle_set)."""
    refine_disconnected: bool = True
    """A go-to that is free but not connected to the start at grid_resolution is planned again on a finer grid over a
    box around start and go-to (refine.py) before the shot's goal is moved; False: moved at once."""
    corner_detours: bool = True
    """With grid polytopes: a voxel-path step that passes an occupied voxel at an edge or corner is replaced by axis
    moves through free voxels where such a route exists (corner_steps.py), so its corridor polytope comes from the grid
    instead of Prop-2. False: the voxel path as A* found it."""
    corridor_backend: str = "auto"
    """Corridor polytopes: 'cpu' one host polytope per segment; 'batched' all in one torch batch on the scene's own
    device; 'auto': 'cpu' for one request's corridor (the CPU mirror's compiled polytopes beat GPU launches) unless
    requests run on a CUDA scene, 'batched' for many-corridor batches on a CUDA scene (corridor_options; workers
    always 'cpu'). Same guarantee either way."""
    candidate_workers: Optional[int] = None
    """Forked processes plan_candidates spreads candidates over (workers.py). None: one per CPU with 'fork' and
    >= 4 CPUs, else 0; 0: in this process. Never with requests on a GPU (no CUDA after fork)."""
    corridor_threads: Optional[int] = 1
    """How many Prop-2 corridor polytopes a request builds at once (threads: their compiled kernel releases the GIL;
    the same corridor whatever the number). None: one per usable CPU, at most CORRIDOR_THREADS_MAX; always 1 inside a
    candidate worker. 1 because threads cut the corridor's p95 but lost on its median (docs/PLANNER_DEFAULTS.md)."""
    worker_scoring: bool = True
    """With candidate workers, each also computes its shot's score inputs (sight lines, exact clearance); False:
    the parent scores them (on the GPU when the scene is there) while the workers run. Same score terms."""

    def validate(self) -> None:
        """InvalidInputError naming the first field out of its range (Planner checks its config at construction)."""
        if self.region_rule not in REGION_RULES:
            raise InvalidInputError(f"region_rule must be one of {REGION_RULES}, got "
                                    f"{self.region_rule!r}")
        if self.request_device not in ("auto", "scene"):
            raise InvalidInputError(f"request_device must be 'auto' or 'scene', got {self.request_device!r}")
        if self.corridor_backend not in ("auto", "cpu", "batched"):
            raise InvalidInputError(
                f"corridor_backend must be 'auto', 'cpu' or 'batched', got {self.corridor_backend!r}")
        w = self.astar_weight
        if isinstance(w, bool) or not isinstance(w, (int, float)) or not (math.isfinite(w) and w >= 1.0):
            raise InvalidInputError(f"astar_weight must be a finite number >= 1, got {w!r}")
        d = self.start_look_distance
        if isinstance(d, bool) or not isinstance(d, (int, float)) or not (math.isfinite(d) and 0.0 <= d < 1.0):
            raise InvalidInputError(f"start_look_distance must be a fraction in [0, 1) of the start region's longest "
                                    f"side, got {d!r}")
        validate_workers(self.candidate_workers)
        t = self.corridor_threads
        if t is not None and (isinstance(t, bool) or not isinstance(t, (int, np.integer)) or t < 1):
            raise InvalidInputError(f"corridor_threads must be None (auto) or an integer >= 1, got {t!r}")
        lo_r, hi_r = GRID_RESOLUTION_RANGE
        res = self.grid_resolution
        if isinstance(res, bool) or not isinstance(res, (int, np.integer)) or not lo_r <= res <= hi_r:
            raise InvalidInputError(f"grid_resolution (--grid-resolution) must be an integer in [{lo_r}, {hi_r}] "
                                    f"voxels along the planning region's longest side, got {res!r}")
        v = self.max_voxel_radii
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))
                              or not (math.isfinite(v) and v > 0)):
            raise InvalidInputError(f"max_voxel_radii must be None or a finite number > 0 (camera radii per voxel), "
                                    f"got {v!r}")
        mb = self.memory_budget_mb
        if isinstance(mb, bool) or not isinstance(mb, (int, float)) or not (math.isfinite(mb) and mb >= 64):
            raise InvalidInputError(f"memory_budget_mb (--memory-budget-mb) must be a number >= 64, got {mb!r}")
        for name, lo in (("region_padding", 0.0), ("far_limit", 1e-9)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= lo):
                raise InvalidInputError(f"{name} must be a finite number >= {lo:g} (a fraction / multiple of the "
                                        f"planning region's longest side), got {v!r}")
        self.timing.validate()
        if not isinstance(self.refine_disconnected, (bool, np.bool_)):
            raise InvalidInputError(f"refine_disconnected must be True or False, got {self.refine_disconnected!r}")
        if not isinstance(self.corner_detours, (bool, np.bool_)):
            raise InvalidInputError(f"corner_detours must be True or False, got {self.corner_detours!r}")
        if self.grid_polytopes not in (True, False, "auto"):
            raise InvalidInputError(f"grid_polytopes must be True, False or 'auto', got {self.grid_polytopes!r}")


def validate_workers(value: Any) -> None:
    """InvalidInputError unless ``value`` is a valid PlannerConfig.candidate_workers (None, 0, or N > 0 where fork
    exists)."""
    if value is None:
        return
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise InvalidInputError(f"candidate_workers must be None (auto), 0 (in this process) or a positive integer, "
                                f"got {value!r}")
    if value > 0 and not fork_available():
        raise InvalidInputError("candidate_workers > 0 needs the 'fork' start method (Linux); use None or 0 here")
