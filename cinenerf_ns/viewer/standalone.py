"""``cinesplat-viewer``: the cinematography panel on a plain viser server, no GPU needed.

The splat is drawn client-side by the browser (viser's Gaussian-splat node); planning runs on the
``--device`` (CPU by default) with the real planner (``cinenerf_ns.planner.shots.planner.Planner``).

    cinesplat-viewer --load-config outputs/<run>/cinesplat/<ts>/config.yml   # or the run folder / a .ckpt
    cinesplat-viewer --load-config scene_compact.pt   # a compact export (method.checkpoint.export_compact)
    cinesplat-viewer --load-config scene.ply          # a 3DGS / splatfacto-export .ply
    cinesplat-viewer --load-config procedural:20000   # generated test room with named objects
    cinesplat-viewer --load-config demo               # built-in labelled demo scene

Targets can always be typed as coordinates "x y z" (scene units). Text queries need semantics: a
cinesplat checkpoint / compact export with latents + codec (relevancy, ``method.semantic_scene``), or
the ground-truth names of the procedural / demo scenes. Scenes are loaded by ``cinesplat-plan``'s
loader, so the command line and the viewer plan around the same obstacles.
"""
from __future__ import annotations

import dataclasses
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, List, Optional, Tuple

import numpy as np
import tyro

from cinenerf_ns.planner.config import PlannerConfig
from cinenerf_ns.planner.errors import InvalidInputError, PlanningError
from cinenerf_ns.planner.scene.scene_config import DEFAULT_SAFETY_MARGIN, SceneConfig

from .backend import FunctionBackend, LocateFn, PlanFn, SceneGaussians, label_locate, to_numpy
from .conventions import VISER_NERFSTUDIO_SCALE_RATIO
from .views import TrainingCameras

if TYPE_CHECKING:
    from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
    from cinenerf_ns.planner.scene.splat_params import SplatParams
    from cinenerf_ns.scenes import LoadedScene

# The scene and planner modules (torch) are imported where they are used: `cinesplat-viewer --help` and its option
# errors need only the config dataclasses above.

LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")


def display_gaussians(splat: SplatParams) -> SceneGaussians:
    """What the browser draws of a splat: colours (grey where it has none), opacities and covariances."""
    import torch

    from cinenerf_ns.planner.scene.ellipsoids import quat_wxyz_to_rotmat
    from cinenerf_ns.planner.scene.splat_params import NO_COLOUR_GREY

    rot = quat_wxyz_to_rotmat(torch.as_tensor(np.asarray(splat.quats_wxyz, np.float64))).numpy()  # [N, 3, 3]
    s2 = np.exp(2.0 * splat.log_scales.astype(np.float64))  # [N, 3]
    cov = (rot * s2[:, None, :]) @ np.swapaxes(rot, -1, -2)  # [N, 3, 3]
    return SceneGaussians(splat.means, splat.rgb(default=NO_COLOUR_GREY), splat.opacities(), cov)


@dataclass
class ViewerScene:
    """What the viewer draws, plans around and answers text with: the scene as every command loads it
    (``scenes.load_scene``'s LoadedScene) plus how the viewer presents it."""

    loaded: LoadedScene  # obstacles, Gaussians, start region, semantics, training cameras
    name: str
    data_dir: Path
    config_path: Optional[Path] = None  # the run's config.yml, absolute
    locate: Optional[LocateFn] = None  # text -> (centroid [3], mask [N] over ``splat``); None: coordinates only
    default_goto: str = ""
    default_look_at: str = ""
    semantics: str = "none"  # what answers text queries: "none" | "labels" | "relevancy"
    object_names: List[str] = dataclasses.field(default_factory=list)  # ground-truth names (procedural / demo)
    scene_note: str = ""  # what the scene is when it has no run (said instead of an ns-render command)
    # the capture's training cameras (the opening view); None: generated scenes
    cameras: Optional[TrainingCameras] = None

    @property
    def splat(self) -> SplatParams:
        """What the browser draws."""
        return self.loaded.splat

    @property
    def obstacles(self) -> EllipsoidScene:
        return self.loaded.scene

    @property
    def start_region(self) -> Optional[Tuple[np.ndarray, np.ndarray]]:
        """(lo [3], hi [3]) of random starts."""
        return self.loaded.start_region

    @property
    def semantic(self) -> Optional[Any]:
        """The SemanticScene answering text ("relevancy" scenes), see warm_semantics."""
        return None if self.loaded.semantics is None else self.loaded.semantics.semantic

    @property
    def free_text(self) -> bool:
        """Whether free text (not only label names) means anything to ``semantic``."""
        return self.loaded.semantics is not None and self.loaded.semantics.free_text


