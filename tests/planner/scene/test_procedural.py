import numpy as np
import pytest
import torch

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene, quat_wxyz_to_rotmat
from cinenerf_ns.planner.scene.procedural import procedural_room


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


def test_walls_of_a_long_room_get_gaussians_by_their_area():
    """The walls at x = +-W/2 are D x H, those at y = +-D/2 are W x H: in a 4 x 1 room the y walls hold 4x as many
    Gaussians as the x walls, at the same density (the areas were swapped: x walls got W x H)."""
    w, d, h = 4.0, 1.0, 1.0
    s = procedural_room(40_000, seed=2, room=(w, d, h))
    m = s.means.double()
    wall = (s.object_ids == -1) & (m[:, 2] > 1e-9)
    on_x = wall & ((m[:, 0].abs() - w / 2).abs() < 1e-5)
    on_y = wall & ((m[:, 1].abs() - d / 2).abs() < 1e-5)
    assert int((on_x & on_y).sum()) == 0 and int((on_x | on_y).sum()) == int(wall.sum())
    dens_x, dens_y = int(on_x.sum()) / (2 * d * h), int(on_y.sum()) / (2 * w * h)
    assert abs(dens_x / dens_y - 1) < 0.1, (dens_x, dens_y)
    # disc sizes follow the spacing of their own surface: the same density gives the same sizes
    sx, sy = s.log_scales[on_x, 0].double().exp().median(), s.log_scales[on_y, 0].double().exp().median()
    assert abs(float(sx / sy) - 1) < 0.1, (float(sx), float(sy))
