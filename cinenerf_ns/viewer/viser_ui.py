"""The panel's widgets and drawings on a viser server (the :class:`~.panel.PanelView` for viser).

Used by both the nerfstudio viewer adapter and the standalone viewer. Scene coordinates are drawn at
``scale`` times nerfstudio units (nerfstudio's viewer uses 10); cameras are converted with
:func:`~.conventions.nerfstudio_c2w_to_viser`.
"""
from __future__ import annotations

import logging
import threading
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

import numpy as np
import viser

from cinenerf_ns.planner.shots.camera_path import DEFAULT_FOV_DEG, DEFAULT_PREVIEW_SIZE, DEFAULT_RENDER_SIZE
from cinenerf_ns.planner.shots.framing import FRAMINGS

from .backend import to_numpy
from .conventions import VISER_NERFSTUDIO_SCALE_RATIO, nerfstudio_c2w_to_viser, viser_to_world
from .panel import (
    MAX_PANEL_CANDIDATES,
    CinePanel,
    DisplayOptions,
    PanelBackend,
    PanelConfig,
    ServerLimits,
    Shot,
    Target,
    min_clearance,
)
from .panel_output import Previewer
from .polytope_mesh import polytope_mesh
from .region_box import RegionInfo
from .region_ui import RegionWidgets
from .safe_text import md_code_block, md_escape
from .shot_text import SCORE_RULE
from .views import TrainingCameras, View, highlight_box, opening_view, overview_view

log = logging.getLogger(__name__)

_LEVEL_ICON = {"info": "", "busy": "⏳ ", "ok": "✅ ", "warn": "⚠️ ", "error": "❌ "}
_TARGET_COLOR = {"Go to": (40, 220, 90), "Look at": (255, 150, 20)}
_NO_CANDIDATES = "(plan first)"