# --------------------------------------------------------------------------------------- loading
def run_data_dir(config_path: Path) -> Optional[Path]:
    """The dataset directory of a nerfstudio run's config.yml (where the Render tab keeps camera_paths/)."""
    from cinenerf_ns.method.training_cameras import run_data_path

    data = run_data_path(config_path)
    if data is None:
        return None
    return data.parent if data.is_file() else data


def procedural_locate(room: Any) -> LocateFn:
    """Ground-truth text query of a procedural room (object names, as ``cinesplat-plan`` answers them)."""
    from cinenerf_ns.scenes import procedural_object

    ids = room.object_ids.cpu().numpy()

    def locate(text: str):
        i = procedural_object(room, text)
        return np.asarray(room.objects[i].center, np.float64), ids == i, f"the object '{room.objects[i].name}'"

    return locate


def semantic_locate(sem: Any, label_names: List[str], free: bool = True) -> LocateFn:
    """Text query of a cinesplat scene: relevancy of the distilled latents (``SemanticScene.locate``), with
    ``cinesplat-plan``'s mapping of words onto the scene's own label names (only those when not ``free``)."""
    from cinenerf_ns.scenes import label_query

    def locate(text: str):
        query = label_query(text, label_names, free)  # InvalidInputError listing the scene's names for nonsense
        r = sem.locate_full(query)
        mask = to_numpy(r.mask, bool)  # [N]
        best = float(to_numpy(r.relevancy)[mask].max()) if mask.any() else float("nan")
        label = f"the label '{query}', " if query in label_names else ""
        return to_numpy(r.centroid), mask, f"{label}best relevancy {best:.2f}"

    return locate


def open_scene(source: str, data_dir: Optional[Path] = None, scene_config: Optional[SceneConfig] = None,
               device: str = "cpu") -> ViewerScene:
    """``--load-config`` -> the scene loaded by ``scenes.load_scene`` (the loader of every command: the same
    obstacles, start regions and text semantics as cinesplat-plan), presented for the viewer. 'demo' names the
    bundled trained room; 'demo-tiny' the tiny labelled scene of viewer/demo.py."""
    from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
    from cinenerf_ns.scenes import DEMO_SCENE, LoadedScene, load_scene

    scfg = scene_config or SceneConfig()
    if source == "demo":  # the bundled trained room (make demo's scene) when the package ships it
        if DEMO_SCENE.exists():
            vs = open_scene(str(DEMO_SCENE), data_dir or Path("demo_output") / "cinesplat-viewer-demo", scene_config,
                            device)
            vs.default_goto, vs.default_look_at = "red armchair", "floor lamp"
            return vs
        source = "demo-tiny"
    if source == "demo-tiny":
        from .demo import demo_scene

        d = demo_scene()
        ld = LoadedScene(EllipsoidScene.from_params(d.splat, scfg).to(device), None, "demo", source, params=d.splat)
        return ViewerScene(
            ld, "demo", data_dir or Path("demo_output") / "cinesplat-viewer-demo",
            locate=label_locate(d.splat.means, d.labels, d.label_of), default_goto="red box",
            default_look_at="blue pillar", semantics="labels", object_names=list(d.labels),
            scene_note="the tiny built-in demo scene has no training run",
        )
    ld = load_scene(source, scfg, device)
    if ld.kind == "procedural":
        names = [o.name for o in ld.room.objects]
        return ViewerScene(
            ld, source.replace(":", "-"), data_dir or Path("demo_output") / "cinesplat-viewer-procedural",
            locate=procedural_locate(ld.room), default_goto=names[0], default_look_at=names[1 % len(names)],
            semantics="labels", object_names=names,
            scene_note=f"'{source}' is a generated test room with no training run",
        )
    path = Path(source)
    if ld.kind == "ply":
        return ViewerScene(ld, path.stem, data_dir or path.parent,
                           scene_note=f"{path.absolute()} is a .ply splat with no training run")
    cfg_path = None if ld.config_path is None else Path(ld.config_path).absolute()
    data = run_data_dir(cfg_path) if cfg_path is not None else None
    name = data.name if data is not None else (path.stem if path.is_file() else path.name)
    sem = ld.semantics
    return ViewerScene(
        ld, name, data_dir or data or (path if path.is_dir() else path.parent), cfg_path,
        locate=None if sem is None else semantic_locate(sem.semantic, sem.label_names, sem.free_text),
        semantics="none" if sem is None else "relevancy",
        scene_note="" if cfg_path is not None else f"{path.absolute()} is a compact export with no training run",
        cameras=TrainingCameras.of(ld.camera_centres, ld.camera_poses),
    )


