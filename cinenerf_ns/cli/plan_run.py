"""What ``cinesplat-plan`` runs once its options are checked (plan.py parses them, torch-free): load the scene,
resolve the targets, plan, and write the camera paths, report and plots together (run_plan)."""
from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Dict, List, Optional

import numpy as np
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

from cinenerf_ns.console_text import lit
from cinenerf_ns.output_set import OutputSet
from cinenerf_ns.planner.scene.floaters import apply_floater_rule
from cinenerf_ns.planner.shots import stages
from cinenerf_ns.planner.shots.camera_path import (
    shot_to_camera_path,
    write_camera_path,
)
from cinenerf_ns.planner.shots.candidates import RankedShot
from cinenerf_ns.planner.shots.multistop import plan_multistop
from cinenerf_ns.planner.shots.planner import Planner
from cinenerf_ns.planner.shots.safety import plot_clearance, plot_paths_topdown
from cinenerf_ns.planner.shots.score_config import ScoreConfig
from cinenerf_ns.planner.trajectory.dynamics import DynamicLimits
from cinenerf_ns.point_text import parse_point
from cinenerf_ns.scenes import LoadedScene, _word_match, load_scene, resolve_match
from cinenerf_ns.shot_request import ShotRequest, plan_request
from cinenerf_ns.shot_targets import ShotTargets, end_pose_count, shot_targets, start_region_centre

from .plan_args import (
    PlanArgs,
    check_args,
    framing_config,
    memory_budget,
    parse_region,
    worker_count,
)

CONSOLE = Console(emoji=False)  # user text is printed as typed (console_text)


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
        max_speed=args.planner.timing.max_speed, fps=args.planner.timing.fps,
        max_acceleration=DynamicLimits.max_acceleration if args.max_acceleration is None else args.max_acceleration,
        max_angular_rate_deg=(DynamicLimits.max_angular_rate_deg if args.max_angular_rate is None
                              else args.max_angular_rate),
    )


def _targets(args: PlanArgs, planner: Planner, loaded: LoadedScene, gm: Dict[str, Any], lm: Dict[str, Any],
             start: Optional[np.ndarray]) -> Optional[ShotTargets]:
    """The look-at subject and, for an object go-to, the end poses (shot_targets.py); None for multi-stop shots."""
    if args.then_go_to:
        return None
    if start is not None:
        start = planner.checked_start(start, force=args.force_start)  # may grow the region: before the component
        comp, facing = stages.start_voxel(planner.space, start)[1], start
    else:
        comp, facing = planner.main_component(), start_region_centre(planner)
    k = 1 if start is not None else end_pose_count(args.candidates)
    return shot_targets(planner, gm, lm, framing_config(args), comp, k=k, object_radius=_object_radius(args, loaded),
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
    req = ShotRequest(goals=targets.goals(goal), look_at=look, start=start, candidates=args.candidates,
                      seed=args.seed, subject=targets.samples, score=score_cfg, limits=limits, object_radius=obj_r,
                      time_budget_s=args.time_budget, force_start=args.force_start)
    ranked: List[RankedShot] = plan_request(planner, req, timings)
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


def run_plan(args: PlanArgs, console: Console = CONSOLE, keep: Optional[Dict[str, Any]] = None,
             checked: bool = False) -> Dict[str, Any]:
    """Check the options, plan, and write the outputs all together; returns a summary dict (paths, per-candidate
    metrics). Raises InvalidInputError / PlanningError / CheckpointError with a message for the user. ``keep``: a dict
    that receives the LoadedScene under "loaded" (the demo renders its preview from it instead of loading again).
    ``checked``: the caller ran check_args already (plan.main, before torch loads); it normalises --up, so twice
    could move it by a rounding."""
    if not checked:
        check_args(args)
    memory_budget_mb = memory_budget(args, console)
    workers = worker_count(args, console)
    scfg = replace(args.obstacles, camera_radius=args.obstacles.camera_radius + args.safety_margin)
    t_all = time.perf_counter()
    # auto_refresh=False: no refresh thread. plan_candidates forks worker processes, and a fork while another thread
    # holds an output lock can hang the child; the bar is redrawn at each stage instead (prog.update(refresh=True)).
    with Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(), console=console,
                  transient=True, auto_refresh=False) as prog:
        task = prog.add_task("loading scene", total=5)
        loaded = load_scene(args.scene, scfg, args.device, args.threshold, smooth_neighbors=args.semantic_smoothing,
                            object_cluster=args.object_cluster, object_centre=args.object_centre, up=args.up,
                            drop_support=not args.keep_support, centre_relevancy=args.centre_relevancy,
                            unseen_fill=args.unseen_fill)
        if keep is not None:
            keep["loaded"] = loaded
        for note in loaded.notes:
            console.print(f"note: {note}", markup=False, highlight=False)
        prog.update(task, advance=1, description="resolving targets", refresh=True)
        # text first: a query that matches nothing fails before the grid is built
        gm, lm = resolve_match(args.go_to, loaded, "go-to"), resolve_match(args.look_at, loaded, "look-at")
        stops = [resolve_match(t, loaded, f"go-to {i + 2}")["point"] for i, t in enumerate(args.then_go_to)]
        stop_looks = [resolve_match(t, loaded, f"look-at {i + 2}")["point"] for i, t in enumerate(args.then_look_at)]
        prog.update(task, advance=1, description="preparing (index, occupancy grid)", refresh=True)
        loaded.scene, floaters = apply_floater_rule(loaded.scene, args.ignore_floaters)
        pcfg = replace(args.planner, up=tuple(args.up), start_region=loaded.start_region, candidate_workers=workers,
                       memory_budget_mb=memory_budget_mb, **_region_config(args, loaded),
                       obstacles_note=floaters.obstacle_note())
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
        "planning_region": {"lo": lo.tolist(), "hi": hi.tolist(), "rule": planner.region_rule(),
                            "grid_shape": list(prep.grid.shape), "grid_note": planner.grid_note},
        "prepare_ms": prep.timings_ms,
        "camera_radius": args.obstacles.camera_radius,
        "safety_margin": args.safety_margin,
        "clearance_note": "clearances are measured from the camera sphere of radius camera_radius + safety_margin",
        "requested_candidates": args.candidates,
        "stopped_by_time_budget": bool(batch_tm.get("budget_stopped")),
        "candidates": [
            {**(multi.to_dict() if multi is not None else sh.to_dict()), "rank": k + 1,
             "score": None if scores[k] is None else scores[k].to_dict(),
             "dynamics": sh.dynamics if multi is None else multi.dynamics,
             "camera_path": str(files[k]), "goal_moved": moves[k],
             "refinement": sh.refinement,
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
        dyn = sh.dynamics if multi is None else multi.dynamics
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
                  f"{summary['floaters']['obstacles']}" + (f"; {reg['grid_note']}" if reg["grid_note"] else ""),
                  markup=False, emoji=False)
    band = framing_config(args).band
    console.print("score: lower is better (every term in the report); seen: frames with at least half of the look-at "
                  "object visible; end: its visible share in the last frame; size: its size in the last frame "
                  f"({args.framing}: {band[0]:g}-{band[2]:g}); clr/len in scene units"
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
