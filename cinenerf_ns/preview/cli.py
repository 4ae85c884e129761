"""cinesplat-preview: render a nerfstudio camera path through a splat on the CPU (mp4 + contact sheet [+ GIF]).

  cinesplat-preview --scene scene.npz --camera-path demo_output/demo_0.json --output-dir renders

Bad input (missing file, size or fps out of range, unreadable scene or path) is reported on stderr with the
option's name and exit status 2, before anything is written.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Optional, Sequence

from rich.console import Console

from cinenerf_ns.planner.shots.camera_path import DEFAULT_PREVIEW_FPS, DEFAULT_PREVIEW_SIZE
from cinenerf_ns.preview.cameras import MAX_FPS, MAX_SIZE, MIN_FPS, MIN_SIZE


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="cinesplat-preview", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, required=True,
                    help="compact scene (.npz / .pt from export_compact), .ckpt, run folder or ns-train config.yml")
    ap.add_argument("--camera-path", type=Path, required=True,
                    help="nerfstudio camera-path JSON (cinesplat-plan, viewer)")
    ap.add_argument("--output-dir", type=Path, default=Path("renders"), help="folder of the outputs (default: renders)")
    ap.add_argument("--name", default=None, help="output file stem (default: the camera path's file stem)")
    w, h = DEFAULT_PREVIEW_SIZE
    ap.add_argument("--width", type=int, default=w, help=f"frame width in pixels, {MIN_SIZE}..{MAX_SIZE} (default {w})")
    ap.add_argument("--height", type=int, default=h,
                    help=f"frame height in pixels, {MIN_SIZE}..{MAX_SIZE} (default {h})")
    ap.add_argument("--fps", type=float, default=DEFAULT_PREVIEW_FPS,
                    help=f"frames per second, {MIN_FPS:g}..{MAX_FPS:g} (default {DEFAULT_PREVIEW_FPS:g})")
    ap.add_argument("--gif", action="store_true", help="also write a small looping GIF")
    ap.add_argument("--device", default="cpu", help="cpu (default) or cuda (gsplat)")
    ap.add_argument("--backend", default="auto", choices=["auto", "native", "torch", "gsplat"],
                    help="auto: compiled CPU kernel, else pure torch; gsplat on cuda")
    return ap


def _check_args(ap: argparse.ArgumentParser, a: argparse.Namespace):
    """Validate everything before writing: returns (splat, camera-path dict); calls ap.error (exit 2) otherwise."""
    from cinenerf_ns.planner.errors import InvalidInputError
    from cinenerf_ns.planner.shots.camera_path import read_camera_path
    from cinenerf_ns.preview.cameras import path_cameras

    for opt, v in (("--width", a.width), ("--height", a.height)):
        if not MIN_SIZE <= v <= MAX_SIZE:
            ap.error(f"{opt} must be in {MIN_SIZE}..{MAX_SIZE} pixels, got {v}")
    if not MIN_FPS <= a.fps <= MAX_FPS:  # also rejects nan
        ap.error(f"--fps must be in {MIN_FPS:g}..{MAX_FPS:g}, got {a.fps:g}")
    if not a.scene.exists():
        ap.error(f"--scene: file or folder not found: {a.scene}")
    if not a.camera_path.is_file():
        ap.error(f"--camera-path: file not found: {a.camera_path}")
    if a.output_dir.exists() and not a.output_dir.is_dir():
        ap.error(f"--output-dir: {a.output_dir} exists and is not a folder")
    if a.name is not None and (not a.name or "/" in a.name or a.name.startswith(".")):
        ap.error(f"--name must be a plain file name, got {a.name!r}")
    try:
        cam = read_camera_path(a.camera_path)
        path_cameras(cam, a.width, a.height, a.fps)
    except InvalidInputError as e:
        ap.error(f"--camera-path: {e}")
    from cinenerf_ns.method.checkpoint import load_splat

    try:
        splat = load_splat(a.scene).params
    except (ValueError, OSError, KeyError) as e:
        ap.error(f"--scene: could not load {a.scene}: {e}")
    if splat.colors_dc is None:
        ap.error(f"--scene: {a.scene} has no colour (features_dc / rgb)")
    return splat, cam


def main(argv: Optional[Sequence[str]] = None) -> dict:
    ap = _parser()
    a = ap.parse_args(argv)
    splat, cam = _check_args(ap, a)
    from cinenerf_ns.planner.errors import InvalidInputError
    from cinenerf_ns.preview.preview import preview_camera_path

    console = Console(emoji=False)  # paths printed as typed (console_text)
    name = a.name or a.camera_path.stem
    try:
        out = preview_camera_path(splat, cam, a.output_dir, name, width=a.width, height=a.height, fps=a.fps,
                                  device=a.device, backend=a.backend, gif=a.gif, console=console)
    except InvalidInputError as e:
        ap.error(str(e))
    t = out["timings"]
    console.print(f"[green]{out['frames']} frames[/green] {out['width']}x{out['height']} @ {out['fps']:g} fps "
                  f"({out['backend']}) in {t['total_s']:.1f} s (render {t['render_s']:.1f} s, "
                  f"median {t['frame_ms_median']:.0f} ms/frame)")
    for k, p in out["paths"].items():
        console.print(f"  {k:14s} {p}", markup=False, soft_wrap=True)  # a path: as typed, one line
    return out


def entrypoint() -> None:
    try:
        main()
    except RuntimeError as e:  # ffmpeg or the rasteriser failed mid-way; no partial file is left
        print(f"cinesplat-preview: {e}", file=sys.stderr)
        raise SystemExit(1)


if __name__ == "__main__":
    entrypoint()