class ViserPanelUI:
    """Builds the "Cinematography" GUI folder and implements ``PanelView`` on ``server``: for one browser page
    (``client``: its own widgets, drawings and camera, through viser's per-client ``client.gui`` / ``client.scene``),
    or with ``client`` None on the server scope, shared by every page (scripts and tests).

    Every text shown in markdown goes through :func:`~.safe_text.md_escape` (viser renders markdown with raw HTML):
    the panel's status, details and export texts are plain text that may hold what a user typed."""

    def __init__(
        self,
        server: viser.ViserServer,
        scale: float = VISER_NERFSTUDIO_SCALE_RATIO,
        scene_extent: float = 2.0,
        fov_deg: float = DEFAULT_FOV_DEG,
        aspect: float = DEFAULT_RENDER_SIZE[0] / DEFAULT_RENDER_SIZE[1],
        default_goto: str = "",
        default_look_at: str = "",
        folder_label: str = "Cinematography",
        root: str = "/cine",
        n_candidates: int = 3,
        export_name: str = "shot",
        preview_size: Tuple[int, int] = DEFAULT_PREVIEW_SIZE,
        client: Any = None,
    ) -> None:
        self.server = server
        self.client = client
        api = client if client is not None else server
        self.scene = api.scene
        self.scale = float(scale)
        self.root = root
        self.fov_deg, self.aspect = fov_deg, aspect
        self.fov_rad = float(np.deg2rad(fov_deg))
        self.unit = max(scene_extent, 1e-3) * self.scale * 0.01  # 1% of the scene, in viser units
        self.gaussian_means: Optional[np.ndarray] = None  # [N, 3] scene units, for highlighting
        self._draw_lock = threading.RLock()
        self._nodes: Dict[str, List[Any]] = {"shot": [], "targets": []}
        self.camera_updates = 0
        self.panel: Optional[CinePanel] = None
        self.home: Optional[View] = None  # the opening view (scene units); set by attach_cine_panel
        self.overview: Optional[View] = None  # the top-down overview
        self.preview_path: Optional[Path] = None
        # scene nodes hidden while the top-down overview is on: the standalone viewer's Gaussians above the start
        # region (a room's ceiling), which would hide the path and frustums from above (see draw_shot)
        self.overview_hides: List[Any] = []
        self.status_text, self.details_text = "", ""  # the texts the markdown widgets show, before escaping

        gui = api.gui
        with gui.add_folder(folder_label):
            self.goto = gui.add_text("Go to", default_goto, hint="An object ('the chair') or coordinates 'x y z'")
            self.look_at = gui.add_text("Look at", default_look_at, hint="An object or coordinates 'x y z'")
            self.n_candidates = gui.add_number("Candidates", n_candidates, min=1, max=MAX_PANEL_CANDIDATES, step=1,
                                               hint="Shots planned from different random starts")
            self.framing = gui.add_dropdown("Framing", list(FRAMINGS), initial_value="medium",
                                            hint="How large the look-at object is in the last frame (wide 0.15-0.35, "
                                                 "medium 0.35-0.6, close 0.6-0.85 of the frame)")
            self.from_camera = gui.add_checkbox("Start at my camera", False,
                                                hint="Plan from the current browser camera instead of a random start")
            self.plan_button = gui.add_button("Plan", icon=viser.Icon.ROUTE, color="green")
            self.new_start_button = gui.add_button("New random start", icon=viser.Icon.DICE)
            self.candidate = gui.add_dropdown("Candidate", [_NO_CANDIDATES],
                                              hint=f"Best first: sorted by score, {SCORE_RULE}")
            self.play_button = gui.add_button("Play", icon=viser.Icon.PLAYER_PLAY_FILLED)
            self.pause_button = gui.add_button("Pause", icon=viser.Icon.PLAYER_PAUSE_FILLED, visible=False)
            self.speed = gui.add_slider("Speed", min=0.25, max=4.0, step=0.25, initial_value=1.0)
            self.loop = gui.add_checkbox("Loop", False)
            with gui.add_folder("Show", expand_by_default=False):
                self.show_path = gui.add_checkbox("Path + frustums", True)
                self.show_targets = gui.add_checkbox("Selected objects", True)
                self.show_corridor = gui.add_checkbox("Safe corridor", False)
                self.show_clearance = gui.add_checkbox("Closest approach", False,
                                                       hint="Where the shot passes closest to the scene, and how close")
                self.overview_box = gui.add_checkbox("Top-down overview", False,
                                                     hint="See the whole scene from above; untick to go back inside")
            self.region = RegionWidgets(gui, self.scene, self.scale, root)
            self.status_md = gui.add_markdown("Type where the camera should go and what it should look at, then Plan.")
            self.export_name = gui.add_text("Export name", export_name,
                                            hint="File name; a taken name gets -2, -3, ... (nothing is overwritten)")
            self.export_button = gui.add_button("Export camera path", icon=viser.Icon.FILE_EXPORT)
            self.export_info = gui.add_markdown("", visible=False)
            self.preview_button = gui.add_button("Preview video", icon=viser.Icon.MOVIE, visible=False,
                                                 hint="Render the selected candidate on the CPU "
                                                      f"({preview_size[0]}x{preview_size[1]})")
            self.preview_download = gui.add_button("Download preview", icon=viser.Icon.DOWNLOAD, visible=False)
            with gui.add_folder("Details", expand_by_default=False):
                self.details_md = gui.add_markdown("(plan first)")

    # ------------------------------------------------------------------ wiring
    def attach(self, panel: CinePanel) -> None:
        """Connect widgets to ``panel`` (callbacks only request work; the panel runs it on its threads)."""
        self.panel = panel
        p = panel

        def guarded(fn):
            def cb(event: viser.GuiEvent) -> None:
                try:
                    fn(event)
                except Exception as err:  # never raise into viser's callback thread
                    p._fail("Panel", err)

            return cb

        self.plan_button.on_click(guarded(lambda e: p.request_plan(
            self.goto.value, self.look_at.value, n_candidates=int(self.n_candidates.value),
            start_from_camera=bool(self.from_camera.value), framing=str(self.framing.value))))
        self.new_start_button.on_click(guarded(lambda e: p.request_plan(
            self.goto.value, self.look_at.value, n_candidates=int(self.n_candidates.value), new_start=True,
            framing=str(self.framing.value))))
        self.play_button.on_click(guarded(lambda e: p.play()))
        self.pause_button.on_click(guarded(lambda e: p.pause()))
        self.speed.on_update(guarded(lambda e: p.set_speed(float(self.speed.value))))
        self.loop.on_update(guarded(lambda e: p.set_loop(bool(self.loop.value))))
        self.export_button.on_click(guarded(lambda e: p.export(self.export_name.value)))
        self.preview_button.visible = p.previewer is not None
        self.preview_button.on_click(guarded(lambda e: p.preview(self.export_name.value)))
        self.preview_download.on_click(guarded(self._send_preview))
        self.overview_box.on_update(guarded(lambda e: self.show_overview(bool(self.overview_box.value))))
        self.region.attach(p, guarded)

        @self.candidate.on_update
        def _(event: viser.GuiEvent) -> None:
            if event.client is None:  # set by show_candidates (server side), not by the user
                return
            value = self.candidate.value
            if value != _NO_CANDIDATES:
                p.select(int(value.split(":")[0]) - 1)

        for box, key in [(self.show_path, "show_path"), (self.show_targets, "show_targets"),
                         (self.show_corridor, "show_corridor"), (self.show_clearance, "show_clearance")]:
            box.on_update(guarded(lambda e, box=box, key=key: p.set_display(**{key: bool(box.value)})))
        p.options = DisplayOptions(self.show_path.value, self.show_targets.value,
                                   self.show_corridor.value, self.show_clearance.value)

    # ------------------------------------------------------------------ PanelView
    def set_status(self, text: str, level: str) -> None:
        self.status_text = text  # plain, as the panel said it
        self.status_md.content = f"{_LEVEL_ICON.get(level, '')}{md_escape(text)}"

    def show_inputs(self, goto: str, look_at: str) -> None:
        """The boxes show what the server plans with. viser's client sends all GUI updates through one 50 ms throttle
        that keeps only the latest message, so an edit followed within 50 ms by another edit (or a click) never
        reaches the server while the box still shows it; re-sending the server's values makes every box show them."""
        for handle, value in ((self.goto, goto), (self.look_at, look_at)):
            handle.value = value  # the server's state
            push_value(handle)  # and on every screen, whatever the client showed

    def show_region(self, info: RegionInfo) -> None:
        self.region.show_region(info)

    def draw_region(self, info: Optional[RegionInfo]) -> None:
        self.region.draw_region(info)

    def show_details(self, text: str) -> None:
        self.details_text = text or "(plan first)"  # plain, as the panel said it
        self.details_md.content = md_escape(self.details_text)

    def show_preview(self, path: Optional[Path]) -> None:
        self.preview_path = path
        self.preview_download.visible = path is not None

    def _send_preview(self, event: viser.GuiEvent) -> None:
        path = self.preview_path
        if path is None or event.client is None:
            return
        if self.client is not None and event.client.client_id != self.client.client_id:
            return  # only this page's own preview, to this page
        event.client.send_file_download(path.name, path.read_bytes())

    def go_to_view(self, view: Optional[View], client: Any = None) -> None:
        """Move ``client``'s camera (when None: this page's, or every page's on the server scope) to ``view`` (scene
        units; its up becomes the orbit's up)."""
        if view is None:
            return
        clients = [client or self.client] if (client or self.client) is not None else self._clients()
        for c in clients:
            try:
                with c.atomic():
                    c.camera.position = np.asarray(view.position) * self.scale
                    c.camera.look_at = np.asarray(view.look_at) * self.scale
                    c.camera.up_direction = np.asarray(view.up, np.float64)
            except Exception:
                log.debug("moving client %s to a view failed", getattr(c, "client_id", "?"), exc_info=True)

    def _clients(self) -> List[Any]:
        """The pages this view moves: its own, or on the server scope every connected one."""
        if self.client is not None:
            return [self.client]
        return list(self.server.get_clients().values())

    def show_overview(self, on: bool) -> None:
        """The "Top-down overview" toggle: this page's camera (every page's on the server scope) to the overview
        (``on``) or back home; ``overview_hides`` (server nodes) hidden while it is on: for this page alone (a
        visibility message on its own connection; the server's state, and so every other page, keeps them), or on
        the server scope for every page."""
        from viser import _messages as vm

        for h in self.overview_hides:
            try:
                if self.client is None:
                    h.visible = not on
                else:  # owner "": the server's node, seen by this page only
                    self.client._websock_connection.queue_message(vm.SetSceneNodeVisibilityMessage(h.name, not on))
            except Exception:
                log.debug("(un)hiding %s for the overview failed", getattr(h, "name", "?"), exc_info=True)
        self.go_to_view(self.overview if on else self.home)

    def show_candidates(self, labels: List[str], selected: int) -> None:
        opts = list(labels) or [_NO_CANDIDATES]
        self.candidate.options = opts
        self.candidate.value = opts[selected]

    def set_playing(self, playing: bool) -> None:
        self.play_button.visible = not playing
        self.pause_button.visible = playing

    def show_export(self, path: Optional[Path], text: str, command: Optional[str] = None) -> None:
        shown = md_escape(text) + (f"\n\n{md_code_block(command)}" if command else "")
        self.export_info.content = shown if path is not None else ""
        self.export_info.visible = path is not None

    def set_camera(self, c2w: np.ndarray) -> int:
        wxyz, pos = nerfstudio_c2w_to_viser(np.asarray(c2w), self.scale)
        moved = 0
        for client in self._clients():
            try:
                with client.atomic():
                    # preview with the export's vertical fov, as nerfstudio's Render-tab preview does
                    client.camera.fov = self.fov_rad
                    client.camera.wxyz = wxyz
                    client.camera.position = pos
                moved += 1
            except AssertionError:
                pass  # this client has not sent its first camera yet
            except Exception:
                log.debug("camera update for client %s failed", client.client_id, exc_info=True)
        self.camera_updates += 1
        return moved

    def camera_position(self) -> Optional[np.ndarray]:
        """This page's camera (on the server scope: the first page's), scene units; None when unknown or not
        finite."""
        for client in self._clients():
            try:
                p = viser_to_world(np.asarray(client.camera.position, np.float64), self.scale)
            except AssertionError:
                continue
            return p if np.all(np.isfinite(p)) else None
        return None

    # ------------------------------------------------------------------ drawing
    def _clear(self, group: str) -> None:
        for h in self._nodes[group]:
            try:
                h.remove()
            except Exception:
                pass
        self._nodes[group] = []

    def _means_for(self, mask: Optional[np.ndarray]) -> Optional[np.ndarray]:
        """Gaussian means matching ``mask``'s length (training changes N: refetch from the backend)."""
        if mask is None:
            return None
        if self.gaussian_means is None or len(self.gaussian_means) != len(mask):
            if self.panel is None:
                return None
            self.gaussian_means = to_numpy(self.panel.backend.gaussians().means)
        return self.gaussian_means if len(self.gaussian_means) == len(mask) else None

    def draw_targets(self, targets: List[Target], options: DisplayOptions) -> None:
        """Each matched object as a wireframe box with a faint fill (the splat stays visible through it) and a label
        saying what the query matched; typed coordinates as a small box."""
        with self._draw_lock:
            self._clear("targets")
            if not options.show_targets:
                return
            add = self._nodes["targets"].append
            for i, t in enumerate(targets):
                color = _TARGET_COLOR.get(t.role, (200, 200, 200))
                base = f"{self.root}/targets/{i}"
                means = self._means_for(t.mask)
                if means is not None and t.mask.any():
                    centre, size = highlight_box(means[t.mask])  # [3], [3] scene units
                else:
                    centre, size = np.asarray(t.point, np.float64), np.full(3, 2.0 * self.unit / self.scale)
                kw = dict(color=color, dimensions=tuple(np.maximum(size, 1e-4) * self.scale),
                          position=tuple(centre * self.scale))
                add(self.scene.add_box(f"{base}/outline", wireframe=True, **kw))
                add(self.scene.add_box(f"{base}/fill", opacity=0.12, cast_shadow=False, receive_shadow=False,
                                              **kw))
                top = centre + np.array([0.0, 0.0, size[2] / 2])
                what = f" ({t.count} Gaussians)" if t.count is not None else ""
                text = t.text if len(t.text) <= 60 else f"{t.text[:57]}..."  # the status has it whole
                add(self.scene.add_label(f"{base}/label", f"{t.role}: {text}{what}",
                                                position=top * self.scale))

    def draw_shot(self, shot: Optional[Shot], options: DisplayOptions) -> None:
        """The path (a spline), 8 camera frustums along it (white at the ends) and labels at its start and end; the
        corridor and the closest approach when asked.

        Draw order: viser 1.1.1 draws Gaussian splats after every other scene node (client renderOrders.ts,
        SPLAT_RENDER_ORDER; depth-tested, not depth-writing) and gives lines, splines, frustums and meshes no render
        order or depth-test option, so a splat Gaussian in front of the path covers it. Labels alone are drawn after
        splats, with depth_test=False (LABEL_*_RENDER_ORDER): the shot's start and end are labelled that way, so they
        show through anything in front; the top-down overview hides what lies above the start region (a ceiling,
        ``overview_hides``)."""
        with self._draw_lock:
            self._clear("shot")
            if shot is None:
                return
            add = self._nodes["shot"].append
            pos = to_numpy(shot.positions)  # [T, 3]
            rot = to_numpy(shot.rotations)  # [T, 3, 3]
            base = f"{self.root}/shot"
            if options.show_path:
                idx = np.unique(np.linspace(0, len(pos) - 1, min(len(pos), 300)).round().astype(int))
                add(self.scene.add_spline_catmull_rom(
                    f"{base}/path", points=pos[idx] * self.scale, color=(255, 60, 200),
                    thickness=3.0, thickness_units="screen"))
                n_fr = min(8, len(pos))
                for j, i in enumerate(np.linspace(0, len(pos) - 1, n_fr).round().astype(int)):
                    wxyz, p = nerfstudio_c2w_to_viser(np.c_[rot[i], pos[i]], self.scale)
                    add(self.scene.add_camera_frustum(
                        f"{base}/frustum_{j}", fov=np.deg2rad(self.fov_deg), aspect=self.aspect,
                        scale=1.5 * self.unit, color=(255, 60, 200) if 0 < j < n_fr - 1 else (255, 255, 255),
                        wxyz=wxyz, position=p, thickness=1.5, thickness_units="screen"))
                for end, i in (("start", 0), ("end", len(pos) - 1)):  # over the splat, whatever stands in front
                    add(self.scene.add_label(f"{base}/{end}_label", f"shot {end}", position=pos[i] * self.scale,
                                                    depth_test=False, anchor="bottom-center"))
            if options.show_corridor:
                self._draw_corridor(shot, base)
            if options.show_clearance:  # one label, where it matters: the closest approach
                i, text = closest_approach(shot)
                add(self.scene.add_label(f"{base}/clearance_min", text, position=pos[i] * self.scale))

    def _draw_corridor(self, shot: Shot, base: str) -> None:
        polys = None if shot.corridor is None else shot.corridor.polytopes
        if not polys:
            self._nodes["shot"].append(self.scene.add_label(
                f"{base}/corridor_none", "(this planner gave no corridor)",
                position=to_numpy(shot.positions)[0] * self.scale))
            return
        for k, poly in enumerate(polys):
            mesh = polytope_mesh(to_numpy(poly.A), to_numpy(poly.b), to_numpy(poly.seed).reshape(-1, 3).mean(0))
            if mesh is None:
                continue
            verts, faces = mesh
            self._nodes["shot"].append(self.scene.add_mesh_simple(
                f"{base}/corridor_{k}", vertices=(verts * self.scale).astype(np.float32), faces=faces,
                color=(80, 170, 255), opacity=0.06, side="double", cast_shadow=False, receive_shadow=False))


