"""CPU preview of a shot (cinenerf_ns.preview.preview_camera_path): per-frame and total time at 480x270, 15 fps.

    python benchmarks/bench_preview.py [--camera-path demo_output/demo_0.json]
        [--fox ../shared/data/fox_cinesplat/fox3000.npz]

Scenes: the bundled room (cinenerf_ns/assets/room0.npz) with the demo shot ("go to the red armchair, look at the
floor lamp", planned with run_plan unless --camera-path is given), and the real fox capture (skipped with a message
when absent) on a 5 s cone orbit around the centre of a sphere fitted to its training camera centres (world z up).
Each preview is rendered --repeats times (mp4 + contact sheet written each time); frame statistics pool the
repeats. The pure-torch fallback is timed on the first frame of the room shot. Appends to benchmarks/RESULTS.md.
"""
from __future__ import annotations

import argparse
import datetime
import io
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._results import append_results, device_name  # noqa: E402
from cinenerf_ns.planner.shots.camera_path import read_camera_path  # noqa: E402
from cinenerf_ns.planner.trajectory.orientation import look_at_rotations  # noqa: E402
from cinenerf_ns.preview import native, path_cameras, preview_camera_path, scene_from_splat  # noqa: E402
from cinenerf_ns.preview.render import render_premultiplied  # noqa: E402
from cinenerf_ns.scenes import load_scene  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
FOX = REPO.parent / "shared" / "data" / "fox_cinesplat" / "fox3000.npz"


def demo_camera_path(out_dir: Path) -> dict:
    """The demo's planned shot on the bundled room (run_plan, quiet)."""
    from cinenerf_ns.cli.demo import demo_args
    from cinenerf_ns.cli.plan_run import run_plan

    summary = run_plan(demo_args(out_dir), console=Console(file=io.StringIO()))
    return read_camera_path(summary["candidates"][0]["camera_path"])


def orbit_camera_path(centres: np.ndarray, seconds: float = 5.0, fps: float = 30.0, cone_deg: float = 30.0) -> dict:
    """Cone orbit looking at the centre of the sphere fitted to the training camera centres [C, 3]."""
    A = np.c_[2 * centres, np.ones(len(centres))]
    x = np.linalg.lstsq(A, (centres ** 2).sum(1), rcond=None)[0]
    ctr, r = x[:3], float(np.sqrt(x[3] + x[:3] @ x[:3]))
    m = (centres - ctr).mean(0)
    m /= np.linalg.norm(m)
    a = np.cross(m, [0.0, 0.0, 1.0])
    a /= np.linalg.norm(a)
    b = np.cross(m, a)
    T = int(round(seconds * fps))
    th = np.linspace(0.0, 2 * np.pi, T)[:, None]
    phi = np.radians(cone_deg)
    pos = ctr + r * (np.cos(phi) * m + np.sin(phi) * (np.cos(th) * a + np.sin(th) * b))  # [T, 3]
    c2w = np.tile(np.eye(4), (T, 1, 1))
    c2w[:, :3, :3], c2w[:, :3, 3] = look_at_rotations(pos, ctr), pos
    frames = [{"camera_to_world": c.reshape(-1).tolist(), "fov": 50.0, "aspect": 16 / 9} for c in c2w]
    return {"camera_type": "perspective", "render_width": 1920, "render_height": 1080, "seconds": T / fps,
            "fps": fps, "camera_path": frames}


def bench(splat, cam: dict, out_dir: Path, name: str, repeats: int) -> dict:
    ms, totals, frames = [], [], 0
    for _ in range(repeats):
        out = preview_camera_path(splat, cam, out_dir, name, width=480, height=270, fps=15, progress=False)
        ms += out["timings"]["frame_ms"]
        totals.append(out["timings"]["total_s"])
        frames = out["frames"]
    ms = np.asarray(ms)
    return {"frames": frames, "gaussians": len(splat), "median": float(np.median(ms)),
            "p95": float(np.percentile(ms, 95)),
            "max": float(ms.max()), "total": float(np.median(totals)), "totals": totals, "backend": out["backend"]}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--camera-path", type=Path, default=None, help="room shot to render (default: plan the demo shot)")
    ap.add_argument("--fox", type=Path, default=FOX)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--no-record", action="store_true")
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    if native.render_fn("float32") is None:
        raise SystemExit(f"the compiled preview rasteriser did not load: {native.native_status()}")
    compile_s = time.perf_counter() - t0
    tmp = Path(tempfile.mkdtemp(prefix="bench_preview_"))
    rows = []
    room = load_scene(str(REPO / "cinenerf_ns" / "assets" / "room0.npz"), planning=False).splat
    cam = read_camera_path(a.camera_path) if a.camera_path else demo_camera_path(tmp / "plan")
    rows.append(("bundled room, demo shot", bench(room, cam, tmp, "room", a.repeats)))
    cams = path_cameras(cam, 480, 270, 15)
    t = time.perf_counter()
    render_premultiplied(scene_from_splat(room), cams.viewmats[0], cams.intrinsics[0], 480, 270, backend="torch")
    torch_ms = (time.perf_counter() - t) * 1e3
    if a.fox.exists():
        fox = load_scene(str(a.fox), planning=False)
        rows.append(("fox capture (real), orbit",
                     bench(fox.splat, orbit_camera_path(np.asarray(fox.camera_centres)), tmp, "fox", a.repeats)))
    else:
        print(f"fox scene not found at {a.fox}: skipped")
    lines = [f"## bench_preview ({datetime.date.today()}, {device_name('cpu')})", "",
             f"480x270, 15 fps, mp4 + contact sheet; {a.repeats} runs per scene, frame times pooled; load average at "
             f"the end {os.getloadavg()[0]:.2f}; compiled kernel load {compile_s * 1e3:.0f} ms", "",
             "| scene | Gaussians | frames | backend | median ms/frame | p95 | max | total s (median of runs) |",
             "|---|---|---|---|---|---|---|---|"]
    for label, r in rows:
        lines.append(f"| {label} | {r['gaussians']} | {r['frames']} | {r['backend']} | {r['median']:.0f} | "
                     f"{r['p95']:.0f} "
                     f"| {r['max']:.0f} | {r['total']:.1f} ({', '.join(f'{x:.1f}' for x in r['totals'])}) |")
    lines += ["", f"pure-torch fallback, first frame of the room shot: {torch_ms:.0f} ms"]
    text = "\n".join(lines)
    print(text)
    print(f"outputs in {tmp}")
    if not a.no_record:
        append_results(text)


if __name__ == "__main__":
    main()
