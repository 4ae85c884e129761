"""Issue 24 parts 4-6 with the fakes: the screen shows what is planned, queries say what they matched, the status
speaks the user's words, exports never overwrite, the preview renders on a thread, views start inside the scene."""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from viewer_fakes import FakeBackend, FakeView, camera_looking, line_shot

from cinenerf_ns.viewer.panel import CinePanel, PanelConfig, Target, same_place_warning
from cinenerf_ns.viewer.shot_text import sort_by_score
from cinenerf_ns.viewer.views import TrainingCameras, highlight_box, opening_view, overview_view


def make(tmp_path, config_path="config.yml", previewer=None, **kw):
    backend, view = FakeBackend(), FakeView()
    cfg = PanelConfig(data_dir=kw.pop("data_dir", tmp_path), autoplay=False,
                      config_path=None if config_path is None else tmp_path / config_path, **kw)
    return CinePanel(backend, view, cfg, previewer=previewer), backend, view


# ------------------------------------------------------------------ part 4: a viewer that never lies
def test_plan_puts_the_texts_it_uses_on_screen_before_planning(tmp_path):
    panel, backend, view = make(tmp_path)
    res = panel.request_plan("the chair", "lamp").result(10)
    assert res is not None and view.inputs == [("the chair", "lamp")]
    kinds = [c[0] for c in view.calls]
    assert kinds.index("inputs") < kinds.index("status")  # on screen before "Planning..." and the planner call
    np.testing.assert_allclose(backend.plan_calls[0]["goal"], backend.means[:10].mean(0))  # planned with those texts
    panel.close()


def test_each_query_says_what_it_matched(tmp_path):
    panel, _, view = make(tmp_path)
    res = panel.request_plan("chair", "0 0 1").result(10)
    assert [t.count for t in res.targets] == [10, None]
    text = view.last_status[0]
    assert "go to 'chair' matched label 'chair' (10 Gaussians)" in text and "look at the point (0, 0, 1)" in text
    panel.close()


def test_a_query_that_selects_nothing_is_refused(tmp_path):
    panel, backend, view = make(tmp_path)
    assert panel.request_plan("ghost", "lamp").result(10) is None
    assert view.last_status == ("Plan failed: 'Go to': 'ghost' matches nothing in this scene (no Gaussian selected)",
                                "error")
    assert backend.plan_calls == []  # never planned with it
    assert panel.request_plan("unicorn", "lamp").result(10) is None and "'unicorn' matches nothing" in panel.status
    panel.close()


def test_go_to_equal_to_look_at_warns(tmp_path):
    panel, backend, view = make(tmp_path)
    orig = backend.plan

    def short_of_goal(goal, look_at, **k):  # a planner that stops beside the object it looks at
        return orig(np.asarray(goal) + [0.3, 0, 0], look_at, **k)

    backend.plan = short_of_goal
    res = panel.request_plan("chair", "the chair").result(10)
    assert res is not None and "same place" in res.warning, panel.status
    assert view.last_status[1] == "warn" and "Warning: 'Go to' and 'Look at' are the same place" in view.last_status[0]
    assert any(s[1] == "busy" and "same place" in s[0] for s in view.statuses)  # said while planning too
    backend.plan = orig  # a planner that fails on it (the fake's last frame looks at its own position): still said
    assert panel.request_plan("lamp", "lamp").result(10) is None
    assert view.last_status[1] == "error"
    assert "position. Warning: 'Go to' and 'Look at' are the same place" in view.last_status[0]
    assert panel.request_plan("chair", "lamp").result(10).warning == ""
    assert view.last_status[1] == "ok"
    a = Target("Go to", "0 0 1", np.array([0.0, 0, 1]))
    assert same_place_warning(a, Target("Look at", "0 0 1.0", np.array([0.0, 0, 1])))
    assert not same_place_warning(a, Target("Look at", "0 0 2", np.array([0.0, 0, 2])))
    panel.close()


def test_status_in_words_and_timings_in_details(tmp_path):
    panel, backend, view = make(tmp_path)
    orig = backend.plan

    def with_internals(*a, **k):
        shots = orig(*a, **k)
        shots[0].timings = {"batch_qp_ms": 12.0, "batch_score_ms": 3.0}
        return shots

    backend.plan = with_internals
    panel.request_plan("chair", "lamp", n_candidates=2).result(10)
    assert any(s == ("Planning: go to 'chair', look at 'lamp'...", "busy") for s in view.statuses)
    text = view.last_status[0]
    assert text.startswith("Planned 2 shots: ") and not any(w in text for w in ("batch_qp", "_ms", "query_s", "seed"))
    assert "batch_qp 12 ms" in view.details[-1] and "planning" in view.details[-1]
    panel.close()


