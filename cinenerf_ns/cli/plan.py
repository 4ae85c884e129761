"""``cinesplat-plan``: plan camera shots through a splat from the command line (no viewer, no GPU needed).

    cinesplat-plan --scene outputs/room/cinesplat/<run>/config.yml --go-to "armchair" --look-at "floor lamp"
    cinesplat-plan --scene scene.ply --go-to "0.1 0.2 0.3" --look-at "0 0 0.2" --candidates 4
    cinesplat-plan --scene procedural --go-to armchair --look-at "floor lamp"
    cinesplat-plan --scene procedural --go-to armchair --then-go-to sofa table --look-at "floor lamp" --max-angular-rate 45

With random starts the candidates are planned in one batched call, scored (occlusion of the look-at
object, framing, clearance, smoothness, duration; planner/scoring.py) and ranked: rank 1 is written as
``<name>_0.json``, rank 2 as ``<name>_1.json``, ...; the table and the report state every score term.

Targets are "x y z" points (scene units, nerfstudio's normalised coordinates for checkpoints) or text.
Text needs semantics: a cinesplat checkpoint / compact export (relevancy of the distilled CLIP latents,
eq. 4) or the procedural test scene (its ground-truth object names). Writes, per candidate, a
nerfstudio camera-path JSON (``ns-render camera-path``), plus a safety report JSON and PNG plots.
"""
from __future__ import annotations

import json

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, List, Literal, Optional, Tuple

import numpy as np
import tyro
from rich.console import Console
from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
from rich.table import Table

from cinenerf_ns.method.semantic_scene import CENTRE_RELEVANCY
from cinenerf_ns.planner.camera_path import shot_to_camera_path, write_camera_path
from cinenerf_ns.planner.candidates import RankedShot, plan_candidates, score_shots
from cinenerf_ns.planner.dynamics import DynamicLimits, retime_shot
from cinenerf_ns.planner.multistop import plan_multistop
from cinenerf_ns.planner.scoring import ScoreConfig
from cinenerf_ns.planner.errors import InvalidInputError, PlanningError
from cinenerf_ns.planner.planner import Planner, PlannerConfig
from cinenerf_ns.planner.safety import plot_clearance, plot_paths_topdown, safety_report
from cinenerf_ns.planner.scene import SceneConfig
from cinenerf_ns.planner.timing import TimingConfig
from cinenerf_ns.scenes import LoadedScene, _word_match, load_scene, parse_point, resolve_target

CONSOLE = Console()


