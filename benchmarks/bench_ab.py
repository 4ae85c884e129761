"""Interleaved A/B of plan requests between two source trees on one machine.

Why: on a shared host the same tree's bench_planner median moves by 20-30 % from one run to the next (the
twentieth session saw 7.3 and 9.6 ms for one tree, back to back), so base/new/new/base runs of bench_planner cannot
resolve a 10 % change. Here one warm worker process per tree (each prepared once, as bench_planner prepares) runs the
same requests in alternating blocks, A B B A per block, so both trees see the same host conditions; the per-block
ratio of medians B/A is the comparison. The absolute values are higher than bench_planner's (the two processes'
1M-Gaussian scenes share the caches), so only the ratios are results; bench_planner gives the numbers recorded.

    python benchmarks/bench_ab.py --tree-a OLD_TREE --tree-b . --family blobs --start-mode given \\
        --n-gaussians 1000000 --device cuda --pairs 100 --block 20

A tree is a directory holding cinenerf_ns/ and benchmarks/ (e.g. `git archive <commit> cinenerf_ns benchmarks`).
--config-a / --config-b set PlannerConfig fields of one side (`--tree-a . --tree-b . --config-b plan_cpu_threads=None`
compares two settings of one tree). Prints median, p95 and max per side and the block ratios; records nothing.
"""
from __future__ import annotations

import argparse
import ast
import dataclasses
import json
import os
import subprocess
import sys
import time
from pathlib import Path


def _worker(args) -> None:
    """One warm planner of the tree in the working directory: answers 'go I J' on stdin with the wall ms of requests
    I..J-1 (None for a failed one) as one JSON line."""
    import warnings

    warnings.filterwarnings("ignore")
    sys.path.insert(0, os.getcwd())
    import numpy as np
    import torch

    from benchmarks.scene_families import given_starts, load_family, request_fn
    from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig

    cuda = args.device.startswith("cuda")
    sync = (lambda: torch.cuda.synchronize()) if cuda else (lambda: None)
    fam = load_family(args.family, args.n_gaussians, args.seed, args.device)
    cfg = PlannerConfig(up=fam.up, start_region=None if fam.kind == "procedural" else fam.start_region)
    cfg = dataclasses.replace(cfg, **_overrides(args.config))
    planner = Planner(fam.scene, cfg)
    if cuda:  # as bench_planner: kernels and allocator warmed on a tiny prepare
        Planner(fam.scene.subset(torch.arange(min(len(fam.scene), 2000), device=fam.scene.device)), cfg).prepare()
    planner.prepare()
    rng = np.random.default_rng(args.seed)
    region = fam.start_region if fam.start_region is not None else planner.region()
    reqs = [(*fam.targets(rng, *region), args.seed * 100_003 + k) for k in range(args.pairs)]
    starts = (given_starts(planner, [g for g, _, _ in reqs], region, args.seed) if args.start_mode == "given"
              else [None] * len(reqs))
    plan = request_fn(planner, args.start_mode)
    print("ready", flush=True)
    for line in sys.stdin:
        cmd = line.split()
        if not cmd or cmd[0] == "quit":
            break
        i, j = int(cmd[1]), int(cmd[2])
        out = []
        for (g, look, s), st in zip(reqs[i:j], starts[i:j]):
            sync()
            t0 = time.perf_counter()
            try:
                plan(g, look, st, s)
                ok = True
            except Exception:  # noqa: BLE001 - a failed request is reported as None, as bench_planner counts it
                ok = False
            sync()
            out.append(1e3 * (time.perf_counter() - t0) if ok else None)
        print(json.dumps(out), flush=True)


