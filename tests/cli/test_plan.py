"""cinesplat-plan: outputs exist and are valid, text and point targets, specific errors."""
import dataclasses
import json

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from cinenerf_ns.cli.plan_args import PlanArgs
from cinenerf_ns.cli.plan_run import run_plan
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.ply import write_splat_ply
from cinenerf_ns.planner.scene.procedural import procedural_room
from cinenerf_ns.planner.shots.planner import PlannerConfig
from cinenerf_ns.scenes import _word_match, word_matches


def grid(resolution: int, **planner) -> PlannerConfig:
    """--grid-resolution (and other --planner.* settings) as PlanArgs takes them."""
    return PlannerConfig(grid_resolution=resolution, **planner)


def test_word_match():
    """Whole words, singular or plural; a part of a word is no match (issue 38: 'hair' planned to the red armchair,
    'ant' to the potted plant)."""
    names = ["red armchair", "floor lamp", "table", "potted plant", "blue vase", "bookshelf", "glass box",
             "floor lamp stand", "thing 1", "thing 12"]
    assert _word_match("go to the armchair", names) == 0
    assert _word_match("lamp", names) == 1  # ties: the fewest words ('floor lamp stand' holds it too)
    assert word_matches("lamp", names) == [1, 7]
    assert _word_match("piano", names) is None
    for fragment in ("hair", "ant", "chair", "arm", "shelf", "lam", "oor", "bo"):
        assert word_matches(fragment, names) == [], fragment
    for plural, i in [("lamps", 1), ("Floor Lamps", 1), ("plants", 3), ("vases", 4), ("bookshelves", 5),
                      ("boxes", 6), ("glasses", 6), ("tables", 2)]:
        assert _word_match(plural, names) == i, plural
    assert _word_match("thing 1", names) == 8 and _word_match("thing 12", names) == 9
    assert word_matches("the red elephant", names) == [] and word_matches("the", names) == []


@settings(max_examples=60, deadline=None)
@given(name=st.lists(st.text("abcdefghijklmnopqrstuvwxyz", min_size=1, max_size=8), min_size=1, max_size=4),
       pick=st.lists(st.integers(0, 3), min_size=1, max_size=4), upper=st.booleans())
def test_a_name_matches_any_of_its_words_and_no_cut_word(name, pick, upper):
    """Property: a query of some of a name's words (any order, any case, stop words added) matches it; a query of one
    word cut short (a strict prefix or suffix that is none of its words' forms) does not."""
    from cinenerf_ns.scenes import _STOP_WORDS, _forms

    full = " ".join(name)
    words = [name[i % len(name)] for i in pick]
    q = "go to the " + " ".join(w.upper() if upper else w for w in reversed(words))
    if not set(words) <= _STOP_WORDS:
        assert word_matches(q, [full]) == [0]
    for w in name:
        for cut in (w[1:], w[:-1]):
            if cut and cut not in _STOP_WORDS and not any(_forms(cut) & _forms(v) for v in name):
                assert word_matches(cut, [full]) == []


def test_procedural_text_plan(tmp_path):
    from nerfstudio.cameras.camera_paths import get_path_from_json

    s = run_plan(PlanArgs(scene="procedural:3000:1", go_to="the armchair", look_at="floor lamp", candidates=2,
                          output_dir=tmp_path, planner=grid(64)))
    assert len(s["candidates"]) == 2
    for c in s["candidates"]:
        d = json.loads(open(c["camera_path"]).read())
        cams = get_path_from_json(d)
        assert cams.camera_to_worlds.shape[0] == len(d["camera_path"])
        assert c["exact_clearance"]["min_clearance"] >= 0
    for p in s["plots"].values():
        assert open(p, "rb").read(8) == b"\x89PNG\r\n\x1a\n"
    rep = json.loads(open(s["report"]).read())
    assert "-> object 'armchair'" in rep["go_to"]["resolved"]  # the text and the object it picked