@dataclass
class PlanArgs:
    """Plan camera shots: go to one thing, look at another."""

    scene: str
    """A cinesplat/splatfacto run (config.yml, its folder or a .ckpt), a compact export (.pt), a 3DGS .ply,
    or 'procedural[:N[:SEED]]' (a generated test room with known object names)."""
    go_to: str
    """Where the camera should end: text (needs a semantic scene) or 'x y z'."""
    look_at: str
    """What every frame looks at: text or 'x y z'."""
    start: Optional[str] = None
    """Start point 'x y z'; default: random collision-free starts (seeded)."""
    seed: int = 0
    """Seed of the random starts (same seed, same starts)."""
    start_look_distance: float = PlannerConfig.start_look_distance
    """Random starts keep at least this fraction of the start region's longest side from the look-at point when the
    region allows (an opening frame that shows the subject; the aim is less sensitive to the estimated centre's
    error). 0: uniform random starts. Ignored with --start."""
    candidates: int = 1
    """Number of shots from different random starts."""
    workers: Optional[int] = None
    """Worker processes that plan the candidates in parallel (Linux, fork; see PlannerConfig.candidate_workers).
    None: one per CPU on machines with >= 4 CPUs, else 0 (plan in this process)."""
    output_dir: Path = Path("cinesplat_plans")
    """Where camera paths, the report and the plots go."""
    name: str = "shot"
    """File name stem of the outputs."""
    fps: float = 30.0
    """Frames per second of the exported path."""
    max_speed: float = 0.5
    """Camera speed cap, scene units per second."""
    fov: float = 50.0
    """Vertical field of view of the exported camera, degrees."""
    width: int = 1280
    """Render width written into the camera path."""
    height: int = 720
    """Render height written into the camera path."""
    camera_radius: float = 0.03
    """Camera body sphere radius, scene units (paper: 0.03)."""
    safety_margin: float = 0.01
    """Extra distance (scene units) kept from every ellipsoid on top of camera_radius: a splat only
    approximates the real surfaces (measured on a synthetic room: the true surface can lie ~0.0005 outside
    the ellipsoids). Clearances in the report are measured from the camera sphere grown by this margin."""
    beta: float = 2.0
    """Ellipsoid size in sigmas (paper: 2), scaled by each Gaussian's opacity."""
    opacity_floor: float = 0.05
    """Gaussians below this opacity are not obstacles."""
    grid_resolution: int = 96
    """A* voxels along the longest side of the planning region."""
    grid_polytopes: Literal["auto", "on", "off"] = "auto"
    """Corridor polytopes from the occupancy grid where the path lies in free voxels (same safety, far cheaper, up to
    a voxel more conservative); auto: on when the voxels are fine (<= 2 camera radii), see PlannerConfig."""
    threshold: Optional[float] = None
    """Relevancy threshold of text queries (default: the scene's)."""
    semantic_smoothing: int = 32
    """Average each Gaussian's latent over this many nearest Gaussians before text queries (0: off): denoises
    object selection (synthetic room: mean IoU 0.28 -> 0.40) for ~2 s of CPU per 400k Gaussians, once per
    scene load (see SemanticScene / smooth_latents)."""
    object_cluster: float = 0.02
    """A text target is the heaviest spatial cluster (relevancy x opacity) of the selected Gaussians, binned at
    this fraction of the scene's extent (0: all selected Gaussians). One object, not the centroid of scattered
    matches or of several instances (synthetic room: centroid within 5% for 6 of 8 objects instead of 3)."""
    object_centre: Literal["volume", "surface"] = "volume"
    """Where a text target is: 'volume' (estimated volume centroid of the selected object: surface Gaussians
    voxelised and filled, see cinenerf_ns/method/object_centre.py) or 'surface' (opacity-weighted mean of the
    selected Gaussians: pulled toward thin parts such as a lamp's pole). Synthetic room: worst object 7.4% -> 0.9%
    of the room size from the true centre (with the support-layer rule below)."""
    keep_support: bool = False
    """Keep the floor / table layer under a text target in its selection. By default it is dropped: features bleed
    across contact, and the floor around a lamp's base pulls its centre down (synthetic room: lamp 2.9% -> 0.9% of
    the room size; see cinenerf_ns/method/object_support.py)."""
    centre_relevancy: float = CENTRE_RELEVANCY
    """Estimate a text target's centre only from its selected Gaussians with relevancy above this (the confident core;
    the whole selection when the core is under a quarter of it); the selection keeps --threshold. Gaussians that only
    show through an object's pixels (behind it, in a wall beside it) carry its label weakly and pull its centre off.
    0: off. Measured on four trained synthetic rooms (benchmarks/RESULTS.md): worst centre 7.96 -> 0.67% of the room
    (room 4's bookshelf), 1.17 -> 1.00%, 0.90 -> 0.65%, but 1.31 -> 1.39% in room 2; shots within 2 deg of the true
    centre at every frame (10 starts per pair) 306 -> 314 of 320."""
    no_unseen_fill: bool = False
    """Estimate a text target's volume centre from its Gaussians alone. By default, when the scene knows its training
    cameras (a run's config.yml with its data in place, or a compact export that carries them), the part of the object
    that no camera saw (a back facing away from the capture, left thin in the splat) is filled as the object's volume
    (see cinenerf_ns/method/object_centre.py). Measured on four trained synthetic rooms (benchmarks/RESULTS.md): room 2's
    cabinet 1.39 -> 0.40% of the room off, worst centres 0.65/1.00/1.39/0.68 -> 0.51/1.42/0.93/0.87%; shots within 2 deg
    of the true centre at every frame (3 starts per pair) 94 -> 96 of 96. It overfills pockets no camera looks into."""
    device: str = "cpu"
    """torch device of the scene tensors ('cpu' or 'cuda')."""
    up: Tuple[float, float, float] = (0.0, 0.0, 1.0)
    """World up direction (nerfstudio scenes: +z)."""
    then_go_to: Tuple[str, ...] = ()
    """Further stops after --go-to, in order (text or 'x y z' each): one smooth shot through all stops."""
    then_look_at: Tuple[str, ...] = ()
    """Look-at of each further stop (one per --then-go-to); empty: every stop looks at --look-at."""
    max_acceleration: Optional[float] = None
    """Acceleration limit of the exported frames, units/s^2 (enables dynamic limits; default 0.5 when
    another limit is set)."""
    max_angular_rate: Optional[float] = None
    """Limit on how fast the view direction turns, deg/s (enables dynamic limits; default 60)."""
    object_radius: Optional[float] = None
    """Bounding-sphere radius of the look-at object for scoring (framing size; sight lines stop at it so
    the object does not hide itself). Default: the procedural object's half diagonal, else 0.1."""
    score: ScoreConfig = field(default_factory=ScoreConfig)
    """Weights of the shot score (its fov_deg is replaced by --fov)."""


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
        if not (np.isfinite(args.object_radius) and args.object_radius >= 0):
            raise InvalidInputError(f"--object-radius must be >= 0, got {args.object_radius}")
        return float(args.object_radius)
    if loaded.kind == "procedural" and parse_point(args.look_at) is None:
        objs = loaded.extra["room"].objects
        i = _word_match(args.look_at, [o.name for o in objs])
        if i is not None:
            return float(0.5 * np.linalg.norm(objs[i].size))
    return 0.1


