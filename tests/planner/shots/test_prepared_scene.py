"""prepared_scene.py: a region with no free space says why (Gaussians larger than the scene, or the camera sphere),
naming options that exist; a splat of Gaussians all larger than the scene is refused at once."""
import time

import numpy as np
import pytest
import torch

from cinenerf_ns.planner.errors import GoalUnreachableError
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene, SceneConfig
from cinenerf_ns.planner.scene.procedural import procedural_room
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig

HANG_GUARD_S = 60.0  # not a performance figure: minutes of rasterising is what this case once took


def test_gaussians_larger_than_the_scene_are_named_as_the_cause():
    r = procedural_room(3000, seed=1)
    huge = torch.full((3000, 3), float(np.log(5.0)))
    sc = EllipsoidScene.from_splat(r.means, r.quats, huge, torch.full((3000,), 5.0), SceneConfig())
    t = time.perf_counter()
    with pytest.raises(GoalUnreachableError, match=r"3000 of the scene's 3000 Gaussians are larger than the region") \
            as e:
        Planner(sc, PlannerConfig(grid_resolution=96)).prepare()
    assert time.perf_counter() - t < HANG_GUARD_S
    assert "--bounds" not in str(e.value)


def test_no_free_voxel_for_the_camera_names_existing_options():
    from cinenerf_ns.planner.shots.prepared_scene import no_free_space

    r = procedural_room(1000, seed=0)
    sc = EllipsoidScene.from_splat(r.means, r.quats, r.log_scales, r.opacity_logits, SceneConfig(camera_radius=0.3))
    msg = no_free_space(sc, torch.full((3,), -1.0, dtype=torch.float64), torch.full((3,), 1.0, dtype=torch.float64))
    assert "--camera-radius" in msg and "--grid-resolution" in msg and "--bounds" not in msg
