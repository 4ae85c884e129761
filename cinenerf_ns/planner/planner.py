"""The camera planner: go-to / look-at points in, verified safe shots out (paper Sec. IV).

Pipeline per candidate (each stage timed in ``Shot.timings``):
  start (given, or sampled free in the start's region)  ->  goal = closest safe point to the go-to
  target in the start's free component  ->  voxel path on the conservative grid (A* with a budget,
  hard cases on a 2x-coarse grid by compiled Dijkstra, coarse_path.py)  ->  line-of-sight
  shortcut (swept-sphere test)  ->  safe polytope corridor (Prop. 2, exact offsets)  ->  Bezier QP
  (control points inside the polytopes: the whole curve is safe by the convex-hull property)  ->
  timing + look-at orientation  ->  exact clearance along the densely sampled curve (verification).

One-time work (spatial index, occupancy grid, free-space components) happens in ``prepare()`` and
is reported separately from per-plan cost.
"""
from __future__ import annotations

import contextlib
import math
import time
from dataclasses import dataclass, field, replace
from typing import Optional, Sequence, Union

import numpy as np
import torch
from torch import Tensor

from . import shortcut, stages
from .astar import AStarGrid
from .coarse_path import CoarseGrid
from .collision import points_collide
from .corridor import CorridorError
from .distance import clearance
from .errors import (
    GoalUnreachableError,
    InvalidInputError,
    StartInCollisionError,
)
from .goal import mean_voxel_mask, sample_free_starts
from .grid_polytope import VoxelObstacles
from .native import grid_polytope_c as native_grid_polytope, search26 as native_search26
from .occupancy import OccupancyGrid, build_occupancy
from .polytope import prepare_native as prepare_native_polytope
from .safety import DEFAULT_CLEARANCE_CAP, safety_report
from .scene import EllipsoidScene
from .shot import Shot
from .spatial_index import GridIndex
from .timing import TimingConfig
from .trajectory import TrajectoryConfig
from .workers import CandidatePool, default_workers, in_worker, pool_for, validate_workers

ArrayLike = Union[Tensor, np.ndarray, Sequence[float]]


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


