"""Shot quality as the user sees it: is the look-at subject visible and framed at the end of the shot? (issue 34)

    python benchmarks/bench_shot_quality.py --room cinenerf_ns/assets/room0.npz:cinenerf_ns/assets/room0_gt \\
        --room .data/room1/room1.npz:.data/room1 --room .data/room2/room2.npz:.data/room2 [--framing medium]

Every ordered pair of distinct objects of each room is planned as ``cinesplat-plan --go-to A --look-at B`` plans it
(text -> the method's selection -> end poses -> one candidate from a seeded random start; ``--no-end-pose``: the
go-to object's centre, the behaviour before end poses). Each shot is then judged independently of the planner:
each Gaussian gets the colour of its ground-truth object (geometry.json: the Gaussians on or in the object's true
volume), the frames are rendered with the project's compiled rasteriser at --width x --height, and

  visible fraction  = subject colour composited through the whole splat / the subject rendered alone,
  subject size      = the larger relative extent of the subject-alone pixels with alpha > 0.5 (framing.py's measure),
  cut off           = such a pixel on the frame border,
  go-to fill        = share of pixels where the go-to object's colour composites to > 0.5.

Frames: at most --frames evenly spaced ones, the last always. Writes shot_quality.json / .md into --out and appends a
summary to benchmarks/RESULTS.md; the demo pair's last frame is saved as a PNG with the subject outlined.
"""
from __future__ import annotations

import argparse
import datetime
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._results import append_results, device_name  # noqa: E402
from benchmarks.eval_synthetic import gaussians_in_object, load_ground_truth, object_names  # noqa: E402
from cinenerf_ns.planner.scene.scene_config import DEFAULT_SAFETY_MARGIN, SceneConfig  # noqa: E402
from cinenerf_ns.planner.shots import stages  # noqa: E402,F401
from cinenerf_ns.planner.shots.camera_path import shot_to_camera_path  # noqa: E402
from cinenerf_ns.planner.shots.candidates import plan_candidates  # noqa: E402
from cinenerf_ns.planner.shots.framing import FRAMING_BANDS, FramingConfig  # noqa: E402
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig  # noqa: E402
from cinenerf_ns.planner.shots.scoring import ScoreConfig  # noqa: E402
from cinenerf_ns.preview.cameras import path_cameras  # noqa: E402
from cinenerf_ns.preview.raster_torch import make_scene  # noqa: E402
from cinenerf_ns.preview.render import render_premultiplied  # noqa: E402
from cinenerf_ns.scenes import load_scene, resolve_match  # noqa: E402
from cinenerf_ns.shot_targets import shot_targets, start_region_centre  # noqa: E402


def label_ids(means: torch.Tensor, gt, names) -> np.ndarray:
    """int [N]: the ground-truth object of each Gaussian (index into names), -1 for none."""
    lab = np.full(means.shape[0], -1, np.int64)
    tol = 0.01 * gt.room_size()
    for i, n in enumerate(names):
        m = gaussians_in_object(means, gt, n, tol).cpu().numpy()
        lab[m & (lab < 0)] = i
    return lab


def frame_metrics(full_rgb: np.ndarray, alone_alpha: np.ndarray) -> dict:
    """Metrics of one frame from the label render through the splat (R: subject, G: go-to) and the subject alone."""
    den = float(alone_alpha.sum())
    vis = float(full_rgb[..., 0].sum() / den) if den > 1e-6 else 0.0
    px = alone_alpha > 0.5
    h, w = px.shape
    if px.any():
        ys, xs = np.nonzero(px)
        size = max((ys.max() - ys.min() + 1) / h, (xs.max() - xs.min() + 1) / w)
        cut = bool(px[0].any() or px[-1].any() or px[:, 0].any() or px[:, -1].any())
    else:
        size, cut = 0.0, False
    return {"visible": min(1.0, vis), "size": float(size), "cut": cut,
            "goto_fill": float((full_rgb[..., 1] > 0.5).mean())}


def render_pair(scene_full, scene_alone, cams, frames) -> list:
    out = []
    for f in frames:
        vm, intr = cams.viewmats[f], cams.intrinsics[f]
        rgb, _ = render_premultiplied(scene_full, vm, intr, cams.width, cams.height)
        _, alpha = render_premultiplied(scene_alone, vm, intr, cams.width, cams.height)
        out.append(frame_metrics(rgb.numpy(), alpha.numpy()[..., 0]))
    return out


