"""CineSplatModel.get_outputs / get_loss_dict end to end on CPU, with gsplat's rasterization replaced by the
float64 reference (gsplat itself needs CUDA; tests/method/test_model_gpu.py checks the real kernels against the
same reference). Checks the latent pass wiring: resolution, detached geometry, eval outputs, fused mode."""
from __future__ import annotations

import pytest
import torch

from cinenerf_ns.method.codec import CodecConfig, FeatureCodec
from cinenerf_ns.method.render_reference import render_reference


def fake_rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height, render_mode="RGB",
                       sh_degree=None, **kw):
    assert sh_degree is None, "tests use sh_degree=0 (colours, no SH evaluation)"
    vm = viewmats[0]
    if render_mode == "RGB+ED":
        z = (means @ vm[:3, :3].T + vm[:3, 3])[:, 2:3]
        colors = torch.cat([colors, z], -1)
    img, acc = render_reference(means, quats, scales, opacities, colors, vm, Ks[0], width, height)
    n = means.shape[0]
    # the fields the "shared" latent pass reads (2D means / conics are stand-ins; opacities are the real ones, with
    # their autograd graph, as gsplat's meta["opacities"] has); the 3D geometry rides along for fake_r2p
    info = {"means2d": torch.zeros(1, n, 2, requires_grad=True), "width": width, "height": height, "n_cameras": 1,
            "radii": torch.ones(1, n, 2), "gaussian_ids": None, "conics": means[None, :, :3] * 0 + 1,
            "opacities": opacities[None], "tile_size": 16, "isect_offsets": torch.zeros(1, 1, 1, dtype=torch.int32),
            "flatten_ids": torch.zeros(0, dtype=torch.int32),
            "_geometry": (means.detach(), quats.detach(), scales.detach(), vm.detach(), Ks[0].detach())}
    FAKE_STATE["info"] = info
    return img[None].float(), acc[None].float(), info


FAKE_STATE: dict = {}


def fake_rasterize_to_pixels(means2d, conics, colors, opacities, width, height, tile_size, isect_offsets, flatten_ids,
                             backgrounds=None, masks=None, packed=False, absgrad=False):
    """gsplat's rasterize_to_pixels on the last fake_rasterization call's geometry. The geometry it receives must be
    DETACHED (the shared latent pass gives the latent loss no path to it): checked here."""
    assert not packed and backgrounds is None
    for name, t in (("means2d", means2d), ("conics", conics), ("opacities", opacities)):
        assert not t.requires_grad, f"shared latent pass: {name} not detached"
    info = FAKE_STATE["info"]
    assert width == info["width"] and height == info["height"] and flatten_ids is info["flatten_ids"]
    means, quats, scales, vm, K = info["_geometry"]
    assert colors.shape == (1, means.shape[0], colors.shape[-1])
    img, acc = render_reference(means, quats, scales, opacities[0], colors[0], vm, K, width, height)
    return img[None].float(), acc[None].float()


@pytest.fixture
def cpu_gsplat(monkeypatch):
    import gsplat.rendering
    import nerfstudio.models.splatfacto as sf

    import cinenerf_ns.method.model as cm

    monkeypatch.setattr(sf, "rasterization", fake_rasterization)
    monkeypatch.setattr(cm, "rasterize_to_pixels", fake_rasterize_to_pixels)
    monkeypatch.setattr(gsplat.rendering, "rasterization", fake_rasterization)
    plain = getattr(sf.get_viewmat, "_torchdynamo_orig_callable", sf.get_viewmat)  # skip torch.compile on CPU
    monkeypatch.setattr(sf, "get_viewmat", plain)
    monkeypatch.setattr(cm, "get_viewmat", plain)
    monkeypatch.setattr(torch.Tensor, "cuda", lambda self, *a, **k: self)  # splatfacto hard-codes K.cuda()


def _model(n=60, **kw):
    from nerfstudio.data.scene_box import SceneBox

    from cinenerf_ns.method.model import META_CODEC_STATE, META_INFO, CineSplatModel, CineSplatModelConfig

    cc = CodecConfig(hidden_dim=16, backend="torch")
    codec = FeatureCodec(16, cc)
    meta = {META_CODEC_STATE: codec.state_dict(),
            META_INFO: {"feature_dim": 16, "codec_config": vars(cc), "feature_long_side": 8, "source": "clip",
                        "clip": None}}
    kw.setdefault("num_downscales", 1)
    cfg = CineSplatModelConfig(random_init=True, num_random=n, lpips="off", sh_degree=0, background_color="black", **kw)
    m = CineSplatModel(cfg, scene_box=SceneBox(aabb=torch.tensor([[-1.0, -1, -1], [1, 1, 1]])), num_train_data=2,
                       metadata=meta)
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():
        m.gauss_params["means"].copy_(torch.stack([torch.rand(n, generator=g) - 0.5, torch.rand(n, generator=g) - 0.5,
                                                   -1.5 - torch.rand(n, generator=g)], -1))
        m.gauss_params["scales"].copy_(torch.log(0.08 + 0.1 * torch.rand(n, 3, generator=g)))
        m.gauss_params["opacities"].fill_(2.0)
        m.gauss_params["latents"].copy_(torch.rand(n, 3, generator=g) * 2 - 1)
    m.optimizers = {}
    m.strategy_state = m.strategy.initialize_state(scene_scale=1.0)
    return m


