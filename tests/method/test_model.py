"""CineSplatModel constructs offline on CPU, carries latents in its optimizer groups, round-trips its state."""
from __future__ import annotations

import torch
from nerfstudio.data.scene_box import SceneBox

from cinenerf_ns.method.codec import CodecConfig, FeatureCodec
from cinenerf_ns.method.compat import UnavailableLPIPS
from cinenerf_ns.method.model import META_CODEC_STATE, META_INFO, CineSplatModel, CineSplatModelConfig


def _make(metadata=None, n=64, lpips="cached"):
    cfg = CineSplatModelConfig(random_init=True, num_random=n, lpips=lpips)
    box = SceneBox(aabb=torch.tensor([[-1.0, -1, -1], [1, 1, 1]]))
    return CineSplatModel(cfg, scene_box=box, num_train_data=3, metadata=metadata or {})


def _meta(D=16):
    codec = FeatureCodec(D, CodecConfig(hidden_dim=16, train_steps=1))
    info = {
        "feature_dim": D,
        "codec_config": vars(CodecConfig(hidden_dim=16, train_steps=1)),
        "feature_long_side": 32,
        "source": "labels",
        "clip": {"model_name": "RN50", "pretrained": "", "checkpoint_path": None, "random_weights": True,
                 "random_seed": 0},
        "label_names": ["a", "b"],
    }
    return {META_CODEC_STATE: codec.state_dict(), META_INFO: info, "label_embeddings": torch.randn(2, D)}, codec


def test_constructs_offline_with_latents():
    m = _make()
    assert m.gauss_params["latents"].shape == (64, 3)
    groups = m.get_gaussian_param_groups()
    assert "latents" in groups and groups["latents"][0] is m.gauss_params["latents"]
    # no network on this box and no cached AlexNet: the stand-in is used and the metric dropped
    from cinenerf_ns.method.compat import lpips_weights_cached

    assert isinstance(m.lpips, UnavailableLPIPS) != lpips_weights_cached()


def test_state_roundtrip_resizes_latents_and_restores_codec():
    meta, codec = _meta()
    m = _make(meta, n=64)
    with torch.no_grad():
        m.gauss_params["latents"].copy_(torch.randn(64, 3))
    sd = m.state_dict()
    assert "_extra_state" in sd and "codec.enc.0.weight" in sd
    # a model built without metadata (as in ns-render) with a different point count
    m2 = _make({}, n=10)
    assert m2.codec is None
    m2.load_state_dict(dict(sd))
    assert m2.gauss_params["latents"].shape == (64, 3)
    assert torch.equal(m2.gauss_params["latents"], m.gauss_params["latents"])
    assert m2.codec is not None
    x = torch.randn(5, 3)
    assert torch.allclose(m2.codec.decode(x), codec.decode(x))
    assert m2.cine_info["label_names"] == ["a", "b"]
    assert m2.label_embeddings.shape == (2, 16)


def test_loads_plain_splatfacto_state():
    m = _make(n=20)
    sd = {k: v for k, v in m.state_dict().items()
          if "latents" not in k and k not in ("_extra_state", "label_embeddings")}
    m2 = _make(n=5)
    m2.load_state_dict(sd)
    assert m2.gauss_params["latents"].shape == (20, 3)
    assert float(m2.gauss_params["latents"].detach().abs().sum()) == 0.0


def test_latent_loss_masked_mse_and_metrics_without_lpips():
    meta, _ = _meta()
    m = _make(meta, n=16)
    m.train()
    m.step = 0
    H, W = 8, 12
    outputs = {
        "rgb": torch.rand(H, W, 3),
        "background": torch.zeros(3),
        "latent": torch.zeros(4, 6, 3, requires_grad=True),
    }
    target = torch.ones(4, 6, 3) * 0.5
    valid = torch.ones(4, 6, 1, dtype=torch.bool)
    valid[0] = False  # one row ignored
    target[0] = 100.0  # would dominate if it were not masked
    batch = {"image": (torch.rand(H * 4, W * 4, 3) * 255).to(torch.uint8), "latent_target": target,
             "latent_valid": valid}
    losses = m.get_loss_dict(outputs, batch)
    assert torch.allclose(losses["latent_loss"], torch.tensor(0.25))  # mean of 0.5^2 over valid pixels/channels
    losses["latent_loss"].backward()
    assert outputs["latent"].grad[0].abs().sum() == 0 and outputs["latent"].grad[1:].abs().sum() > 0
    # a latent render at a different size is area-pooled to the target grid
    outputs["latent"] = torch.zeros(8, 12, 3)
    assert torch.allclose(m.get_loss_dict(outputs, batch)["latent_loss"], torch.tensor(0.25))
    m.eval()
    metrics, images = m.get_image_metrics_and_images({"rgb": torch.rand(H, W, 3), "background": torch.zeros(3)},
                                                     {"image": torch.rand(H, W, 3)})
    assert "psnr" in metrics and ("lpips" in metrics) != isinstance(m.lpips, UnavailableLPIPS)


def test_viewer_query_element_and_relevancy_without_gpu():
    from nerfstudio.viewer.viewer_elements import ViewerText

    meta, codec = _meta()
    m = _make(meta, n=16)
    assert isinstance(m.viewer_query, ViewerText)
    table = torch.nn.functional.normalize(torch.randn(6, 16), dim=-1)
    words = ["a", "object", "things", "stuff", "texture", "b"]
    m._text_encoder = lambda texts: table[[words.index(t) for t in texts]]
    assert m.query_relevancy() is None  # no query yet
    m.set_query("a")
    rel = m.query_relevancy()
    assert rel.shape == (16,) and ((rel > 0) & (rel < 1)).all()
    assert m.query_relevancy() is rel  # cached until the query, the point count or the step changes
    m.step += 1
    assert m.query_relevancy() is not rel
