"""Render-time benchmark of the synthetic room ray caster (issue 5 target: 150 views at 480x360 <= 2 min).

    PYTHONPATH=. .venv/bin/python benchmarks/bench_synth_render.py --views 20 --threads 1

Prints median wall and CPU seconds per view and the 150-view extrapolation. On a shared CPU the CPU
time is the honest number (wall time includes waiting for a core).
"""
from __future__ import annotations

import argparse
import statistics
import time

import torch

from cinenerf_ns.synthetic.cameras import sample_cameras
from cinenerf_ns.synthetic.generate import RoomConfig, generate_room
from cinenerf_ns.synthetic.render import Intrinsics, RoomRenderer


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--width", type=int, default=480)
    ap.add_argument("--height", type=int, default=360)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--supersample", type=int, default=1)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    room = generate_room(RoomConfig(), a.seed)
    c2w, _ = sample_cameras(room, a.views, a.seed)
    r = RoomRenderer(room)
    intr = Intrinsics.from_fov(a.width, a.height, 75.0)
    r.render(c2w[0], intr, a.supersample)  # warm-up
    wall, cpu = [], []
    for i in range(a.views):
        t0, c0 = time.perf_counter(), time.process_time()
        r.render(c2w[i], intr, a.supersample)
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    mw, mc = statistics.median(wall), statistics.median(cpu)
    print(f"{a.views} views {a.width}x{a.height} ss={a.supersample} threads={a.threads}: "
          f"median {mw:.3f} s wall, {mc:.3f} s CPU per view; 150 views ~ {150 * mw:.0f} s wall, {150 * mc:.0f} s CPU")


if __name__ == "__main__":
    main()
