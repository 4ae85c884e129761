"""``cinesplat-plan``: plan camera shots through a splat from the command line (no viewer, no GPU needed).

    cinesplat-plan --scene outputs/room/cinesplat/<run>/config.yml --go-to "armchair" --look-at "floor lamp"
    cinesplat-plan --scene scene.ply --go-to "0.1 0.2 0.3" --look-at "0 0 0.2" --candidates 4
    cinesplat-plan --scene procedural --go-to armchair --look-at "floor lamp"
    cinesplat-plan --scene procedural --go-to armchair --then-go-to sofa table --look-at "floor lamp" \\
        --max-angular-rate 45

With random starts the candidates are planned, scored (occlusion of the look-at object, framing, clearance,
smoothness, duration; planner/shots/scoring.py) and ranked: rank 1 is written as ``<name>_0.json``, rank 2 as
``<name>_1.json``, ...; the table and the report state every score term.

Targets are "x y z" points (scene units, nerfstudio's normalised coordinates for checkpoints) or text. Every option
is checked before the scene is loaded; errors go to stderr with exit status 2 and leave no file behind. The outputs
(camera paths, report, plots) appear together at the end or not at all.
"""
from __future__ import annotations

import json
import os
import re
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Literal, Optional, Tuple

import numpy as np
import tyro
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

from cinenerf_ns.console_text import error_line, lit
from cinenerf_ns.method.semantic_scene import CENTRE_RELEVANCY, OBJECT_CLUSTER, SMOOTH_NEIGHBORS
from cinenerf_ns.options import check_device, check_number
from cinenerf_ns.output_set import OutputSet, check_file_size_limit, check_name, check_writable
from cinenerf_ns.planner.errors import InvalidInputError, PlanningError
from cinenerf_ns.planner.scene.ellipsoids import DEFAULT_SAFETY_MARGIN, SceneConfig
from cinenerf_ns.planner.scene.floaters import apply_floater_rule
from cinenerf_ns.planner.scene.planning_region import user_box
from cinenerf_ns.planner.shots import stages
from cinenerf_ns.planner.shots.camera_path import (
    DEFAULT_FOV_DEG,
    DEFAULT_PREVIEW_FPS,
    DEFAULT_PREVIEW_SIZE,
    DEFAULT_RENDER_SIZE,
    shot_to_camera_path,
    write_camera_path,
)
from cinenerf_ns.planner.shots.candidates import RankedShot, plan_candidates, score_shots
from cinenerf_ns.planner.shots.framing import FramingConfig
from cinenerf_ns.planner.shots.multistop import plan_multistop
from cinenerf_ns.planner.shots.planner import GRID_RESOLUTION_RANGE, MAX_CANDIDATES, Planner, PlannerConfig
from cinenerf_ns.planner.shots.safety import plot_clearance, plot_paths_topdown
from cinenerf_ns.planner.shots.scoring import ScoreConfig
from cinenerf_ns.planner.trajectory.dynamics import DynamicLimits, retime_shot
from cinenerf_ns.planner.trajectory.timing import MAX_FPS, MIN_FPS, TimingConfig
from cinenerf_ns.scenes import LoadedScene, _word_match, load_scene, parse_point, resolve_match
from cinenerf_ns.shot_targets import ShotTargets, end_pose_count, shot_targets, start_region_centre
from cinenerf_ns.signals import interrupted, signals_as_interrupts

CONSOLE = Console(emoji=False)  # user text is printed as typed (console_text)
ERRORS = Console(stderr=True, emoji=False)


