"""preview_camera_path: render a camera path through a splat into an mp4, a contact sheet and (optionally) a GIF."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Union

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.splat_params import SplatParams
from cinenerf_ns.planner.shots.camera_path import DEFAULT_PREVIEW_FPS, DEFAULT_PREVIEW_SIZE, read_camera_path

from .cameras import PreviewCameras, path_cameras
from .raster_torch import PreviewScene
from .render import (
    NERFSTUDIO_BACKGROUND,
    choose_backend,
    composite,
    render_gsplat,
    render_premultiplied,
    scene_from_splat,
    to_uint8,
)
from .video import Mp4Writer, contact_sheet, gif_frame, write_gif, write_png

GSPLAT_BATCH = 8
MAX_GIF_FRAMES = 900  # a GIF holds its frames in memory until written: a minute at 15 fps, at most


def check_gif_frames(n: int) -> None:
    """InvalidInputError when a GIF of ``n`` frames is asked for (more than MAX_GIF_FRAMES)."""
    if n > MAX_GIF_FRAMES:
        raise InvalidInputError(f"--gif is for short previews: at most {MAX_GIF_FRAMES} frames, this one has {n}; "
                                f"lower --fps or leave out --gif")


def _frames(scene: PreviewScene, cams: PreviewCameras, backend: str, background, device: str):
    """Yield (frame uint8 [H, W, 3], seconds spent rendering it) for every preview camera."""
    W, H = cams.width, cams.height
    if backend != "gsplat":
        for i in range(len(cams)):
            t0 = time.perf_counter()
            rgb, alpha = render_premultiplied(scene, cams.viewmats[i], cams.intrinsics[i], W, H, backend=backend)
            img = to_uint8(composite(rgb, alpha, background))
            yield img, time.perf_counter() - t0
        return
    import torch

    scene = scene.to(device=device, dtype=torch.float32)  # once; render_gsplat's .to is then a no-op
    for s in range(0, len(cams), GSPLAT_BATCH):
        ids = range(s, min(s + GSPLAT_BATCH, len(cams)))
        t0 = time.perf_counter()
        rgb, alpha = render_gsplat(scene, cams.viewmats[s:ids.stop], np.stack([cams.K(i) for i in ids]), W, H,
                                   device=device)
        imgs = to_uint8(composite(rgb, alpha, background))
        torch.cuda.synchronize()
        dt = (time.perf_counter() - t0) / len(ids)
        for img in imgs:
            yield img, dt


def mark_subject(img: np.ndarray, cams: PreviewCameras, i: int, points: np.ndarray) -> np.ndarray:
    """A copy of frame ``i`` [H, W, 3] with the projected box of ``points`` [P, 3] (those in front of the camera)
    outlined in yellow and labelled; the frame itself when none is in front."""
    from PIL import Image, ImageDraw

    pts = np.asarray(points, np.float64).reshape(-1, 3)
    vm = cams.viewmats[i]
    c = pts @ vm[:3, :3].T + vm[:3, 3]  # OpenCV camera coordinates
    c = c[c[:, 2] > 1e-6]
    if len(c) == 0:
        return img
    fx, fy, cx, cy = cams.intrinsics[i]
    u, v = fx * c[:, 0] / c[:, 2] + cx, fy * c[:, 1] / c[:, 2] + cy
    h, w = img.shape[:2]
    x0, x1 = float(np.clip(u.min(), 0, w - 1)), float(np.clip(u.max(), 0, w - 1))
    y0, y1 = float(np.clip(v.min(), 0, h - 1)), float(np.clip(v.max(), 0, h - 1))
    im = Image.fromarray(img)
    draw = ImageDraw.Draw(im)
    draw.rectangle([x0, y0, x1, y1], outline=(255, 220, 0), width=2)
    draw.text((x0 + 3, min(y1 + 2, h - 12)), "look-at", fill=(255, 220, 0))
    return np.asarray(im)


def preview_camera_path(
    splat: Union[SplatParams, PreviewScene],
    camera_path: Union[Dict[str, Any], str, Path],
    out_dir: Union[str, Path],
    name: str = "preview",
    width: int = DEFAULT_PREVIEW_SIZE[0],
    height: int = DEFAULT_PREVIEW_SIZE[1],
    fps: float = DEFAULT_PREVIEW_FPS,
    device: str = "cpu",
    backend: str = "auto",
    background: Optional[Sequence[float]] = NERFSTUDIO_BACKGROUND,
    sheet_frames: int = 6,
    gif: bool = False,
    console: Optional[Console] = None,
    progress: bool = True,
    subject_points: Optional[np.ndarray] = None,
) -> Dict[str, Any]:
    """Render ``camera_path`` (a nerfstudio camera-path dict or JSON file) through ``splat`` at width x height, fps.

    Writes ``<out_dir>/<name>.mp4``, ``<name>_sheet.png`` (``sheet_frames`` frames, first and last included) and,
    with ``gif``, ``<name>.gif``. ``backend``: "auto" (compiled CPU kernel, else torch; gsplat on CUDA), "native",
    "torch" or "gsplat". ``subject_points`` [P, 3]: points of the look-at object; the contact sheet outlines them
    (their projected box, yellow) in each frame. Inputs are checked before anything is written (InvalidInputError).
    Returns
    {"paths": {...}, "timings": {...}, "frames", "frame_index", "backend", "width", "height", "fps"}.
    """
    t_start = time.perf_counter()
    if not isinstance(camera_path, dict):
        camera_path = read_camera_path(camera_path)
    if not name or "/" in name or name.startswith("."):
        raise InvalidInputError(f"preview name must be a plain file name, got {name!r}.")
    cams = path_cameras(camera_path, width, height, fps)
    if gif:
        check_gif_frames(len(cams))
    b = choose_backend(backend, device)
    t0 = time.perf_counter()
    scene = splat if isinstance(splat, PreviewScene) else scene_from_splat(splat)
    t_prepare = time.perf_counter() - t0
    out = Path(out_dir)
    paths = {"mp4": out / f"{name}.mp4", "contact_sheet": out / f"{name}_sheet.png"}
    if gif:
        paths["gif"] = out / f"{name}.gif"
    n = len(cams)
    sheet_at = set(np.unique(np.rint(np.linspace(0, n - 1, min(sheet_frames, n))).astype(int)).tolist())
    kept: Dict[int, np.ndarray] = {}
    gif_frames: List[np.ndarray] = []
    per_frame: List[float] = []
    t_encode = 0.0
    console = console or Console(stderr=True)
    # the description holds the user's name: plain text, never markup
    bar = Progress(TextColumn("[bold]preview[/bold]"), TextColumn("{task.description}", markup=False), BarColumn(),
                   MofNCompleteColumn(), TimeRemainingColumn(), console=console, disable=not progress, transient=False)
    with bar, Mp4Writer(paths["mp4"], cams.width, cams.height, cams.fps) as writer:
        task = bar.add_task(f"{name} {cams.width}x{cams.height} @ {cams.fps:g} fps ({b})", total=n)
        for i, (img, dt) in enumerate(_frames(scene, cams, b, background, device)):
            per_frame.append(dt)
            t0 = time.perf_counter()
            writer.add(img)
            t_encode += time.perf_counter() - t0
            if i in sheet_at:
                kept[i] = img if subject_points is None else mark_subject(img, cams, i, subject_points)
            if gif:
                gif_frames.append(gif_frame(img))  # small frames: a 4096-wide GIF preview holds no full frames
            bar.advance(task)
        t0 = time.perf_counter()
    t_encode += time.perf_counter() - t0  # the writer's close (ffmpeg flushing) ran at the end of the with block
    t0 = time.perf_counter()
    idx = sorted(kept)
    write_png(paths["contact_sheet"], contact_sheet([kept[i] for i in idx],
                                                    [f"frame {i}  {i / cams.fps:.2f} s" for i in idx]))
    if gif:
        write_gif(paths["gif"], gif_frames, cams.fps)
    t_images = time.perf_counter() - t0
    ms = np.asarray(per_frame) * 1e3
    timings = {
        "prepare_s": t_prepare, "render_s": float(ms.sum() / 1e3), "encode_s": t_encode, "images_s": t_images,
        "total_s": time.perf_counter() - t_start, "frame_ms": ms.tolist(), "frame_ms_median": float(np.median(ms)),
        "frame_ms_p95": float(np.percentile(ms, 95)), "frame_ms_max": float(ms.max()),
    }
    return {"paths": {k: str(v) for k, v in paths.items()}, "timings": timings, "frames": n,
            "frame_index": cams.frame_index.tolist(), "backend": b, "width": cams.width, "height": cams.height,
            "fps": cams.fps}
