"""score_parts per shot as a candidate worker calls it (batch=False, CPU copy), 1M procedural / blobs.

    PYTHONPATH=. python benchmarks/score_parts_bench.py --family procedural --n 1000000 --shots 16 [--profile]
Prints per-shot median / p95 of score_parts and of its parts, and a digest of the results and of
plan_candidates(k=8, seed=0)'s ranking (to compare before / after a change)."""
from __future__ import annotations

import argparse
import hashlib
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from scene_families import load_family  # noqa: E402

from cinenerf_ns.planner.shots.candidate_scores import score_parts  # noqa: E402
from cinenerf_ns.planner.shots.candidates import plan_candidates  # noqa: E402
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig  # noqa: E402
from cinenerf_ns.planner.shots.scoring import ScoreConfig  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--family", default="procedural")
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--shots", type=int, default=16)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--no-candidates", action="store_true")
    a = ap.parse_args()
    fam = load_family(a.family, a.n, 0, "cpu")
    planner = Planner(fam.scene, PlannerConfig(up=fam.up, start_region=fam.start_region))
    planner.prepare()
    rng = np.random.default_rng(0)
    shots, looks = [], []
    for k in range(a.shots * 3):
        if len(shots) >= a.shots:
            break
        goal, look = fam.targets(rng, *planner.region())
        try:
            shots.append(planner.plan(goal, look, seed=k)[0])
            looks.append(np.asarray(look, np.float64))
        except Exception as e:  # noqa: BLE001
            print("plan failed:", type(e).__name__, str(e)[:80])
    cfg = ScoreConfig()
    h = hashlib.sha256()
    times = []
    for rep in range(a.reps):
        for sh, look in zip(shots, looks):
            t = time.perf_counter()
            part = score_parts(planner, [sh], look, cfg, 0.1, None, None, batch=False)[0]
            times.append((time.perf_counter() - t) * 1e3)
            if rep == 0:
                i, occ, clr = part
                h.update(np.asarray(i, np.int64).tobytes())
                h.update(np.asarray(occ, bool).tobytes())
                h.update(np.asarray(clr, np.float64).tobytes())
    ts = np.array(times[len(shots):] if a.reps > 1 else times)
    print(f"{a.family} n={a.n} shots={len(shots)} frames/shot~{np.mean([s.num_frames for s in shots]):.0f}: "
          f"score_parts median {np.median(ts):.2f} ms p95 {np.percentile(ts, 95):.2f} ms  digest {h.hexdigest()[:16]}")
    if a.profile:
        import cProfile
        import pstats
        pr = cProfile.Profile()
        pr.enable()
        for sh, look in zip(shots, looks):
            score_parts(planner, [sh], look, cfg, 0.1, None, None, batch=False)
        pr.disable()
        pstats.Stats(pr).sort_stats("cumulative").print_stats(25)
    if not a.no_candidates:
        goal, look = fam.targets(np.random.default_rng(123), *planner.region())
        ranked = plan_candidates(planner, goal, look, k=8, seed=0)
        hc = hashlib.sha256()
        for r in ranked:
            d = r.score.to_dict()
            hc.update(repr((r.rank, r.candidate, sorted((k, v) for k, v in d.items() if "ms" not in k))).encode())
            hc.update(np.asarray(r.shot.positions, np.float64).tobytes())
        print("candidates:", [(r.rank, r.candidate, round(float(r.score.total), 9)) for r in ranked],
              "digest", hc.hexdigest()[:16])


if __name__ == "__main__":
    main()
