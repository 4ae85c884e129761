"""What leaves the panel: the exported camera path (for ``ns-render`` / the Render tab) and the preview video.

A mixin of :class:`~.panel.CinePanel` (it uses the panel's ``config``, ``view``, ``shot``, ``selected``,
``exporter``, ``previewer`` and status). Exports never overwrite: a taken name gets a numbered suffix, and the
status says so. The preview renders the selected candidate on its own thread (CPU, ``cinenerf_ns.preview``): the
status says "Rendering..." then where the video is, and the view offers it for download.
"""
from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Any, Callable, Dict, Optional

from cinenerf_ns.planner.errors import InvalidInputError

from .export import check_export_name, command_lines, render_command, unique_json_path, write_json_atomic
from .panel_types import ExportResult

log = logging.getLogger(__name__)

# (camera-path dict, out_dir, name, width, height, fps) -> the written video's path
Previewer = Callable[[Dict[str, Any], Path, str, int, int, int], Path]


class OutputMixin:
    """Export and preview of the selected candidate."""

    def _init_output(self) -> None:
        self._preview_thread: Optional[threading.Thread] = None
        self.last_preview: Optional[Path] = None

    # ------------------------------------------------------------------ export
    def _camera_path(self, shot: Any, fps: int, width: int, height: int) -> Dict[str, Any]:
        """The nerfstudio camera-path dict of ``shot``, re-timed to ``fps`` (ns-render plays frames at the file's
        own rate: re-time, never relabel)."""
        if hasattr(shot, "resampled"):
            shot = shot.resampled(fps)
        return self.exporter(shot, self.config.fov_deg, width, height, fps)

    def export(self, name: str) -> Optional[ExportResult]:
        """Write the selected shot to ``<data>/camera_paths/<name>.json`` (absolute; ``<name>-2`` ... when taken) and
        show the ``ns-render`` command with the run's config.yml, or why there is none. None (and an error status)
        on failure."""
        try:
            name = check_export_name(name)
            shot = self.shot
            if shot is None:
                raise InvalidInputError("nothing to export: press Plan first")
            cfg = self.config
            data = self._camera_path(shot, cfg.fps, cfg.render_width, cfg.render_height)
            path, used = unique_json_path(Path(cfg.data_dir) / "camera_paths", name)
            path = write_json_atomic(path, data).absolute()
            command = render_command(cfg.config_path, path, Path(cfg.data_dir).name, used)
        except BaseException as err:
            self._fail("Export", err)
            return None
        renamed = None if used == name else name
        if command is not None:
            how = f"Render it with:\n\n```\n{command_lines(command)}\n```"
        else:
            what = cfg.scene_note or "this scene has no nerfstudio run"
            how = (f"No `ns-render` command: {what}, and `ns-render` needs the run's config.yml. Load the run's "
                   f"config.yml to get one, or press **Preview video** for a CPU preview.")
        self._call_view("show_export", path, f"Camera path: `{path}`\n\n{how}")
        note = f" ('{renamed}.json' already exists, so this one is '{used}.json')" if renamed else ""
        self._set_status(f"Exported candidate {self.selected + 1}{note}; the file and how to render it are below.",
                         "ok")
        return ExportResult(path, command, renamed)

    # ------------------------------------------------------------------ preview
    @property
    def preview_running(self) -> bool:
        th = self._preview_thread
        return th is not None and th.is_alive()

    def preview(self, name: str) -> Optional[threading.Thread]:
        """Render the selected candidate to ``<data>/previews/<name>[-k].mp4`` on a background thread. Returns the
        thread (None when nothing starts: no previewer, no shot, a preview already running; the status says why)."""
        try:
            name = check_export_name(name)
            if self.previewer is None:
                raise InvalidInputError("this viewer has no preview renderer; export the path and use ns-render")
            shot = self.shot
            if shot is None:
                raise InvalidInputError("nothing to preview: press Plan first")
            if self.preview_running:
                raise InvalidInputError("a preview is already rendering; wait for it to finish")
            cfg = self.config
            data = self._camera_path(shot, cfg.preview_fps, cfg.preview_width, cfg.preview_height)
            out_dir = Path(cfg.data_dir) / "previews"
            stem = unique_json_path(out_dir, name, ".mp4")[1]
        except BaseException as err:
            self._fail("Preview", err)
            return None
        which = self.selected + 1
        self._call_view("show_preview", None)
        self._set_status(f"Rendering a {cfg.preview_width}x{cfg.preview_height} preview of candidate {which} "
                         f"(CPU, in the background)...", "busy")
        th = threading.Thread(target=self._preview_job, args=(data, out_dir, stem, which, self._generation),
                              name="cine-preview",
                              daemon=True)
        self._preview_thread = th
        th.start()
        return th

    def _preview_job(self, data: Dict[str, Any], out_dir: Path, stem: str, which: int, generation: int) -> None:
        cfg = self.config
        try:
            path = Path(self.previewer(data, out_dir, stem, cfg.preview_width, cfg.preview_height,
                                       cfg.preview_fps)).absolute()
            if not path.is_file():
                raise InvalidInputError(f"the preview renderer wrote no video at {path}")
        except BaseException as err:
            self._fail("Preview", err)
            return
        self.last_preview = path
        self._call_view("show_preview", path)
        old = "" if generation == self._generation else " (of the previous plan)"
        self._set_status(f"Preview of candidate {which}{old} written: {path}", "ok")

    def _close_output(self) -> None:
        th = self._preview_thread
        if th is not None and th.is_alive():
            th.join(timeout=60.0)
