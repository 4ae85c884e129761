"""Viewer latency with the real planner: Plan click -> path drawn -> first camera update, and the
animation's camera-update rate, through the panel's API on a real viser server.

Targets (issue 6): <= 1.5 s on the CPU box for a 200k-Gaussian scene; <= 300 ms on an H100 for 1M.

    .venv/bin/python benchmarks/bench_viewer.py --n-gaussians 200000                  # CPU box
    python benchmarks/bench_viewer.py --n-gaussians 1000000 --device cuda             # H100

Scene: ``procedural:N`` (the generated test room, its object names answer text queries), loaded as
``cinesplat-viewer --load-config procedural:N`` loads it; planner: ``cinenerf_ns.planner.Planner``
through the viewer's :class:`PreparedPlanner` (one-time ``prepare()`` reported separately).

What is timed (median over --repeats, after one warm-up Plan): ``CinePanel.request_plan(goto_text,
look_at_text)`` (what the Plan button calls) until (a) the view has finished drawing the path and (b)
the animation thread sent its first camera pose (autoplay), split into query / planner / drawing. Then
the animation loop's camera updates per second (server side; each connected client gets one per tick)
and the median interval between updates.
"""
from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._results import device_name  # noqa: E402
from cinenerf_ns.planner.scene.scene_config import SceneConfig  # noqa: E402
from cinenerf_ns.planner.shots.planner import PlannerConfig  # noqa: E402
from cinenerf_ns.viewer.backend import FunctionBackend  # noqa: E402
from cinenerf_ns.viewer.panel import PanelConfig  # noqa: E402
from cinenerf_ns.viewer.planner_backend import PreparedPlanner  # noqa: E402
from cinenerf_ns.viewer.standalone import display_gaussians, open_scene  # noqa: E402


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n-gaussians", type=int, default=200_000)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--grid-resolution", type=int, default=96)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--request-device", default="auto", choices=["auto", "scene"],
                    help="PlannerConfig.request_device: auto = per-request queries on a CPU mirror of a GPU scene")
    ap.add_argument("--n-candidates", type=int, default=1)
    ap.add_argument("--play-seconds", type=float, default=2.0)
    ap.add_argument("--results", type=Path, default=Path(__file__).resolve().parent / "RESULTS.md",
                    help="append a summary here ('' to skip)")
    args = ap.parse_args()

    import viser

    from cinenerf_ns.viewer.viser_ui import attach_cine_panel

    t0 = time.perf_counter()
    loaded = open_scene(f"procedural:{args.n_gaussians}", Path("/tmp"), SceneConfig(), args.device)
    load_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    planner = PreparedPlanner(loaded.obstacles, PlannerConfig(grid_resolution=args.grid_resolution,
                                                               start_region=loaded.start_region,
                                                               request_device=args.request_device))
    planner.start(background=False)
    if planner.error is not None:
        raise SystemExit(f"prepare failed: {planner.error}")
    prep_s = time.perf_counter() - t0
    display = display_gaussians(loaded.splat)
    backend = FunctionBackend(display, planner.plan, loaded.locate, loaded.name, PreparedPlanner.name)

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    panels = attach_cine_panel(server, backend, PanelConfig(autoplay=True, n_candidates=args.n_candidates))
    panel = panels.server_panel()  # one panel on the server scope (what every page sees), driven from here
    ui = panel.view
    marks: dict = {}
    first_cam = threading.Event()
    orig_draw, orig_cam = ui.draw_shot, ui.set_camera
    cam_times: list = []

    def timed_draw(shot, options):
        orig_draw(shot, options)
        marks["drawn"] = time.perf_counter()

    def timed_cam(c2w):
        now = time.perf_counter()
        cam_times.append(now)
        if not first_cam.is_set():
            marks["camera"] = now
            first_cam.set()
        return orig_cam(c2w)

    ui.draw_shot, ui.set_camera = timed_draw, timed_cam

    names = loaded.object_names
    queries = [(names[i % len(names)], names[(i + 2) % len(names)]) for i in range(args.repeats + 1)]
    rows, failures = [], 0
    for i, (goto, look) in enumerate(queries):
        marks.clear()
        first_cam.clear()
        t_req = time.perf_counter()
        res = panel.request_plan(goto, look, n_candidates=args.n_candidates).result(600)
        if res is None:
            failures += 1
            print(f"  run {i}: failed: {panel.status}")
            continue
        first_cam.wait(10)
        panel.pause()
        drawn, cam = marks["drawn"] - t_req, marks.get("camera", float("nan")) - t_req
        st = panel.shot.timings if panel.shot is not None else {}
        stages = ", ".join(f"{k[:-3]} {v:.0f}" for k, v in st.items() if k.endswith("_ms") and k != "plan_ms")
        print(f"  run {i}: {goto!r} -> look at {look!r}: drawn {drawn:.3f} s, first camera update {cam:.3f} s"
              f"{' (warm-up)' if i == 0 else ''}\n    planner stages ms: {stages}")
        if i > 0:
            rows.append((drawn, cam, res.timings["query_s"], res.timings["plan_s"], res.timings["draw_s"]))

    dev = device_name(args.device)
    lines = [f"viewer latency, real planner: procedural:{args.n_gaussians} ({len(loaded.obstacles)} obstacles), "
             f"device {args.device} [{dev}], request_device {args.request_device}, grid {args.grid_resolution}, "
             f"{args.n_candidates} candidate(s)",
             f"scene load {load_s:.3f} s; planner prepare (one-time) {prep_s:.3f} s"]
    if rows:
        med = [statistics.median(c) for c in zip(*rows)]
        lines.append(f"Plan click -> path drawn, median of {len(rows)}: {med[0]:.3f} s (query {med[2]:.3f} s, "
                     f"planner {med[3]:.3f} s, drawing {med[4]:.3f} s); -> first camera update {med[1]:.3f} s")
    lines.append(f"failed plans: {failures}")

    if panel.shot is not None:
        panel.config.loop = True
        cam_times.clear()
        n0, t_play = panel.frames_sent, time.perf_counter()
        panel.play()
        time.sleep(args.play_seconds)
        panel.pause()
        rate = (panel.frames_sent - n0) / (time.perf_counter() - t_play)
        gaps = np.diff(cam_times) * 1e3
        lines.append(f"animation: {rate:.1f} camera updates/s, median interval {np.median(gaps):.1f} ms "
                     f"(config update_hz {panel.config.update_hz:g}; target >= 30 per client)")
    panel.close()
    server.stop()
    print("\n" + "\n".join(lines))
    if str(args.results):
        date = subprocess.run(["date", "-u", "+%F"], capture_output=True, text=True).stdout.strip()
        cmd = "benchmarks/bench_viewer.py " + " ".join(sys.argv[1:])
        with open(args.results, "a") as f:
            f.write(f"\n## bench_viewer ({date}, {dev})\n\n`{cmd}`\n\n" + "".join(f"- {ln}\n" for ln in lines))


if __name__ == "__main__":
    main()