def test_speed_error_clears_with_a_good_speed_and_plans_clear_old_outputs(tmp_path):
    panel, _, view = make(tmp_path)
    panel.request_plan("chair", "lamp").result(10)
    planned = view.last_status
    panel.set_speed(0.0)  # "0" on the way to typing 0.25
    assert view.last_status[1] == "error" and "Speed must be above 0" in view.last_status[0]
    panel.set_speed(0.25)
    assert view.last_status == planned and panel.config.speed == 0.25
    panel.export("take")
    assert view.exports[-1][0] is not None
    panel.request_plan("chair", "lamp").result(10)
    assert (None, "") in view.exports[-3:] and view.details[-1] != ""  # export box hidden by the new plan
    assert view.exports[-1] == (None, "") and view.previews[-1] is None
    panel.close()


def test_candidates_sorted_lower_score_first(tmp_path):
    shots = [line_shot([0, 0, 0], [1, 0, 0], [0, 1, 0]) for _ in range(5)]
    for s, score in zip(shots, (None, 3.0, 1.0, None, 2.0)):
        s.score = score
    assert [s.score for s in sort_by_score(shots)] == [1.0, 2.0, 3.0, None, None]
    assert sort_by_score(shots)[3] is shots[0]  # unscored keep their order


# ------------------------------------------------------------------ part 6: export you can trust
def test_exports_are_absolute_and_never_overwrite(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    panel, _, view = make(tmp_path, data_dir=Path("rel"))
    os.chdir("/")  # a later working directory must not move the exports
    panel.request_plan("chair", "lamp").result(10)
    a, b = panel.export("take"), panel.export("take")
    assert a.path == tmp_path / "rel" / "camera_paths" / "take.json" and a.path.is_absolute()
    assert b.path == a.path.with_name("take-2.json") and b.renamed_from == "take"
    assert "'take.json' already exists, so this one is 'take-2.json'" in view.last_status[0]
    assert json.loads(a.path.read_text())["camera_path"] and json.loads(b.path.read_text())["camera_path"]
    assert str(tmp_path / "config.yml") in b.command and str(b.path) in b.command
    panel.close()


def test_no_run_means_no_placeholder_command(tmp_path):
    panel, _, view = make(tmp_path, config_path=None, scene_note="'procedural:3000' is a generated test room")
    panel.request_plan("chair", "lamp").result(10)
    res = panel.export("take")
    assert res.command is None
    text = view.exports[-1][1]
    assert "No ns-render command: 'procedural:3000' is a generated test room" in text and "<path" not in text
    assert view.commands[-1] is None and text.count(f"{tmp_path.name}/camera_paths/take.json") == 1  # the file, once
    assert str(tmp_path) not in text  # no absolute server path
    panel.close()


def test_preview_renders_on_a_thread_and_offers_the_file(tmp_path):
    calls = []

    def previewer(camera_path, out_dir, name, w, h, fps):
        calls.append((camera_path, name, w, h, fps))
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / f"{name}.mp4").write_bytes(b"mp4")
        return out_dir / f"{name}.mp4"

    panel, _, view = make(tmp_path, previewer=previewer)
    assert panel.preview("take") is None and "nothing to preview" in view.last_status[0]
    panel.request_plan("chair", "lamp").result(10)
    th = panel.preview("take")
    th.join(10)
    busy = [t for t, level in view.statuses if level == "busy" and "Rendering a 480x270 preview of candidate 1" in t]
    assert th is not None and len(busy) == 1
    path = tmp_path / "previews" / "take.mp4"
    shown = f"{tmp_path.name}/previews/take.mp4"  # relative to the output folder's parent
    assert view.last_status == (f"Preview of candidate 1 written: {shown}. Download it below.", "ok")
    assert view.previews[-1] == path
    cam, name, w, h, fps = calls[0]
    assert (name, w, h, fps) == ("take", 480, 270, 15) and cam["fps"] == 15 and len(cam["camera_path"]) == 16
    panel.preview("take").join(10)  # a second preview gets its own file
    assert (tmp_path / "previews" / "take-2.mp4").exists()
    no_renderer, _, v2 = make(tmp_path / "x")
    no_renderer.request_plan("chair", "lamp").result(10)
    assert no_renderer.preview("take") is None and "no preview renderer" in v2.last_status[0]
    panel.close()
    no_renderer.close()


