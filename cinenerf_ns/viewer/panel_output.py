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

from .backend import to_numpy
from .export import check_export_name, command_lines, render_command, unique_json_path, write_json_unique
from .panel_types import ExportResult, Shot
from .safe_text import check_text, client_path

log = logging.getLogger(__name__)

# (camera-path dict, out_dir, name, width, height, fps) -> the written video's path
Previewer = Callable[[Dict[str, Any], Path, str, int, int, int], Path]


class OutputMixin:
    """Export and preview of the selected candidate."""

    def _init_output(self) -> None:
        self._preview_thread: Optional[threading.Thread] = None
        self.last_preview: Optional[Path] = None

    # ------------------------------------------------------------------ export
    def _camera_path(self, shot: Shot, fps: int, width: int, height: int) -> Dict[str, Any]:
        """The nerfstudio camera-path dict of ``shot``, re-timed to ``fps`` (ns-render plays frames at the file's
        own rate: re-time, never relabel)."""
        return self.exporter(shot.resampled(fps), self.config.fov_deg, width, height, fps)

    @property
    def output_root(self) -> Path:
        """Where exports and previews go: ``config.output_dir``, else ``config.data_dir``."""
        cfg = self.config
        return Path(cfg.output_dir if cfg.output_dir is not None else cfg.data_dir)

    def shown(self, path: Path) -> str:
        """A written file as clients see it: relative to the output folder's parent (or its name), never absolute."""
        return client_path(path, self.output_root.parent)

    def export(self, name: str) -> Optional[ExportResult]:
        """Write the selected shot to ``<output>/camera_paths/<name>.json`` (``<name>-2`` ... when taken, also when
        another client writes the same name at the same time) and show the ``ns-render`` command with the run's
        config.yml, or why there is none; clients are shown paths relative to the output folder's parent, never the
        server's absolute paths. None (and an error status) on failure."""
        try:
            name = check_export_name(check_text(name, "Export name"))
            shot = self.shot
            if shot is None:
                raise InvalidInputError("nothing to export: press Plan first")
            cfg = self.config
            data = self._camera_path(shot, cfg.fps, cfg.render_width, cfg.render_height)
            self.limits.reserve_file()
            path, used = write_json_unique(self.output_root / "camera_paths", name, data)
            path = path.absolute()
            self.limits.add_bytes(path.stat().st_size)
            log.info("exported %s", path)
            command = render_command(cfg.config_path, path, Path(cfg.data_dir).name, used)
        except BaseException as err:
            self._fail("Export", err)
            return None
        renamed = None if used == name else name
        shown_command = None
        if command is not None:
            how = "Render it with:"
            shown_command = command_lines(render_command(
                client_path(cfg.config_path), Path(self.shown(path)), Path(cfg.data_dir).name, used, absolute=False))
        else:
            what = cfg.scene_note or "this scene has no nerfstudio run"
            how = (f"No ns-render command: {what}, and ns-render needs the run's config.yml. Load the run's "
                   f"config.yml to get one, or press Preview video for a CPU preview.")
        self._call_view("show_export", path, f"Camera path: {self.shown(path)}. {how}", shown_command)
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
            times = to_numpy(shot.times).reshape(-1)
            duration = float(times[-1] - times[0]) if times.size else 0.0
            if not duration <= self.limits.max_preview_s:
                raise InvalidInputError(f"this shot lasts {duration:.1f} s; previews are rendered up to "
                                        f"{self.limits.max_preview_s:g} s (export it and use ns-render)")
            if not self.limits.try_start_preview():  # one render at a time over every client of this viewer
                raise InvalidInputError("a preview is already rendering on this viewer; wait for it to finish")
        except BaseException as err:
            self._fail("Preview", err)
            return None
        try:
            cfg = self.config
            data = self._camera_path(shot, cfg.preview_fps, cfg.preview_width, cfg.preview_height)
            self.limits.reserve_file()
            out_dir = self.output_root / "previews"
            stem = unique_json_path(out_dir, name, ".mp4")[1]  # unique: one preview renders at a time
        except BaseException as err:
            self.limits.end_preview()
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
        try:
            th.start()
        except BaseException as err:
            self.limits.end_preview()
            self._fail("Preview", err)
            return None
        return th

    def _preview_job(self, data: Dict[str, Any], out_dir: Path, stem: str, which: int, generation: int) -> None:
        cfg = self.config
        try:
            path = Path(self.previewer(data, out_dir, stem, cfg.preview_width, cfg.preview_height,
                                       cfg.preview_fps)).absolute()
            if not path.is_file():
                raise InvalidInputError(f"the preview renderer wrote no video named {path.name}")
            self.limits.add_bytes(sum(f.stat().st_size for f in path.parent.glob(f"{stem}*") if f.is_file()))
            log.info("preview written: %s", path)
        except BaseException as err:
            self._fail("Preview", err)
            return
        finally:
            self.limits.end_preview()
        self.last_preview = path
        self._call_view("show_preview", path)
        old = "" if generation == self._generation else " (of the previous plan)"
        self._set_status(f"Preview of candidate {which}{old} written: {self.shown(path)}. Download it below.", "ok")

    def _close_output(self) -> None:
        th = self._preview_thread
        if th is not None and th.is_alive():
            th.join(timeout=60.0)
