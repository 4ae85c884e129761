"""Export a Shot as a nerfstudio camera-path JSON (ns-render camera-path and the viewer's "Load Path").

Format ground truth (nerfstudio 1.1.5):
  * nerfstudio/cameras/camera_paths.py::get_path_from_json reads render_height, render_width,
    camera_type and, per frame of "camera_path", camera_to_world (16 floats, row-major 4x4, only the top
    3 rows are used) and fov (vertical, degrees; focal = (H/2) / tan(fov/2), viewer_legacy/server/utils.py);
    nerfstudio/scripts/render.py reads "seconds" and renders at fps = len(camera_path) / seconds.
  * nerfstudio/viewer/render_panel.py "Load Path" reads "keyframes" [{matrix, fov, aspect,
    override_transition_enabled, override_transition_sec, (render_time, override_time_enabled)}] and
    "default_fov", "default_transition_sec". A keyframe's "matrix" is in the SAME frame as
    camera_to_world: nerfstudio world coordinates, OpenGL camera axes. On load the viewer turns it into
    a viser camera itself (rotation @ Rx(pi) for viser's OpenCV axes, position * VISER_NERFSTUDIO_SCALE_RATIO
    = 10) and undoes exactly that when it writes keyframes back, so no conversion happens here.
    override_transition_sec of keyframe i is the time from keyframe i-1 to i (compute_transition_times_cumsum).

Keyframes are a subsample of the frames (every `keyframe_interval_s`, first and last always). The viewer
draws a Kochanek-Bartels spline through them, so its preview is an interpolation of our path (close, not
identical); `camera_path` carries every frame exactly and is what ns-render renders.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Dict, Union

import numpy as np

from ..atomic import atomic_write
from ..errors import InvalidInputError
from .shot import Shot

REQUIRED_KEYS = ("camera_type", "render_height", "render_width", "seconds", "camera_path")


def keyframe_indices(times: np.ndarray, interval_s: float) -> np.ndarray:
    """Frame indices of keyframes: the first frame, then the first frame at or after every interval_s, the last."""
    if interval_s <= 0:
        raise InvalidInputError(f"keyframe interval must be positive, got {interval_s}.")
    rel = times - times[0]
    slots = np.floor(rel / interval_s + 1e-9).astype(np.int64)
    first_of_slot = np.flatnonzero(np.diff(np.concatenate([[-1], slots])) > 0)
    return np.union1d(first_of_slot, [0, len(times) - 1])


DEFAULT_FOV_DEG = 50.0  # vertical field of view of exported cameras, degrees (the CLI, the viewer, the shot score)
DEFAULT_RENDER_SIZE = (1920, 1080)  # render width, height written into exported camera paths (nerfstudio's usual)
DEFAULT_PREVIEW_SIZE = (480, 270)  # width, height of the quick CPU preview of a path (cinesplat-plan, -preview, viewer)
DEFAULT_PREVIEW_FPS = 15.0  # frame rate of that preview (frames are taken from the path, never interpolated)


def shot_to_camera_path(
    shot: Shot,
    fov_deg: float = DEFAULT_FOV_DEG,
    width: int = DEFAULT_RENDER_SIZE[0],
    height: int = DEFAULT_RENDER_SIZE[1],
    fps: float = None,
    keyframe_interval_s: float = 0.5,
    camera_type: str = "perspective",
) -> Dict[str, Any]:
    """Nerfstudio camera-path dict of the shot's frames (see the module docstring for the format).

    fov_deg is the vertical field of view. fps defaults to the shot's own frame rate and must equal it
    (ns-render plays the frames at len(camera_path) / seconds; resample the shot to change it).
    """
    if not (0.0 < fov_deg < 180.0):
        raise InvalidInputError(f"fov must be in (0, 180) degrees, got {fov_deg}.")
    if int(width) <= 0 or int(height) <= 0:
        raise InvalidInputError(f"render size must be positive, got {width}x{height}.")
    fps = float(shot.fps if fps is None else fps)
    if not math.isclose(fps, float(shot.fps), rel_tol=1e-6):
        raise InvalidInputError(
            f"fps {fps} differs from the shot's frame rate {shot.fps}; re-time the shot "
            "(TimingConfig.fps) instead of relabelling its frames."
        )
    aspect = float(width) / float(height)
    c2w = shot.camera_to_worlds()  # [T, 4, 4]
    frames = [
        {"camera_to_world": m.reshape(-1).tolist(), "fov": float(fov_deg), "aspect": aspect} for m in c2w
    ]
    # ns-render: fps = len(frames) / seconds, so frames j/fps, j = 0..T-1 -> seconds = T / fps
    seconds = len(frames) / fps
    kf = keyframe_indices(shot.times, keyframe_interval_s)
    keyframes = []
    for n, i in enumerate(kf):
        transition = None if n == 0 else float(shot.times[i] - shot.times[kf[n - 1]])
        keyframes.append(
            {
                "matrix": c2w[i].reshape(-1).tolist(),
                "fov": float(fov_deg),
                "aspect": aspect,
                "override_transition_enabled": n > 0,
                "override_transition_sec": transition,
            }
        )
    return {
        "default_fov": float(fov_deg),
        "default_transition_sec": float(keyframe_interval_s),
        "keyframes": keyframes,
        "camera_type": camera_type,
        "render_height": int(height),
        "render_width": int(width),
        "fps": fps,
        "seconds": seconds,
        "is_cycle": False,
        "smoothness_value": 0.0,
        "camera_path": frames,
    }


def validate_camera_path(d: Dict[str, Any]) -> None:
    """Raise InvalidInputError unless d has what ns-render and the viewer's Load Path read."""
    missing = [k for k in REQUIRED_KEYS if k not in d]
    if missing:
        raise InvalidInputError(f"camera path is missing {missing}.")
    if not d["camera_path"]:
        raise InvalidInputError("camera path has no frames.")
    for i, frame in enumerate(d["camera_path"]):
        m = frame.get("camera_to_world")
        if m is None or len(m) != 16 or "fov" not in frame:
            raise InvalidInputError(f"camera path frame {i} needs camera_to_world (16 floats) and fov.")
        if not all(math.isfinite(float(v)) for v in m):
            raise InvalidInputError(f"camera path frame {i} has a non-finite camera_to_world.")
    for i, kf in enumerate(d.get("keyframes", [])):
        if len(kf.get("matrix", [])) != 16 or "fov" not in kf or "aspect" not in kf:
            raise InvalidInputError(f"camera path keyframe {i} needs matrix (16 floats), fov and aspect.")
    if not (float(d["seconds"]) > 0):
        raise InvalidInputError(f"camera path seconds must be positive, got {d['seconds']}.")


def write_camera_path(path: Union[str, Path], d: Dict[str, Any]) -> Path:
    """Validate and write atomically (temporary file in the same folder + os.replace): a reader never
    sees a half-written file and a failed write leaves any previous file untouched."""
    validate_camera_path(d)
    return atomic_write(path, json.dumps(d, indent=2, allow_nan=False))


def read_camera_path(path: Union[str, Path]) -> Dict[str, Any]:
    """Read and validate a camera-path JSON."""
    path = Path(path)
    if not path.is_file():
        raise InvalidInputError(f"camera path file not found: {path}")
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise InvalidInputError(f"camera path {path} is not valid JSON: {e}") from None
    validate_camera_path(d)
    return d


def camera_path_poses(d: Dict[str, Any]) -> np.ndarray:
    """[T, 4, 4] camera_to_world matrices of a camera-path dict."""
    return np.asarray([f["camera_to_world"] for f in d["camera_path"]], dtype=np.float64).reshape(-1, 4, 4)
