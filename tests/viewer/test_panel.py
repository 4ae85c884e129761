"""CinePanel logic with a fake view and a scripted backend: state transitions, threading
(cancel / supersede), bad input, atomic export."""
from __future__ import annotations

import json
import os
import time

import numpy as np
import pytest
from viewer_fakes import FakeBackend, FakeView

from cinenerf_ns.planner.errors import GoalUnreachableError, StartInCollisionError
from cinenerf_ns.viewer.panel import CinePanel, PanelBackend, PanelConfig


def make(tmp_path, **kw):
    backend = FakeBackend(**{k: kw.pop(k) for k in list(kw) if k in ("plan_delay", "n_shots", "duration")})
    view = FakeView(camera=kw.pop("camera", None))
    cfg = PanelConfig(data_dir=tmp_path, config_path=tmp_path / "config.yml", autoplay=kw.pop("autoplay", False), **kw)
    return CinePanel(backend, view, cfg), backend, view


def wait_for(pred, timeout=5.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.005)
    return False


def test_fake_backend_satisfies_protocol():
    assert isinstance(FakeBackend(), PanelBackend)


def test_plan_resolves_text_and_coordinates(tmp_path):
    panel, backend, view = make(tmp_path)
    res = panel.request_plan("the chair", "0.1 0.2, 0.3", n_candidates=2).result(10)
    assert res is not None and len(res.shots) == 2
    call = backend.plan_calls[-1]
    np.testing.assert_allclose(call["goal"], backend.means[:10].mean(0))
    np.testing.assert_allclose(call["look_at"], [0.1, 0.2, 0.3])
    assert call["start"] is None and call["n"] == 2 and call["seed"] == 0
    assert panel.state == CinePanel.READY and panel.selected == 0
    assert view.drawn_shot is res.shots[0]
    assert len(view.candidates) == 2 and view.candidates[0].startswith("1: 1.0 s")
    assert [t.role for t in view.targets] == ["Go to", "Look at"]
    assert view.targets[0].mask.sum() == 10 and view.targets[1].mask is None
    assert view.last_status[1] == "ok" and view.last_status[0].startswith("Planned 2 shots: ")
    assert "go to 'the chair' matched label 'chair' (10 Gaussians)" in view.last_status[0]
    assert "look at the point (0.1, 0.2, 0.3)" in view.last_status[0]
    assert set(panel.last_timings) == {"query_s", "plan_s", "draw_s", "total_s"}
    panel.close()


@pytest.mark.parametrize(
    "goto,look,needle",
    [
        ("", "lamp", "'Go to' is empty"),
        ("   ", "lamp", "'Go to' is empty"),
        ("chair", "", "'Look at' is empty"),
        ("the spaceship", "lamp", "matches nothing"),
        ("1 2", "lamp", "matches nothing"),  # two numbers are not a point: treated as a query
        ("nan 1 2", "lamp", "'Go to': the point 'nan 1 2' is not finite"),  # once a query for 'nan 1 2'
        ("chair", "[1, inf, 2]", "'Look at': the point '[1, inf, 2]' is not finite"),
    ],
)
def test_bad_text_gives_readable_status_and_no_plan(tmp_path, goto, look, needle):
    panel, backend, view = make(tmp_path)
    assert panel.request_plan(goto, look).result(10) is None
    text, level = view.last_status
    assert level == "error" and needle in text, text
    assert backend.plan_calls == [] and panel.state == CinePanel.IDLE and panel.shot is None
    panel.close()


@pytest.mark.parametrize(
    "err,needle",
    [
        (GoalUnreachableError("no collision-free path to the goal"), "no collision-free path"),
        (StartInCollisionError("the start is inside the scene"), "start is inside"),
        (RuntimeError("CUDA out of memory"), "internal error (RuntimeError: CUDA out of memory)"),
        (ZeroDivisionError("boom"), "ZeroDivisionError"),
    ],
)
def test_planner_errors_keep_previous_shot_and_panel_alive(tmp_path, err, needle):
    panel, backend, view = make(tmp_path)
    first = panel.request_plan("chair", "lamp").result(10)
    backend.fail = err
    assert panel.request_plan("chair", "lamp").result(10) is None
    text, level = view.last_status
    assert level == "error" and needle in text and text.startswith("Plan failed")
    assert panel.state == CinePanel.READY and panel.shot is first.shots[0]  # nothing lost
    backend.fail = None
    assert panel.request_plan("lamp", "chair").result(10) is not None  # still works afterwards
    panel.close()


