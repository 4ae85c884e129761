"""Camera-path export for ``ns-render camera-path`` and the viewer's Render tab "Load Path".

Files go where nerfstudio's render panel writes them: ``<data>/camera_paths/<name>.json``
(``nerfstudio/viewer/render_panel.py``), so the Render tab lists them.

``camera_path_from_shot`` is the viewer's own exporter, used when the planner's
``cinenerf_ns.planner.camera_path.shot_to_camera_path`` is not importable; both write the same
keys nerfstudio reads (``get_path_from_json``: camera_path[i].camera_to_world/fov/aspect,
render_height/width, camera_type; Render tab: keyframes[i].matrix/fov/aspect, default_transition_sec).
"""
from __future__ import annotations

import json
import os
import re
import tempfile
from pathlib import Path
from typing import Any, Callable, Dict, Optional

import numpy as np

from cinenerf_ns.planner.errors import InvalidInputError

from .backend import to_numpy

Exporter = Callable[[Any, float, int, int, int], Dict[str, Any]]  # (shot, fov_deg, width, height, fps) -> dict

_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")


def check_export_name(name: str) -> str:
    """A camera-path name becomes a file name: letters, digits, '.', '_', '-' only."""
    name = (name or "").strip()
    if name.endswith(".json"):
        name = name[: -len(".json")]
    if not _NAME_RE.match(name):
        raise InvalidInputError(
            f"camera path name '{name}' is not a plain file name: use letters, digits, '.', '_' or '-'"
        )
    return name


def default_exporter() -> Exporter:
    """The planner's exporter when it exists (one source of truth), else :func:`camera_path_from_shot`."""
    try:
        from cinenerf_ns.planner.camera_path import shot_to_camera_path  # type: ignore

        return lambda shot, fov, w, h, fps: shot_to_camera_path(shot, fov_deg=fov, width=w, height=h, fps=fps)
    except Exception:  # planner module not there yet (parallel development) -> local exporter
        return camera_path_from_shot


def _resample(times: np.ndarray, positions: np.ndarray, rotations: np.ndarray, fps: int):
    from .conventions import interpolate_pose

    duration = float(times[-1] - times[0])
    n = max(int(round(duration * fps)), 1) + 1
    ts = times[0] + np.arange(n) / fps
    ts = np.minimum(ts, times[-1])
    return ts, np.stack([interpolate_pose(times, positions, rotations, t) for t in ts])  # [F, 3, 4]


def camera_path_from_shot(shot: Any, fov_deg: float, width: int, height: int, fps: int) -> Dict[str, Any]:
    """Shot (times [T], positions [T,3], rotations [T,3,3] nerfstudio c2w) -> nerfstudio camera-path dict.

    Frames are resampled at ``fps`` over the shot's real duration; ~2 keyframes per second (at least 2)
    are added for the Render tab, with ``default_transition_sec`` so its spline lasts as long as the shot."""
    times = to_numpy(shot.times).reshape(-1)
    positions = to_numpy(shot.positions).reshape(-1, 3)
    rotations = to_numpy(shot.rotations).reshape(-1, 3, 3)
    if len(times) < 2 or not np.all(np.diff(times) > 0):
        raise InvalidInputError("a shot needs at least 2 samples with increasing times to export")
    if width <= 0 or height <= 0 or fps <= 0 or not (0 < fov_deg < 180):
        raise InvalidInputError(f"bad render settings: {width}x{height} px, {fps} fps, fov {fov_deg} deg")
    aspect = width / height
    _, c2ws = _resample(times, positions, rotations, fps)
    bottom = np.array([[0.0, 0.0, 0.0, 1.0]])

    def mat(c2w: np.ndarray) -> list:
        return np.concatenate([c2w, bottom], 0).reshape(-1).tolist()

    duration = float(times[-1] - times[0])
    n_key = max(2, int(np.ceil(duration * 2)) + 1)
    key_t = np.linspace(times[0], times[-1], n_key)
    from .conventions import interpolate_pose

    keyframes = [
        {
            "matrix": mat(interpolate_pose(times, positions, rotations, t)),
            "fov": float(fov_deg),
            "aspect": aspect,
            "override_transition_enabled": False,
            "override_transition_sec": None,
        }
        for t in key_t
    ]
    return {
        "default_fov": float(fov_deg),
        "default_transition_sec": duration / (n_key - 1),
        "keyframes": keyframes,
        "camera_type": "perspective",
        "render_height": int(height),
        "render_width": int(width),
        "fps": int(fps),
        "seconds": duration,
        "is_cycle": False,
        "smoothness_value": 0.0,
        "camera_path": [{"camera_to_world": mat(c), "fov": float(fov_deg), "aspect": aspect} for c in c2ws],
    }


def write_json_atomic(path: Path, data: Dict[str, Any]) -> Path:
    """Write JSON to ``path`` so readers never see a half-written file: serialise fully first (an
    unserialisable value fails before the disk is touched), write a temp file beside it, fsync,
    then ``os.replace`` (atomic on POSIX)."""
    text = json.dumps(data, indent=1, allow_nan=False)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


def render_command(config_path: Optional[Path], json_path: Path, data_name: str, name: str) -> str:
    """The ``ns-render`` command nerfstudio's Render tab shows for the same file."""
    cfg = str(config_path) if config_path is not None else "<path/to/your/run/config.yml>"
    return " ".join(
        [
            "ns-render camera-path",
            f"--load-config {cfg}",
            f"--camera-path-filename {Path(json_path).absolute()}",
            f"--output-path renders/{data_name}/{name}.mp4",
        ]
    )
