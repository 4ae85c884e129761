"""synthetic/grove.py: the open grove family (ground, thin trunks + canopies, rocks, floaters, far background) and its
fine-grid reference search."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.geometry.distance import clearance
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.ply import read_splat_ply
from cinenerf_ns.planner.scene.spatial_index import GridIndex
from cinenerf_ns.synthetic.grove import (
    GROUND,
    MIN_PAIR_DISTANCE,
    GroveScene,
    grove_pairs,
    grove_scene,
    reference_grid,
    reference_search,
)


def test_grove_is_seeded_sized_and_has_every_kind():
    a, b = grove_scene(20_000, seed=3), grove_scene(20_000, seed=3)
    assert len(a.splat) == 20_000 and np.array_equal(a.splat.means, b.splat.means)
    assert not np.array_equal(a.splat.means, grove_scene(20_000, 4).splat.means)
    counts = np.bincount(a.kind, minlength=len(GroveScene.KINDS))
    assert (counts > 0).all() and len(a.trees) == 36
    assert counts[4] == 600 and counts[5] == 600  # 3% floaters, 3% background
    m = a.splat.means
    back = np.linalg.norm(m[a.kind == 5], axis=1)
    assert back.min() >= 5.9 and back.max() <= 7.6  # the far shell
    fl = m[a.kind == 4]
    assert (np.abs(fl[:, :2]) <= GROUND).all() and fl[:, 2].min() > 0 and fl[:, 2].max() < 2.3
    op = a.splat.opacities()
    assert op[a.kind == 4].max() <= 0.35 + 1e-6 and np.median(op[a.kind != 4]) > 0.6  # floaters are faint
    trunks = m[a.kind == 1].astype(np.float64)
    d = np.min([np.hypot(*(trunks[:, :2] - t.base[:2]).T) - t.radius for t in a.trees], axis=0)
    assert d.max() < 1e-3 and all(0.02 <= t.radius <= 0.06 for t in a.trees)  # within thin cylinders (side, top)
    with pytest.raises(InvalidInputError):
        grove_scene(10)
    with pytest.raises(InvalidInputError, match="floater_fraction"):
        grove_scene(5000, floater_fraction=0.5)


def test_grove_writes_a_plain_ply(tmp_path):
    g = grove_scene(2000, seed=1)
    back = read_splat_ply(g.write_ply(tmp_path / "grove.ply"))
    np.testing.assert_allclose(back.means, g.splat.means, atol=1e-6)
    np.testing.assert_allclose(back.opacity_logits.reshape(-1), g.splat.opacity_logits.reshape(-1), atol=1e-5)


@pytest.fixture(scope="module")
def small_grove():
    g = grove_scene(6000, seed=2)
    scene = EllipsoidScene.from_params(g.splat)
    return g, scene, GridIndex.build(scene)


def test_reference_free_voxels_are_free_by_brute_force(small_grove):
    """Every voxel the reference calls free has float64 brute-force clearance >= spacing * sqrt(3) / 2 (all
    ellipsoids, no index): its 26-neighbour steps are collision-free."""
    g, scene, index = small_grove
    ref = reference_grid(scene, index, np.array([-1.0, -1.0, 0.1]), np.array([1.0, 1.0, 0.7]), 0.08)
    need = ref.spacing * math.sqrt(3) / 2
    ijk = np.argwhere(np.ones_like(ref.free))
    c = clearance(torch.as_tensor(ref.centre_of(ijk)), scene, None).numpy()  # brute force
    assert ref.free.any() and (~ref.free).any()
    np.testing.assert_array_equal(ref.free.reshape(-1), c >= need)


def test_pairs_are_free_apart_and_their_reference_paths_are_safe(small_grove):
    g, scene, index = small_grove
    pairs, ref = grove_pairs(g, scene, index, 4, seed=0, spacing=0.05)
    assert len(pairs) == 4
    ends = np.stack([p.start for p in pairs] + [p.goal for p in pairs])
    assert (clearance(torch.as_tensor(ends), scene, None).numpy() >= math.sqrt(3) * ref.spacing).all()
    joined = [p for p in pairs if p.reference_length is not None]
    assert joined
    for p in pairs:
        assert p.straight >= MIN_PAIR_DISTANCE
        if p.reference_length is not None:
            assert p.reference_length >= p.straight - 1e-9  # never shorter than the straight line
    # a pair the reference cannot join: the go-to inside a trunk
    t = g.trees[0]
    assert reference_search(ref, pairs[0].start, t.base + [0, 0, 0.5]) is None
