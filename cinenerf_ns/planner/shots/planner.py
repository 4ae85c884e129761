"""The camera planner: go-to / look-at points in, verified safe shots out (paper Sec. IV).

``Planner`` is the thin user-facing API over one prepared planning space (space.py's ``PlanningSpace``: the scenes,
the ``PreparedScene`` (spatial index, occupancy grid, free-space components) and the ``PlannerConfig``, built once
by ``prepare()`` and reported separately from per-plan cost). Everything below shots/ takes that space or plain
arrays, never the Planner:
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

import time
from dataclasses import replace
from typing import Optional

import numpy as np
from torch import Tensor

from ..blas_threads import request_threads, warm_blas_controller
from ..config import GRID_RESOLUTION_RANGE, PlannerConfig  # noqa: F401 (re-exported: the CLI and viewer import them)
from ..corridor.corridor_options import GRID_POLYTOPE_MAX_VOXEL  # noqa: F401 (re-exported: PlannerConfig.grid_polytopes)
from ..geometry import clearance_queries
from ..scene import planning_region
from ..scene.ellipsoids import EllipsoidScene
from ..scene.planning_region import GRID_BYTES_PER_VOXEL, ArrayLike  # noqa: F401 (GRID_BYTES_PER_VOXEL re-exported)
from ..search import reach, starts
from ..search.starts import ENCLOSED_COMPONENT_FRACTION, preferred_component  # noqa: F401 (re-exported)
from ..space import PlanningSpace, PreparedScene
from .plan_request import check_candidates, plan_request
from .prepared_scene import prepare_scene
from .safety import DEFAULT_CLEARANCE_CAP, clearance_report
from .shot import Shot
from .workers import CandidatePool, candidate_workers, pool_for


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
        self.grid_note: Optional[str] = None  # set by prepare() when the grid is finer than config.grid_resolution
        self.prepared: Optional[PreparedScene] = None
        self._space: Optional[PlanningSpace] = None  # see space
        self._pool: Optional[tuple] = None  # (PreparedScene, processes, CandidatePool), see candidate_pool()

    def _mirror_to_cpu(self) -> bool:
        """Requests query a CPU mirror of the scene (request_device 'auto' and a scene off the CPU)."""
        return self.config.request_device == "auto" and self.batch_scene.device.type != "cpu"

    # ------------------------------------------------------------------ one-time work
    def prepare(self) -> PreparedScene:
        """Build the prepared scene (prepared_scene.prepare_scene: spatial index, occupancy grid, components, ...;
        timed, one-time) for the planning region on the scene's device, and the planning space over it (``space``);
        with request_device 'auto' and a GPU scene, requests then query a CPU mirror of scene, index and grid
        (``self.scene``)."""
        self.scene = self.batch_scene
        lo, hi = self.planning_bounds()
        # before any expensive work: the camera sphere and the voxel grid fit the region
        planning_region.check_region(self.config, float(self.scene.camera_radius), lo.cpu().numpy(), hi.cpu().numpy())
        if self.config.bounds is not None and self.config.start_region is not None:  # random starts inside the box
            inside = planning_region.starts_within(self.config.start_region, lo.cpu().numpy(), hi.cpu().numpy())
            self.config = replace(self.config, start_region=inside)
        res = planning_region.grid_resolution_for(self.config, float(self.scene.camera_radius), lo.cpu().numpy(),
                                                  hi.cpu().numpy())
        self.grid_note = None if res == self.config.grid_resolution else (
            f"grid {res} voxels along the longest side, not {self.config.grid_resolution}: made finer so that a voxel "
            f"is at most {self.config.max_voxel_radii:g} camera radii (--planner.max-voxel-radii; None keeps "
            f"--grid-resolution)")
        self.scene, self.prepared = prepare_scene(self.batch_scene, res, lo, hi, mirror=self._mirror_to_cpu())
        self._space = PlanningSpace(self.scene, self.batch_scene, self.config, self.prepared)
        if self.config.plan_cpu_threads is not None:
            t = time.perf_counter()
            warm_blas_controller()  # what request_threads' first use would build, off the request path
            self.prepared.timings_ms["blas_ms"] = 1e3 * (time.perf_counter() - t)
        return self.prepared

    def ready(self) -> PreparedScene:
        """The prepared scene (prepare() on first use)."""
        return self.prepared if self.prepared is not None else self.prepare()

    @property
    def space(self) -> PlanningSpace:
        """The prepared planning space (prepare() on first use) that every stage below shots/ reads; built again
        when scene, prepared scene or config were replaced since (grow_region)."""
        prep, sp = self.ready(), self._space
        if sp is None or sp.prepared is not prep or sp.scene is not self.scene or sp.config is not self.config \
                or sp.batch_scene is not self.batch_scene:
            sp = self._space = PlanningSpace(self.scene, self.batch_scene, self.config, prep)
        return sp

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

    def check_timing(self) -> None:
        """InvalidInputError when a shot across the planning region would need more than config.timing.max_frames
        frames (planning_region.check_timing)."""
        lo, hi = self.region()
        planning_region.check_timing(self.config.timing, lo, hi)

    def region(self) -> tuple[np.ndarray, np.ndarray]:
        """The prepared planning region (lo [3], hi [3]) float64: the occupancy grid's box. Paths stay inside it."""
        return self.space.region()

    def distance_outside(self, point: np.ndarray) -> float:
        """Euclidean distance [scene units] from a point [3] to the planning region (0 inside)."""
        lo, hi = self.region()
        return planning_region.distance_outside(lo, hi, point)

    def checked_point(self, point: ArrayLike, what: str) -> np.ndarray:
        """A user point [3] as float64: finite and within config.far_limit region sizes of the planning region, else
        InvalidInputError naming ``what`` and the allowed range (planning_region.checked_point)."""
        lo, hi = self.region()
        return planning_region.checked_point(point, what, lo, hi, self.config.far_limit)

    def checked_start(self, start: ArrayLike, force: bool = False) -> np.ndarray:
        """A user-given start [3] as float64: InvalidInputError when it lies outside the planning region (unless
        ``force``: the region then grows to hold it, grow_region), StartInCollisionError when the camera would be
        inside the scene (starts.check_start_inside, starts.check_start_free)."""
        s = self.checked_point(start, "start point")
        if force and self.distance_outside(s) > 0:
            self.grow_region(s)
        else:
            starts.check_start_inside(self.space, s)
        return starts.check_start_free(self.space, s)

    def explain_goal(self, target: ArrayLike, reached: ArrayLike, tol: float = 1e-6) -> Optional[dict]:
        """Why a shot ends away from its go-to target: None when it ends there, else {"from", "to", "distance",
        "why"} (reach.explain_goal)."""
        return reach.explain_goal(self.space, target, reached, tol)

    def main_component(self) -> int:
        """The free component random starts come from (starts.main_component: the start region's, else
        preferred_component's choice). Constant per prepared scene: computed once, not per request."""
        return starts.main_component(self.space)

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

    # ------------------------------------------------------------------ clearance (clearance_queries.py)
    def clearance(self, points: ArrayLike, cap: Optional[float] = None, batch: bool = False) -> np.ndarray:
        """Exact clearance [P] (camera radius included) of camera centres [P, 3], capped at ``cap`` when given;
        ``batch``: on the scene's own device (clearance_queries.clearance)."""
        return clearance_queries.clearance(self.space, points, cap=cap, batch=batch)

    def clearance_report(self, shot: Shot, max_spacing: float = 0.02, label: str = "",
                         cap: float = DEFAULT_CLEARANCE_CAP) -> dict:
        """safety.safety_report of a shot with this scene's exact clearance capped at ``cap``
        (safety.clearance_report)."""
        return clearance_report(self.space, shot, max_spacing=max_spacing, label=label, cap=cap)

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
            check_candidates(n_candidates)
            self.ready()  # prepare on first use, before the request clock starts
            goal_p = self.checked_point(goal, "go-to point")
            look_p = self.checked_point(look_at, "look-at point")
            self.check_timing()
            t_req = time.perf_counter()
            starts, check_ms = [], None
            if start is not None:
                starts = [self.checked_start(start, force=force_start)]
                check_ms = 1e3 * (time.perf_counter() - t_req)  # a given start's region + sign-of-clearance check
                n_candidates = 1
            return plan_request(self.space, goal_p, look_p, starts, seed, n_candidates, t_req, check_ms)

    def request_threads(self):
        """Context: torch CPU threads and numpy's / scipy's BLAS threads = config.plan_cpu_threads while a request
        runs, restored afterwards (blas_threads.request_threads: a plan is many small ops, for which extra threads
        cost more than they give; the QP's linear algebra always runs on the CPU)."""
        on_cpu = self.scene.device.type == "cpu" or self._mirror_to_cpu()  # the mirror exists once prepared
        return request_threads(self.config.plan_cpu_threads, on_cpu)
