
import pytest
import torch
from _corridor_refs import min_distance as exact_min_distance
from _geom_helpers import random_scene
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.geometry.collision import (
    ellipsoids_collide,
    k_general,
    k_sherman_morrison,
    k_sphere,
    max_k_sherman_morrison,
    max_k_sphere,
    points_collide,
    segments_collide,
)
from cinenerf_ns.planner.geometry.distance import ellipsoid_scaling_factor, point_ellipsoid_distance
from cinenerf_ns.planner.scene.ellipsoids import quat_wxyz_to_rotmat
from cinenerf_ns.planner.scene.spatial_index import GridIndex

F64 = torch.float64


def _rand_ell(g, n, lo=0.05, hi=1.0):
    mu = torch.randn(n, 3, generator=g, dtype=F64)
    rot = quat_wxyz_to_rotmat(torch.randn(n, 4, generator=g, dtype=F64))
    radii = lo + (hi - lo) * torch.rand(n, 3, generator=g, dtype=F64)
    return mu, rot, radii


def _cov(rot, radii):
    return (rot * radii[..., None, :] ** 2) @ rot.transpose(-1, -2)


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 100_000))
def test_corollary1_equals_theorem1(seed):
    g = torch.Generator().manual_seed(seed)
    mu, rot, radii = _rand_ell(g, 20, 0.001, 2.0)
    x = torch.randn(20, 3, generator=g, dtype=F64)
    r = float(torch.rand(1, generator=g)) * 0.5 + 1e-3
    s = torch.rand(9, generator=g, dtype=F64) * 0.998 + 0.001
    w = ((x - mu)[:, :, None] * rot).sum(-2)
    k_cor = k_sphere(w, radii, r, s)
    k_thm = k_general(x, torch.eye(3, dtype=F64).expand(20, 3, 3) * r * r, mu, _cov(rot, radii), s)
    torch.testing.assert_close(k_cor, k_thm, rtol=1e-9, atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 100_000))
def test_proposition1_equals_theorem1(seed):
    g = torch.Generator().manual_seed(seed)
    a = _rand_ell(g, 16, 0.01, 1.5)
    b = _rand_ell(g, 16, 0.01, 1.5)
    s = torch.rand(7, generator=g, dtype=F64) * 0.99 + 0.005
    k_sm = k_sherman_morrison(*a, *b, s)
    k_thm = k_general(a[0], _cov(a[1], a[2]), b[0], _cov(b[1], b[2]), s)
    torch.testing.assert_close(k_sm, k_thm, rtol=1e-8, atol=1e-10)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 100_000))
def test_max_k_matches_scaling_factor_reference(seed):
    """Theorem 1: max_s K = lambda*^2 (independent convex-optimisation reference)."""
    g = torch.Generator().manual_seed(seed)
    a = _rand_ell(g, 1, 0.1, 1.0)
    b = _rand_ell(g, 1, 0.1, 1.0)
    kmax, s_star = max_k_sherman_morrison(*a, *b)
    lam = ellipsoid_scaling_factor(*(t[0] for t in a), *(t[0] for t in b))
    assert float(kmax[0]) == pytest.approx(lam * lam, rel=1e-6)
    assert 0 < float(s_star[0]) < 1
    # and the reported value is a true K value at s*
    k_at = k_sherman_morrison(*a, *b, s_star)
    assert float(k_at[0, 0]) == pytest.approx(float(kmax[0]), rel=1e-12)


def test_max_k_sphere_dense_grid_and_extremes():
    g = torch.Generator().manual_seed(0)
    radii = torch.cat([torch.rand(300, 3, generator=g, dtype=F64) * 0.5 + 1e-4,
                       torch.tensor([[1e-4, 1e-4, 1e-4], [10.0, 10.0, 1e-4]], dtype=F64)])
    w = torch.randn(302, 3, generator=g, dtype=F64) * 0.5
    for r in (1e-3, 0.03, 1.0):
        kmax, s_star = max_k_sphere(w, radii, r)
        s = torch.sigmoid(torch.linspace(-16, 16, 20001, dtype=F64))
        dense = k_sphere(w, radii, r, s).max(-1).values
        assert (kmax >= dense * (1 - 1e-9)).all()  # refined max is at least as good as a fine grid
        torch.testing.assert_close(k_sphere(w, radii, r, s_star[:, None])[:, 0], kmax)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 100_000), r=st.floats(0.0, 0.2), flat=st.booleans())
def test_sphere_never_free_when_touching_and_tight_when_far(seed, r, flat):
    sc = random_scene(12, seed, rmin=0.005, rmax=0.3, camera_radius=r, flat=flat)
    g = torch.Generator().manual_seed(seed)
    pts = torch.rand(300, 3, generator=g, dtype=F64) * 2.8 - 1.4
    d = point_ellipsoid_distance(pts, sc.means, sc.rotations, sc.radii)  # [P, N] exact
    clear = d.min(-1).values - r
    hit = points_collide(pts, sc)
    assert hit[clear <= 0].all(), "reported free although the ball touches an ellipsoid"
    assert not hit[clear > 1e-6 * (1 + r)].any(), "not tight: clearly free point reported colliding"
    idx = GridIndex.build(sc)
    assert torch.equal(points_collide(pts, sc, idx), hit)


