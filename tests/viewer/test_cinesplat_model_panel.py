"""The real CineSplatModel (built on CPU, as in tests/method) carries the cinematography control:
nerfstudio's own Viewer finds it and installs the panel; the panel plans with the real planner on a
snapshot of the model's Gaussians and answers text through the model's latents + codec."""
from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from _xdist import free_port
from nerfstudio.data.scene_box import SceneBox
from torch import nn

from cinenerf_ns.method.codec import CodecConfig, FeatureCodec
from cinenerf_ns.method.model import META_CODEC_STATE, META_INFO, CineSplatModel, CineSplatModelConfig
from cinenerf_ns.method.semantic_scene import SemanticScene
from cinenerf_ns.semantic_defaults import OBJECT_CLUSTER, SMOOTH_NEIGHBORS
from cinenerf_ns.viewer.nerfstudio_panel import CinePanelControl, SplatModelBackend
from cinenerf_ns.viewer.panel import CinePanel

torch.set_num_threads(1)
D = 16


def make_model(n=200, panel=True, codec=True) -> CineSplatModel:
    meta = {}
    if codec:
        info = {
            "feature_dim": D, "codec_config": vars(CodecConfig(hidden_dim=16, train_steps=1)), "feature_long_side": 32,
            "source": "labels", "clip": None, "label_names": ["red chair", "lamp", "floor"],
        }
        torch.manual_seed(0)
        meta = {META_CODEC_STATE: FeatureCodec(D, CodecConfig(hidden_dim=16, train_steps=1)).state_dict(),
                META_INFO: info, "label_embeddings": torch.nn.functional.normalize(torch.randn(3, D), dim=-1)}
    # offline: the negatives are a label too (no CLIP weights needed)
    cfg = CineSplatModelConfig(random_init=True, num_random=n, random_scale=2.0, lpips="off", viewer_cine_panel=panel,
                               relevancy_negatives=("floor",), relevancy_threshold=0.05)
    box = SceneBox(aabb=torch.tensor([[-1.0, -1, -1], [1, 1, 1]]))
    m = CineSplatModel(cfg, scene_box=box, num_train_data=3, metadata=meta)
    with torch.no_grad():  # small opaque Gaussians; latents spread so some Gaussians match a label, and varying
        # smoothly in space: the text queries average each latent over its nearest Gaussians (SMOOTH_NEIGHBORS)
        m.gauss_params["scales"].fill_(float(np.log(0.02)))
        m.gauss_params["opacities"].fill_(3.0)
        means = m.gauss_params["means"]
        m.gauss_params["latents"].copy_((2 * means / means.abs().max()).clamp(-1, 1))
    return m


def test_model_declares_the_control_only_when_enabled():
    assert isinstance(make_model(panel=True, codec=False).cine_panel, CinePanelControl)
    assert not hasattr(make_model(panel=False, codec=False), "cine_panel")


def test_nerfstudio_viewer_installs_panel_on_cinesplat_model(tmp_path):
    from nerfstudio.configs.base_config import ViewerConfig
    from nerfstudio.viewer.viewer import Viewer

    model = make_model()

    class Pipeline(nn.Module):
        def __init__(self):
            super().__init__()
            self.model = model
            self.datamanager = SimpleNamespace(includes_time=False)

    lock = threading.Lock()
    viewer = Viewer(
        ViewerConfig(websocket_port=free_port(), websocket_host="127.0.0.1"),
        log_filename=tmp_path / "run" / "viewer_log_filename.txt", datapath=tmp_path / "data",
        pipeline=Pipeline(), train_lock=lock,
    )
    try:
        panel = model.cine_panel.panels.server_panel()
        assert isinstance(panel, CinePanel)
        backend = panel.backend
        assert isinstance(backend, SplatModelBackend) and backend.lock is lock and backend.model is model
        assert backend.planner_name == "cinenerf_ns planner"
        res = panel.request_plan("0 0 0.3", "0 0 0", n_candidates=2).result(120)
        assert res is not None, panel.status
        assert "Planned" in panel.status and "timings" not in panel.status
        details = panel.view.details_text  # internals go to the details fold, not the status line
        assert "cinenerf_ns planner" in details
        assert "prepare " in details  # the first Plan on a snapshot reports the one-time prepare()
        for s in res.shots:
            assert s.clearance.min() >= 0 and s.safety["safe"]
        out = panel.export("model-take")
        assert out is not None and out.path == tmp_path / "data" / "camera_paths" / "model-take.json"

        # text: the same answer (or the same readable refusal) as a SemanticScene over the model's own tensors
        with torch.no_grad():
            ref = SemanticScene(model.means.detach(), torch.sigmoid(model.opacities.detach()).reshape(-1),
                                model.latents.detach(), model.codec, model.text_encoder(),
                                negatives=model.config.relevancy_negatives,
                                temperature=model.config.relevancy_temperature,
                                threshold=model.config.relevancy_threshold, smooth_neighbors=SMOOTH_NEIGHBORS,
                                cluster_fraction=OBJECT_CLUSTER)
        matched = 0
        for text in ["red chair", "the lamp", "sofa"]:
            query = "lamp" if "lamp" in text else text  # cinesplat-plan's word -> label-name mapping
            if text == "sofa":  # no label: goes to the CLIP tower, which this offline scene has none of
                with pytest.raises(ValueError, match="answers only its own object names"):
                    backend.locate(text)
                continue
            try:
                c_ref, m_ref = ref.locate(query)
            except ValueError as err:
                with pytest.raises(ValueError, match="nothing in the scene matches"):
                    backend.locate(text)
                assert "nothing in the scene matches" in str(err)
                continue
            c, m = backend.locate(text)[:2]
            np.testing.assert_allclose(c, c_ref.numpy(), atol=1e-5)
            assert np.array_equal(m, m_ref.numpy())
            matched += 1
        assert matched >= 1, "no label matched"  # the latents (position-based) make "red chair" and "the lamp" match
        assert panel.request_plan("", "lamp").result(30) is None and "'Go to' is empty" in panel.status
        panel.close()
    finally:
        viewer.viser_server.stop()


def test_model_without_codec_asks_for_coordinates():
    model = make_model(codec=False)
    backend = model.cine_panel._backend_factory()
    with pytest.raises(ValueError, match="coordinates"):
        backend.locate("the chair")
    shots = backend.plan(np.array([0.0, 0.0, 0.3]), np.zeros(3), seed=2)
    assert len(shots) == 1 and shots[0].clearance.min() >= 0
