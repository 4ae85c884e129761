"""planning_region.py: a start region (the training cameras' box) that is inverted or not finite is refused with the
cause named (issue 38: the message once named the symptom, the "planning region's longest side (-0.69)")."""
import numpy as np
import pytest

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.planning_region import check_start_region


def test_inverted_start_region_names_the_axis():
    with pytest.raises(InvalidInputError, match=r"start region .* inverted along x, z: lo \(1, 0, 2\) is above hi"):
        check_start_region(np.array([1.0, 0.0, 2.0]), np.array([0.0, 1.0, 1.0]))


@pytest.mark.parametrize("lo,hi", [([0, 0, np.nan], [1, 1, 1]), ([0, 0, 0], [1, np.inf, 1]), ([0, 0], [1, 1])])
def test_non_finite_or_malformed_start_region(lo, hi):
    with pytest.raises(InvalidInputError, match="start region .* must be two finite points"):
        check_start_region(np.array(lo, float), np.array(hi, float))


def test_flat_and_ordinary_regions_pass():
    check_start_region(np.zeros(3), np.zeros(3))  # one camera: a point (the planner grows it)
    check_start_region(-np.ones(3), np.ones(3))


def test_a_planner_with_an_inverted_start_region_refuses_before_building_anything():
    from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
    from cinenerf_ns.planner.scene.procedural import procedural_room
    from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig

    r = procedural_room(1000, seed=0)
    sc = EllipsoidScene.from_splat(r.means, r.quats, r.log_scales, r.opacity_logits)
    p = Planner(sc, PlannerConfig(start_region=(np.array([0.5, 0, 0]), np.array([-0.5, 1, 1]))))
    with pytest.raises(InvalidInputError, match="inverted along x"):
        p.region()


@pytest.mark.parametrize("p", [(0.0, 0.0, 1e300), (1e300, -1e300, 0.5), (3.0, 4.0, 0.5), (0.5, 0.5, 0.5)])
def test_distance_outside_without_overflow(p):
    """A point 1e300 away is 1e300 away, without numpy's overflow warning (it once printed one to stderr)."""
    import math
    import warnings

    from cinenerf_ns.planner.scene.planning_region import distance_outside

    lo, hi = np.zeros(3), np.ones(3)
    d = [max(a - x, x - b, 0.0) for a, b, x in zip(lo, hi, p)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert distance_outside(lo, hi, np.array(p)) == pytest.approx(math.hypot(*d), rel=1e-12)
