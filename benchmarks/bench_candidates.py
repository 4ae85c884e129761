#!/usr/bin/env python3
"""K ranked candidates (planned + scored) in one batched call vs K sequential single-candidate plans.

    python benchmarks/bench_candidates.py --device cuda --n-gaussians 1000000 --k 32 [--repeats 5] [--workers N]
    [--no-record]
        [--family procedural|blobs|fox|ply:PATH|npz:PATH] [--start-mode random|given]

Scene (--family, benchmarks/scene_families.py; default the procedural room, seeded) on --device; go to object 0, look
at object 1 (files: seeded points in the start region). One-time work (spatial index, occupancy grid) is done once
before timing and is not included.
--start-mode given: the sequential variant plans from K explicit starts (drawn seeded before timing, see
scene_families.given_starts; each Planner.plan includes its start check); plan_candidates samples its own starts
(it takes none), so the batched / workers rows are the same as with random.
  batched:    candidates.plan_candidates(planner, goal, look, k, seed)  (planned, verified, scored, ranked),
              all in this process (PlannerConfig.candidate_workers=0)
  workers:    the same call with candidate_workers=--workers (None/auto: one per usable CPU, 0 on
              < 4 CPUs; the row is then left out): whole candidates in forked worker processes (workers.py),
              scoring and ranking in this process; the pool is forked in the warm-up run, not timed
  sequential: k x planner.plan(goal, look, seed=i, n_candidates=1) + candidates.score_shots on that one shot
Each variant runs once untimed (warm-up: CUDA kernels, caches), then --repeats timed runs (CUDA-synchronised);
the medians and their ratio are printed and appended to benchmarks/RESULTS.md with the date and device.
Issue 7 target (H100, 1M Gaussians, K = 32): batched <= 150 ms and >= 5x faster than sequential.
"""
from __future__ import annotations

import argparse
import datetime as dt
import functools
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks._results import append_results, device_name  # noqa: E402
from benchmarks.scene_families import FAMILIES, given_starts, load_family  # noqa: E402
from cinenerf_ns.planner.corridor import corridor_options  # noqa: E402
from cinenerf_ns.planner.shots.candidates import plan_candidates, score_shots  # noqa: E402
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig  # noqa: E402
from cinenerf_ns.planner.shots.scoring import ScoreConfig  # noqa: E402