def warm_semantics(loaded: ViewerScene, background: bool = True,
                   stop: Optional[threading.Event] = None) -> Optional[threading.Thread]:
    """Compute the text-independent part of text queries (SemanticScene.warm: latent smoothing, every label's answer)
    once per scene, off the request path: on a daemon thread when ``background`` (returned; None when the scene has no
    relevancy semantics). A query typed meanwhile waits for the computation in progress, never repeats it.
    ``stop``: setting it ends the warm-up after the part in progress (StandaloneViewer.close sets it and joins)."""
    sem = loaded.semantic
    if sem is None:
        return None

    def work() -> None:
        try:
            sem.warm(labels=True, negatives=loaded.free_text, stop=stop)
        except Exception:  # noqa: BLE001 - warming is an optimisation: the query itself reports any error
            pass

    if not background:
        work()
        return None
    th = threading.Thread(target=work, name="cine-semantic-warm", daemon=True)
    th.start()
    return th


class SplatPreviewer:
    """The panel's "Preview video": renders a camera-path dict through the viewer's splat with
    ``cinenerf_ns.preview`` (CPU); the renderable scene is built on first use (exp of log-scales, sigmoid of logits)."""

    def __init__(self, splat: SplatParams) -> None:
        self.splat = splat
        self._scene = None

    def scene(self):
        if self._scene is None:
            from cinenerf_ns.planner.scene.splat_params import NO_COLOUR_GREY
            from cinenerf_ns.preview.render import scene_from_splat

            self._scene = scene_from_splat(self.splat, grey=NO_COLOUR_GREY)
        return self._scene

    def __call__(self, camera_path, out_dir: Path, name: str, width: int, height: int, fps: int) -> Path:
        from cinenerf_ns.preview import preview_camera_path

        out = preview_camera_path(self.scene(), camera_path, out_dir, name, width=width, height=height, fps=fps,
                                  progress=False)
        return Path(out["paths"]["mp4"])


# --------------------------------------------------------------------------------------- viewer
@dataclass
class StandaloneConfig:
    """cinesplat-viewer: plan, watch and export camera paths in the browser, no GPU needed."""

    load_config: Annotated[str, tyro.conf.arg(aliases=("--scene",))] = "demo"
    """A run's config.yml (or run folder / .ckpt), a compact export (.pt/.npz), a Gaussian-splat .ply,
    'procedural[:N[:SEED]]' (generated test room with named objects), 'demo' (the bundled trained room of
    `make demo`) or 'demo-tiny' (a tiny built-in labelled scene)."""
    port: int = 7007
    """Port of the viewer (open http://localhost:<port>)."""
    host: str = "127.0.0.1"
    """Address to listen on: 127.0.0.1 (this machine only), or an address of this machine such as 0.0.0.0 (every
    network interface: anyone who reaches the port can plan, preview and export; a warning is printed)."""
    output_dir: Path = Path("cinesplat_viewer_exports")
    """Where exported camera paths (camera_paths/) and preview videos (previews/) are written."""
    max_pages: int = 8
    """Browser pages served at once (each has its own panel and is sent the whole splat); more are refused."""
    safety_margin: float = DEFAULT_SAFETY_MARGIN
    """Extra distance kept from every ellipsoid on top of the camera radius (as cinesplat-plan's --safety-margin)."""
    device: str = "cpu"
    """torch device of the obstacle scene and the planner ('cpu' or 'cuda')."""
    candidates: int = 3
    """Default number of candidate shots per Plan (the panel's "Candidates")."""
    max_display_gaussians: int = 1_000_000
    """Draw at most this many Gaussians in the browser (highest opacity first); planning uses all."""
    scale: float = VISER_NERFSTUDIO_SCALE_RATIO
    """viser units per scene unit (nerfstudio's viewer uses 10)."""
    planner: PlannerConfig = dataclasses.field(default_factory=PlannerConfig)
    """The planner's settings, as cinesplat-plan's --planner.* (--trajectory.*, --timing.*: its curve and clock)."""
    obstacles: SceneConfig = dataclasses.field(default_factory=SceneConfig)
    """How the splat's Gaussians become obstacles, as cinesplat-plan's --obstacles.*."""


