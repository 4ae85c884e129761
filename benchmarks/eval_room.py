"""End-to-end evaluation on a trained synthetic room (issue 5, item 2): text -> object -> safe shot.

    python benchmarks/eval_room.py --scene cinenerf_ns/assets/room0.npz --dataset cinenerf_ns/assets/room0_gt

The method and the planner see exactly what a user's run gives them: the trained splat (compact export
or config.yml) and the text of each label name, loaded through ``cinesplat-plan``'s own ``load_scene``.
The ground truth (``geometry.json`` + the run's ``dataparser_transforms.json``) is only used afterwards
to score the results:

* selection: for every object, the Gaussians the text query selects vs the Gaussians on/in the true
  object (IoU, precision, recall) and the selection centroid's error (fraction of the room size);
* shots: for go-to/look-at pairs (object i -> look at object i+1) x ``--starts`` random starts:
  success (positive TRUE clearance and every sample inside the room's interior: outside the walls the SDF is
  positive too), TRUE clearance (analytic SDF minus the camera radius) along the whole densely sampled curve
  plus a certified bound between samples, look-at error at every frame against the planner's target and
  against the TRUE object centre, final distance to the go-to object's surface, planning latency.

Writes ``eval_room.md`` / ``eval_room.json`` and the plots (true clearance over time, top view of the
paths through the room) into ``--out`` and appends a summary to benchmarks/RESULTS.md.
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._results import append_results, device_name  # noqa: E402
from benchmarks.eval_synthetic import (  # noqa: E402
    clearance_along,
    clearance_lower_bound,
    distance_to_object,
    load_ground_truth,
    look_at_errors_deg,
    markdown_table,
    object_names,
    plot_clearance,
    plot_topdown,
    selection_metrics,
)
from cinenerf_ns.method.semantic_scene import CENTRE_RELEVANCY  # noqa: E402
from cinenerf_ns.planner.errors import PlanningError  # noqa: E402
from cinenerf_ns.planner.scene.scene_config import DEFAULT_SAFETY_MARGIN, SceneConfig  # noqa: E402
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig  # noqa: E402
from cinenerf_ns.scenes import load_scene  # noqa: E402


def evaluate_selection(loaded, gt) -> list[dict]:
    sem = loaded.semantics.semantic if loaded.semantics else None
    if sem is None:
        raise SystemExit("the scene has no semantic latents (train it with ns-train cinesplat)")
    rows = []
    for name in object_names(gt):
        t0 = time.perf_counter()
        try:
            res = sem.locate_full(name)
            mask = res.mask
        except Exception as e:  # noqa: BLE001 (reported per object)
            rows.append({"object": name, "iou": 0.0, "error": str(e)})
            continue
        m = selection_metrics(sem.means.detach().cpu().double(), mask.cpu(), gt, name)
        # centroid_error_frac (issue 5's "centroid error"): the object centre the method returns and the planner
        # looks at (SemanticScene.locate: the volume estimate by default); selection_mean_error_frac: the plain
        # mean of the selected Gaussians (a surface centroid); surface_centroid_error_frac: the opacity-weighted one
        m["selection_mean_error_frac"] = m.pop("centroid_error_frac")
        c = res.centroid.detach().cpu().double()
        m["centroid_error_frac"] = float((c - gt.object_centres()[name]).norm()) / gt.room_size()
        if res.surface_centroid is not None:
            sc = res.surface_centroid.detach().cpu().double()
            m["surface_centroid_error_frac"] = float((sc - gt.object_centres()[name]).norm()) / gt.room_size()
        m["n_core"] = int(res.core.sum()) if res.core is not None else m.get("n_selected")
        m["query_ms"] = 1e3 * (time.perf_counter() - t0)
        rows.append(m)
    return rows


def dense_curve(shot, spacing: float = 0.005) -> tuple[np.ndarray, np.ndarray]:
    """(times [S], positions [S, 3]) along the shot's whole curve, consecutive samples <= spacing apart."""
    if shot.trajectory is None or shot.curve_times is None:
        return shot.times, shot.positions
    n = max(2, int(math.ceil(shot.length / spacing)) + 1)
    tau = np.linspace(shot.curve_times[0], shot.curve_times[-1], n)
    pos = shot.trajectory.evaluate(tau)
    while np.linalg.norm(np.diff(pos, axis=0), axis=1).max() > spacing and n < 2_000_000:
        n *= 2
        tau = np.linspace(shot.curve_times[0], shot.curve_times[-1], n)
        pos = shot.trajectory.evaluate(tau)
    times = np.interp(tau, shot.curve_times, shot.times)
    return times, pos


