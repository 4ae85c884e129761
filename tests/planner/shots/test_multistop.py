"""Multi-stop shots: the curve passes exactly through every stop, the frames pass within one frame step
of it, the path is verified safe with the exact clearance, the look-at turns smoothly from stop to stop,
the dynamic limits hold on the exported frames; specific errors."""
import numpy as np
import pytest
import torch
from _shot_scenes import TARGET, walled_target_scene

from cinenerf_ns.planner.errors import InvalidInputError, StartInCollisionError
from cinenerf_ns.planner.geometry.distance import clearance
from cinenerf_ns.planner.shots.multistop import plan_multistop
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig
from cinenerf_ns.planner.trajectory.dynamics import DynamicLimits, frame_peaks


@pytest.fixture(scope="module")
def planner():
    pl = Planner(walled_target_scene(), PlannerConfig(grid_resolution=48))
    pl.prepare()
    return pl


STOPS = np.array([[0.5, -0.6, 0.5], [-0.5, -0.5, 0.6], [-0.5, 0.5, 0.4]])  # around the wall's end
LOOKS = np.array([TARGET, [-0.5, 0.0, 0.2], [0.0, 0.9, 0.3]])


def test_visits_every_stop_safely(planner):
    lim = DynamicLimits(max_speed=0.6, max_acceleration=0.6, max_angular_rate_deg=45)
    ms = plan_multistop(planner, STOPS, LOOKS, start=[0.7, 0.5, 0.5], limits=lim)
    sh = ms.shot
    # the requested stops are free: the curve's stops are the targets themselves
    assert np.allclose(ms.stops, STOPS, atol=1e-9)
    # exactly on the curve, and the frames pass within half a frame step of each stop
    assert np.allclose(sh.trajectory.evaluate(ms.stop_curve_times), ms.stops, atol=1e-9)
    step = ms.dynamics["peak_speed"] / lim.fps
    for p in ms.stops:
        assert np.min(np.linalg.norm(sh.positions - p, axis=1)) <= 0.5 * step + 1e-9
    assert np.all(np.diff(ms.stop_frame_times) > 0)
    # safety: the planner's dense verification and an independent exact check of every frame
    assert sh.safety["safe"]
    assert float(clearance(torch.as_tensor(sh.positions), planner.scene, planner.prepared.index).min()) >= 0
    # one continuous C2 curve: no stop at the interior stops (nonzero speed there)
    v = np.linalg.norm(sh.trajectory.derivative(ms.stop_curve_times[:-1], 1), axis=1)
    assert np.all(v > 1e-3)
    # look-at: the frames aim at the per-frame look-at points, which reach each stop's look-at at the stop
    view = -sh.rotations[:, :, 2]
    to = ms.look_at_points - sh.positions
    to /= np.linalg.norm(to, axis=1, keepdims=True)
    assert np.max(np.degrees(np.arccos(np.clip((view * to).sum(1), -1, 1)))) < 1e-4
    for t, la in zip(ms.stop_frame_times, ms.stop_look_ats):
        j = int(np.argmin(np.abs(sh.times - t)))
        assert np.linalg.norm(ms.look_at_points[j] - la) < 0.05
    pk = frame_peaks(sh.positions, sh.times, to)
    assert pk.speed <= 0.6 and pk.acceleration <= 0.6 and pk.angular_rate_deg <= 45
    assert ms.to_dict()["max_look_at_error_deg"] < 1e-4


def test_shared_look_at_single_stop_and_seeded_start(planner):
    a = plan_multistop(planner, STOPS[:1], TARGET, seed=4)
    b = plan_multistop(planner, STOPS[:1], TARGET, seed=4)
    assert np.allclose(a.shot.start, b.shot.start)
    assert np.allclose(a.shot.positions[-1], STOPS[0], atol=1e-9)
    assert np.max(a.shot.look_at_errors_deg()) < 1e-4
    # the random start keeps PlannerConfig.start_look_distance x the region's longest side from the (first) look-at
    g = planner.prepared.grid
    side = float(g.voxel_size * max(g.shape))
    for seed in range(4):
        s = plan_multistop(planner, STOPS[:2], LOOKS[:2], seed=seed).shot.start
        assert np.linalg.norm(s - LOOKS[0]) >= planner.config.start_look_distance * side - 1e-12


def test_bad_input(planner):
    with pytest.raises(InvalidInputError, match="at least one stop"):
        plan_multistop(planner, [], TARGET)
    with pytest.raises(InvalidInputError, match="one per stop"):
        plan_multistop(planner, STOPS, LOOKS[:2])
    with pytest.raises(InvalidInputError, match="stop 2"):
        plan_multistop(planner, [STOPS[0], [np.nan, 0, 0]], TARGET)
    with pytest.raises(StartInCollisionError):
        plan_multistop(planner, STOPS, TARGET, start=[0.0, 0.0, 0.5])  # inside the wall


@pytest.mark.parametrize("acc", [None, 0.8])
def test_default_limits_come_from_the_planners_timing(planner, monkeypatch, acc):
    """Without ``limits``: the planner's speed / fps / acceleration; with no acceleration cap in its timing, the
    frames' default cap (DynamicLimits' one definition, not a second literal)."""
    import dataclasses

    import cinenerf_ns.planner.shots.multistop as ms_mod

    seen = []

    class Stop(Exception):
        pass

    def spy(traj, look_of, limits, up=None):
        seen.append(limits)
        raise Stop

    monkeypatch.setattr(ms_mod, "retime", spy)
    monkeypatch.setattr(DynamicLimits, "max_acceleration", 0.37)  # the definition moves: the default follows
    timing = dataclasses.replace(planner.config.timing, max_acceleration=acc, max_speed=0.45)
    monkeypatch.setattr(planner, "config", dataclasses.replace(planner.config, timing=timing))
    with pytest.raises(Stop):
        plan_multistop(planner, STOPS[:1], LOOKS[0], start=[0.7, 0.5, 0.5])
    (lim,) = seen
    assert lim.max_speed == 0.45 and lim.fps == timing.fps
    assert lim.max_acceleration == (0.37 if acc is None else 0.8)
