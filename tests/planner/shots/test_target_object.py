"""Targets (shots/target_object.py): masks over the splat mapped to obstacle ids through the inverse of source_index
(against a brute-force reference), and objects' set-up kept on the volume (the same as a fresh build, keyed by the
members' full contents, read-only, least recently used dropped)."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner import native
from cinenerf_ns.planner.geometry.visibility import SplatVolume, SubjectSamples
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.shots import target_object as T
from cinenerf_ns.planner.shots.target_object import (
    TargetObject,
    object_parts,
    scene_members,
    subject_samples,
)


class _Scene:
    """What scene_members reads of a scene: its length and source_index."""

    def __init__(self, source_index):
        self.source_index = source_index

    def __len__(self) -> int:
        return int(self.source_index.numel())


def _members_reference(src: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Obstacle j is a member when its source Gaussian src[j] is selected: every obstacle tested."""
    return np.array([j for j in range(len(src)) if mask[src[j]]], np.int64)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 60), kind=st.sampled_from(["sorted", "permuted", "repeats"]),
       extra=st.integers(0, 5))
def test_scene_members_matches_the_reference(seed, n, kind, extra):
    rng = np.random.default_rng(seed)
    n_src = n + int(rng.integers(0, 20))
    if kind == "repeats":  # a source Gaussian behind several obstacles: no inverse, the gather
        src = rng.integers(0, n_src, n)
    else:
        src = np.sort(rng.choice(n_src, n, replace=False))
        if kind == "permuted":
            src = rng.permutation(src)
    top = int(src.max())
    mask = rng.random(top + 1 + extra) < rng.uniform(0.0, 1.0)  # longer than the sources: the tail is never an obstacle
    got = scene_members(_Scene(torch.as_tensor(src)), mask)
    want = _members_reference(src, mask)
    assert got.dtype == np.int64
    np.testing.assert_array_equal(got, want)
    assert got.size < 2 or bool(np.all(got[1:] > got[:-1]))  # sorted, unique


def _volume(n: int = 400, seed: int = 0) -> SplatVolume:
    rng = np.random.default_rng(seed)
    t = torch.as_tensor
    sc = EllipsoidScene.from_splat(t(rng.uniform(-1, 1, (n, 3))), t(rng.normal(size=(n, 4))),
                                   t(rng.uniform(-3.5, -2.0, (n, 3))), t(rng.uniform(-1, 3, n)),
                                   SceneConfig(opacity_floor=0.0, min_axis=1e-9))
    return SplatVolume.build(sc, -1.2 * np.ones(3), 1.2 * np.ones(3))


def _fresh(vol: SplatVolume, members, centre) -> TargetObject:
    """TargetObject.of_members on an empty memo (what a first request builds)."""
    vol.memo.clear()
    return TargetObject.of_members(vol, members, centre, "fresh")


def test_object_set_up_is_kept_and_equals_a_fresh_build():
    vol = _volume()
    members = np.flatnonzero(vol.means[:, 0] > 0.3)
    a = TargetObject.of_members(vol, members, None, "a")
    b = TargetObject.of_members(vol, members.copy(), np.ones(3), "b")  # equal contents, another array and centre
    assert b.extent is a.extent and b.members is a.members  # from the memo
    np.testing.assert_array_equal(b.centre, np.ones(3))
    np.testing.assert_allclose(a.centre, vol.means[members].mean(0), rtol=0, atol=1e-12)
    f = _fresh(vol, members, None)
    for k in ("members", "extent", "centre"):
        np.testing.assert_array_equal(getattr(a, k), getattr(f, k))
    assert a.outline is None  # the hull is made on first use (a go-to object never needs it)
    np.testing.assert_array_equal(a.outline_points(), f.outline_points())
    np.testing.assert_array_equal(a.outline_points(), T._hull(np.array(a.extent)))
    assert a.outline_points() is b.outline_points()  # made once for the object
    assert (a.pad, a.gap()) == (f.pad, f.gap()) == (a.pad, T._spacing(np.array(a.extent)))
    mask = np.zeros(len(vol), bool)
    mask[members] = True
    assert TargetObject.of_members(vol, mask, None).extent is f.extent  # a mask names the same object
    with pytest.raises(ValueError):
        a.extent[0, 0] = 5.0  # shared by every request: read-only
    members[0] = members[1]  # the caller's array changing later does not change what is kept
    np.testing.assert_array_equal(TargetObject.of_members(vol, f.members, None).members, f.members)