def test_preview_failure_is_a_readable_error(tmp_path):
    def broken(*a):
        raise ValueError("ffmpeg is missing")

    panel, _, view = make(tmp_path, previewer=broken)
    panel.request_plan("chair", "lamp").result(10)
    panel.preview("take").join(10)
    assert view.last_status == ("Preview failed: ffmpeg is missing", "error")
    panel.close()


# ------------------------------------------------------------------ part 5: a shot you can see
def room_means():
    rng = np.random.default_rng(0)  # a 4 x 3 x 2.5 room: floor, walls
    floor = np.c_[rng.uniform(0, 4, 500), rng.uniform(0, 3, 500), np.zeros(500)]
    wall = np.c_[np.zeros(300), rng.uniform(0, 3, 300), rng.uniform(0, 2.5, 300)]
    wall2 = np.c_[np.full(300, 4.0), rng.uniform(0, 3, 300), rng.uniform(0, 2.5, 300)]
    return np.r_[floor, wall, wall2]


def test_opening_view_is_inside_the_room():
    means = room_means()
    v = opening_view(means, (np.array([0.5, 0.5, 0.3]), np.array([3.5, 2.5, 2.0])))
    lo, hi = means.min(0), means.max(0)
    assert np.all(v.position > lo) and np.all(v.position < hi)  # inside, not outside the walls
    assert np.linalg.norm(v.look_at - v.position) > 0.1
    np.testing.assert_array_equal(v.up, [0, 0, 1])  # no training camera: the scene's up
    no_region = opening_view(means)
    assert np.all(no_region.position > lo) and np.all(no_region.position < hi)


def test_opening_view_is_the_typical_training_camera_s_pose():
    """With training-camera poses: the pose of the camera nearest the cameras' median position -- its position, its
    look direction (-z), its up (+y, roll included), the orbit point ahead of it near the splat's mass."""
    means = room_means()
    xs = [0.6, 1.2, 2.0, 2.8, 3.4]  # five cameras along the room; the middle one is the typical camera
    c2w = np.stack([camera_looking([x, 0.4, 1.2], [0.1 * (i - 2), 1.0, -0.2], roll_deg=10.0 * i)
                    for i, x in enumerate(xs)])
    cams = TrainingCameras.of(None, c2w)
    assert cams.typical() == 2
    np.testing.assert_array_equal(cams.centres, c2w[:, :, 3])
    v = opening_view(means, (np.array([0.5, 0.5, 0.3]), np.array([3.5, 2.5, 2.0])), cams)  # the region plays no part
    np.testing.assert_allclose(v.position, [2.0, 0.4, 1.2])
    d = (v.look_at - v.position) / np.linalg.norm(v.look_at - v.position)
    np.testing.assert_allclose(d, -c2w[2, :, 2], atol=1e-12)  # looking where that camera looked
    np.testing.assert_allclose(v.up, c2w[2, :, 1], atol=1e-12)  # with its up (20 deg of roll here)
    assert np.rad2deg(np.arccos(v.up @ [0, 0, 1])) > 15
    ahead = np.linalg.norm(v.look_at - v.position)  # the orbit point: nearest the median Gaussian along the view
    median = np.median(means, axis=0)
    np.testing.assert_allclose(ahead, (median - v.position) @ d)
    behind = opening_view(means, cameras=TrainingCameras.of(None, camera_looking([2.0, 2.9, 1.2], [0, 1, 0])[None]))
    assert np.linalg.norm(behind.look_at - behind.position) > 0  # the mass behind the camera: still a view ahead
    np.testing.assert_allclose((behind.look_at - behind.position) / np.linalg.norm(behind.look_at - behind.position),
                               [0, 1, 0], atol=1e-12)


def test_opening_view_from_camera_centres_only():
    """Centres without poses (compact exports made before the poses were stored): the typical camera's position,
    looking at the median Gaussian, up the scene's up; no cameras at all (a generated scene): the start region."""
    means = room_means()
    centres = np.array([[0.8, 0.5, 1.5], [1.5, 2.5, 1.4], [3.0, 1.0, 1.6]])
    cams = TrainingCameras.of(centres)
    assert cams.c2w is None
    v = opening_view(means, None, cams)
    np.testing.assert_allclose(v.position, centres[cams.typical()])
    np.testing.assert_allclose(v.look_at, np.median(means, axis=0))
    np.testing.assert_array_equal(v.up, [0, 0, 1])
    above = TrainingCameras.of(np.median(means, axis=0)[None] + [0.0, 0.0, 1.0])  # straight above the median
    a = opening_view(means, None, above)
    np.testing.assert_allclose(a.position, above.centres[0])  # still the camera's position, looking sideways
    assert abs((a.look_at - a.position)[2]) < 1e-12 and np.linalg.norm(a.look_at - a.position) > 0.5
    # nothing usable: no cameras (the opening view falls back to the start region)
    assert TrainingCameras.of(None) is None and TrainingCameras.of(np.zeros((0, 3))) is None
    assert TrainingCameras.of([[0.0, np.nan, 1.0]]) is None
    assert TrainingCameras.of(centres, np.full((1, 3, 4), np.nan)).c2w is None  # bad poses: the centres still count


