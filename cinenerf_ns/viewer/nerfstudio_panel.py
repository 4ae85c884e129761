"""Put the cinematography panel into nerfstudio's own viewer (``ns-train cinesplat`` / ``ns-viewer``).

How it gets there: nerfstudio's ``Viewer.__init__`` scrapes the pipeline (and every nn.Module under
it, attributes not starting with '_') for ``ViewerControl`` instances and calls ``control._setup(viewer)``
once the viser server and its tabs exist (``nerfstudio/viewer/viewer.py``). :class:`CinePanelControl`
is such a control: the model declares one, and its ``_setup`` adds the panel (a "Cinematography"
folder under the Control/Render/Export tabs) to ``viewer.viser_server``. ``ns-viewer`` builds the same
``Viewer`` on the loaded pipeline, so the panel appears there too.

In the cinesplat model (``populate_modules``)::

    from cinenerf_ns.viewer.nerfstudio_panel import CinePanelControl, SplatModelBackend
    self.cine_panel = CinePanelControl(lambda: SplatModelBackend(
        self, make_planner=lambda scene: Planner(scene, planner_config),   # cinenerf_ns.planner
        locate_fn=lambda text: self.semantic_scene().locate(text),          # cinenerf_ns.method
    ))

Camera moves go straight to every client's viser camera (nerfstudio 1.1.5's ``ViewerControl.set_pose``
raises NotImplementedError); nerfstudio's render state machine re-renders on the client's echo.
"""
from __future__ import annotations

import contextlib
import threading
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional

import numpy as np
import torch

from cinenerf_ns.planner.scene import EllipsoidScene, SceneConfig

from .backend import LocateFn, SceneGaussians
from .conventions import VISER_NERFSTUDIO_SCALE_RATIO
from .panel import CinePanel, PanelBackend, PanelConfig

try:  # nerfstudio is a runtime dependency; keep this module importable for docs/tests without it
    from nerfstudio.viewer.viewer_elements import ViewerControl as _ViewerControl
except Exception:  # pragma: no cover
    _ViewerControl = object  # type: ignore


def attach_to_nerfstudio_viewer(
    viewer: Any,
    backend: PanelBackend,
    config: Optional[PanelConfig] = None,
    exporter=None,
) -> CinePanel:
    """Add the panel to a running ``nerfstudio.viewer.viewer.Viewer``: exports go to
    ``viewer.datapath / camera_paths`` (where the Render tab writes and loads them) and the command
    names the run's ``config.yml`` (``viewer.log_filename.parent / 'config.yml'``, as the Render tab does)."""
    from .viser_ui import attach_cine_panel

    cfg = config or PanelConfig()
    cfg.data_dir = Path(viewer.datapath)
    cfg.config_path = Path(viewer.log_filename).parent / "config.yml"
    lock = getattr(viewer, "train_lock", None)
    if lock is not None and not isinstance(backend, LockedBackend):
        backend = LockedBackend(backend, lock)
    return attach_cine_panel(viewer.viser_server, backend, cfg, exporter, scale=VISER_NERFSTUDIO_SCALE_RATIO)


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
        self.panel: Optional[CinePanel] = None

    def _setup(self, viewer: Any) -> None:
        super()._setup(viewer)  # sets self.viewer / self.viser_server (nerfstudio's ViewerControl)
        if self.panel is not None:  # a second viewer on the same model: start fresh
            self.panel.close()
        self.panel = attach_to_nerfstudio_viewer(viewer, self._backend_factory(), self._config, self._exporter)


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


class SplatModelBackend:
    """PanelBackend over a live splatfacto-style model (``means``, ``quats``, ``scales`` (log),
    ``opacities`` (logits), ``colors`` properties).

    The obstacle scene and the planner are rebuilt when the model's ``step`` changed since the last
    plan (training moves and densifies the Gaussians); between steps they are reused, so repeated
    Plans on a paused or finished run only pay for planning. Planner-like: ``make_planner(scene)``
    returns an object with ``plan(goal, look_at, start=None, seed=0, n_candidates=1)`` taking torch
    tensors on the scene's device (``cinenerf_ns.planner.Planner``); ``prepare()`` is called if present."""

    def __init__(
        self,
        model: Any,
        make_planner: Callable[[EllipsoidScene], Any],
        locate_fn: Optional[LocateFn] = None,
        scene_config: Optional[SceneConfig] = None,
        version_fn: Optional[Callable[[], Any]] = None,
    ) -> None:
        self.model = model
        self.make_planner = make_planner
        self.locate_fn = locate_fn
        self.scene_config = scene_config or SceneConfig()
        self.version_fn = version_fn or (lambda: (getattr(model, "step", 0), int(model.means.shape[0])))
        self._cache: Dict[str, Any] = {}
        self._cache_lock = threading.Lock()

    @torch.no_grad()
    def _current(self, what: str):
        version = self.version_fn()
        with self._cache_lock:
            if self._cache.get("version") != version:
                self._cache = {"version": version}
            if what not in self._cache:
                m = self.model
                if what == "gaussians":
                    self._cache[what] = SceneGaussians(m.means, m.colors.clamp(0, 1), torch.sigmoid(m.opacities))
                elif what == "planner":
                    scene = EllipsoidScene.from_splat(
                        m.means.detach(), m.quats.detach(), m.scales.detach(), m.opacities.detach(), self.scene_config
                    )
                    planner = self.make_planner(scene)
                    if hasattr(planner, "prepare"):
                        planner.prepare()
                    self._cache[what] = (scene, planner)
            return self._cache[what]

    def gaussians(self) -> SceneGaussians:
        return self._current("gaussians")

    def locate(self, text: str):
        from .backend import FunctionBackend

        # FunctionBackend gives the same empty-text / no-semantics messages as the standalone viewer.
        return FunctionBackend(self.gaussians(), lambda *a, **k: [], self.locate_fn).locate(text)

    def plan(self, goal, look_at, start=None, seed: int = 0, n_candidates: int = 1) -> List[Any]:
        scene, planner = self._current("planner")
        t = lambda x: None if x is None else torch.as_tensor(np.asarray(x), dtype=scene.dtype, device=scene.device)
        return list(planner.plan(t(goal), t(look_at), start=t(start), seed=seed, n_candidates=n_candidates))
