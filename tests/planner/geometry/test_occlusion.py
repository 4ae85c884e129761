"""Sight-line occlusion: the indexed, chunked fast path agrees with the brute-force float64 quadratic
reference on random scenes; exclusion by mask and by stop distance; specific input errors."""
import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner import native
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.geometry.occlusion import sight_lines_blocked, sight_lines_blocked_reference
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene, quat_wxyz_to_rotmat
from cinenerf_ns.planner.scene.spatial_index import GridIndex

# the compiled test (native/polytope.c: cn_segments_blocked) and the torch path, both against the reference
BACKENDS = ["python"] + (["native"] if native.segments_blocked_c() is not None else [])


def _random_scene(rng, n):
    means = rng.uniform(-1, 1, (n, 3))
    rot = quat_wxyz_to_rotmat(torch.as_tensor(rng.normal(size=(n, 4)))).numpy()
    radii = np.exp(rng.uniform(np.log(0.01), np.log(0.3), (n, 3)))
    sc = EllipsoidScene(torch.as_tensor(means), torch.as_tensor(rot), torch.as_tensor(radii),
                        torch.ones(n, dtype=torch.float64), camera_radius=0.02)
    return sc, means, rot, radii


def _tangency_gap(cam, tgt, means, rot, radii, stop):
    """[T, S] min over ellipsoids of |min_t |u + t v|^2 - 1|: lines grazing an ellipsoid within rounding."""
    out = np.full((len(cam), len(tgt)), np.inf)
    for i, p in enumerate(cam):
        for j, q in enumerate(tgt):
            L = np.linalg.norm(q - p)
            te = max(0.0, 1 - stop / L) if L > 0 else 0.0
            u = np.einsum("nji,nj->ni", rot, p - means) / radii
            v = np.einsum("nji,j->ni", rot, q - p) / radii
            vv = (v * v).sum(1)
            t = np.clip(np.where(vv > 0, -(u * v).sum(1) / np.maximum(vv, 1e-300), 0), 0, te)
            w = u + t[:, None] * v
            out[i, j] = np.abs((w * w).sum(1) - 1).min()
    return out


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 60), stop=st.sampled_from([0.0, 0.05, 0.3]),
       use_mask=st.booleans())
def test_matches_brute_force_reference(seed, n, stop, use_mask):
    rng = np.random.default_rng(seed)
    sc, means, rot, radii = _random_scene(rng, n)
    cam = rng.uniform(-1.5, 1.5, (7, 3))
    tgt = rng.uniform(-1, 1, (3, 3))
    mask = rng.random(n) < 0.3 if use_mask else None
    ref = sight_lines_blocked_reference(cam, tgt, means, rot, radii, exclude=mask, stop_distance=stop)
    m_eff = means if mask is None else means[~mask]
    if len(m_eff):
        r_eff, a_eff = (rot, radii) if mask is None else (rot[~mask], radii[~mask])
        clear_cut = _tangency_gap(cam, tgt, m_eff, r_eff, a_eff, stop) > 1e-9
    else:
        clear_cut = np.ones_like(ref)
    idx = GridIndex.build(sc)
    for backend in BACKENDS:
        got = sight_lines_blocked(cam, tgt, sc, idx, exclude=None if mask is None else torch.as_tensor(mask),
                                  stop_distance=stop, backend=backend).numpy()
        assert np.array_equal(got[clear_cut], ref[clear_cut]), backend


def test_wall_blocks_and_mask_or_stop_distance_unblocks():
    # one flat ellipsoid (a wall piece) at x = 0 between the camera at x = -1 and the target at x = 1
    sc = EllipsoidScene(torch.tensor([[0.0, 0, 0], [1.0, 0, 0]], dtype=torch.float64),
                        torch.eye(3, dtype=torch.float64).repeat(2, 1, 1),
                        torch.tensor([[0.01, 0.5, 0.5], [0.2, 0.2, 0.2]], dtype=torch.float64),
                        torch.ones(2, dtype=torch.float64))
    cams = np.array([[-1.0, 0, 0], [-1.0, 2.0, 0]])  # behind the wall / beside it
    tgt = np.array([1.0, 0, 0])  # centre of the second ellipsoid (the "object")
    idx = GridIndex.build(sc)
    for backend in BACKENDS:
        b = sight_lines_blocked(cams, tgt, sc, idx, backend=backend).numpy()[:, 0]
        assert b.tolist() == [True, True]  # the object's own ellipsoid blocks its centre from everywhere
        for first in (True, False):  # whichever of the two the compiled code's spatial order puts first
            mask = torch.tensor([not first, first])
            b = sight_lines_blocked(cams, tgt, sc, idx, exclude=mask, backend=backend).numpy()[:, 0]
            assert b.tolist() == ([True, False] if first else [True, True]), (backend, first)
        b = sight_lines_blocked(cams, tgt, sc, idx, stop_distance=0.25, backend=backend).numpy()[:, 0]
        assert b.tolist() == [True, False]


def test_bad_input():
    rng = np.random.default_rng(0)
    sc, *_ = _random_scene(rng, 5)
    with pytest.raises(InvalidInputError, match="camera positions"):
        sight_lines_blocked(np.zeros((3, 2)), np.zeros(3), sc)
    with pytest.raises(InvalidInputError, match="NaN"):
        sight_lines_blocked(np.full((1, 3), np.nan), np.zeros(3), sc)
    with pytest.raises(InvalidInputError, match="exclude"):
        sight_lines_blocked(np.ones((1, 3)), np.zeros(3), sc, exclude=torch.zeros(4, dtype=torch.bool))
    with pytest.raises(InvalidInputError, match="stop_distance"):
        sight_lines_blocked(np.ones((1, 3)), np.zeros(3), sc, stop_distance=-1.0)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), rho=st.floats(0.9, 1.1).filter(lambda x: abs(x - 1) > 1e-6),
       tpos=st.floats(-0.5, 1.5))
def test_grazing_lines_match_reference(seed, rho, tpos):
    """Sight lines built to pass at unit-frame distance rho of one ellipsoid (closest approach at line
    parameter tpos, possibly beyond an end): the boundary cases where a sloppy test would differ."""
    rng = np.random.default_rng(seed)
    sc, means, rot, radii = _random_scene(rng, 6)
    g = 0
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    n = rng.normal(size=3)
    n -= (n @ d) * d
    n /= np.linalg.norm(n)
    # in the unit frame: w(t) = rho n + (t - tpos) d, t in [0, 1]; closest approach rho at t = tpos
    length = rng.uniform(0.5, 3.0)
    w0, w1 = rho * n - tpos * length * d, rho * n + (1 - tpos) * length * d
    to_world = lambda w: means[g] + rot[g] @ (radii[g] * w)  # noqa: E731
    cam, tgt = to_world(w0), to_world(w1)
    ref = sight_lines_blocked_reference(cam[None], tgt[None], means, rot, radii)[0, 0]
    idx = GridIndex.build(sc)
    for backend in BACKENDS:
        got = sight_lines_blocked(cam[None], tgt[None], sc, idx, backend=backend).numpy()[0, 0]
        assert got == ref, backend
    if 0 <= tpos <= 1:  # the closest approach is on the segment: blocked iff rho <= 1 (or another ellipsoid)
        assert got or rho > 1
