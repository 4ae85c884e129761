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
from ..file_checks import path_problem
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


MAX_PATH_FRAMES = 200_000  # frames a camera path may hold (ours: at most TimingConfig.max_frames)
MAX_TRANSLATION = 1e5  # scene units: a camera farther from the origin is a corrupt or mis-scaled path
MAX_SECONDS = 1e7  # a camera path's duration, seconds (115 days: any more is a corrupt file)
MAX_RENDER_SIZE = 16384  # render_width / render_height, pixels
MAX_CAMERA_PATH_BYTES = 256 << 20  # a camera-path JSON file larger than this is refused before it is read


def _number(v: Any) -> bool:
    """A JSON number: int or float, not a bool, not a string."""
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _pose(m: Any, where: str) -> None:
    """InvalidInputError unless ``m`` is 16 finite numbers, row-major 4x4, whose 3x3 block is a rotation and whose
    translation is bounded: a camera pose (an all-zero or 1e30 matrix renders blank frames)."""
    if not isinstance(m, list) or len(m) != 16 or not all(_number(v) for v in m):
        got = type(m).__name__ if not isinstance(m, list) else f"a list of {len(m)}" + (
            "" if all(_number(v) for v in m) else " with non-numbers (numbers must not be strings)")
        raise InvalidInputError(f"camera path {where} must be 16 numbers (row-major 4x4), got {got}.")
    try:
        a = np.asarray(m, dtype=np.float64).reshape(4, 4)
    except OverflowError:
        a = np.full((4, 4), np.inf)
    if not np.isfinite(a).all():
        raise InvalidInputError(f"camera path {where} has a non-finite value.")
    R, t = a[:3, :3], a[:3, 3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-3:
        det = float(np.linalg.det(R))
        raise InvalidInputError(f"camera path {where} is not a camera pose: its 3x3 block must be a rotation "
                                f"(orthonormal columns, no scale or shear), got determinant {det:.3g}"
                                + (" (a singular matrix)" if abs(det) < 1e-9 else "") + ".")
    if np.abs(t).max() > MAX_TRANSLATION:
        raise InvalidInputError(f"camera path {where} puts the camera {np.abs(t).max():.3g} scene units from the "
                                f"origin (at most {MAX_TRANSLATION:g}): a corrupt or mis-scaled path.")


def validate_camera_path(d: Any) -> None:
    """Raise InvalidInputError unless d is what ns-render and the viewer's Load Path read: a JSON object with
    camera_type (text), render_width / render_height (whole numbers), seconds (a positive number) and camera_path (a
    list of frame objects, each with camera_to_world: a camera pose, and fov in (0, 180)); optional keyframes
    (objects with a 16-number matrix, fov and aspect). Numbers must be JSON numbers, not strings."""
    if not isinstance(d, dict):
        raise InvalidInputError(f"camera path must be a JSON object (a nerfstudio camera path), got "
                                f"{'a list' if isinstance(d, list) else type(d).__name__}.")
    missing = [k for k in REQUIRED_KEYS if k not in d]
    if missing:
        raise InvalidInputError(f"camera path is missing {missing}.")
    if not isinstance(d["camera_type"], str):
        raise InvalidInputError(f"camera path camera_type must be text, got {d['camera_type']!r:.40}.")
    for k in ("render_width", "render_height"):
        v = d[k]
        if not (_number(v) and 1 <= v <= MAX_RENDER_SIZE and float(v) == int(v)):
            raise InvalidInputError(f"camera path {k} must be a whole number in [1, {MAX_RENDER_SIZE}], got "
                                    f"{v!r:.40}.")
    sec = d["seconds"]
    if not (_number(sec) and 0 < sec <= MAX_SECONDS):  # Python compares a huge JSON integer without overflow
        raise InvalidInputError(f"camera path seconds must be a positive number up to {MAX_SECONDS:g}, got "
                                f"{sec!r:.40}.")
    frames = d["camera_path"]
    if not isinstance(frames, list):
        raise InvalidInputError(f"camera path camera_path must be a list of frames, got {type(frames).__name__}.")
    if not frames:
        raise InvalidInputError("camera path has no frames.")
    if len(frames) > MAX_PATH_FRAMES:
        raise InvalidInputError(f"camera path has {len(frames)} frames, more than {MAX_PATH_FRAMES}.")
    for i, frame in enumerate(frames):
        if not isinstance(frame, dict):
            raise InvalidInputError(f"camera path frame {i} must be an object with camera_to_world and fov, got "
                                    f"{'a list' if isinstance(frame, list) else type(frame).__name__}.")
        if "camera_to_world" not in frame or "fov" not in frame:
            raise InvalidInputError(f"camera path frame {i} needs camera_to_world (16 numbers) and fov.")
        _pose(frame["camera_to_world"], f"frame {i} camera_to_world")
        fov = frame["fov"]
        if not (_number(fov) and 0 < fov < 180):
            raise InvalidInputError(f"camera path frame {i} fov must be a number in (0, 180) degrees, got "
                                    f"{fov!r:.40}.")
    if "default_fov" in d and not (_number(d["default_fov"]) and 0 < d["default_fov"] < 180):
        raise InvalidInputError(f"camera path default_fov must be a number in (0, 180) degrees, got "
                                f"{d['default_fov']!r:.40}.")
    kfs = d.get("keyframes", [])
    if not isinstance(kfs, list):
        raise InvalidInputError(f"camera path keyframes must be a list, got {type(kfs).__name__}.")
    for i, kf in enumerate(kfs):
        if not isinstance(kf, dict) or not all(k in kf for k in ("matrix", "fov", "aspect")):
            raise InvalidInputError(f"camera path keyframe {i} needs matrix (16 numbers), fov and aspect.")
        _pose(kf["matrix"], f"keyframe {i} matrix")
        if not (_number(kf["fov"]) and 0 < kf["fov"] < 180 and _number(kf["aspect"]) and 0 < kf["aspect"] < 1e3):
            raise InvalidInputError(f"camera path keyframe {i} fov must be in (0, 180) degrees and aspect a "
                                    f"positive number.")


def write_camera_path(path: Union[str, Path], d: Dict[str, Any]) -> Path:
    """Validate and write atomically (temporary file in the same folder + os.replace): a reader never
    sees a half-written file and a failed write leaves any previous file untouched."""
    validate_camera_path(d)
    return atomic_write(path, json.dumps(d, indent=2, allow_nan=False))


def read_camera_path(path: Union[str, Path]) -> Dict[str, Any]:
    """Read and validate a camera-path JSON."""
    path = Path(path)
    problem = path_problem(path)
    if problem is not None:
        raise InvalidInputError(f"camera path file {path} {problem}")
    size = path.stat().st_size
    if size > MAX_CAMERA_PATH_BYTES:
        raise InvalidInputError(f"camera path {path} is {size / 2**20:.0f} MiB, over the "
                                f"{MAX_CAMERA_PATH_BYTES >> 20} MiB a camera path may take")
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise InvalidInputError(f"camera path {path} is not text (not UTF-8): not a camera-path JSON") from None
    except (ValueError, RecursionError) as e:  # JSONDecodeError, integers of over 4300 digits, deep nesting
        raise InvalidInputError(f"camera path {path} is not valid JSON: {str(e)[:200] or type(e).__name__}") from None
    try:
        validate_camera_path(d)
    except InvalidInputError as e:
        raise InvalidInputError(f"{path}: {e}") from None
    return d


def camera_path_poses(d: Dict[str, Any]) -> np.ndarray:
    """[T, 4, 4] camera_to_world matrices of a camera-path dict."""
    return np.asarray([f["camera_to_world"] for f in d["camera_path"]], dtype=np.float64).reshape(-1, 4, 4)