def test_overview_sees_the_whole_floor_from_above():
    means = room_means()
    v = overview_view(means, fov_deg=50)
    assert v.position[2] > means[:, 2].max()
    d = v.look_at - v.position
    assert d[2] < 0 and abs(d[2]) > 10 * np.linalg.norm(d[:2])  # (nearly) straight down
    half_fov = np.arctan(1.5 / (v.position[2] - v.look_at[2]))  # the room's 4 m side fits, half = 2 m
    assert np.rad2deg(half_fov) < 25


def test_highlight_box_encloses_the_object_but_not_stray_points():
    rng = np.random.default_rng(1)
    obj = rng.uniform([1, 1, 0], [2, 1.5, 0.8], (400, 3))
    centre, size = highlight_box(np.r_[obj, [[9.0, 9.0, 9.0]]])
    np.testing.assert_allclose(centre, [1.5, 1.25, 0.4], atol=0.08)
    assert np.all(size < [1.3, 0.7, 1.0]) and np.all(size > [0.8, 0.4, 0.6])
    with pytest.raises(ValueError):
        highlight_box(np.zeros((0, 3)))


# ------------------------------------------------------------------ bounded work over every client
def test_panels_of_one_viewer_share_its_limits(tmp_path):
    """Two clients' panels over one ServerLimits: one plan at a time (the other says it waits), one preview render
    at a time however many quick clicks, texts and queues bounded, files capped."""
    import threading
    import time

    from cinenerf_ns.viewer.panel import ServerLimits
    from cinenerf_ns.viewer.safe_text import MAX_TEXT_CHARS

    limits = ServerLimits(max_files=3)
    backend = FakeBackend(plan_delay=0.5)
    started, release = threading.Event(), threading.Event()
    renders = []

    def previewer(camera_path, out_dir, name, w, h, fps):
        renders.append(name)
        started.set()
        release.wait(10)
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / f"{name}.mp4").write_bytes(b"mp4")
        return out_dir / f"{name}.mp4"

    views = [FakeView(), FakeView()]
    a, b = (CinePanel(backend, v, PanelConfig(data_dir=tmp_path, output_dir=tmp_path / "out", autoplay=False),
                      previewer=previewer, limits=limits) for v in views)
    fa, fb = a.request_plan("chair", "lamp"), b.request_plan("lamp", "chair")
    assert fa.result(20) is not None and fb.result(20) is not None
    waited = [v for v in views if any("Waiting for another user's Plan" in s for s, _ in v.statuses)]
    assert len(waited) == 1  # the second plan waited for the first: never two at once
    # one preview at a time over both clients, whatever the clicks
    threads = [p.preview("take") for p in (a, b, a, b, a)]
    assert started.wait(10) and sum(t is not None for t in threads) == 1
    assert sum("a preview is already rendering on this viewer" in v.last_status[0] for v in views) == 2
    release.set()
    next(t for t in threads if t is not None).join(10)
    assert renders == ["take"] and not limits._preview_lock.locked()
    # texts and queues bounded; the files budget: 1 preview + 2 exports, then a clear refusal
    assert a.request_plan("x" * (MAX_TEXT_CHARS + 1), "lamp").result(5) is None
    assert f"at most {MAX_TEXT_CHARS} are accepted" in views[0].last_status[0]
    assert a.export("e1") is not None and a.export("e1") is not None
    assert a.export("e1") is None and "limit for one run (3 files" in views[0].last_status[0]
    assert sorted(f.name for f in (tmp_path / "out" / "camera_paths").iterdir()) == ["e1-2.json", "e1.json"]
    backend.plan_delay = 1.0
    futures = [b.request_plan("chair", "lamp") for _ in range(limits.max_pending_plans + 2)]
    assert "Still working on" in views[1].last_status[0]
    assert [f.result(30) for f in futures][-1] is None  # refused at once
    t0 = time.monotonic()
    for p in (a, b):
        p.close()
    assert time.monotonic() - t0 < 10