def _sync(dev: torch.device) -> None:
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cpu", help="cpu | cuda | cuda:N")
    ap.add_argument("--family", default="procedural", help=f"scene family: {FAMILIES}")
    ap.add_argument("--start-mode", default="random", choices=["random", "given"],
                    help="given: the sequential variant plans from K explicit starts drawn before timing")
    ap.add_argument("--n-gaussians", type=int, default=20_000)
    ap.add_argument("--k", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--grid-resolution", type=int, default=96)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-voxel-radii", default="default",
                    help="PlannerConfig.max_voxel_radii: a number, 'none' (exactly --grid-resolution) or 'default'")
    ap.add_argument("--request-device", default="auto", choices=["auto", "scene"],
                    help="PlannerConfig.request_device: auto = per-request queries on a CPU mirror of a GPU scene")
    ap.add_argument("--workers", type=int, default=None,
                    help="PlannerConfig.candidate_workers of the workers row (default: auto, see workers.py)")
    ap.add_argument("--corridor-backend", default="auto", choices=["auto", "cpu", "batched"],
                    help="PlannerConfig.corridor_backend (auto: batched on a CUDA scene, and then the workers' rounds "
                         "have two phases around one batched corridor call)")
    ap.add_argument("--note", default="", help="a line added under the table in RESULTS.md (e.g. about the box)")
    ap.add_argument("--no-record", action="store_true", help="do not append to benchmarks/RESULTS.md")
    args = ap.parse_args()
    dev = torch.device(args.device)

    fam = load_family(args.family, args.n_gaussians, args.seed, args.device, n_pairs=1)  # the grove: one pair
    scene = fam.scene
    planner = Planner(scene, PlannerConfig(grid_resolution=args.grid_resolution, request_device=args.request_device,
                                           start_region=fam.start_region, up=fam.up,
                                           corridor_backend=args.corridor_backend))
    if args.max_voxel_radii != "default":
        planner.config.max_voxel_radii = None if args.max_voxel_radii == "none" else float(args.max_voxel_radii)
    t0 = time.perf_counter()
    planner.prepare()
    _sync(dev)
    prep_s = time.perf_counter() - t0
    region = fam.start_region if fam.start_region is not None else planner.region()
    if fam.objects:
        goal, look = fam.objects[0][0], fam.objects[1][0]
        obj_r = float(0.5 * np.linalg.norm(fam.objects[1][1]))
    else:
        goal, look = fam.targets(np.random.default_rng(args.seed), *region)
        obj_r = 0.1
    starts = given_starts(planner, [goal] * args.k, region, args.seed) if args.start_mode == "given" else None
    cfg = ScoreConfig()

    def batched(workers=0):
        planner.config.candidate_workers = workers
        tm = {}
        out = plan_candidates(planner, goal, look, k=args.k, seed=args.seed, score_config=cfg, object_radius=obj_r,
                              timings=tm)
        return out, tm

    planner.config.candidate_workers = args.workers
    n_workers = planner.candidate_workers()  # auto resolved; 0: no workers row
    pooled = functools.partial(batched, n_workers)

    def sequential():
        out = []
        for i in range(args.k):
            s = None if starts is None else starts[i]
            sh = planner.plan(goal, look, start=s, seed=args.seed + i, n_candidates=1)
            out.append((sh[0], score_shots(planner, sh, look, cfg, object_radius=obj_r)[0]))
        return out

    def timed(fn):
        _sync(dev)
        t = time.perf_counter()
        res = fn()
        _sync(dev)
        return 1e3 * (time.perf_counter() - t), res

    timed(batched)
    if n_workers:
        timed(pooled)  # forks the pool
    timed(sequential)
    b_ms, s_ms, w_ms, stages, w_stages, seq_stages, ends = [], [], [], [], [], [], []
    n_b = n_s = n_w = 0
    for _ in range(args.repeats):
        ms, (res, tm) = timed(batched)
        b_ms.append(ms)
        stages.append(tm)
        n_b = len(res)
        ends = [float(np.linalg.norm(np.asarray(r.shot.goal) - goal)) for r in res]  # rank order
        if n_workers:
            ms, (res, tm) = timed(pooled)
            w_ms.append(ms)
            w_stages.append(tm)
            n_w = len(res)
        ms, res = timed(sequential)
        s_ms.append(ms)
        n_s = len(res)
        seq_stages.append({k: sum(sh.timings.get(k, 0.0) for sh, _ in res) for k in stages[-1]})
    mb, msq = statistics.median(b_ms), statistics.median(s_ms)
    spread = lambda v: f"{np.percentile(v, 95):.1f} / {max(v):.1f}"  # noqa: E731 - p95 / max over the repeats
    stage_keys = [k for k in stages[0] if k.endswith("_ms") and k != "total_ms"]
    med_stage = {k: statistics.median(s[k] for s in stages) for k in stage_keys}
    # the sequential plans' own stage times (Shot.timings; scoring is not in them)
    med_seq = {k: statistics.median(s[k] for s in seq_stages) for k in stage_keys if k != "score_ms"}
    planner.close()
    mw = statistics.median(w_ms) if w_ms else float("nan")
    w_keys = [k for k in w_stages[0] if k.endswith("_ms") and k != "total_ms"] if w_stages else []
    med_w = {k: statistics.median(s.get(k, 0.0) for s in w_stages) for k in w_keys}
    workers_rows = [
        f"| batched plan_candidates, {n_workers} workers | {mw:.1f} | {spread(w_ms)} | {n_w} | {mw / max(n_w, 1):.1f} "
        f"| {mb / mw:.2f} |"
    ] if n_workers else []
    workers_notes = [
        f"- {n_workers}-worker stage medians (ms; per-stage sums of the workers' wall times, which overlap; pool = "
        f"this process waiting for the workers): " + ", ".join(f"{k[:-3]} {v:.1f}" for k, v in med_w.items()),
        f"- speed-up sequential / batched with {n_workers} workers: {msq / mw:.2f}x; batched in-process / "
        f"{n_workers} workers: {mb / mw:.2f}x",
    ] if n_workers else [f"- no workers row: candidate_workers={args.workers} resolves to 0 on this machine"]
    date = dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d")
    try:
        import subprocess

        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                             text=True).stdout.strip()
    except OSError:
        rev = "?"
    lines = [
        f"## bench_candidates {date} — {device_name(dev)}",
        "",
        f"`{' '.join(['python benchmarks/bench_candidates.py', *sys.argv[1:]])}`",
        "",
        f"family {args.family}: {fam.description}, {args.start_mode} starts (sequential row), K={args.k}, "
        f"grid {args.grid_resolution} (max_voxel_radii {planner.config.max_voxel_radii}: "
        f"{list(planner.ready().grid.shape)}), "
        f"request_device {args.request_device}, corridor_backend {args.corridor_backend} -> "
        f"{corridor_options.corridor_backend(planner.space)}, "
        f"repeats {args.repeats}, prepare {prep_s:.2f} s (not timed below), commit {rev or '?'}",
        "",
        "| variant (request total) | median ms | p95 / max ms | shots | ms / shot | x batched |",
        "|---|---|---|---|---|---|",
        f"| batched plan_candidates | {mb:.1f} | {spread(b_ms)} | {n_b} | {mb / max(n_b, 1):.1f} | 1.00 |",
        *workers_rows,
        f"| sequential plan(n_candidates=1) + score | {msq:.1f} | {spread(s_ms)} | {n_s} | {msq / max(n_s, 1):.1f} | "
        f"{msq / mb:.2f} |",
        "",
        "- batched (in-process) stage medians (ms, summed over candidates): "
        + ", ".join(f"{k[:-3]} {v:.1f}" for k, v in med_stage.items()),
        *workers_notes,
        "- sequential stage medians (ms, summed over its plans; "
        + ("the given starts" if starts is not None else "different random starts") + "): "
        + ", ".join(f"{k[:-3]} {v:.1f}" for k, v in med_seq.items()),
        f"- speed-up sequential / batched in-process: {msq / mb:.2f}x; target on H100 at 1M, K=32: batched <= 150 ms "
        f"and >= 5x",
        f"- go-to reached (batched, last repeat): the best-ranked shot ends {ends[0]:.3g} from it; "
        f"{sum(d <= 0.05 for d in ends)}/{len(ends)} candidates within 0.05" if ends else "- no batched shot",
        *([f"- note: {args.note}"] if args.note else []),
        "",
    ]
    table = "\n".join(lines)
    print(table)
    if not args.no_record:
        append_results(table)


if __name__ == "__main__":
    main()