def _limits(args: PlanArgs) -> Optional[DynamicLimits]:
    if args.max_acceleration is None and args.max_angular_rate is None:
        return None
    return DynamicLimits(
        max_speed=args.max_speed, fps=args.fps,
        max_acceleration=0.5 if args.max_acceleration is None else args.max_acceleration,
        max_angular_rate_deg=60.0 if args.max_angular_rate is None else args.max_angular_rate,
    )


def run_plan(args: PlanArgs, console: Console = CONSOLE) -> Dict[str, Any]:
    """Plan and write outputs; returns a summary dict (paths, per-candidate metrics)."""
    if not (args.safety_margin >= 0):
        raise InvalidInputError(f"--safety-margin must be >= 0, got {args.safety_margin}")
    if not (0.0 <= args.centre_relevancy < 1.0):  # checked before anything is loaded or written
        raise InvalidInputError(f"--centre-relevancy must be in [0, 1) (0: the centre from the whole selection), "
                                f"got {args.centre_relevancy}")
    scfg = SceneConfig(beta=args.beta, camera_radius=args.camera_radius + args.safety_margin, opacity_floor=args.opacity_floor)
    out = Path(args.output_dir)
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
        prog.update(task, advance=1, description="resolving targets", refresh=True)
        goal, goal_desc = resolve_target(args.go_to, loaded, "go-to")
        look, look_desc = resolve_target(args.look_at, loaded, "look-at")
        start = None
        if args.start is not None:
            start = parse_point(args.start)
            if start is None:
                raise InvalidInputError(f"--start must be 'x y z', got {args.start!r}")
        prog.update(task, advance=1, description="preparing (index, occupancy grid)", refresh=True)
        pcfg = PlannerConfig(
            grid_resolution=args.grid_resolution, up=tuple(args.up), timing=TimingConfig(max_speed=args.max_speed, fps=args.fps),
            start_region=loaded.start_region, candidate_workers=args.workers,
            start_look_distance=args.start_look_distance, grid_polytopes={"auto": "auto", "on": True, "off": False}[args.grid_polytopes],
        )
        planner = Planner(loaded.scene, pcfg)
        prep = planner.prepare()
        prog.update(task, advance=1, description=f"planning {args.candidates} candidate(s)", refresh=True)
        limits = _limits(args)
        obj_r = _object_radius(args, loaded)
        score_cfg = ScoreConfig(**{**args.score.__dict__, "fov_deg": args.fov})
        multi = None
        if args.then_go_to:
            if args.then_look_at and len(args.then_look_at) != len(args.then_go_to):
                raise InvalidInputError(
                    f"--then-look-at needs one look-at per --then-go-to ({len(args.then_go_to)}), got {len(args.then_look_at)}"
                )
            stops = [goal] + [resolve_target(t, loaded, f"go-to {i + 2}")[0] for i, t in enumerate(args.then_go_to)]
            looks = [look] + ([resolve_target(t, loaded, f"look-at {i + 2}")[0] for i, t in enumerate(args.then_look_at)]
                              if args.then_look_at else [look] * len(args.then_go_to))
            multi = plan_multistop(planner, stops, np.stack(looks), start=start, seed=args.seed, limits=limits)
            shots = [multi.shot]
            scores = [None]
        elif start is not None:
            shots = planner.plan(goal, look, start=start, seed=args.seed, n_candidates=1)
            if limits is not None:
                shots = [retime_shot(sh, limits, up=pcfg.up) for sh in shots]
            scores = score_shots(planner, shots, look, score_cfg, object_radius=obj_r)
        else:
            ranked: List[RankedShot] = plan_candidates(planner, goal, look, k=args.candidates, seed=args.seed,
                                                       score_config=score_cfg, limits=limits, object_radius=obj_r)
            shots = [r.shot for r in ranked]
            scores = [r.score for r in ranked]
        prog.update(task, advance=1, description="exact clearance report + plots", refresh=True)
        out.mkdir(parents=True, exist_ok=True)
        reports, files = [], []
        for k, sh in enumerate(shots):
            rep = safety_report(sh, planner.clearance, max_spacing=0.02, label=f"rank {k + 1}")
            reports.append(rep)
            cp = shot_to_camera_path(sh, fov_deg=args.fov, width=args.width, height=args.height)
            files.append(write_camera_path(out / f"{args.name}_{k}.json", cp))
        png_c = plot_clearance(reports, out / f"{args.name}_clearance.png")
        lo, hi = planner.planning_bounds()
        png_t = plot_paths_topdown(
            [sh.positions for sh in shots], out / f"{args.name}_topdown.png",
            obstacles=_obstacles_near_paths(loaded.scene.means.detach().cpu().numpy(), shots, np.asarray(args.up, float)),
            targets={"go to": goal, "look at": look},
            labels=[f"rank {k + 1}" for k in range(len(shots))],
        )
        summary = {
            "scene": loaded.source,
            "go_to": {"text": args.go_to, "point": goal.tolist(), "resolved": goal_desc},
            "look_at": {"text": args.look_at, "point": look.tolist(), "resolved": look_desc},
            "prepare_ms": prep.timings_ms,
            "camera_radius": args.camera_radius,
            "safety_margin": args.safety_margin,
            "clearance_note": "clearances are measured from the camera sphere of radius camera_radius + safety_margin",
            "candidates": [
                {**(multi.to_dict() if multi is not None else sh.to_dict()), "rank": k + 1,
                 "score": None if scores[k] is None else scores[k].to_dict(),
                 "dynamics": getattr(sh, "dynamics", None) if multi is None else multi.dynamics,
                 "camera_path": str(files[k]), "exact_clearance": {kk: v for kk, v in reports[k].items() if kk not in ("times", "clearance")},
                 "verification": sh.safety}
                for k, sh in enumerate(shots)
            ],
            "object_radius": obj_r,
            "score_config": score_cfg.__dict__,
            "clearance_samples": [{"times": r["times"], "clearance": r["clearance"]} for r in reports],
            "plots": {"clearance": str(png_c), "topdown": str(png_t)},
            "total_s": time.perf_counter() - t_all,
        }
        rpath = out / f"{args.name}_report.json"
        tmp = rpath.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(summary, indent=2, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
        tmp.replace(rpath)
        summary["report"] = str(rpath)
        prog.update(task, advance=1, refresh=True)

    table = Table(title=f"cinesplat-plan: go to {goal_desc}, look at {look_desc}")
    # short headers, no wrapping: the table must stay readable in an 80-column terminal (legend below)
    wide = console.width >= 140
    cols = ["#", "score", "occl", "min clr", "len", "dur s", "peak v/a/w", "file"]
    if wide:
        cols[3:3] = ["fill", "start", "mean clr", "jerk", "turn"]
    for col in cols:
        table.add_column(col, no_wrap=True)
    for k, sh in enumerate(shots):
        sc = scores[k]
        dyn = getattr(sh, "dynamics", None) if multi is None else multi.dynamics
        peaks = "-" if not dyn else f"{dyn['peak_speed']:.2f}/{dyn['peak_acceleration']:.2f}/{dyn['peak_angular_rate_deg']:.0f}"
        t = sc.terms if sc is not None else {}
        f = lambda key, fmt: "-" if key not in t else format(t[key], fmt)  # noqa: E731
        row = [str(k + 1), "-" if sc is None else f"{sc.total:.3f}", f("occluded_fraction", ".2f"),
               f"{reports[k]['min_clearance']:.4f}", f"{sh.length:.2f}", f"{sh.duration:.1f}", peaks, Path(files[k]).name]
        if wide:
            row[3:3] = [f("framing_fill_mean", ".2f"), ",".join(f"{v:.2f}" for v in sh.start),
                        f"{reports[k]['mean_clearance']:.3f}", f("mean_jerk", ".1f"), f("mean_angular_rate_deg", ".0f")]
        table.add_row(*row)
    console.print(table)
    console.print("score: lower is better (every term in the report); occl: occluded fraction of frames; clr/len in scene "
                  "units; peak: speed / acceleration / view rotation deg/s" + ("" if wide else " (wider terminal: more columns)")
                  + f"; files in {out}/")
    console.print(f"report: {summary['report']}\nplots: {png_c}, {png_t}")
    if loaded.config_path is not None:
        console.print(
            f"render: ns-render camera-path --load-config {loaded.config_path} --camera-path-filename {files[0]} "
            f"--output-path renders/{args.name}.mp4"
        )
    return summary


def entrypoint() -> None:
    args = tyro.cli(PlanArgs)
    try:
        run_plan(args)
    except PlanningError as e:
        CONSOLE.print(f"[bold red]cinesplat-plan: {e}")
        raise SystemExit(2)
    except (FileNotFoundError, ValueError) as e:  # loaders' user-facing errors (CheckpointError, QueryError, ...)
        CONSOLE.print(f"[bold red]cinesplat-plan: {e}")
        raise SystemExit(2)


if __name__ == "__main__":
    entrypoint()
