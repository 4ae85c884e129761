"""Long off-grid segments split before their Prop-2 polytopes (safe_corridor.py ``split_long``): the corridor still
covers the same polyline with safe polytopes, checked against the float64 exact clearance reference."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch
from hypothesis import HealthCheck, given, settings, strategies as st

from cinenerf_ns.planner.corridor.grid_polytope import VoxelObstacles
from cinenerf_ns.planner.corridor.safe_corridor import build_corridor, build_corridors
from cinenerf_ns.planner.scene.spatial_index import GridIndex

sys.path.insert(0, str(Path(__file__).parents[1]))
from _corridor_refs import clearance, make_scene, random_rotations, random_scene  # noqa: E402
from test_polytope import vertices_and_interior  # noqa: E402
from test_safe_corridor import free_polyline  # noqa: E402

GRID_LO, GRID_N = -1.2, 29  # voxels of 2.4 / 29 ~ 0.083 over [-1.2, 1.2]^3


def conservative_voxels(scene) -> VoxelObstacles:
    """Occupancy grid that is conservative by construction: a voxel is free only when the exact clearance (camera
    radius included) of its centre is at least its half-diagonal (clearance is 1-Lipschitz, so every point of a free
    voxel then has clearance >= 0)."""
    vs = -2 * GRID_LO / GRID_N
    c = GRID_LO + vs * (np.stack(np.meshgrid(*[np.arange(GRID_N)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5)
    occ = clearance(c, scene) < 0.5 * np.sqrt(3) * vs
    return VoxelObstacles.from_occupied(occ.reshape(GRID_N, GRID_N, GRID_N), np.full(3, GRID_LO), vs)


def on_polyline(points: np.ndarray, way: np.ndarray) -> bool:
    """Every point lies on the polyline ``way`` [K, 3], in order, and every vertex of ``way`` is one of them."""
    k = 0
    for p in points:
        while k < len(way) - 1:
            a, b = way[k], way[k + 1]
            t = float(np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1))
            if np.linalg.norm(a + t * (b - a) - p) <= 1e-12:
                break
            k += 1
        else:
            if not np.allclose(p, way[-1], atol=1e-12):
                return False
    return all(np.min(np.linalg.norm(points - v, axis=1)) <= 1e-15 for v in way)


def check_corridor(cor, way: np.ndarray, scene, rng) -> None:
    wps = cor.waypoints.numpy()
    assert on_polyline(wps, way)
    assert len(cor) == len(wps) - 1
    for m, P in enumerate(cor.polytopes):
        assert bool(P.contains(cor.waypoints[m:m + 2]).all())
        assert clearance(vertices_and_interior(P, rng, 15), scene).min() >= -1e-9


def grazing_scene():
    """A small sphere next to the x axis: the segment along it keeps exact clearance 0.02 but crosses voxels the
    conservative grid calls occupied."""
    return make_scene([[0.0, 0.08, 0.03]], random_rotations(np.random.default_rng(0), 1), [[0.02, 0.02, 0.02]], 0.03)


def test_long_grazing_segment_is_split_and_stays_safe():
    scene = grazing_scene()
    grid, index = conservative_voxels(scene), GridIndex.build(scene)
    way = np.array([[-0.9, 0.01, 0.03], [0.9, 0.01, 0.03]])
    assert not grid.segments_free(way[:1], way[1:])[0]
    one = build_corridor(way, scene, index, box_margin=0.1, grid=grid)
    cor = build_corridor(way, scene, index, box_margin=0.1, grid=grid, split_long=0.2)
    assert len(one) == 1 and one.n_long_pieces == 0
    assert cor.n_long_pieces == len(cor) - 1 >= 2 and cor.n_grid_segments == 0
    assert 0 < sum(P.ellipsoid_ids is None for P in cor.polytopes) < len(cor)  # grid pieces and Prop-2 pieces
    check_corridor(cor, way, scene, np.random.default_rng(1))
    # every Prop-2 piece is short; every grid piece lies in free voxels
    for m, P in enumerate(cor.polytopes):
        a, b = cor.waypoints[m].numpy(), cor.waypoints[m + 1].numpy()
        if P.ellipsoid_ids is None:
            assert grid.segments_free(a[None], b[None])[0]
        else:
            assert np.linalg.norm(b - a) <= 0.2
    # build_corridors splits the same way, per path
    many = build_corridors([way, way[::-1].copy()], scene, index, box_margin=0.1, grid=grid, split_long=0.2)
    assert torch.equal(many[0].waypoints, cor.waypoints) and len(many[1]) == len(cor)
    # the batched backend gets the same pieces (the split comes before either backend)
    bat = build_corridor(way, scene, index, box_margin=0.1, grid=grid, split_long=0.2, backend="batched")
    assert torch.equal(bat.waypoints, cor.waypoints) and bat.n_long_pieces == cor.n_long_pieces
    check_corridor(bat, way, scene, np.random.default_rng(2))


def test_no_split_without_grid_or_when_short():
    scene = grazing_scene()
    grid, index = conservative_voxels(scene), GridIndex.build(scene)
    way = np.array([[-0.9, 0.01, 0.03], [0.9, 0.01, 0.03]])
    assert build_corridor(way, scene, index, box_margin=0.1, split_long=0.2).n_long_pieces == 0  # no grid
    assert build_corridor(way, scene, index, box_margin=0.1, grid=grid, split_long=2.0).n_long_pieces == 0


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 6), k=st.integers(2, 4),
       split=st.sampled_from([0.15, 0.3, 0.6]))
def test_split_corridor_covers_the_polyline_and_is_safe(seed, n, k, split):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, n, amax=0.15, camera_radius=0.03)
    way = free_polyline(rng, scene, k, step=0.7)
    if way is None:
        return
    grid, index = conservative_voxels(scene), GridIndex.build(scene)
    cor = build_corridor(way, scene, index, box_margin=0.1, grid=grid, split_long=split)
    ref = build_corridor(way, scene, index, box_margin=0.1, grid=grid)
    assert len(cor) - cor.n_splits == len(ref) - ref.n_splits + cor.n_long_pieces
    check_corridor(cor, way, scene, rng)
