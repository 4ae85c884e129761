"""Camera-path export for ``ns-render camera-path`` and the viewer's Render tab "Load Path".

Files go where nerfstudio's render panel writes them: ``<data>/camera_paths/<name>.json``
(``nerfstudio/viewer/render_panel.py``), so the Render tab lists them.

The JSON itself is the planner's (``cinenerf_ns.planner.shots.camera_path``: one source of truth for the keys
nerfstudio reads: ``get_path_from_json``'s camera_path[i].camera_to_world/fov/aspect, render_height/width,
camera_type, seconds; the Render tab's keyframes[i].matrix/fov/aspect and transitions); files are written
atomically by its ``write_camera_path``.
"""
from __future__ import annotations

import os
import re
import shlex
import uuid
from pathlib import Path
from typing import Any, Callable, Dict, Optional, Tuple

from cinenerf_ns.planner.errors import InvalidInputError

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
    """The planner's camera-path exporter (shot, fov_deg, width, height, fps) -> dict."""
    from cinenerf_ns.planner.shots.camera_path import shot_to_camera_path

    return lambda shot, fov, w, h, fps: shot_to_camera_path(shot, fov_deg=fov, width=w, height=h, fps=fps)

def write_json_atomic(path: Path, data: Dict[str, Any]) -> Path:
    """Write JSON so readers never see a half-written file (the planner's ``write_camera_path``: serialised
    fully first, temp file beside it, fsync, ``os.replace``)."""
    from cinenerf_ns.planner.shots.camera_path import write_camera_path

    return write_camera_path(path, data)


def write_json_unique(folder: Path, name: str, data: Dict[str, Any]) -> Tuple[Path, str]:
    """Write ``data`` to ``folder/<name>.json``, or to the first free ``<name>-2.json``, ``<name>-3.json``, ... when
    taken: atomic (written whole to a hidden temporary file first) and unique under concurrency (the file is put in
    place with ``os.link``, which fails when the name exists: two writers of one name get two files, never one
    overwritten). Returns (path, the name used)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    tmp = folder / f".{name}.{uuid.uuid4().hex}.tmp"
    write_json_atomic(tmp, data)
    try:
        candidate, k = name, 1
        while True:
            path = folder / f"{candidate}.json"
            try:
                os.link(tmp, path)
                return path, candidate
            except FileExistsError:
                k += 1
                candidate = f"{name}-{k}"
    finally:
        tmp.unlink(missing_ok=True)


def unique_json_path(folder: Path, name: str, ext: str = ".json") -> Tuple[Path, str]:
    """(``folder/<name><ext>``, name) or, when that file exists, the first free ``<name>-2``, ``<name>-3``, ...:
    an export never overwrites an earlier one."""
    folder = Path(folder)
    candidate, k = name, 1
    while (folder / f"{candidate}{ext}").exists():
        k += 1
        candidate = f"{name}-{k}"
    return folder / f"{candidate}{ext}", candidate


def render_command(config_path: Optional[Path], json_path: Path, data_name: str, name: str,
                   absolute: bool = True) -> Optional[str]:
    """The ``ns-render`` command nerfstudio's Render tab shows for the same file, with the run's real config.yml
    (absolute paths unless ``absolute`` is False: the form shown to browsers); None when there is no run to render
    with (a compact export, a .ply, a procedural room)."""
    if config_path is None:
        return None

    def p(x) -> str:
        return shlex.quote(str(Path(x).absolute() if absolute else Path(x)))

    return " ".join(
        [
            "ns-render camera-path",
            f"--load-config {p(config_path)}",
            f"--camera-path-filename {p(json_path)}",
            f"--output-path {shlex.quote(str(Path('renders') / data_name / (name + '.mp4')))}",
        ]
    )


def command_lines(command: str) -> str:
    """The command broken before each option with shell line continuations: still one valid command when copied,
    and no line runs off a narrow panel."""
    return " \\\n  --".join(command.split(" --"))
