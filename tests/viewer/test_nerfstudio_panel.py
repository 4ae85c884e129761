"""The nerfstudio adapter: nerfstudio's own scraping finds the control on a model and installs the
panel on the viewer's viser server; the live-model backend snapshots the Gaussians under the
train_lock (and plans without it), rebuilds the real planner per step, and the real CineSplatModel
(built on CPU) carries the control and answers text through its latents + codec."""
from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from _xdist import free_port
from torch import nn

from cinenerf_ns.planner.scene.splat_params import SplatParams
from cinenerf_ns.viewer.nerfstudio_panel import CinePanelControl, LockedBackend, SplatModelBackend
from cinenerf_ns.viewer.panel import CinePanel, PanelBackend
from cinenerf_ns.viewer.planner_backend import PreparedPlanner


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
    """The real planner, counting how often one is built (= how often the scene was rebuilt)."""

    def __init__(self):
        self.built = []

    def __call__(self, scene):
        self.built.append(len(scene))
        return PreparedPlanner(scene).start(background=False)


class RecordingLock:
    """A lock that records whether it is held when asked."""

    def __init__(self):
        self._lock = threading.Lock()
        self.acquired = 0

    def __enter__(self):
        self._lock.acquire()
        self.acquired += 1
        return self

    def __exit__(self, *exc):
        self._lock.release()

    def locked(self):
        return self._lock.locked()


GOAL, LOOK = np.array([0.0, 0.0, 0.5]), np.zeros(3)


def locate_first_half(text):
    mask = np.zeros(300, bool)
    mask[:150] = True
    return np.array([0.0, 0.0, 0.0]), mask


def test_splat_model_backend_caches_per_step():
    model, planners = TinySplatModel(), Planners()
    backend = SplatModelBackend(model, planners, locate_fn=locate_first_half)
    assert isinstance(backend, PanelBackend)
    assert len(backend.gaussians()) == 300
    shots = backend.plan(GOAL, LOOK, seed=0)
    assert len(shots) == 1 and isinstance(shots[0].positions, np.ndarray) and shots[0].clearance.min() >= 0
    backend.plan(GOAL, LOOK, seed=1)
    assert planners.built == [300]  # reused while the step did not change
    model.step = 10
    backend.plan(GOAL, LOOK, seed=0)
    assert planners.built == [300, 300]
    c, m = backend.locate("anything")
    assert m.sum() == 150
    with pytest.raises(ValueError, match="empty query"):
        backend.locate("  ")
    no_sem = SplatModelBackend(model, planners)
    with pytest.raises(ValueError, match="coordinates"):
        no_sem.locate("the chair")


def test_snapshot_is_a_copy_taken_under_the_lock_and_planning_does_not_hold_it():
    model, lock = TinySplatModel(), RecordingLock()
    held_during_plan = []

    class Spy:
        def __init__(self, scene):
            self.inner = PreparedPlanner(scene).start(background=False)

        def wait_ready(self):
            return True

        def plan(self, *a, **k):
            held_during_plan.append(lock.locked())
            return self.inner.plan(*a, **k)

    backend = SplatModelBackend(model, Spy, lock=lock)
    shots = backend.plan(GOAL, LOOK)
    assert lock.acquired == 1 and held_during_plan == [False] and len(shots) == 1
    snap = backend._current("snapshot")
    with torch.no_grad():
        model.means.add_(1.0)  # training moves the Gaussians after the snapshot ...
    assert np.array_equal(snap.splat.means + 1.0, model.means.detach().numpy())  # ... the snapshot is a copy
    assert snap.splat.means.dtype == np.float32 and snap.splat.opacity_logits.shape == (300,)
    model.step = 1
    backend.gaussians()
    assert lock.acquired == 2  # a new step: a new snapshot, again under the lock


