"""reach.free_voxel_near's segment tests: the certain-collision proof against float64 brute force, and the first
free segment against the swept-capsule test on every segment (the answer it replaced)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings, strategies as st

from cinenerf_ns.planner.geometry.collision import segments_collide
from cinenerf_ns.planner.native import points_distance_c
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.procedural import procedural_room
from cinenerf_ns.planner.search import reach, shortcut as shortcut_module
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig

sys.path.insert(0, str(Path(__file__).parents[1]))
from _corridor_refs import clearance  # noqa: E402

pytestmark = pytest.mark.skipif(points_distance_c() is None, reason="no C compiler: the compiled search is not built")
SETTINGS = dict(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(scope="module")
def planner():
    room = procedural_room(4000, seed=2)
    e = EllipsoidScene.from_splat(room.means, room.quats, room.log_scales, room.opacity_logits)
    pl = Planner(e, PlannerConfig(grid_resolution=48, candidate_workers=0))
    pl.prepare()
    return pl


def _segment_clearance(scene, p, q, n=200) -> float:
    """min exact clearance (float64 brute force) of n points along p -> q, over the ellipsoids whose bounding sphere
    inflated by the camera radius reaches the segment (no other one can be within the radius of it)."""
    mu = scene.means.double().numpy()
    d = q - p
    u = np.clip((mu - p) @ d / max(float(d @ d), 1e-300), 0, 1)
    gap = np.linalg.norm(p + u[:, None] * d - mu, axis=1)
    near = np.flatnonzero(gap <= scene.radii.double().numpy().max(1) + scene.camera_radius + 1e-6)
    if near.size == 0:
        return np.inf
    t = np.linspace(0, 1, n)[:, None]
    return float(clearance(p + t * d, scene.subset(torch.as_tensor(near))).min())


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 24))
def test_proven_blocked_segments_really_collide(planner, seed, n):
    rng = np.random.default_rng(seed)
    lo, hi = planner.region()
    p = rng.uniform(lo, hi)
    ends = p + rng.normal(0, 0.15, (n, 3))
    blocked = reach.segments_proven_blocked(planner.space, p, ends)
    scene = planner.scene
    for k in np.flatnonzero(blocked)[:4]:  # float64 brute force: some point of it is within the radius
        assert _segment_clearance(scene, p, ends[k], n=400) < 0
    # and the capsule test (conservative) never accepts one of them
    coll = segments_collide(torch.as_tensor(np.broadcast_to(p, ends.shape).copy()), torch.as_tensor(ends), scene,
                            planner.ready().index)
    assert coll.numpy()[blocked].all()


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 24), spread=st.sampled_from([0.03, 0.15, 0.4]))
def test_first_free_segment_is_the_capsule_tests_first_or_proven_free(planner, seed, n, spread):
    rng = np.random.default_rng(seed)
    lo, hi = planner.region()
    p = rng.uniform(lo, hi)
    ends = p + rng.normal(0, spread, (n, 3))
    pt, et = torch.as_tensor(p), torch.as_tensor(ends)
    got = reach._first_free_segment(planner.space, pt, et)
    ref_free = np.flatnonzero(~segments_collide(pt.expand_as(et), et, planner.scene, planner.ready().index).numpy())
    proven = np.flatnonzero(shortcut_module.segments_free(planner.space, np.broadcast_to(p, ends.shape), ends))
    if got is None:
        assert ref_free.size == 0 and proven.size == 0
        return
    # the capsule test's first free one, unless the cheap proof accepted an earlier one
    want = min(ref_free[0] if ref_free.size else n, proven[0] if proven.size else n)
    assert got == want
    # the segment returned is collision-free: float64 brute force on dense samples
    assert _segment_clearance(planner.scene, p, ends[got]) >= 0
