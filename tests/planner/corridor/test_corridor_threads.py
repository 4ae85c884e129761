"""build_corridor / build_corridors with ``threads``: the same polytopes, waypoints, counts and errors as the serial
build (the grid and host polytopes of a corridor are independent; host_pool.ordered_map runs them at once)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings, strategies as st

from cinenerf_ns.planner.corridor.safe_corridor import CorridorError, build_corridor, build_corridors
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.spatial_index import GridIndex

sys.path.insert(0, str(Path(__file__).parents[1]))
sys.path.insert(0, str(Path(__file__).parent))
from _corridor_refs import make_scene, random_scene  # noqa: E402
from test_safe_corridor import free_polyline  # noqa: E402
from test_split_long import conservative_voxels  # noqa: E402


def same_corridor(a, b) -> None:
    assert len(a) == len(b)
    assert torch.equal(a.waypoints, b.waypoints)
    for p, q in zip(a.polytopes, b.polytopes):
        assert torch.equal(p.A, q.A) and torch.equal(p.b, q.b)
    assert torch.equal(a.overlap_radius, b.overlap_radius)
    assert (a.n_splits, a.n_grid_segments, a.n_known_segments, a.n_long_pieces, a.thin_joints) == \
        (b.n_splits, b.n_grid_segments, b.n_known_segments, b.n_long_pieces, b.thin_joints)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 8), k=st.integers(2, 6), with_grid=st.booleans(),
       threads=st.integers(2, 6))
def test_threads_build_the_serial_corridor(seed, n, k, with_grid, threads):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, n, amax=0.15, camera_radius=0.03)
    ways = [w for w in (free_polyline(rng, scene, k, step=0.5) for _ in range(3)) if w is not None]
    if not ways:
        return
    index = GridIndex.build(scene)
    kw = dict(box_margin=0.1)
    if with_grid:
        kw.update(grid=conservative_voxels(scene), split_long=0.3)
    for w in ways:
        same_corridor(build_corridor(w, scene, index, threads=threads, **kw), build_corridor(w, scene, index, **kw))
    serial = build_corridors(ways, scene, index, **kw)
    for a, b in zip(build_corridors(ways, scene, index, threads=threads, **kw), serial):
        same_corridor(a, b)


@pytest.mark.parametrize("threads", [1, 3])
def test_first_blocked_segment_is_the_error(threads):
    """Two segments through obstacles: the error names the first one, as the serial loop does."""
    scene = make_scene([[0.0, 0, 0], [1.0, 0, 0]], np.stack([np.eye(3)] * 2), [[0.2, 0.2, 0.2]] * 2, 0.03)
    way = [[-0.5, 0.5, 0.0], [-0.5, 0.0, 0.0], [0.5, 0.0, 0.0], [1.0, -0.5, 0.0], [1.0, 0.5, 0.0]]
    with pytest.raises(CorridorError, match="segment 1 "):
        build_corridor(way, scene, GridIndex.build(scene), 0.1, max_split_depth=2, threads=threads)


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_bad_thread_counts_are_refused(bad):
    scene = make_scene([[5.0, 5, 5]], np.eye(3)[None], [[0.2, 0.2, 0.2]], 0.03)
    with pytest.raises(InvalidInputError, match="threads must be an integer >= 1"):
        build_corridor([[0.0, 0, 0], [1.0, 0, 0]], scene, None, 0.1, threads=bad)
    with pytest.raises(InvalidInputError, match="threads must be an integer >= 1"):
        build_corridors([[[0.0, 0, 0], [1.0, 0, 0]]], scene, None, threads=bad)
