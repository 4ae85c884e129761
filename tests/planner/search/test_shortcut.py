"""The shortcut's grid filters (cinenerf_ns/planner/search/shortcut.py) against per-point float64 references."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import torch
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner.search.shortcut import FreeVoxels, free_voxels, grid_sight


def in_free_voxel_reference(occ: np.ndarray, lo: np.ndarray, vs: float, p: np.ndarray) -> bool:
    """One point, plain Python: its voxel floor((p - lo) / vs) is in the grid and free (Planner.in_free_voxel)."""
    ijk = [math.floor((float(p[a]) - float(lo[a])) / vs) for a in range(3)]
    return all(0 <= ijk[a] < occ.shape[a] for a in range(3)) and not bool(occ[ijk[0], ijk[1], ijk[2]])


def grid_sight_reference(occ: np.ndarray, lo: np.ndarray, vs: float, p0: np.ndarray, p1: np.ndarray) -> bool:
    """One segment, sample by sample: every sample k / (n - 1) (n = max(2, ceil(L / (vs / 2)) + 1)) farther than one
    voxel from both ends lies in a free voxel."""
    L = float(np.linalg.norm(p1 - p0))
    n = max(2, int(math.ceil(L / (0.5 * vs))) + 1)
    for k in range(n):
        frac = k / (n - 1)
        if min(frac, 1 - frac) * L > vs and not in_free_voxel_reference(occ, lo, vs, p0 + frac * (p1 - p0)):
            return False
    return True


def fake_planner(occ: np.ndarray, lo: np.ndarray, vs: float):
    """What free_voxels reads of a prepared Planner: the A* grid's occupancy and the grid's corner and voxel size."""
    prep = SimpleNamespace(astar_grid=SimpleNamespace(_occ=occ),
                           grid=SimpleNamespace(lo=torch.as_tensor(lo, dtype=torch.float64), voxel_size=vs))
    return SimpleNamespace(ready=lambda: prep)


grids = st.tuples(st.integers(0, 2**31 - 1), st.integers(1, 9), st.integers(1, 9), st.integers(1, 9),
                  st.floats(0.0, 0.9), st.sampled_from([0.05, 0.1, 0.37]))


def make_grid(spec):
    seed, X, Y, Z, fill, vs = spec
    rng = np.random.default_rng(seed)
    occ = rng.random((X, Y, Z)) < fill
    lo = rng.uniform(-1, 1, 3)
    return rng, occ, lo, vs


@settings(max_examples=150, deadline=None)
@given(spec=grids, n=st.integers(0, 60))
def test_free_voxels_matches_the_per_point_reference(spec, n):
    """FreeVoxels.contains == the per-point reference, for points inside, outside and exactly on voxel faces."""
    rng, occ, lo, vs = make_grid(spec)
    ext = np.array(occ.shape) * vs
    pts = lo - 0.3 * ext + rng.random((n, 3)) * 1.6 * ext
    on_faces = lo + rng.integers(-1, max(occ.shape) + 2, (n, 3)) * vs  # exactly on faces, edges and corners
    pts = np.vstack([pts, on_faces])
    fv = FreeVoxels(occ, lo, vs)
    got = fv.contains(pts)
    assert got.dtype == bool and got.shape == (len(pts),)
    assert got.tolist() == [in_free_voxel_reference(occ, lo, vs, p) for p in pts]


@settings(max_examples=150, deadline=None)
@given(spec=grids, n=st.integers(1, 12), grid_aligned=st.booleans())
def test_grid_sight_matches_the_sample_by_sample_reference(spec, n, grid_aligned):
    rng, occ, lo, vs = make_grid(spec)
    ext = np.array(occ.shape) * vs
    p0 = lo - 0.2 * ext + rng.random((n, 3)) * 1.4 * ext
    p1 = lo - 0.2 * ext + rng.random((n, 3)) * 1.4 * ext
    if grid_aligned:  # voxel centres and corners, as the voxel path gives; some segments of length 0
        p0 = lo + (rng.integers(0, max(occ.shape), (n, 3)) + 0.5 * rng.integers(0, 2, (n, 1))) * vs
        p1 = np.where(rng.random((n, 1)) < 0.2, p0, lo + (rng.integers(0, max(occ.shape), (n, 3)) + 0.5) * vs)
    pl = fake_planner(occ, lo, vs)
    got = grid_sight(pl, p0, p1)
    assert got.tolist() == [grid_sight_reference(occ, lo, vs, a, b) for a, b in zip(p0, p1)]


def test_free_voxels_is_cached_per_grid():
    occ = np.zeros((3, 3, 3), dtype=bool)
    pl = fake_planner(occ, np.zeros(3), 0.1)
    fv = free_voxels(pl)
    assert free_voxels(pl) is fv
    pl.ready().astar_grid._occ = occ.copy()  # another grid: rebuilt
    assert free_voxels(pl) is not fv