def _camera(w=16, h=12, f=30.0):
    from nerfstudio.cameras.cameras import Cameras, CameraType

    return Cameras(camera_to_worlds=torch.eye(4)[:3][None], fx=f, fy=f, cx=w / 2, cy=h / 2, width=w, height=h,
                   camera_type=CameraType.PERSPECTIVE)


@pytest.mark.parametrize("mode,resolution", [("shared", "image"), ("separate", "feature"), ("separate", "image")])
def test_training_latent_pass_with_detached_geometry(cpu_gsplat, mode, resolution):  # shared + image: the default
    from cinenerf_ns.method.feature_grid import feature_map_size

    m = _model(latent_render_mode=mode, latent_render_resolution=resolution)
    m.train()
    m.step = 0
    out = m.get_outputs(_camera())
    assert out["rgb"].shape == (6, 8, 3)  # splatfacto's pass at 1/2 resolution (num_downscales=1)
    # the feature map here is 8 px long = splatfacto's 1/2 image: both modes render 6 x 8
    assert out["latent"].shape == (*feature_map_size(12, 16, 8), 3) == (6, 8, 3)
    batch = {"image": torch.rand(12, 16, 3), "latent_target": torch.full((6, 8, 3), 0.25)}
    losses = m.get_loss_dict(out, batch)
    params = [m.gauss_params[k] for k in ("means", "scales", "quats", "opacities", "latents")]
    grads = torch.autograd.grad(losses["latent_loss"], params, allow_unused=True)
    for name, g in zip(("means", "scales", "quats", "opacities"), grads[:4]):
        assert g is None or float(g.abs().sum()) == 0.0, name
    assert grads[4] is not None and float(grads[4].abs().sum()) > 0
    # the RGB loss still trains the geometry
    g_rgb = torch.autograd.grad(losses["main_loss"], [m.gauss_params["means"]], allow_unused=True)[0]
    assert g_rgb is not None and float(g_rgb.abs().sum()) > 0


def test_latent_start_step_and_every(cpu_gsplat):
    m = _model(latent_start_step=10, latent_every=3)
    m.train()
    seen = []
    for step in (0, 9, 10, 11, 13):
        m.step = step
        seen.append("latent" in m.get_outputs(_camera()))
    assert seen == [False, False, True, False, True]


def test_the_default_runs_the_latent_pass_every_second_step(cpu_gsplat):
    m = _model()
    m.train()
    seen = []
    for step in range(4):
        m.step = step
        seen.append("latent" in m.get_outputs(_camera()))
    assert seen == [True, False, True, False]


def test_latents_fit_a_target_by_gradient_descent(cpu_gsplat):
    m = _model(latent_every=1)  # a latent loss on every step of the loop
    m.train()
    opt = torch.optim.Adam([m.gauss_params["latents"]], lr=0.05)
    target = torch.tensor([0.4, -0.3, 0.6]).expand(6, 8, 3)
    batch = {"image": torch.rand(12, 16, 3), "latent_target": target}
    first = None
    for step in range(40):
        m.step = step
        loss = m.get_loss_dict(m.get_outputs(_camera()), batch)["latent_loss"]
        first = float(loss) if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss) < 0.1 * first


def test_shared_and_separate_modes_give_the_same_image_and_latent_gradient(cpu_gsplat):
    m = _model(latent_render_resolution="image")
    m.train()
    m.step = 0
    batch = {"image": torch.rand(12, 16, 3), "latent_target": torch.rand(6, 8, 3) * 2 - 1}
    res = {}
    for mode in ("shared", "separate"):
        m.config.latent_render_mode = mode
        out = m.get_outputs(_camera())
        loss = m.get_loss_dict(out, batch)["latent_loss"]
        res[mode] = (out["latent"], torch.autograd.grad(loss, [m.gauss_params["latents"]])[0])
    assert res["shared"][0].shape == (6, 8, 3)
    assert torch.allclose(res["shared"][0], res["separate"][0], atol=1e-6)
    assert torch.allclose(res["shared"][1], res["separate"][1], atol=1e-7)
    assert float(res["shared"][1].abs().sum()) > 0


