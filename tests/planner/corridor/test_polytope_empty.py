"""safe_polytope's stop_when_empty: the compiled emptiness proof (native/polytope.c cn_planes_empty) against the
float64 radius of the planes in the cube (HiGHS), and the stopped polytopes of both paths against the full ones."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, example, given, settings, strategies as st

from cinenerf_ns.planner.corridor.polytope import chebyshev_center, safe_polytope
from cinenerf_ns.planner.corridor.polytope_native import planes_empty_native
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.native import planes_empty_c
from cinenerf_ns.planner.scene.spatial_index import GridIndex
from cinenerf_ns.planner.search.projection import INTERIOR_RADIUS, project_onto_polytope

sys.path.insert(0, str(Path(__file__).parents[1]))
from _corridor_refs import make_scene, random_rotations  # noqa: E402

pytestmark = pytest.mark.skipif(planes_empty_c() is None, reason="no C compiler: the compiled polytope is not built")
SETTINGS = dict(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
BAND = 1e-7  # HiGHS' feasibility tolerance: inside this band around the shrink radius either answer is right


def _plane_radius_in_cube(n, b, centre, half) -> float:
    """max over x in the cube |x - centre|_inf <= half of min_f (b_f - n_f.x) / |n_f| (float64 LP, HiGHS): the largest
    shrink for which cn_planes_empty's set {x in the cube : n.x <= b - shrink |n|} is not empty. The cube bounds x
    and is not shrunk (unlike a Chebyshev ball, which must also fit inside the cube)."""
    from scipy.optimize import linprog

    norm = np.linalg.norm(n, axis=1)
    res = linprog(np.r_[0.0, 0.0, 0.0, -1.0], A_ub=np.hstack([n, norm[:, None]]), b_ub=b,
                  bounds=[(c - half, c + half) for c in centre] + [(None, None)], method="highs")
    assert res.status == 0, res.message
    return float(-res.fun)


def _cube(centre, half):
    A = np.vstack([np.eye(3), -np.eye(3)])
    return A, np.concatenate([centre + half, half - centre])


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), F=st.integers(1, 40), spread=st.sampled_from([0.05, 0.3, 1.0]),
       shrink=st.sampled_from([0.0, 5e-10, 1e-3, 0.05]), scale=st.sampled_from([1.0, 1e-3, 50.0]))
@example(seed=89, F=4, spread=0.05, shrink=0.05, scale=1.0)  # the widest point lies at the cube's face
def test_planes_empty_is_the_plane_radius_in_the_cube(seed, F, spread, shrink, scale):
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-2, 2, 3) * scale
    half = float(rng.uniform(0.2, 1.0)) * scale
    n = rng.normal(size=(F, 3)) * rng.uniform(0.5, 2.0, (F, 1))  # not unit: the proof normalises
    # planes through points near the centre, some facing it, some away: empty and non-empty sets
    p = centre + rng.normal(size=(F, 3)) * spread * half
    b = np.einsum("fi,fi->f", n, p)
    got = planes_empty_native(planes_empty_c(), n, b, shrink * scale, centre, half)
    rad = _plane_radius_in_cube(n, b, centre, half)
    band = BAND * max(scale, 1.0)
    if got:
        assert rad < shrink * scale + band, (rad, shrink * scale)
    else:
        assert rad > shrink * scale - band, (rad, shrink * scale)


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), F=st.integers(4, 40), shrink=st.sampled_from([0.0, 5e-10, 1e-3]))
def test_planes_empty_known_answers(seed, F, shrink):
    rng = np.random.default_rng(seed)
    centre, half = rng.uniform(-1, 1, 3), 1.0
    x = centre + rng.uniform(-0.5, 0.5, 3)
    n = rng.normal(size=(F, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    b = n @ x + rng.uniform(2 * shrink + 1e-6, 0.3, F)  # every plane keeps a ball of radius > shrink around x
    fn = planes_empty_c()
    assert not planes_empty_native(fn, n, b, shrink, centre, half)
    # and two opposite planes a gap apart make any superset empty
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    gap = float(rng.uniform(1e-6, 0.2))
    n2 = np.vstack([n, u, -u])
    b2 = np.concatenate([b, [u @ x - gap / 2, -(u @ x) - gap / 2]])
    order = rng.permutation(F + 2)
    assert planes_empty_native(fn, n2[order], b2[order], shrink, centre, half)


def _clump_scene(rng, n_clump=600, n_far=300):
    """A dense clump of ellipsoids around the origin inside sparse clutter."""
    means = np.vstack([rng.normal(0, 0.08, (n_clump, 3)), rng.uniform(-1, 1, (n_far, 3))])
    radii = np.vstack([rng.uniform(0.02, 0.06, (n_clump, 3)), rng.uniform(0.005, 0.05, (n_far, 3))])
    return make_scene(means, random_rotations(rng, len(means)), radii, 0.02)


@pytest.mark.parametrize("backend", ["native", "python"])
@pytest.mark.parametrize("seed", range(4))
def test_stopped_polytope_is_empty_and_only_when_the_full_one_is(backend, seed):
    rng = np.random.default_rng(seed)
    scene = _clump_scene(rng)
    index = GridIndex.build(scene)
    rho = 0.5 * INTERIOR_RADIUS
    stops = 0
    targets = np.vstack([rng.normal(0, 0.03, (6, 3)), rng.uniform(-1, 1, (6, 3))])  # in the clump, in the open
    for t in targets:
        lo, hi = t - 0.3, t + 0.3
        kw = dict(require_seed_inside=False, backend=backend)
        full = safe_polytope(t[None], scene, index, lo, hi, **kw)
        stop = safe_polytope(t[None], scene, index, lo, hi, stop_when_empty=rho, **kw)
        Af, bf = full.to_numpy()
        As, bs = stop.to_numpy()
        stopped = stop.ellipsoid_ids.numel() > 0 and int(stop.ellipsoid_ids[-1]) == -1
        assert stop.proven_empty == stopped and not full.proven_empty  # what closest_safe_point reads
        if stopped:
            stops += 1
            assert chebyshev_center(As, bs)[1] == -np.inf  # explicitly empty: no point at all
            assert (As[-1] == As[0]).all() and bs[-1] < -bs[3]
            assert chebyshev_center(Af, bf)[1] < rho + BAND  # and the full polytope holds no such ball either
            assert project_onto_polytope(Af, bf, t) is None and project_onto_polytope(As, bs, t) is None
        else:  # the probe's planes were dropped: the very same polytope
            assert np.array_equal(Af, As) and np.array_equal(bf, bs)
            assert torch.equal(full.ellipsoid_ids, stop.ellipsoid_ids)
    assert stops >= 3  # targets in the clump are stopped early


def test_stop_when_empty_needs_seeds_that_may_be_outside():
    rng = np.random.default_rng(0)
    scene = _clump_scene(rng, 50, 50)
    t = np.zeros(3)
    with pytest.raises(InvalidInputError):
        safe_polytope(t[None], scene, None, t - 0.3, t + 0.3, stop_when_empty=1e-9)
    with pytest.raises(InvalidInputError):
        safe_polytope(t[None], scene, None, t - 0.3, t + 0.3, require_seed_inside=False, stop_when_empty=-1.0)
