"""Put the cinematography panel into nerfstudio's own viewer (``ns-train cinesplat`` / ``ns-viewer``).

How it gets there: nerfstudio's ``Viewer.__init__`` scrapes the pipeline (and every nn.Module under
it, attributes not starting with '_') for ``ViewerControl`` instances and calls ``control._setup(viewer)``
once the viser server and its tabs exist (``nerfstudio/viewer/viewer.py``). :class:`CinePanelControl`
is such a control: the model declares one, and its ``_setup`` adds the panel (a "Cinematography"
folder under the Control/Render/Export tabs) to ``viewer.viser_server``. ``ns-viewer`` builds the same
``Viewer`` on the loaded pipeline, so the panel appears there too.

The cinesplat model never imports this module: ``populate_modules`` calls every entry point of the group
``cinenerf_ns.viewer_extensions`` (pyproject) with itself; this module's :func:`attach` is the ``cine_panel`` one::

    model.cine_panel = attach(model)  # CinePanelControl(lambda: cinesplat_backend(model, device=...))

:func:`cinesplat_backend` builds a :class:`SplatModelBackend`: each Plan snapshots the model's current
Gaussians under the viewer's ``train_lock`` (copies, so training goes on while planning runs), builds
an ``EllipsoidScene`` and the real planner from the snapshot (rebuilt only when the training step or the
Gaussian count changed), and answers text with a ``SemanticScene`` over the snapshot's latents + the
model's codec and text encoder (coordinates only when the model has no codec).

Camera moves go straight to every client's viser camera (nerfstudio 1.1.5's ``ViewerControl.set_pose``
raises NotImplementedError); nerfstudio's render state machine re-renders on the client's echo.
"""
from __future__ import annotations

import contextlib
import copy
import dataclasses
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Dict, List, Optional, Union

import numpy as np
import torch

from cinenerf_ns.method.training_cameras import camera_box
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.scene.splat_params import SplatParams, rgb_to_dc

from .backend import LocateFn, SceneGaussians
from .conventions import VISER_NERFSTUDIO_SCALE_RATIO
from .panel import PanelBackend, PanelConfig

if TYPE_CHECKING:
    from .viser_ui import ClientPanels

try:  # nerfstudio is a runtime dependency; keep this module importable for docs/tests without it
    from nerfstudio.viewer.viewer_elements import ViewerControl as _ViewerControl
except Exception:  # pragma: no cover
    _ViewerControl = object  # type: ignore


def attach_to_nerfstudio_viewer(
    viewer: Any,
    backend: PanelBackend,
    config: Optional[PanelConfig] = None,
    exporter=None,
) -> "ClientPanels":
    """Give every page of a running ``nerfstudio.viewer.viewer.Viewer`` its own panel: exports go to
    ``viewer.datapath / camera_paths`` (where the Render tab writes and loads them) and the command
    names the run's ``config.yml`` (``viewer.log_filename.parent / 'config.yml'``, as the Render tab does). What pages
    send the server is checked first (:func:`~.viser_guard.guard_server`: values only, no uploads or share requests,
    the Origin)."""
    from .viser_guard import guard_server
    from .viser_ui import attach_cine_panel

    cfg = config or PanelConfig()
    cfg.data_dir = Path(viewer.datapath)
    cfg.config_path = Path(viewer.log_filename).parent / "config.yml"
    lock = getattr(viewer, "train_lock", None)
    if isinstance(backend, SplatModelBackend):  # snapshots the model under the lock; plans without it
        backend.lock = lock
        cams = backend.camera_centres = train_camera_centres(viewer)  # the volume centre fills what no camera saw
        region = None if cams is None else camera_box(cams)
        if region is not None and getattr(backend.planner_config, "start_region", None) is None:
            from cinenerf_ns.planner.shots.planner import PlannerConfig

            base = backend.planner_config or PlannerConfig(candidate_workers=0)  # PreparedPlanner's default
            if isinstance(base, PlannerConfig):
                backend.planner_config = dataclasses.replace(base, start_region=region)
    elif lock is not None and not isinstance(backend, LockedBackend):
        backend = LockedBackend(backend, lock)
    server = viewer.viser_server
    if getattr(server, "_cine_guard", None) is None:
        server._cine_guard = guard_server(server, server.get_host(), hide_share_button=False)
    return attach_cine_panel(server, backend, cfg, exporter, scale=VISER_NERFSTUDIO_SCALE_RATIO)


