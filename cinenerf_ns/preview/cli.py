"""cinesplat-preview: render a nerfstudio camera path through a splat on the CPU (mp4 + contact sheet [+ GIF]).

  cinesplat-preview --scene scene.npz --camera-path demo_output/demo_0.json --output-dir renders

Bad input (missing file, size or fps out of range, unreadable scene or path) is reported on stderr with the
option's name and exit status 2, before anything is written.
"""
from __future__ import annotations

import argparse
import re
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
                    help="compact scene (.npz / .pt from export_compact), .ckpt, run folder, ns-train config.yml, a "
                         "3DGS .ply or procedural[:N[:SEED]] (cinenerf_ns.scenes.load_scene)")
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
    ap.add_argument("--device", default="cpu", help="cpu (default), cuda or cuda:N (gsplat)")
    ap.add_argument("--backend", default="auto", choices=["auto", "native", "torch", "gsplat"],
                    help="auto: compiled CPU kernel, else pure torch; gsplat on cuda")
    return ap


def _default_name(camera_path: Path, console) -> str:
    """The output stem when --name is not given: the camera path's file stem, made a plain name (said when changed)."""
    stem = camera_path.stem
    name = re.sub(r"[^A-Za-z0-9._-]", "_", stem).lstrip("._-")[:100] or "preview"
    if name != stem:
        console.print(f"note: output name {name!r} (from the camera path's file name {stem!r}; give --name to "
                      f"choose another)", markup=False, highlight=False)
    return name


def _check_args(ap: argparse.ArgumentParser, a: argparse.Namespace, console=None):
    """Validate everything before writing: returns (splat, camera-path dict, output name); calls ap.error (exit 2)
    otherwise. Every check that needs no scene runs before the scene is loaded."""
    from cinenerf_ns.options import check_device
    from cinenerf_ns.output_set import check_file_size_limit, check_name, check_writable
    from cinenerf_ns.planner.errors import InvalidInputError
    from cinenerf_ns.planner.file_checks import path_problem
    from cinenerf_ns.planner.shots.camera_path import read_camera_path
    from cinenerf_ns.preview.cameras import path_cameras

    for opt, v in (("--width", a.width), ("--height", a.height)):
        if not MIN_SIZE <= v <= MAX_SIZE:
            ap.error(f"{opt} must be in {MIN_SIZE}..{MAX_SIZE} pixels, got {v}")
    if not MIN_FPS <= a.fps <= MAX_FPS:  # also rejects nan
        ap.error(f"--fps must be in {MIN_FPS:g}..{MAX_FPS:g}, got {a.fps:g}")
    # torch from here on (the renderer's modules): the checks above answer in a fraction of a second
    from cinenerf_ns.preview.preview import check_gif_frames
    from cinenerf_ns.preview.render import choose_backend

    try:
        a.device = check_device(a.device)
        choose_backend(a.backend, a.device)
        name = _default_name(a.camera_path, console) if a.name is None else check_name(a.name, "--name")
        check_writable(a.output_dir)
        check_file_size_limit(a.output_dir)
    except InvalidInputError as e:
        ap.error(str(e))
    from cinenerf_ns.scenes import load_scene, procedural_spec

    try:
        procedural = procedural_spec(str(a.scene)) is not None
    except InvalidInputError as e:
        ap.error(f"--scene: {e}")
    files = (("--scene", a.scene, True),) * (not procedural) + (("--camera-path", a.camera_path, False),)
    for opt, path, folder_ok in files:
        problem = path_problem(path, folder_ok=folder_ok)
        if problem == "was not found":
            ap.error(f"{opt}: file{' or folder' if folder_ok else ''} not found: {path}")
        if problem is not None:
            ap.error(f"{opt}: {path} {problem}")
    try:
        cam = read_camera_path(a.camera_path)  # its messages name the file
    except InvalidInputError as e:
        ap.error(f"--camera-path: {e}")
    try:
        cams = path_cameras(cam, a.width, a.height, a.fps)
        if a.gif:
            check_gif_frames(len(cams))
    except InvalidInputError as e:
        ap.error(f"--camera-path {a.camera_path}: {e}")
    try:
        splat = load_scene(str(a.scene), planning=False).splat  # the Gaussians only: no obstacles, no semantics
    except (ValueError, OSError, KeyError) as e:
        ap.error(f"--scene: could not load {a.scene}: {e}")
    if splat.colors_dc is None:
        ap.error(f"--scene: {a.scene} has no colour (features_dc / rgb, or f_dc_* / red green blue in a .ply)")
    return splat, cam, name


def main(argv: Optional[Sequence[str]] = None) -> dict:
    ap = _parser()
    a = ap.parse_args(argv)
    console = Console(emoji=False)  # paths printed as typed (console_text)
    splat, cam, name = _check_args(ap, a, console)
    from cinenerf_ns.output_set import OutputSet
    from cinenerf_ns.planner.errors import InvalidInputError
    from cinenerf_ns.preview.preview import preview_camera_path

    try:
        # all files appear together at the end, or none (an interrupt or a failure leaves the folder as it was);
        # earlier files of this name are kept (the camera path itself may be one: shot_0.json for --name shot_0)
        with OutputSet(a.output_dir, name, remove_stale=False) as outs:
            out = preview_camera_path(splat, cam, outs.staging, name, width=a.width, height=a.height, fps=a.fps,
                                      device=a.device, backend=a.backend, gif=a.gif, console=console)
            out["paths"] = {k: str(outs.final(Path(p).name)) for k, p in out["paths"].items()}
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
    from cinenerf_ns.signals import interrupted, signals_as_interrupts

    with signals_as_interrupts():  # SIGTERM / SIGHUP unwind like Ctrl-C: nothing is left behind
        try:
            main()
        except KeyboardInterrupt as e:
            code, what = interrupted(e)
            print(f"cinesplat-preview: {what}; no output was written", file=sys.stderr)
            raise SystemExit(code) from None
        except RuntimeError as e:  # ffmpeg or the rasteriser failed mid-way; no partial file is left
            print(f"cinesplat-preview: {e}", file=sys.stderr)
            raise SystemExit(1) from None
        except MemoryError:
            print("cinesplat-preview: out of memory; lower --width / --height or --fps", file=sys.stderr)
            raise SystemExit(2) from None


if __name__ == "__main__":
    entrypoint()