@dataclass
class PlannerConfig:
    """Everything the planner needs besides the scene and the request."""

    grid_resolution: int = 96
    """Voxels along the longest side of the planning bounds (A* grid; conservative occupancy)."""
    bounds: Optional[tuple] = None
    """(lo[3], hi[3]) planning region in scene units; None: the scene bounds (robust, see prepare())."""
    start_region: Optional[tuple] = None
    """(lo[3], hi[3]) where random starts are drawn; None: the planning bounds (e.g. pass the
    training cameras' bounding box for real captures). Without it, starts come from the largest free component that
    does not touch the planning box when it holds >= ENCLOSED_COMPONENT_FRACTION of the free voxels (a closed room's
    interior: the shell between its walls and the padded box can be larger), else from the largest."""
    start_look_distance: float = 0.25
    """Random starts (none given) are drawn at least this fraction of the start region's longest side away from the
    look-at point, when the region has such free starts (else anywhere: it never fails a request). Why: a random
    start is the shot's opening frame, and one pressed against the subject shows only its near surface; and the aim
    is only as good as the subject's estimated centre: a centre off by e turns into up to asin(e / range) of aim
    error, which grows fast at close range (issue 5: a 0.019-unit centre error cost 3.2 deg at a 0.27-unit range in
    a 2.1-unit room). 0: starts anywhere (the paper's uniform random starts). User-given starts are never moved."""
    up: tuple = (0.0, 0.0, 1.0)
    """World up direction: cameras keep their y axis as close to it as possible."""
    astar_weight: float = 1.0
    """Heuristic weight of the initial voxel path's A* (1: minimum-cost path; w > 1: its cost is at most w x the
    minimum, found with far fewer expansions; the path is only the corridor's seed and is shortcut first, so the
    shot's safety does not depend on it). Measured (CPU 200k, 100 pairs): 1.5 cut the A* median 22.3 -> 2.6 ms but
    its longer seed paths cost about as much in shortcut + corridor (plan median 86.7 -> 91.1 ms), so 1.0 stays the
    default."""
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
    """With bounds=None and a start_region (a capture's training cameras), the planning region is the start region
    grown by this fraction of its longest side on every side, cut to the robust scene box: a real capture's floaters
    and open background far from the cameras do not stretch the grid. Paths never leave the planning region."""
    memory_budget_mb: float = 4096.0
    """Memory the voxel grid and its companions may take (MB); a finer --grid-resolution is refused, not swapped."""
    far_limit: float = 1.0
    """Targets and starts farther than this x the planning region's longest side from the region are errors (a typo
    or a point in other units, never something to move silently)."""
    max_attempts_per_candidate: int = 4
    """Random starts tried per requested candidate before giving up on it."""
    plan_cpu_threads: Optional[int] = 1
    """torch intra-op threads while plan() runs its queries on the CPU (restored afterwards); None: leave
    torch's setting alone. A request is thousands of small tensor ops, where thread hand-offs cost
    more than they save: on a 2-core box shared with other work 1 thread was ~5x faster (median)."""
    request_device: str = "auto"
    """Where a request's collision / polytope / clearance queries run. 'auto': on the CPU when the scene
    is on a GPU (the spatial index and the occupancy grid are still built there, then mirrored to the
    CPU once in prepare()): a request is thousands of tiny queries whose kernel launches and syncs cost
    more than they compute (H100 host, 1M Gaussians, median per plan: 388 ms on CUDA tensors, 194 ms with
    the CPU mirror). 'scene': on the scene's device. Batched scoring of many candidates (occlusion, clearance)
    keeps using the scene's device (``Planner.batch_scene``)."""
    grid_polytopes: Union[bool, str] = "auto"
    """Corridor segments that lie in free voxels of the occupancy grid get polytopes built from the grid's surface
    voxels (grid_polytope.py: the same safety guarantee without a Gaussian query, far cheaper, up to about one
    voxel more distance from the scene); the others (usually the last one, next to the go-to object) get exact
    Prop-2 polytopes from corridor_backend, and the shortcut prefers segments in free voxels (shortcut_way).
    False: Prop-2 polytopes for every segment (the paper's corridor). 'auto': on when the grid's voxels are at most
    GRID_POLYTOPE_MAX_VOXEL x the camera radius (fine voxels: a room at grid 96, voxel 0.85 r, plans ~40% faster);
    off for coarse ones (a real capture with far floaters, voxel 4 r, planned ~15% slower with them)."""
    corridor_backend: str = "auto"
    """How a request builds its corridor of safe polytopes. 'cpu': one host polytope per segment
    (polytope.safe_polytope) on the request device's scene. 'batched': all segments' polytopes in one batched
    torch computation (polytope_batched.py) on the scene's own device (``Planner.batch_scene`` and its index:
    the GPU copy when the scene is on a GPU, even with request_device 'auto'); segments it cannot cover go
    through the host path (with splitting). 'auto': 'batched' when the scene is on a CUDA device, else 'cpu'.
    Candidate worker processes always use 'cpu' (no CUDA after fork). Same safety guarantee either way."""
    candidate_workers: Optional[int] = None
    """Worker processes that plan_candidates spreads its candidates over (workers.py: forked after prepare(),
    sharing the prepared CPU state copy-on-write; each plans whole candidates single-threaded, the parent
    samples starts, scores and ranks). None: auto, one per usable CPU (at most k busy per request)
    when the 'fork' start method exists (Linux) and there are >= 4 CPUs, else 0. 0: plan in this process.
    N: N workers. Workers are never used when requests run on a GPU (request_device 'scene' with a CUDA
    scene): CUDA cannot be used after fork."""
    worker_scoring: bool = True
    """With candidate workers: each worker also computes its shot's score inputs (sight lines and exact clearance of
    the scored frames, on the CPU copy with the compiled searches) and the parent only combines them. False: the
    parent scores the shots (on the GPU when the scene is there) while the workers run. Same score terms (the
    clearances agree to ~1e-13; occlusion flags can differ only for sight lines grazing an ellipsoid)."""


def preload_request_modules() -> None:
    """Import now what requests import lazily (the goal's QP, polytope centres, the corridor QP's solvers): measured
    ~90 ms of the first request after prepare() on the CPU box (scipy.optimize's import alone), paid once per process."""
    import scipy.optimize  # noqa: F401
    import scipy.sparse  # noqa: F401 - imported for its side effect (loaded once)

    for name in ("clarabel", "osqp"):
        try:
            __import__(name)
        except ImportError:  # optional solvers: the request reports what is missing
            pass


@dataclass
class PreparedScene:
    index: GridIndex  # on the request device (Planner.scene's)
    grid: OccupancyGrid
    astar_grid: AStarGrid
    timings_ms: dict
    coarse: Optional[CoarseGrid] = None  # 2x-coarse blocks for hard path searches (coarse_path.py)
    batch_index: Optional[GridIndex] = None  # the index on the scene's own device (Planner.batch_scene)
    free_edt: Optional[np.ndarray] = None  # [X+2, Y+2, Z+2] see Planner.clearance_lower_bound (lazy)
    voxels: Optional[VoxelObstacles] = None  # the grid's occupied + surface voxels for grid polytopes
    mean_voxels: Optional[np.ndarray] = None  # [X, Y, Z] bool voxels holding a Gaussian mean (goal.mean_voxel_mask)


GRID_POLYTOPE_MAX_VOXEL = 2.0
"""PlannerConfig.grid_polytopes 'auto': grid polytopes when voxel_size <= this x camera_radius. Measured at 0.85 (the
procedural room, a win) and 4.1 (the fox capture, a loss); the threshold between them is a guess."""


def _fmt(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{v:.3g}" for v in np.asarray(p, dtype=np.float64).reshape(-1)) + ")"