def save_last_frame(scene_rgb, scene_alone, cams, path: Path) -> None:
    """The last frame in colour with the subject's alpha > 0.5 outlined in red (the demo pair's check)."""
    import imageio.v3 as iio

    f = len(cams) - 1
    rgb, alpha = render_premultiplied(scene_rgb, cams.viewmats[f], cams.intrinsics[f], cams.width, cams.height)
    img = (np.clip(rgb.numpy() + (1 - alpha.numpy()) * 0.15, 0, 1) * 255).astype(np.uint8)
    _, a = render_premultiplied(scene_alone, cams.viewmats[f], cams.intrinsics[f], cams.width, cams.height)
    m = a.numpy()[..., 0] > 0.5
    edge = m & ~(np.roll(m, 1, 0) & np.roll(m, -1, 0) & np.roll(m, 1, 1) & np.roll(m, -1, 1))
    img[edge] = (255, 0, 0)
    iio.imwrite(path, img)


def bench_room(scene_path: str, gt_dir: str, args, rows: list) -> None:
    scfg = SceneConfig.with_margin(0.03, DEFAULT_SAFETY_MARGIN)
    loaded = load_scene(scene_path, scfg)
    gt = load_ground_truth(gt_dir, Path(gt_dir) / "dataparser_transforms.json")
    names = object_names(gt)
    st = loaded.checkpoint
    means, quats, log_scales, logits = st.params.tensors()
    lab = label_ids(means.double(), gt, names)
    base = make_scene(means, quats, torch.exp(log_scales), torch.sigmoid(logits), torch.zeros(len(lab), 3),
                      drop_transparent=False)
    rgb_scene = make_scene(means, quats, torch.exp(log_scales), torch.sigmoid(logits),
                           torch.from_numpy(st.params.rgb(default=0.6)), drop_transparent=False)
    planner = Planner(loaded.scene, PlannerConfig(start_region=loaded.start_region, candidate_workers=0))
    planner.prepare()
    framing = FramingConfig(args.framing, 50.0, 16 / 9)
    score_cfg = ScoreConfig(fov_deg=50.0)
    room = Path(scene_path).stem
    pair_i = 0
    for a in names:
        for b in names:
            if a == b:
                continue
            pair_i += 1
            t0 = time.perf_counter()
            gm, lm = resolve_match(a, loaded, "go-to"), resolve_match(b, loaded, "look-at")
            goal = planner.checked_point(gm["point"], "go-to")
            look = planner.checked_point(lm["point"], "look-at")
            t1 = time.perf_counter()
            targets = shot_targets(planner, gm, lm, framing, planner.main_component(), k=1,
                                   end_pose=not args.no_end_pose, facing_from=start_region_centre(planner))
            goals = targets.goals(goal)
            ranked = plan_candidates(planner, goals[0], look, k=1, seed=pair_i, score_config=score_cfg,
                                     subject=targets.samples)
            t2 = time.perf_counter()
            shot = ranked[0].shot
            cp = shot_to_camera_path(shot, fov_deg=50.0, width=1920, height=1080)
            cams = path_cameras(cp, width=args.width, height=args.height, fps=max(1.0, min(120.0, 1.0 / cp["seconds"]
                                * len(cp["camera_path"]))))
            n = len(cams)
            frames = sorted(set(np.rint(np.linspace(0, n - 1, min(n, args.frames))).astype(int).tolist()) | {n - 1})
            ia, ib = names.index(a), names.index(b)
            col = np.zeros((len(lab), 3), np.float32)
            col[lab == ib, 0] = 1.0
            col[lab == ia, 1] = 1.0
            full = type(base)(base.means, base.cov3d, base.opacities, torch.from_numpy(col), base.quats, base.scales)
            sel = torch.from_numpy(lab == ib)
            alone = type(base)(base.means[sel], base.cov3d[sel], base.opacities[sel], torch.ones(int(sel.sum()), 3),
                               base.quats[sel], base.scales[sel])
            fm = render_pair(full, alone, cams, frames)
            last = fm[-1]
            lo, _, hi = FRAMING_BANDS[args.framing]
            rows.append({
                "room": room, "go_to": a, "look_at": b,
                "visible_last": last["visible"], "size_last": last["size"], "cut_last": last["cut"],
                "goto_fill_last": last["goto_fill"], "in_band": bool(lo <= last["size"] <= hi),
                "frames_visible_half": float(np.mean([f["visible"] >= 0.5 for f in fm])),
                "end_pose": targets.choice is not None and bool(targets.choice.poses),
                "end_pose_ms": None if targets.choice is None else targets.choice.ms,
                "request_ms": 1e3 * (t2 - t1), "resolve_ms": 1e3 * (t1 - t0),
                "planner_visible_last": ranked[0].score.terms.get("visible_last"),
                "duration_s": float(shot.duration), "length": float(shot.length),
                "safe": bool(shot.safety["safe"]),
            })
            r = rows[-1]
            print(f"{room} {a:>14} -> {b:<14} vis_last {r['visible_last']:.2f} seen {r['frames_visible_half']:.2f} "
                  f"size {r['size_last']:.2f}{' CUT' if r['cut_last'] else ''} goto_fill {r['goto_fill_last']:.2f} "
                  f"req {r['request_ms']:.0f} ms", flush=True)
            if args.demo_png and room == "room0" and a == "red armchair" and b == "floor lamp":
                tag = "_no_end_pose" if args.no_end_pose else ""
                save_last_frame(rgb_scene, alone, path_cameras(cp, width=480, height=270, fps=15.0),
                                Path(args.out) / f"demo_pair_last_frame{tag}.png")


