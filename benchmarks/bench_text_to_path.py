"""Text to path drawn, as the user of the standalone viewer waits for it (issue 23).

    python benchmarks/bench_text_to_path.py [--scene demo] [--requests 10] [--candidates 1] [--no-warm] [--append]

What the viewer does, in its order: viewer.standalone.open_scene(--scene) (timed), the planner prepared on a background
thread (PreparedPlanner.start) and, unless --no-warm, the text queries warmed on another (warm_semantics:
SemanticScene.warm: latent smoothing + every label's answer); both are waited for (timed: "ready"). Then --requests
seeded requests of (go-to text, look-at text) pairs drawn from the scene's label names, written as a user would type
them ("the <label>"), some pairs repeated; one request = locate(go) + locate(look) (the viewer's text -> point) +
PreparedPlanner.plan (random start, every check, the capped per-frame clearance the panel draws). Prints the first
request and the median / p95 / max of the others, with the locate and plan parts; --append adds it to RESULTS.md.
Issue 23 targets (CPU box, bundled scene): first request <= 1 s, median after the first <= 150 ms.
"""
from __future__ import annotations

import argparse
import datetime
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Optional

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from benchmarks._results import append_results, device_name  # noqa: E402
from cinenerf_ns.planner.errors import PlanningError  # noqa: E402
from cinenerf_ns.planner.scene.scene_config import SceneConfig  # noqa: E402
from cinenerf_ns.viewer.planner_backend import PreparedPlanner  # noqa: E402
from cinenerf_ns.viewer.standalone import StandaloneConfig, open_scene, warm_semantics  # noqa: E402


def text_pairs(names: list, n: int, seed: int) -> list:
    """n (go-to, look-at) texts: distinct label pairs, every third request from the 2nd on repeating an earlier one."""
    rng = np.random.default_rng(seed)
    out: list = []
    for k in range(n):
        if k >= 2 and k % 3 == 2:
            out.append(out[int(rng.integers(0, len(out)))])
            continue
        i, j = rng.choice(len(names), 2, replace=False)
        out.append((f"the {names[i]}", f"the {names[j]}"))
    return out


def stats(ms) -> str:
    a = np.asarray(ms, dtype=float)
    if not len(a):
        return "n/a"
    return f"median {np.median(a):.1f} ms, p95 {np.percentile(a, 95):.1f} ms, max {a.max():.1f} ms"


def main(argv: Optional[list] = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="demo", help="the viewer's --load-config (default: the bundled room)")
    ap.add_argument("--requests", type=int, default=10)
    ap.add_argument("--candidates", type=int, default=1, help="shots per request (>1: ranked plan_candidates)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--no-warm", action="store_true", help="leave text queries lazy (the first one smooths)")
    ap.add_argument("--append", action="store_true", help="append the block to benchmarks/RESULTS.md")
    a = ap.parse_args(argv)
    vc = StandaloneConfig()
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ls = open_scene(a.scene, scene_config=SceneConfig.with_margin(vc.obstacles.camera_radius, vc.safety_margin),
                        device=a.device)
    load_s = time.perf_counter() - t0
    if ls.locate is None or ls.obstacles is None:
        sys.exit(f"{a.scene}: no text semantics or obstacles to plan around")
    t0 = time.perf_counter()
    planner = PreparedPlanner(ls.obstacles, replace(vc.planner, start_region=ls.start_region,
                                                    candidate_workers=0)).start(background=True)
    th = None if a.no_warm else warm_semantics(ls)
    planner.wait_ready()
    prep_s = time.perf_counter() - t0
    if th is not None:
        th.join()
    ready_s = time.perf_counter() - t0
    names = list(ls.semantic.label_names) if ls.semantic is not None else list(ls.object_names)
    pairs = text_pairs(names, a.requests, a.seed)
    total, loc, plan, fails = [], [], [], []
    for k, (go, look) in enumerate(pairs):
        t0 = time.perf_counter()
        try:
            g = ls.locate(go)[0]  # (centre, mask, what it matched)
            la = ls.locate(look)[0]
            t1 = time.perf_counter()
            planner.plan(g, la, seed=a.seed + k, n_candidates=a.candidates)
        except (PlanningError, ValueError) as e:  # QueryError is a ValueError
            fails.append(f"{go} / {look}: {type(e).__name__}: {str(e)[:80]}")
            continue
        t2 = time.perf_counter()
        total.append(1e3 * (t2 - t0))
        loc.append(1e3 * (t1 - t0))
        plan.append(1e3 * (t2 - t1))
        print(f"{k}: {go!r} -> {look!r}: {total[-1]:.1f} ms (locate {loc[-1]:.1f}, plan {plan[-1]:.1f})")
    warm = "warmed" if th is not None else "not warmed (--no-warm)"
    lines = [
        f"\n### bench_text_to_path {datetime.date.today()} — {device_name(a.device)}",
        f"`python benchmarks/bench_text_to_path.py --scene {a.scene} --requests {a.requests} --candidates "
        f"{a.candidates}"
        + (" --no-warm" if a.no_warm else "") + "`",
        "",
        f"- scene `{a.scene}` ({ls.name}): {len(ls.obstacles)} obstacles, {len(names)} labels, load {load_s:.2f} s; "
        f"planner prepared {prep_s:.2f} s and text queries {warm}: ready {ready_s:.2f} s after loading "
        "(background threads)",
        f"- {len(total)}/{len(pairs)} requests planned; first request {total[0]:.1f} ms (locate {loc[0]:.1f}, plan "
        f"{plan[0]:.1f})" if total else "- no request planned",
        f"- after the first: total {stats(total[1:])}; locate (two texts) {stats(loc[1:])}; plan {stats(plan[1:])}",
        *([f"- failures: {'; '.join(fails)}"] if fails else []),
    ]
    print("\n".join(lines))
    if a.append:
        append_results("\n".join(lines))
    if not total:
        sys.exit("bench_text_to_path: no request was planned (see the failures above)")


if __name__ == "__main__":
    main()
