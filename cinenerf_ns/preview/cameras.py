"""The cameras ns-render would use for a nerfstudio camera-path JSON, as gsplat-style viewmats and intrinsics.

nerfstudio 1.1.5 (cameras/camera_paths.py::get_path_from_json, models/splatfacto.py::get_viewmat):
camera_to_world is a row-major 4x4 (top 3 rows used) in OpenGL camera axes (x right, y up, looking down -z);
fov is vertical in degrees, focal = (H / 2) / tan(fov / 2) for fx and fy, principal point (W / 2, H / 2);
the world -> camera viewmat flips the camera's y and z axes (OpenCV axes) and inverts the pose.
ns-render plays all frames at len(camera_path) / seconds fps; a preview at another frame rate takes the
nearest frames of the path (first and last always), never interpolated poses.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Dict

import numpy as np

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.shots.camera_path import (
    DEFAULT_PREVIEW_FPS,
    DEFAULT_PREVIEW_SIZE,
    camera_path_poses,
    validate_camera_path,
)

MIN_SIZE, MAX_SIZE = 16, 4096
MIN_FPS, MAX_FPS = 1.0, 120.0
MAX_PREVIEW_FRAMES = 9000  # frames one preview may render (10 minutes at 15 fps), checked before anything is made


@dataclass
class PreviewCameras:
    """Cameras of the preview frames."""

    viewmats: np.ndarray  # [F, 4, 4] world -> camera, OpenCV axes, float64
    intrinsics: np.ndarray  # [F, 4] fx, fy, cx, cy in preview pixels
    frame_index: np.ndarray  # [F] index into the camera path's frames
    width: int
    height: int
    fps: float

    def __len__(self) -> int:
        return int(self.viewmats.shape[0])

    def K(self, i: int) -> np.ndarray:
        """[3, 3] intrinsics matrix of frame i."""
        fx, fy, cx, cy = self.intrinsics[i]
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def viewmat_from_c2w(c2w: np.ndarray) -> np.ndarray:
    """[..., 4, 4] world -> camera (OpenCV axes) from camera_to_world [..., 3 or 4, 4] (OpenGL axes)."""
    c2w = np.asarray(c2w, dtype=np.float64)
    R = c2w[..., :3, :3] * np.array([1.0, -1.0, -1.0])  # [..., 3, 3] flip camera y and z
    t = c2w[..., :3, 3:4]  # [..., 3, 1]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros(c2w.shape[:-2] + (4, 4))
    out[..., :3, :3] = Rt
    out[..., :3, 3:4] = -Rt @ t
    out[..., 3, 3] = 1.0
    return out


def check_size(width: int, height: int, fps: float) -> None:
    """Raise InvalidInputError naming the option and its allowed range."""
    for name, v in (("width", width), ("height", height)):
        if not isinstance(v, (int, np.integer)) or not (MIN_SIZE <= int(v) <= MAX_SIZE):
            raise InvalidInputError(f"--{name} must be an integer in {MIN_SIZE}..{MAX_SIZE} pixels, got {v!r}.")
    if not (isinstance(fps, (int, float)) and math.isfinite(fps) and MIN_FPS <= fps <= MAX_FPS):
        raise InvalidInputError(f"--fps must be in {MIN_FPS:g}..{MAX_FPS:g}, got {fps!r}.")


def frame_indices(n_path: int, seconds: float, fps: float) -> np.ndarray:
    """[F] path frames shown at ``fps``: F = max(2, round(seconds * fps)) (1 for a one-frame path), nearest frames
    of an even spread from the first to the last."""
    if n_path == 1:
        return np.zeros(1, dtype=np.int64)
    n = max(2, int(round(seconds * fps)))
    return np.rint(np.linspace(0.0, n_path - 1, n)).astype(np.int64)


def path_cameras(camera_path: Dict[str, Any], width: int = DEFAULT_PREVIEW_SIZE[0],
                 height: int = DEFAULT_PREVIEW_SIZE[1],
                 fps: float = DEFAULT_PREVIEW_FPS) -> PreviewCameras:
    """Preview cameras of a camera-path dict at ``width`` x ``height`` (the path's vertical fov is kept)."""
    validate_camera_path(camera_path)
    check_size(width, height, fps)
    ctype = str(camera_path.get("camera_type", "perspective")).lower()
    if ctype != "perspective":
        raise InvalidInputError(f"the preview renders perspective camera paths only, got camera_type {ctype!r}.")
    frames = camera_path["camera_path"]
    seconds = float(camera_path["seconds"])
    if len(frames) > 1 and seconds * fps > MAX_PREVIEW_FRAMES:
        raise InvalidInputError(
            f"the preview would render {seconds * fps:.4g} frames (the camera path's seconds {seconds:.4g} x "
            f"{fps:g} fps), more than {MAX_PREVIEW_FRAMES}: lower the preview's fps or preview a shorter path.")
    idx = frame_indices(len(frames), seconds, float(fps))
    c2w = camera_path_poses(camera_path)[idx]  # [F, 4, 4]
    fov = np.array([float(frames[i]["fov"]) for i in idx])  # [F] vertical, degrees
    if not np.all((fov > 0) & (fov < 180)):
        raise InvalidInputError("camera path fov must be in (0, 180) degrees.")
    focal = (height / 2.0) / np.tan(np.deg2rad(fov) / 2.0)  # three_js_perspective_camera_focal_length
    intr = np.stack([focal, focal, np.full_like(focal, width / 2.0), np.full_like(focal, height / 2.0)], -1)
    return PreviewCameras(viewmat_from_c2w(c2w), intr, idx, int(width), int(height), float(fps))

