"""CineSplatDatamanager on the real fox capture (CPU): targets per training image, metadata for the model,
feature cache reused by a second set-up."""
from __future__ import annotations

import pytest
import torch

pytestmark = [pytest.mark.fox, pytest.mark.slow]


def _dm_config(fox_dir, tmp_path, model_name):
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    from cinenerf_ns.method.clip_features import ClipFeatureConfig
    from cinenerf_ns.method.codec import CodecConfig
    from cinenerf_ns.method.datamanager import CineSplatDatamanagerConfig

    return CineSplatDatamanagerConfig(
        data=fox_dir,
        dataparser=NerfstudioDataParserConfig(data=fox_dir, downscale_factor=4, load_3D_points=True),
        cache_images="gpu",  # "cpu" pins memory (needs CUDA); with device="cpu" "gpu" just keeps them on the CPU
        cache_images_type="uint8",
        clip=ClipFeatureConfig(model_name=model_name, random_weights=True, input_long_sides=(64,),
                               feature_long_side=16),
        codec=CodecConfig(train_steps=50, batch_size=1024, hidden_dim=16, backend="torch"),
        feature_cache_dir=tmp_path / "cache",
    )


def test_fox_targets_metadata_and_cache(fox_dir, tmp_path, tiny_clip_models):
    from nerfstudio.data.scene_box import SceneBox

    from cinenerf_ns.method.feature_grid import feature_map_size
    from cinenerf_ns.method.model import META_CODEC_STATE, META_INFO, CineSplatModel, CineSplatModelConfig

    cfg = _dm_config(fox_dir, tmp_path, tiny_clip_models[0])
    dm = cfg.setup(device="cpu", test_mode="val")
    n = len(dm.train_dataset)
    assert len(dm.latent_targets) == n == len(dm.latent_valid)
    cam, batch = dm.next_train(0)
    H, W = int(cam.height.item()), int(cam.width.item())
    assert batch["image"].shape[:2] == (H, W)
    assert tuple(batch["latent_target"].shape) == (*feature_map_size(H, W, 16), 3)
    assert batch["latent_target"].abs().max() <= 1.0
    assert batch["latent_all_valid"] is True and bool(batch["latent_valid"].all())  # CLIP: every pixel (no mask work)
    meta = dm.train_dataset.metadata
    assert META_CODEC_STATE in meta and meta[META_INFO]["feature_dim"] == 32
    assert not dm.semantic_stats["cache_hit"]
    # the model picks the codec up from the metadata (as VanillaPipeline passes it)
    m = CineSplatModel(
        CineSplatModelConfig(random_init=True, num_random=100, lpips="off"),
        scene_box=SceneBox(aabb=torch.tensor([[-1.0, -1, -1], [1, 1, 1]])),
        num_train_data=n,
        metadata=meta,
    )
    assert m.codec is not None and m.cine_info["feature_long_side"] == 16
    assert m._latent_target_size(cam) == tuple(batch["latent_target"].shape[:2])
    # inference mode (ns-render / ns-viewer) computes nothing
    dm_inf = cfg.setup(device="cpu", test_mode="inference")
    assert dm_inf.latent_targets == []
    # a second training set-up reuses the cached features
    dm2 = _dm_config(fox_dir, tmp_path, tiny_clip_models[0]).setup(device="cpu", test_mode="val")
    assert dm2.semantic_stats["cache_hit"]
