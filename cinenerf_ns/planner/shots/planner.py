"""The camera planner: go-to / look-at points in, verified safe shots out (paper Sec. IV).

``Planner`` is a facade over one scene's prepared state (prepared_scene.py's ``PreparedScene``: spatial index,
occupancy grid, free-space components, built once by ``prepare()`` and reported separately from per-plan cost). Its
methods delegate to the modules that do the work:
  planning_region.py   the planning region, its checks, user points against it
  starts.py            given starts checked, random starts drawn in the main free component
  clearance_queries.py free-voxel tests, conservative and exact clearance
  corridor_options.py  corridor backend and grid polytopes resolved for this process
  shortcut.py          the line-of-sight shortcut
  plan_request.py      plan(): n shots, each a leg of stages.py (goal -> voxel path -> shortcut -> corridor -> QP ->
                       timing + orientation -> verification), a failed random start replaced
  workers.py           the forked candidate worker pool (candidates.py)
"""
from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass, field, replace
from typing import Optional, Union

import numpy as np
import torch
from torch import Tensor

from ..blas_threads import blas_threads, warm_blas_controller
from ..corridor import corridor_options
from ..corridor.corridor_options import GRID_POLYTOPE_MAX_VOXEL  # noqa: F401 (re-exported: PlannerConfig.grid_polytopes)
from ..errors import InvalidInputError
from ..geometry import clearance_queries
from ..scene import planning_region
from ..scene.ellipsoids import EllipsoidScene
from ..scene.planning_region import GRID_BYTES_PER_VOXEL, ArrayLike  # noqa: F401 (GRID_BYTES_PER_VOXEL re-exported)
from ..search import reach, shortcut, starts
from ..search.starts import ENCLOSED_COMPONENT_FRACTION, preferred_component  # noqa: F401 (re-exported)
from ..trajectory.qp import TrajectoryConfig
from ..trajectory.timing import TimingConfig
from .plan_request import MAX_CANDIDATES, plan_request  # noqa: F401 (MAX_CANDIDATES re-exported)
from .prepared_scene import PreparedScene, prepare_scene
from .safety import DEFAULT_CLEARANCE_CAP
from .shot import Shot
from .workers import CandidatePool, candidate_workers, pool_for, validate_workers

GRID_RESOLUTION_RANGE = (8, 1024)
"""Allowed PlannerConfig.grid_resolution (voxels along the planning region's longest side)."""


