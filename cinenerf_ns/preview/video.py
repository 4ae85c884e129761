"""Write preview frames: H.264 mp4 (the imageio-ffmpeg wheel's ffmpeg), contact-sheet PNG and GIF.

Every file is written to a temporary name in its folder, given mode 0644 and renamed over the target
(os.replace), so a reader never sees a half-written file and a failure leaves no partial output.
"""
from __future__ import annotations

import contextlib
import subprocess
from pathlib import Path
from typing import List, Optional, Sequence

import numpy as np
from PIL import Image, ImageDraw

from cinenerf_ns.planner.atomic import atomic_path


def ffmpeg_exe() -> str:
    """Path of the ffmpeg binary bundled with the imageio-ffmpeg wheel."""
    try:
        import imageio_ffmpeg
    except ImportError as e:  # pragma: no cover - a dependency of the package
        raise RuntimeError("imageio-ffmpeg is not installed (pip install imageio-ffmpeg)") from e
    return imageio_ffmpeg.get_ffmpeg_exe()


class Mp4Writer:
    """Stream uint8 frames [H, W, 3] into an H.264 mp4 (yuv420p, odd sizes padded by one pixel)."""

    def __init__(self, path: Path, width: int, height: int, fps: float, crf: int = 20):
        self.path, self.width, self.height = Path(path), int(width), int(height)
        self._ctx = atomic_path(self.path)
        self._tmp = self._ctx.__enter__()
        cmd = [ffmpeg_exe(), "-y", "-hide_banner", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24",
               "-s", f"{self.width}x{self.height}", "-r", f"{fps:g}", "-i", "-",
               "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264", "-preset", "veryfast", "-crf", str(crf),
               "-pix_fmt", "yuv420p", "-movflags", "+faststart", "-f", "mp4", str(self._tmp)]
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        self.frames = 0

    def add(self, frame: np.ndarray) -> None:
        if frame.shape != (self.height, self.width, 3) or frame.dtype != np.uint8:
            raise ValueError(f"frame must be uint8 [{self.height}, {self.width}, 3], got {frame.dtype} {frame.shape}")
        try:
            self._proc.stdin.write(np.ascontiguousarray(frame).tobytes())
        except BrokenPipeError:
            self._fail()
        self.frames += 1

    def _fail(self):
        self._proc.kill()
        err = self._proc.communicate()[1].decode(errors="replace").strip()
        raise RuntimeError(f"ffmpeg failed writing {self.path}: {err[-500:]}")

    def close(self) -> Path:
        """Finish the file (raises RuntimeError when ffmpeg failed; nothing is left behind then)."""
        try:
            _, err = self._proc.communicate()
            if self._proc.returncode != 0 or self.frames == 0:
                msg = err.decode(errors="replace").strip()[-500:] or "no frames"
                raise RuntimeError(f"ffmpeg failed writing {self.path}: {msg}")
        except BaseException as e:
            self.abort(e)
            raise
        self._ctx.__exit__(None, None, None)
        return self.path

    def abort(self, exc: Optional[BaseException] = None) -> None:
        """Stop ffmpeg and remove the temporary file."""
        if self._proc.poll() is None:
            self._proc.kill()
            self._proc.communicate()
        err = exc or RuntimeError("aborted")
        with contextlib.suppress(BaseException):
            self._ctx.__exit__(type(err), err, None)

    def __enter__(self) -> "Mp4Writer":
        return self

    def __exit__(self, et, ev, tb) -> None:
        if et is None:
            self.close()
        else:
            self.abort(ev)


SHEET_TILE_WIDTH = 480  # contact-sheet tiles at most this wide: full-size tiles make the PNG slow to write


def contact_sheet(frames: Sequence[np.ndarray], labels: Sequence[str], cols: int = 3, pad: int = 4,
                  max_tile_width: int = SHEET_TILE_WIDTH) -> np.ndarray:
    """uint8 [H', W', 3] grid of frames [H, W, 3] (scaled down to ``max_tile_width`` when wider) with a label in each
    frame's corner."""
    if frames[0].shape[1] > max_tile_width:
        h0, w0 = frames[0].shape[:2]
        size = (int(max_tile_width), max(1, round(h0 * max_tile_width / w0)))
        frames = [np.asarray(Image.fromarray(f).resize(size, Image.BILINEAR)) for f in frames]
    h, w = frames[0].shape[:2]
    cols = max(1, min(cols, len(frames)))
    rows = (len(frames) + cols - 1) // cols
    sheet = Image.new("RGB", (cols * w + (cols + 1) * pad, rows * h + (rows + 1) * pad), (20, 20, 20))
    draw = ImageDraw.Draw(sheet)
    for k, (f, lab) in enumerate(zip(frames, labels)):
        x, y = pad + (k % cols) * (w + pad), pad + (k // cols) * (h + pad)
        sheet.paste(Image.fromarray(f), (x, y))
        draw.rectangle([x, y, x + 7 * len(lab) + 6, y + 14], fill=(0, 0, 0))
        draw.text((x + 3, y + 2), lab, fill=(255, 255, 255))
    return np.asarray(sheet)


def write_png(path: Path, image: np.ndarray) -> Path:
    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG")
    return Path(path)


GIF_WIDTH = 240  # pixels: GIF frames are scaled to this width


def gif_frame(frame: np.ndarray, width: int = GIF_WIDTH) -> np.ndarray:
    """A frame [H, W, 3] scaled to ``width`` pixels wide, as the GIF holds it (kept instead of the full frame)."""
    h, w = frame.shape[:2]
    if w == width:
        return frame
    return np.asarray(Image.fromarray(frame).resize((int(width), max(1, round(h * width / w))), Image.BILINEAR))


def write_gif(path: Path, frames: List[np.ndarray], fps: float, width: int = GIF_WIDTH) -> Path:
    """Looping GIF of the frames, scaled to ``width`` pixels wide."""
    imgs = [Image.fromarray(gif_frame(f, width)) for f in frames]
    with atomic_path(path) as tmp:
        imgs[0].save(tmp, format="GIF", save_all=True, append_images=imgs[1:], duration=round(1000 / fps), loop=0)
    return Path(path)
