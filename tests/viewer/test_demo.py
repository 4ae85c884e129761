"""Stand-in straight-line planner and demo scene: every returned shot keeps the camera sphere out of
every obstacle (checked independently with inflated ellipsoids), bad starts / blocked goals raise."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from cinenerf_ns.planner.errors import GoalUnreachableError, StartInCollisionError
from cinenerf_ns.planner.scene import EllipsoidScene
from cinenerf_ns.viewer.backend import NoMatchError, label_locate, parse_point
from cinenerf_ns.viewer.demo import StraightLinePlanner, demo_scene, look_at_rotation


def scene_of(d) -> EllipsoidScene:
    t = lambda x: torch.as_tensor(np.asarray(x), dtype=torch.float64)
    return EllipsoidScene.from_splat(t(d.means), t(d.quats_wxyz), t(d.log_scales), t(d.opacity_logits))


def inside_inflated(points, scene) -> np.ndarray:
    """Reference: p is unsafe if inside the ellipsoid with semi-axes a + r (a superset of
    ellipsoid (+) camera ball)."""
    mu, R = scene.means.numpy(), scene.rotations.numpy()
    a = scene.radii.numpy() + scene.camera_radius
    d = np.einsum("nji,pnj->pni", R, points[:, None, :] - mu[None])  # body coordinates [P, N, 3]
    return ((d / a[None]) ** 2).sum(-1).min(1) <= 1.0


@pytest.fixture(scope="module")
def demo():
    d = demo_scene()
    return d, scene_of(d), label_locate(d.means, d.labels, d.label_of)


def densify(pos, step=0.002):
    out = [pos[0]]
    for a, b in zip(pos[:-1], pos[1:]):
        n = max(int(np.ceil(np.linalg.norm(b - a) / step)), 1)
        out.extend(a + (b - a) * k / n for k in range(1, n + 1))
    return np.array(out)


@pytest.mark.parametrize("goto,look", [("green ball", "red box"), ("red box", "blue pillar"), ("blue pillar", "green ball")])
def test_demo_shots_are_safe(demo, goto, look):
    d, scene, locate = demo
    planner = StraightLinePlanner.from_scene(scene)
    goal, look_at = locate(goto)[0], locate(look)[0]
    shots = planner.plan(goal, look_at, seed=1, n_candidates=3)
    assert len(shots) == 3
    for s in shots:
        dense = densify(s.positions)
        assert not inside_inflated(dense, scene).any()
        assert np.linalg.norm(s.positions[-1] - goal) < 0.5 * np.linalg.norm(s.positions[0] - goal)
        fwd = -s.rotations[-1][:, 2]
        to_target = (look_at - s.positions[-1]) / np.linalg.norm(look_at - s.positions[-1])
        assert fwd @ to_target > 0.999  # looks at the look-at target
        assert np.all(np.diff(s.times) > 0) and s.clearance.min() > 0


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000))
def test_random_goals_safe_or_refused(demo, seed):
    d, scene, _ = demo
    planner = StraightLinePlanner.from_scene(scene)
    rng = np.random.default_rng(seed)
    goal, look = rng.uniform(-1, 1, 3) * [1, 1, 0.5] + [0, 0, 0.3], rng.uniform(-1, 1, 3)
    try:
        shots = planner.plan(goal, look, seed=seed, n_candidates=1)
    except GoalUnreachableError:
        return
    for s in shots:
        assert not inside_inflated(densify(s.positions), scene).any()


def test_start_in_collision_and_unreachable(demo):
    d, scene, locate = demo
    planner = StraightLinePlanner.from_scene(scene)
    with pytest.raises(StartInCollisionError):
        planner.plan(np.array([0.0, 0.0, 0.5]), np.zeros(3), start=locate("red box")[0] + [0.12, 0, 0])
    # behind the pillar as seen from the start, the straight line is blocked
    with pytest.raises(GoalUnreachableError):
        planner.plan(np.array([0.0, -0.9, 0.3]), np.zeros(3), start=np.array([0.0, -0.3, 0.3]))


def test_look_at_rotation_convention():
    R = look_at_rotation(np.zeros(3), np.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(R, [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)  # -z forward, +y up
    R = look_at_rotation(np.zeros(3), np.array([0.0, 0.0, -1.0]))  # straight down: no NaN
    assert np.all(np.isfinite(R)) and np.allclose(R @ R.T, np.eye(3))


def test_label_locate_and_parse_point(demo):
    d, _, locate = demo
    c, m = locate("the Red Box")
    assert m.sum() == (d.label_of == 0).sum()
    np.testing.assert_allclose(c, d.means[d.label_of == 0].mean(0), atol=1e-6)
    assert locate("pillar")[1].sum() == (d.label_of == 2).sum()
    with pytest.raises(NoMatchError, match="known: red box"):
        locate("sofa")
    assert parse_point("1 2 3").tolist() == [1, 2, 3]
    assert parse_point("(1.5, -2e-1, .3)").tolist() == [1.5, -0.2, 0.3]
    for bad in ["1 2", "chair", "1 2 3 4", "nan 1 2", ""]:
        assert parse_point(bad) is None


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 300))
def test_kdtree_clearance_equals_brute_force(seed, n):
    rng = np.random.default_rng(seed)
    planner = StraightLinePlanner(rng.uniform(-1, 1, (n, 3)), rng.exponential(0.1, n), camera_radius=0.03)
    pts = rng.uniform(-1.5, 1.5, (50, 3))
    np.testing.assert_allclose(planner.clearance_lower_bound(pts), planner.clearance_lower_bound_reference(pts),
                               rtol=0, atol=1e-12)