def test_ply_points_and_errors(tmp_path):
    room = procedural_room(3000, seed=2)
    ply = tmp_path / "scene.ply"
    write_splat_ply(ply, room.means, room.quats, room.log_scales, room.opacity_logits)
    g = room.objects[0].center
    lk = room.objects[1].center
    s = run_plan(PlanArgs(scene=str(ply), go_to=" ".join(map(str, g)), look_at=" ".join(map(str, lk)),
                          output_dir=tmp_path / "o", planner=grid(64), start="0 0 0.7"))
    assert np.allclose(s["candidates"][0]["start"], [0, 0, 0.7])
    with pytest.raises(InvalidInputError, match="no semantics"):
        run_plan(PlanArgs(scene=str(ply), go_to="armchair", look_at="0 0 0", output_dir=tmp_path / "x"))
    with pytest.raises(InvalidInputError, match="empty"):
        run_plan(PlanArgs(scene=str(ply), go_to="  ", look_at="0 0 0", output_dir=tmp_path / "x"))
    with pytest.raises(InvalidInputError, match="not found"):
        run_plan(PlanArgs(scene=str(tmp_path / "nope.ply"), go_to="0 0 0", look_at="0 0 0", output_dir=tmp_path / "x"))
    assert not (tmp_path / "x").exists()  # nothing half-written on bad input


def test_ranked_candidates_with_limits_in_table_and_report(tmp_path):
    from rich.console import Console

    con = Console(record=True, width=250)
    s = run_plan(PlanArgs(scene="procedural:3000:1", go_to="the armchair", look_at="floor lamp", candidates=3,
                          output_dir=tmp_path, planner=grid(64), max_angular_rate=40.0, max_acceleration=0.4),
                 console=con)
    cands = s["candidates"]
    assert [c["rank"] for c in cands] == [1, 2, 3]
    totals = [c["score"]["total"] for c in cands]
    assert totals == sorted(totals)
    for c in cands:
        assert {"occluded_fraction", "framing_size_error", "min_clearance", "mean_jerk",
                "duration_s"} <= set(c["score"]["terms"])
        assert c["dynamics"]["peak_angular_rate_deg"] <= 40.0 and c["dynamics"]["peak_acceleration"] <= 0.4
        assert c["exact_clearance"]["min_clearance"] >= 0
    rep = json.loads(open(s["report"]).read())
    assert rep["candidates"][0]["score"]["costs"]["occlusion"] >= 0
    assert rep["object_radius"] > 0.1  # the procedural lamp's half diagonal
    text = con.export_text()
    assert "rank" in text and "visible" in text


def test_multi_stop(tmp_path):
    room = procedural_room(3000, seed=1)
    s = run_plan(PlanArgs(scene="procedural:3000:1", go_to="armchair", then_go_to=("table",), look_at="floor lamp",
                          then_look_at=("vase",), output_dir=tmp_path, planner=grid(64), start="0 0 0.8"))
    c = s["candidates"][0]
    assert len(c["stops"]) == 2 and c["verification"]["safe"]
    assert np.allclose(c["stop_look_ats"][1], room.object("vase").center)
    assert c["max_look_at_error_deg"] < 1e-3
    with pytest.raises(InvalidInputError, match="then-look-at"):
        run_plan(PlanArgs(scene="procedural:3000:1", go_to="armchair", then_go_to=("table", "sofa"), look_at="vase",
                          then_look_at=("vase",), output_dir=tmp_path / "x", planner=grid(64)))


def test_workers_option(tmp_path):
    """--workers 2 plans the same ranked candidates as in-process; a negative count is a clear error."""
    kw = dict(scene="procedural:3000:1", go_to="the armchair", look_at="floor lamp", candidates=3, planner=grid(64))
    a = run_plan(PlanArgs(output_dir=tmp_path / "a", workers=0, **kw))
    b = run_plan(PlanArgs(output_dir=tmp_path / "b", workers=2, **kw))
    assert [c["start"] for c in a["candidates"]] == [c["start"] for c in b["candidates"]]
    totals = lambda r: [c["score"]["total"] for c in r["candidates"]]
    assert totals(a) == pytest.approx(totals(b))
    with pytest.raises(InvalidInputError, match="--workers"):
        run_plan(PlanArgs(output_dir=tmp_path / "c", workers=-1, **kw))


class _StopAtLoad(Exception):
    pass


def _load_scene_kwargs(monkeypatch, key: str, **plan_kw) -> list:
    """run_plan(PlanArgs(**plan_kw)) up to its load_scene call, which is stubbed: returns [the kwarg `key` it got]
    (empty when run_plan stopped before loading). Other exceptions propagate."""
    import cinenerf_ns.cli.plan_run as plan_mod

    seen = []

    def fake_load_scene(*a, **kw):
        seen.append(kw.get(key))
        raise _StopAtLoad

    monkeypatch.setattr(plan_mod, "load_scene", fake_load_scene)
    kw = dict(scene="procedural:3000:1", go_to="the armchair", look_at="floor lamp", **plan_kw)
    try:
        run_plan(PlanArgs(**kw))
    except _StopAtLoad:
        pass
    return seen