class StandaloneViewer:
    """A running standalone viewer (server + panel); ``close()`` stops it.

    The real planner prepares on a background thread (the status line shows progress and its time);
    a Plan pressed meanwhile waits for it. ``plan_fn`` replaces the planner (tests, benchmarks)."""

    def __init__(self, cfg: StandaloneConfig, locate: Optional[LocateFn] = None,
                 plan_fn: Optional[PlanFn] = None) -> None:
        import viser

        from .panel import PanelConfig, ServerLimits
        from .planner_backend import PreparedPlanner
        from .region_box import stored_region_config
        from .viser_guard import guard_server
        from .viser_ui import attach_cine_panel

        t0 = time.perf_counter()
        self.cfg = cfg
        scfg = dataclasses.replace(cfg.obstacles, camera_radius=cfg.obstacles.camera_radius + cfg.safety_margin)
        self.loaded = open_scene(cfg.load_config, None, scfg, cfg.device)
        sp = self.loaded.splat
        self.obstacles = self.loaded.obstacles
        self.planner: Optional[PreparedPlanner] = None
        if plan_fn is None:
            self.planner = PreparedPlanner(self.obstacles, dataclasses.replace(
                cfg.planner, start_region=self.loaded.start_region, candidate_workers=0,  # see PreparedPlanner
                **stored_region_config(self.loaded.loaded.planning_region)))
            plan_fn, planner_name = self.planner.plan, PreparedPlanner.name
        else:
            planner_name = "injected planner"
        self.planner_name = planner_name
        display = display_gaussians(sp)
        locate = locate or self.loaded.locate
        self.backend = FunctionBackend(display, plan_fn, locate, self.loaded.name, planner_name, self.planner)
        self.server = start_server(viser, cfg.host, cfg.port)
        self.guard = guard_server(self.server, cfg.host, max_connections=cfg.max_pages)
        self.server.scene.set_up_direction("+z")
        self._draw_splat(display)
        self.panels = attach_cine_panel(
            self.server, self.backend,
            PanelConfig(data_dir=self.loaded.data_dir, config_path=self.loaded.config_path,
                        output_dir=Path(cfg.output_dir).expanduser().absolute(),
                        n_candidates=cfg.candidates, scene_note=self.loaded.scene_note),
            scale=cfg.scale, default_goto=self.loaded.default_goto, default_look_at=self.loaded.default_look_at,
            previewer=SplatPreviewer(sp), export_name=f"{self.loaded.name}-shot", start_region=self.loaded.start_region,
            cameras=self.loaded.cameras, limits=ServerLimits(max_clients=cfg.max_pages),
        )
        self.panels.overview_hides.extend(self.splat_above)
        self.panels.use_home_as_initial_camera()  # browsers open (and "Reset View" returns) inside the captured region

        if locate is None:
            text = ("Text queries need a trained cinesplat scene (semantic latents + codec); this scene has none: "
                    "type targets as x y z.")
        elif self.loaded.semantics == "relevancy":
            text = "Text queries: relevancy of the distilled CLIP latents (or x y z)."
        else:
            text = "Text queries: object names (or x y z)."
        self.loaded_message = f"Loaded '{self.loaded.name}' ({len(display)} Gaussians). {text}"
        self.load_detail = (f"Scene loaded in {time.perf_counter() - t0:.1f} s: {len(display)} Gaussians, "
                            f"{len(self.obstacles)} obstacles. Planner: {planner_name}.")
        self.panels.set_status(self.loaded_message, "info", details=self.load_detail)
        if self.planner is not None:
            self.planner.on_status = self._prepare_status
            self.planner.start(background=True)
        self.warm_stop = threading.Event()  # close() ends the warm-up with it
        # text queries' smoothing and labels, off the request path
        self.warm_thread = warm_semantics(self.loaded, stop=self.warm_stop)

    def _prepare_status(self, text: str, level: str) -> None:
        """Progress of the planner's one-time preparation, shown on each page until its first Plan owns the status line
        (a Plan that failed fast, e.g. text that matches nothing, leaves the panel idle: its message must not be
        overwritten); the preparation's timings go to the details fold."""
        detail = getattr(self.planner, "prepare_detail", "") if self.planner is not None else ""
        detail = f"{self.load_detail} {detail}".strip()  # the latest preparation's (a new planning region's)
        if level == "error":
            self.panels.set_status(text, "error")
        elif level == "busy":
            self.panels.set_status(f"{text} {self.loaded_message}", "busy")
        else:
            self.panels.set_status(f"{text} {self.loaded_message} Type where the camera should go and what it should "
                                   "look at, then Plan.", "info", details=detail or None)

    def _draw_splat(self, g: SceneGaussians) -> None:
        """The splat as viser Gaussian-splat nodes: "/splat", and with a start region its Gaussians whose centres lie
        above the region's top as "/splat_above" (``splat_above``), which the top-down overview hides: a room's
        ceiling lies up there (the training cameras' box +0.1, or a generated room's free space, stays below it) and
        would hide the path from above."""
        n = len(g)
        idx = np.arange(n)
        if n > self.cfg.max_display_gaussians:
            idx = np.argsort(-g.opacities)[: self.cfg.max_display_gaussians]
        region = self.loaded.start_region
        above = np.zeros(len(idx), bool) if region is None else g.means[idx, 2] > float(np.asarray(region[1])[2])
        s = self.cfg.scale
        self.splat_above: List[Any] = []
        for name, sel in (("/splat", idx[~above]), ("/splat_above", idx[above])):
            if len(sel) == 0:
                continue
            h = self.server.scene.add_gaussian_splats(
                name, centers=(g.means[sel] * s).astype(np.float32),
                covariances=(g.covariances[sel] * s * s).astype(np.float32),
                rgbs=g.colors[sel].astype(np.float32), opacities=g.opacities[sel, None].astype(np.float32),
            )
            if name == "/splat_above":
                self.splat_above.append(h)

    @property
    def url(self) -> str:
        host = self.cfg.host
        shown = "localhost" if host in ("0.0.0.0", "::") else (f"[{host}]" if ":" in host else host)
        return f"http://{shown}:{self.server.get_port()}"

    def close(self, join_s: float = 10.0) -> bool:
        """Stop the server and the text-query warm-up; wait up to ``join_s`` for the warm-up to end (it stops after the
        part in progress: one label's answer). True when no background computation of the viewer is still running (the
        warm-up, the planner's preparation): a process must not exit while one runs torch / scipy code on a daemon
        thread, the C++ runtime can abort it ('terminate called without an active exception')."""
        self.warm_stop.set()
        self.panels.close()
        self.server.stop()
        deadline = time.monotonic() + max(float(join_s), 0.0)
        for th in self.background_threads():
            th.join(max(deadline - time.monotonic(), 0.0))
        return not any(th.is_alive() for th in self.background_threads())

    def background_threads(self) -> List[threading.Thread]:
        """The viewer's computations on daemon threads still running: the text-query warm-up, the planner's
        preparation (not interruptible: a few seconds)."""
        prep = None if self.planner is None else self.planner._thread
        return [th for th in (self.warm_thread, prep) if th is not None and th.is_alive()]