@dataclass
class PlannerConfig:
    """Everything the planner needs besides the scene and the request."""

    grid_resolution: int = 96
    """Voxels along the longest side of the planning bounds (A* grid; conservative occupancy)."""
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
        if self.region_rule not in planning_region.REGION_RULES:
            raise InvalidInputError(f"region_rule must be one of {planning_region.REGION_RULES}, got "
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


class Planner:
    """Plans camera shots through one scene. ``prepare()`` once, then ``plan()`` many times."""

    def __init__(self, scene: EllipsoidScene, config: Optional[PlannerConfig] = None):
        if len(scene) == 0:
            from ..errors import EmptySceneError

            raise EmptySceneError("the scene has no obstacles; nothing to plan around")
        self.config = config or PlannerConfig()
        self.config.validate()
        self.batch_scene = scene  # the scene on its own device: big batched queries (candidate scoring)
        self.scene = scene  # the scene on the request device (a CPU mirror after prepare() when 'auto' + GPU)
        self._region_rule: Optional[str] = None  # region_rule(), computed once
        self.prepared: Optional[PreparedScene] = None
        self._pool: Optional[tuple] = None  # (PreparedScene, processes, CandidatePool), see candidate_pool()

    def _mirror_to_cpu(self) -> bool:
        """Requests query a CPU mirror of the scene (request_device 'auto' and a scene off the CPU)."""
        return self.config.request_device == "auto" and self.batch_scene.device.type != "cpu"

    # ------------------------------------------------------------------ one-time work
    def prepare(self) -> PreparedScene:
        """Build the prepared scene (prepared_scene.prepare_scene: spatial index, occupancy grid, components, ...;
        timed, one-time) for the planning region on the scene's device; with request_device 'auto' and a GPU scene,
        requests then query a CPU mirror of scene, index and grid (``self.scene``)."""
        self.scene = self.batch_scene
        lo, hi = self.planning_bounds()
        self.check_region(lo.cpu().numpy(), hi.cpu().numpy())  # before any expensive work
        if self.config.bounds is not None and self.config.start_region is not None:  # random starts inside the box
            inside = planning_region.starts_within(self.config.start_region, lo.cpu().numpy(), hi.cpu().numpy())
            self.config = replace(self.config, start_region=inside)
        self.scene, self.prepared = prepare_scene(self.batch_scene, self.config.grid_resolution, lo, hi,
                                                  mirror=self._mirror_to_cpu())
        if self.config.plan_cpu_threads is not None:
            t = time.perf_counter()
            warm_blas_controller()  # what request_threads' first use would build, off the request path
            self.prepared.timings_ms["blas_ms"] = 1e3 * (time.perf_counter() - t)
        return self.prepared

    def ready(self) -> PreparedScene:
        """The prepared scene (prepare() on first use)."""
        return self.prepared if self.prepared is not None else self.prepare()

    def grow_region(self, point: np.ndarray) -> None:
        """Grow the planning region to hold ``point`` [3] (with a voxel's room) and prepare again: a forced start."""
        lo, hi = self.region()
        room = 2.0 * float(self.ready().grid.voxel_size) + float(self.scene.camera_radius)
        lo, hi = np.minimum(lo, point - room), np.maximum(hi, point + room)
        self.close()
        rule = f"{self.region_rule()}, grown to hold the forced start"
        self.config = replace(self.config, bounds=(lo, hi), bounds_rule=rule)
        self._region_rule = None
        self.prepared = None
        self.prepare()

    # ------------------------------------------------------------------ the planning region (planning_region.py)
    def planning_bounds(self) -> tuple[Tensor, Tensor]:
        """(lo [3], hi [3]) of the region prepare() will grid (planning_region.planning_bounds)."""
        return planning_region.planning_bounds(self.scene, self.config)

    def region_rule(self) -> str:
        """Which rule chose the planning region: 'user box', 'training cameras', 'dense content', ...
        (planning_region.region_rule)."""
        if self._region_rule is None:  # the dense-content test costs a histogram of the means: once
            self._region_rule = planning_region.region_rule(self.config, self.batch_scene)
        return self._region_rule

    def obstacle_set(self) -> str:
        """The obstacle set shots are planned and verified against (config.obstacles_note, else every ellipsoid)."""
        return self.config.obstacles_note or f"all {len(self.scene)} ellipsoids of the scene"

    def check_region(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """InvalidInputError when the camera sphere or the voxel grid does not fit the region [lo, hi]
        (planning_region.check_region)."""
        planning_region.check_region(self.config, float(self.scene.camera_radius), lo, hi)

    def check_timing(self) -> None:
        """InvalidInputError when a shot across the planning region would need more than config.timing.max_frames
        frames (planning_region.check_timing)."""
        lo, hi = self.region()
        planning_region.check_timing(self.config.timing, lo, hi)

    def region(self) -> tuple[np.ndarray, np.ndarray]:
        """The prepared planning region (lo [3], hi [3]) float64: the occupancy grid's box. Paths stay inside it."""
        return planning_region.grid_region(self.ready().grid)

    def distance_outside(self, point: np.ndarray) -> float:
        """Euclidean distance [scene units] from a point [3] to the planning region (0 inside)."""
        lo, hi = self.region()
        return planning_region.distance_outside(lo, hi, point)

    def checked_point(self, point: ArrayLike, what: str) -> np.ndarray:
        """A user point [3] as float64: finite and within config.far_limit region sizes of the planning region, else
        InvalidInputError naming ``what`` and the allowed range (planning_region.checked_point)."""
        lo, hi = self.region()
        return planning_region.checked_point(point, what, lo, hi, self.config.far_limit)

    def explain_goal(self, target: ArrayLike, reached: ArrayLike, tol: float = 1e-6) -> Optional[dict]:
        """Why a shot ends away from its go-to target: None when it ends there, else {"from", "to", "distance",
        "why"} (reach.explain_goal)."""
        return reach.explain_goal(self, target, reached, tol)

    # ------------------------------------------------------------------ candidate workers (workers.py)
    def candidate_workers(self) -> int:
        """Worker processes plan_candidates uses now (workers.candidate_workers)."""
        return candidate_workers(self)

    def candidate_pool(self) -> Optional[CandidatePool]:
        """The forked worker pool for candidate_workers() > 0 (None for 0), created on first use and again
        when prepare() has run since (the workers hold the planner as it was at the fork)."""
        n = self.candidate_workers()
        if n == 0:
            return None
        self.main_component()  # cached before the fork so that workers inherit it
        from .end_pose import visibility_volume

        visibility_volume(self)  # the same: workers score visibility on it (built once, ~0.5 s at 400k)
        self._pool = pool_for(self, self.ready(), n, self._pool)
        return self._pool[2]

    def close(self) -> None:
        """Terminate the candidate worker pool if there is one (also done when the planner is garbage
        collected and at interpreter exit). The planner stays usable: a later request forks a new pool."""
        if self._pool is not None:
            self._pool[2].close()
            self._pool = None

    # ------------------------------------------------------------------ corridors (corridor_options.py)
    def corridor_backend(self, many: bool = False) -> str:
        """config.corridor_backend resolved for this process and one request's corridor (``many``: a batch of many
        corridors): 'batched' or 'cpu' (corridor_options.corridor_backend)."""
        return corridor_options.corridor_backend(self, many)

    def use_grid_polytopes(self) -> bool:
        """config.grid_polytopes resolved for the prepared grid (corridor_options.use_grid_polytopes)."""
        return corridor_options.use_grid_polytopes(self)

    def corridor_kwargs(self, many: bool = False) -> dict:
        """Keyword arguments of build_corridor for this planner's requests (``many``: of build_corridors over many
        ways; corridor_options.corridor_kwargs)."""
        return corridor_options.corridor_kwargs(self, many)

    # ------------------------------------------------------------------ clearance (clearance_queries.py)
    def clearance(self, points: ArrayLike, cap: Optional[float] = None, batch: bool = False) -> np.ndarray:
        """Exact clearance [P] (camera radius included) of camera centres [P, 3], capped at ``cap`` when given;
        ``batch``: on the scene's own device (clearance_queries.clearance)."""
        return clearance_queries.clearance(self, points, cap=cap, batch=batch)

    def clearance_report(self, shot: Shot, max_spacing: float = 0.02, label: str = "",
                         cap: float = DEFAULT_CLEARANCE_CAP) -> dict:
        """safety.safety_report of a shot with this scene's exact clearance capped at ``cap``
        (clearance_queries.clearance_report)."""
        return clearance_queries.clearance_report(self, shot, max_spacing=max_spacing, label=label, cap=cap)

    def clearance_lower_bound(self, points: ArrayLike) -> np.ndarray:
        """A lower bound [P] of the clearance of camera centres [P, 3] from the occupancy grid alone
        (clearance_queries.clearance_lower_bound)."""
        return clearance_queries.clearance_lower_bound(self, points)

    def points_free(self, points) -> np.ndarray:
        """bool [P]: camera ball at each point [P, 3] proven clear, conservatively (clearance_queries.points_free)."""
        return clearance_queries.points_free(self, points)

    def in_free_voxel(self, points) -> np.ndarray:
        """bool [P]: the point lies in a free voxel of the occupancy grid (clearance_queries.in_free_voxel)."""
        return clearance_queries.in_free_voxel(self, points)

    def free_test(self, points: Tensor) -> Tensor:
        """points_free of a tensor [P, 3] as a bool tensor (clearance_queries.free_test)."""
        return clearance_queries.free_test(self, points)

    # ------------------------------------------------------------------ the shortcut (shortcut.py)
    def segments_free(self, p0, p1) -> np.ndarray:
        """bool [P]: segment p0[i] -> p1[i] proven collision-free for the camera ball (shortcut.segments_free)."""
        return shortcut.segments_free(self, p0, p1)

    def segments_off_grid(self, way: np.ndarray) -> int:
        """Segments of a polyline [K, 3] that do not lie in free voxels (shortcut.segments_off_grid)."""
        return shortcut.segments_off_grid(self, way)

    def choose_way(self, grid_way: np.ndarray, any_way: Optional[np.ndarray]) -> np.ndarray:
        """The cheaper corridor of two shortcuts of one path (shortcut.choose_way)."""
        return shortcut.choose_way(self, grid_way, any_way)

    def shortcut_way(self, way: np.ndarray) -> np.ndarray:
        """The shortcut of one polyline [K, 3]: with grid polytopes, the grid rule's, unless it leaves more than
        CLASSIC_SHORTCUT_AFTER segments off the grid; then also the classic shortcut, and the cheaper of the two
        (choose_way)."""
        return self.shortcut_ways([way])[0]

    def shortcut_ways(self, ways: list) -> list:
        """The shortcut of several polylines [K, 3] (shortcut.shortcut_ways)."""
        return shortcut.shortcut_ways(self, ways)

    # ------------------------------------------------------------------ starts (starts.py)
    def main_component(self) -> int:
        """The free component random starts come from (starts.main_component: the start region's, else
        preferred_component's choice). Constant per prepared scene: computed once, not per request."""
        return starts.main_component(self)

    def random_starts(self, n: int, generator: torch.Generator, look_at: np.ndarray) -> Tensor:
        """n random collision-free starts [n, 3] as every request draws them (starts.random_starts)."""
        return starts.random_starts(self, n, generator, look_at)

    def checked_start(self, start: ArrayLike, force: bool = False) -> np.ndarray:
        """A user-given start [3] as float64, checked against the planning region (grown to hold it when ``force``)
        and the scene (starts.checked_start)."""
        return starts.checked_start(self, start, force)

    # ------------------------------------------------------------------ planning
    def plan(self, goal: ArrayLike, look_at: ArrayLike, start: Optional[ArrayLike] = None, seed: int = 0,
             n_candidates: int = 1, force_start: bool = False) -> list[Shot]:
        """Plan ``n_candidates`` shots ending as close as safely possible to ``goal`` and always
        looking at ``look_at``. With ``start`` all candidates start there (n_candidates is then 1);
        otherwise starts are sampled free and reachable with the seeded generator. A start outside the planning
        region is an error unless ``force_start`` (the region then grows to hold it).

        Raises InvalidInputError, StartInCollisionError, GoalUnreachableError (see messages).
        Every returned shot's exact clearance along the densely sampled curve is >= 0; explain_goal says why a
        shot ends away from ``goal``."""
        with self.request_threads():
            return plan_request(self, goal, look_at, start, seed, n_candidates, force_start)

    @contextlib.contextmanager
    def request_threads(self):
        """torch CPU threads = config.plan_cpu_threads while a request runs (restored afterwards): a plan is
        many small ops, for which extra threads cost more than they give. numpy's / scipy's BLAS threads are capped
        the same way (blas_threads), on any device: the QP's linear algebra always runs on the CPU."""
        threads, old = self.config.plan_cpu_threads, torch.get_num_threads()
        on_cpu = self.scene.device.type == "cpu" or self._mirror_to_cpu()  # the mirror exists once prepared
        swap = threads is not None and on_cpu and int(threads) != old
        if swap:
            torch.set_num_threads(int(threads))
        try:
            with blas_threads(threads):
                yield
        finally:
            if swap:
                torch.set_num_threads(old)