def test_keep_support_reaches_the_locator(monkeypatch, tmp_path):
    """--keep-support turns the support-layer rule off in the scene's text locator (default: on)."""
    seen = [_load_scene_kwargs(monkeypatch, "drop_support", output_dir=tmp_path, keep_support=keep)
            for keep in (False, True)]
    assert seen == [[True], [False]]


@pytest.mark.slow
def test_load_scene_passes_drop_support():
    from cinenerf_ns.planner.scene.scene_config import SceneConfig
    from cinenerf_ns.scenes import DEMO_SCENE, load_scene

    for flag in (True, False):
        sem = load_scene(str(DEMO_SCENE), SceneConfig(), smooth_neighbors=0, drop_support=flag).semantics.semantic
        assert sem.drop_support is flag


def test_centre_relevancy_reaches_the_locator(monkeypatch, tmp_path):
    """--centre-relevancy is passed to load_scene (default CENTRE_RELEVANCY); a bad value is a clear error raised
    before anything is loaded or written."""
    from cinenerf_ns.semantic_defaults import CENTRE_RELEVANCY

    assert _load_scene_kwargs(monkeypatch, "centre_relevancy", output_dir=tmp_path / "a") == [CENTRE_RELEVANCY]
    assert _load_scene_kwargs(monkeypatch, "centre_relevancy", output_dir=tmp_path / "b", centre_relevancy=0.8) == [0.8]
    for k, bad in enumerate([1.0, -0.2, float("nan")]):
        with pytest.raises(InvalidInputError, match="--centre-relevancy"):
            _load_scene_kwargs(monkeypatch, "centre_relevancy", output_dir=tmp_path / f"bad{k}", centre_relevancy=bad)
        assert not (tmp_path / f"bad{k}").exists()


@pytest.mark.slow
def test_load_scene_passes_centre_relevancy():
    """load_scene hands centre_relevancy to the bundled scene's SemanticScene, and the locator's description says how
    many Gaussians the centre came from."""
    import torch

    from cinenerf_ns.planner.scene.scene_config import SceneConfig
    from cinenerf_ns.scenes import DEMO_SCENE, label_query, load_scene

    for v in (0.0, 0.7):
        ld = load_scene(str(DEMO_SCENE), SceneConfig(), smooth_neighbors=0, centre_relevancy=v)
        sem = ld.semantics.semantic
        assert sem.centre_relevancy == v
        point, desc = ld.locate("armchair")
        r = sem.locate_full(label_query("armchair", ld.semantics.label_names))
        np.testing.assert_allclose(point, r.centroid.double().numpy())
        assert ("centre from the" in desc) == (int(r.core.sum()) < int(r.mask.sum()))
        assert (v == 0.0) == torch.equal(r.core, r.mask)


def test_no_unseen_fill_reaches_the_locator(monkeypatch, tmp_path):
    """--no-unseen-fill turns the volume centre's camera fill off (default: on)."""
    seen = [_load_scene_kwargs(monkeypatch, "unseen_fill", output_dir=tmp_path / str(f), unseen_fill=not f)
            for f in (False, True)]
    assert seen == [[True], [False]]


@pytest.mark.slow
def test_load_scene_gives_the_bundled_scene_its_training_cameras():
    """The bundled export carries its 150 training cameras (info["camera_centres"]): load_scene hands them to the
    SemanticScene (unless unseen_fill=False) and draws random starts from their box (+0.1)."""
    from cinenerf_ns.planner.scene.scene_config import SceneConfig
    from cinenerf_ns.scenes import DEMO_SCENE, load_scene

    ld = load_scene(str(DEMO_SCENE), SceneConfig(), smooth_neighbors=0)
    cams = ld.semantics.semantic.camera_centres
    assert cams is not None and cams.shape == (150, 3)
    np.testing.assert_allclose(ld.start_region[0], cams.min(0) - 0.1)
    np.testing.assert_allclose(ld.start_region[1], cams.max(0) + 0.1)
    off = load_scene(str(DEMO_SCENE), SceneConfig(), smooth_neighbors=0, unseen_fill=False)
    assert off.semantics.semantic.camera_centres is None
    np.testing.assert_allclose(off.start_region[0], ld.start_region[0])  # the start region does not depend on it