@dataclass
class PlanArgs:
    """Plan camera shots: go to one thing, look at another."""

    scene: str
    """A cinesplat/splatfacto run (config.yml, its folder or a .ckpt), a compact export (.npz/.pt), a 3DGS .ply,
    or 'procedural[:N[:SEED]]' (a generated test room with known object names)."""
    go_to: str
    """Where the camera should end: text (needs a semantic scene) or 'x y z'."""
    look_at: str
    """What every frame looks at: text or 'x y z'."""
    framing: Literal["wide", "medium", "close"] = "medium"
    """How large the look-at object is in the last frame: wide 0.15-0.35, medium 0.35-0.6, close 0.6-0.85 of the
    frame (its larger relative extent), kept whole in frame."""
    end_pose: bool = True
    """With an object as go-to: end at a free viewpoint near it that frames the look-at object (chosen by visibility
    through the splat, framing and distance; the same object twice means a good view of it). --no-end-pose: end at
    the go-to object's centre, moved to the nearest safe point (what a point go-to always does)."""
    start: Optional[str] = None
    """Start point 'x y z' inside the planning region; default: random collision-free starts (seeded)."""
    force_start: bool = False
    """Plan from a --start outside the planning region (the region grows to hold it) instead of refusing it."""
    seed: int = 0
    """Seed of the random starts (same seed, same starts)."""
    start_look_distance: float = PlannerConfig.start_look_distance
    """Random starts keep at least this fraction of the start region's longest side from the look-at point when the
    region allows (an opening frame that shows the subject). 0: uniform random starts. Ignored with --start."""
    candidates: int = 1
    """Number of shots from different random starts, 1-64."""
    time_budget: float = 60.0
    """Seconds the candidates may take: once over it, no further candidate is started (fewer come back, reported)."""
    workers: Optional[int] = None
    """Worker processes that plan the candidates in parallel (Linux, fork). None: one per CPU on machines with
    >= 4 CPUs, else 0 (plan in this process)."""
    output_dir: Path = Path("cinesplat_plans")
    """Where camera paths, the report and the plots go."""
    name: str = "shot"
    """File name stem of the outputs (letters, digits, '.', '_', '-')."""
    preview: bool = False
    """Also render each candidate as a video on the CPU (SH degree 0): <name>_<k>_preview.mp4 and a contact sheet
    PNG."""
    preview_size: Tuple[int, int] = DEFAULT_PREVIEW_SIZE
    """Width and height of the preview videos, pixels (16-4096 each)."""
    preview_fps: float = DEFAULT_PREVIEW_FPS
    """Frame rate of the preview videos (1-120; frames are taken from the camera path, never interpolated)."""
    fps: float = TimingConfig.fps
    """Frames per second of the exported path, 1-240."""
    max_speed: float = TimingConfig.max_speed
    """Camera speed cap, scene units per second."""
    fov: float = DEFAULT_FOV_DEG
    """Vertical field of view of the exported camera, degrees (1-179)."""
    width: int = DEFAULT_RENDER_SIZE[0]
    """Render width written into the camera path, pixels."""
    height: int = DEFAULT_RENDER_SIZE[1]
    """Render height written into the camera path, pixels."""
    camera_radius: float = SceneConfig.camera_radius
    """Camera body sphere radius, scene units (paper: 0.03)."""
    safety_margin: float = DEFAULT_SAFETY_MARGIN
    """Extra distance (scene units) kept from every ellipsoid on top of camera_radius: a splat only approximates the
    real surfaces. Clearances in the report are measured from the camera sphere grown by this margin."""
    beta: float = SceneConfig.beta
    """Ellipsoid size in sigmas (paper: 2), scaled by each Gaussian's opacity."""
    opacity_floor: float = SceneConfig.opacity_floor
    """Gaussians below this opacity are not obstacles."""
    region: Optional[str] = None
    """Planning region 'x0 y0 z0 x1 y1 z1' (two corners, scene units): every path stays in it. Default: the region
    stored in a compact export, else the training cameras' box grown, else the box of the dense content (far background,
    sky and floaters do not stretch it); the report says which rule chose it."""
    ignore_floaters: Literal["auto", "on", "off"] = "off"
    """Treat small, faint, isolated Gaussians (a capture's noise in the air) as non-obstacles: on, off, or auto (on
    when they are at least 1% of the Gaussians). The rule is in the report, with how many were ignored; shots are
    verified against the obstacles that remain (cinenerf_ns/planner/scene/floaters.py)."""
    grid_resolution: int = PlannerConfig.grid_resolution
    """A* voxels along the longest side of the planning region (8-1024, within --memory-budget-mb)."""
    memory_budget_mb: float = PlannerConfig.memory_budget_mb
    """Memory the voxel grid may take, MB; a finer grid is refused with the largest resolution that fits."""
    grid_polytopes: Literal["auto", "on", "off"] = "auto"
    """Corridor polytopes from the occupancy grid where the path lies in free voxels (same safety, cheaper, up to a
    voxel more conservative); auto: on when the voxels are at most 2 camera radii."""
    threshold: Optional[float] = None
    """Relevancy threshold of text queries, in (0, 1) (default: the scene's)."""
    semantic_smoothing: int = SMOOTH_NEIGHBORS
    """Average each Gaussian's latent over this many nearest Gaussians before text queries (0: off; once per load)."""
    object_cluster: float = OBJECT_CLUSTER
    """A text target is the heaviest spatial cluster of the selected Gaussians, binned at this fraction of the scene's
    extent (0: all selected Gaussians): one object, not the centroid of scattered matches."""
    object_centre: Literal["volume", "surface"] = "volume"
    """Where a text target is: 'volume' (the selected object's estimated volume centroid,
    cinenerf_ns/method/object_centre.py) or 'surface' (opacity-weighted mean of its Gaussians)."""
    keep_support: bool = False
    """Keep the floor / table layer under a text target in its selection (by default it is dropped: features bleed
    across contact, cinenerf_ns/method/object_support.py)."""
    centre_relevancy: float = CENTRE_RELEVANCY
    """Estimate a text target's centre only from its Gaussians with relevancy above this, in [0, 1) (the confident
    core; the whole selection when the core is under a quarter of it). 0: off."""
    no_unseen_fill: bool = False
    """Estimate a text target's volume centre from its Gaussians alone, without filling the part of the object that
    no training camera saw."""
    device: str = "cpu"
    """torch device of the scene tensors ('cpu' or 'cuda')."""
    up: Tuple[float, float, float] = (0.0, 0.0, 1.0)
    """World up direction (nerfstudio scenes: +z)."""
    then_go_to: Tuple[str, ...] = ()
    """Further stops after --go-to, in order (text or 'x y z' each): one smooth shot through all stops."""
    then_look_at: Tuple[str, ...] = ()
    """Look-at of each further stop (one per --then-go-to); empty: every stop looks at --look-at."""
    max_acceleration: Optional[float] = None
    """Acceleration limit of the exported frames, units/s^2 (enables dynamic limits; default 0.5 when another limit
    is set)."""
    max_angular_rate: Optional[float] = None
    """Limit on how fast the view direction turns, deg/s (enables dynamic limits; default 60)."""
    object_radius: Optional[float] = None
    """Bounding-sphere radius of the look-at object for scoring (framing size; sight lines stop at it). Default: the
    procedural object's half diagonal, else 0.1."""
    score: ScoreConfig = field(default_factory=ScoreConfig)
    """Weights of the shot score (its fov_deg is replaced by --fov)."""