def check_host(host: str) -> str:
    """``--host`` as given when it is an IP address or 'localhost'; a clear error otherwise (viser would try 1,000
    ports on an address it cannot bind, silently)."""
    import ipaddress

    if not isinstance(host, str) or not host.strip():
        raise InvalidInputError("--host is empty: give 127.0.0.1 (this machine only) or an address of this machine "
                                "such as 0.0.0.0")
    if host == "localhost":
        return host
    try:
        ipaddress.ip_address(host)
    except ValueError:
        raise InvalidInputError(f"--host {host!r} is not an IP address: give 127.0.0.1 (this machine only), 0.0.0.0 "
                                f"(every interface) or one of this machine's addresses") from None
    return host


def check_bind(host: str, port: int) -> None:
    """Bind ``host``:``port`` once, as the server will, and say clearly why it cannot be (not an address of this
    machine, port in use, no permission) before viser starts."""
    import errno
    import socket

    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_NUMERICSERV)
    except OSError as e:
        raise InvalidInputError(f"--host {host}: cannot be resolved ({e})") from None
    family, _, _, _, addr = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as asyncio's server does
        try:
            s.bind(addr)
        except OSError as e:
            if e.errno == errno.EADDRINUSE:
                raise InvalidInputError(f"--port {port} is already in use on {host} (another viewer?): stop it or "
                                        f"give another --port") from None
            if e.errno == errno.EADDRNOTAVAIL:
                raise InvalidInputError(f"--host {host} is not an address of this machine: give 127.0.0.1, 0.0.0.0 "
                                        f"or one of its interface addresses") from None
            if e.errno == errno.EACCES:
                raise InvalidInputError(f"--port {port}: permission denied (ports below 1024 need privileges); give "
                                        f"a port from 1024 to 65535") from None
            raise InvalidInputError(f"cannot listen on {host}:{port}: {e.strerror or e}") from None