def push_value(handle: Any) -> None:
    """Make every client show ``handle``'s server value, even where the client shows something else that never
    reached the server. The box goes through a different value first (two messages, flushed apart so the server's
    buffer does not merge them): this is the form the browser test checks; re-sending only the equal value was not
    tested on its own."""
    value = handle.value
    handle.value = value + " "  # differs from the value: the client applies it
    handle._impl.gui_api._websock_interface.get_message_buffer().flush()  # the server's, or one page's buffer
    handle.value = value


def closest_approach(shot: Shot) -> "tuple[int, str]":
    """(frame index, label) of the shot's minimum clearance: the per-frame ``clearance`` [T] when given, else the
    shot's reported minimum at the path's middle."""
    if shot.clearance is not None and shot.clearance.size:
        c = to_numpy(shot.clearance).reshape(-1)  # [T]
        i = int(np.argmin(c))
        return i, f"closest approach {c[i]:.3f}"
    m = min_clearance(shot)
    return len(to_numpy(shot.positions)) // 2, f"min clearance {'n/a' if m is None else f'{m:.3f}'}"


class ClientPanels:
    """One panel per browser page: each page gets its own widgets, texts, candidates, chosen shot, status, drawings
    and camera animation (viser's per-client ``client.gui`` / ``client.scene``, built in ``on_client_connect``), so a
    page never changes another's. What they share: the backend, the opening views, and ``limits`` (plans one at a
    time over all pages, one preview render, a budget of files written, at most ``limits.max_clients`` pages).

    ``set_status`` says something to every page (loading, the planner's preparation) until a page's own Plan owns
    its status line; pages that open later start with it."""

    def __init__(self, server: viser.ViserServer, backend: PanelBackend, config: PanelConfig, exporter=None,
                 previewer: Optional[Previewer] = None, limits: Optional[ServerLimits] = None,
                 **ui_kwargs: Any) -> None:
        self.server, self.backend, self.config = server, backend, config
        self.exporter, self.previewer = exporter, previewer
        self.limits = limits or ServerLimits()
        self.ui_kwargs = ui_kwargs
        self.status, self.status_level, self.details = "", "info", ""
        self.gaussian_means: Optional[np.ndarray] = None
        self.home: Optional[View] = None
        self.overview: Optional[View] = None
        self.overview_hides: List[Any] = []
        self.panels: Dict[int, CinePanel] = {}
        # the planner's planning region (region_box.RegionSource, shared by every page), when the backend has one
        self.region_source = getattr(backend, "region_source", None)
        self.refused: List[int] = []  # pages turned away (too many open)
        self._lock = threading.Lock()
        self._server_panel: Optional[CinePanel] = None
        self._closed = False

    def listen(self) -> "ClientPanels":
        """Build a panel for each page that opens (and those already open), close it when the page leaves."""
        self.server.on_client_connect(self._connect)
        self.server.on_client_disconnect(self._disconnect)
        if self.region_source is not None:  # a region applied on one page: every page's fold and box follow
            self.region_source.add_region_listener(self.region_changed)
        return self

    def use_home_as_initial_camera(self) -> None:
        """Make the opening view (``home``) viser's initial camera: where a browser that connects starts and where
        its "Reset View" returns (the standalone viewer; inside ns-viewer, nerfstudio keeps its own)."""
        if self.home is None:
            return
        cam = self.server.initial_camera
        cam.up = np.asarray(self.home.up, np.float64)
        cam.position = np.asarray(self.home.position, np.float64) * self.ui_kwargs.get("scale", 1.0)
        cam.look_at = np.asarray(self.home.look_at, np.float64) * self.ui_kwargs.get("scale", 1.0)

    def make(self, client: Any = None) -> CinePanel:
        """A panel on ``client``'s page (None: on the server scope, shown to every page: scripts and tests)."""
        ui = ViserPanelUI(self.server, client=client, **self.ui_kwargs)
        ui.gaussian_means, ui.home, ui.overview = self.gaussian_means, self.home, self.overview
        ui.overview_hides = self.overview_hides
        panel = CinePanel(self.backend, ui, self.config, self.exporter, self.previewer, self.limits)
        panel.region_source = self.region_source
        ui.attach(panel)
        panel.region_changed()
        if self.status:
            panel._set_status(self.status, self.status_level)
        if self.details:
            panel._call_view("show_details", self.details)
        return panel

    def server_panel(self) -> CinePanel:
        """The one panel on the server scope (made on first use): every page sees it. For scripts and tests; the
        viewers give each page its own."""
        with self._lock:
            if self._server_panel is None:
                self._server_panel = self.make(None)
            return self._server_panel

    def all(self) -> List[CinePanel]:
        with self._lock:
            return list(self.panels.values()) + ([self._server_panel] if self._server_panel is not None else [])

    def _connect(self, client: Any) -> None:
        with self._lock:
            full = len(self.panels) >= self.limits.max_clients
            if full:
                self.refused.append(client.client_id)
        if self._closed:
            return
        if full:
            client.gui.add_markdown(f"This viewer already serves {self.limits.max_clients} pages, its limit: close "
                                    "another page, then reload this one.")
            return
        try:
            panel = self.make(client)
        except Exception:  # a page that left while its panel was built: expected; any other failure: said
            gone = client.client_id not in self.server.get_clients()
            (log.debug if gone else log.warning)("building the panel of page %s failed%s", client.client_id,
                                                 " (the page had left)" if gone else "", exc_info=True)
            return
        with self._lock:
            self.panels[client.client_id] = panel
        panel.view.go_to_view(self.overview if panel.view.overview_box.value else self.home)

    def _disconnect(self, client: Any) -> None:
        with self._lock:
            panel = self.panels.pop(client.client_id, None)
        if panel is not None:  # stops its animation and plan worker; joins off viser's threads
            threading.Thread(target=panel.close, name="cine-panel-close", daemon=True).start()

    def set_status(self, text: str, level: str = "info", details: Optional[str] = None) -> None:
        """Say ``text`` to every page whose own Plan does not own its status yet (errors: to every page)."""
        self.status, self.status_level = text, level
        if details is not None:
            self.details = details
        for p in self.all():
            if (p.state == p.IDLE and not p.planned_before) or level == "error":
                p._set_status(text, level)
                if details is not None:
                    p._call_view("show_details", details)

    def region_changed(self) -> None:
        """The planner's region or its state changed: every page's fold and box (and status, see
        RegionMixin.region_changed) follow."""
        if not self._closed:
            for p in self.all():
                p.region_changed()

    def close(self) -> None:
        self._closed = True
        for p in self.all():
            p.close()