def check_args(args: PlanArgs) -> None:
    """Every option that can be judged without the scene, before anything is loaded or written. The scene-relative
    checks (points near the scene, camera radius against its size, grid against memory, frames) follow in the
    planner (Planner.checked_point, check_region, check_timing)."""
    if not isinstance(args.scene, str) or not args.scene.strip():
        raise InvalidInputError("--scene is empty: give a run's config.yml, a compact export, a .ply or 'procedural'")
    check_number(args.candidates, "--candidates", 1, MAX_CANDIDATES, integer=True)
    check_number(args.time_budget, "--time-budget", 0, 3600, lo_open=True)
    check_number(args.seed, "--seed", 0, 2**63 - 1, integer=True)
    check_number(args.fps, "--fps", MIN_FPS, MAX_FPS)
    check_number(args.max_speed, "--max-speed", 0, 100, lo_open=True)
    check_number(args.fov, "--fov", 1, 179)
    check_number(args.width, "--width", 16, 8192, integer=True)
    check_number(args.height, "--height", 16, 8192, integer=True)
    check_number(args.camera_radius, "--camera-radius", 0, 10)
    check_number(args.safety_margin, "--safety-margin", 0, 10)
    check_number(args.beta, "--beta", 0, 10, lo_open=True)
    check_number(args.opacity_floor, "--opacity-floor", 0, 0.999)
    check_number(args.grid_resolution, "--grid-resolution", *GRID_RESOLUTION_RANGE, integer=True)
    check_number(args.memory_budget_mb, "--memory-budget-mb", 64, 2**20)
    check_number(args.semantic_smoothing, "--semantic-smoothing", 0, 256, integer=True)
    check_number(args.object_cluster, "--object-cluster", 0, 0.5)
    check_number(args.start_look_distance, "--start-look-distance", 0, 0.99)
    if not (0.0 <= args.centre_relevancy < 1.0):
        raise InvalidInputError(f"--centre-relevancy must be in [0, 1) (0: the centre from the whole selection), "
                                f"got {args.centre_relevancy}")
    if args.threshold is not None:
        check_number(args.threshold, "--threshold", 0, 0.999, lo_open=True)
    if args.workers is not None:
        check_number(args.workers, "--workers", 0, 256, integer=True)
    if args.max_acceleration is not None:
        check_number(args.max_acceleration, "--max-acceleration", 0, 1000, lo_open=True)
    if args.max_angular_rate is not None:
        check_number(args.max_angular_rate, "--max-angular-rate", 0, 3600, lo_open=True)
    if args.object_radius is not None:
        check_number(args.object_radius, "--object-radius", 0, 100)
    args.up = unit_up(args.up)
    args.device = check_device(args.device)
    if args.then_look_at and len(args.then_look_at) != len(args.then_go_to):
        raise InvalidInputError(f"--then-look-at needs one look-at per --then-go-to ({len(args.then_go_to)}), got "
                                f"{len(args.then_look_at)}")
    if args.start is not None:
        p = parse_point(args.start)
        if p is None or not np.all(np.isfinite(p)):
            raise InvalidInputError(f"--start must be a point 'x y z' of three finite numbers, got {args.start!r}")
    _check_targets(args)
    if args.region is not None:
        parse_region(args.region)
    check_name(args.name)
    if args.preview:
        for v, opt in zip(args.preview_size, ("--preview-size (width)", "--preview-size (height)")):
            check_number(v, opt, 16, 4096, integer=True)
        check_number(args.preview_fps, "--preview-fps", 1, 120)
    check_writable(Path(args.output_dir))
    check_file_size_limit(Path(args.output_dir))
    args.score.validate()
    _framing(args).validate()


