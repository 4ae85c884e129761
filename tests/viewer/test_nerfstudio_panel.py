"""The nerfstudio adapter: nerfstudio's own scraping finds the control on a model and installs the
panel on the viewer's viser server; the live-model backend snapshots and rebuilds per step."""
from __future__ import annotations

import socket
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from torch import nn

from cinenerf_ns.viewer.demo import StraightLinePlanner
from cinenerf_ns.viewer.nerfstudio_panel import CinePanelControl, LockedBackend, SplatModelBackend
from cinenerf_ns.viewer.panel import CinePanel, PanelBackend


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class TinySplatModel(nn.Module):
    """The splatfacto properties the backend reads."""

    def __init__(self, n=300, seed=0):
        super().__init__()
        g = torch.Generator().manual_seed(seed)
        self.means = nn.Parameter(torch.rand(n, 3, generator=g) * 2 - 1)
        self.quats = nn.Parameter(torch.randn(n, 4, generator=g))
        self.scales = nn.Parameter(torch.full((n, 3), -4.0))
        self.opacities = nn.Parameter(torch.full((n, 1), 2.0))
        self.colors = torch.rand(n, 3, generator=g)
        self.step = 0


class Planners:
    def __init__(self):
        self.built = []

    def __call__(self, scene):
        self.built.append(len(scene))
        return StraightLinePlanner.from_scene(scene)


def locate_first_half(text):
    mask = np.zeros(300, bool)
    mask[:150] = True
    return np.array([0.0, 0.0, 0.0]), mask


def test_splat_model_backend_caches_per_step():
    model, planners = TinySplatModel(), Planners()
    backend = SplatModelBackend(model, planners, locate_fn=locate_first_half)
    assert isinstance(backend, PanelBackend)
    assert len(backend.gaussians()) == 300
    shots = backend.plan(np.array([0.0, 0.0, 1.5]), np.zeros(3), start=np.array([0.0, 0.0, 3.0]))
    assert len(shots) == 1 and isinstance(shots[0].positions, np.ndarray)
    backend.plan(np.array([0.0, 0.0, 1.5]), np.zeros(3), start=np.array([0.0, 0.0, 3.0]))
    assert planners.built == [300]  # reused while the step did not change
    model.step = 10
    backend.plan(np.array([0.0, 0.0, 1.5]), np.zeros(3), start=np.array([0.0, 0.0, 3.0]))
    assert planners.built == [300, 300]
    c, m = backend.locate("anything")
    assert m.sum() == 150
    with pytest.raises(ValueError, match="empty query"):
        backend.locate("  ")
    no_sem = SplatModelBackend(model, planners)
    with pytest.raises(ValueError, match="coordinates"):
        no_sem.locate("the chair")


def test_locked_backend_holds_train_lock():
    lock = threading.Lock()
    seen = []

    class Inner:
        def gaussians(self):
            seen.append(lock.locked())

        def locate(self, text):
            seen.append(lock.locked())

        def plan(self, *a, **k):
            seen.append(lock.locked())
            return []

    b = LockedBackend(Inner(), lock)
    b.gaussians(), b.locate("x"), b.plan(np.zeros(3), np.ones(3))
    assert seen == [True, True, True] and not lock.locked()


def test_control_is_found_by_nerfstudio_and_installs_panel(tmp_path):
    from nerfstudio.viewer.utils import parse_object
    from nerfstudio.viewer.viewer_elements import ViewerControl
    import viser

    model = TinySplatModel()
    model.cine_panel = CinePanelControl(lambda: SplatModelBackend(model, Planners(), locate_first_half))
    pipeline = nn.Module()
    pipeline._model = model  # nerfstudio's VanillaPipeline keeps the model as _model, reached via .model
    pipeline.model = model
    found = [c for _, c in parse_object(pipeline, ViewerControl, "Custom Elements")]
    assert found == [model.cine_panel]

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        viewer = SimpleNamespace(viser_server=server, datapath=tmp_path / "data",
                                 log_filename=tmp_path / "run" / "viewer_log_filename.txt", train_lock=threading.Lock())
        for c in found:  # what Viewer.__init__ does
            c._setup(viewer)
        panel = model.cine_panel.panel
        assert isinstance(panel, CinePanel) and isinstance(panel.backend, LockedBackend)
        assert panel.config.data_dir == tmp_path / "data"
        assert panel.config.config_path == tmp_path / "run" / "config.yml"
        res = panel.request_plan("0 0 1.5", "0 0 0").result(30)
        assert res is not None, panel.status
        out = panel.export("from-ns")
        assert out.path == tmp_path / "data" / "camera_paths" / "from-ns.json"
        assert f"--load-config {tmp_path / 'run' / 'config.yml'}" in out.command
        panel.close()
    finally:
        server.stop()


def test_real_nerfstudio_viewer_installs_panel(tmp_path):
    """nerfstudio 1.1.5's own Viewer (as ns-train / ns-viewer build it) on a minimal pipeline."""
    from nerfstudio.configs.base_config import ViewerConfig
    from nerfstudio.viewer.viewer import Viewer

    model = TinySplatModel()
    model.cine_panel = CinePanelControl(lambda: SplatModelBackend(model, Planners(), locate_first_half))

    class Pipeline(nn.Module):
        def __init__(self):
            super().__init__()
            self.model = model
            self.datamanager = SimpleNamespace(includes_time=False)

    viewer = Viewer(
        ViewerConfig(websocket_port=free_port(), websocket_host="127.0.0.1"),
        log_filename=tmp_path / "run" / "viewer_log_filename.txt", datapath=tmp_path / "data",
        pipeline=Pipeline(), train_lock=threading.Lock(),
    )
    try:
        panel = model.cine_panel.panel
        assert isinstance(panel, CinePanel)
        assert panel.config.data_dir == tmp_path / "data"
        assert panel.config.config_path == tmp_path / "run" / "config.yml"
        assert panel.request_plan("0 0 1.5", "0 0 0").result(30) is not None, panel.status
        assert panel.export("ns-take").path == tmp_path / "data" / "camera_paths" / "ns-take.json"
        panel.close()
    finally:
        viewer.viser_server.stop()