def test_start_look_distance_option(tmp_path):
    """--planner.start-look-distance reaches the planner: 0 gives the uniform starts, a bad fraction a clear error."""
    kw = dict(scene="procedural:3000:1", go_to="the armchair", look_at="floor lamp", candidates=3, workers=0)
    a = run_plan(PlanArgs(output_dir=tmp_path / "a", planner=grid(64), **kw))
    b = run_plan(PlanArgs(output_dir=tmp_path / "b", planner=grid(64, start_look_distance=0.0), **kw))
    assert [c["start"] for c in a["candidates"]] != [c["start"] for c in b["candidates"]]
    with pytest.raises(InvalidInputError, match="--planner.start-look-distance"):
        run_plan(PlanArgs(output_dir=tmp_path / "c", planner=grid(64, start_look_distance=1.0), **kw))
    assert not (tmp_path / "c").exists()


@pytest.mark.parametrize("shared_data", [True, False])
def test_training_cameras_read_ns_train_configs(tmp_path, shared_data):
    """The start region of a run comes from the config.yml nerfstudio writes. `ns-train --data X` sets the
    datamanager's data to the same Path, so yaml.dump writes it once with an anchor ("data: &id001 !!python/...")
    and refers to it later: both forms must give the cameras' box (this was silently None for every ns-train run)."""
    import copy

    import yaml

    from cinenerf_ns.method.cinesplat_config import cinesplat
    from cinenerf_ns.method.training_cameras import camera_box, camera_centres, training_camera_centres

    data = tmp_path / "my data" / "room"
    data.mkdir(parents=True)
    rng = np.random.default_rng(0)
    frames = []
    for c in rng.uniform(-2, 2, size=(7, 3)):
        m = np.eye(4)
        m[:3, 3] = c
        frames.append({"file_path": "images/x.png", "transform_matrix": m.tolist()})
    (data / "transforms.json").write_text(json.dumps({"frames": frames}))
    run = tmp_path / "outputs" / "room" / "cinesplat" / "run"
    run.mkdir(parents=True)
    dp = {"transform": [[0, -1, 0, 0.3], [1, 0, 0, -0.2], [0, 0, 1, 0.1]], "scale": 0.4}
    (run / "dataparser_transforms.json").write_text(json.dumps(dp))
    cfg = copy.deepcopy(cinesplat.config)
    cfg.data = data
    if shared_data:  # what nerfstudio's train.py does with --data
        cfg.pipeline.datamanager.data = cfg.data
    text = yaml.dump(cfg)
    assert ("data: &id" in text) == shared_data  # the premise: the anchor form is what ns-train writes
    (run / "config.yml").write_text(text)
    c = training_camera_centres(run / "config.yml")
    assert c is not None
    got = camera_box(c)
    want = camera_box(camera_centres(data / "transforms.json", run / "dataparser_transforms.json"))
    np.testing.assert_allclose(got[0], want[0])
    np.testing.assert_allclose(got[1], want[1])
    # the box is the cameras' box in the run's normalised frame, grown by the pad
    T = np.asarray(dp["transform"], dtype=float)
    cams = np.array([f["transform_matrix"] for f in frames])[:, :3, 3]
    norm = (cams @ T[:, :3].T + T[:, 3]) * dp["scale"]
    np.testing.assert_allclose(got[0], norm.min(0) - 0.1)
    np.testing.assert_allclose(got[1], norm.max(0) + 0.1)
    (data / "transforms.json").unlink()  # data gone: no region, no crash
    assert training_camera_centres(run / "config.yml") is None


def test_rerun_with_fewer_candidates_leaves_no_stale_shot(tmp_path):
    """A second run into the same folder with fewer candidates removes the first run's extra camera paths; files
    are 0644; the report names exactly the camera paths that exist."""
    import os
    import stat

    kw = dict(scene="procedural:3000:1", go_to="the armchair", look_at="floor lamp", planner=grid(48), workers=0,
              output_dir=tmp_path)
    run_plan(PlanArgs(candidates=3, **kw))
    assert sorted(p.name for p in tmp_path.glob("shot_?.json")) == ["shot_0.json", "shot_1.json", "shot_2.json"]
    s = run_plan(PlanArgs(candidates=1, **kw))
    assert sorted(p.name for p in tmp_path.glob("shot_?.json")) == ["shot_0.json"]
    assert [c["camera_path"] for c in s["candidates"]] == [str(tmp_path.absolute() / "shot_0.json")]
    assert all(stat.S_IMODE(os.stat(p).st_mode) == 0o644 for p in tmp_path.iterdir())
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging folder left


