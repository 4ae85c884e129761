"""prepared_scene.py: a region with no free space says why (Gaussians larger than the scene, or the camera sphere),
naming options that exist; a splat of Gaussians all larger than the scene is refused at once."""
import time

import numpy as np
import pytest
import torch

from cinenerf_ns.planner.errors import GoalUnreachableError, InvalidInputError
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.procedural import procedural_room
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig

HANG_GUARD_S = 60.0  # not a performance figure: minutes of rasterising is what this case once took


@pytest.mark.parametrize("n,radius", [(3000, 5.0), (3000, 1.5), (500, 5.0)])
def test_gaussians_larger_than_the_scene_are_named_as_the_cause(n, radius):
    """Every Gaussian larger than the scene (or than half of it): refused at once with the cause (it once rasterised
    for minutes); a small scene of them (under OVERSIZED_SPLAT) ends with no free space, the same cause named."""
    r = procedural_room(max(n, 1000), seed=1)
    huge = torch.full((n, 3), float(np.log(radius / 2)))  # semi-axis = beta 2 x opacity ~1 x scale
    sc = EllipsoidScene.from_splat(r.means[:n], r.quats[:n], huge, torch.full((n,), 9.0), SceneConfig())
    t = time.perf_counter()
    with pytest.raises((InvalidInputError, GoalUnreachableError)) as e:
        Planner(sc, PlannerConfig(grid_resolution=96)).prepare()
    assert time.perf_counter() - t < HANG_GUARD_S
    want = ("larger than half the planning region" if n >= 1000 else "larger than the region itself")
    assert f"{n} of the scene's {n} Gaussians are {want}" in str(e.value) and "--bounds" not in str(e.value)


def test_no_free_voxel_for_the_camera_names_existing_options():
    from cinenerf_ns.planner.shots.prepared_scene import no_free_space

    r = procedural_room(1000, seed=0)
    sc = EllipsoidScene.from_splat(r.means, r.quats, r.log_scales, r.opacity_logits, SceneConfig(camera_radius=0.3))
    msg = no_free_space(sc, torch.full((3,), -1.0, dtype=torch.float64), torch.full((3,), 1.0, dtype=torch.float64))
    assert "--camera-radius" in msg and "--grid-resolution" in msg and "--bounds" not in msg
