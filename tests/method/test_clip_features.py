"""Dense CLIP features (MaskCLIP) with random-weight open_clip towers: shapes, unit norm, determinism, errors."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch

from cinenerf_ns.method.clip_features import (
    ClipFeatureConfig,
    ClipWeightsError,
    DenseClipExtractor,
    _vit_dense,
    clip_config_from_spec,
    clip_embed_dim,
    encode_text,
    load_clip,
)


def _cfg(name, **kw):
    kw.setdefault("input_long_sides", (64, 96))
    kw.setdefault("feature_long_side", 12)
    return ClipFeatureConfig(model_name=name, random_weights=True, **kw)


@pytest.mark.parametrize("which", [0, 1])
def test_dense_features_shape_and_unit_norm(tiny_clip_models, which):
    name = tiny_clip_models[which]
    ex = DenseClipExtractor(_cfg(name))
    img = torch.rand(30, 50, 3)
    f = ex.extract(img)
    assert f.shape == (7, 12, 32)  # long side 12, aspect kept: 30/50*12 = 7.2 -> 7
    assert torch.allclose(f.norm(dim=-1), torch.ones(7, 12), atol=1e-5)
    # uint8 input gives the same features as float input
    f8 = ex.extract((img * 255).round().to(torch.uint8))
    assert (f8 - ex.extract((img * 255).round() / 255)).abs().max() < 1e-5
    assert clip_embed_dim(name) == 32 == ex.feature_dim


def test_random_weights_are_reproducible(tiny_clip_models):
    m1, tok = load_clip(_cfg(tiny_clip_models[0], random_seed=3))
    m2, _ = load_clip(_cfg(tiny_clip_models[0], random_seed=3))
    m3, _ = load_clip(_cfg(tiny_clip_models[0], random_seed=4))
    e1, e2, e3 = (encode_text(m, tok, ["a palm tree"]) for m in (m1, m2, m3))
    assert torch.equal(e1, e2) and not torch.allclose(e1, e3)
    assert torch.allclose(e1.norm(dim=-1), torch.ones(1))


def test_vit_dense_matches_open_clip_value_path(tiny_clip_models):
    """At the native grid (no positional interpolation) our token pipeline equals open_clip's own blocks
    up to the last one; the last block's value path is checked against nn.MultiheadAttention with an
    identity attention pattern (MaskCLIP: every token attends only to itself)."""
    model, _ = load_clip(_cfg(tiny_clip_models[0]))
    v = model.visual
    x = torch.randn(1, 3, 64, 64)
    with torch.no_grad():
        tokens = v._embeds(x)
        for blk in v.transformer.resblocks[:-1]:
            tokens = blk(tokens)
        last = v.transformer.resblocks[-1]
        y = last.ln_1(tokens)
        n = y.shape[1]
        eye_mask = torch.full((n, n), float("-inf"))
        eye_mask.fill_diagonal_(0.0)
        ref = last.attn(y, y, y, need_weights=False, attn_mask=eye_mask)[0]
        ref = v.ln_post(ref) @ v.proj
        ours = _vit_dense(v, x)
    assert ours.shape == (4, 4, 32)
    assert torch.allclose(ours.reshape(-1, 32), ref[0, 1:], atol=1e-5)


def test_missing_checkpoint_file_is_one_clear_error(tiny_clip_models, tmp_path):
    cfg = ClipFeatureConfig(model_name=tiny_clip_models[0], checkpoint_path=tmp_path / "nope.bin")
    with pytest.raises(ClipWeightsError, match="not found"):
        load_clip(cfg)
    with pytest.raises(ClipWeightsError, match="unknown open_clip model"):
        load_clip(ClipFeatureConfig(model_name="No-Such-Model", random_weights=True))


def test_unavailable_pretrained_tag_says_how_to_provide(tiny_clip_models, monkeypatch):
    import open_clip

    def boom(*a, **k):
        raise RuntimeError("Failed to download (network unreachable)")

    monkeypatch.setattr(open_clip, "create_model", boom)
    with pytest.raises(ClipWeightsError) as ei:
        load_clip(ClipFeatureConfig(model_name=tiny_clip_models[0], pretrained="laion2b_s34b_b88k"))
    msg = str(ei.value)
    assert "checkpoint-path" in msg and "random-weights" in msg
    assert ei.value.__cause__ is None and ei.value.__suppress_context__


def test_spec_roundtrip():
    cfg = ClipFeatureConfig(model_name="ViT-B-16", checkpoint_path=Path("/x/y.bin"), random_weights=True, random_seed=5)
    back = clip_config_from_spec(cfg.spec())
    assert back.spec() == cfg.spec()