def _as_point(x: ArrayLike, what: str) -> np.ndarray:
    try:
        p = np.asarray(x.detach().cpu() if isinstance(x, Tensor) else x, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as e:
        raise InvalidInputError(f"{what} must be 3 numbers, got {x!r}") from e
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise InvalidInputError(f"{what} must be 3 finite numbers, got {p.tolist()}")
    return p


MAX_CANDIDATES = 64
"""Most candidates one request may ask for (each is a whole plan; more are better drawn as several requests)."""

GRID_BYTES_PER_VOXEL = 80
"""Peak memory per grid voxel of prepare() + a plan (occupancy, components, distance transform, search workspaces):
measured 64 B/voxel between grids of 1.2M and 9.8M voxels, rounded up."""

MAX_RADIUS_FRACTION = 0.1
"""The camera sphere's radius may be at most this fraction of the planning region's longest side."""

GRID_RESOLUTION_RANGE = (8, 1024)


class Planner:
    """Plans camera shots through one scene. ``prepare()`` once, then ``plan()`` many times."""

    def __init__(self, scene: EllipsoidScene, config: Optional[PlannerConfig] = None):
        if len(scene) == 0:
            from .errors import EmptySceneError

            raise EmptySceneError("the scene has no obstacles; nothing to plan around")
        self.config = config or PlannerConfig()
        if self.config.request_device not in ("auto", "scene"):
            raise InvalidInputError(f"request_device must be 'auto' or 'scene', got {self.config.request_device!r}")
        if self.config.corridor_backend not in ("auto", "cpu", "batched"):
            raise InvalidInputError(
                f"corridor_backend must be 'auto', 'cpu' or 'batched', got {self.config.corridor_backend!r}")
        w = self.config.astar_weight
        if isinstance(w, bool) or not isinstance(w, (int, float)) or not (math.isfinite(w) and w >= 1.0):
            raise InvalidInputError(f"astar_weight must be a finite number >= 1, got {w!r}")
        d = self.config.start_look_distance
        if isinstance(d, bool) or not isinstance(d, (int, float)) or not (math.isfinite(d) and 0.0 <= d < 1.0):
            raise InvalidInputError(f"start_look_distance must be a fraction in [0, 1) of the start region's longest "
                                    f"side, got {d!r}")
        self.batch_scene = scene  # the scene on its own device: big batched queries (candidate scoring)
        self.scene = scene  # the scene on the request device (a CPU mirror after prepare() when 'auto' + GPU)
        validate_workers(self.config.candidate_workers)
        lo_r, hi_r = GRID_RESOLUTION_RANGE
        res = self.config.grid_resolution
        if isinstance(res, bool) or not isinstance(res, (int, np.integer)) or not lo_r <= res <= hi_r:
            raise InvalidInputError(f"grid_resolution (--grid-resolution) must be an integer in [{lo_r}, {hi_r}] voxels "
                                    f"along the planning region's longest side, got {res!r}")
        mb = self.config.memory_budget_mb
        if isinstance(mb, bool) or not isinstance(mb, (int, float)) or not (math.isfinite(mb) and mb >= 64):
            raise InvalidInputError(f"memory_budget_mb (--memory-budget-mb) must be a number >= 64, got {mb!r}")
        for name, lo in (("region_padding", 0.0), ("far_limit", 1e-9)):
            v = getattr(self.config, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= lo):
                raise InvalidInputError(f"{name} must be a finite number >= {lo:g} (a fraction / multiple of the "
                                        f"planning region's longest side), got {v!r}")
        self.config.timing.validate()
        if self.config.grid_polytopes not in (True, False, "auto"):
            raise InvalidInputError(f"grid_polytopes must be True, False or 'auto', got {self.config.grid_polytopes!r}")
        self.prepared: Optional[PreparedScene] = None
        self._pool: Optional[tuple] = None  # (PreparedScene, processes, CandidatePool), see candidate_pool()

    def _mirror_to_cpu(self) -> bool:
        return self.config.request_device == "auto" and self.batch_scene.device.type != "cpu"

    # ------------------------------------------------------------------ one-time work
    def planning_bounds(self) -> tuple[Tensor, Tensor]:
        cfg = self.config
        dev = self.scene.device
        if cfg.bounds is not None:
            lo = torch.as_tensor(cfg.bounds[0], dtype=torch.float64, device=dev).reshape(3)
            hi = torch.as_tensor(cfg.bounds[1], dtype=torch.float64, device=dev).reshape(3)
            if not (torch.isfinite(lo).all() and torch.isfinite(hi).all() and (hi > lo).all()):
                raise InvalidInputError(f"planning bounds need finite lo < hi, got {lo.tolist()}, {hi.tolist()}")
            return lo, hi
        m = self.scene.means.double()
        q = cfg.robust_bounds_quantile
        if len(self.scene) > 1000 and q > 0:
            # torch.quantile has an input-size limit; a strided subsample is plenty for bounds
            sub = m[:: max(1, len(m) // 200_000)]
            lo = torch.quantile(sub, q, dim=0)
            hi = torch.quantile(sub, 1 - q, dim=0)
        else:
            lo, hi = m.min(0).values, m.max(0).values
        pad = 0.1 * (hi - lo).max() + self.scene.camera_radius
        lo, hi = lo - pad, hi + pad
        if cfg.start_region is not None:  # the capture's cameras: the region that matters
            slo, shi = (torch.as_tensor(np.asarray(v, dtype=np.float64), device=dev).reshape(3) for v in cfg.start_region)
            grow = cfg.region_padding * float((shi - slo).max())
            inner = self.scene.camera_radius + 1e-6  # the start region itself always fits
            lo = torch.minimum(torch.maximum(lo, slo - grow), slo - inner)
            hi = torch.maximum(torch.minimum(hi, shi + grow), shi + inner)
        return lo, hi

    def check_region(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """InvalidInputError when the camera sphere is too large for the planning region [lo, hi] or the voxel grid
        would not fit config.memory_budget_mb (both named by their options, with the allowed range)."""
        side = np.asarray(hi, dtype=np.float64) - np.asarray(lo, dtype=np.float64)
        longest = float(side.max())
        r = float(self.scene.camera_radius)
        if r > MAX_RADIUS_FRACTION * longest:
            raise InvalidInputError(
                f"the camera sphere (--camera-radius + --safety-margin = {r:.4g}) is too large for this scene: its "
                f"radius may be at most {MAX_RADIUS_FRACTION:g} x the planning region's longest side "
                f"({longest:.4g} scene units), i.e. <= {MAX_RADIUS_FRACTION * longest:.4g}")
        res = int(self.config.grid_resolution)
        voxels = float(np.prod(np.ceil(side / (longest / res))))
        need = voxels * GRID_BYTES_PER_VOXEL / 2**20
        budget = float(self.config.memory_budget_mb)
        if need > budget:
            fits = int(res * (budget / need) ** (1 / 3))
            raise InvalidInputError(
                f"--grid-resolution {res} needs about {need:.0f} MB for its voxel grid ({voxels:.3g} voxels), more "
                f"than the memory budget {budget:g} MB (--memory-budget-mb); at most {fits} fits")

    def check_timing(self) -> None:
        """InvalidInputError when a shot across the planning region (its diagonal at config.timing.max_speed) would
        need more than config.timing.max_frames frames: refused before planning, not when the frames are made."""
        lo, hi = self.region()
        t = self.config.timing
        diag = float(np.linalg.norm(hi - lo))
        frames = diag / t.max_speed * t.fps
        if frames > t.max_frames:
            need = diag * t.fps / t.max_frames
            raise InvalidInputError(
                f"--max-speed {t.max_speed:g} is too slow for --fps {t.fps:g}: crossing the planning region "
                f"({diag:.3g} scene units) would take {frames:.3g} frames, more than max_frames {t.max_frames}; "
                f"use --max-speed >= {need:.3g} or a lower --fps")

    def region(self) -> tuple[np.ndarray, np.ndarray]:
        """The prepared planning region (lo [3], hi [3]) float64: the occupancy grid's box. Paths stay inside it."""
        g = self.ready().grid
        lo = g.lo.detach().cpu().double().numpy()
        return lo, lo + np.array(g.shape, dtype=np.float64) * float(g.voxel_size)

    def distance_outside(self, point: np.ndarray) -> float:
        """Euclidean distance [scene units] from a point [3] to the planning region (0 inside)."""
        lo, hi = self.region()
        return float(np.linalg.norm(np.maximum(np.maximum(lo - point, point - hi), 0.0)))

    def checked_point(self, point: ArrayLike, what: str) -> np.ndarray:
        """A user point [3] as float64: finite and within config.far_limit region sizes of the planning region, else
        InvalidInputError naming ``what`` and the allowed range."""
        p = _as_point(point, what)
        lo, hi = self.region()
        limit = self.config.far_limit * float((hi - lo).max())
        d = self.distance_outside(p)
        if d > limit:
            raise InvalidInputError(
                f"the {what} {_fmt(p)} is {d:.3g} units outside the planning region {_fmt(lo)}..{_fmt(hi)}; points must "
                f"lie within {limit:.3g} units of it (scene units: a run's normalised coordinates)")
        return p

    def prepare(self) -> PreparedScene:
        """Build the spatial index and the occupancy grid (timed, one-time) on the scene's device; with
        request_device 'auto' and a GPU scene, mirror scene, index and grid to the CPU for requests."""
        self.scene = self.batch_scene
        lo, hi = self.planning_bounds()
        self.check_region(lo.cpu().numpy(), hi.cpu().numpy())  # before any expensive work
        t0 = time.perf_counter()
        index = GridIndex.build(self.scene)
        t1 = time.perf_counter()
        grid = build_occupancy(self.scene, index, self.config.grid_resolution, bounds=(lo, hi))
        t2 = time.perf_counter()
        batch_index = index
        mirrored = self._mirror_to_cpu()
        if mirrored:
            self.scene = self.batch_scene.to("cpu")
            index, grid = index.to("cpu"), grid.to("cpu")
        t3 = time.perf_counter()
        ag = AStarGrid(grid.numpy())
        _ = ag.labels  # free-space components, used for reachability of goals and starts
        coarse = CoarseGrid(ag)
        t4 = time.perf_counter()
        voxels = VoxelObstacles.from_occupied(ag._occ, grid.lo.detach().cpu().double().numpy(), grid.voxel_size)
        t5 = time.perf_counter()
        # compile / load the compiled path search and polytope now (cached on disk after the first time), before
        # candidate worker processes fork: they inherit them instead of each loading them on first use
        native_search26()
        native_grid_polytope()
        prepare_native_polytope(self.scene, index)
        preload_request_modules()
        t6 = time.perf_counter()
        if not (~grid.occupied).any():
            raise GoalUnreachableError(
                "the occupancy grid has no free voxel: the camera radius is too large for this scene, or the "
                "planning bounds hold no free space (raise --grid-resolution or check --bounds)"
            )
        self.prepared = PreparedScene(
            index=index,
            grid=grid,
            astar_grid=ag,
            coarse=coarse,
            batch_index=batch_index,
            voxels=voxels,
            mean_voxels=mean_voxel_mask(self.scene, grid),
            timings_ms={"index_ms": 1e3 * (t1 - t0), "grid_ms": 1e3 * (t2 - t1), "mirror_ms": 1e3 * (t3 - t2) if mirrored else 0.0,
                        "components_ms": 1e3 * (t4 - t3), "surface_ms": 1e3 * (t5 - t4), "native_ms": 1e3 * (t6 - t5)},
        )
        self.clearance_lower_bound(np.zeros((1, 3)))  # its distance transform, once, off the request path
        self.prepared.timings_ms["warm_ms"] = 1e3 * (time.perf_counter() - t6)  # mean voxels + distance transform
        return self.prepared

    def candidate_workers(self) -> int:
        """Worker processes plan_candidates uses now: config.candidate_workers resolved (None: auto), 0 when
        requests run on a non-CPU device (a forked child cannot use CUDA)."""
        n = self.config.candidate_workers
        validate_workers(n)
        n = default_workers() if n is None else int(n)
        if n:
            self.ready()  # the request device (self.scene's) is settled by prepare()
            if self.scene.device.type != "cpu":
                return 0
        return n

    def candidate_pool(self) -> Optional[CandidatePool]:
        """The forked worker pool for candidate_workers() > 0 (None for 0), created on first use and again
        when prepare() has run since (the workers hold the planner as it was at the fork)."""
        n = self.candidate_workers()
        if n == 0:
            return None
        self.main_component()  # cached before the fork so that workers inherit it
        self._pool = pool_for(self, self.ready(), n, self._pool)
        return self._pool[2]

    def close(self) -> None:
        """Terminate the candidate worker pool if there is one (also done when the planner is garbage
        collected and at interpreter exit). The planner stays usable: a later request forks a new pool."""
        if self._pool is not None:
            self._pool[2].close()
            self._pool = None

    def grow_region(self, point: np.ndarray) -> None:
        """Grow the planning region to hold ``point`` [3] (with a voxel's room) and prepare again: a forced start."""
        lo, hi = self.region()
        room = 2.0 * float(self.ready().grid.voxel_size) + float(self.scene.camera_radius)
        lo, hi = np.minimum(lo, point - room), np.maximum(hi, point + room)
        self.close()
        self.config = replace(self.config, bounds=(lo, hi))
        self.prepared = None
        self.prepare()

    def explain_goal(self, target: ArrayLike, reached: ArrayLike, tol: float = 1e-6) -> Optional[dict]:
        """Why a shot ends away from its go-to target: None when it ends there, else {"from", "to", "distance",
        "why"}, for the report, the CLI and the viewer (a moved goal is never silent)."""
        t, g = (np.asarray(v, dtype=np.float64).reshape(3) for v in (target, reached))
        d = float(np.linalg.norm(g - t))
        if d <= tol:
            return None
        if self.distance_outside(t) > 0:
            why = "the go-to point is outside the planning region; the shot ends at the nearest safe point inside it"
        elif not bool(self.points_free(t[None])[0]):
            why = ("the camera does not fit at the go-to point (inside an object or wall, or closer than the camera "
                   "radius + safety margin); the shot ends at the nearest safe point")
        else:
            why = ("the go-to point is free but cannot be reached from the start (its free space is not connected "
                   "to the start's at this grid resolution); the shot ends at the nearest reachable point")
        return {"from": t.tolist(), "to": g.tolist(), "distance": d, "why": why}

    def ready(self) -> PreparedScene:
        """The prepared scene (prepare() on first use)."""
        return self.prepared if self.prepared is not None else self.prepare()

    # ------------------------------------------------------------------ helpers
    def corridor_backend(self) -> str:
        """config.corridor_backend resolved for this process: 'batched' or 'cpu' ('auto': batched on a CUDA
        scene; always 'cpu' inside a forked candidate worker, where CUDA cannot be used)."""
        b = self.config.corridor_backend
        if in_worker() or (b == "batched" and self.batch_scene.device.type == "cuda" and torch.cuda._is_in_bad_fork()):
            return "cpu"
        if b == "auto":
            return "batched" if self.batch_scene.device.type == "cuda" else "cpu"
        return b

    def use_grid_polytopes(self) -> bool:
        """config.grid_polytopes resolved for the prepared grid ('auto': voxel_size <= GRID_POLYTOPE_MAX_VOXEL x the
        camera radius)."""
        g = self.config.grid_polytopes
        if g == "auto":
            return float(self.ready().grid.voxel_size) <= GRID_POLYTOPE_MAX_VOXEL * float(self.scene.camera_radius)
        return bool(g)

    def corridor_kwargs(self) -> dict:
        """Keyword arguments of build_corridor (after waypoints, scene, index) for this planner's requests: the box
        margin and the resolved corridor backend (the batched one runs on ``batch_scene`` / its index; the corridor's
        polytopes end up on the request device)."""
        prep = self.ready()
        kw = dict(box_margin=self.config.box_margin, region=self.region())
        if self.use_grid_polytopes():
            kw["grid"] = prep.voxels
        if self.corridor_backend() == "batched":
            bidx = prep.batch_index if prep.batch_index is not None else prep.index
            kw.update(backend="batched", batch_scene=self.batch_scene, batch_index=bidx)
        return kw

    def clearance(self, points: ArrayLike, cap: Optional[float] = None, batch: bool = False) -> np.ndarray:
        """Exact clearance [P] (camera radius included) of camera centres [P, 3]. ``cap``: clearances above it
        are not searched for and reported as ``cap`` (a lower bound; much cheaper far from everything: points
        that the occupancy grid already proves to be >= cap from every obstacle cost no distance query, see
        clearance_lower_bound). ``batch``: many points (e.g. every frame of a shot): run on the scene's own
        device (a GPU when there is one) instead of the request device."""
        prep = self.ready()
        scene, index = self.scene, prep.index
        if batch and prep.batch_index is not None:
            scene, index = self.batch_scene, prep.batch_index
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.empty(len(pts))
        todo = np.arange(len(pts))
        if cap is not None:
            far = self.clearance_lower_bound(pts) >= float(cap)
            out[far] = float(cap)
            todo = np.flatnonzero(~far)
        if todo.size:
            p = torch.as_tensor(pts[todo], device=scene.device)
            md = None if cap is None else float(cap) + float(scene.camera_radius)
            # capped queries start from the grid's estimate (far fewer search rounds); uncapped ones keep the small
            # default start: their far points would otherwise gather many more pairs (measured slower on the CPU)
            start = None if cap is None else torch.as_tensor(self._distance_estimate(pts[todo]), device=scene.device)
            with self.request_threads():
                out[todo] = clearance(p, scene, index, max_distance=md, start_radius=start).detach().cpu().numpy()
        return out

    def clearance_report(self, shot: Shot, max_spacing: float = 0.02, label: str = "",
                         cap: float = DEFAULT_CLEARANCE_CAP) -> dict:
        """safety.safety_report of a shot with this scene's exact clearance capped at ``cap`` (bounded work on any
        scene: far from everything a sample is 'at least the cap')."""
        return safety_report(shot, lambda p: self.clearance(p, cap=cap, batch=True), max_spacing=max_spacing,
                             label=label, clearance_cap=cap)

    def _distance_estimate(self, points: np.ndarray) -> np.ndarray:
        """An estimate [P] of each camera centre's distance to the nearest ellipsoid from the occupancy grid, for
        the exact clearance's first search box: clearance_lower_bound (which is ~2 half-diagonals below the grid's
        own estimate) + half a voxel diagonal + the camera radius; 0 where the grid knows nothing. Not a bound in
        either direction; it only changes how many search rounds and candidate pairs the exact answer takes.
        Measured (H100 host, 1M Gaussians, 2048 scored frames of 32 candidates, capped at 0.1): 12 index rounds,
        157 ms from the default start; 3 rounds, 62 ms with this estimate (identical values); 2 rounds but 101 ms
        with a full diagonal more (bigger boxes, more pairs)."""
        lb = self.clearance_lower_bound(points)
        vs = float(self.ready().grid.voxel_size)
        est = lb + 0.5 * math.sqrt(3.0) * vs + float(self.scene.camera_radius)
        return np.where(np.isfinite(lb), est, 0.0)

    def clearance_lower_bound(self, points: ArrayLike) -> np.ndarray:
        """A lower bound [P] of the clearance of camera centres [P, 3] from the occupancy grid alone (no
        distance query). Every point of a free voxel keeps the camera ball clear (occupancy.py), so if the
        ball B(p, D) lies in free voxels, the obstacles are >= D + radius away: clearance(p) >= D. With E the
        distance from p's voxel centre to the nearest occupied voxel centre (Euclidean distance transform;
        outside the grid counts as occupied) and h half a voxel diagonal, D = E - 2h (p and the nearest
        occupied point each lie within h of their voxel centres); max(D, 0) in free voxels (their points are
        proven clear); -inf (no information) in occupied voxels and outside the grid."""
        prep = self.ready()
        grid = prep.grid
        if prep.free_edt is None:
            from scipy import ndimage

            free = np.pad(~prep.astar_grid._occ, 1, constant_values=False)  # the ring outside the grid: occupied
            prep.free_edt = ndimage.distance_transform_edt(free) * float(grid.voxel_size)
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        lo, vs = grid.lo.detach().cpu().double().numpy(), float(grid.voxel_size)
        ijk = np.floor((pts - lo) / vs).astype(np.int64)
        inside = ((ijk >= 0) & (ijk < np.array(grid.shape))).all(1)
        c = np.clip(ijk, 0, np.array(grid.shape) - 1) + 1  # into the padded array
        e = prep.free_edt[c[:, 0], c[:, 1], c[:, 2]]
        # (1 + 1e-9): the transform is float64 and the bound must never be optimistic
        d = e - math.sqrt(3.0) * vs * (1 + 1e-9)
        return np.where(inside & (e > 0), np.maximum(d, 0.0), -np.inf)


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


    def points_free(self, points) -> np.ndarray:
        """bool [P]: camera ball at each point proven clear. Points in a free voxel of the occupancy grid are proven
        by the grid (occupancy.py: every point of a free voxel keeps the ball clear, with slack for rounding); the
        rest by the conservative Cor. 1 test. Both are conservative, never optimistic."""
        prep = self.ready()
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        free = self.in_free_voxel(pts)
        todo = np.flatnonzero(~free)
        if todo.size:
            p = torch.as_tensor(pts[todo], device=self.scene.device)  # float64 points
            free[todo] = (~points_collide(p, self.scene, prep.index)).cpu().numpy()
        return free

    def in_free_voxel(self, points) -> np.ndarray:
        """bool [P]: the point lies in a free voxel of the (conservative) occupancy grid; False outside the grid."""
        prep = self.ready()
        grid, occ = prep.grid, prep.astar_grid._occ
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        lo, vs = grid.lo.detach().cpu().double().numpy(), float(grid.voxel_size)
        ijk = np.floor((pts - lo) / vs).astype(np.int64)
        shape = np.array(occ.shape)
        inside = ((ijk >= 0) & (ijk < shape)).all(1)
        c = np.clip(ijk, 0, shape - 1)
        return inside & ~occ[c[:, 0], c[:, 1], c[:, 2]]

    def free_test(self, points: Tensor) -> Tensor:
        # goal/start acceptance only needs a proof of freedom: the conservative test is exact enough
        return torch.as_tensor(self.points_free(points.detach().cpu().numpy()))

    def main_component(self) -> int:
        """The free component random starts come from: the one with the most free voxels inside the
        start region when one is set (a room's interior, where the capture's cameras were: the shell of
        free space *outside* the walls inside the planning bounds can be larger), else preferred_component's choice
        (a large enclosed component, else the largest).
        Constant per prepared scene: computed once, not per request."""
        prep = self.ready()
        key = (prep, self.config.start_region)
        cached = getattr(self, "_main_component_of", None)
        if cached is not None and cached[0][0] is key[0] and cached[0][1] is key[1]:
            return cached[1]
        comp = self._largest_component(prep)
        self._main_component_of = (key, comp)
        return comp

    def _largest_component(self, prep: PreparedScene) -> int:
        labels = prep.astar_grid.labels  # [X, Y, Z] 0: occupied, k >= 1: free component k
        if self.config.start_region is not None:
            grid = prep.grid
            lo, hi = (torch.as_tensor(np.asarray(v, dtype=np.float64), device=grid.device) for v in self.config.start_region)
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

    # ------------------------------------------------------------------ planning
    def plan(
        self,
        goal: ArrayLike,
        look_at: ArrayLike,
        start: Optional[ArrayLike] = None,
        seed: int = 0,
        n_candidates: int = 1,
        force_start: bool = False,
    ) -> list[Shot]:
        """Plan ``n_candidates`` shots ending as close as safely possible to ``goal`` and always
        looking at ``look_at``. With ``start`` all candidates start there (n_candidates is then 1);
        otherwise starts are sampled free and reachable with the seeded generator. A start outside the planning
        region is an error unless ``force_start`` (the region then grows to hold it).

        Raises InvalidInputError, StartInCollisionError, GoalUnreachableError (see messages).
        Every returned shot's exact clearance along the densely sampled curve is >= 0; explain_goal says why a
        shot ends away from ``goal``."""
        with self.request_threads():
            return self._plan_request(goal, look_at, start, seed, n_candidates, force_start)

    @contextlib.contextmanager
    def request_threads(self):
        """torch CPU threads = config.plan_cpu_threads while a request runs (restored afterwards): a plan is
        many small ops, for which extra threads cost more than they give (measured ~5x on a busy 2-core box)."""
        threads, old = self.config.plan_cpu_threads, torch.get_num_threads()
        on_cpu = self.scene.device.type == "cpu" or self._mirror_to_cpu()  # the mirror exists once prepared
        swap = threads is not None and on_cpu and int(threads) != old
        if swap:
            torch.set_num_threads(int(threads))
        try:
            yield
        finally:
            if swap:
                torch.set_num_threads(old)

    def random_starts(self, n: int, generator: torch.Generator, look_at: np.ndarray) -> Tensor:
        """n random collision-free starts [n, 3] (goal.sample_free_starts) as every request draws them: in
        config.start_region, in the main free component, config.start_look_distance away from ``look_at`` [3] where
        the region allows."""
        prep = self.ready()
        lo, hi = self.config.start_region or (None, None)
        return sample_free_starts(
            n, self.scene, prep.index, prep.grid, generator=generator, region_lo=lo, region_hi=hi,
            reachable=prep.astar_grid.labels == self.main_component(), clearance_fn=self.free_test,
            away_from=look_at, away_fraction=self.config.start_look_distance,
        )

    def checked_start(self, start: ArrayLike, force: bool = False) -> np.ndarray:
        """A user-given start [3] as float64: InvalidInputError when it lies outside the planning region (unless
        ``force``: the region then grows to hold it, see grow_region), StartInCollisionError when the camera would be
        inside the scene. Only the sign of the clearance is needed: a proof from the grid, else a capped distance."""
        s = self.checked_point(start, "start point")
        if self.distance_outside(s) > 0:
            if not force:
                lo, hi = self.region()
                raise InvalidInputError(
                    f"the start point {_fmt(s)} is outside the planning region {_fmt(lo)}..{_fmt(hi)} (the training "
                    f"cameras' box grown by region_padding, or the scene's box); pick a start inside it or force it "
                    f"(cinesplat-plan --force-start: the region then grows to hold the start)")
            self.grow_region(s)
        if bool(self.points_free(s[None])[0]):
            return s
        c = float(self.clearance(s[None], cap=float(self.ready().grid.voxel_size))[0])
        if c < 0:
            raise StartInCollisionError(
                f"the start {np.round(s, 4).tolist()} puts the camera inside the scene (clearance {c:.4f}); "
                f"pick another start or use a random start"
            )
        return s

    def _plan_request(
        self,
        goal: ArrayLike,
        look_at: ArrayLike,
        start: Optional[ArrayLike] = None,
        seed: int = 0,
        n_candidates: int = 1,
        force_start: bool = False,
    ) -> list[Shot]:
        """The body of :meth:`plan` (which sets the request's thread count)."""
        if int(n_candidates) != n_candidates or not 1 <= n_candidates <= MAX_CANDIDATES:
            raise InvalidInputError(f"number of candidates must be an integer in [1, {MAX_CANDIDATES}], got {n_candidates}")
        self.ready()  # prepare on first use, before the request clock starts
        goal_p = self.checked_point(goal, "go-to point")
        look_p = self.checked_point(look_at, "look-at point")
        self.check_timing()
        t_req = time.perf_counter()

        check_ms = None
        if start is not None:
            starts = [self.checked_start(start, force=force_start)]
            check_ms = 1e3 * (time.perf_counter() - t_req)  # a given start's region + sign-of-clearance check
            n_candidates = 1
        else:
            starts = []
        gen = torch.Generator().manual_seed(int(seed))
        shots: list[Shot] = []
        errors: list[str] = []
        goal_cache: dict[int, np.ndarray] = {}
        attempts = 0
        max_attempts = n_candidates * self.config.max_attempts_per_candidate
        pending = list(starts)
        while len(shots) < n_candidates and attempts < max_attempts:
            if not pending:
                k = n_candidates - len(shots)
                t0 = time.perf_counter()
                pts = self.random_starts(k, gen, look_p)
                sample_ms = 1e3 * (time.perf_counter() - t0) / k
                pending = [(p.cpu().numpy(), sample_ms) for p in pts]
            item = pending.pop(0)
            s, sample_ms = (item, 0.0) if isinstance(item, np.ndarray) else item
            attempts += 1
            try:
                shots.append(stages.plan_leg(self, s, goal_p, look_p, goal_cache, sample_ms))
            except (GoalUnreachableError, CorridorError, StartInCollisionError) as e:
                errors.append(str(e))
                if start is not None:
                    raise
        if not shots:
            raise GoalUnreachableError(
                f"no safe shot found after {attempts} start(s); last reason: {errors[-1] if errors else 'unknown'}"
            )
        for sh in shots:
            sh.timings["request_total_ms"] = 1e3 * (time.perf_counter() - t_req)
            if check_ms is not None:
                sh.timings["start_check_ms"] = check_ms
        return shots
