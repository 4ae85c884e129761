"""Shot score terms against hand computations and the brute-force occlusion reference; the total is
the documented weighted sum; bad configs get specific errors."""
import math

import numpy as np
import pytest
import torch
from _shot_scenes import TARGET, TARGET_RADIUS, walled_target_scene

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.geometry.occlusion import sight_lines_blocked_reference
from cinenerf_ns.planner.shots.scoring import ScoreConfig, score_shot
from cinenerf_ns.planner.shots.shot import Shot
from cinenerf_ns.planner.trajectory.orientation import look_at_rotations


def _line_shot(a, b, look, fps=30.0, dur=3.0):
    t = np.arange(int(dur * fps) + 1) / fps
    pos = a[None] + (b - a)[None] * (t / t[-1])[:, None]
    return Shot(times=t, positions=pos, rotations=look_at_rotations(pos, look), look_at=look, goal=b, start=a)


@pytest.fixture(scope="module")
def scene():
    return walled_target_scene()


def test_occlusion_term_matches_reference_and_walled_side_is_occluded(scene):
    # fly from behind the wall (x < 0) to the open side (x > 0), looking at the target
    sh = _line_shot(np.array([-0.6, 0.1, 0.4]), np.array([0.9, 0.1, 0.4]), TARGET)
    cfg = ScoreConfig(occlusion_frames=0)
    stop = TARGET_RADIUS + 0.03
    sc = score_shot(sh, scene, TARGET, cfg, object_radius=stop)
    ref = sight_lines_blocked_reference(sh.positions, TARGET, scene.means.numpy(), scene.rotations.numpy(),
                                        scene.radii.numpy(), stop_distance=stop)[:, 0]
    assert np.array_equal(sc.occluded_frames, ref)
    assert math.isclose(sc.terms["occluded_fraction"], ref.mean())
    behind = sh.positions[:, 0] < -0.05
    assert ref[behind].all() and not ref[sh.positions[:, 0] > 0.05].any()
    # the object's own ball hides its centre when the sight line does not stop at its sphere
    own = score_shot(sh, scene, TARGET, cfg, object_radius=0.0)
    assert own.terms["occluded_fraction"] == 1.0


def test_framing_smoothness_duration_and_total(scene):
    look = TARGET
    a = TARGET + np.array([0.6, 0.0, 0.0])
    b = TARGET + np.array([0.6, 0.0, 0.3])
    sh = _line_shot(a, b, look, dur=2.0)
    cfg = ScoreConfig(fov_deg=40.0, target_fill=0.2, occlusion_frames=16)
    sc = score_shot(sh, scene, look, cfg, object_radius=TARGET_RADIUS)
    d = np.linalg.norm(sh.positions - look, axis=1)
    fill = 2 * np.arctan(TARGET_RADIUS / d) / math.radians(40.0)
    assert math.isclose(sc.terms["framing_fill_mean"], fill.mean(), rel_tol=1e-12)
    assert math.isclose(sc.terms["framing_size_error"], np.abs(np.log(fill / 0.2)).mean(), rel_tol=1e-12)
    assert sc.terms["framing_offset"] < 1e-6  # frames aim at the look-at point
    assert sc.terms["max_jerk"] < 1e-6  # constant velocity
    assert math.isclose(sc.terms["duration_s"], 2.0)
    # view turns by the angle subtended by the segment, at a nonzero rate
    total_turn = math.degrees(math.atan2(0.3, 0.6))
    assert math.isclose(sc.terms["mean_angular_rate_deg"] * 2.0, total_turn, rel_tol=1e-6)
    assert math.isclose(sc.total, sum(sc.costs.values()))
    assert len(sc.tested_frame_index) == 16
    d = sc.to_dict()
    assert set(d["terms"]) >= {"occluded_fraction", "min_clearance", "mean_clearance", "max_jerk", "duration_s"}
    # an off-centre object centre shows in framing_offset (in half-fov units)
    centre = look + np.array([0.0, 0.1, 0.0])
    off = score_shot(sh, scene, look, cfg, object_radius=TARGET_RADIUS, object_center=centre)
    ang0 = math.atan2(0.1, 0.6) / math.radians(20.0)
    assert math.isclose(off.terms["framing_offset"], ang0, rel_tol=0.2)
    # zero weights remove terms
    z = score_shot(sh, scene, look, ScoreConfig(w_duration=0, w_jerk=0), object_radius=TARGET_RADIUS)
    assert z.costs["duration"] == 0 and z.costs["jerk"] == 0


def test_clearance_terms_use_exact_clearance(scene):
    sh = _line_shot(np.array([0.5, -0.5, 0.5]), np.array([0.5, 0.5, 0.5]), TARGET)
    sc = score_shot(sh, scene, TARGET, ScoreConfig(clearance_cap=None), object_radius=TARGET_RADIUS)
    from cinenerf_ns.planner.geometry.distance import clearance

    c = clearance(torch.as_tensor(sh.positions), scene).numpy()
    assert math.isclose(sc.terms["min_clearance"], c.min(), rel_tol=1e-9)
    assert math.isclose(sc.terms["mean_clearance"], c.mean(), rel_tol=1e-9)
    # capped search: terms of min(clearance, cap); the costs are unchanged while cap >= clearance_ref
    capped = score_shot(sh, scene, TARGET, ScoreConfig(clearance_cap=0.1), object_radius=TARGET_RADIUS)
    assert c.min() < 0.1 < c.max()
    assert math.isclose(capped.terms["min_clearance"], c.min(), rel_tol=1e-9)
    assert math.isclose(capped.terms["mean_clearance"], np.minimum(c, 0.1).mean(), rel_tol=1e-9)
    assert math.isclose(capped.total, sc.total, rel_tol=1e-12)


def test_bad_config(scene):
    sh = _line_shot(np.array([0.5, -0.5, 0.5]), np.array([0.5, 0.5, 0.5]), TARGET)
    with pytest.raises(InvalidInputError, match="w_occlusion"):
        score_shot(sh, scene, TARGET, ScoreConfig(w_occlusion=-1))
    with pytest.raises(InvalidInputError, match="fov_deg"):
        score_shot(sh, scene, TARGET, ScoreConfig(fov_deg=200))
    with pytest.raises(InvalidInputError, match="look_at"):
        score_shot(sh, scene, [0, 0], ScoreConfig())
