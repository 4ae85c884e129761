"""object_support.py: the support layer under a selected object is dropped, the object is kept."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from cinenerf_ns.method.object_centre import volume_centroid
from cinenerf_ns.method.object_support import drop_support_layer


def _floor(rng, n=20_000, half=1.0, noise=0.004):
    p = np.column_stack([rng.uniform(-half, half, n), rng.uniform(-half, half, n), rng.normal(0.0, noise, n)])
    return p


def _cylinder(rng, r=0.15, h=0.6, density=20_000.0, centre=(0.2, -0.1)):
    """Side and top of a cylinder standing on z = 0 (its underside touches the floor: never seen), ``density``
    Gaussians per unit area."""
    n = int(density * 2 * np.pi * r * h)
    t = rng.uniform(0, 2 * np.pi, n)
    side = np.column_stack([centre[0] + r * np.cos(t), centre[1] + r * np.sin(t), rng.uniform(0, h, n)])
    k = int(density * np.pi * r * r)
    rr = r * np.sqrt(rng.uniform(0, 1, k))
    tt = rng.uniform(0, 2 * np.pi, k)
    top = np.column_stack([centre[0] + rr * np.cos(tt), centre[1] + rr * np.sin(tt), np.full(k, h)])
    return np.concatenate([side, top])


def _scene(rng, bleed=0.05, floor_noise=0.004):
    floor = _floor(rng, noise=floor_noise)
    obj = _cylinder(rng)
    means = np.concatenate([obj, floor])
    is_obj = np.zeros(len(means), bool)
    is_obj[: len(obj)] = True
    # the selection: the object + the floor within `bleed` of its footprint (features bleed across contact)
    d = np.hypot(means[:, 0] - 0.2, means[:, 1] + 0.1)
    sel = is_obj | (~is_obj & (d <= 0.15 + bleed))
    return means, sel, is_obj


def test_floor_under_an_object_is_dropped_and_the_object_kept():
    rng = np.random.default_rng(0)
    means, sel, is_obj = _scene(rng)
    out = drop_support_layer(means, sel, inner=0.02, outer=0.06)
    floor_sel = sel & ~is_obj
    # the layer's top is the 95% height quantile of its dense bins, so ~5-10% of a noisy floor stays (its upper fringe)
    assert (out & floor_sel).sum() <= 0.15 * floor_sel.sum()
    kept_obj = (out & is_obj).sum() / is_obj.sum()
    assert kept_obj > 0.97  # only the object's lowest sliver (at the floor's height) goes with it


def test_ring_points_exactly_at_the_outer_distance_count():
    """The ring is the closed interval [inner, outer]: floor points exactly `outer` from a wall-like footprint (a thin
    line, the case the distance bound speeds up) form the layer, and the wall's bottom row on it is dropped."""
    outer = 0.0625  # a power of two: the distance sqrt(outer^2) is outer exactly
    y, z = np.meshgrid(np.linspace(-0.2, 0.2, 41), np.linspace(0.0, 0.6, 61), indexing="ij")
    wall = np.column_stack([np.zeros(y.size), y.ravel(), z.ravel()])  # [2501, 3] selected, footprint x = 0
    ys = np.linspace(-0.2, 0.2, 41)
    ring = np.concatenate([np.column_stack([np.full(41, sx * outer), ys, np.zeros(41)]) for sx in (-1, 1)])
    means = np.concatenate([wall, ring])
    sel = np.arange(len(means)) < len(wall)
    out = drop_support_layer(means, sel, inner=0.02, outer=outer)
    assert np.array_equal(out[: len(wall)], wall[:, 2] > 0) and not out[len(wall):].any()


def test_a_thick_floor_slab_no_longer_pulls_the_centre_down():
    """A fuzzy floor (sigma 1 cm, as reconstructed floors are) bled into the selection 10 cm around the footprint
    is a slab under the object that drags the centre estimate down; without it the estimate returns toward what
    the object's own Gaussians give (averaged over seeds: one estimate has ~5 mm of voxel noise)."""
    before, after = [], []
    for seed in range(4):
        means, sel, is_obj = _scene(np.random.default_rng(seed), bleed=0.1, floor_noise=0.01)
        out = drop_support_layer(means, sel, inner=0.02, outer=0.06)
        own = volume_centroid(means[is_obj])
        before.append(np.linalg.norm(volume_centroid(means[sel]) - own))
        after.append(np.linalg.norm(volume_centroid(means[out]) - own))
    assert np.mean(after) < 0.7 * np.mean(before)


