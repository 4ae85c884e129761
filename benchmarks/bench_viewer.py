"""Viewer latency: typing a query -> path drawn, through the panel's API on a real viser server.

Targets (issue 6): <= 1.5 s on the CPU box for a 200k-Gaussian scene; <= 300 ms on an H100 for 1M.

    .venv/bin/python benchmarks/bench_viewer.py --n-gaussians 200000                  # CPU box
    python benchmarks/bench_viewer.py --n-gaussians 1000000 --device cuda             # H100
    ... --planner straight      # the viewer's stand-in planner (when the real one is not wired)

What is timed (median over --repeats, after one warm-up Plan that also pays one-time planner
preparation, reported separately): ``CinePanel.request_plan(goto_text, look_at_text)`` until the
viser view has finished sending the path (spline + frustums + highlighted Gaussians), split into
query / planner / drawing. Also the animation loop's camera-update rate (server side; each connected
client gets one update per tick).

The scene is synthetic (floor + labelled box-shaped objects, all Gaussians opaque obstacles); text
queries use exact labels (no CLIP) unless the integrator passes a real ``locate``.
"""
from __future__ import annotations

import argparse
import socket
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from cinenerf_ns.planner.scene import EllipsoidScene, SceneConfig  # noqa: E402
from cinenerf_ns.viewer.backend import FunctionBackend, SceneGaussians, label_locate  # noqa: E402
from cinenerf_ns.viewer.panel import PanelConfig  # noqa: E402
from cinenerf_ns.viewer.standalone import make_plan_fn  # noqa: E402


def synthetic_room(n: int, seed: int = 0):
    """~40% floor/walls, ~60% in 8 labelled objects, isotropic Gaussians of ~1 cm (scene ~4 units)."""
    rng = np.random.default_rng(seed)
    n_floor = int(0.4 * n)
    floor = np.c_[rng.uniform(-2, 2, (n_floor, 2)), rng.normal(0, 0.002, n_floor)]
    labels = [f"object {k}" for k in range(8)]
    centers = np.c_[rng.uniform(-1.5, 1.5, (8, 2)), rng.uniform(0.15, 0.4, 8)]
    sizes = rng.uniform(0.08, 0.2, (8, 3))
    per = np.full(8, (n - n_floor) // 8)
    per[: (n - n_floor) - per.sum()] += 1
    objs = np.concatenate([c + rng.uniform(-1, 1, (k, 3)) * s for c, s, k in zip(centers, sizes, per)])
    means = np.concatenate([floor, objs]).astype(np.float32)
    label_of = np.concatenate([np.full(n_floor, -1), np.repeat(np.arange(8), per)])
    log_scales = np.full((n, 3), np.log(0.01), np.float32)
    quats = np.tile(np.array([1, 0, 0, 0], np.float32), (n, 1))
    opac = np.full(n, 3.0, np.float32)
    colors = rng.uniform(0, 1, (n, 3)).astype(np.float32)
    return means, quats, log_scales, opac, colors, labels, label_of


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n-gaussians", type=int, default=200_000)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--planner", default="auto", choices=["auto", "real", "straight"])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--n-candidates", type=int, default=1)
    ap.add_argument("--play-seconds", type=float, default=2.0)
    args = ap.parse_args()

    import viser

    from cinenerf_ns.viewer.viser_ui import attach_cine_panel

    means, quats, log_scales, opac, colors, labels, label_of = synthetic_room(args.n_gaussians)
    t = lambda x: torch.as_tensor(x, device=args.device)
    t0 = time.perf_counter()
    scene = EllipsoidScene.from_splat(t(means), t(quats), t(log_scales), t(opac), SceneConfig())
    plan_fn, planner_name = make_plan_fn(scene, args.planner)
    prep_s = time.perf_counter() - t0
    backend = FunctionBackend(SceneGaussians(means, colors), plan_fn, label_locate(means, labels, label_of))

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    panel = attach_cine_panel(server, backend, PanelConfig(autoplay=False, n_candidates=args.n_candidates))
    ui = panel.view
    drawn = {}
    orig_draw = ui.draw_shot

    def timed_draw(shot, options):
        orig_draw(shot, options)
        drawn["t"] = time.perf_counter()

    ui.draw_shot = timed_draw

    queries = [(f"object {i % 8}", f"object {(i + 3) % 8}") for i in range(args.repeats + 1)]
    rows = []
    failures = 0
    for i, (goto, look) in enumerate(queries):
        drawn.clear()
        t_req = time.perf_counter()
        res = panel.request_plan(goto, look, n_candidates=args.n_candidates).result(600)
        if res is None:
            failures += 1
            print(f"  run {i}: failed: {panel.status}")
            continue
        total = drawn["t"] - t_req
        if i == 0:
            print(f"warm-up: {total:.3f} s (includes first-call costs)")
            continue
        rows.append((total, res.timings["query_s"], res.timings["plan_s"], res.timings["draw_s"]))

    print(f"\nviewer latency: {args.n_gaussians} Gaussians, device {args.device}, planner: {planner_name}")
    print(f"scene + planner preparation (one-time): {prep_s:.3f} s")
    if rows:
        med = [statistics.median(c) for c in zip(*rows)]
        print(f"query -> path drawn, median of {len(rows)}: {med[0]:.3f} s "
              f"(query {med[1]:.3f} s, planner {med[2]:.3f} s, drawing {med[3]:.3f} s)")
    print(f"failed plans: {failures}")

    if panel.shot is not None:
        panel.config.loop = True
        n0, t_play = panel.frames_sent, time.perf_counter()
        panel.play()
        time.sleep(args.play_seconds)
        panel.pause()
        rate = (panel.frames_sent - n0) / (time.perf_counter() - t_play)
        print(f"animation: {rate:.1f} camera updates/s (target >= 30 per client; config update_hz "
              f"{panel.config.update_hz})")
    panel.close()
    server.stop()


if __name__ == "__main__":
    main()