def evaluate_shots(loaded, gt, starts: int, camera_radius: float, grid_resolution: int,
                   start_look_distance: float = PlannerConfig.start_look_distance) -> tuple[list[dict], dict, dict]:
    planner = Planner(loaded.scene, PlannerConfig(start_region=loaded.start_region, grid_resolution=grid_resolution,
                                                  start_look_distance=start_look_distance))
    prep = planner.prepare()
    names = object_names(gt)
    centres = gt.object_centres()
    rows, paths, series, look_frames = [], {}, {}, {}
    from rich.progress import Progress

    progress = Progress(transient=True)
    task = progress.add_task("planning and scoring shots", total=len(names) * starts)
    progress.start()
    for i, goto in enumerate(names):
        look = names[(i + 1) % len(names)]
        g, _ = loaded.locate(goto)
        lk, _ = loaded.locate(look)
        for seed in range(starts):
            progress.advance(task)
            row = {"go_to": goto, "look_at": look, "seed": seed}
            t0 = time.perf_counter()
            try:
                shot = planner.plan(g, lk, seed=seed, n_candidates=1)[0]
            except PlanningError as e:
                row.update(success=False, reason=f"{type(e).__name__}: {e}"[:200],
                           plan_ms=1e3 * (time.perf_counter() - t0))
                rows.append(row)
                continue
            row["plan_ms"] = 1e3 * (time.perf_counter() - t0)
            t, pos = dense_curve(shot)
            clr = clearance_along(torch.from_numpy(pos), gt, camera_radius)
            # outside the walls / under the floor the SDF is positive too, but no camera of this room belongs there
            outside = int((~gt.inside_room(torch.from_numpy(pos))).sum())
            bound = clearance_lower_bound(torch.from_numpy(pos), clr) if len(pos) > 1 else clr
            c2w = torch.from_numpy(shot.camera_to_worlds())
            err_target = shot.look_at_errors_deg()
            err_true = look_at_errors_deg(c2w, centres[look]).numpy()
            rng_look = np.linalg.norm(shot.positions - centres[look].numpy(), axis=1)  # [T] camera -> true centre
            d = distance_to_object(torch.from_numpy(shot.positions[-1]), gt, goto)
            row.update(
                success=bool(clr.min() > 0 and outside == 0), true_min_clearance=float(clr.min()),
                true_clearance_bound=float(bound.min()), outside_room_samples=outside,
                samples=len(pos), look_err_target_max_deg=float(err_target.max()),
                look_err_true_max_deg=float(err_true.max()),
                look_err_true_median_deg=float(np.median(err_true)), frames=int(len(err_true)),
                frames_look_err_true_le_2deg=int((err_true <= 2.0).sum()), min_range_to_look=float(rng_look.min()),
                final_surface_dist=d["surface"], final_centre_dist=d["centre"], duration_s=shot.duration,
                length=shot.length, planner_ms=shot.timings.get("plan_ms", float("nan")),
            )
            rows.append(row)
            label = f"{goto} -> {look} #{seed}"
            paths[label] = torch.from_numpy(shot.positions)
            series[label] = (torch.from_numpy(t), clr)
            look_frames.setdefault(look, []).append((rng_look, err_true))
    progress.stop()
    return rows, {"paths": paths, "series": series, "look": look_frames}, prep.timings_ms


