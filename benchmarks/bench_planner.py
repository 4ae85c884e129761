"""Planner latency per stage (issue 3): prepare() once, then >= 100 seeded plan() requests.

Usage: .venv/bin/python benchmarks/bench_planner.py [--device cpu|cuda] [--n-gaussians 200000]
       [--pairs 100] [--seed 0] [--grid-resolution 96] [--corridor-backend auto|cpu|batched] [--quick] [--no-record]
       [--family procedural|blobs|grove|fox|ply:PATH|npz:PATH] [--start-mode random|given]

Scene (--family, benchmarks/scene_families.py): procedural_room(N) (floor, walls, 6 objects; the default), blobs
(synthetic/blobs.py: y up, walls + random round blobs + floaters), or a file (the fox capture, any .ply / compact
export; loaded with cinenerf_ns.scenes.load_scene, its start_region passed to PlannerConfig). Request k: go-to = a
random object's centre (+ seeded jitter inside it), look-at = another object's centre (files: both uniform in the start
region); start (--start-mode): sampled by the planner with seed k (random: what the viewer does), or given: an explicit
start drawn seeded before timing (>= 0.1 from every Gaussian centre, >= 0.5 from the go-to target, accepted by the
planner's checks); Planner.plan then includes its start check (start_check stage). Reports success rate, the request
total (wall time of Planner.plan: what the user waits for) with median / p95 / max, per-stage median / p95 / max of
every key in Shot.timings, failures by exception type, and two clearances: the planner's own
verification (every dense sample proven free by the conservative test, else the exact clearance of
the inconclusive ones) and an independent exact clearance of every frame (not timed; on the scene's own device). The
grove (--family grove) plans its seeded pairs (given: from the pair's start) and, where the fine reference search joins
them, reports the go-tos reached within REACH_TOL and the path length over the reference path's. On CUDA
every timed region is bracketed by torch.cuda.synchronize(). Prints a rich table, writes
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
from benchmarks.scene_families import FAMILIES, given_starts, load_family, request_fn  # noqa: E402
from cinenerf_ns.planner.corridor import corridor_options  # noqa: E402
from cinenerf_ns.planner.geometry.distance import clearance  # noqa: E402
from cinenerf_ns.planner.scene.floaters import apply_floater_rule  # noqa: E402
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig  # noqa: E402

REACH_TOL = 0.05  # scene units: a grove shot reaches its go-to when it ends this close to it (issue 37)


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
                    help="PlannerConfig.corridor_backend: auto = host polytopes per request, batched for candidate "
                         "batches on CUDA")
    ap.add_argument("--start-look-distance", type=float, default=None,
                    help="PlannerConfig.start_look_distance (default: PlannerConfig's; 0: uniform random starts)")
    ap.add_argument("--family", default="procedural", help=f"scene family: {FAMILIES}")
    ap.add_argument("--start-mode", default="random", choices=["random", "given"],
                    help="random: the planner samples each start; given: explicit starts, drawn before timing")
    ap.add_argument("--region-rule", default="auto", choices=["auto", "dense", "robust"],
                    help="PlannerConfig.region_rule without training cameras (robust: the rule before issue 37)")
    ap.add_argument("--no-refine", action="store_true",
                    help="PlannerConfig.refine_disconnected=False (the behaviour before issue 37)")
    ap.add_argument("--max-voxel-radii", default="default",
                    help="PlannerConfig.max_voxel_radii: a number, 'none' (exactly --grid-resolution: the rule before "
                         "the finer open-scene grids) or 'default'")
    ap.add_argument("--ignore-floaters", default="off", choices=["auto", "on", "off"],
                    help="scene/floaters.py: plan without the small, faint, isolated Gaussians (the independent exact "
                         "check then also reports the clearance to every Gaussian)")
    ap.add_argument("--profile", type=int, default=0,
                    help="cProfile the N slowest requests again after the run (printed, not recorded)")
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
    fam = load_family(args.family, args.n_gaussians, args.seed, args.device, n_pairs=args.pairs)
    full_scene = fam.scene
    scene, floaters = apply_floater_rule(full_scene, args.ignore_floaters)
    sync()
    build_s = time.perf_counter() - t0
    # the procedural room keeps its historical setting (no start region: comparable with older records)
    cfg = PlannerConfig(request_device=args.request_device, corridor_backend=args.corridor_backend, up=fam.up,
                        start_region=None if fam.kind == "procedural" else fam.start_region,
                        obstacles_note=floaters.obstacle_note(), region_rule=args.region_rule,
                        refine_disconnected=not args.no_refine)
    if args.grid_resolution is not None:
        cfg.grid_resolution = args.grid_resolution
    if args.max_voxel_radii != "default":
        cfg.max_voxel_radii = None if args.max_voxel_radii == "none" else float(args.max_voxel_radii)
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
    region = fam.start_region if fam.start_region is not None else planner.region()
    requests = []
    for k in range(args.pairs):
        goal, look = fam.targets(rng, *region)
        requests.append((goal, look, args.seed * 100_003 + k))
    starts = [None] * len(requests)
    if fam.pairs:  # the grove: its seeded pairs (reference-searched); given mode starts at the pair's start
        requests = [(p.goal, p.look_at, args.seed * 100_003 + k) for k, p in enumerate(fam.pairs)]
        starts = [p.start if args.start_mode == "given" else None for p in fam.pairs]
    elif args.start_mode == "given":  # drawn (and checked) before timing
        starts = given_starts(planner, [g for g, _, _ in requests], region, args.seed)
    plan = request_fn(planner, args.start_mode)

    per_stage: dict[str, list] = {}
    totals, fails, clear_verified, clear_exact, inconclusive = [], Counter(), [], [], []
    clear_all = []  # with floaters ignored: exact clearance of every frame to every Gaussian (floaters included)
    full_index = None
    if floaters.ignored:
        from cinenerf_ns.planner.scene.spatial_index import GridIndex

        full_index = GridIndex.build(full_scene)
    fail_examples: dict[str, str] = {}
    reach = []  # grove pairs the reference joins: (reached within REACH_TOL, shot length / reference length or None)
    timed = []  # (ms, request index)
    shot_timings = []  # (ms, request index, Shot.timings) of each planned request
    for ri, ((goal, look, seed), st) in enumerate(zip(requests, starts)):
        sync()
        t0 = time.perf_counter()
        ref = fam.pairs[ri].reference_length if fam.pairs and args.start_mode == "given" else None
        try:
            shot = plan(goal, look, st, seed)[0]
        except Exception as e:  # noqa: BLE001 - the benchmark counts every failure by type
            sync()
            if ref is not None:
                reach.append((False, None))
            name = type(e).__name__
            fails[name] += 1
            fail_examples.setdefault(name, "".join(traceback.format_exception_only(type(e), e)).strip()[:300])
            continue
        sync()
        totals.append(1e3 * (time.perf_counter() - t0))
        timed.append((totals[-1], ri))
        if ref is not None:
            reached = float(np.linalg.norm(np.asarray(shot.goal) - goal)) <= REACH_TOL
            reach.append((reached, shot.length / ref if reached else None))
        for k, v in shot.timings.items():
            per_stage.setdefault(k, []).append(float(v))
        shot_timings.append((totals[-1], ri, dict(shot.timings)))
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
        if full_index is not None:
            clear_all.append(float(clearance(pts, full_scene, full_index, max_distance=0.25).min()))
        torch.set_num_threads(threads)

    def stat(v):
        a = np.asarray(v, dtype=np.float64)
        return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)),
                "max": float(a.max())} if len(a) else None

    n_ok = len(totals)
    stages = {"wall_total_ms": stat(totals), **{k: stat(v) for k, v in sorted(per_stage.items())}}
    result = {
        "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%d"),
        "device": device_name(args.device),
        "device_arg": args.device,
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "n_gaussians": len(scene),
        "grid_resolution": cfg.grid_resolution,
        "corridor_backend": f"{args.corridor_backend} -> {corridor_options.corridor_backend(planner.space)}",
        "grid_shape": list(prep.grid.shape),
        "pairs": args.pairs,
        "seed": args.seed,
        "family": args.family,
        "region_rule": planner.region_rule(),
        "refine_disconnected": not args.no_refine,
        "family_description": fam.description,
        "start_mode": args.start_mode,
        "slowest_requests": [{"ms": ms, "request": ri, "timings_ms": tm}
                             for ms, ri, tm in sorted(shot_timings, key=lambda x: -x[0])[:3]],
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
        "floaters": floaters.to_dict(),
    }
    if clear_all:  # floaters ignored: how close the frames come to every Gaussian (negative: through a floater)
        a = np.asarray(clear_all)
        result["floaters"].update({"min_frame_clearance_all_gaussians": float(a.min()),
                                   "shots_through_ignored_floaters": int((a < 0).sum())})
    if reach:  # the grove's reference-joined pairs (given starts)
        ratios = [r for ok, r in reach if r is not None]
        result["reference"] = {
            "pairs_joined": len(reach), "reached_within": REACH_TOL,
            "reached": int(sum(ok for ok, _ in reach)), "reach_rate": sum(ok for ok, _ in reach) / len(reach),
            "length_ratio": stat(ratios), "length_ratio_over_1_3": int(sum(r > 1.3 for r in ratios))}

    try:
        from rich.console import Console
        from rich.table import Table

        tab = Table(title=f"plan() request total, then per stage: {fam.description}, {args.start_mode} starts, "
                          f"{result['device']} ({n_ok}/{args.pairs} ok)")
        for c in ("stage", "median ms", "p95 ms", "max ms"):
            tab.add_column(c, justify="right" if c != "stage" else "left")
        for k, v in stages.items():
            if v:
                tab.add_row(k, f"{v['median']:.2f}", f"{v['p95']:.2f}", f"{v['max']:.2f}")
        for k, v in prepare_ms.items():
            tab.add_row(f"prepare: {k}", f"{v:.0f}", "", "")
        Console().print(tab)
    except ImportError:
        print(json.dumps(stages, indent=1))
    print(f"failures: {dict(fails) or 'none'}  examples: {fail_examples}")
    if "reference" in result:
        print(f"reference: {result['reference']}")
    print(f"floaters: {result['floaters']}")
    print(
        f"min exact frame clearance {result['min_exact_frame_clearance']}, verified exact (inconclusive samples only) "
        f"{result['min_verified_exact_clearance']}, shots with inconclusive samples "
        f"{result['shots_with_inconclusive_samples']}"
    )
    for sl in result["slowest_requests"]:
        print(f"slow request {sl['request']}: {sl['ms']:.1f} ms: "
              + ", ".join(f"{k[:-3]} {v:.1f}" for k, v in sl["timings_ms"].items() if k.endswith("_ms")))
    if args.profile:
        profile_requests(plan, requests, starts, [ri for _, ri in sorted(timed, reverse=True)[: args.profile]])
    if args.no_record:  # a trial run: neither the committed JSON nor RESULTS.md changes
        return
    default = args.family == "procedural" and args.start_mode == "random"  # the historical file names
    tag = "" if default else f"{fam.name.split(':')[0]}_{args.start_mode}_"
    out = REPO / "benchmarks" / f"bench_planner_{dev.type}_{tag}{len(scene)}.json"
    out.write_text(json.dumps(result, indent=1))
    print(f"wrote {out}")
    med = lambda k: stages[k]["median"] if stages.get(k) else float("nan")  # noqa: E731
    p95 = lambda k: stages[k]["p95"] if stages.get(k) else float("nan")  # noqa: E731
    mx = lambda k: stages[k]["max"] if stages.get(k) else float("nan")  # noqa: E731
    keys = [k for k in ("start_check_ms", "start_sample_ms", "goal_ms", "astar_ms", "shortcut_ms", "corridor_ms",
                        "qp_ms", "timing_ms", "orientation_ms", "verify_ms") if k in stages]
    cmd = " ".join(["python benchmarks/bench_planner.py", *sys.argv[1:]])
    lines = [
        f"### bench_planner.py  {result['date']}  {result['device']} ({args.device}, request_device "
        f"{args.request_device}, corridor_backend {result['corridor_backend']}, torch threads "
        f"{result['torch_threads']})"
        + (f"  {args.note}" if args.note else ""),
        "",
        f"`{cmd}`",
        "",
        f"family {args.family}: {fam.description}, region {result['region_rule']}"
        + ("" if not args.no_refine else ", no refinement")
        + f", grid_resolution {cfg.grid_resolution} (max_voxel_radii {cfg.max_voxel_radii}) {result['grid_shape']}, "
        f"{args.pairs} requests ({args.start_mode} start, "
        + (f"floaters ignored: {floaters.count} of {floaters.total} Gaussians, "
           f"{result['floaters'].get('shots_through_ignored_floaters', 0)} shots pass through one "
           f"(min clearance to all Gaussians {result['floaters'].get('min_frame_clearance_all_gaussians', 0):.4f}), "
           if floaters.ignored else "")
        + ("go-to object +-jitter, look-at object" if fam.objects else
           "seeded grove pairs" if fam.pairs else "go-to and look-at uniform in the start region")
        + f"); success {n_ok}/{args.pairs}, failures {dict(fails) or 'none'}; min exact frame clearance "
        f"{result['min_exact_frame_clearance']}",
        "",
        *([reference_line(result["reference"]), ""] if "reference" in result else []),
        "prepare ms: " + ", ".join(f"{k} {v:.0f}" for k, v in prepare_ms.items()),
        "",
        "| ms | median | p95 | max |",
        "|---|---|---|---|",
        f"| **request total (wall)** | {med('wall_total_ms'):.1f} | {p95('wall_total_ms'):.1f} | "
        f"{mx('wall_total_ms'):.1f} |",
        *[f"| {k.replace('_ms', '')} | {med(k):.1f} | {p95(k):.1f} | {mx(k):.1f} |" for k in keys],
        "",
    ]
    append_results("\n".join(lines))


def reference_line(ref: dict) -> str:
    """The RESULTS.md line of the grove's reference comparison."""
    lr = ref["length_ratio"]
    ratio = ("no pair reached" if lr is None else f"path length / reference: median {lr['median']:.3f}, p95 "
             f"{lr['p95']:.3f}, max {lr['max']:.3f} ({ref['length_ratio_over_1_3']} over 1.3)")
    return (f"reference-joined pairs: {ref['reached']}/{ref['pairs_joined']} go-tos reached within "
            f"{ref['reached_within']:g} ({100 * ref['reach_rate']:.0f}%); {ratio}")


def profile_requests(plan, requests, starts, indices) -> None:
    """Run the given requests again under cProfile and print each one's top functions (cumulative time)."""
    import cProfile
    import io
    import pstats

    for ri in indices:
        (goal, look, seed), st = requests[ri], starts[ri]
        pr = cProfile.Profile()
        t0 = time.perf_counter()
        pr.enable()
        try:
            shot = plan(goal, look, st, seed)[0]
        finally:
            pr.disable()
        ms = 1e3 * (time.perf_counter() - t0)
        buf = io.StringIO()
        pstats.Stats(pr, stream=buf).sort_stats("cumulative").print_stats(30)
        print(f"--- profile of request {ri} ({ms:.1f} ms under the profiler; goal {np.round(goal, 3).tolist()}, start "
              f"{None if st is None else np.round(st, 3).tolist()}; stages "
              + ", ".join(f"{k[:-3]} {v:.1f}" for k, v in shot.timings.items() if k.endswith("_ms")) + ")")
        print(buf.getvalue())


if __name__ == "__main__":
    main()