def test_different_members_and_the_oldest_objects_dropped():
    vol = _volume()
    objs = [np.arange(i, i + 30) for i in range(0, 30 * (T.OBJECT_MEMO + 2), 30)]
    first = object_parts(vol, objs[0])
    near = objs[0].copy()
    near[5] = 200  # same size, first and last id: another object
    assert object_parts(vol, np.sort(near)) is not first
    for m in objs[1:]:
        object_parts(vol, m)
    assert len(vol.memo["objects"]) == T.OBJECT_MEMO
    assert object_parts(vol, objs[0]) is not first  # dropped, built again
    np.testing.assert_array_equal(object_parts(vol, objs[0]).extent, first.extent)


def test_subject_samples_are_kept_with_the_object():
    vol = _volume()
    members = np.flatnonzero(vol.means[:, 1] < -0.2)
    s = subject_samples(vol, members, 16)
    assert subject_samples(vol, members.copy(), 16) is s
    assert subject_samples(vol, members, 8) is not s
    ref = SubjectSamples.of_members(vol, members, 16)
    for k in ("points", "weights", "ids", "members"):
        np.testing.assert_array_equal(getattr(s, k), getattr(ref, k))
    np.testing.assert_array_equal(s.box[0], ref.box[0])
    np.testing.assert_array_equal(s.box[1], ref.box[1])
    with pytest.raises(ValueError):
        s.points[0, 0] = 1.0


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 20_000), kind=st.sampled_from(["lognormal", "ties", "sorted",
                                                                                     "two", "nan"]))
def test_exact_median_equals_numpys(seed, n, kind):
    """The bracketed median is np.median's value, bit for bit (even and odd counts, ties, sorted input, a bimodal
    sample whose bracket may miss, NaN)."""
    rng = np.random.default_rng(seed)
    v = rng.lognormal(-4.0, 1.0, n)
    if kind == "ties":
        v = np.round(v, 3)
    elif kind == "sorted":
        v = np.sort(v)
    elif kind == "two":
        v = np.where(rng.random(n) < 0.5, 1e-3, 1.0) + 1e-9 * rng.random(n)
    elif kind == "nan":
        v[rng.integers(0, n)] = np.nan
    want = np.median(v)
    for backend in ["python"] + (["native"] if native.bracket_c() else []):
        got = T.exact_median(v, sample=int(rng.integers(1, 64)), backend=backend)
        assert (np.isnan(want) and np.isnan(got)) or got == want


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 600), kind=st.sampled_from(["cloud", "grid", "repeats", "flat"]))
def test_spacing_is_the_brute_force_median_gap(seed, n, kind):
    """The typical gap between extent points: compiled sweep, k-d tree and every pair (float64) agree."""
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 3)) * rng.uniform(0.01, 2.0, 3)
    if kind == "grid":  # many equal distances and equal x
        pts = np.round(pts * 4) / 4
    elif kind == "repeats":  # duplicates: gap 0
        pts = pts[rng.integers(0, n, n)]
    elif kind == "flat":
        pts[:, 0] = 0.5
    if n < 2:
        assert T._spacing(pts) == 0.0
        return
    d2 = ((pts[:, None] - pts[None]) ** 2).sum(-1)
    np.fill_diagonal(d2, np.inf)
    want = float(np.median(np.sqrt(d2.min(1))))
    for backend in ["python"] + (["native"] if native.nearest_gaps_c() else []):
        np.testing.assert_allclose(T._spacing(pts, backend), want, rtol=1e-12, atol=1e-300)
    if native.nearest_gaps_c():
        assert T._spacing(pts, "native") == T._spacing(pts, "python")