def summarise(rows: list) -> dict:
    v = np.array([r["visible_last"] for r in rows])
    return {
        "shots": len(rows),
        "end_with_subject_80_visible": float(np.mean(v >= 0.8)),
        "median_visible_last": float(np.median(v)),
        "median_frames_visible_half": float(np.median([r["frames_visible_half"] for r in rows])),
        "size_in_band": float(np.mean([r["in_band"] for r in rows])),
        "median_size_last": float(np.median([r["size_last"] for r in rows])),
        "cut_off_last": float(np.mean([r["cut_last"] for r in rows])),
        "goto_fills_over_half": int(sum(r["goto_fill_last"] > 0.5 for r in rows)),
        "all_safe": bool(all(r["safe"] for r in rows)),
        "request_ms_median": float(np.median([r["request_ms"] for r in rows])),
        "request_ms_p95": float(np.percentile([r["request_ms"] for r in rows], 95)),
        "request_ms_max": float(np.max([r["request_ms"] for r in rows])),
        "end_pose_ms_median": (None if rows[0]["end_pose_ms"] is None
                               else float(np.median([r["end_pose_ms"] or 0.0 for r in rows]))),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--room", action="append", required=True, help="SCENE:GROUND_TRUTH_DIR (repeatable)")
    ap.add_argument("--framing", default="medium", choices=list(FRAMING_BANDS))
    ap.add_argument("--no-end-pose", action="store_true", help="plan to the go-to object's centre (the old rule)")
    ap.add_argument("--frames", type=int, default=10, help="frames judged per shot (evenly spaced, last included)")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=90)
    ap.add_argument("--out", default="benchmarks/shot_quality")
    ap.add_argument("--demo-png", action="store_true",
                    help="save the demo pair's last frame with the subject outlined")
    ap.add_argument("--no-record", action="store_true", help="do not append to benchmarks/RESULTS.md")
    args = ap.parse_args()
    Path(args.out).mkdir(parents=True, exist_ok=True)
    rows: list = []
    per_room = {}
    for spec in args.room:
        scene, gt_dir = spec.split(":")
        n0 = len(rows)
        bench_room(scene, gt_dir, args, rows)
        per_room[Path(scene).stem] = summarise(rows[n0:])
    summ = summarise(rows)
    tag = "no end pose (go-to centre)" if args.no_end_pose else f"end poses, framing {args.framing}"
    stem = f"shot_quality_{'baseline' if args.no_end_pose else args.framing}"
    (Path(args.out) / f"{stem}.json").write_text(json.dumps({"summary": summ, "per_room": per_room, "rows": rows},
                                                             indent=1))
    lines = [f"### Shot quality ({tag}), {datetime.date.today()}, {device_name('cpu')}", "",
             "| rooms | shots | end >= 80% visible | median frames >= 50% visible | size in band | go-to fills > 50% "
             "| cut off | median request ms (p95, max) |", "|---|---|---|---|---|---|---|---|"]
    for name, s in [*per_room.items(), ("all", summ)]:
        lines.append(f"| {name} | {s['shots']} | {100 * s['end_with_subject_80_visible']:.0f}% | "
                     f"{100 * s['median_frames_visible_half']:.0f}% | {100 * s['size_in_band']:.0f}% | "
                     f"{s['goto_fills_over_half']} | {100 * s['cut_off_last']:.0f}% | {s['request_ms_median']:.0f} "
                     f"({s['request_ms_p95']:.0f}, {s['request_ms_max']:.0f}) |")
    text = "\n".join(lines) + "\n"
    (Path(args.out) / f"{stem}.md").write_text(text)
    print(text)
    if not args.no_record:
        append_results(text)


if __name__ == "__main__":
    main()