def test_attach_gives_the_train_lock_to_the_model_backend(tmp_path):
    import viser

    from cinenerf_ns.viewer.nerfstudio_panel import attach_to_nerfstudio_viewer

    model, lock = TinySplatModel(), RecordingLock()
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        viewer = SimpleNamespace(viser_server=server, datapath=tmp_path, log_filename=tmp_path / "log.txt",
                                 train_lock=lock)
        panel = attach_to_nerfstudio_viewer(viewer, SplatModelBackend(model, Planners()))
        assert isinstance(panel.backend, SplatModelBackend) and panel.backend.lock is lock
        assert lock.acquired == 1  # the panel read the Gaussians (scene extent) through a locked snapshot
        panel.close()
    finally:
        server.stop()


def test_attach_gives_the_model_backend_the_training_cameras_as_start_region(tmp_path):
    """In ns-train / ns-viewer the panel's random starts come from the training cameras' box (+ 0.1), as
    cinesplat-plan's do; a backend whose planner config already has a region keeps it, and a viewer without cameras
    sets none."""
    import viser

    from cinenerf_ns.planner.shots.planner import PlannerConfig
    from cinenerf_ns.viewer.nerfstudio_panel import attach_to_nerfstudio_viewer

    t = torch.tensor([[0.1, -0.2, 0.3], [0.5, 0.4, -0.1], [-0.3, 0.0, 0.2]])
    c2w = torch.cat([torch.eye(3).expand(3, 3, 3), t[:, :, None]], dim=-1)  # [3, 3, 4]
    cams = SimpleNamespace(camera_to_worlds=c2w)
    pipeline = SimpleNamespace(datamanager=SimpleNamespace(train_dataset=SimpleNamespace(cameras=cams)))
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        got, cams_seen = [], []
        with_region = PlannerConfig(start_region=([0, 0, 0], [1, 1, 1]))
        for pipe, cfg in ((pipeline, None), (pipeline, with_region), (None, None)):
            viewer = SimpleNamespace(viser_server=server, datapath=tmp_path, log_filename=tmp_path / "log.txt",
                                     train_lock=RecordingLock(), **({} if pipe is None else {"pipeline": pipe}))
            backend = SplatModelBackend(TinySplatModel(), Planners(), planner_config=cfg)
            panel = attach_to_nerfstudio_viewer(viewer, backend)
            got.append(None if backend.planner_config is None else backend.planner_config.start_region)
            cams_seen.append(backend.camera_centres)
            panel.close()
        # the semantic scene's unseen fill gets the cameras themselves
        np.testing.assert_allclose(cams_seen[0], t.double().numpy())
        assert cams_seen[2] is None
        np.testing.assert_allclose(got[0][0], t.double().numpy().min(0) - 0.1)
        np.testing.assert_allclose(got[0][1], t.double().numpy().max(0) + 0.1)
        assert got[1] == ([0, 0, 0], [1, 1, 1]) and got[2] is None
    finally:
        server.stop()


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
    import viser
    from nerfstudio.viewer.utils import parse_object
    from nerfstudio.viewer.viewer_elements import ViewerControl

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
        panel = model.cine_panel.panels.server_panel()
        assert isinstance(panel, CinePanel) and panel.backend.lock is viewer.train_lock
        assert panel.config.data_dir == tmp_path / "data"
        assert panel.config.config_path == tmp_path / "run" / "config.yml"
        res = panel.request_plan("0 0 0.5", "0 0 0").result(60)
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
        panel = model.cine_panel.panels.server_panel()
        assert isinstance(panel, CinePanel)
        assert viewer.viser_server._cine_guard is not None  # what pages send is checked in ns-viewer too
        assert panel.config.data_dir == tmp_path / "data"
        assert panel.config.config_path == tmp_path / "run" / "config.yml"
        assert panel.request_plan("0 0 0.5", "0 0 0").result(60) is not None, panel.status
        assert panel.export("ns-take").path == tmp_path / "data" / "camera_paths" / "ns-take.json"
        panel.close()
    finally:
        viewer.viser_server.stop()