def train_camera_centres(viewer: Any) -> Optional[np.ndarray]:
    """[F, 3] float64: the training cameras' centres (the pipeline's normalised coordinates), or None when the viewer's
    pipeline has no training cameras."""
    try:
        c2w = viewer.pipeline.datamanager.train_dataset.cameras.camera_to_worlds  # [F, 3, 4]
        t = c2w[..., :3, 3].detach().double().cpu().numpy().reshape(-1, 3)  # [F, 3]
    except AttributeError:
        return None
    if t.shape[0] == 0 or not np.isfinite(t).all():
        return None
    return t


class CinePanelControl(_ViewerControl):  # type: ignore[misc]
    """A nerfstudio ``ViewerControl`` that installs the panel when the viewer starts.

    ``backend_factory`` is called once, in ``_setup`` (the model is fully built by then)."""

    def __init__(
        self,
        backend_factory: Callable[[], PanelBackend],
        config: Optional[PanelConfig] = None,
        exporter=None,
    ) -> None:
        self._backend_factory = backend_factory
        self._config = config
        self._exporter = exporter
        self.panels: Optional["ClientPanels"] = None  # one panel per page (viser_ui.ClientPanels)

    def _setup(self, viewer: Any) -> None:
        super()._setup(viewer)  # sets self.viewer / self.viser_server (nerfstudio's ViewerControl)
        if self.panels is not None:  # a second viewer on the same model: start fresh
            self.panels.close()
        self.panels = attach_to_nerfstudio_viewer(viewer, self._backend_factory(), self._config, self._exporter)


class LockedBackend:
    """Holds nerfstudio's ``train_lock`` while the backend reads the model (Gaussians, query,
    planning), so training steps (densification changes N) never interleave with a read."""

    def __init__(self, inner: PanelBackend, lock: Any) -> None:
        self.inner = inner
        self.lock = lock if lock is not None else contextlib.nullcontext()

    def gaussians(self) -> SceneGaussians:
        with self.lock:
            return self.inner.gaussians()

    def locate(self, text: str):
        with self.lock:
            return self.inner.locate(text)

    def plan(self, goal, look_at, start=None, seed: int = 0, n_candidates: int = 1):
        with self.lock:
            return self.inner.plan(goal, look_at, start=start, seed=seed, n_candidates=n_candidates)


@dataclass
class ModelSnapshot:
    """A copy of a splatfacto-style model's Gaussians at one training step, and the device planning runs on."""

    version: Any  # what the backend compares to know the model changed (step, N)
    splat: SplatParams  # colour from the model's ``colors``, latents when it has them
    device: torch.device = torch.device("cpu")


