"""Two-pass candidate gathering of safe_polytope (near the seeds first, then only grid cells not cut
off by the kept planes) and GridIndex.query_box_in_planes, against float64 brute force."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch
from hypothesis import HealthCheck, assume, given, settings, strategies as st
from scipy.optimize import linprog

from cinenerf_ns.planner.corridor.polytope import SeedNotFreeError, safe_polytope
from cinenerf_ns.planner.scene.spatial_index import GridIndex

sys.path.insert(0, str(Path(__file__).parents[1]))
from _corridor_refs import polytope_min_distance, random_scene  # noqa: E402

SETTINGS = dict(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _box_meets_polytope(lo, hi, A, b) -> bool:
    """float64 LP: does the box [lo, hi] meet {A x <= b}?"""
    res = linprog(np.zeros(3), A_ub=A, b_ub=b, bounds=list(zip(lo, hi)), method="highs")
    return res.status == 0


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), n_planes=st.integers(0, 6), cell=st.sampled_from([None, 0.03, 0.3]),
       max_cells=st.sampled_from([4_000_000, 1]), dedupe=st.sampled_from([0, 10**9]))
def test_query_box_in_planes_returns_every_aabb_meeting_box_and_planes(seed, n_planes, cell, max_cells, dedupe):
    import cinenerf_ns.planner.scene.spatial_index as si

    old, si.SORT_DEDUPE_RATIO = si.SORT_DEDUPE_RATIO, dedupe  # 0: flags over N; huge: sort the entries
    try:
        _check_query_box_in_planes(seed, n_planes, cell, max_cells)
    finally:
        si.SORT_DEDUPE_RATIO = old


def _check_query_box_in_planes(seed, n_planes, cell, max_cells):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, 300, amin=0.01, amax=0.08, camera_radius=0.03)
    idx = GridIndex.build(scene, cell_size=cell)
    c = rng.uniform(-0.8, 0.8, 3)
    lo, hi = c - rng.uniform(0.05, 0.6, 3), c + rng.uniform(0.05, 0.6, 3)
    n = rng.normal(size=(n_planes, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    b = n @ c + rng.uniform(-0.1, 0.3, n_planes)  # planes through the box, some cutting off its centre
    got = set(idx.query_box_in_planes(torch.tensor(lo), torch.tensor(hi), torch.tensor(n), torch.tensor(b),
                                     max_cells=max_cells).tolist())
    glo, ghi = idx.lo.numpy(), idx.hi.numpy()
    meets_box = ((glo <= hi) & (ghi >= lo)).all(1)
    assert got <= set(np.flatnonzero(meets_box).tolist())  # never an ellipsoid outside the box
    for j in np.flatnonzero(meets_box):
        if j not in got:  # skipped: its padded AABB must miss box ∩ planes (exact LP)
            assert not _box_meets_polytope(np.maximum(glo[j], lo), np.minimum(ghi[j], hi), n, b), j


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), n_seeds=st.sampled_from([1, 2]), frac=st.sampled_from([0.1, 0.5, 1.0]),
       backend=st.sampled_from(["python", "auto"]))
def test_two_pass_polytope_excludes_every_inflated_ellipsoid(seed, n_seeds, frac, backend):
    """Both paths: Python and (auto) the compiled one where it loads."""
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, 250, amin=0.01, amax=0.1, camera_radius=0.03)
    idx = GridIndex.build(scene)
    seeds = rng.uniform(-0.6, 0.6, (n_seeds, 3))
    if n_seeds == 2:
        seeds[1] = seeds[0] + rng.normal(size=3) * 0.2
    lo, hi = seeds.min(0) - 0.25, seeds.max(0) + 0.25
    try:
        P = safe_polytope(seeds, scene, idx, lo, hi, two_pass=True, near_fraction=frac, backend=backend)
    except SeedNotFreeError:
        assume(False)
    A, b = P.to_numpy()
    assert (seeds @ A.T <= b + 1e-12).all()  # seeds inside
    # brute force over ALL ellipsoids, float64: excluded by one plane (exact support function), else
    # the exact SOCP distance from the polytope to the ellipsoid must be >= the camera radius
    r = scene.camera_radius
    mu, R, a = (t.double().numpy() for t in (scene.means, scene.rotations, scene.radii))
    nb = np.einsum("cji,fj->cfi", R, A)  # [C, F, 3]
    gap = mu @ A.T - np.linalg.norm(a[:, None, :] * nb, axis=-1) - r  # [C, F]
    single = (gap >= b).any(1)
    rest = np.flatnonzero(~single)
    if rest.size:
        d = polytope_min_distance(A, b, scene.subset(torch.as_tensor(rest)))
        assert (d >= r - 1e-6).all(), (rest[d < r - 1e-6], d.min())