def test_empty_and_malformed_planner_output(tmp_path):
    panel, backend, view = make(tmp_path, n_shots=0)
    assert panel.request_plan("chair", "lamp").result(10) is None
    assert "no collision-free shot" in view.last_status[0]
    backend.n_shots = None
    orig = backend.plan

    def bad(*a, **k):
        shots = orig(*a, **k)
        shots[0].positions = shots[0].positions.copy()
        shots[0].positions[3] = np.nan
        return shots

    backend.plan = bad
    assert panel.request_plan("chair", "lamp").result(10) is None
    assert "NaN" in view.last_status[0] and view.last_status[1] == "error"
    backend.plan = lambda *a, **k: [type("Duck", (), {"times": [0, 1], "positions": [[0] * 3] * 2})()]
    assert panel.request_plan("chair", "lamp").result(10) is None  # a look-alike is refused
    assert "malformed candidate 1: a Duck, not a cinenerf_ns.planner Shot" in view.last_status[0]
    panel.close()


def test_start_from_camera(tmp_path):
    panel, backend, view = make(tmp_path)
    assert panel.request_plan("chair", "lamp", start_from_camera=True).result(10) is None
    assert "needs a connected browser" in view.last_status[0]
    view.camera = np.array([0.5, 0.5, 0.5])
    assert panel.request_plan("chair", "lamp", start_from_camera=True).result(10) is not None
    np.testing.assert_allclose(backend.plan_calls[-1]["start"], [0.5, 0.5, 0.5])
    panel.close()


def test_new_random_start_bumps_seed_and_reuses_text(tmp_path):
    panel, backend, view = make(tmp_path)
    panel.request_plan("chair", "lamp").result(10)
    panel.new_random_start(n_candidates=4).result(10)
    panel.new_random_start().result(10)
    assert [c["seed"] for c in backend.plan_calls] == [0, 1, 2]
    assert [c["n"] for c in backend.plan_calls] == [3, 4, 3]
    np.testing.assert_allclose(backend.plan_calls[-1]["goal"], backend.means[:10].mean(0))
    panel.close()


def test_select_candidate(tmp_path):
    panel, backend, view = make(tmp_path)
    res = panel.request_plan("chair", "lamp", n_candidates=3).result(10)
    panel.select(2)
    assert panel.selected == 2 and view.drawn_shot is res.shots[2]
    assert "Candidate 3" in view.last_status[0]
    panel.select(5)
    assert panel.selected == 2 and view.last_status[1] == "error"
    panel.close()


def test_display_toggles_redraw(tmp_path):
    panel, backend, view = make(tmp_path)
    panel.request_plan("chair", "lamp").result(10)
    n = len(view.calls)
    panel.set_display(show_corridor=True, show_clearance=True, show_path=False)
    new = [c for c in view.calls[n:] if c[0] in ("draw_shot", "draw_targets")]
    assert len(new) == 2 and new[0][2].show_corridor and not new[0][2].show_path
    with pytest.raises(AttributeError):
        panel.set_display(show_everything=True)
    panel.close()


def test_animation_plays_at_real_speed_and_ends_at_goal(tmp_path):
    panel, backend, view = make(tmp_path, duration=0.4, autoplay=True, update_hz=100)
    res = panel.request_plan("chair", "lamp").result(10)
    assert wait_for(lambda: panel.state == CinePanel.READY and len(view.cameras) > 0, 5)
    shot = res.shots[0]
    t0, c0 = view.cameras[0]
    t1, c1 = view.cameras[-1]
    np.testing.assert_allclose(c0[:, 3], shot.positions[0], atol=0.05)  # starts at the start
    np.testing.assert_allclose(c1[:, 3], shot.positions[-1], atol=1e-9)  # ends exactly at the end
    np.testing.assert_allclose(c1[:, :3], shot.rotations[-1], atol=1e-9)
    # real speed: wall time of the flight ~ the shot's duration (generous bounds: shared CPU)
    assert 0.35 <= t1 - t0 <= 2.0
    assert view.playing[0] is True and view.playing[-1] is False
    panel.close()