def test_training_step_reads_camera_sizes_once_per_camera(cpu_gsplat, monkeypatch):
    # a training camera lives on the GPU, where .item() waits for all queued work: after a camera's first step the
    # latent pass and its loss read no tensor value (the two reads left are splatfacto's own width / height)
    m = _model()
    m.train()
    m.step = 0
    cam = _camera()
    cam.metadata = {"cam_idx": 3}
    batch = {"image": torch.rand(12, 16, 3), "latent_target": torch.rand(6, 8, 3), "latent_all_valid": True,
             "latent_valid": torch.ones(6, 8, 1, dtype=torch.bool)}
    m.get_loss_dict(m.get_outputs(cam), batch)
    assert m._train_camera_hw == {3: (12, 16)}
    reads = []
    orig_item = torch.Tensor.item
    monkeypatch.setattr(torch.Tensor, "item", lambda t: reads.append(t.shape) or orig_item(t))
    for mode in ("shared", "separate"):
        reads.clear()
        m.config.latent_render_mode = mode
        cam = _camera()
        cam.metadata = {"cam_idx": 3}
        losses = m.get_loss_dict(m.get_outputs(cam), batch)
        assert "latent_loss" in losses and len(reads) == 2, (mode, reads)


def test_all_valid_flag_skips_the_mask_with_the_same_loss(cpu_gsplat):
    m = _model()
    m.train()
    m.step = 0
    out = m.get_outputs(_camera())
    target = torch.rand(6, 8, 3)
    ones = torch.ones(6, 8, 1, dtype=torch.bool)
    masked = m.get_loss_dict(out, {"image": torch.rand(12, 16, 3), "latent_target": target, "latent_valid": ones})
    flag = m.get_loss_dict(out, {"image": torch.rand(12, 16, 3), "latent_target": target, "latent_valid": ones,
                                 "latent_all_valid": True})
    assert torch.allclose(masked["latent_loss"], flag["latent_loss"])
    # the flag off: the mask counts (half the pixels invalid -> the loss over the other half)
    half = ones.clone()
    half[:3] = False
    part = m.get_loss_dict(out, {"image": torch.rand(12, 16, 3), "latent_target": target, "latent_valid": half,
                                 "latent_all_valid": False})
    err = ((out["latent"] - target) ** 2).sum(-1)[3:].mean() / 3
    assert torch.allclose(part["latent_loss"], err)


def test_image_resolution_and_fused_modes_agree(cpu_gsplat):
    m = _model(latent_render_resolution="image", latent_render_mode="separate")
    m.train()
    m.step = 0
    sep = m.get_outputs(_camera())
    assert sep["latent"].shape == (6, 8, 3)
    m.config.latent_render_mode = "fused"
    fused = m.get_outputs(_camera())
    assert torch.allclose(sep["latent"], fused["latent"], atol=1e-6)
    assert torch.allclose(sep["rgb"], fused["rgb"], atol=1e-6)
    # fused: the latent loss reaches the geometry (documented approximation of eq. 3)
    batch = {"image": torch.rand(12, 16, 3), "latent_target": torch.full((6, 8, 3), 0.25)}
    lat_loss = m.get_loss_dict(fused, batch)["latent_loss"]
    g = torch.autograd.grad(lat_loss, [m.gauss_params["opacities"]], allow_unused=True)[0]
    assert g is not None and float(g.abs().sum()) > 0


def test_eval_outputs_latent_and_relevancy(cpu_gsplat):
    m = _model()
    m.eval()
    words = ["chair", "object", "things", "stuff", "texture"]
    table = torch.nn.functional.normalize(torch.randn(5, 16), dim=-1)
    m._text_encoder = lambda texts: table[[words.index(t) for t in texts]]
    out = m.get_outputs_for_camera(_camera())
    assert out["latent"].shape == (12, 16, 3) and float(out["relevancy"].abs().sum()) == 0
    m.set_query("chair")
    out = m.get_outputs_for_camera(_camera())
    rel_g = m.query_relevancy()
    # a pixel's relevancy is the alpha-normalised blend of the Gaussians' relevancies: within their range
    r = out["relevancy"][out["accumulation"] > 0.5]
    assert float(r.min()) >= float(rel_g.min()) - 1e-5 and float(r.max()) <= float(rel_g.max()) + 1e-5
    assert out["latent"].min() >= 0 and out["latent"].max() <= 1


def test_image_mode_renders_at_the_feature_map_when_splatfactos_pass_is_smaller(cpu_gsplat):
    # early in training splatfacto renders at 1/2^k of the image: pooling that to a larger feature map would
    # upsample, so the latent pass renders at the feature map's own size then
    m = _model(latent_render_resolution="image")
    m.cine_info["feature_long_side"] = 16
    m.train()
    m.step = 0
    out = m.get_outputs(_camera())
    assert out["rgb"].shape == (6, 8, 3)
    assert out["latent"].shape == (12, 16, 3)
