"""CineSplatDatamanager with label masks on a tiny synthetic capture with lens distortion (CPU)."""
from __future__ import annotations

import json

import numpy as np
import torch
from PIL import Image


def test_labels_source_with_distortion(tmp_path, tiny_clip_models, tiny_scene):
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    from cinenerf_ns.method.clip_features import ClipFeatureConfig
    from cinenerf_ns.method.codec import CodecConfig
    from cinenerf_ns.method.datamanager import CineSplatDatamanagerConfig
    from cinenerf_ns.method.feature_grid import feature_map_size

    data = tmp_path / "scene"
    tiny_scene(data, w=40, h=30)
    meta = json.loads((data / "transforms.json").read_text())
    meta.update(k1=0.05, k2=-0.05, p1=0.001)
    (data / "transforms.json").write_text(json.dumps(meta))
    (data / "labels").mkdir()
    for f in (data / "images").glob("*.png"):
        lab = np.zeros((60, 80), np.uint8)  # labels at 2x the image resolution: resized to the camera
        lab[:, 40:] = 1
        lab[:10] = 7  # unnamed
        Image.fromarray(lab).save(data / "labels" / f.name)
    (data / "labels.json").write_text(json.dumps({"0": "left wall", "1": "right wall"}))
    cfg = CineSplatDatamanagerConfig(
        data=data,
        dataparser=NerfstudioDataParserConfig(data=data),
        cache_images="gpu",
        feature_source="labels",
        clip=ClipFeatureConfig(model_name=tiny_clip_models[0], random_weights=True, feature_long_side=20),
        codec=CodecConfig(train_steps=200, batch_size=64, hidden_dim=16, backend="torch"),
        feature_cache_dir=tmp_path / "cache",
    )
    dm = cfg.setup(device="cpu", test_mode="val")
    cam, batch = dm.next_train(0)
    H, W = int(cam.height.item()), int(cam.width.item())
    assert (H, W) != (30, 40)  # nerfstudio undistorted + cropped the image
    t, v = batch["latent_target"], batch["latent_valid"][..., 0]
    assert tuple(t.shape[:2]) == feature_map_size(H, W, 20) == tuple(v.shape)
    assert not v[0].any() and v[-1].all()  # the unnamed top band is ignored
    assert batch["latent_all_valid"] is False  # so the loss applies the mask
    info = dm.train_dataset.metadata["cinesplat_info"]
    assert info["label_names"] == ["left wall", "right wall"] and info["source"] == "labels"
    # left / right halves carry the two labels' codes
    emb = dm.train_dataset.metadata["label_embeddings"]
    assert emb.shape[0] == 2
    left, right = t[-1, 1], t[-1, -2]
    assert not torch.allclose(left, right)
