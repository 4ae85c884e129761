"""Planner on a trained real capture, grid polytopes on and off (same requests): the fox records in RESULTS.md.

    python benchmarks/bench_capture_planner.py --scene <run>/config.yml [--requests 30] [--device cuda]

The scene is loaded as ``cinesplat-plan`` loads it. Request k: go-to = a random Gaussian mean (seeded), look-at = the
median of the means plus a little noise, a random start (planner seed k; the training cameras' box when the run has
one). Prints, per mode: successes, failures by type, per-plan wall median / p95 (ms), the minimum exact clearance of
every frame (capped search at 0.25, on the scene's device), corridor segments and how many came from the grid or the
goal's polytope, the median path length, the grid shape and voxel size. Nothing is appended to RESULTS.md (quote
the printout with its date and device). Timings are wall times on the request device (a CPU mirror of a GPU scene).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cinenerf_ns.planner.geometry.distance import clearance  # noqa: E402
from cinenerf_ns.planner.scene.scene_config import SceneConfig  # noqa: E402
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig  # noqa: E402
from cinenerf_ns.scenes import load_scene  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", required=True, help="a trained run's config.yml (or a compact export)")
    ap.add_argument("--requests", type=int, default=30)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    loaded = load_scene(args.scene, SceneConfig(), device=args.device)
    scene = loaded.scene
    print("gaussians", len(scene), "device", args.device)
    m = scene.means.detach().cpu().double().numpy()
    rng = np.random.default_rng(args.seed)
    centre = np.median(m, 0)
    reqs = [(m[rng.integers(len(m))], centre + rng.normal(size=3) * 0.05, k) for k in range(args.requests)]
    for mode in (True, False):
        pl = Planner(scene, PlannerConfig(grid_polytopes=mode, start_region=loaded.start_region))
        prep = pl.prepare()
        idx = prep.batch_index if prep.batch_index is not None else prep.index
        fails: dict = {}
        tms, clr, prebuilt, segs, lengths = [], [], 0, 0, []
        for goal, look, seed in reqs:
            t = time.perf_counter()
            try:
                sh = pl.plan(goal, look, seed=seed)[0]
            except Exception as e:  # noqa: BLE001 - counted by type
                fails[type(e).__name__] = fails.get(type(e).__name__, 0) + 1
                continue
            tms.append(1e3 * (time.perf_counter() - t))
            pts = torch.as_tensor(sh.positions, dtype=torch.float64, device=scene.device)
            clr.append(float(clearance(pts, pl.batch_scene, idx, max_distance=0.25).min()))
            prebuilt += sh.corridor.n_grid_segments + sh.corridor.n_known_segments
            segs += len(sh.corridor)
            lengths.append(float(np.linalg.norm(np.diff(sh.positions, axis=0), axis=1).sum()))
        if not tms:
            print(f"grid_polytopes={mode}: no plan succeeded, failures {fails}")
            continue
        print(f"grid_polytopes={mode}: {len(tms)}/{len(reqs)} ok, failures {fails}, plan median "
              f"{np.median(tms):.1f} ms p95 {np.percentile(tms, 95):.1f}, min exact frame clearance {min(clr):.3g}, "
              f"segments {segs} "
              f"(grid or known {prebuilt}), path length median {np.median(lengths):.3f}, grid {prep.grid.shape} "
              f"voxel {prep.grid.voxel_size:.4f} ({prep.grid.voxel_size / scene.camera_radius:.2f} camera radii)")


if __name__ == "__main__":
    main()
