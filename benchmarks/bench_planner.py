"""Planner latency per stage (issue 3): prepare() once, then >= 100 seeded plan() requests.

Usage: .venv/bin/python benchmarks/bench_planner.py [--device cpu|cuda] [--n-gaussians 200000]
       [--pairs 100] [--seed 0] [--grid-resolution 96] [--corridor-backend auto|cpu|batched] [--quick] [--no-record]

Scene: procedural_room(N) (floor, walls, 6 objects). Request k: go-to = a random object's centre
(+ seeded jitter inside its box), look-at = another object's centre, start sampled by the planner
with seed k (what the viewer does). Reports success rate, per-stage median / p95 ms of every key in
Shot.timings, the request total, failures by exception type, and two clearances: the planner's own
verification (every dense sample proven free by the conservative test, else the exact clearance of
the inconclusive ones) and an independent exact clearance of every frame (not timed; on the scene's own device). On CUDA every
timed region is bracketed by torch.cuda.synchronize(). Prints a rich table, writes
benchmarks/bench_planner_<device>_<N>.json and appends a summary to benchmarks/RESULTS.md.
"""
from __future__ import annotations

import argparse
import datetime as dt
import json
import sys
import time
import traceback
from collections import Counter
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks._results import append_results, device_name  # noqa: E402
from cinenerf_ns.planner.distance import clearance  # noqa: E402
from cinenerf_ns.planner.planner import Planner, PlannerConfig  # noqa: E402
from cinenerf_ns.planner.procedural import procedural_room  # noqa: E402
from cinenerf_ns.planner.scene import EllipsoidScene  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cpu", help="cpu | cuda | cuda:N")
    ap.add_argument("--n-gaussians", type=int, default=200_000)
    ap.add_argument("--pairs", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0, help="scene seed and base of the request seeds")
    ap.add_argument("--grid-resolution", type=int, default=None, help="default: PlannerConfig's")
    ap.add_argument("--request-device", default="auto", choices=["auto", "scene"],
                    help="PlannerConfig.request_device: auto = per-request queries on a CPU mirror of a GPU scene")
    ap.add_argument("--corridor-backend", default="auto", choices=["auto", "cpu", "batched"],
                    help="PlannerConfig.corridor_backend: auto = batched polytopes on a CUDA scene, else host polytopes")
    ap.add_argument("--start-look-distance", type=float, default=None,
                    help="PlannerConfig.start_look_distance (default: PlannerConfig's; 0: uniform random starts)")
    ap.add_argument("--quick", action="store_true", help="20k Gaussians, 20 requests (smoke run)")
    ap.add_argument("--no-record", action="store_true",
                    help="do not append to benchmarks/RESULTS.md nor write benchmarks/bench_planner_<device>_<N>.json")
    ap.add_argument("--note", default="", help="free text appended to the RESULTS.md line (e.g. 'box loaded')")
    args = ap.parse_args()
    if args.quick:
        args.n_gaussians, args.pairs = min(args.n_gaussians, 20_000), min(args.pairs, 20)
    dev = torch.device(args.device)
    cuda = dev.type == "cuda"
    if cuda and not torch.cuda.is_available():
        sys.exit("--device cuda but torch.cuda.is_available() is False")

    def sync():
        if cuda:
            torch.cuda.synchronize(dev)

    t0 = time.perf_counter()
    room = procedural_room(args.n_gaussians, seed=args.seed)
    scene = EllipsoidScene.from_splat(
        room.means.to(dev), room.quats.to(dev), room.log_scales.to(dev), room.opacity_logits.to(dev)
    )
    sync()
    build_s = time.perf_counter() - t0
    cfg = PlannerConfig(request_device=args.request_device, corridor_backend=args.corridor_backend)
    if args.grid_resolution is not None:
        cfg.grid_resolution = args.grid_resolution
    if args.start_look_distance is not None:
        cfg.start_look_distance = args.start_look_distance
    planner = Planner(scene, cfg)
    if cuda:  # warm-up of kernels/allocator on a tiny prepare, not timed
        Planner(scene.subset(torch.arange(min(len(scene), 2000), device=dev)), cfg).prepare()
    sync()
    t0 = time.perf_counter()
    prep = planner.prepare()
    sync()
    prepare_ms = {**prep.timings_ms, "prepare_total_ms": 1e3 * (time.perf_counter() - t0)}

    rng = np.random.default_rng(args.seed)
    objs = room.objects
    requests = []
    for k in range(args.pairs):
        i, j = rng.choice(len(objs), 2, replace=False)
        goal = objs[i].center + rng.uniform(-0.25, 0.25, 3) * objs[i].size
        requests.append((goal, objs[j].center.copy(), args.seed * 100_003 + k))

    per_stage: dict[str, list] = {}
    totals, fails, clear_verified, clear_exact, inconclusive = [], Counter(), [], [], []
    fail_examples: dict[str, str] = {}
    for goal, look, seed in requests:
        sync()
        t0 = time.perf_counter()
        try:
            shot = planner.plan(goal, look, seed=seed)[0]
        except Exception as e:  # noqa: BLE001 - the benchmark counts every failure by type
            sync()
            name = type(e).__name__
            fails[name] += 1
            fail_examples.setdefault(name, "".join(traceback.format_exception_only(type(e), e)).strip()[:300])
            continue
        sync()
        totals.append(1e3 * (time.perf_counter() - t0))
        for k, v in shot.timings.items():
            per_stage.setdefault(k, []).append(float(v))
        rep = shot.safety
        inconclusive.append(rep["num_inconclusive"])
        if rep["min_exact_clearance"] is not None:
            clear_verified.append(rep["min_exact_clearance"])
        # independent exact check of every frame (not timed); distances beyond 0.25 are not searched
        # for (reported as 0.25 - camera radius, a lower bound): only the minimum matters here
        # on the scene's own device (the GPU for --device cuda: the same exact distance, far faster than the
        # CPU mirror for a whole shot at 1M Gaussians)
        pts = torch.as_tensor(shot.positions, dtype=torch.float64, device=planner.batch_scene.device)
        threads = torch.get_num_threads()
        torch.set_num_threads(1 if not cuda else threads)  # small ops: 1 thread is faster on a shared CPU
        cidx = prep.batch_index if prep.batch_index is not None else prep.index
        clear_exact.append(float(clearance(pts, planner.batch_scene, cidx, max_distance=0.25).min()))
        torch.set_num_threads(threads)

    def stat(v):
        a = np.asarray(v, dtype=np.float64)
        return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "max": float(a.max())} if len(a) else None

    n_ok = len(totals)
    stages = {k: stat(v) for k, v in sorted(per_stage.items())}
    stages["wall_total_ms"] = stat(totals)
    result = {
        "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d"),
        "device": device_name(args.device),
        "device_arg": args.device,
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "n_gaussians": len(scene),
        "grid_resolution": cfg.grid_resolution,
        "corridor_backend": f"{args.corridor_backend} -> {planner.corridor_backend()}",
        "grid_shape": list(prep.grid.shape),
        "pairs": args.pairs,
        "seed": args.seed,
        "scene_build_s": build_s,
        "prepare_ms": prepare_ms,
        "success": n_ok,
        "success_rate": n_ok / max(1, args.pairs),
        "failures": dict(fails),
        "failure_examples": fail_examples,
        "stages_ms": stages,
        # every sample was proven free by the conservative test unless an exact value is listed
        "min_verified_exact_clearance": min(clear_verified) if clear_verified else None,
        "shots_with_inconclusive_samples": int(sum(1 for x in inconclusive if x)),
        "min_exact_frame_clearance": min(clear_exact) if clear_exact else None,
    }

    try:
        from rich.console import Console
        from rich.table import Table

        tab = Table(title=f"plan() per stage, {len(scene)} Gaussians, {result['device']} ({n_ok}/{args.pairs} ok)")
        for c in ("stage", "median ms", "p95 ms", "max ms"):
            tab.add_column(c, justify="right" if c != "stage" else "left")
        for k, v in stages.items():
            if v:
                tab.add_row(k, f"{v['median']:.1f}", f"{v['p95']:.1f}", f"{v['max']:.1f}")
        for k, v in prepare_ms.items():
            tab.add_row(f"prepare: {k}", f"{v:.0f}", "", "")
        Console().print(tab)
    except ImportError:
        print(json.dumps(stages, indent=1))
    print(f"failures: {dict(fails) or 'none'}  examples: {fail_examples}")
    print(
        f"min exact frame clearance {result['min_exact_frame_clearance']}, verified exact (inconclusive samples only) "
        f"{result['min_verified_exact_clearance']}, shots with inconclusive samples {result['shots_with_inconclusive_samples']}"
    )
    if args.no_record:  # a trial run: neither the committed JSON nor RESULTS.md changes
        return
    out = REPO / "benchmarks" / f"bench_planner_{dev.type}_{len(scene)}.json"
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out}")
    med = lambda k: stages[k]["median"] if stages.get(k) else float("nan")  # noqa: E731
    p95 = lambda k: stages[k]["p95"] if stages.get(k) else float("nan")  # noqa: E731
    keys = [k for k in ("start_sample_ms", "goal_ms", "astar_ms", "shortcut_ms", "corridor_ms", "qp_ms", "timing_ms",
                        "orientation_ms", "verify_ms") if k in stages]
    lines = [
        f"### bench_planner.py  {result['date']}  {result['device']} ({args.device}, request_device {args.request_device}, corridor_backend {result['corridor_backend']}, torch threads {result['torch_threads']})"
        + (f"  {args.note}" if args.note else ""),
        "",
        f"procedural_room N={len(scene)} seed {args.seed}, grid_resolution {cfg.grid_resolution} {result['grid_shape']}, "
        f"{args.pairs} requests (random start, go-to object +-jitter, look-at object); success {n_ok}/{args.pairs}, "
        f"failures {dict(fails) or 'none'}; min exact frame clearance {result['min_exact_frame_clearance']}",
        "",
        "prepare ms: " + ", ".join(f"{k} {v:.0f}" for k, v in prepare_ms.items()),
        "",
        "| stage | " + " | ".join(k.replace("_ms", "") for k in keys) + " | request total (wall) |",
        "|---" * (len(keys) + 2) + "|",
        "| median ms | " + " | ".join(f"{med(k):.1f}" for k in keys) + f" | {med('wall_total_ms'):.1f} |",
        "| p95 ms | " + " | ".join(f"{p95(k):.1f}" for k in keys) + f" | {p95('wall_total_ms'):.1f} |",
        "",
    ]
    append_results("\n".join(lines))


if __name__ == "__main__":
    main()