def test_pause_resume_and_seek(tmp_path):
    panel, backend, view = make(tmp_path, duration=5.0)
    panel.request_plan("chair", "lamp").result(10)
    panel.play()
    assert wait_for(lambda: len(view.cameras) >= 3)
    panel.pause()
    assert panel.state == CinePanel.PAUSED
    n, t_paused = len(view.cameras), panel.playback_time
    time.sleep(0.1)
    assert len(view.cameras) == n and panel.playback_time == t_paused  # really stopped
    panel.play()
    assert wait_for(lambda: len(view.cameras) > n + 2)
    assert panel.playback_time >= t_paused  # resumed, not restarted
    panel.pause()
    panel.seek(4.0)
    assert panel.playback_time == 4.0
    np.testing.assert_allclose(view.cameras[-1][1][:, 3], panel.shot.positions[24], atol=1e-9)  # t=4 of 5 s, 31 samples
    panel.seek(99)
    assert panel.playback_time == 5.0
    panel.close()


def test_loop_keeps_playing(tmp_path):
    panel, backend, view = make(tmp_path, duration=0.15, loop=True, update_hz=100)
    panel.request_plan("chair", "lamp").result(10)
    panel.play()
    time.sleep(0.5)
    assert panel.state == CinePanel.PLAYING
    panel.pause()
    panel.close()


def test_new_plan_cancels_running_animation(tmp_path):
    panel, backend, view = make(tmp_path, duration=10.0, plan_delay=0.2)
    panel.request_plan("chair", "lamp").result(10)
    panel.play()
    assert wait_for(lambda: len(view.cameras) >= 2)
    anim = panel._anim_thread
    assert anim is not None and anim.is_alive()
    fut = panel.request_plan("lamp", "chair")
    # the animation is stopped (joined) before request_plan returns
    assert panel.state == CinePanel.PLANNING
    n = len(view.cameras)
    time.sleep(0.1)
    assert len(view.cameras) == n
    assert fut.result(10) is not None and panel.state == CinePanel.READY
    # this panel's animation thread is gone (other tests' panels may still own theirs)
    assert not anim.is_alive() and panel._anim_thread is None
    panel.close()


def test_superseded_plans_are_skipped_or_dropped(tmp_path):
    panel, backend, view = make(tmp_path, plan_delay=0.3, autoplay=True)
    f1 = panel.request_plan("chair", "lamp")
    assert backend.started.wait(5)  # f1 is running in the planner
    f2 = panel.request_plan("chair", "lamp", n_candidates=1)  # queued, superseded by f3 before it starts
    f3 = panel.request_plan("lamp", "chair", n_candidates=2)
    assert f1.result(10) is None  # finished after f2/f3 were requested: dropped
    assert f2.result(10) is None  # never ran
    r3 = f3.result(10)
    assert r3 is not None and len(panel.shots) == 2 and panel.shot is r3.shots[0]
    assert len(backend.plan_calls) == 2
    assert panel.wait_idle(5)
    panel.close()


def test_export_atomic_and_command(tmp_path):
    panel, backend, view = make(tmp_path, fps=10)
    assert panel.export("take1") is None and "nothing to export" in view.last_status[0]
    panel.request_plan("chair", "lamp").result(10)
    res = panel.export("take1")
    assert res is not None
    assert res.path == tmp_path / "camera_paths" / "take1.json"
    data = json.loads(res.path.read_text())
    # ns-render plays len(camera_path) / seconds frames per second: 11 frames at 10 fps -> 1.1 s
    assert len(data["camera_path"]) == 11 and data["fps"] == 10 and data["seconds"] == pytest.approx(1.1)
    c2w = np.array(data["camera_path"][0]["camera_to_world"]).reshape(4, 4)
    np.testing.assert_allclose(c2w[:3, 3], panel.shot.positions[0], atol=1e-9)
    np.testing.assert_allclose(c2w[:3, :3], panel.shot.rotations[0], atol=1e-9)
    assert res.command == (
        f"ns-render camera-path --load-config {tmp_path / 'config.yml'} --camera-path-filename "
        f"{res.path.absolute()} --output-path renders/{tmp_path.name}/take1.mp4"
    )
    shown_path, text = view.exports[-1]
    command = view.commands[-1]
    shown = f"{tmp_path.name}/camera_paths/take1.json"  # relative to the output folder's parent, never absolute
    assert shown_path == res.path and f"Camera path: {shown}." in text and f"--camera-path-filename {shown}" in command
    assert str(tmp_path) not in text + command and "Exported candidate 1" in view.last_status[0]
    assert "--load-config config.yml" in command or "--load-config " + (tmp_path / "config.yml").name in command
    assert sorted(os.listdir(res.path.parent)) == ["take1.json"]  # no temp files left
    panel.close()


