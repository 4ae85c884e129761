"""Shot: construction from a trajectory, validation, summary JSON."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.shots.shot import Shot
from cinenerf_ns.planner.trajectory.bezier import BezierTrajectory
from cinenerf_ns.planner.trajectory.timing import TimingConfig


def arc_trajectory() -> BezierTrajectory:
    cps = np.array(
        [
            [[0, -2, 0.5], [0, -2, 0.5], [1, -2, 0.6], [2, -1.5, 0.7], [2.5, -0.5, 0.8], [2.5, 0, 0.8]],
            [[2.5, 0, 0.8], [2.5, 0.5, 0.8], [2.4, 1.2, 0.9], [1.5, 2, 1.0], [0.5, 2, 1.0], [0.5, 2, 1.0]],
        ]
    )
    return BezierTrajectory(cps, [3.0, 3.0])


def make_shot(**kw) -> Shot:
    traj = arc_trajectory()
    sphere = lambda p: np.linalg.norm(np.asarray(p) - np.array([0.0, 0.0, 0.5]), axis=1) - 1.0
    return Shot.from_trajectory(
        traj, look_at=np.array([0.0, 0.0, 0.5]), timing=TimingConfig(fps=24.0, **kw),
        clearance_fn=sphere, timings={"qp_ms": 3.5},
    )


def test_from_trajectory():
    shot = make_shot()
    assert shot.num_frames == len(shot.times) and shot.fps == 24.0
    np.testing.assert_allclose(np.diff(shot.times), 1 / 24, rtol=1e-9)
    np.testing.assert_array_equal(shot.positions[0], shot.start)
    np.testing.assert_allclose(shot.positions[-1], shot.goal, atol=1e-12)
    assert shot.look_at_errors_deg().max() < 1e-6
    assert shot.frame_speeds().max() <= 0.5 * (1 + 1e-7)
    c2w = shot.camera_to_worlds()
    np.testing.assert_array_equal(c2w[:, :3, :3], shot.rotations)
    np.testing.assert_array_equal(c2w[:, :3, 3], shot.positions)
    np.testing.assert_array_equal(c2w[:, 3], np.broadcast_to([0, 0, 0, 1.0], (shot.num_frames, 4)))
    assert {"qp_ms", "timing_ms", "orientation_ms", "clearance_ms"} <= set(shot.timings)
    # clearance is what the function says at the frames
    np.testing.assert_allclose(shot.clearance, np.linalg.norm(shot.positions - [0, 0, 0.5], axis=1) - 1.0)


def test_summary_json():
    shot = make_shot()
    d = json.loads(shot.to_json())
    assert d["num_frames"] == shot.num_frames
    assert d["duration_s"] == pytest.approx(shot.times[-1])
    assert d["length"] == pytest.approx(shot.length)
    i = int(np.argmin(shot.clearance))
    assert d["min_clearance"] == pytest.approx(shot.clearance[i])
    assert d["argmin_clearance_time_s"] == pytest.approx(shot.times[i])
    assert d["timings_ms"]["qp_ms"] == 3.5
    assert d["trajectory"]["segments"] == 2
    full = json.loads(shot.to_json(include_frames=True))
    np.testing.assert_allclose(full["frames"]["positions"], shot.positions)
    assert BezierTrajectory.from_dict(full["trajectory"]["bezier"]).num_segments == 2
    # length: exact arc length, at least the frame polyline
    poly = np.linalg.norm(np.diff(shot.positions, axis=0), axis=1).sum()
    assert poly <= shot.length <= poly * 1.001


def test_torch_inputs_and_no_trajectory():
    t = torch.linspace(0, 1, 5, dtype=torch.float64)
    pos = torch.stack([t, torch.zeros(5, dtype=torch.float64), torch.zeros(5, dtype=torch.float64)], 1)
    shot = Shot(t, pos, torch.eye(3, dtype=torch.float64).expand(5, 3, 3), [0, 0, 1], [1, 0, 0], [0, 0, 0])
    assert isinstance(shot.positions, np.ndarray) and shot.length == pytest.approx(1.0)
    assert shot.fps == pytest.approx(4.0)
    d = json.loads(shot.to_json())
    assert d["min_clearance"] is None and "trajectory" not in d


@pytest.mark.parametrize(
    "kw",
    [
        dict(times=np.array([0.0, 0.0])),
        dict(positions=np.zeros((3, 3))),
        dict(rotations=np.zeros((2, 3))),
        dict(look_at=[np.nan, 0, 0]),
        dict(clearance=np.zeros(5)),
    ],
)
def test_bad_shot(kw):
    base = dict(
        times=np.array([0.0, 1.0]), positions=np.zeros((2, 3)), rotations=np.tile(np.eye(3), (2, 1, 1)),
        look_at=[0, 0, 1], goal=[0, 0, 0], start=[0, 0, 0],
    )
    base.update(kw)
    with pytest.raises(InvalidInputError):
        Shot(**base)


@pytest.mark.parametrize("fps", [10.0, 30.0, 60.0])
def test_resampled_stays_on_curve_and_keeps_roll(fps):
    shot = make_shot()
    r = shot.resampled(fps)
    assert r.fps == fps and r.clearance is None
    assert r.duration == pytest.approx(shot.duration, abs=1e-12)
    np.testing.assert_allclose(np.diff(r.times)[:-1], 1 / fps, rtol=1e-9)
    np.testing.assert_allclose(r.positions[0], shot.start, atol=1e-12)
    np.testing.assert_allclose(r.positions[-1], shot.goal, atol=1e-9)
    # every new frame is a point of the Bezier curve at the interpolated curve time
    np.testing.assert_allclose(r.positions, shot.trajectory.evaluate(r.curve_times), atol=1e-12)
    assert r.look_at_errors_deg().max() < 1e-6
    np.testing.assert_allclose(np.einsum("tij,tik->tjk", r.rotations, r.rotations),
                               np.broadcast_to(np.eye(3), r.rotations.shape), atol=1e-9)
    assert np.linalg.det(r.rotations).min() > 0.999
    # at times both shots have, the frames agree (roll preserved)
    common = np.isclose(r.times[:, None], shot.times[None], atol=1e-9)
    i, j = np.nonzero(common)
    assert len(i) >= 2
    np.testing.assert_allclose(r.rotations[i], shot.rotations[j], atol=1e-6)


def test_resampled_same_fps_is_identity_and_bad_fps():
    shot = make_shot()
    assert shot.resampled(24.0) is shot
    with pytest.raises(InvalidInputError):
        shot.resampled(0.0)