class SplatModelBackend:
    """PanelBackend over a live splatfacto-style model (``means``, ``quats``, ``scales`` (log),
    ``opacities`` (logits), ``colors`` properties; cinesplat models also ``latents`` / ``codec``).

    Reads of the model happen only in :meth:`snapshot`, under ``lock`` (nerfstudio's ``train_lock``,
    set by :func:`attach_to_nerfstudio_viewer`), and copy the tensors (a SplatParams); planning and text
    queries then run on the copy, on ``device``, without blocking training. The obstacle scene, the planner and the
    semantic scene are rebuilt when ``version_fn()`` (default: step and Gaussian count) changed since
    the last snapshot; otherwise they are reused, so repeated Plans on a paused or finished run only
    pay for planning.

    ``make_planner(scene)`` returns an object with ``plan(goal, look_at, start=None, seed=0,
    n_candidates=1)`` (default: :class:`~.planner_backend.PreparedPlanner` with ``planner_config``).
    ``locate_fn(text)`` overrides the text query; by default a ``SemanticScene`` is built when the model
    has a codec (``semantic_fn`` can replace that too)."""

    def __init__(
        self,
        model: Any,
        make_planner: Optional[Callable[[EllipsoidScene], Any]] = None,
        locate_fn: Optional[LocateFn] = None,
        scene_config: Optional[SceneConfig] = None,
        version_fn: Optional[Callable[[], Any]] = None,
        planner_config: Any = None,
        device: Union[str, torch.device] = "cpu",
        lock: Any = None,
        semantic_fn: Optional[Callable[["ModelSnapshot"], Any]] = None,
    ) -> None:
        self.model = model
        self.planner_config = planner_config
        self.make_planner = make_planner or self._default_planner
        self.locate_fn = locate_fn
        self.scene_config = scene_config or SceneConfig.with_margin()  # cinesplat-plan's camera radius + margin
        self.version_fn = version_fn or (lambda: (int(getattr(model, "step", 0)), int(model.means.shape[0])))
        self.device = torch.device(device)
        self.lock = lock
        self.camera_centres: Optional[np.ndarray] = None  # [F, 3] the training cameras (set when the panel installs)
        self.semantic_fn = (semantic_fn if semantic_fn is not None
                            else model_semantic_scene(model, lambda: self.camera_centres))
        self.planner_name = "cinenerf_ns planner" if make_planner is None else None
        self.snapshots_taken = 0
        self._cache: Dict[str, Any] = {}
        self._cache_lock = threading.Lock()
        self.region_source = ModelRegion(self)  # the panel's planning region (region_box.RegionSource)

    def _default_planner(self, scene: EllipsoidScene):
        from .planner_backend import PreparedPlanner

        return PreparedPlanner(scene, self.planner_config).start(background=False)

    # ------------------------------------------------------------------ model reads
    @torch.no_grad()
    def snapshot(self) -> ModelSnapshot:
        """Copy the model's Gaussians (under ``lock``)."""
        m = self.model
        with (self.lock if self.lock is not None else contextlib.nullcontext()):
            version = self.version_fn()
            colors = getattr(m, "colors", None)
            splat = SplatParams.of(m.means, m.quats, m.scales, m.opacities, latents=getattr(m, "latents", None),
                                   colors_dc=None if colors is None else rgb_to_dc(colors.clamp(0, 1)))
        snap = ModelSnapshot(version=version, splat=splat, device=self.device)
        self.snapshots_taken += 1
        return snap

    def _current(self, what: str):
        with self._cache_lock:
            if self._cache.get("version") != self.version_fn() or "snapshot" not in self._cache:
                snap = self.snapshot()
                self._cache = {"version": snap.version, "snapshot": snap}
            snap = self._cache["snapshot"]
            if what not in self._cache:
                if what == "gaussians":
                    self._cache[what] = SceneGaussians(snap.splat.means, snap.splat.rgb(), snap.splat.opacities())
                elif what == "planner":
                    scene = EllipsoidScene.from_params(snap.splat, self.scene_config, device=snap.device)
                    planner = self.make_planner(scene)
                    if hasattr(planner, "prepare") and not hasattr(planner, "wait_ready"):
                        planner.prepare()
                    self._cache[what] = (scene, planner)
                    if hasattr(planner, "add_region_listener"):  # a region applied later: the pages follow
                        planner.add_region_listener(self.region_source.notify)
                    self.region_source.notify()  # this snapshot's region: the pages show it
                elif what == "semantic":
                    self._cache[what] = None if self.semantic_fn is None else self.semantic_fn(snap)
            return self._cache[what]

    # ------------------------------------------------------------------ PanelBackend
    def gaussians(self) -> SceneGaussians:
        return self._current("gaussians")

    def locate(self, text: str):
        from .backend import FunctionBackend

        locate_fn = self.locate_fn
        if locate_fn is None:
            sem = self._current("semantic")
            if sem is not None:
                from cinenerf_ns.scenes import free_text

                from .standalone import semantic_locate  # says what matched: the label, the best relevancy

                info = getattr(self.model, "cine_info", {}) or {}
                names, free = list(info.get("label_names") or []), free_text(info)
                locate_fn = semantic_locate(sem, names, free)
        # FunctionBackend gives the same empty-text / no-semantics messages as the standalone viewer.
        return FunctionBackend(self.gaussians(), lambda *a, **k: [], locate_fn).locate(text)

    def plan(self, goal, look_at, start=None, seed: int = 0, n_candidates: int = 1) -> List[Any]:
        scene, planner = self._current("planner")
        if hasattr(planner, "wait_ready"):  # PreparedPlanner: numpy in, float64 planning
            shots = list(planner.plan(goal, look_at, start=start, seed=seed, n_candidates=n_candidates))
            prep = getattr(planner, "prepare_s", None)
            if prep is not None and not getattr(planner, "_reported_prepare", False):
                planner._reported_prepare = True  # the first Plan on a new snapshot also paid prepare()
                for s in shots:
                    s.timings["prepare_ms"] = 1e3 * prep
            return shots
        def t(x):
            return None if x is None else torch.as_tensor(np.asarray(x), dtype=scene.dtype, device=scene.device)

        return list(planner.plan(t(goal), t(look_at), start=t(start), seed=seed, n_candidates=n_candidates))