def test_model_semantic_scene_gets_the_training_cameras():
    """The ns-viewer panel's SemanticScene (model_semantic_scene) carries the training cameras the panel read, so its
    volume centres fill what no camera saw as cinesplat-plan's do; without cameras it has none; no codec: no scene."""
    from cinenerf_ns.viewer.nerfstudio_panel import ModelSnapshot, model_semantic_scene

    class Codec(torch.nn.Module):
        def decode(self, latents):
            return latents

    n = 6
    model = SimpleNamespace(codec=Codec(), text_encoder=lambda: (lambda texts: torch.ones(len(texts), 3)),
                            cine_info={"label_names": ["a"]})
    splat = SplatParams.of(torch.rand(n, 3), torch.tensor([[1.0, 0, 0, 0]] * n), torch.zeros(n, 3), torch.zeros(n),
                           latents=torch.rand(n, 3))
    snap = ModelSnapshot(version=(0, n), splat=splat)
    cams = np.array([[0.0, 0.0, 1.0], [1.0, 2.0, 3.0]])
    box = {"c": cams}
    build = model_semantic_scene(model, lambda: box["c"])
    np.testing.assert_array_equal(build(snap).camera_centres, cams)
    box["c"] = None  # read per snapshot
    assert build(snap).camera_centres is None
    assert model_semantic_scene(model)(snap).camera_centres is None
    assert model_semantic_scene(SimpleNamespace(codec=None))(snap) is None


def test_model_backend_plans_with_the_safety_margin():
    """The ns-viewer panel keeps cinesplat-plan's and cinesplat-viewer's distance from the scene: the camera radius
    plus the safety margin (it planned with the bare radius)."""
    from cinenerf_ns.planner.scene.scene_config import DEFAULT_SAFETY_MARGIN, SceneConfig

    scene, _ = SplatModelBackend(TinySplatModel(), Planners())._current("planner")
    assert scene.camera_radius == pytest.approx(SceneConfig.camera_radius + DEFAULT_SAFETY_MARGIN)


def test_model_semantic_scene_answers_text_as_cinesplat_plan_and_the_standalone_viewer(tmp_path):
    """The ns-viewer panel's text queries use the settings of cinesplat-plan / cinesplat-viewer (scenes.load_scene:
    latents smoothed over SMOOTH_NEIGHBORS neighbours, the heaviest OBJECT_CLUSTER cluster...): the same text picks
    the same Gaussians and centre in both viewers (the panel did no smoothing)."""
    import re

    from test_standalone import compact_scene_with_labels

    from cinenerf_ns.method.checkpoint import load_compact
    from cinenerf_ns.method.relevancy import QueryError
    from cinenerf_ns.planner.scene.scene_config import SceneConfig
    from cinenerf_ns.scenes import load_scene
    from cinenerf_ns.semantic_defaults import SMOOTH_NEIGHBORS
    from cinenerf_ns.viewer.nerfstudio_panel import ModelSnapshot, model_semantic_scene

    path = compact_scene_with_labels(tmp_path / "scene_compact.pt", 4)
    cli = load_scene(str(path), SceneConfig()).semantics.semantic
    st = load_compact(path)
    names = st.info["label_names"]
    model = SimpleNamespace(codec=st.codec, text_encoder=lambda: cli.text_encoder, cine_info={"label_names": names})
    panel = model_semantic_scene(model)(ModelSnapshot(version=(0, len(st.params.means)), splat=st.params))
    settings = ("smooth_neighbors", "cluster_fraction", "centre", "drop_support", "centre_relevancy", "threshold",
                "temperature", "negatives", "up", "min_opacity")
    assert {k: getattr(panel, k) for k in settings} == {k: getattr(cli, k) for k in settings}
    assert panel.smooth_neighbors == SMOOTH_NEIGHBORS > 1
    answered = 0
    for name in names:
        try:
            b = cli.locate_full(name)
        except QueryError as e:  # matches nothing: the panel says the same
            with pytest.raises(QueryError, match=re.escape(str(e))):
                panel.locate_full(name)
            continue
        a = panel.locate_full(name)
        assert torch.equal(a.mask, b.mask) and torch.allclose(a.centroid, b.centroid)
        answered += 1
    assert answered >= 1