def plot_look_errors(frames: dict, centre_err: dict, png: Path) -> Path:
    """Per-frame look-at error vs the TRUE centre against the camera's range to that centre, one colour per
    look-at object; the dashed curve of each object is the error a centre estimate off by e would cause at most,
    asin(e / range): why close frames miss the 2-degree line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for i, (name, runs) in enumerate(sorted(frames.items())):
        col = f"C{i % 10}"
        r = np.concatenate([x[0] for x in runs])
        e = np.concatenate([x[1] for x in runs])
        ax.scatter(r, e, s=4, color=col, alpha=0.5, label=f"{name} (centre off {centre_err.get(name, math.nan):.3f})")
        err = centre_err.get(name, math.nan)
        if math.isfinite(err) and err > 0:
            rr = np.linspace(max(err * 1.01, r.min()), r.max(), 200)
            ax.plot(rr, np.degrees(np.arcsin(np.clip(err / rr, 0, 1))), color=col, lw=1, ls="--")
    ax.axhline(2.0, color="r", lw=1, label="2 deg")
    ax.set_xlabel("camera range to the look-at object's true centre (scene units)")
    ax.set_ylabel("look-at error vs true centre (deg)")
    ax.set_yscale("log")
    ax.set_title("look-at error per frame (dashed: asin(centre error / range))")
    ax.legend(fontsize=6, loc="upper right")
    fig.tight_layout()
    fig.savefig(png, dpi=130)
    plt.close(fig)
    return png


def summarise(sel: list[dict], shots: list[dict], gt) -> dict:
    ok = [r for r in shots if r.get("success")]
    planned = [r for r in shots if "true_min_clearance" in r]
    f = lambda rows, k, fn: float(fn([r[k] for r in rows])) if rows else float("nan")  # noqa: E731
    return {
        "objects": len(sel),
        "iou_min": min(r.get("iou", 0.0) for r in sel), "iou_mean": float(np.mean([r.get("iou", 0.0) for r in sel])),
        "objects_iou_ge_0.7": sum(r.get("iou", 0.0) >= 0.7 for r in sel),
        "centroid_err_frac_max": max(r.get("centroid_error_frac", math.inf) for r in sel),
        "objects_centroid_le_5pct": sum(r.get("centroid_error_frac", math.inf) <= 0.05 for r in sel),
        "shots": len(shots), "planned": len(planned), "success": len(ok),
        "success_rate": len(ok) / len(shots) if shots else float("nan"),
        "planned_with_positive_true_clearance": sum(r["true_min_clearance"] > 0 for r in planned),
        "planned_inside_room": sum(r["outside_room_samples"] == 0 for r in planned),
        "true_min_clearance": f(planned, "true_min_clearance", np.min),
        "look_err_target_max_deg": f(planned, "look_err_target_max_deg", np.max),
        "look_err_true_median_of_max_deg": f(planned, "look_err_true_max_deg", np.median),
        "look_err_true_max_deg": f(planned, "look_err_true_max_deg", np.max),
        "shots_look_err_true_le_2deg_every_frame": sum(r["look_err_true_max_deg"] <= 2.0 for r in planned),
        "frames_look_err_true_le_2deg_frac": (sum(r["frames_look_err_true_le_2deg"] for r in planned)
                                              / max(1, sum(r["frames"] for r in planned))),
        "final_surface_dist_median": f(planned, "final_surface_dist", np.median),
        "plan_ms_median": f(planned, "plan_ms", np.median),
        "plan_ms_p95": f(planned, "plan_ms", lambda v: np.percentile(v, 95)),
        "room_size": gt.room_size(),
    }


def unit_fraction(text: str) -> float:
    """argparse type of --centre-relevancy: a number in [0, 1)."""
    try:
        v = float(text)
    except ValueError:
        v = math.nan
    if not 0.0 <= v < 1.0:
        raise argparse.ArgumentTypeError(f"--centre-relevancy must be a number in [0, 1), got {text!r}")
    return v


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", required=True, help="compact export (.npz/.pt) or a run's config.yml")
    ap.add_argument("--dataset", type=Path, required=True,
                    help="folder with geometry.json + dataparser_transforms.json")
    ap.add_argument("--dataparser-transforms", type=Path, default=None,
                    help="default: <dataset>/dataparser_transforms.json")
    ap.add_argument("--starts", type=int, default=3, help="random starts per go-to/look-at pair")
    ap.add_argument("--camera-radius", type=float, default=SceneConfig.camera_radius)
    ap.add_argument("--safety-margin", type=float, default=DEFAULT_SAFETY_MARGIN,
                    help="planning margin on top of the radius (cinesplat-plan's default)")
    ap.add_argument("--grid-resolution", type=int, default=96)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--start-look-distance", type=float, default=PlannerConfig.start_look_distance,
                    help="PlannerConfig.start_look_distance (same default): random starts at least this fraction of "
                         "the start region's longest side from the look-at point; 0: uniform starts (the paper's)")
    ap.add_argument("--selection-only", action="store_true")
    ap.add_argument("--semantic-smoothing", type=int, default=32,
                    help="as cinesplat-plan --semantic-smoothing (same default)")
    ap.add_argument("--object-cluster", type=float, default=0.02,
                    help="as cinesplat-plan --object-cluster (same default)")
    ap.add_argument("--object-centre", choices=["volume", "surface"], default="volume",
                    help="as cinesplat-plan --object-centre (same default)")
    ap.add_argument("--keep-support", action="store_true", help="as cinesplat-plan --keep-support (default: dropped)")
    ap.add_argument("--centre-relevancy", type=unit_fraction, default=CENTRE_RELEVANCY,
                    help="as cinesplat-plan --centre-relevancy (same default): the centre from the selected Gaussians "
                         "above this relevancy; 0: from the whole selection")
    ap.add_argument("--no-unseen-fill", action="store_true",
                    help="as cinesplat-plan --no-unseen-fill: the volume centre ignores the training cameras")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/room_eval"))
    ap.add_argument("--no-record", action="store_true", help="do not append to benchmarks/RESULTS.md")
    a = ap.parse_args(argv)
    dpt = a.dataparser_transforms or a.dataset / "dataparser_transforms.json"
    gt = load_ground_truth(a.dataset, dpt)
    # the planner plans for radius + margin, exactly as cinesplat-plan does; the truth is scored for the radius
    loaded = load_scene(str(a.scene), SceneConfig.with_margin(a.camera_radius, a.safety_margin), device=a.device,
                        smooth_neighbors=a.semantic_smoothing, object_cluster=a.object_cluster,
                        object_centre=a.object_centre, drop_support=not a.keep_support,
                        centre_relevancy=a.centre_relevancy, unseen_fill=not a.no_unseen_fill)
    sem = loaded.semantics.semantic if loaded.semantics else None
    n_cams = 0 if sem is None or sem.camera_centres is None else len(sem.camera_centres)
    unseen = f"unseen parts filled ({n_cams} training cameras)" if n_cams else "no unseen fill (no training cameras)"
    sel = evaluate_selection(loaded, gt)
    shots, plots, prep_ms = ([], {"paths": {}, "series": {}}, {}) if a.selection_only else evaluate_shots(
        loaded, gt, a.starts, a.camera_radius, a.grid_resolution, a.start_look_distance)
    summary = summarise(sel, shots, gt)
    a.out.mkdir(parents=True, exist_ok=True)
    date, dev = datetime.date.today().isoformat(), device_name(a.device)
    md = [f"# End-to-end evaluation: {a.scene}", "", f"{date}, {dev}, {len(loaded.scene)} Gaussians, prepare {prep_ms}",
          "",
          "## Object selection (text -> Gaussians) vs ground truth", "",
          markdown_table(sel, ["object", "iou", "precision", "recall", "n_selected", "n_core", "n_true",
                               "centroid_error_frac", "surface_centroid_error_frac", "selection_mean_error_frac",
                               "truth_centroid_error_frac", "query_ms"]),
          "", "centroid_error_frac: the object centre the method returns (the planner's look-at target; "
          f"--object-centre {a.object_centre}, estimated from the n_core selected Gaussians above relevancy "
          f"{a.centre_relevancy:g}; {unseen}) "
          "to the true volume centroid, / room size. surface_centroid: the opacity-weighted mean of that core; "
          "selection_mean: "
          "the plain mean of the whole selection; truth_centroid: the plain mean of the object's TRUE Gaussians.",
          "", "## Shots (true geometry)", "",
          markdown_table(shots, ["go_to", "look_at", "seed", "success", "true_min_clearance", "true_clearance_bound",
                                 "outside_room_samples",
                                 "look_err_target_max_deg", "look_err_true_max_deg", "look_err_true_median_deg",
                                 "frames_look_err_true_le_2deg", "frames", "min_range_to_look", "final_surface_dist",
                                 "plan_ms", "reason"]),
          "", "## Summary", "", "```", json.dumps(summary, indent=1), "```"]
    (a.out / "eval_room.md").write_text("\n".join(md) + "\n")
    (a.out / "eval_room.json").write_text(json.dumps({"summary": summary, "selection": sel, "shots": shots,
                                                      "prepare_ms": prep_ms},
                                                     indent=1, default=float))
    if plots["paths"]:
        look_targets = {lbl: gt.object_centres()[lbl.split(" -> ")[1].rsplit(" #", 1)[0]] for lbl in plots["paths"]}
        plot_topdown(gt, plots["paths"], a.out / "eval_room_topdown.png", look_targets=look_targets)
        plot_clearance(plots["series"], a.out / "eval_room_clearance.png")
        centre_err = {r["object"]: r.get("centroid_error_frac", math.nan) * gt.room_size() for r in sel}
        plot_look_errors(plots["look"], centre_err, a.out / "eval_room_lookat.png")
    print("\n".join(md))
    if not a.no_record:
        append_results(f"\n## eval_room ({date}, {dev})\n\nscene `{a.scene}`, {len(loaded.scene)} Gaussians, "
                       f"{a.starts} starts per pair "
                       f"(start look distance {a.start_look_distance}), camera radius {a.camera_radius} (+ planning "
                       f"margin {a.safety_margin}), semantic smoothing {a.semantic_smoothing}, object cluster "
                       f"{a.object_cluster}, object centre {a.object_centre} (centre relevancy {a.centre_relevancy:g}; "
                       f"{unseen}), support layer {'kept' if a.keep_support else 'dropped'}; details in "
                       f"`{a.out}/eval_room.md`\n\n```\n{json.dumps(summary, indent=1)}\n```\n")
    return summary


if __name__ == "__main__":
    main()