def test_rotated_up_vector():
    """The same scene rotated, with its up vector: the same Gaussians are dropped."""
    rng = np.random.default_rng(1)
    means, sel, _ = _scene(rng)
    q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    a = drop_support_layer(means, sel, inner=0.02, outer=0.06)
    b = drop_support_layer(means @ q.T, sel, up=q @ np.array([0.0, 0.0, 1.0]), inner=0.02, outer=0.06)
    np.testing.assert_array_equal(a, b)


def test_no_surroundings_nothing_dropped():
    """A floating object (no layer around its bottom) is returned as is."""
    rng = np.random.default_rng(2)
    obj = _cylinder(rng)
    sel = np.ones(len(obj), bool)
    out = drop_support_layer(obj, sel, inner=0.02, outer=0.06)
    assert out is sel


def test_a_flat_object_is_not_erased():
    """A rug (all its Gaussians at the floor's height): dropping 'the layer' would drop the whole selection, more than
    max_fraction, so nothing is dropped (the documented limit: such an object is not trimmed)."""
    rng = np.random.default_rng(3)
    floor = _floor(rng)
    rug = floor[np.hypot(floor[:, 0], floor[:, 1]) < 0.3]
    others = floor[np.hypot(floor[:, 0], floor[:, 1]) >= 0.3]
    wall = np.column_stack([rng.uniform(-1, 1, 3000), np.full(3000, 0.9), rng.uniform(0, 1, 3000)])
    means = np.concatenate([rug, others, wall])
    sel = np.zeros(len(means), bool)
    sel[: len(rug)] = True
    out = drop_support_layer(means, sel, inner=0.02, outer=0.06)
    np.testing.assert_array_equal(out, sel)


def test_torch_in_torch_out():
    rng = np.random.default_rng(4)
    means, sel, is_obj = _scene(rng)
    out = drop_support_layer(torch.from_numpy(means), torch.from_numpy(sel), inner=0.02, outer=0.06)
    assert isinstance(out, torch.Tensor) and out.dtype == torch.bool
    np.testing.assert_array_equal(out.numpy(), drop_support_layer(means, sel, inner=0.02, outer=0.06))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.0, 0.15), st.floats(0.0, 0.5))
def test_only_a_bottom_slab_is_ever_dropped(seed, bleed, max_fraction):
    """Whatever the scene: the result is a subset of the selection, every dropped Gaussian lies below every kept one
    (a bottom slab), and at most max_fraction of the selection is dropped."""
    rng = np.random.default_rng(seed)
    means, sel, _ = _scene(rng, bleed=bleed)
    extra = rng.random(len(means)) < 0.01  # random stray Gaussians in the selection
    sel = sel | extra
    out = drop_support_layer(means, sel, inner=0.02, outer=0.06, max_fraction=max_fraction)
    assert not (out & ~sel).any()
    dropped = sel & ~out
    if dropped.any():
        assert means[dropped, 2].max() < means[out, 2].min()
    assert dropped.sum() <= max_fraction * sel.sum()


def test_bad_input():
    with pytest.raises(ValueError, match="inner"):
        drop_support_layer(np.zeros((5, 3)), np.ones(5, bool), inner=0.1, outer=0.05)
    with pytest.raises(ValueError, match="disagree"):
        drop_support_layer(np.zeros((5, 3)), np.ones(4, bool))
    with pytest.raises(ValueError, match="max_fraction"):
        drop_support_layer(np.zeros((5, 3)), np.ones(5, bool), max_fraction=1.0)


def test_floaters_under_the_floor_are_dropped():
    """Floaters up to 0.35 units under the floor carrying the object's label (room 1's sofa): the layer is still
    found (the densest thin layer around the footprint, not the selection's lowest band) and everything at or below
    it goes."""
    rng = np.random.default_rng(6)
    means, sel, is_obj = _scene(rng)
    junk = np.column_stack([rng.uniform(0.1, 0.3, 400), rng.uniform(-0.2, 0.0, 400), rng.uniform(-0.35, -0.02, 400)])
    means = np.concatenate([means, junk])
    sel = np.concatenate([sel, np.ones(400, bool)])
    is_obj = np.concatenate([is_obj, np.zeros(400, bool)])
    out = drop_support_layer(means, sel, inner=0.02, outer=0.06)
    assert not out[-400:].any()
    assert (out & is_obj).sum() > 0.97 * is_obj.sum()