def test_export_failure_leaves_no_partial_file(tmp_path):
    panel, backend, view = make(tmp_path)
    panel.request_plan("chair", "lamp").result(10)
    good = panel.export("take")
    before = good.path.read_bytes()

    panel.exporter = lambda *a: {"camera_path": [{"fov": float("nan")}]}  # NaN is not JSON
    assert panel.export("take") is None and view.last_status[1] == "error"
    assert good.path.read_bytes() == before  # old file untouched

    panel.exporter = lambda *a: {"x": object()}
    assert panel.export("take2") is None
    assert sorted(os.listdir(good.path.parent)) == ["take.json"]

    for bad in ["", "../evil", "a/b", "..", "name with spaces"]:
        assert panel.export(bad) is None and "not a plain file name" in view.last_status[0]
    panel.close()


def test_close_stops_everything(tmp_path):
    panel, backend, view = make(tmp_path, duration=10.0)
    panel.request_plan("chair", "lamp").result(10)
    panel.play()
    assert wait_for(lambda: len(view.cameras) >= 2)
    panel.close()
    n = len(view.cameras)
    time.sleep(0.1)
    assert len(view.cameras) == n
    assert panel.request_plan("chair", "lamp").result(1) is None


def test_candidate_labels_show_duration_clearance_and_optional_score(tmp_path):
    from cinenerf_ns.viewer.panel import candidate_label, min_clearance, timings_detail

    panel, backend, view = make(tmp_path)
    orig = backend.plan

    def ranked(*a, **k):
        shots = orig(*a, **k)
        shots[1].score = 0.25  # a ranked planner (planner/shots/candidates.py) sets .score; the others do not
        shots[2].clearance = None  # only the planner's dense verification
        shots[2].safety = {"min_exact_clearance": 0.0123, "safe": True}
        return shots

    backend.plan = ranked
    res = panel.request_plan("chair", "lamp", n_candidates=3).result(10)
    assert res is not None
    # scored candidates first, best (lowest score) first: the planner's unscored ones keep their order after them
    assert view.candidates == ["1: 1.0 s, clearance 1.05, score 0.25", "2: 1.0 s, clearance 0.05",
                               "3: 1.0 s, clearance 0.0123"]
    res.shots[2].safety = {"min_exact_clearance": None, "safe": True}  # every sample proven free: no number
    assert min_clearance(res.shots[2]) is None and candidate_label(2, res.shots[2]).endswith("clearance n/a")
    panel.select(0)
    assert "score 0.25" in view.last_status[0] and "lower score is better" in view.last_status[0]
    assert timings_detail({"astar_ms": 12.34, "fit_s": 0.5, "n": 3, "note": "x"}) == "astar 12 ms, fit 0.50 s, n 3"
    panel.close()


def test_framing_reaches_a_backend_that_plans_end_poses_and_bad_framing_is_refused(tmp_path):
    panel, backend, view = make(tmp_path)
    calls = []
    plain = backend.plan

    def plan(goal, look_at, start=None, seed=0, n_candidates=1, targets=None, framing="medium"):
        calls.append((targets, framing))
        return plain(goal, look_at, start=start, seed=seed, n_candidates=n_candidates)

    backend.plan, backend.plans_end_poses = plan, True
    assert panel.request_plan("the chair", "lamp", framing="close").result(10) is not None
    targets, framing = calls[-1]
    assert framing == "close" and [t.text for t in targets] == ["the chair", "lamp"]
    assert targets[0].mask is not None and targets[0].mask.sum() == 10  # the query's Gaussians go with it
    assert panel.request_plan("the chair", "lamp", framing="<b>huge</b>").result(10) is None
    text, level = view.last_status
    assert level == "error" and "'Framing' must be one of wide, medium, close" in text
    assert len(calls) == 1
    panel.close()