def _overrides(items: list) -> dict:
    """--config KEY=VALUE items as {KEY: the Python literal VALUE} (a bare word stays a string)."""
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.isidentifier():
            raise SystemExit(f"bench_ab: --config-a / --config-b take KEY=VALUE, got {item!r}")
        try:
            out[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            out[key] = value
    return out


def _start(tree: Path, args, config: list) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree)] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--family", args.family, "--start-mode",
           args.start_mode, "--n-gaussians", str(args.n_gaussians), "--device", args.device, "--pairs",
           str(args.pairs), "--seed", str(args.seed)] + [f"--config={c}" for c in config]
    p = subprocess.Popen(cmd, cwd=tree, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    line = p.stdout.readline().strip()
    if line != "ready":
        p.kill()
        sys.exit(f"bench_ab: the worker of {tree} did not start (see its error output above)")
    return p


def _stats(v: list) -> str:
    import numpy as np

    if not v:
        return "no successful request"
    return (f"median {np.median(v):.2f} p95 {np.percentile(v, 95):.2f} max {max(v):.2f} ms "
            f"({len(v)} timed)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tree-a", type=Path, help="the base tree (a directory with cinenerf_ns/ and benchmarks/)")
    ap.add_argument("--tree-b", type=Path, help="the tree compared with it")
    ap.add_argument("--family", default="procedural", help="scene family, as bench_planner's --family")
    ap.add_argument("--start-mode", choices=["random", "given"], default="random")
    ap.add_argument("--n-gaussians", type=int, default=200_000)
    ap.add_argument("--device", default="cpu", help="cpu | cuda | cuda:N")
    ap.add_argument("--pairs", type=int, default=60, help="requests; each runs twice per tree per round")
    ap.add_argument("--block", type=int, default=10, help="requests per block (A B B A per block)")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--config-a", action="append", default=[], metavar="KEY=VALUE",
                    help="a PlannerConfig field for tree A's planner (repeatable)")
    ap.add_argument("--config-b", action="append", default=[], metavar="KEY=VALUE",
                    help="a PlannerConfig field for tree B's planner (repeatable)")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--config", action="append", default=[], help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        _worker(args)
        return
    if args.tree_a is None or args.tree_b is None:
        ap.error("--tree-a and --tree-b are required")
    for name, t in (("--tree-a", args.tree_a), ("--tree-b", args.tree_b)):
        if not (t / "cinenerf_ns").is_dir() or not (t / "benchmarks").is_dir():
            ap.error(f"{name} {t} must hold cinenerf_ns/ and benchmarks/")
    for name, v, lo in (("--pairs", args.pairs, 1), ("--block", args.block, 1), ("--rounds", args.rounds, 1)):
        if v < lo:
            ap.error(f"{name} must be >= {lo}, got {v}")
    if args.family == "fox":  # the capture beside this checkout (a tree elsewhere would look beside itself)
        sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
        from benchmarks.scene_families import FOX

        args.family = f"npz:{FOX}"
    prefix, _, source = args.family.partition(":")
    if prefix in ("npz", "ply", "scene") and not source.startswith("procedural"):  # the workers run in the trees:
        args.family = f"{prefix}:{Path(source).resolve()}"  # make the path absolute
    import numpy as np

    from cinenerf_ns.planner.config import PlannerConfig  # the config alone: no torch in this process

    fields = {f.name for f in dataclasses.fields(PlannerConfig)}
    for c in args.config_a + args.config_b:
        if next(iter(_overrides([c]))) not in fields:
            ap.error(f"{c!r}: PlannerConfig has no field {c.partition('=')[0]!r}")
    workers = [_start(args.tree_a.resolve(), args, args.config_a), _start(args.tree_b.resolve(), args, args.config_b)]

    def run(p, i, j):
        p.stdin.write(f"go {i} {j}\n")
        p.stdin.flush()
        return json.loads(p.stdout.readline())

    a_ms, b_ms, ratios = [], [], []
    for _ in range(args.rounds):
        for i in range(0, args.pairs, args.block):
            j = min(i + args.block, args.pairs)
            a1 = run(workers[0], i, j)
            b1, b2 = run(workers[1], i, j), run(workers[1], i, j)
            a2 = run(workers[0], i, j)
            av = [x for x in a1 + a2 if x is not None]
            bv = [x for x in b1 + b2 if x is not None]
            a_ms += av
            b_ms += bv
            if av and bv:
                ratios.append(float(np.median(bv) / np.median(av)))
    for p in workers:
        p.stdin.write("quit\n")
        p.stdin.flush()
        p.wait()
    print(f"{args.family}@{args.start_mode}, {args.n_gaussians} Gaussians, {args.device}")
    print(f"  A {args.tree_a}{' ' + ' '.join(args.config_a) if args.config_a else ''}: {_stats(a_ms)}")
    print(f"  B {args.tree_b}{' ' + ' '.join(args.config_b) if args.config_b else ''}: {_stats(b_ms)}")
    if ratios:
        print(f"  block ratio B/A: median {np.median(ratios):.3f}, range [{min(ratios):.3f}, {max(ratios):.3f}] over "
              f"{len(ratios)} blocks")


if __name__ == "__main__":
    main()