def attach_cine_panel(
    server: viser.ViserServer,
    backend: PanelBackend,
    config: Optional[PanelConfig] = None,
    exporter=None,
    scale: float = VISER_NERFSTUDIO_SCALE_RATIO,
    default_goto: str = "",
    default_look_at: str = "",
    folder_label: str = "Cinematography",
    previewer: Optional[Previewer] = None,
    export_name: str = "shot",
    start_region=None,
    cameras: Optional[TrainingCameras] = None,
    limits: Optional[ServerLimits] = None,
) -> ClientPanels:
    """Give every browser page of ``server`` its own cinematography panel; returns the :class:`ClientPanels`.

    ``backend`` gives Gaussians / locate / plan (see :class:`PanelBackend`); coordinates are drawn at
    ``scale`` x scene units (10 inside nerfstudio's viewer). ``previewer`` enables "Preview video"; ``start_region``
    (lo [3], hi [3]) and ``cameras`` (the scene's training cameras) place the opening view (``home``) inside the
    captured region (:func:`~.views.opening_view`)."""
    cfg = config or PanelConfig()
    g = backend.gaussians()
    means = to_numpy(g.means)
    extent = float(np.linalg.norm(np.percentile(means, 98, axis=0)
                                  - np.percentile(means, 2, axis=0))) if len(means) else 2.0
    panels = ClientPanels(server, backend, cfg, exporter, previewer, limits, scale=scale, scene_extent=extent,
                          fov_deg=cfg.fov_deg, aspect=cfg.render_width / cfg.render_height,
                          default_goto=default_goto, default_look_at=default_look_at, folder_label=folder_label,
                          n_candidates=cfg.n_candidates, export_name=export_name,
                          preview_size=(cfg.preview_width, cfg.preview_height))
    panels.gaussian_means = means
    if len(means):
        panels.home, panels.overview = opening_view(means, start_region, cameras), overview_view(means, cfg.fov_deg)
    return panels.listen()
