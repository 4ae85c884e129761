"""``cinesplat-plan``'s options (PlanArgs: the request's flags, and the planner's configs nested the nerfstudio way,
``--planner.*``, ``--trajectory.*``, ``--timing.*``, ``--obstacles.*``, ``--score.*``: option_surface.py) and their
checks, all made before the scene is loaded (check_args); the machine-dependent ones (memory budget, worker
processes) say what they chose."""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Optional, Tuple

import numpy as np
from rich.console import Console

from cinenerf_ns.option_ranges import check_config_ranges
from cinenerf_ns.option_surface import validated
from cinenerf_ns.options import check_device, check_number
from cinenerf_ns.output_set import check_file_size_limit, check_name, check_writable
from cinenerf_ns.planner.config import MAX_CANDIDATES, PlannerConfig
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.native import kernel_threads
from cinenerf_ns.planner.scene.scene_config import DEFAULT_SAFETY_MARGIN, SceneConfig
from cinenerf_ns.planner.scene.user_box import user_box
from cinenerf_ns.planner.shots.camera_path import (
    DEFAULT_FOV_DEG,
    DEFAULT_PREVIEW_FPS,
    DEFAULT_PREVIEW_SIZE,
    DEFAULT_RENDER_SIZE,
)
from cinenerf_ns.planner.shots.framing import FramingConfig
from cinenerf_ns.planner.shots.score_config import ScoreConfig
from cinenerf_ns.point_text import number_tokens, parse_point
from cinenerf_ns.semantic_defaults import CENTRE_RELEVANCY, OBJECT_CLUSTER, SMOOTH_NEIGHBORS


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
    then_go_to: Tuple[str, ...] = ()
    """Further stops after --go-to, in order (text or 'x y z' each): one smooth shot through all stops."""
    then_look_at: Tuple[str, ...] = ()
    """Look-at of each further stop (one per --then-go-to); empty: every stop looks at --look-at."""
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
    fov: float = DEFAULT_FOV_DEG
    """Vertical field of view of the exported camera, degrees (1-179)."""
    width: int = DEFAULT_RENDER_SIZE[0]
    """Render width written into the camera path, pixels."""
    height: int = DEFAULT_RENDER_SIZE[1]
    """Render height written into the camera path, pixels."""
    safety_margin: float = DEFAULT_SAFETY_MARGIN
    """Extra distance (scene units) kept from every ellipsoid on top of the camera radius: a splat only approximates
    the real surfaces. Clearances in the report are measured from the camera sphere grown by this margin."""
    region: Optional[str] = None
    """Planning region 'x0 y0 z0 x1 y1 z1' (two corners, scene units): every path stays in it. Default: the region
    stored in a compact export, else the training cameras' box grown, else the box of the dense content (far background,
    sky and floaters do not stretch it); the report says which rule chose it."""
    ignore_floaters: Literal["auto", "on", "off"] = "off"
    """Treat small, faint, isolated Gaussians (a capture's noise in the air) as non-obstacles: on, off, or auto (on
    when they are at least 1% of the Gaussians). The rule is in the report, with how many were ignored; shots are
    verified against the obstacles that remain (cinenerf_ns/planner/scene/floaters.py)."""
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
    unseen_fill: bool = True
    """Fill the part of a text target that no training camera saw when estimating its volume centre;
    --no-unseen-fill: from its Gaussians alone."""
    device: str = "cpu"
    """torch device of the scene tensors ('cpu' or 'cuda')."""
    up: Tuple[float, float, float] = (0.0, 0.0, 1.0)
    """World up direction (nerfstudio scenes: +z)."""
    max_acceleration: Optional[float] = None
    """Acceleration limit of the exported frames, units/s^2 (enables dynamic limits; default 0.5 when another limit
    is set)."""
    max_angular_rate: Optional[float] = None
    """Limit on how fast the view direction turns, deg/s (enables dynamic limits; default 60)."""
    object_radius: Optional[float] = None
    """Bounding-sphere radius of the look-at object for scoring (framing size; sight lines stop at it). Default: the
    procedural object's half diagonal, else 0.1."""
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    """The planner's settings: grid, region rules, corridor, workers (--trajectory.* and --timing.* are its curve and
    its clock)."""
    obstacles: SceneConfig = field(default_factory=SceneConfig)
    """How the splat's Gaussians become obstacles (--safety-margin is added to the camera radius)."""
    score: ScoreConfig = field(default_factory=ScoreConfig)
    """Weights and scales of the shot score that ranks random-start candidates (its field of view is --fov)."""


