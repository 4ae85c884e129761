"""Feature cache: computed once, reused on a match, recomputed when images or settings change; targets."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest
import torch
from PIL import Image

from cinenerf_ns.method.clip_features import ClipFeatureConfig
from cinenerf_ns.method.codec import CodecConfig
from cinenerf_ns.method.feature_cache import prepare_semantic_targets


def _scene(tmp_path, n=3, hw=(24, 40)):
    (tmp_path / "images").mkdir()
    (tmp_path / "labels").mkdir()
    g = np.random.default_rng(0)
    paths, imgs = [], []
    for i in range(n):
        img = g.integers(0, 255, (*hw, 3), dtype=np.uint8)
        p = tmp_path / "images" / f"frame_{i:03d}.png"
        Image.fromarray(img).save(p)
        paths.append(p)
        imgs.append(torch.from_numpy(img))
        lab = np.zeros(hw, np.uint8)
        lab[:, hw[1] // 2 :] = 1
        lab[: hw[0] // 3, : hw[1] // 4] = 2
        lab[-2:, :2] = 9  # unnamed -> invalid
        Image.fromarray(lab).save(tmp_path / "labels" / f"frame_{i:03d}.png")
    (tmp_path / "labels.json").write_text(json.dumps({"0": "floor", "1": "palm tree", "2": "lamp"}))
    return paths, imgs


def _run(tmp_path, paths, imgs, source, clip, logs):
    return prepare_semantic_targets(
        images=[(lambda im=im: im) for im in imgs],
        image_paths=paths,
        image_sizes=[tuple(im.shape[:2]) for im in imgs],
        source=source,
        clip_config=clip,
        codec_config=CodecConfig(train_steps=150, batch_size=512, hidden_dim=16, backend="torch"),
        cache_dir=tmp_path / "cache",
        data_dir=tmp_path,
        progress=False,
        log=logs.append,
    )


def test_clip_cache_hit_miss_invalidation(tmp_path, tiny_clip_models):
    paths, imgs = _scene(tmp_path)
    clip = ClipFeatureConfig(model_name=tiny_clip_models[0], random_weights=True, input_long_sides=(64,),
                             feature_long_side=10)
    logs = []
    r1 = _run(tmp_path, paths, imgs, "clip", clip, logs)
    assert not r1.cache_hit and len(list((tmp_path / "cache").glob("clip-*.pt"))) == 1
    assert r1.latent_targets[0].shape == (6, 10, 3) and r1.latent_valid[0].all()
    assert r1.info["feature_dim"] == 32 and r1.info["source"] == "clip" and r1.info["feature_long_side"] == 10
    r2 = _run(tmp_path, paths, imgs, "clip", clip, logs)
    assert r2.cache_hit
    assert torch.allclose(r1.latent_targets[1], r2.latent_targets[1], atol=1e-6)  # same features, same seed
    # an image file changes -> miss
    st = os.stat(paths[1])
    os.utime(paths[1], ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    assert not _run(tmp_path, paths, imgs, "clip", clip, logs).cache_hit
    assert _run(tmp_path, paths, imgs, "clip", clip, logs).cache_hit
    # a setting changes -> miss
    clip2 = ClipFeatureConfig(model_name=tiny_clip_models[0], random_weights=True, input_long_sides=(64,),
                              feature_long_side=8)
    r5 = _run(tmp_path, paths, imgs, "clip", clip2, logs)
    assert not r5.cache_hit and r5.latent_targets[0].shape == (5, 8, 3)
    assert any("reusing cached" in m for m in logs)


def test_labels_source_targets_and_invalidation(tmp_path, tiny_clip_models):
    paths, imgs = _scene(tmp_path)
    clip = ClipFeatureConfig(model_name=tiny_clip_models[0], random_weights=True, feature_long_side=40)  # full res
    logs = []
    r = _run(tmp_path, paths, imgs, "labels", clip, logs)
    assert r.info["label_names"] == ["floor", "palm tree", "lamp"] and r.label_embeddings.shape == (3, 32)
    valid = r.latent_valid[0][..., 0]
    assert valid.shape == (24, 40) and not valid[-1, 0] and valid[0, 0]
    # every pixel of one label gets the same target = f_enc(embedding of the label name)
    tgt = r.latent_targets[0]
    expect = r.codec.encode(r.label_embeddings[1])
    assert torch.allclose(tgt[5, 30], expect, atol=1e-5) and torch.allclose(tgt[20, 39], expect, atol=1e-5)
    assert (tgt[~valid] == 0).all()
    # decoding each label's target gives back that label (argmax over the label embeddings)
    for j in range(3):
        d = r.codec.decode(r.codec.encode(r.label_embeddings[j]))
        assert int(torch.argmax(r.label_embeddings @ d)) == j
    assert _run(tmp_path, paths, imgs, "labels", clip, logs).cache_hit
    (tmp_path / "labels.json").write_text(json.dumps({"0": "floor", "1": "palm", "2": "lamp"}))
    r3 = _run(tmp_path, paths, imgs, "labels", clip, logs)
    assert not r3.cache_hit and r3.info["label_names"][1] == "palm"


def test_unknown_source(tmp_path):
    with pytest.raises(ValueError, match="feature_source"):
        prepare_semantic_targets([], [], [], "depth", ClipFeatureConfig(), CodecConfig(), tmp_path, tmp_path,
                                 progress=False)
