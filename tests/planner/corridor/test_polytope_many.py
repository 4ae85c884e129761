"""polytope_many.aabb_polytopes (one compiled call for a corridor's Prop-2 segments) against its reference, one
polytope.aabb_polytope per segment: the same planes, offsets, seeds and ids bit for bit, None exactly where that call
raises SeedNotFreeError or does not take the compiled path."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings, strategies as st

from cinenerf_ns.planner.corridor import polytope_many
from cinenerf_ns.planner.corridor.polytope import SeedNotFreeError, aabb_polytope
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.native import safe_polytopes_aabb_c
from cinenerf_ns.planner.scene.spatial_index import GridIndex

sys.path.insert(0, str(Path(__file__).parents[1]))
from _corridor_refs import random_scene  # noqa: E402

pytestmark = pytest.mark.skipif(safe_polytopes_aabb_c() is None, reason="no C compiler: the polytopes are not built")
SETTINGS = dict(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _bits(t: torch.Tensor) -> bytes:
    return t.contiguous().numpy().tobytes()  # bit for bit: -0.0 and 0.0 differ


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), dtype=st.sampled_from([torch.float32, torch.float64]),
       normal=st.sampled_from(["auto", "prop2"]), near=st.sampled_from([0.0, 0.5]),
       empty=st.sampled_from([None, 0.05]), margin=st.sampled_from([1e-6, 0.01]), with_index=st.booleans(),
       n=st.sampled_from([300, 1500]), k=st.integers(1, 6), box_margin=st.sampled_from([0.0, 0.05, 0.2]),
       tiny=st.booleans(), flat=st.booleans())
def test_aabb_polytopes_are_aabb_polytope(seed, dtype, normal, near, empty, margin, with_index, n, k, box_margin,
                                          tiny, flat):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, n, amin=0.005, amax=0.12, camera_radius=0.03).to(dtype=dtype)
    idx = GridIndex.build(scene, cell_size=0.1) if with_index else None
    w = np.cumsum(np.concatenate([rng.uniform(-0.6, 0.6, (1, 3)), rng.normal(size=(k, 3)) * 0.15]), axis=0)
    if flat:  # an axis-aligned segment: with box margin 0 its box is flat, which aabb_polytope hands on
        w[1, 2] = w[0, 2]
    kw = dict(normal=normal, two_pass=near > 0, near_fraction=near or 0.5, margin=margin)
    if empty is not None:
        kw.update(stop_when_empty=empty, require_seed_inside=False)  # not the corridor's: handed on
    segs = [(w[m], w[m + 1]) for m in range(k)]
    with pytest.MonkeyPatch.context() as mp:
        if tiny:  # the first buffer too small: retried with more room
            mp.setattr(polytope_many, "FIRST_CAP", 0)
        got = polytope_many.aabb_polytopes(segs, scene, idx, box_margin, **kw)
    assert len(got) == k
    for (p0, p1), g in zip(segs, got):
        lo, hi = np.minimum(p0, p1) - box_margin, np.maximum(p0, p1) + box_margin
        try:
            r = aabb_polytope(np.stack([p0, p1]), scene, idx, lo, hi, **kw)
        except (SeedNotFreeError, InvalidInputError):  # the caller's own path raises it
            r = None
        if g is None:
            assert r is None or not with_index or not (hi > lo).all() or empty is not None
            continue
        assert r is not None and with_index
        for name in ("A", "b", "seed", "ellipsoid_ids"):
            a, b = getattr(g, name), getattr(r, name)
            assert a.dtype == b.dtype and a.shape == b.shape and _bits(a) == _bits(b), name
        assert g.proven_empty == r.proven_empty
        assert g.host_arrays() is not None


def test_no_segments_and_python_backend():
    rng = np.random.default_rng(0)
    scene = random_scene(rng, 50, amin=0.005, amax=0.05, camera_radius=0.02)
    idx = GridIndex.build(scene, cell_size=0.1)
    assert polytope_many.aabb_polytopes([], scene, idx, 0.1) == []
    seg = [(np.zeros(3) + 2.0, np.ones(3) + 2.0)]
    assert polytope_many.aabb_polytopes(seg, scene, idx, 0.1, backend="python") == [None]
    assert polytope_many.aabb_polytopes(seg, scene, idx, 0.1)[0] is not None
