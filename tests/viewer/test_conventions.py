"""nerfstudio <-> viser conversions against nerfstudio's own formula (viser.transforms), round trips."""
from __future__ import annotations

import numpy as np
import viser.transforms as vtf
from hypothesis import given, settings, strategies as st

from cinenerf_ns.viewer.conventions import (
    VISER_NERFSTUDIO_SCALE_RATIO,
    interpolate_pose,
    nerfstudio_c2w_to_viser,
    rotmat_to_wxyz,
    viser_to_nerfstudio_c2w,
    viser_to_world,
    world_to_viser,
    wxyz_to_rotmat,
)

finite = st.floats(-10, 10, allow_nan=False)
quat = st.tuples(*[st.floats(-1, 1)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1)


def random_c2w(q, t):
    R = wxyz_to_rotmat(np.array(q))
    return np.concatenate([R, np.array(t)[:, None]], 1)


def test_scale_matches_nerfstudio():
    from nerfstudio.viewer.viewer import VISER_NERFSTUDIO_SCALE_RATIO as ns_ratio

    assert VISER_NERFSTUDIO_SCALE_RATIO == ns_ratio


@settings(max_examples=150, deadline=None)
@given(quat)
def test_quaternion_matches_viser(q):
    q = np.array(q) / np.linalg.norm(q)
    R = vtf.SO3(q).as_matrix()
    np.testing.assert_allclose(wxyz_to_rotmat(q), R, atol=1e-12)
    ours = rotmat_to_wxyz(R)
    assert abs(abs(ours @ q) - 1) < 1e-9  # same rotation (q and -q)
    assert ours[0] >= 0


def test_rotmat_to_wxyz_half_turns():
    for R in [np.diag([1.0, -1, -1]), np.diag([-1.0, 1, -1]), np.diag([-1.0, -1, 1]), np.eye(3)]:
        np.testing.assert_allclose(wxyz_to_rotmat(rotmat_to_wxyz(R)), R, atol=1e-12)


@settings(max_examples=150, deadline=None)
@given(quat, st.tuples(finite, finite, finite))
def test_c2w_to_viser_matches_nerfstudio_formula(q, t):
    c2w = random_c2w(q, t)
    wxyz, pos = nerfstudio_c2w_to_viser(c2w)
    # nerfstudio Viewer.init_scene: R = SO3.from_matrix(c2w[:3,:3]) @ SO3.from_x_radians(pi); pos = t * 10
    ref = vtf.SO3.from_matrix(c2w[:3, :3]) @ vtf.SO3.from_x_radians(np.pi)
    np.testing.assert_allclose(wxyz_to_rotmat(wxyz), ref.as_matrix(), atol=1e-9)
    np.testing.assert_allclose(pos, np.array(t) * 10.0, atol=1e-9)
    # nerfstudio Viewer.get_camera_state (viser camera -> c2w) is our inverse
    R = (vtf.SO3(wxyz) @ vtf.SO3.from_x_radians(np.pi)).as_matrix()
    back = viser_to_nerfstudio_c2w(wxyz, pos)
    np.testing.assert_allclose(back[:, :3], R, atol=1e-9)
    np.testing.assert_allclose(back, c2w, atol=1e-9)


def test_axes_meaning():
    # nerfstudio camera looking along world +y with +z up: c2w columns x=+x, y=+z, z=-y
    c2w = np.array([[1.0, 0, 0, 1], [0, 0, -1, 2], [0, 1, 0, 3]])
    wxyz, pos = nerfstudio_c2w_to_viser(c2w, scale=10)
    R = wxyz_to_rotmat(wxyz)
    np.testing.assert_allclose(R[:, 2], [0, 1, 0], atol=1e-12)  # viser +z forward = world +y
    np.testing.assert_allclose(-R[:, 1], [0, 0, 1], atol=1e-12)  # viser -y up = world +z
    np.testing.assert_allclose(pos, [10, 20, 30])


def test_batched_and_4x4():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(5, 4))
    c2w = np.concatenate([wxyz_to_rotmat(q), rng.normal(size=(5, 3, 1))], -1)
    c44 = np.concatenate([c2w, np.tile([[[0, 0, 0, 1.0]]], (5, 1, 1))], 1)
    w1, p1 = nerfstudio_c2w_to_viser(c2w, 2.0)
    w2, p2 = nerfstudio_c2w_to_viser(c44, 2.0)
    np.testing.assert_allclose(w1, w2)
    np.testing.assert_allclose(viser_to_nerfstudio_c2w(w1, p1, 2.0), c2w, atol=1e-9)
    np.testing.assert_allclose(viser_to_world(world_to_viser(c2w[:, :, 3], 3.0), 3.0), c2w[:, :, 3])


def test_interpolate_pose():
    times = np.array([0.0, 1.0, 3.0])
    pos = np.array([[0.0, 0, 0], [1, 0, 0], [1, 2, 0]])
    Rz = lambda a: vtf.SO3.from_z_radians(np.float64(a)).as_matrix()
    rots = np.stack([Rz(0), Rz(1.0), Rz(2.0)])
    np.testing.assert_allclose(interpolate_pose(times, pos, rots, 2.0)[:, 3], [1, 1, 0])
    np.testing.assert_allclose(interpolate_pose(times, pos, rots, 2.0)[:, :3], Rz(1.5), atol=1e-12)
    np.testing.assert_allclose(interpolate_pose(times, pos, rots, 0.5)[:, :3], Rz(0.5), atol=1e-12)
    np.testing.assert_allclose(interpolate_pose(times, pos, rots, -1)[:, 3], pos[0])  # clamped
    np.testing.assert_allclose(interpolate_pose(times, pos, rots, 9)[:, :3], rots[-1], atol=1e-12)
