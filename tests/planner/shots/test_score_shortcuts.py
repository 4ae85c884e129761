"""The cheaper sight-line test of candidate scoring (score_parts on the CPU copy) gives exactly the answer of the
plain compiled test and of the brute-force float64 reference: the occupancy grid's free-voxel proof and the packed
bounding-sphere prefilter (native/polytope.c: cn_segments_blocked) only skip pieces / ellipsoids that cannot block."""
import numpy as np
import pytest
import torch
from _shot_scenes import TARGET, TARGET_RADIUS, walled_target_scene

from cinenerf_ns.planner import native
from cinenerf_ns.planner.geometry import clearance_queries
from cinenerf_ns.planner.geometry.occlusion import sight_lines_blocked, sight_lines_blocked_reference
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene, quat_wxyz_to_rotmat
from cinenerf_ns.planner.shots.candidate_scores import score_parts
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig
from cinenerf_ns.planner.shots.score_config import ScoreConfig
from cinenerf_ns.planner.shots.shot import Shot
from cinenerf_ns.planner.trajectory.orientation import look_at_rotations

pytestmark = pytest.mark.skipif(native.segments_blocked_c() is None, reason="no compiled sight-line test")


def _random_planner(seed: int, n: int) -> Planner:
    rng = np.random.default_rng(seed)
    means = rng.uniform(-1, 1, (n, 3))
    rot = quat_wxyz_to_rotmat(torch.as_tensor(rng.normal(size=(n, 4)))).numpy()
    radii = np.exp(rng.uniform(np.log(0.01), np.log(0.15), (n, 3)))
    sc = EllipsoidScene(torch.as_tensor(means), torch.as_tensor(rot), torch.as_tensor(radii),
                        torch.ones(n, dtype=torch.float64), camera_radius=0.02)
    pl = Planner(sc, PlannerConfig(grid_resolution=40, start_region=([-1.2] * 3, [1.2] * 3)))
    pl.prepare()
    return pl


def _arrays(pl):
    s = pl.scene
    return s.means.numpy(), s.rotations.numpy(), s.radii.numpy()


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("stop", [0.0, 0.1])
def test_free_grid_and_sphere_prefilter_match_reference(seed, stop):
    pl = _random_planner(seed, 60)
    rng = np.random.default_rng(100 + seed)
    cams = rng.uniform(-1.3, 1.3, (150, 3))  # in and outside the grid, in free and occupied voxels
    tgts = rng.uniform(-1.0, 1.0, (3, 3))
    prep = pl.ready()
    ref = sight_lines_blocked_reference(cams, tgts, *_arrays(pl), stop_distance=stop)
    plain = sight_lines_blocked(cams, tgts, pl.scene, prep.index, stop_distance=stop, backend="native").numpy()
    fast = sight_lines_blocked(cams, tgts, pl.scene, prep.index, stop_distance=stop, backend="native",
                               free_grid=clearance_queries.free_voxel_grid(pl.space)).numpy()
    assert np.array_equal(fast, plain)
    assert np.array_equal(fast, ref)
    assert 0 < ref.mean() < 1  # both answers occur


def test_grazing_lines_match_reference():
    # lines passing just outside / inside one ellipsoid: the prefilter's slack must never drop a hit
    pl = _random_planner(5, 40)
    m, r, a = _arrays(pl)
    prep, fg = pl.ready(), clearance_queries.free_voxel_grid(pl.space)
    rng = np.random.default_rng(7)
    for g in rng.choice(len(m), 10, replace=False):
        axis = r[g][:, int(np.argmax(a[g]))] * a[g].max()  # the longest semi-axis, in world coordinates
        side = r[g][:, int(np.argmin(a[g]))]
        for eps in (-1e-9, 1e-9, -1e-6, 1e-6):
            tip = m[g] + axis * (1 + eps)
            cam, tgt = tip - 0.7 * side, tip + 0.7 * side  # tangent at the tip of the long axis
            ref = sight_lines_blocked_reference(cam, tgt, m, r, a)
            fast = sight_lines_blocked(cam, tgt, pl.scene, prep.index, backend="native", free_grid=fg).numpy()
            plain = sight_lines_blocked(cam, tgt, pl.scene, prep.index, backend="native").numpy()
            assert np.array_equal(fast, plain)
            if abs(eps) >= 1e-6:  # clear of rounding: the reference decides
                assert np.array_equal(fast, ref)