def start_server(viser: Any, host: str, port: int) -> Any:
    """A viser server on exactly ``host``:``port``, or a clear error (viser would silently move to the next free
    port)."""
    check_bind(host, port)
    server = viser.ViserServer(host=host, port=port, verbose=False)
    if server.get_port() != port:  # taken between the check and the start
        server.stop()
        raise InvalidInputError(f"--port {port} was taken while the viewer started: give another --port")
    return server


def exposure_warning(host: str) -> Optional[str]:
    """The warning printed when the viewer listens beyond this machine (None on a loopback address)."""
    import ipaddress

    if host in LOOPBACK_HOSTS or (host != "localhost" and ipaddress.ip_address(host).is_loopback):
        return None
    return (f"Warning: listening on {host}: anyone who can reach this port can plan, preview and export with this "
            "viewer (files go to --output-dir). Use --host 127.0.0.1 to keep it to this machine.")


def check_config(cfg: StandaloneConfig) -> None:
    """The options' ranges, before the scene is loaded (messages name the option); the scene-relative checks (camera
    radius against the scene, grid against memory) follow in the planner, shown in the status line."""
    from cinenerf_ns.option_ranges import check_config_ranges
    from cinenerf_ns.option_surface import validated
    from cinenerf_ns.options import check_number
    from cinenerf_ns.planner.config import MAX_CANDIDATES

    if not isinstance(cfg.load_config, str) or not cfg.load_config.strip():
        raise InvalidInputError("--load-config is empty: give a run's config.yml, a compact export, a .ply, "
                                "'procedural' or 'demo'")
    check_number(cfg.port, "--port", 1, 65535, integer=True)
    check_host(cfg.host)
    from cinenerf_ns.output_set import check_writable

    check_writable(Path(cfg.output_dir))  # a file, under a file, read-only, /proc: said now, not at the first export
    check_config_ranges([("--planner", cfg.planner), ("--obstacles", cfg.obstacles)])
    check_number(cfg.safety_margin, "--safety-margin", 0, 10)
    check_number(cfg.candidates, "--candidates", 1, MAX_CANDIDATES, integer=True)
    check_number(cfg.max_pages, "--max-pages", 1, 64, integer=True)
    check_number(cfg.max_display_gaussians, "--max-display-gaussians", 1, 50_000_000, integer=True)
    check_number(cfg.scale, "--scale", 0, 1e6, lo_open=True)
    if cfg.device != "cpu" and not str(cfg.device).startswith("cuda"):
        raise InvalidInputError(f"--device must be 'cpu' or 'cuda', got {cfg.device!r}")
    validated("--planner", cfg.planner.validate)
    validated("--trajectory", cfg.planner.trajectory.validate)


