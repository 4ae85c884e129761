"""planner/scene/planning_region.py: which rule chooses the planning region (user box, training cameras, dense
content), bad user boxes refused with clear errors; a start region (the training cameras' box) that is inverted or
not finite is refused with the cause named (issue 38: the message once named the symptom)."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.planning_region import (
    AUTO_RESOLUTION_MAX,
    GRID_BYTES_PER_VOXEL,
    check_start_region,
    dense_content_box,
    grid_resolution_for,
)
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig
from cinenerf_ns.synthetic.grove import grove_scene


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
    from cinenerf_ns.planner.scene.procedural import procedural_room

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


@pytest.fixture(scope="module")
def grove():
    g = grove_scene(30_000, seed=5, background_fraction=0.1, floater_fraction=0.05)
    return g, EllipsoidScene.from_params(g.splat)


def test_dense_content_ignores_the_background_shell_and_floaters(grove):
    g, e = grove
    lo, hi = dense_content_box(e.means, e.opacities)
    cell = 15.0 / 64  # about the outer box's longest side / bins
    assert (lo >= g.content_lo - 2 * cell).all() and (hi <= g.content_hi + 2 * cell).all()
    assert (lo <= g.content_lo + [0.5, 0.5, 0.1]).all() and (hi >= g.content_hi - [0.5, 0.5, 0.3]).all()
    # the robust box of all means is stretched by the far shell (what the dense rule is for)
    rlo, rhi = (t.numpy() for t in Planner(e, PlannerConfig(region_rule="robust")).planning_bounds())
    assert (rhi - rlo).max() > 2 * (hi - lo).max()


def test_dense_content_box_of_a_single_cluster_is_its_box():
    """With no sparse matter at all the dense box is the points' own box (to a cell)."""
    rng = np.random.default_rng(0)
    m = torch.as_tensor(rng.uniform([0, 0, 0], [2, 1, 0.5], (5000, 3)))
    lo, hi = dense_content_box(m, torch.ones(5000))
    cell = 2.0 / 64
    np.testing.assert_allclose(lo, [0, 0, 0], atol=cell)
    np.testing.assert_allclose(hi, [2, 1, 0.5], atol=cell)


def test_rules_are_named(grove):
    _, e = grove
    dense = Planner(e, PlannerConfig(grid_resolution=32))
    assert dense.region_rule() == "dense content"
    lo, hi = (t.numpy() for t in dense.planning_bounds())
    assert (hi - lo).max() < 8.5  # the grove (6 units) + padding, not the 15-unit shell
    box = (np.array([-1.0, -1.0, 0.1]), np.array([1.0, 1.0, 1.0]))
    cams = Planner(e, PlannerConfig(grid_resolution=32, start_region=box))
    assert cams.region_rule() == "training cameras"
    clo, chi = (t.numpy() for t in cams.planning_bounds())
    grow = 0.5 * 2.0  # region_padding x the start region's longest side
    assert (clo >= box[0] - grow - 1e-9).all() and (chi <= box[1] + grow + 1e-9).all()
    user = Planner(e, PlannerConfig(grid_resolution=32, bounds=box))
    assert user.region_rule() == "user box"
    user.prepare()
    rlo, rhi = user.region()
    vs = float(user.prepared.grid.voxel_size)
    np.testing.assert_allclose(rlo, box[0])
    assert (rhi >= box[1] - 1e-9).all() and (rhi <= box[1] + vs + 1e-9).all()  # whole voxels
    assert Planner(e, PlannerConfig(region_rule="robust")).region_rule() == "robust box of all means"


@pytest.mark.parametrize("bounds,regex", [
    (([20, 20, 20], [21, 21, 21]), r"lies outside the scene, whose Gaussians span"),
    (([-1, -1, 0.5], [1, 1, 0.55]), r"too small for the camera along z"),
    (([0, 0, 0], [0, 1, 1]), r"empty or inverted along x"),
    (([-1e30, -1e30, -1e30], [1e30, 1e30, 1e30]), r"more than 10 x larger than the scene"),
])
def test_bad_boxes_are_refused_before_the_grid(grove, bounds, regex):
    _, e = grove
    pl = Planner(e, PlannerConfig(bounds=tuple(np.asarray(b, float) for b in bounds)))
    with pytest.raises(InvalidInputError, match=regex):
        pl.prepare()
    assert pl.prepared is None


def test_region_rule_is_validated():
    with pytest.raises(InvalidInputError, match="region_rule"):
        PlannerConfig(region_rule="widest").validate()


