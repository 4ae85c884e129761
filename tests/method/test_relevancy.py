"""Relevancy (eq. 4) against a float64 hand computation; mask / centroid / extent."""
from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F
from hypothesis import given, settings, strategies as st

from cinenerf_ns.method.relevancy import (
    CORE_MIN_COUNT,
    CORE_MIN_FRACTION,
    QueryError,
    centre_core,
    object_centroid_extent,
    relevancy,
    relevancy_from_features,
    relevancy_mask,
)


class LinearDecoder:
    """decode(l) = normalize(l @ W): a stand-in codec with a known closed form."""

    def __init__(self, W):
        self.W = W

    def decode(self, l):
        return F.normalize(l @ self.W, dim=-1)


def _hand(latents, W, q, negs, t):
    out = []
    for l in latents.double().tolist():
        d = [sum(l[a] * W[a][b] for a in range(3)) for b in range(len(W[0]))]
        nrm = math.sqrt(sum(v * v for v in d))
        d = [v / nrm for v in d]
        qn = math.sqrt(sum(v * v for v in q))
        sq = sum(a * b / qn for a, b in zip(q, d))
        vals = []
        for n in negs:
            nn_ = math.sqrt(sum(v * v for v in n))
            sn = sum(a * b / nn_ for a, b in zip(n, d))
            vals.append(math.exp(t * sq) / (math.exp(t * sq) + math.exp(t * sn)))
        out.append(min(vals))
    return torch.tensor(out, dtype=torch.float64)


@pytest.mark.parametrize("t", [1.0, 10.0])
def test_matches_hand_computation(t):
    g = torch.Generator().manual_seed(0)
    W = torch.randn(3, 6, generator=g).double()
    lat = torch.randn(25, 3, generator=g).double()
    q = torch.randn(6, generator=g).double()
    negs = torch.randn(4, 6, generator=g).double()
    ours = relevancy(lat, LinearDecoder(W), q, negs, temperature=t, chunk=7)  # chunking exercised
    ref = _hand(lat, W.tolist(), q.tolist(), negs.tolist(), t)
    assert torch.allclose(ours, ref, atol=1e-12)


def test_known_values():
    # feature equals the query: q.d = 1; negative orthogonal: n.d = 0 -> sigmoid(t)
    d = torch.tensor([[1.0, 0.0]])
    r = relevancy_from_features(d, torch.tensor([1.0, 0.0]), torch.tensor([[0.0, 1.0]]), temperature=1.0)
    assert r.item() == pytest.approx(math.exp(1) / (math.exp(1) + 1))
    # min over negatives: a negative identical to the query caps relevancy at 0.5
    r2 = relevancy_from_features(d, torch.tensor([1.0, 0.0]), torch.tensor([[0.0, 1.0], [1.0, 0.0]]), temperature=10.0)
    assert r2.item() == pytest.approx(0.5)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.floats(0.1, 50.0))
def test_range_and_negative_monotonicity(seed, t):
    g = torch.Generator().manual_seed(seed)
    feats = F.normalize(torch.randn(20, 8, generator=g, dtype=torch.float64), dim=-1)
    q = torch.randn(8, generator=g, dtype=torch.float64)
    negs = torch.randn(3, 8, generator=g, dtype=torch.float64)
    r = relevancy_from_features(feats, q, negs, t)
    assert ((r >= 0) & (r <= 1)).all()
    # adding a negative can only lower (or keep) relevancy: it is a min over negatives
    r_more = relevancy_from_features(feats, q, torch.cat([negs, torch.randn(1, 8, generator=g, dtype=torch.float64)]),
                                     t)
    assert (r_more <= r + 1e-12).all()