def unit_up(up: Any) -> Tuple[float, float, float]:
    """--up as a unit vector, scaled by its largest component before its norm is taken (0 1e300 0 is +y, not a
    zero vector from an overflowed norm); InvalidInputError when it is not three finite numbers, not all zero."""
    try:
        u = np.asarray(up, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        u = np.full(1, np.nan)
    big = float(np.abs(u).max()) if u.size else 0.0
    if u.shape != (3,) or not np.all(np.isfinite(u)) or big == 0.0:
        raise InvalidInputError(f"--up must be three finite numbers, not all zero, got {tuple(up)}")
    u = u / big
    u = u / np.linalg.norm(u)
    return (float(u[0]), float(u[1]), float(u[2]))


def _check_targets(args: PlanArgs) -> None:
    """Targets that need no scene to be judged: points given as 'x y z' are finite, stops differ from the stop
    before them (a leg from a stop to itself)."""
    stops = [("--go-to", args.go_to)] + [(f"--then-go-to (stop {i + 2})", t) for i, t in enumerate(args.then_go_to)]
    looks = [("--look-at", args.look_at)] + [(f"--then-look-at (stop {i + 2})", t)
                                             for i, t in enumerate(args.then_look_at)]
    for opt, text in stops + looks:
        p = parse_point(text) if isinstance(text, str) else None
        if p is not None and not np.all(np.isfinite(p)):
            what = "go-to" if "go-to" in opt else "look-at"
            raise InvalidInputError(f"the {what} point {text!r} is not finite ({opt}): give three finite numbers "
                                    f"'x y z'")

    def key(text: str):
        p = parse_point(text)
        return tuple(p.tolist()) if p is not None else " ".join(text.lower().split())

    for (o1, t1), (o2, t2) in zip(stops, stops[1:]):
        if isinstance(t1, str) and isinstance(t2, str) and key(t1) == key(t2):
            raise InvalidInputError(f"{o2} {t2!r} repeats the stop before it ({o1}): consecutive stops must differ")


def available_memory_mb() -> Optional[float]:
    """Memory this process may still take, MB: the machine's available memory (MemAvailable) and the address-space
    limit (ulimit -v) less what the process maps now, the smaller; None when unknown."""
    found = []
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    found.append(int(line.split()[1]) / 1024)
    except (OSError, ValueError, IndexError):
        pass
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        if soft != resource.RLIM_INFINITY:
            with open("/proc/self/statm") as f:
                mapped = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
            found.append(max(soft - mapped, 0) / 2**20)
    except (ImportError, OSError, ValueError, IndexError):
        pass
    return min(found) if found else None


def _memory_budget(args: PlanArgs, console: Console) -> float:
    """--memory-budget-mb trusted only up to the memory available: a larger explicit budget is refused, the default
    is lowered to what is available (said)."""
    avail = available_memory_mb()
    budget = float(args.memory_budget_mb)
    if avail is None or budget <= avail:
        return budget
    if budget != PlannerConfig.memory_budget_mb:
        raise InvalidInputError(f"--memory-budget-mb {budget:g} is more than the memory available to this process "
                                f"(about {avail:.0f} MB: free memory and ulimit -v); give at most {avail:.0f}")
    lowered = max(64.0, float(int(avail)))
    console.print(f"note: memory budget {lowered:.0f} MB (the default {budget:g} MB is more than the memory available "
                  f"to this process)", markup=False, highlight=False)
    return lowered


def _workers(args: PlanArgs, console: Console) -> Optional[int]:
    """--workers capped by the CPUs this process may use and the candidates (said when capped); the default (one
    per CPU on >= 4 CPUs) is capped by the candidates too."""
    from cinenerf_ns.planner.shots.workers import default_workers, usable_cpus

    if args.workers is None:
        auto = default_workers()
        return None if auto <= args.candidates else (args.candidates if args.candidates > 1 else 0)
    if args.workers <= 1:
        return args.workers
    cap = min(usable_cpus(), args.candidates)
    if args.workers <= cap:
        return args.workers
    console.print(f"note: --workers {args.workers} capped to {cap} ({usable_cpus()} usable CPUs, {args.candidates} "
                  f"candidate(s))", markup=False, highlight=False)
    return cap


def parse_region(text: str) -> Tuple[np.ndarray, np.ndarray]:
    """--region 'x0 y0 z0 x1 y1 z1' -> (lo [3], hi [3]); InvalidInputError unless 6 finite numbers with lo < hi on
    every axis (planning_region.user_box)."""
    tokens = [t for t in re.split(r"[\s,;\[\]()]+", str(text).strip()) if t]
    try:
        vals = [float(t) for t in tokens]
    except ValueError as e:
        raise InvalidInputError(f"--region must be 6 numbers 'x0 y0 z0 x1 y1 z1', got {text!r}") from e
    return user_box(vals, "the planning region (--region)")


def _region_config(args: PlanArgs, loaded: LoadedScene) -> Dict[str, Any]:
    """PlannerConfig's bounds / bounds_rule: --region, else the region a compact export stores, else none (the
    planner's rules)."""
    if args.region is not None:
        return {"bounds": parse_region(args.region), "bounds_rule": "user box"}
    stored = loaded.planning_region
    if stored is not None:
        return {"bounds": stored, "bounds_rule": "stored in the export"}
    return {}


def _obstacles_near_paths(means: np.ndarray, shots, up: np.ndarray, band: float = 0.1) -> np.ndarray:
    """Gaussian centres at the cameras' heights (+- band along `up`): a top view of everything would show
    only floor and ceiling."""
    up = up / np.linalg.norm(up)
    h = means @ up
    ph = np.concatenate([sh.positions @ up for sh in shots]) if shots else h
    keep = (h >= ph.min() - band) & (h <= ph.max() + band)
    return means[keep]


def _object_radius(args: PlanArgs, loaded: LoadedScene) -> float:
    if args.object_radius is not None:
        return float(args.object_radius)
    if loaded.kind == "procedural" and parse_point(args.look_at) is None:
        objs = loaded.room.objects
        i = _word_match(args.look_at, [o.name for o in objs])
        if i is not None:
            return float(0.5 * np.linalg.norm(objs[i].size))
    return 0.1


def _limits(args: PlanArgs) -> Optional[DynamicLimits]:
    if args.max_acceleration is None and args.max_angular_rate is None:
        return None
    return DynamicLimits(
        max_speed=args.max_speed, fps=args.fps,
        max_acceleration=DynamicLimits.max_acceleration if args.max_acceleration is None else args.max_acceleration,
        max_angular_rate_deg=(DynamicLimits.max_angular_rate_deg if args.max_angular_rate is None
                              else args.max_angular_rate),
    )


def _framing(args: PlanArgs) -> FramingConfig:
    return FramingConfig(args.framing, float(args.fov), float(args.width) / float(args.height))


def _targets(args: PlanArgs, planner: Planner, loaded: LoadedScene, gm: Dict[str, Any], lm: Dict[str, Any],
             start: Optional[np.ndarray]) -> Optional[ShotTargets]:
    """The look-at subject and, for an object go-to, the end poses (shot_targets.py); None for multi-stop shots."""
    if args.then_go_to:
        return None
    if start is not None:
        start = planner.checked_start(start, force=args.force_start)  # may grow the region: before the component
        comp, facing = stages.start_voxel(planner, start)[1], start
    else:
        comp, facing = planner.main_component(), start_region_centre(planner)
    k = 1 if start is not None else end_pose_count(args.candidates)
    return shot_targets(planner, gm, lm, _framing(args), comp, k=k, object_radius=_object_radius(args, loaded),
                        end_pose=args.end_pose, facing_from=facing)


def _plan_shots(args: PlanArgs, planner: Planner, loaded: LoadedScene, goal: np.ndarray, look: np.ndarray,
                start: Optional[np.ndarray], stops: list, stop_looks: list, timings: Dict[str, float],
                targets: Optional[ShotTargets]) -> tuple:
    """(shots, scores, multi-stop shot or None, object radius, score config, candidate ids) for the request the
    options describe; ``stops`` / ``stop_looks``: the points of --then-go-to / --then-look-at (resolved once, in
    run_plan); ``targets``: the subject and end poses (_targets)."""
    limits = _limits(args)
    obj_r = _object_radius(args, loaded)
    score_cfg = ScoreConfig(**{**args.score.__dict__, "fov_deg": args.fov})
    if args.then_go_to:
        looks = [look] + (stop_looks or [look] * len(stops))
        multi = plan_multistop(planner, [goal] + stops, np.stack(looks), start=start, seed=args.seed, limits=limits,
                               force_start=args.force_start)
        return [multi.shot], [None], multi, obj_r, score_cfg, [0]
    goals = targets.goals(goal)  # [P, 3]: end poses, or the go-to point
    subject = targets.samples
    if start is not None:
        shots = planner.plan(goals[0], look, start=start, seed=args.seed, n_candidates=1,
                             force_start=args.force_start)
        if limits is not None:
            shots = [retime_shot(sh, limits, up=planner.config.up) for sh in shots]
        scores = score_shots(planner, shots, look, score_cfg, object_radius=obj_r, subject=subject)
        return shots, scores, None, obj_r, score_cfg, [0]
    ranked: List[RankedShot] = plan_candidates(planner, goals if len(goals) > 1 else goals[0], look,
                                               k=args.candidates, seed=args.seed, score_config=score_cfg,
                                               limits=limits, object_radius=obj_r, timings=timings,
                                               time_budget_s=args.time_budget, subject=subject)
    return ([r.shot for r in ranked], [r.score for r in ranked], None, obj_r, score_cfg,
            [r.candidate for r in ranked])


def _write_outputs(args: PlanArgs, out: OutputSet, planner: Planner, loaded: LoadedScene, shots, goal, look,
                   reports, subject_points: Optional[np.ndarray] = None) -> tuple:
    """Camera paths and plots into the output set: (camera-path files as they will be named, plot files)."""
    files = []
    for k, sh in enumerate(shots):
        cp = shot_to_camera_path(sh, fov_deg=args.fov, width=args.width, height=args.height)
        write_camera_path(out.path(f"{args.name}_{k}.json"), cp)
        files.append(out.final(f"{args.name}_{k}.json"))
    plot_clearance(reports, out.path(f"{args.name}_clearance.png"))
    plot_paths_topdown(
        [sh.positions for sh in shots], out.path(f"{args.name}_topdown.png"),
        obstacles=_obstacles_near_paths(loaded.scene.means.detach().cpu().numpy(), shots, np.asarray(args.up, float)),
        targets={"go to": goal, "look at": look}, labels=[f"rank {k + 1}" for k in range(len(shots))],
    )
    plots = {"clearance": str(out.final(f"{args.name}_clearance.png")),
             "topdown": str(out.final(f"{args.name}_topdown.png"))}
    if args.preview:
        from cinenerf_ns.preview import preview_camera_path
        from cinenerf_ns.scenes import preview_scene

        scene = preview_scene(loaded)
        w, h = args.preview_size
        for k in range(len(shots)):
            res = preview_camera_path(scene, out.path(f"{args.name}_{k}.json"), out.staging,
                                      name=f"{args.name}_{k}_preview",
                                      width=w, height=h, fps=args.preview_fps, progress=False,
                                      subject_points=subject_points)
            plots[f"preview_{k}"] = str(out.final(Path(res["paths"]["mp4"]).name))
            plots[f"preview_sheet_{k}"] = str(out.final(Path(res["paths"]["contact_sheet"]).name))
    return files, plots


def _resolve(args: PlanArgs, planner: Planner, gm: Dict[str, Any], lm: Dict[str, Any]) -> tuple:
    """Targets and the given start checked against the planning region, with messages naming the options (the planning
    calls check them again, and the start's region, collision and the frame count, before any planning)."""
    goal = planner.checked_point(gm["point"], "go-to point (--go-to)")
    look = planner.checked_point(lm["point"], "look-at point (--look-at)")
    start = None if args.start is None else planner.checked_point(parse_point(args.start), "start point (--start)")
    return goal, look, start


def run_plan(args: PlanArgs, console: Console = CONSOLE) -> Dict[str, Any]:
    """Check the options, plan, and write the outputs all together; returns a summary dict (paths, per-candidate
    metrics). Raises InvalidInputError / PlanningError / CheckpointError with a message for the user."""
    check_args(args)
    memory_budget_mb = _memory_budget(args, console)
    workers = _workers(args, console)
    scfg = SceneConfig.with_margin(args.camera_radius, args.safety_margin, beta=args.beta,
                                   opacity_floor=args.opacity_floor)
    t_all = time.perf_counter()
    # auto_refresh=False: no refresh thread. plan_candidates forks worker processes, and a fork while another thread
    # holds an output lock can hang the child; the bar is redrawn at each stage instead (prog.update(refresh=True)).
    with Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(), console=console,
                  transient=True, auto_refresh=False) as prog:
        task = prog.add_task("loading scene", total=5)
        loaded = load_scene(args.scene, scfg, args.device, args.threshold, smooth_neighbors=args.semantic_smoothing,
                            object_cluster=args.object_cluster, object_centre=args.object_centre, up=args.up,
                            drop_support=not args.keep_support, centre_relevancy=args.centre_relevancy,
                            unseen_fill=not args.no_unseen_fill)
        for note in loaded.notes:
            console.print(f"note: {note}", markup=False, highlight=False)
        prog.update(task, advance=1, description="resolving targets", refresh=True)
        # text first: a query that matches nothing fails before the grid is built
        gm, lm = resolve_match(args.go_to, loaded, "go-to"), resolve_match(args.look_at, loaded, "look-at")
        stops = [resolve_match(t, loaded, f"go-to {i + 2}")["point"] for i, t in enumerate(args.then_go_to)]
        stop_looks = [resolve_match(t, loaded, f"look-at {i + 2}")["point"] for i, t in enumerate(args.then_look_at)]
        prog.update(task, advance=1, description="preparing (index, occupancy grid)", refresh=True)
        loaded.scene, floaters = apply_floater_rule(loaded.scene, args.ignore_floaters)
        pcfg = PlannerConfig(
            grid_resolution=args.grid_resolution, up=tuple(args.up),
            timing=TimingConfig(max_speed=args.max_speed, fps=args.fps),
            start_region=loaded.start_region, candidate_workers=workers, memory_budget_mb=memory_budget_mb,
            start_look_distance=args.start_look_distance,
            grid_polytopes={"auto": "auto", "on": True, "off": False}[args.grid_polytopes],
            **_region_config(args, loaded), obstacles_note=floaters.obstacle_note(),
        )
        planner = Planner(loaded.scene, pcfg)
        prep = planner.prepare()
        goal, look, start = _resolve(args, planner, gm, lm)
        prog.update(task, advance=1, description=f"choosing the end pose, planning {args.candidates} candidate(s)",
                    refresh=True)
        t_req = time.perf_counter()
        targets = _targets(args, planner, loaded, gm, lm, start)
        batch_tm: Dict[str, float] = {}
        shots, scores, multi, obj_r, score_cfg, cands = _plan_shots(args, planner, loaded, goal, look, start, stops,
                                                                    stop_looks, batch_tm, targets)
        request_ms = 1e3 * (time.perf_counter() - t_req)
        prog.update(task, advance=1, refresh=True, description="exact clearance report + plots"
                    + (" + preview videos" if args.preview else ""))
        reports = [planner.clearance_report(sh, max_spacing=0.02, label=f"rank {k + 1}") for k, sh in enumerate(shots)]
        at_poses = targets is not None and targets.ends_at_poses  # else the go-to point (or the multi-stop's)
        moves = [planner.explain_goal(sh.goal_target if at_poses else goal if multi is None
                                      else multi.shot.goal_target, sh.goal) for sh in shots]
        views = [None if targets is None else
                 targets.view_report(sh.positions[-1], look, args.up, None if scores[k] is None else scores[k].terms)
                 for k, sh in enumerate(shots)]
        with OutputSet(Path(args.output_dir), args.name) as out:
            extent = None if targets is None else targets.subject.extent[:: max(1, len(targets.subject.extent) // 64)]
            files, plots = _write_outputs(args, out, planner, loaded, shots, goal, look, reports, extent)
            summary = _summary(args, loaded, planner, prep, gm, lm, goal, look, shots, scores, multi, reports, moves,
                               files, plots, obj_r, score_cfg, batch_tm)
            summary["request_ms"] = request_ms
            summary["end_pose"] = None if targets is None or targets.choice is None else targets.choice.to_dict()
            summary["end_pose_note"] = None if targets is None else targets.note()
            summary["look_at"]["extent_points"] = None if extent is None else extent.tolist()  # the sheets' marker
            for k, c in enumerate(summary["candidates"]):
                c["subject_view"] = views[k]
                c["end_pose"] = None if targets is None else targets.pose_of(cands[k])
            summary["floaters"] = floaters.to_dict()
            summary["total_s"] = time.perf_counter() - t_all
            rpath = out.final(f"{args.name}_report.json")
            summary["report"] = str(rpath)
            Path(out.path(rpath.name)).write_text(json.dumps(
                summary, indent=2, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
        prog.update(task, advance=1, refresh=True)
    _print_summary(args, console, loaded, gm, lm, shots, scores, multi, reports, moves, files, summary, views)
    return summary


def _summary(args, loaded, planner, prep, gm, lm, goal, look, shots, scores, multi, reports, moves, files, plots,
             obj_r, score_cfg, batch_tm) -> Dict[str, Any]:
    """The report's JSON content."""
    lo, hi = planner.region()
    strip = lambda m: {k: v for k, v in m.items() if k not in ("point", "mask")}  # noqa: E731
    return {
        "scene": loaded.source,
        "go_to": {**strip(gm), "point": goal.tolist(), "resolved": gm["description"]},
        "look_at": {**strip(lm), "point": look.tolist(), "resolved": lm["description"]},
        "planning_region": {"lo": lo.tolist(), "hi": hi.tolist(), "rule": planner.region_rule()},
        "prepare_ms": prep.timings_ms,
        "camera_radius": args.camera_radius,
        "safety_margin": args.safety_margin,
        "clearance_note": "clearances are measured from the camera sphere of radius camera_radius + safety_margin",
        "requested_candidates": args.candidates,
        "stopped_by_time_budget": bool(batch_tm.get("budget_stopped")),
        "candidates": [
            {**(multi.to_dict() if multi is not None else sh.to_dict()), "rank": k + 1,
             "score": None if scores[k] is None else scores[k].to_dict(),
             "dynamics": getattr(sh, "dynamics", None) if multi is None else multi.dynamics,
             "camera_path": str(files[k]), "goal_moved": moves[k],
             "refinement": getattr(sh, "refinement", None),
             "exact_clearance": {kk: v for kk, v in reports[k].items() if kk not in ("times", "clearance")},
             "verification": sh.safety}
            for k, sh in enumerate(shots)
        ],
        "object_radius": obj_r,
        "score_config": score_cfg.__dict__,
        "clearance_samples": [{"times": r["times"], "clearance": r["clearance"]} for r in reports],
        "plots": plots,
    }


def _print_summary(args, console, loaded, gm, lm, shots, scores, multi, reports, moves, files, summary, views) -> None:
    table = Table(title=Text(f"cinesplat-plan: go to {gm['description']}, look at {lm['description']}"))
    # short headers, no wrapping: the table must stay readable in an 80-column terminal (legend below)
    wide = console.width >= 140
    cols = ["#", "score", "seen", "end", "size", "min clr", "len", "dur s", "file"]
    if wide:
        cols[5:5] = ["start", "mean clr", "jerk", "turn", "peak v/a/w"]
    for col in cols:
        table.add_column(col, no_wrap=True)
    for k, sh in enumerate(shots):
        sc = scores[k]
        dyn = getattr(sh, "dynamics", None) if multi is None else multi.dynamics
        peaks = ("-" if not dyn else
                 f"{dyn['peak_speed']:.2f}/{dyn['peak_acceleration']:.2f}/{dyn['peak_angular_rate_deg']:.0f}")
        t = sc.terms if sc is not None else {}
        f = lambda key, fmt: "-" if key not in t else format(t[key], fmt)  # noqa: E731
        v = views[k] or {}
        pct = lambda x: "-" if x is None else f"{100 * x:.0f}%"  # noqa: E731
        seen = None if "occluded_fraction" not in t else 1.0 - t["occluded_fraction"]
        row = [str(k + 1), "-" if sc is None else f"{sc.total:.3f}", pct(seen), pct(t.get("visible_last")),
               "-" if "size_last" not in v else f"{v['size_last']:.2f}",
               f"{reports[k]['min_clearance']:.4f}", f"{sh.length:.2f}", f"{sh.duration:.1f}", Path(files[k]).name]
        if wide:
            row[5:5] = [",".join(f"{v:.2f}" for v in sh.start), f"{reports[k]['mean_clearance']:.3f}",
                        f("mean_jerk", ".1f"), f("mean_angular_rate_deg", ".0f"), peaks]
        table.add_row(*row)
    console.print(table)
    reg = summary["planning_region"]
    console.print(f"planning region {_fmt3(reg['lo'])}..{_fmt3(reg['hi'])} ({reg['rule']}); obstacles: "
                  f"{summary['floaters']['obstacles']}")
    console.print("score: lower is better (every term in the report); seen: frames with at least half of the look-at "
                  "object visible; end: its visible share in the last frame; size: its size in the last frame "
                  f"({args.framing}: {_framing(args).band[0]:g}-{_framing(args).band[2]:g}); clr/len in scene units"
                  + ("; peak: speed / acceleration / view rotation deg/s" if wide else "")
                  + ("" if wide else " (wider terminal: more columns)")
                  + f"; files in {lit(Path(args.output_dir).absolute())}/", emoji=False)
    if summary["stopped_by_time_budget"]:
        console.print(f"[yellow]note: {len(shots)} of {args.candidates} candidates planned within --time-budget "
                      f"{args.time_budget:g} s[/yellow]")
    elif len(shots) < args.candidates and multi is None and args.start is None:
        console.print(f"[yellow]note: {len(shots)} of {args.candidates} candidates could be planned[/yellow]")
    if summary.get("end_pose_note"):
        console.print(f"[cyan]end pose: {escape(summary['end_pose_note'])}[/cyan]")
    for k, mv in enumerate(moves):
        if mv is not None:
            console.print(f"[yellow]note (rank {k + 1}): the go-to point moved {mv['distance']:.3f} units, from "
                          f"{_fmt3(mv['from'])} to {_fmt3(mv['to'])}: {lit(mv['why'])}[/yellow]", emoji=False)
    console.print(Text(f"report: {summary['report']}\nplots: {summary['plots']['clearance']}, "
                       f"{summary['plots']['topdown']}"), soft_wrap=True)  # paths: one line each, to copy
    videos = [v for k, v in summary["plots"].items() if k.startswith("preview_") and not k.startswith("preview_sheet")]
    if videos:
        console.print(Text("preview: " + ", ".join(videos)))
    if loaded.config_path is not None:
        console.print(Text(
            f"render: ns-render camera-path --load-config {loaded.config_path} --camera-path-filename {files[0]} "
            f"--output-path renders/{args.name}.mp4"
        ))


def _fmt3(p) -> str:
    return "(" + ", ".join(f"{v:.3f}" for v in p) + ")"


def main(argv: Optional[List[str]] = None) -> int:
    """Parse ``argv`` (default: sys.argv), run; returns the exit status: 0, 2 for a user error (message on stderr),
    130 when interrupted (143 on SIGTERM, 129 on SIGHUP). Nothing partial is left behind in either case."""
    args = tyro.cli(PlanArgs, args=argv)
    try:
        with signals_as_interrupts():  # SIGTERM / SIGHUP unwind like Ctrl-C: nothing is left behind
            run_plan(args)
    except KeyboardInterrupt as e:
        code, what = interrupted(e)
        ERRORS.print(f"cinesplat-plan: {what}; no output was written", markup=False, highlight=False)
        return code
    except MemoryError:
        ERRORS.print("cinesplat-plan: out of memory; lower --grid-resolution or --memory-budget-mb, or plan fewer "
                     "--candidates")
        return 2
    except (PlanningError, FileNotFoundError, ValueError, OSError) as e:  # user-facing: CheckpointError, QueryError...
        ERRORS.print(error_line("cinesplat-plan", e), soft_wrap=True)
        return 2
    return 0


def entrypoint() -> None:
    sys.exit(main())


if __name__ == "__main__":
    entrypoint()
