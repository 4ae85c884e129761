"""synthetic/blobs.py: the second benchmark scene family (walls + round blobs, y up, about [-1, 1]^3)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.ellipsoids import quat_wxyz_to_rotmat
from cinenerf_ns.synthetic.blobs import blob_scene


def test_blob_scene_is_seeded_sized_and_in_the_box():
    a, b = blob_scene(5000, seed=3), blob_scene(5000, seed=3)
    sa = a.splat
    assert len(sa.means) == 5000 and np.array_equal(sa.means, b.splat.means)
    assert not np.array_equal(sa.means, blob_scene(5000, 4).splat.means)
    assert sa.quats_wxyz.shape == (5000, 4) and sa.log_scales.shape == (5000, 3) and sa.opacity_logits.shape == (5000,)
    np.testing.assert_allclose(np.linalg.norm(sa.quats_wxyz, axis=1), np.ones(5000), atol=1e-5)
    assert (np.abs(sa.means) < 1.05).all() and a.up == (0.0, 1.0, 0.0)
    for i, blob in enumerate(a.blobs):  # every blob's Gaussians lie around its centre
        d = np.linalg.norm(sa.means[a.blob_ids == i] - blob.center, axis=1)
        assert d.max() < 1.3 * blob.radius and np.all(np.abs(blob.center) <= 1)
    with pytest.raises(InvalidInputError):
        blob_scene(10)


def test_wall_discs_are_thin_along_the_wall_normal():
    s = blob_scene(4000, seed=0)
    walls = s.blob_ids < 0
    m = s.splat.means
    floor = walls & (np.abs(m[:, 1] + 1) < 0.02) & (np.abs(m[:, 0]) < 0.95) & (m[:, 2] > -0.95)  # not the other walls
    # [K, 3, 3], columns: the local axes in the world
    rot = quat_wxyz_to_rotmat(torch.as_tensor(s.splat.quats_wxyz[floor]).double())
    thin = rot[:, :, 2]  # local z: the disc's thin axis
    assert floor.sum() > 100 and (thin[:, 1].abs() > 0.999).all()  # the floor's normal is y (up)