def test_mask_centroid_extent():
    means = torch.tensor([[0.0, 0, 0], [2.0, 0, 0], [10.0, 10, 10], [4.0, 2, 0]])
    opac = torch.tensor([1.0, 3.0, 1.0, 0.0])
    rel = torch.tensor([0.9, 0.8, 0.1, 0.95])
    mask = relevancy_mask(rel, 0.5)
    assert mask.tolist() == [True, True, False, True]
    c, lo, hi = object_centroid_extent(means, opac, mask)
    # opacity-weighted: (0*1 + 2*3 + 4*0) / 4 = 1.5
    assert torch.allclose(c, torch.tensor([1.5, 0.0, 0.0]))
    assert lo.tolist() == [0.0, 0.0, 0.0] and hi.tolist() == [4.0, 2.0, 0.0]
    assert relevancy_mask(rel, 0.5, opac, min_opacity=0.5).tolist() == [True, True, False, False]
    with pytest.raises(QueryError, match="threshold"):
        object_centroid_extent(means, opac, torch.zeros(4, dtype=torch.bool))


def test_needs_a_negative():
    with pytest.raises(QueryError):
        relevancy_from_features(torch.ones(2, 3), torch.ones(3), torch.zeros(0, 3))


def test_fast_path_equals_decode_path():
    from cinenerf_ns.method.codec import CodecConfig, FeatureCodec

    torch.manual_seed(0)
    codec = FeatureCodec(40, CodecConfig(hidden_dim=16, backend="torch"))
    with torch.no_grad():
        codec.center.copy_(torch.randn(40) * 0.3)
    lat = torch.rand(300, 3) * 2 - 1
    q, negs = torch.randn(40), torch.randn(4, 40)
    emb = F.normalize(torch.cat([q[None], negs]), dim=-1)
    assert torch.allclose(codec.decoded_cosines(lat, emb), codec.decode(lat) @ emb.T, atol=1e-5)
    fast = relevancy(lat, codec, q, negs, temperature=10.0, chunk=64)
    slow = relevancy(lat, codec, q, negs, temperature=10.0, fast=False)
    assert torch.allclose(fast, slow, atol=1e-5)


def _core_by_definition(rel, mask, t, sel_t, min_fraction, min_count):
    """centre_core written out element by element (plain Python floats and bools)."""
    sel = [bool(m) for m in mask]
    if t <= sel_t:
        return sel
    core = [m and r > t for m, r in zip(sel, rel)]
    k, n = sum(core), sum(sel)
    return sel if (k < min_count or k < min_fraction * n) else core


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(st.floats(0.0, 1.0), st.booleans()), min_size=0, max_size=60),
    st.floats(0.0, 0.99),
    st.floats(0.0, 0.99),
    st.sampled_from([0.0, 0.1, CORE_MIN_FRACTION, 0.9]),
    st.sampled_from([0, 1, CORE_MIN_COUNT, 10]),
)
def test_centre_core_matches_its_definition(items, t, sel_t, min_fraction, min_count):
    rel = torch.tensor([r for r, _ in items], dtype=torch.float64)
    mask = torch.tensor([m for _, m in items], dtype=torch.bool)
    out = centre_core(rel, mask, t, sel_t, min_fraction=min_fraction, min_count=min_count)
    ref = _core_by_definition(rel.tolist(), mask.tolist(), t, sel_t, min_fraction, min_count)
    assert out.dtype == torch.bool and out.tolist() == ref
    assert not (out & ~mask).any()  # a subset of the selection, always


def test_centre_core_keeps_the_confident_part_or_falls_back():
    rel = torch.tensor([0.9, 0.8, 0.7, 0.66, 0.6, 0.55, 0.52, 0.3])
    mask = rel > 0.5
    assert centre_core(rel, mask, 0.65, 0.5).tolist() == [True] * 4 + [False] * 4
    assert torch.equal(centre_core(rel, mask, 0.5, 0.5), mask)  # at the selection threshold: off
    assert torch.equal(centre_core(rel, mask, 0.0, 0.5), mask)
    assert torch.equal(centre_core(rel, mask, 0.85, 0.5), mask)  # one Gaussian: under CORE_MIN_COUNT
    many = torch.cat([rel[:4], torch.full((13,), 0.55)])  # 4 of 17 above 0.65: under a quarter
    assert torch.equal(centre_core(many, many > 0.5, 0.65, 0.5), many > 0.5)