def test_interrupted_run_writes_nothing(tmp_path, monkeypatch, capsys):
    """Ctrl-C while the plots are drawn: exit 130, a message on stderr, no file in the output folder."""
    import cinenerf_ns.cli.plan as plan_mod
    import cinenerf_ns.cli.plan_run as plan_run

    def interrupt(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(plan_run, "plot_paths_topdown", interrupt)
    out = tmp_path / "out"
    code = plan_mod.main(["--scene", "procedural:3000:1", "--go-to", "armchair", "--look-at", "floor lamp",
                          "--grid-resolution", "48", "--candidates", "2", "--workers", "0", "--output-dir", str(out)])
    assert code == 130 and "interrupted" in capsys.readouterr().err
    assert not out.exists() or not list(out.iterdir())


def test_moved_goal_is_reported(tmp_path, capsys):
    """A go-to inside the room's wall band but outside the planning region ends inside it; the report and the
    summary say from where to where and why."""
    s = run_plan(PlanArgs(scene="procedural:3000:1", go_to="1.9 0 0.5", look_at="floor lamp", planner=grid(48),
                          workers=0, output_dir=tmp_path))
    mv = s["candidates"][0]["goal_moved"]
    assert mv is not None and mv["distance"] > 0.1 and "outside the planning region" in mv["why"]
    assert "the go-to point moved" in " ".join(capsys.readouterr().out.split())
    rep = json.loads(open(s["report"]).read())
    assert rep["candidates"][0]["goal_moved"]["why"] == mv["why"]


def test_preview_videos_per_candidate(tmp_path):
    """--preview writes one mp4 + contact sheet per candidate beside the camera paths; the report names them."""
    s = run_plan(PlanArgs(scene="procedural:3000:1", go_to="the armchair", look_at="floor lamp", planner=grid(48),
                          workers=0, candidates=2, preview=True, preview_size=(64, 36), preview_fps=5,
                          output_dir=tmp_path))
    for k in range(2):
        mp4 = tmp_path / f"shot_{k}_preview.mp4"
        assert s["plots"][f"preview_{k}"] == str(mp4.absolute())
        assert mp4.read_bytes()[4:8] == b"ftyp"
        assert (tmp_path / f"shot_{k}_preview_sheet.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_end_pose_and_framing_in_report_and_table(tmp_path, capsys):
    """An object go-to ends at a chosen end pose (reported with why), the look-at object's view per candidate;
    --no-end-pose keeps the go-to centre rule; the same object twice is a good view of it."""
    kw = dict(scene="procedural:20000:0", look_at="floor lamp", planner=grid(64))
    s = run_plan(PlanArgs(go_to="the armchair", candidates=3, framing="close", output_dir=tmp_path / "a", **kw))
    rep = json.loads(open(s["report"]).read())
    assert rep["end_pose"]["framing"] == "close" and rep["end_pose"]["poses"]
    assert "end pose chosen from" in rep["end_pose_note"]
    ends = set()
    for c in rep["candidates"]:
        ep, view = c["end_pose"], c["subject_view"]
        assert np.allclose(c["goal"], ep["point"], atol=1e-6) and c["goal_moved"] is None  # it ends at its pose
        assert view["framing"] == "close" and view["framing_band"] == [0.6, 0.7, 0.85]
        assert 0 <= view["visible_last"] <= 1 and 0 <= view["frames_visible_half"] <= 1
        ends.add(tuple(np.round(c["goal"], 6)))
    assert len(ends) == len(rep["candidates"])  # different candidates, different end poses
    out = capsys.readouterr().out
    assert "end pose:" in out and "close: 0.6-0.85" in out
    old = run_plan(PlanArgs(go_to="the armchair", end_pose=False, output_dir=tmp_path / "b", start="0 0 0.7", **kw))
    orep = json.loads(open(old["report"]).read())
    assert orep["end_pose"] is None and orep["candidates"][0]["end_pose"] is None
    assert orep["candidates"][0]["subject_view"]["visible_last"] is not None  # the view is reported either way
    same = run_plan(PlanArgs(go_to="floor lamp", output_dir=tmp_path / "c", start="0 0 0.7", **kw))
    srep = json.loads(open(same["report"]).read())
    assert srep["end_pose"]["poses"][0]["goto_distance"] == 0.0  # a good view of the lamp, no go-to distance
    with pytest.raises(InvalidInputError, match="framing"):
        run_plan(PlanArgs(go_to="armchair", framing="huge", output_dir=tmp_path / "d", **kw))
    assert not (tmp_path / "d").exists()


def test_planning_region_rules_in_report_and_export(tmp_path, capsys):
    """No cameras: the dense content's box; --region: that box; a compact export's stored region: used on load. The
    report and the printed summary say which rule chose it."""
    from cinenerf_ns.method.checkpoint import SplatCheckpoint, export_compact
    from cinenerf_ns.synthetic.grove import grove_scene

    g = grove_scene(20_000, seed=1, background_fraction=0.1)
    ply = g.write_ply(tmp_path / "grove.ply")
    common = dict(go_to="-0.3 0.2 0.5", look_at="0.5 0.5 0.5", start="0.6 -0.5 0.6", planner=grid(48))
    s = run_plan(PlanArgs(scene=str(ply), output_dir=tmp_path / "a", **common))
    reg = s["planning_region"]
    assert reg["rule"] == "dense content"
    assert np.ptp(np.array([reg["lo"], reg["hi"]]), axis=0).max() < 9.0  # not the 15-unit background shell
    assert "(dense content)" in capsys.readouterr().out
    box = "-1.5 -1.5 0 1.5 1.5 1.2"
    s = run_plan(PlanArgs(scene=str(ply), output_dir=tmp_path / "b", region=box, **common))
    assert s["planning_region"]["rule"] == "user box"
    np.testing.assert_allclose(s["planning_region"]["lo"], [-1.5, -1.5, 0])
    st = SplatCheckpoint(params=g.splat)
    npz = export_compact(st, tmp_path / "grove.npz", half=False,
                         planning_region=(np.array([-1.2, -1.2, 0.0]), np.array([1.2, 1.2, 1.0])))
    s = run_plan(PlanArgs(scene=str(npz), output_dir=tmp_path / "c", **common))
    assert s["planning_region"]["rule"] == "stored in the export"
    np.testing.assert_allclose(s["planning_region"]["lo"], [-1.2, -1.2, 0])
    s = run_plan(PlanArgs(scene=str(npz), output_dir=tmp_path / "d", region=box, **common))
    assert s["planning_region"]["rule"] == "user box"  # --region wins over the stored one


def test_ignore_floaters_reports_the_count_and_the_verified_obstacles(tmp_path, capsys):
    from cinenerf_ns.synthetic.grove import grove_scene

    ply = grove_scene(20_000, seed=3).write_ply(tmp_path / "grove.ply")
    common = dict(scene=str(ply), go_to="-0.3 0.2 0.5", look_at="0.5 0.5 0.5", start="0.6 -0.5 0.6",
                  planner=grid(48))
    s = run_plan(PlanArgs(output_dir=tmp_path / "on", ignore_floaters="on", **common))
    fl = s["floaters"]
    assert fl["ignored"] and fl["ignored_gaussians"] > 0 and "opacity <=" in fl["rule"]
    assert s["candidates"][0]["verification"]["obstacles"] == fl["obstacles"]
    assert f"{fl['ignored_gaussians']} floaters ignored" in " ".join(capsys.readouterr().out.split())
    s = run_plan(PlanArgs(output_dir=tmp_path / "off", **common))  # the default keeps every Gaussian
    assert not s["floaters"]["ignored"] and s["floaters"]["ignored_gaussians"] == 0
    assert s["candidates"][0]["verification"]["obstacles"].startswith("all ")


def test_a_grid_made_finer_is_said(tmp_path, capsys):
    """--grid-resolution below what max_voxel_radii asks for is raised, and the report and the summary say so; with
    --planner.max-voxel-radii None the grid is the one asked for, and nothing is said."""
    s = run_plan(PlanArgs(scene="procedural:3000:1", go_to="1 0 0.5", look_at="floor lamp", planner=grid(16),
                          workers=0, output_dir=tmp_path / "a"))
    reg = json.loads(open(s["report"]).read())["planning_region"]
    assert max(reg["grid_shape"]) > 16 and reg["grid_note"].startswith(f"grid {max(reg['grid_shape'])} voxels")
    assert "made finer so that a voxel" in " ".join(capsys.readouterr().out.split())
    kept = dataclasses.replace(grid(16), max_voxel_radii=None)
    s = run_plan(PlanArgs(scene="procedural:3000:1", go_to="1 0 0.5", look_at="floor lamp", planner=kept, workers=0,
                          output_dir=tmp_path / "b"))
    reg = json.loads(open(s["report"]).read())["planning_region"]
    assert max(reg["grid_shape"]) == 16 and reg["grid_note"] is None
    assert "made finer" not in " ".join(capsys.readouterr().out.split())
