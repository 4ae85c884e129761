"""Seeded go-to / look-at pairs on a real capture and a synthetic room, measured as the user waits for them.

    python benchmarks/bench_real_capture.py [--pairs 20] [--scene PATH ...] [--append]

Per scene (default: ../shared/data/fox_cinesplat/fox3000.npz, the fox capture, and the bundled room
cinenerf_ns/assets/room0.npz): load (timed), prepare (timed, once), then for each pair (go-to and look-at uniform in
the training cameras' box, seeded) one request = Planner.plan (random start, every check included) + the capped
exact clearance report that cinesplat-plan writes. Prints successes, shots verified safe by the report, goals moved
(with why), and the request time's median, p95 and max. --append adds the block to benchmarks/RESULTS.md.
"""
from __future__ import annotations

import argparse
import datetime
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._results import append_results, device_name  # noqa: E402
from cinenerf_ns.planner.errors import PlanningError  # noqa: E402
from cinenerf_ns.planner.scene.scene_config import SceneConfig  # noqa: E402
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig  # noqa: E402
from cinenerf_ns.scenes import load_scene  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DEFAULT_SCENES = [REPO.parent / "shared" / "data" / "fox_cinesplat" / "fox3000.npz",
                  REPO / "cinenerf_ns" / "assets" / "room0.npz"]


def stats(ms) -> str:
    a = np.asarray(ms, dtype=float)
    return f"median {np.median(a):.1f} ms, p95 {np.percentile(a, 95):.1f} ms, max {a.max():.1f} ms"


def bench_scene(path: Path, pairs: int, seed: int) -> str:
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        loaded = load_scene(str(path), SceneConfig.with_margin())  # cinesplat-plan's radius + margin
    load_s = time.perf_counter() - t0
    planner = Planner(loaded.scene, PlannerConfig(start_region=loaded.start_region))
    t0 = time.perf_counter()
    planner.prepare()
    prep_s = time.perf_counter() - t0
    lo, hi = loaded.start_region if loaded.start_region is not None else planner.region()
    rng = np.random.default_rng(seed)
    ok, safe, moved, times, fails = 0, 0, [], [], []
    for i in range(pairs):
        goal, look = rng.uniform(lo, hi), rng.uniform(lo, hi)
        t0 = time.perf_counter()
        try:
            shot = planner.plan(goal, look, seed=i)[0]
            rep = planner.clearance_report(shot)
        except PlanningError as e:
            fails.append(f"{type(e).__name__}: {str(e)[:80]}")
            continue
        times.append(1e3 * (time.perf_counter() - t0))
        ok += 1
        safe += bool(rep["safe"] and shot.safety["safe"] and np.isfinite(rep["clearance"]).all())
        mv = planner.explain_goal(goal, shot.goal)
        if mv is not None:
            moved.append(f"{mv['distance']:.3f} ({mv['why'].split(';')[0]})")
    rlo, rhi = planner.region()
    lines = [
        f"- `{path.name}`: {len(loaded.scene)} Gaussians, load {load_s:.2f} s, prepare {prep_s:.2f} s, planning region "
        f"{np.round(rhi - rlo, 2).tolist()} (grid {list(planner.prepared.grid.shape)}, voxel "
        f"{float(planner.prepared.grid.voxel_size):.4f})",
        f"  - planned {ok}/{pairs}, verified safe (planner + capped exact report, all finite) {safe}/{ok}; "
        f"request (plan + report): {stats(times) if times else 'n/a'}",
        f"  - goals moved: {len(moved)}" + (f" ({'; '.join(moved)})" if moved else "")
        + (f"; failures: {'; '.join(fails)}" if fails else ""),
    ]
    print("\n".join(lines))
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, nargs="*", default=DEFAULT_SCENES)
    ap.add_argument("--pairs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--append", action="store_true")
    a = ap.parse_args()
    blocks = [bench_scene(p, a.pairs, a.seed) for p in a.scene if p.exists()]
    head = (f"\n### Real capture and room, {a.pairs} seeded pairs ({datetime.date.today()}, {device_name('cpu')})\n"
            f"`python benchmarks/bench_real_capture.py --pairs {a.pairs}`\n")
    if a.append:
        append_results(head + "\n".join(blocks))


if __name__ == "__main__":
    main()