def test_sphere_boundary_cases():
    sc = random_scene(1, 0, camera_radius=0.1)
    sc.means.zero_()
    sc.rotations.copy_(torch.eye(3, dtype=F64))
    sc.radii.copy_(torch.tensor([[0.5, 0.3, 0.2]], dtype=F64))
    eps = 1e-5
    pts = torch.tensor([[0.6 - eps, 0, 0], [0.6 + eps, 0, 0], [0, 0, 0.3 + eps], [0, 0, 0], [0, 0.4 - eps, 0]],
                       dtype=F64)
    assert points_collide(pts, sc).tolist() == [True, False, False, True, True]
    with pytest.raises(InvalidInputError):
        points_collide(torch.tensor([[float("nan"), 0, 0]]), sc)
    with pytest.raises(InvalidInputError):
        points_collide(torch.zeros(3), sc)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 100_000))
def test_general_camera_conservative(seed):
    g = torch.Generator().manual_seed(seed)
    a = _rand_ell(g, 8, 0.05, 0.8)
    b = _rand_ell(g, 8, 0.05, 0.8)
    coll = ellipsoids_collide(*a, *b)
    for i in range(8):
        lam = ellipsoid_scaling_factor(*(t[i] for t in a), *(t[i] for t in b))
        if lam <= 1:
            assert coll[i]
        elif lam > 1 + 1e-5:
            assert not coll[i]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 100_000), r=st.floats(0.005, 0.1))
def test_segments_conservative(seed, r):
    sc = random_scene(10, seed, rmin=0.02, rmax=0.25, camera_radius=r)
    g = torch.Generator().manual_seed(seed)
    p0 = torch.rand(40, 3, generator=g, dtype=F64) * 2.6 - 1.3
    p1 = p0 + torch.randn(40, 3, generator=g, dtype=F64) * 0.3
    idx = GridIndex.build(sc)
    hit = segments_collide(p0, p1, sc, idx)
    t = torch.linspace(0, 1, 150, dtype=F64)
    samples = p0[:, None] + t[None, :, None] * (p1 - p0)[:, None]  # [40, 150, 3]
    # exact float64 distances by the tests' own vectorised bisection (independent of the package; -1 inside, where
    # only the sign matters here)
    d = torch.as_tensor(exact_min_distance(samples.reshape(-1, 3).numpy(), sc))
    clear = d.reshape(40, 150).min(-1).values - r
    assert hit[clear <= 0].all()
    # tight: the exact clearance along a segment is at least the sampled one minus half the sample
    # spacing (distance is 1-Lipschitz), so a segment whose sampled clearance beats that is free
    slack = (p1 - p0).norm(dim=-1) / 149 / 2 + 1e-6
    assert not hit[clear > slack].any()
    # a zero-length segment is a point
    assert torch.equal(segments_collide(p0, p0, sc, idx), points_collide(p0, sc, idx))
    assert torch.equal(segments_collide(p0, p1, sc, None), hit)


def test_segment_degenerate_and_endpoint():
    sc = random_scene(1, 0, camera_radius=0.1)
    sc.means.zero_()
    sc.rotations.copy_(torch.eye(3, dtype=F64))
    sc.radii.copy_(torch.tensor([[0.5, 0.3, 0.2]], dtype=F64))
    p0 = torch.tensor([[-2.0, 0, 0], [-2.0, 0.41, 0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]], dtype=F64)
    p1 = torch.tensor([[2.0, 0, 0], [2.0, 0.41, 0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0]], dtype=F64)
    assert segments_collide(p0, p1, sc).tolist() == [True, False, False, True]


@pytest.mark.gpu
def test_cuda_points_collide():
    sc = random_scene(200, 2, camera_radius=0.05)
    pts = torch.rand(500, 3, dtype=F64) * 2 - 1
    a = points_collide(pts, sc, GridIndex.build(sc))
    scc = sc.to("cuda")
    b = points_collide(pts.cuda(), scc, GridIndex.build(scc))
    assert torch.equal(a, b.cpu())


@pytest.mark.gpu
def test_cuda_segments_collide():
    sc = random_scene(100, 6, camera_radius=0.05)
    p0 = torch.rand(200, 3, dtype=F64) * 2 - 1
    p1 = p0 + torch.randn(200, 3, dtype=F64) * 0.2
    a = segments_collide(p0, p1, sc, GridIndex.build(sc))
    scc = sc.to("cuda")
    b = segments_collide(p0.cuda(), p1.cuda(), scc, GridIndex.build(scc))
    assert torch.equal(a, b.cpu())