def check_args(args: PlanArgs) -> None:
    """Every option that can be judged without the scene, before anything is loaded or written. The scene-relative
    checks (points near the scene, camera radius against its size, grid against memory, frames) follow in the
    planner (Planner.checked_point, check_region, check_timing)."""
    if not isinstance(args.scene, str) or not args.scene.strip():
        raise InvalidInputError("--scene is empty: give a run's config.yml, a compact export, a .ply or 'procedural'")
    kernel_threads()  # $CINENERF_THREADS, checked before any work
    check_number(args.candidates, "--candidates", 1, MAX_CANDIDATES, integer=True)
    check_number(args.time_budget, "--time-budget", 0, 3600, lo_open=True)
    check_number(args.seed, "--seed", 0, 2**63 - 1, integer=True)
    # every number of the nested configs (--planner.*, --trajectory.*, --timing.*, --obstacles.*, --score.*)
    check_config_ranges([("--planner", args.planner), ("--obstacles", args.obstacles), ("--score", args.score)])
    check_number(args.fov, "--fov", 1, 179)
    check_number(args.width, "--width", 16, 8192, integer=True)
    check_number(args.height, "--height", 16, 8192, integer=True)
    check_number(args.safety_margin, "--safety-margin", 0, 10)
    check_number(args.semantic_smoothing, "--semantic-smoothing", 0, 256, integer=True)
    check_number(args.object_cluster, "--object-cluster", 0, 0.5)
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
    check_targets(args)
    if args.region is not None:
        parse_region(args.region)
    check_name(args.name)
    if args.preview:
        for v, opt in zip(args.preview_size, ("--preview-size (width)", "--preview-size (height)")):
            check_number(v, opt, 16, 4096, integer=True)
        check_number(args.preview_fps, "--preview-fps", 1, 120)
    check_writable(Path(args.output_dir))
    check_file_size_limit(Path(args.output_dir))
    args.planner.grid_polytopes = grid_polytopes(args.planner.grid_polytopes)
    validated("--planner", args.planner.validate)
    validated("--trajectory", args.planner.trajectory.validate)
    validated("--score", args.score.validate)
    framing_config(args).validate()


def grid_polytopes(value: Any) -> Any:
    """--planner.grid-polytopes as PlannerConfig takes it: True / False / 'auto' (also 'on' / 'off')."""
    key = value.strip().lower() if isinstance(value, str) else value
    choices = {"auto": "auto", "on": True, "true": True, "off": False, "false": False, True: True, False: False}
    if key not in choices:
        raise InvalidInputError(f"--planner.grid-polytopes must be auto, on (True) or off (False), got {value!r}")
    return choices[key]


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


def check_targets(args: PlanArgs) -> None:
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


def memory_budget(args: PlanArgs, console: Console) -> float:
    """--memory-budget-mb trusted only up to the memory available: a larger explicit budget is refused, the default
    is lowered to what is available (said)."""
    avail = available_memory_mb()
    budget = float(args.planner.memory_budget_mb)
    if avail is None or budget <= avail:
        return budget
    if budget != PlannerConfig.memory_budget_mb:
        raise InvalidInputError(f"--memory-budget-mb {budget:g} is more than the memory available to this process "
                                f"(about {avail:.0f} MB: free memory and ulimit -v); give at most {avail:.0f}")
    lowered = max(64.0, float(int(avail)))
    console.print(f"note: memory budget {lowered:.0f} MB (the default {budget:g} MB is more than the memory available "
                  f"to this process)", markup=False, highlight=False)
    return lowered


def worker_count(args: PlanArgs, console: Console) -> Optional[int]:
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
    every axis (user_box.user_box)."""
    tokens = number_tokens(text)
    try:
        vals = [float(t) for t in tokens]
    except ValueError as e:
        raise InvalidInputError(f"--region must be 6 numbers 'x0 y0 z0 x1 y1 z1', got {text!r}") from e
    return user_box(vals, "the planning region (--region)")


def framing_config(args: PlanArgs) -> FramingConfig:
    """The framing band --framing names, for the frame --fov / --width / --height describe."""
    return FramingConfig(args.framing, float(args.fov), float(args.width) / float(args.height))


RENAMED_FLAGS = {
    "--beta": "--obstacles.beta",
    "--start-look-distance": "--planner.start-look-distance",
    "--grid-polytopes": "--planner.grid-polytopes",
    "--no-no-unseen-fill": "--unseen-fill",
    "--score.fov-deg": "--fov",
}
"""Flags of cinesplat-plan that changed name: the old spelling fails with the new one."""