class ModelRegion:
    """The planning region of a live model's planner (``SplatModelBackend.region_source``, a region_box.RegionSource).
    The planner is built at a Plan, again per training step; the region asked for stays in the backend's
    ``planner_config`` (bounds) for every later one. Before the first Plan no region is prepared: the pages say it is
    known at the first Plan."""

    def __init__(self, backend: "SplatModelBackend") -> None:
        self.backend = backend
        self._listeners: List[Callable[[], None]] = []

    def _planner(self) -> Any:
        cached = self.backend._cache.get("planner")
        return None if cached is None else cached[1]

    def region_info(self) -> Any:
        from .region_box import AUTOMATIC, RegionInfo

        planner = self._planner()
        info = planner.region_info() if hasattr(planner, "region_info") else None
        if info is not None:
            return info
        bounds = getattr(self.backend.planner_config, "bounds", None)
        lo, hi = (None, None) if bounds is None else (np.asarray(v, dtype=np.float64) for v in bounds)
        return RegionInfo(lo, hi, AUTOMATIC if bounds is None else "user box", "later", automatic=bounds is None,
                          asked=None if bounds is None else (lo, hi))

    def set_region(self, bounds: Any) -> Any:
        """Checked by the current planner (its rules, before any work; it prepares again in the background) or, before
        the first Plan, by user_box.user_box (the rest when the next Plan prepares); kept for later steps."""
        from cinenerf_ns.planner.scene.user_box import user_box
        from cinenerf_ns.planner.shots.planner import PlannerConfig

        planner = self._planner()
        if bounds is not None:
            bounds = user_box(bounds, "the planning region")
        info = planner.set_region(bounds) if hasattr(planner, "set_region") else None
        base = self.backend.planner_config or PlannerConfig(candidate_workers=0)  # PreparedPlanner's default
        if isinstance(base, PlannerConfig):
            self.backend.planner_config = dataclasses.replace(base, bounds=bounds, bounds_rule="user box")
        if info is None:
            info = self.region_info()
            self.notify()
        return info

    def add_region_listener(self, fn: Callable[[], None]) -> None:
        self._listeners.append(fn)

    def notify(self) -> None:
        from .region_box import notify_all

        notify_all(self._listeners)


def model_semantic_scene(model: Any, camera_centres: Optional[Callable[[], Optional[np.ndarray]]] = None
                         ) -> Callable[[ModelSnapshot], Any]:
    """``snapshot -> SemanticScene`` for a cinesplat model (latents + codec + text encoder, relevancy
    settings from its config); the function returns None when the model has no codec (then text
    queries ask for coordinates). ``camera_centres``: returns the training cameras' centres [F, 3] (or None), read
    per snapshot: the volume centre then fills what no camera saw."""
    state: Dict[str, Any] = {}

    def build(snap: ModelSnapshot):
        # checked per snapshot: ns-viewer builds the codec when it loads the checkpoint, after construction
        if snap.splat.latents is None or getattr(model, "codec", None) is None or not hasattr(model, "text_encoder"):
            return None
        from cinenerf_ns.method.semantic_scene import SemanticScene
        from cinenerf_ns.semantic_defaults import OBJECT_CLUSTER, SMOOTH_NEIGHBORS

        if state.get("codec_src") is not model.codec:  # frozen: one copy on the planning device
            state["codec"] = copy.deepcopy(model.codec).to(snap.device).eval()
            state["codec_src"] = model.codec
        cfg = getattr(model, "config", None)
        kw = {}
        if cfg is not None:
            kw = dict(negatives=tuple(cfg.relevancy_negatives), temperature=float(cfg.relevancy_temperature),
                      threshold=float(cfg.relevancy_threshold))
        return SemanticScene.from_params(snap.splat, state["codec"], model.text_encoder(), snap.device,
                                         label_names=(getattr(model, "cine_info", None) or {}).get("label_names"),
                                         # the text settings of cinesplat-plan and cinesplat-viewer (scenes.load_scene):
                                         # the same text selects the same object in every viewer
                                         smooth_neighbors=SMOOTH_NEIGHBORS, cluster_fraction=OBJECT_CLUSTER,
                                         camera_centres=None if camera_centres is None else camera_centres(), **kw)

    return build


def cinesplat_backend(model: Any, device: Union[str, torch.device] = "cpu",
                      planner_config: Any = None) -> SplatModelBackend:
    """The backend ``CineSplatModel`` installs: real planner + its semantics, planning on ``device``."""
    return SplatModelBackend(model, planner_config=planner_config, device=device)


def attach(model: Any) -> CinePanelControl:
    """The ``cine_panel`` viewer extension of a CineSplatModel (entry point group cinenerf_ns.viewer_extensions): the
    panel's backend (a snapshot under the train lock, the real planner, semantics) is built when the viewer sets it
    up."""
    return CinePanelControl(lambda: cinesplat_backend(model, device=model.config.viewer_planner_device))
