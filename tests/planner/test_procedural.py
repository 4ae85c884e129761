import numpy as np
import pytest
import torch

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.procedural import procedural_room
from cinenerf_ns.planner.scene import EllipsoidScene, quat_wxyz_to_rotmat


def test_counts_seed_and_objects():
    a = procedural_room(5000, seed=3)
    b = procedural_room(5000, seed=3)
    c = procedural_room(5000, seed=4)
    assert a.means.shape == (5000, 3) and a.quats.shape == (5000, 4)
    assert torch.equal(a.means, b.means)
    assert not torch.equal(a.means, c.means)
    assert len(a.objects) == 6 and len({o.name for o in a.objects}) == 6
    # every Gaussian of an object lies on that object's bounding box surface (within tolerance)
    for k, o in enumerate(a.objects):
        pts = a.means[a.object_ids == k].numpy()
        assert len(pts) > 0
        lo, hi = o.center - o.size / 2 - 1e-6, o.center + o.size / 2 + 1e-6
        assert np.all((pts >= lo) & (pts <= hi))


def test_discs_lie_flat_on_surfaces():
    s = procedural_room(2000, seed=0)
    rot = quat_wxyz_to_rotmat(s.quats.double())
    floor = (s.object_ids == -1) & (s.means[:, 2].abs() < 1e-9)
    # the thinnest axis (z of the disc frame) of floor discs is the world z axis
    assert torch.allclose(rot[floor][:, :, 2].abs()[:, 2], torch.ones(int(floor.sum()), dtype=torch.float64), atol=1e-6)
    assert (s.log_scales[:, 2] < s.log_scales[:, 0]).all()


def test_scene_objects_do_not_overlap_and_fit_room():
    for seed in range(5):
        s = procedural_room(1000, seed=seed)
        boxes = [(o.center[:2] - o.size[:2] / 2, o.center[:2] + o.size[:2] / 2) for o in s.objects]
        for i in range(len(boxes)):
            assert np.all(boxes[i][0] >= s.free_lo[:2]) and np.all(boxes[i][1] <= s.free_hi[:2])
            for j in range(i + 1, len(boxes)):
                sep = np.any(boxes[i][1] < boxes[j][0]) or np.any(boxes[j][1] < boxes[i][0])
                assert sep, f"objects {i} and {j} overlap (seed {seed})"


def test_bad_arguments():
    with pytest.raises(InvalidInputError):
        procedural_room(10)
    with pytest.raises(InvalidInputError):
        procedural_room(1000, n_objects=0)
    with pytest.raises(InvalidInputError):
        procedural_room(1000).object("piano")


def test_becomes_ellipsoid_scene():
    s = procedural_room(3000, seed=1)
    e = EllipsoidScene.from_splat(s.means, s.quats, s.log_scales, s.opacity_logits)
    assert len(e) == 3000