def test_an_evenly_spread_scene_keeps_the_robust_box():
    """Without far content (no shell, no sky) the dense rule does not apply: a scene of evenly spread Gaussians has no
    dense core, and cutting it to a random heaviest group of cells once made a tiny region (issue 37 merge)."""
    g = torch.Generator().manual_seed(0)
    n = 2000
    sc = EllipsoidScene.from_splat(torch.rand(n, 3, generator=g) * 2 - 1, torch.randn(n, 4, generator=g),
                                   torch.full((n, 3), -4.0), torch.zeros(n))
    pl = Planner(sc, PlannerConfig())
    lo, hi = (t.cpu().numpy() for t in pl.planning_bounds())
    assert (hi - lo).min() > 1.8  # about the [-1, 1] cube, not a corner of it
    assert pl.region_rule().startswith("robust box of all means")


def test_random_starts_stay_in_a_user_box_that_leaves_the_cameras_out():
    """A user box cuts the start region (the training cameras' box) to their intersection; a box that leaves the
    cameras out entirely draws random starts anywhere in it (they once raised 'start region is empty')."""
    from cinenerf_ns.planner.scene.planning_region import starts_within
    from cinenerf_ns.planner.scene.procedural import procedural_room

    lo, hi = np.zeros(3), np.ones(3)
    cut = starts_within((np.full(3, -1.0), np.full(3, 0.5)), lo, hi)
    np.testing.assert_array_equal(cut[0], lo)
    np.testing.assert_array_equal(cut[1], np.full(3, 0.5))
    assert starts_within((np.full(3, 2.0), np.full(3, 3.0)), lo, hi) is None
    assert starts_within(None, lo, hi) is None

    torch.set_num_threads(1)
    r = procedural_room(2000, seed=0)
    scene = EllipsoidScene.from_splat(r.means, r.quats, r.log_scales, r.opacity_logits)
    flo, fhi = np.asarray(r.free_lo), np.asarray(r.free_hi)
    cameras = (flo + 0.03, flo + 0.3 * (fhi - flo))  # one corner of the room
    box = (np.r_[flo[:2] + 0.6 * (fhi - flo)[:2], flo[2] + 0.02], fhi - 0.02)  # the opposite corner
    planner = Planner(scene, PlannerConfig(grid_resolution=32, start_region=cameras, bounds=box, candidate_workers=0))
    shots = planner.plan((box[0] + box[1]) / 2, box[1] - 0.05, seed=0, n_candidates=2)
    rlo, rhi = planner.region()
    assert planner.config.start_region is None and shots
    for s in shots:
        assert np.all(s.positions >= rlo - 1e-9) and np.all(s.positions <= rhi + 1e-9)


@settings(max_examples=200, deadline=None)
@given(side=st.tuples(*[st.floats(0.05, 40.0)] * 3), r=st.floats(1e-3, 0.5), res=st.integers(8, 300),
       radii=st.one_of(st.none(), st.floats(0.2, 8.0)), budget=st.floats(64, 8192))
def test_grid_resolution_for_raises_only_as_far_as_asked_and_allowed(side, r, res, radii, budget):
    cfg = PlannerConfig(grid_resolution=res, max_voxel_radii=radii, memory_budget_mb=budget)
    lo = np.zeros(3)
    hi = np.asarray(side, dtype=np.float64)
    got = grid_resolution_for(cfg, r, lo, hi)
    longest = float(hi.max())
    assert isinstance(got, int) and got >= res
    if radii is None:
        assert got == res
        return
    assert got <= max(res, AUTO_RESOLUTION_MAX)
    if got > res:  # a raise: never finer than asked, within the memory budget
        assert longest / got >= radii * r * (1 - 1e-12) or longest / (got - 1) > radii * r
        voxels = float(np.prod(np.ceil(hi / (longest / got))))
        assert voxels * GRID_BYTES_PER_VOXEL / 2**20 <= budget * (1 + 1e-9)
    elif longest / res > radii * r:  # not raised although coarse: capped or out of budget
        want = int(np.ceil(longest / (radii * r)))
        capped = min(want, AUTO_RESOLUTION_MAX) <= res
        over = float(np.prod(np.ceil(hi / (longest / min(want, AUTO_RESOLUTION_MAX))))) * GRID_BYTES_PER_VOXEL / 2**20
        assert capped or over > budget


def test_the_grove_region_is_planned_at_voxels_under_two_camera_radii(grove):
    pl = Planner(grove[1], PlannerConfig())
    lo, hi = (v.cpu().numpy() for v in pl.planning_bounds())
    r = float(pl.scene.camera_radius)
    res = grid_resolution_for(pl.config, r, lo, hi)
    assert res > 96 and float((hi - lo).max()) / res <= 1.9 * r
    assert grid_resolution_for(PlannerConfig(max_voxel_radii=None), r, lo, hi) == 96


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), True, "2"])
def test_max_voxel_radii_is_validated(bad):
    with pytest.raises(InvalidInputError, match="max_voxel_radii"):
        PlannerConfig(max_voxel_radii=bad).validate()
