"""Capped exact clearance with different first search boxes (clearance_queries.distance_estimate): the records in
RESULTS.md.

    python benchmarks/bench_clearance_start.py [--device cuda] [--n-gaussians 1000000] [--k 32] [--cap 0.1]

Scene: procedural_room(N). K candidates are planned once (plan_candidates, in this process); their scored frames
(at most 64 per shot, as scoring takes them) are the points. Each variant of the first search box is timed over 4
runs (median of the last 3; CUDA synchronised) and counted in index rounds (GridIndex.query_points calls), and every
variant's values are compared with the default start's (they agree to rounding, ~1e-17: the search is exact for any
start; only which candidate pairs reach the root finding first differs).
Variants: the default (a quarter index cell), and the grid lower bound + camera radius + f x voxel diagonal for
f in 0, 0.5 (what the planner uses), 1, 2. Prints a table; nothing is appended to RESULTS.md.
"""
from __future__ import annotations

import argparse
import functools
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cinenerf_ns.planner.geometry import clearance_queries  # noqa: E402
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene  # noqa: E402
from cinenerf_ns.planner.scene.procedural import procedural_room  # noqa: E402
from cinenerf_ns.planner.shots.candidates import plan_candidates  # noqa: E402
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig  # noqa: E402
from cinenerf_ns.planner.shots.scoring import scored_frames  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--n-gaussians", type=int, default=1_000_000)
    ap.add_argument("--k", type=int, default=32)
    ap.add_argument("--cap", type=float, default=0.1)
    args = ap.parse_args()
    dev = torch.device(args.device)
    room = procedural_room(args.n_gaussians, seed=0)
    scene = EllipsoidScene.from_splat(room.means.to(dev), room.quats.to(dev), room.log_scales.to(dev),
                                      room.opacity_logits.to(dev))
    pl = Planner(scene, PlannerConfig(candidate_workers=0))
    prep = pl.prepare()
    objs = room.objects
    ranked = plan_candidates(pl, objs[0].center, objs[1].center, k=args.k, seed=3)
    pos = np.concatenate([r.shot.positions[scored_frames(r.shot.num_frames, 64)] for r in ranked])
    idx = prep.batch_index if prep.batch_index is not None else prep.index
    rounds = [0]
    real_query = type(idx).query_points

    def counting(self, *a, **kw):
        rounds[0] += 1
        return real_query(self, *a, **kw)

    type(idx).query_points = counting
    real_lb = functools.partial(clearance_queries.clearance_lower_bound, pl.space)
    vs, r = float(prep.grid.voxel_size), float(pl.scene.camera_radius)

    def sync():
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)

    print(f"procedural_room N={len(scene)}, {len(pos)} scored frames of {len(ranked)} shots, cap {args.cap}, "
          f"device {dev}")
    print("| first search box | index rounds | median ms | max abs diff to default |")
    print("|---|---|---|---|")
    ref = None
    real_estimate = clearance_queries.distance_estimate  # Planner.clearance's first search box
    for f in (None, 0.0, 0.5, 1.0, 2.0):
        if f is None:
            clearance_queries.distance_estimate = lambda _pl, p: np.zeros(len(p))
        else:
            clearance_queries.distance_estimate = lambda _pl, p, f=f: np.where(
                np.isfinite(real_lb(p)), real_lb(p) + r + f * math.sqrt(3) * vs, 0.0)
        ts = []
        for _ in range(4):
            sync()
            rounds[0] = 0
            t = time.perf_counter()
            c = pl.clearance(pos, cap=args.cap, batch=True)
            sync()
            ts.append(1e3 * (time.perf_counter() - t))
        ref = c if ref is None else ref
        name = "default (quarter cell)" if f is None else f"lower bound + r + {f} x diagonal"
        print(f"| {name} | {rounds[0]} | {np.median(ts[1:]):.1f} | {float(np.abs(c - ref).max()):.3g} |")
    type(idx).query_points = real_query
    clearance_queries.distance_estimate = real_estimate


if __name__ == "__main__":
    main()
