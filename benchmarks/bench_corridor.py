"""Corridor stage alone (issue 3): host polytopes vs the batched builder, and the batched builder's index query.

Usage: .venv/bin/python benchmarks/bench_corridor.py [--device cuda] [--n-gaussians 1000000] [--paths 20]

Plans ``--paths`` requests (as bench_planner.py: random object go-to / look-at) with the host corridor and keeps
each request's shortcut polyline; then, per polyline: build_corridor with backend 'cpu' (the request device's
scene: the CPU mirror of a GPU scene) and 'batched' (the scene's own device), GridIndex.query_boxes 'grid' vs
'scan' on the scene's device for the polyline's boxes (same pairs checked), and the batched builder's counts
(candidate pairs, rounds). Prints medians / p95; timings bracketed by torch.cuda.synchronize() on CUDA. Not
recorded in RESULTS.md (quote it by hand).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import cinenerf_ns.planner.shots.stages as planner_mod  # the leg builds its corridor there  # noqa: E402
from cinenerf_ns.planner.corridor.polytope_batched import safe_polytopes_batched  # noqa: E402
from cinenerf_ns.planner.corridor.safe_corridor import build_corridor  # noqa: E402
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene  # noqa: E402
from cinenerf_ns.planner.scene.procedural import procedural_room  # noqa: E402
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--n-gaussians", type=int, default=1_000_000)
    ap.add_argument("--paths", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    dev = torch.device(args.device)
    sync = (lambda: torch.cuda.synchronize(dev)) if dev.type == "cuda" else (lambda: None)
    room = procedural_room(args.n_gaussians, seed=args.seed)
    scene = EllipsoidScene.from_splat(room.means.to(dev), room.quats.to(dev), room.log_scales.to(dev),
                                      room.opacity_logits.to(dev))
    pl = Planner(scene, PlannerConfig(corridor_backend="cpu", candidate_workers=0))
    prep = pl.prepare()
    ways = []
    real = planner_mod.build_corridor

    def keep(w, *a, **kw):
        ways.append(w.cpu().numpy())
        return real(w, *a, **kw)

    planner_mod.build_corridor = keep
    rng = np.random.default_rng(args.seed)
    objs = room.objects
    for k in range(args.paths):
        i, j = rng.choice(len(objs), 2, replace=False)
        goal = objs[i].center + rng.uniform(-0.25, 0.25, 3) * objs[i].size
        try:
            pl.plan(goal, objs[j].center.copy(), seed=args.seed * 100_003 + k)
        except Exception as e:  # noqa: BLE001
            print("plan failed:", type(e).__name__)
    planner_mod.build_corridor = real
    bidx = prep.batch_index
    m = pl.config.box_margin
    rows = []
    for w in ways:
        wt = torch.as_tensor(w, dtype=torch.float64)
        t0 = time.perf_counter()
        c_host = build_corridor(wt, pl.scene, prep.index, box_margin=m)
        t1 = time.perf_counter()
        sync()
        t2 = time.perf_counter()
        c_bat = build_corridor(wt, pl.scene, prep.index, box_margin=m, backend="batched", batch_scene=scene,
                               batch_index=bidx)
        sync()
        t3 = time.perf_counter()
        wd = wt.to(dev)
        lo, hi = torch.minimum(wd[:-1], wd[1:]) - m, torch.maximum(wd[:-1], wd[1:]) + m
        times = {}
        pairs = {}
        for meth in ("grid", "scan"):
            sync()
            t = time.perf_counter()
            q, g = bidx.query_boxes(lo, hi, method=meth)
            sync()
            times[meth] = 1e3 * (time.perf_counter() - t)
            pairs[meth] = torch.sort(q * len(scene) + g).values
        assert torch.equal(pairs["grid"], pairs["scan"]), "query_boxes grid and scan disagree"
        st = {}
        sync()
        t = time.perf_counter()
        safe_polytopes_batched(torch.stack([wd[:-1], wd[1:]], 1), scene, bidx, lo, hi, stats=st)
        sync()
        t_b = 1e3 * (time.perf_counter() - t)
        rows.append(dict(segs=len(w) - 1, host=1e3 * (t1 - t0), batched=1e3 * (t3 - t2), batched_only=t_b,
                         grid=times["grid"], scan=times["scan"], pairs=st["pairs"], rounds=len(st["alive"]),
                         host_segments=c_bat.n_host_segments, faces_host=sum(c_host.num_faces),
                         faces_batched=sum(c_bat.num_faces)))
        print(rows[-1], flush=True)

    def s(k):
        a = np.array([r[k] for r in rows], dtype=float)
        return f"{k}: median {np.median(a):.1f} p95 {np.percentile(a, 95):.1f}"

    print(f"{len(rows)} polylines, N={len(scene)}, device {dev}")
    for k in ("host", "batched", "batched_only", "grid", "scan", "pairs", "rounds", "host_segments", "faces_host",
              "faces_batched"):
        print(s(k))


if __name__ == "__main__":
    main()