def test_score_parts_on_the_cpu_copy_match_reference():
    pl = Planner(walled_target_scene(),
                 PlannerConfig(grid_resolution=48, start_region=([-0.9, -0.9, 0.1], [0.9, 0.9, 0.9])))
    pl.prepare()
    t = np.linspace(0, 1, 91)
    pos = np.array([-0.6, 0.1, 0.4])[None] + np.array([1.5, 0.0, 0.1])[None] * t[:, None]
    sh = Shot(times=t * 3, positions=pos, rotations=look_at_rotations(pos, TARGET), look_at=TARGET, goal=pos[-1],
              start=pos[0])
    cfg = ScoreConfig(occlusion_frames=0)
    i, occ, clr, vis, _ = score_parts(pl, [sh], TARGET, cfg, TARGET_RADIUS + 0.03, None, None, batch=False)[0]
    ref = sight_lines_blocked_reference(pos[i], TARGET, *_arrays(pl), stop_distance=TARGET_RADIUS + 0.03)
    assert vis is None and np.array_equal(occ, ref) and ref.any() and not ref.all()  # no subject: sight lines
    exact = pl.clearance(pos[i])  # uncapped
    assert np.array_equal(clr, np.minimum(exact, cfg.clearance_cap)) or np.allclose(
        clr, np.minimum(exact, cfg.clearance_cap), rtol=0, atol=1e-12)


def _old_capped_clearance(pl, pts, cap):
    """clearance(pts, cap) as it was before the voxel-box bound and the chained search: the EDT bound, then the
    compiled search one point at a time (no earlier point's distance to start from)."""
    from cinenerf_ns.planner.geometry.distance import clearance as exact_clearance

    out = np.full(len(pts), float(cap))
    todo = np.flatnonzero(clearance_queries.clearance_lower_bound(pl.space, pts) < cap)
    md = float(cap) + float(pl.scene.camera_radius)
    for i in todo:
        out[i] = exact_clearance(torch.as_tensor(pts[i:i + 1]), pl.scene, pl.ready().index, max_distance=md).item()
    return out


@pytest.mark.parametrize("seed", [0, 3])
@pytest.mark.parametrize("cap", [0.05, 0.1, 0.2])
def test_capped_clearance_is_unchanged_and_box_bound_is_a_lower_bound(seed, cap):
    from cinenerf_ns.planner.geometry.distance import point_ellipsoid_distance

    pl = _random_planner(seed, 60)
    rng = np.random.default_rng(200 + seed)
    # a wandering path (consecutive points near each other: the chained search's case) and scattered points
    walk = np.cumsum(rng.normal(scale=0.02, size=(300, 3)), 0) + rng.uniform(-0.5, 0.5, 3)
    pts = np.concatenate([walk, rng.uniform(-1.3, 1.3, (200, 3))])
    new = pl.clearance(pts, cap=cap)
    assert np.array_equal(new, _old_capped_clearance(pl, pts, cap))
    s = pl.scene
    exact = point_ellipsoid_distance(torch.as_tensor(pts), s.means, s.rotations, s.radii).min(1).values.numpy()
    exact = exact - float(s.camera_radius)
    lb = clearance_queries.box_clearance_bound(pl.space, pts, cap)
    proven = lb >= cap
    assert np.all(exact[proven] >= cap)  # never optimistic where it decides
    assert np.all(lb[exact > 0] <= exact[exact > 0] + 1e-12)  # a lower bound wherever the camera is clear
    edt = clearance_queries.clearance_lower_bound(pl.space, pts) >= cap
    assert (proven & ~edt).any()  # it proves points the centre-to-centre bound does not
    assert np.allclose(np.minimum(exact, cap)[exact > 0], new[exact > 0], rtol=0, atol=1e-9)
