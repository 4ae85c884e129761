"""What end poses cost the user: the whole request with object targets, with and without the end-pose search (issue 34).

    python benchmarks/bench_end_pose.py --family procedural --n-gaussians 1000000 --device cuda --k 1 --k 32
    python benchmarks/bench_end_pose.py --family npz:cinenerf_ns/assets/room0.npz --k 1

Each request names two objects of the scene (go-to, look-at), as text would after the method's selection: their
Gaussians (procedural / blobs: the Gaussians inside each object's box grown by 10%; a file with labels: the label's
semantic selection; the fox capture: six seeded clusters of Gaussians of radius 0.06 near the training cameras' box
centre). Interleaved, per request:

  end pose   shot_targets (subject samples + end poses) + plan_candidates to the end poses, scored by visibility
  baseline   plan_candidates to the go-to object's centre, scored by sight lines (the rule before end poses)

--cold forgets, before each request, what the scene's SplatVolume keeps between requests (objects' set-up, the
subject's samples, viewpoints and visible fractions: target_object.object_parts): every request then pays what the
first request naming its objects pays.

Reports median / p95 / max of both wholes (what the user waits for) and of the end-pose search alone, the host CPU
time of both (process time, all threads: on a busy shared host less disturbed than wall time; run with
CINENERF_THREADS=1 for one thread's work) and the median over requests of their difference, and appends them to
benchmarks/RESULTS.md with the date and the device.
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
from benchmarks.scene_families import FAMILIES, load_family  # noqa: E402
from cinenerf_ns.planner.shots.candidates import plan_candidates  # noqa: E402
from cinenerf_ns.planner.shots.end_pose import visibility_volume  # noqa: E402
from cinenerf_ns.planner.shots.framing import FramingConfig  # noqa: E402
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig  # noqa: E402
from cinenerf_ns.shot_targets import end_pose_count, shot_targets, start_region_centre  # noqa: E402


def object_masks(fam, seed: int) -> list:
    """[(name, centre [3], mask [N] over the obstacle scene)] of the family's objects."""
    means = fam.scene.means.detach().cpu().double().numpy()
    out = []
    if fam.objects:
        for i, (c, size) in enumerate(fam.objects):
            m = np.all(np.abs(means - c) <= 0.55 * np.asarray(size), axis=1)
            if m.sum() >= 20:
                out.append((f"object {i}", np.asarray(c, np.float64), m))
        return out
    lo, hi = (np.asarray(v, np.float64) for v in fam.start_region) if fam.start_region is not None else (
        means.min(0), means.max(0))
    c0, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    near = np.flatnonzero(np.all(np.abs(means - c0) <= 0.6 * half, axis=1))
    rng = np.random.default_rng(seed)
    for i in rng.choice(near, min(40, len(near)), replace=False):
        m = np.linalg.norm(means - means[i], axis=1) <= 0.06
        if m.sum() >= 50 and all(np.linalg.norm(means[i] - c) > 0.2 for _, c, _ in out):
            out.append((f"cluster {len(out)}", means[m].mean(0), m))
        if len(out) == 6:
            break
    return out


def stats(v) -> str:
    v = np.asarray(v)
    return f"{np.median(v):.1f} / {np.percentile(v, 95):.1f} / {v.max():.1f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--family", default="procedural", help=f"scene family: {FAMILIES}")
    ap.add_argument("--n-gaussians", type=int, default=200_000)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--k", type=int, action="append", help="candidates per request (repeatable; default 1)")
    ap.add_argument("--requests", type=int, default=30)
    ap.add_argument("--framing", default="medium")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-record", action="store_true")
    ap.add_argument("--cold", action="store_true", help="forget the objects' kept set-up before each request")
    a = ap.parse_args()
    ks = a.k or [1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fam = load_family(a.family, a.n_gaussians, a.seed, a.device)
    planner = Planner(fam.scene, PlannerConfig(start_region=fam.start_region, up=fam.up))
    t = time.perf_counter()
    planner.prepare()
    prep_s = time.perf_counter() - t
    objs = object_masks(fam, a.seed)
    if len(objs) < 2:
        raise SystemExit(f"{a.family}: fewer than two objects found")
    src = fam.scene.source_index
    n_src = int(src.max()) + 1 if src is not None else len(fam.scene)

    def source_mask(m):  # the obstacle-scene mask as the splat-level mask resolve_match gives
        if src is None:
            return m
        out = np.zeros(n_src, bool)
        out[src.cpu().numpy()[m]] = True
        return out

    rng = np.random.default_rng(a.seed)
    framing = FramingConfig(a.framing)
    lines = [f"### End poses: whole request, {a.family} ({len(fam.scene)} Gaussians), {datetime.date.today()}, "
             f"{device_name(a.device)}" + (", cold (nothing kept between requests)" if a.cold else ""), "",
             f"{fam.description}; prepare {prep_s:.1f} s; {a.requests} requests per k, object pairs seeded, both "
             "modes interleaved; median / p95 / max ms", "",
             "| k | end pose: whole request | baseline: whole request | end-pose search alone | end poses found | "
             "host CPU: end pose | host CPU: baseline | CPU difference (median) |",
             "|---|---|---|---|---|---|---|---|"]
    for k in ks:
        with_ep, base, search, found, cpu_ep, cpu_base = [], [], [], 0, [], []
        for i in range(a.requests + 1):  # the first request of each k warms caches and workers: not counted
            ia, ib = rng.choice(len(objs), 2, replace=False)
            (na, ca, ma), (nb, cb, mb) = objs[ia], objs[ib]
            gm = {"point": ca, "mask": source_mask(ma), "text": na}
            lm = {"point": cb, "mask": source_mask(mb), "text": nb}
            goal, look = planner.checked_point(ca, "go-to"), planner.checked_point(cb, "look-at")
            if a.cold:
                visibility_volume(planner).memo.clear()
            c0, t0 = time.process_time(), time.perf_counter()
            tg = shot_targets(planner, gm, lm, framing, planner.main_component(), k=end_pose_count(k),
                              facing_from=start_region_centre(planner))
            goals = tg.goals(goal)
            plan_candidates(planner, goals if len(goals) > 1 else goals[0], look, k=k, seed=i, subject=tg.samples)
            c1, t1 = time.process_time(), time.perf_counter()
            plan_candidates(planner, goal, look, k=k, seed=i)
            c2, t2 = time.process_time(), time.perf_counter()
            if i == 0:
                continue
            with_ep.append(1e3 * (t1 - t0))
            base.append(1e3 * (t2 - t1))
            cpu_ep.append(1e3 * (c1 - c0))
            cpu_base.append(1e3 * (c2 - c1))
            search.append(tg.choice.ms if tg.choice is not None else 0.0)
            found += bool(tg.choice is not None and tg.choice.poses)
        row = (f"| {k} | {stats(with_ep)} | {stats(base)} | {stats(search)} | {found}/{a.requests} | {stats(cpu_ep)} | "
               f"{stats(cpu_base)} | {np.median(np.subtract(cpu_ep, cpu_base)):+.1f} |")
        print(row, flush=True)
        lines.append(row)
    text = "\n".join(lines) + "\n"
    print(text)
    if not a.no_record:
        append_results(text)
    planner.close()


if __name__ == "__main__":
    main()
