"""Feature codec (eq. 2): training reduces reconstruction error on structured features; interface contract."""
from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from cinenerf_ns.method.codec import CodecConfig, FeatureCodec, reconstruction_error, train_codec


def _structured(n=4000, D=64, k=6, seed=0):
    """Unit features from k well-separated clusters in D dims (like per-object CLIP features)."""
    g = torch.Generator().manual_seed(seed)
    centers = F.normalize(torch.randn(k, D, generator=g), dim=-1)
    lab = torch.randint(0, k, (n,), generator=g)
    x = centers[lab] + 0.05 * torch.randn(n, D, generator=g)
    return F.normalize(x, dim=-1), centers, lab


def test_training_reduces_reconstruction_error():
    x, centers, lab = _structured()
    cfg = CodecConfig(train_steps=300, batch_size=1024, hidden_dim=32, backend="torch")
    codec, stats = train_codec(x, cfg, progress=False)
    assert stats["error_after"] < 0.25 * stats["error_before"]
    # the within-cluster noise is not representable in 3 dims: the floor is predicting the cluster centre
    floor = float((1 - (x * centers[lab]).sum(-1)).mean())
    assert stats["error_after"] < floor + 0.02
    assert reconstruction_error(codec, x) == pytest.approx(stats["error_after"], rel=1e-5)
    # decoded cluster codes stay closest to their own cluster centre (what relevancy relies on)
    dec = codec(x[:200])
    assert (torch.argmax(dec @ centers.T, dim=1) == lab[:200]).float().mean() > 0.95
    assert not any(p.requires_grad for p in codec.parameters())


def test_interface_shapes_and_ranges():
    codec = FeatureCodec(48, CodecConfig(hidden_dim=16, backend="torch"))
    x = torch.randn(2, 5, 48)
    lat = codec.encode(x)
    assert lat.shape == (2, 5, 3) and lat.abs().max() <= 1.0
    dec = codec.decode(lat)
    assert dec.shape == (2, 5, 48)
    assert torch.allclose(dec.norm(dim=-1), torch.ones(2, 5), atol=1e-5)


def test_weighted_training_on_few_distinct_vectors():
    """Label source: L distinct embeddings, every label decodable back to itself (uniform or mild weights)."""
    g = torch.Generator().manual_seed(1)
    emb = F.normalize(torch.randn(7, 32, generator=g), dim=-1)
    for w in (None, torch.tensor([4.0, 3, 2, 1, 1, 1, 1])):
        codec, stats = train_codec(emb, CodecConfig(train_steps=400, batch_size=256, hidden_dim=32, backend="torch"),
                                   progress=False, weights=w)
        assert stats["error_after"] < 0.5 * stats["error_before"]
        dec = codec(emb)
        assert torch.equal(torch.argmax(dec @ emb.T, dim=1), torch.arange(7))


def test_bad_input():
    with pytest.raises(ValueError, match="non-empty"):
        train_codec(torch.zeros(0, 8), progress=False)
    with pytest.raises(RuntimeError, match="tinycudann"):
        FeatureCodec(8, CodecConfig(backend="tcnn"), device="cpu")
