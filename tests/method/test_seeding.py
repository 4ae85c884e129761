"""Set-up that seeds its own modules (random-weight CLIP, the codec) leaves every training random stream alone: the
CPU generator continues where it was and no CUDA generator is seeded, so ``--machine.seed`` decides cinesplat's CUDA
draws (random backgrounds, split samples) as it decides splatfacto's."""
from __future__ import annotations

import torch

from cinenerf_ns.method.codec import CodecConfig, FeatureCodec
from cinenerf_ns.method.seeding import cpu_seeded


def _no_cuda_seeding(monkeypatch):
    calls = []
    monkeypatch.setattr(torch.cuda, "manual_seed_all", lambda seed: calls.append(("all", seed)))
    monkeypatch.setattr(torch.cuda, "manual_seed", lambda seed: calls.append(("one", seed)))
    return calls


def test_cpu_seeded_is_reproducible_and_restores_the_cpu_stream(monkeypatch):
    calls = _no_cuda_seeding(monkeypatch)
    torch.manual_seed(42)  # what nerfstudio does at start (seeds CUDA too: that call is recorded, then cleared)
    calls.clear()
    expect = torch.rand(4)
    torch.manual_seed(42)
    calls.clear()
    with cpu_seeded(7):
        a = torch.rand(3)
    with cpu_seeded(7):
        b = torch.rand(3)
    assert torch.equal(a, b)
    assert torch.equal(torch.rand(4), expect)  # the outer stream is where it was
    assert calls == []


def test_codec_and_random_clip_do_not_seed_cuda_or_move_the_cpu_stream(monkeypatch, tiny_clip_models):
    from cinenerf_ns.method.clip_features import ClipFeatureConfig, load_clip

    calls = _no_cuda_seeding(monkeypatch)
    torch.manual_seed(42)
    expect = torch.rand(4)
    torch.manual_seed(42)
    calls.clear()
    c1 = FeatureCodec(16, CodecConfig(hidden_dim=8, seed=3))
    load_clip(ClipFeatureConfig(model_name=tiny_clip_models[1], random_weights=True, random_seed=5))
    assert calls == []  # torch.manual_seed would have re-seeded every CUDA generator
    assert torch.equal(torch.rand(4), expect)
    c2 = FeatureCodec(16, CodecConfig(hidden_dim=8, seed=3))
    assert all(torch.equal(p, q) for p, q in zip(c1.parameters(), c2.parameters()))  # still seeded