# How long Ctrl+C waits for the viewer's background computations (the text-query warm-up stops after its current label,
# the planner's preparation finishes) before the process exits without the interpreter's shutdown.
SHUTDOWN_JOIN_S = 5.0


def main(cfg: StandaloneConfig) -> None:
    """Serve until Ctrl+C (then exit status 0; a Ctrl+C while the scene loads: 130, no traceback either way)."""
    from rich.console import Console

    from cinenerf_ns.console_text import lit

    check_config(cfg)
    check_bind(cfg.host, cfg.port)  # before the scene loads: a taken port or a foreign address fails at once
    viewer = None
    try:
        viewer = StandaloneViewer(cfg)
        warning = exposure_warning(cfg.host)
        if warning:
            Console(stderr=True, emoji=False).print(warning, style="bold yellow", markup=False, highlight=False)
        out = Console(emoji=False)  # the status quotes user text (scene path, queries): printed as typed, never markup
        out.print(f"[bold green]cinesplat-viewer[/] running at {lit(viewer.url)}  (Ctrl+C to stop)")
        out.print(viewer.panels.status, markup=False, highlight=False)
        if viewer.planner is not None:
            viewer.planner.wait_ready()
            out.print(viewer.panels.status, markup=False, highlight=False)
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        exit_watchdog(SHUTDOWN_HARD_S)
    finally:
        if viewer is not None and not viewer.close(SHUTDOWN_JOIN_S):
            _exit_now(0)  # a computation still runs on a daemon thread: the interpreter's shutdown could abort
    if viewer is None:  # interrupted while loading
        _exit_now(130)


SHUTDOWN_HARD_S = 20.0
"""After Ctrl+C the process ends within this many seconds whatever still runs: the viewer's close and the interpreter's
shutdown are normally done in a second or two, but a thread of a library (the server's, a pool's) that does not stop
must not keep a stopped viewer alive (a fresh-clone test run once waited over a minute)."""


def exit_watchdog(seconds: float) -> threading.Timer:
    """A daemon timer that ends the process (status 0, output flushed) after ``seconds`` unless it has exited."""
    t = threading.Timer(float(seconds), _exit_now, args=(0,))
    t.daemon = True
    t.start()
    return t


def _exit_now(code: int) -> None:
    """Exit without the interpreter's shutdown (os._exit after flushing the output): the way out while torch / scipy
    code runs on a daemon thread, whose C++ runtime can abort a normal exit ('terminate called without an active
    exception', status 134)."""
    import os
    import sys

    for f in (sys.stdout, sys.stderr):
        try:
            f.flush()
        except Exception:  # noqa: BLE001 - a closed pipe: nothing left to say
            pass
    os._exit(code)


def entrypoint(argv: Optional[List[str]] = None) -> None:
    """cinesplat-viewer: user errors (options, scene files) end with a message on stderr and exit status 2."""
    import sys

    from rich.console import Console

    from cinenerf_ns.console_text import error_line
    from cinenerf_ns.option_surface import parse

    try:
        main(parse(StandaloneConfig, argv, "cinesplat-viewer", RENAMED_FLAGS))
    except (PlanningError, FileNotFoundError, ValueError, OSError) as e:  # CheckpointError, QueryError, port in use
        Console(stderr=True, emoji=False).print(error_line("cinesplat-viewer", e), soft_wrap=True)
        sys.exit(2)


RENAMED_FLAGS = {"--n-candidates": "--candidates"}
"""Flags of cinesplat-viewer that changed name (to cinesplat-plan's): the old spelling fails with the new one."""

if __name__ == "__main__":
    entrypoint()
