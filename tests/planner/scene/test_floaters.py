"""planner/scene/floaters.py: small, faint, isolated Gaussians as non-obstacles, by a stated rule; the verification
says which obstacle set it checked."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.floaters import (
    FLOATER_AUTO_FRACTION,
    FLOATER_ISOLATION_RADII,
    apply_floater_rule,
    floater_mask,
)
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig
from cinenerf_ns.synthetic.grove import grove_scene

R = 0.04  # camera radius of the hand-made scenes


def _scene(means, radii, opacities):
    n = len(means)
    return EllipsoidScene(torch.as_tensor(np.asarray(means, float)), torch.eye(3, dtype=torch.float64).repeat(n, 1, 1),
                          torch.as_tensor(np.asarray(radii, float)), torch.as_tensor(np.asarray(opacities, float)),
                          camera_radius=R)


def test_the_rule_needs_faint_small_and_isolated():
    far = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    small, big = [0.005] * 3, [0.05] * 3
    s = _scene(far, [small, small, big, small], [0.2, 0.9, 0.2, 0.39])
    np.testing.assert_array_equal(floater_mask(s), [True, False, False, True])  # opaque / big ones stay
    # the same faint small Gaussian beside a surface patch (many means within the isolation radius) stays
    rng = np.random.default_rng(0)
    patch = np.c_[rng.uniform(-0.05, 0.05, (10, 2)), np.zeros(10)]
    s = _scene(np.r_[[[0.0, 0, 0.01]], patch], [small] * 11, [0.2] + [0.9] * 10)
    assert not floater_mask(s)[0]
    # isolation is a distance: a second faint speck just outside FLOATER_ISOLATION_RADII leaves both isolated
    d = FLOATER_ISOLATION_RADII * R * 1.01
    s = _scene([[0.0, 0, 0], [d, 0, 0]], [small] * 2, [0.2, 0.2])
    assert floater_mask(s).all()


def test_grove_floaters_are_found_and_surfaces_are_not():
    g = grove_scene(50_000, seed=1)
    e = EllipsoidScene.from_params(g.splat, SceneConfig.with_margin())
    kind = g.kind[e.source_index.numpy()] if e.source_index is not None else g.kind
    m = floater_mask(e)
    assert (kind[m] == 4).all()  # no ground, trunk, canopy, rock or background Gaussian
    assert m.sum() >= 0.5 * (kind == 4).sum()


def test_modes_and_counts():
    small = [0.005] * 3
    n = 200
    rng = np.random.default_rng(1)
    means = rng.uniform(0, 10, (n, 3))  # all isolated
    ops = np.where(np.arange(n) < 3, 0.2, 0.9)  # 3 floaters = 1.5%
    s = _scene(means, [small] * n, ops)
    off, c = apply_floater_rule(s, "off")
    assert off is s and not c.ignored and c.to_dict()["ignored_gaussians"] == 0
    on, c = apply_floater_rule(s, "on")
    assert len(on) == n - 3 and c.ignored and c.count == 3 and "3 floaters ignored" in c.obstacle_note()
    auto, c = apply_floater_rule(s, "auto")
    assert c.ignored == (3 >= FLOATER_AUTO_FRACTION * n)
    few = _scene(means, [small] * n, np.where(np.arange(n) < 1, 0.2, 0.9))
    _, c = apply_floater_rule(few, "auto")
    assert c.count == 1 and not c.ignored and "floaters kept" in c.obstacle_note()
    with pytest.raises(InvalidInputError, match="--ignore-floaters must be one of auto, on, off"):
        apply_floater_rule(s, "sometimes")


def test_verification_states_the_obstacle_set():
    g = grove_scene(20_000, seed=2)
    full = EllipsoidScene.from_params(g.splat, SceneConfig.with_margin())
    scene, choice = apply_floater_rule(full, "on")
    pl = Planner(scene, PlannerConfig(grid_resolution=48, obstacles_note=choice.obstacle_note()))
    shot = pl.plan(np.array([0.4, 0.3, 0.5]), np.zeros(3), start=np.array([-0.6, -0.4, 0.6]))[0]
    assert shot.safety["safe"] and shot.safety["obstacles"] == choice.obstacle_note()
    assert f"{choice.count} floaters ignored" in shot.safety["obstacles"] and choice.count > 0
    plain = Planner(full, PlannerConfig(grid_resolution=48))
    assert plain.obstacle_set() == f"all {len(full)} ellipsoids of the scene"
