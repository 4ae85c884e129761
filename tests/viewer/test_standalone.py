"""Standalone viewer: loading (3DGS .ply, a run's config.yml + checkpoint, compact export, procedural,
demo), the real planner prepared in the background, text queries (names / relevancy) or coordinates
only with a clear message; CLI help."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import yaml
from _xdist import free_port
from viewer_fakes import wait_for

from cinenerf_ns.method.scene_files import CheckpointError
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.splat_params import SH_C0, SplatParams
from cinenerf_ns.planner.shots.planner import PlannerConfig
from cinenerf_ns.viewer.demo import demo_scene
from cinenerf_ns.viewer.standalone import StandaloneConfig, StandaloneViewer, display_gaussians, open_scene

REPO = Path(__file__).resolve().parents[2]


def write_3dgs_ply(path: Path, d) -> None:
    from cinenerf_ns.planner.scene.ply import write_ply_vertices

    n = len(d.means)
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3"]
    arr = np.empty(n, dtype=[(k, "f4") for k in names])
    dc = (d.rgb() - 0.5) / SH_C0
    cols = [d.means[:, 0], d.means[:, 1], d.means[:, 2], dc[:, 0], dc[:, 1], dc[:, 2], d.opacity_logits,
            *d.log_scales.T, *d.quats_wxyz.T]
    for k, c in zip(names, cols):
        arr[k] = c
    write_ply_vertices(path, arr)


def test_load_ply_round_trip(tmp_path):
    d = demo_scene().splat
    write_3dgs_ply(tmp_path / "scene.ply", d)
    sc = open_scene(str(tmp_path / "scene.ply"))
    np.testing.assert_allclose(sc.splat.means, d.means, atol=1e-6)
    np.testing.assert_allclose(sc.splat.rgb(), d.rgb(), atol=1e-5)
    np.testing.assert_allclose(sc.splat.log_scales, d.log_scales, atol=1e-6)
    assert sc.data_dir == tmp_path and sc.config_path is None and sc.locate is None
    g = display_gaussians(sc.splat)
    i = 2000  # an isotropic object Gaussian: covariance = sigma^2 I
    np.testing.assert_allclose(g.covariances[i], np.eye(3) * np.exp(2 * d.log_scales[i, 0]), rtol=1e-4, atol=1e-9)


def test_load_config_and_checkpoint(tmp_path):
    d = demo_scene().splat
    run = tmp_path / "outputs" / "scene" / "cinesplat" / "ts"
    (run / "nerfstudio_models").mkdir(parents=True)
    data = tmp_path / "data" / "myscene"
    data.mkdir(parents=True)
    cfg = SimpleNamespace(data=data, pipeline=SimpleNamespace(datamanager=SimpleNamespace(data=data)))
    (run / "config.yml").write_text(yaml.dump(cfg))
    sd = {f"_model.gauss_params.{k}": torch.as_tensor(v) for k, v in dict(
        means=d.means, quats=d.quats_wxyz, scales=d.log_scales, opacities=d.opacity_logits[:, None],
        features_dc=(d.rgb() - 0.5) / SH_C0).items()}
    torch.save({"pipeline": {k: v * 0 for k, v in sd.items()}}, run / "nerfstudio_models" / "step-000000099.ckpt")
    torch.save({"pipeline": sd}, run / "nerfstudio_models" / "step-000000999.ckpt")  # newest wins
    sc = open_scene(str(run / "config.yml"))
    np.testing.assert_allclose(sc.splat.means, d.means)
    assert sc.data_dir == data and sc.config_path == (run / "config.yml").absolute() and sc.name == "myscene"


def test_bad_sources(tmp_path):
    with pytest.raises(InvalidInputError, match="scene not found"):  # scenes.load_scene's messages
        open_scene(str(tmp_path / "nope.ply"))
    (tmp_path / "x.txt").write_text("hi")
    with pytest.raises(CheckpointError, match=r"suffix '\.txt'.*config.yml"):
        open_scene(str(tmp_path / "x.txt"))
    from cinenerf_ns.planner.scene.ply import write_ply_vertices

    write_ply_vertices(tmp_path / "pts.ply", np.zeros(3, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")]))
    with pytest.raises(InvalidInputError, match="not a Gaussian splat .ply"):
        open_scene(str(tmp_path / "pts.ply"))


def room_splat():
    from cinenerf_ns.planner.scene.procedural import procedural_room
    from cinenerf_ns.scenes import procedural_params

    room = procedural_room(2000, seed=0)
    return room, procedural_params(room)


def viewer_for(source, tmp_path, **kw) -> StandaloneViewer:
    return StandaloneViewer(StandaloneConfig(load_config=source, port=free_port(), host="127.0.0.1",
                                             output_dir=kw.pop("output_dir", tmp_path),
                                             planner=PlannerConfig(grid_resolution=48), **kw))


def test_standalone_on_ply_plans_with_coordinates(tmp_path):
    room, sp = room_splat()
    write_3dgs_ply(tmp_path / "scene.ply", sp)
    v = viewer_for(str(tmp_path / "scene.ply"), tmp_path)
    p = v.panels.server_panel()
    try:
        assert "this scene has none: type targets as x y z" in p.status
        assert v.planner is not None and v.planner.wait_ready(60), p.status
        assert p.request_plan("the armchair", "0 0 0").result(30) is None
        assert "need a trained cinesplat scene" in p.status and p.status_level == "error"
        goal = " ".join(f"{x:.3f}" for x in room.object("table").center + [0, 0, 0.3])
        look = " ".join(f"{x:.3f}" for x in room.object("table").center)
        assert p.request_plan(goal, look, n_candidates=2).result(60) is not None, p.status
        assert "cinenerf_ns planner" in p.view.details_text
        out = p.export("ply-take")
        assert out.path == tmp_path / "camera_paths" / "ply-take.json"
    finally:
        v.close()


def test_standalone_procedural_names_progress_and_errors(tmp_path):
    v = viewer_for("procedural:2000", tmp_path, output_dir=tmp_path / "data")
    p = v.panels.server_panel()
    try:
        assert v.planner.wait_ready(60)
        assert wait_for(lambda: "Planner ready." in p.status), p.status  # prepare progress
        assert "Planner prepared in" in p.view.details_text  # its time in the details
        assert "Text queries: object names" in p.status
        res = p.request_plan("armchair", "floor lamp", n_candidates=2).result(60)
        assert res is not None, p.status
        room, _ = room_splat()  # the same generated room (same N and seed)
        k = [o.name for o in room.objects].index("armchair")
        assert np.array_equal(res.targets[0].mask, room.object_ids.numpy() == k)  # over the drawn Gaussians
        np.testing.assert_allclose(res.targets[0].point, room.objects[k].center)
        labels = p.view.candidate.options
        assert len(labels) == len(res.shots) and all(" s, clearance " in lab for lab in labels)
        ok = p.export("take")
        before = ok.path.read_bytes()
        # readable errors from the real planner / queries, and the export stays whole
        assert p.request_plan("the unicorn", "sofa").result(30) is None
        assert "no object matches 'the unicorn'" in p.status
        inside = v.loaded.obstacles.means[0].double().numpy()
        p.view.camera_position = lambda: inside  # as if the browser camera sat inside an obstacle
        assert p.request_plan("armchair", "sofa", start_from_camera=True).result(60) is None
        assert "puts the camera inside the scene" in p.status and p.status_level == "error"
        assert p.shot is res.shots[0]  # the previous plan is kept
        again = p.export("take")  # never overwrites: a numbered name, said in the status
        assert again.path == ok.path.with_name("take-2.json") and ok.path.read_bytes() == before
        assert again.renamed_from == "take" and "'take.json' already exists" in p.status
        assert again.command is None  # a procedural room has no run: no ns-render command with a placeholder
        assert sorted(f.name for f in ok.path.parent.iterdir()) == ["take-2.json", "take.json"]
    finally:
        v.close()


def test_standalone_compact_scene_answers_text_by_relevancy(tmp_path):
    from cinenerf_ns.method.checkpoint import SplatCheckpoint, export_compact
    from cinenerf_ns.method.codec import CodecConfig, FeatureCodec

    room, sp = room_splat()
    torch.manual_seed(0)
    codec = FeatureCodec(8, CodecConfig(hidden_dim=8, train_steps=1))
    ids = room.object_ids
    latents = torch.zeros(len(ids), 3)
    latents[ids == 0] = torch.tensor([0.9, -0.5, 0.3])  # the armchair's Gaussians share one code
    from cinenerf_ns.method.relevancy import DEFAULT_NEGATIVES

    names = ["armchair", *DEFAULT_NEGATIVES]  # offline: the relevancy negatives are labels too (no CLIP weights)
    with torch.no_grad():  # label embeddings = decoded codes: the armchair's code, the background's for the rest
        emb = codec.decode(torch.tensor([[0.9, -0.5, 0.3]] + [[0.0, 0.0, 0.0]] * len(DEFAULT_NEGATIVES)))
    st = SplatCheckpoint(
        SplatParams.of(sp.means, sp.quats_wxyz, sp.log_scales, sp.opacity_logits, latents=latents), codec=codec,
        codec_state=codec.state_dict(), label_embeddings=emb,
        info={"feature_dim": 8, "codec_config": vars(CodecConfig(hidden_dim=8, train_steps=1)), "label_names": names,
              "clip": None},
    )
    path = export_compact(st, tmp_path / "scene_compact.pt", half=False)
    from cinenerf_ns.planner.scene.scene_config import SceneConfig
    from cinenerf_ns.scenes import load_scene as cli_load

    v = viewer_for(str(path), tmp_path, output_dir=tmp_path / "out")
    p = v.panels.server_panel()
    try:
        assert "relevancy" in p.status and v.loaded.semantics == "relevancy"
        # the viewer warms the text queries on a thread after loading: every label answered from the cache
        assert v.warm_thread is not None
        v.warm_thread.join(60)
        warm = v.loaded.semantic
        assert not v.warm_thread.is_alive() and warm._smoothed is not None
        assert warm.locate_full("armchair") is warm.locate_full("armchair")
        assert len(warm._cache) >= 1
        sem = cli_load(str(path), SceneConfig())
        assert sem.semantics.semantic._smoothed is None and not sem.semantics.semantic._cache  # the CLI stays lazy
        c_ref, m_ref = sem.semantics.semantic.locate("armchair")
        c, m, what = v.backend.locate("the armchair")  # word -> label name, as cinesplat-plan maps it
        assert what.startswith("the label 'armchair', best relevancy ")  # what the query matched, in words
        np.testing.assert_allclose(c, c_ref.numpy(), atol=1e-6)
        assert np.array_equal(m, m_ref.numpy()) and m.sum() > 0
        assert p.request_plan("", "armchair").result(30) is None and "'Go to' is empty" in p.status
        assert p.request_plan("sofa", "armchair").result(30) is None
        assert "answers only its own object names" in p.status
        # the planner's preparation finishing after that fast failure does not overwrite it (it once did, at random)
        v._prepare_status("Planner ready in 0.01 s.", "ok")
        assert "answers only its own object names" in p.status
    finally:
        v.close()


def test_the_overview_cuts_away_what_lies_above_the_start_region(tmp_path, monkeypatch):
    """The splat is sent as two viser nodes, the Gaussians above the start region's top apart ("/splat_above": a
    room's ceiling); the top-down overview hides that node, so the path and frustums show from above (viser draws
    splats over lines, with no option against it). Without a start region (a .ply) the splat stays one node."""
    import viser

    sent = []
    real = viser.SceneApi.add_gaussian_splats

    def record(self, name, centers, covariances, rgbs, opacities, **kw):
        sent.append((name, np.array(centers)))
        return real(self, name, centers, covariances, rgbs, opacities, **kw)

    monkeypatch.setattr(viser.SceneApi, "add_gaussian_splats", record)
    v = StandaloneViewer(StandaloneConfig(load_config="procedural:2000", port=free_port(), host="127.0.0.1",
                                          output_dir=tmp_path), plan_fn=lambda *a, **k: [])
    try:
        top = float(v.loaded.start_region[1][2]) * v.cfg.scale
        parts = dict(sent)
        assert sorted(parts) == ["/splat", "/splat_above"]
        assert parts["/splat"][:, 2].max() <= top < parts["/splat_above"][:, 2].min()
        assert len(parts["/splat"]) + len(parts["/splat_above"]) == len(v.loaded.splat.means)
        above = v.splat_above[0]
        p = v.panels.server_panel()
        assert v.panels.overview_hides == [above] and above.visible
        p.view.overview_box.value = True  # the "Top-down overview" checkbox (set server side: its callback runs)
        assert wait_for(lambda: not above.visible)
        p.view.overview_box.value = False
        assert wait_for(lambda: above.visible)
    finally:
        v.close()
    sent.clear()
    room, sp = room_splat()
    write_3dgs_ply(tmp_path / "scene.ply", sp)
    v = StandaloneViewer(StandaloneConfig(load_config=str(tmp_path / "scene.ply"), port=free_port(), host="127.0.0.1",
                                          output_dir=tmp_path), plan_fn=lambda *a, **k: [])
    try:
        assert [name for name, _ in sent] == ["/splat"] and v.panels.overview_hides == []
    finally:
        v.close()


def test_cli_help(capsys, monkeypatch):
    """--help lists the options and exits 0 (in this process; `python -m cinenerf_ns.viewer.standalone` itself is run
    by test_a_scene_path_that_looks_like_markup_is_served_and_printed_as_typed)."""
    from cinenerf_ns.viewer.standalone import entrypoint

    monkeypatch.setenv("COLUMNS", "120")
    with pytest.raises(SystemExit) as e:
        entrypoint(["--help"])
    out = capsys.readouterr().out
    assert e.value.code == 0 and "--load-config" in out and "--port" in out


def test_help_and_option_errors_come_before_torch():
    """The command run as the module: --help and an option out of range answer without importing torch (the config
    dataclasses are torch-free; the scene and planner modules load when the viewer starts). The process says at exit
    whether torch was loaded."""
    run_as_command = ("import atexit, runpy, sys; atexit.register(lambda: print('torch loaded:', 'torch' in "
                      "sys.modules, file=sys.stderr)); "
                      "runpy.run_module('cinenerf_ns.viewer.standalone', run_name='__main__', alter_sys=True)")
    for argv, code, said in ((["--help"], 0, "--load-config"), (["--port", "0"], 2, "--port must be an integer")):
        r = subprocess.run([sys.executable, "-c", run_as_command, *argv], capture_output=True, text=True, timeout=120,
                           env=dict(os.environ, PYTHONPATH=str(REPO), COLUMNS="120"))
        assert r.returncode == code and said in r.stdout + r.stderr, r.stderr[-2000:]
        assert "torch loaded: False" in r.stderr, r.stderr[-2000:]


@pytest.mark.parametrize("argv,regex", [
    (["--port", "0"], r"--port must be an integer in \[1, 65535\]"),
    (["--camera-radius", "-1"], r"--camera-radius must be"),
    (["--grid-resolution", "100000"], r"--grid-resolution must be an integer in \[8, 1024\]"),
    (["--max-speed", "0"], r"--max-speed must be"),
    (["--candidates", "500"], r"--candidates must be an integer in \[1, 64\]"),
    (["--n-candidates", "5"], r"--n-candidates was renamed: use --candidates"),
    (["--scene", "/nonexistent/scene.npz"], r"scene\.npz"),
    (["--trajectory.smoothness-order", "9"], r"--trajectory.smoothness-order must be in"),
    (["--device", "tpu"], r"--device must be"),
    (["--load-config", "/nonexistent/scene.npz"], r"scene\.npz"),
    (["--load-config", "procedural:abc"], r"bad procedural scene"),
    (["--load-config", "/nonexistent/a[/x] [red]:smile:.npz"], r"/nonexistent/a\[/x\] \[red\]:smile:\.npz"),
])
def test_viewer_options_are_checked_before_anything_starts(argv, regex, capsys):
    """cinesplat-viewer refuses bad options with a message naming them on stderr, exit 2, no server started."""
    import re

    from cinenerf_ns.viewer.standalone import entrypoint

    with pytest.raises(SystemExit) as ei:
        entrypoint(argv)
    assert ei.value.code == 2
    err = " ".join(capsys.readouterr().err.split())
    assert "Traceback" not in err and re.search(regex, err), err


def compact_scene_with_labels(path: Path, n_labels: int) -> Path:
    """A compact export of the small procedural room whose latents answer ``n_labels`` label names (offline)."""
    from cinenerf_ns.method.checkpoint import SplatCheckpoint, export_compact
    from cinenerf_ns.method.codec import CodecConfig, FeatureCodec

    _, sp = room_splat()
    torch.manual_seed(0)
    codec = FeatureCodec(8, CodecConfig(hidden_dim=8, train_steps=1))
    codes = torch.randn(n_labels, 3)
    latents = codes[torch.arange(len(sp.means)) % n_labels]
    with torch.no_grad():
        emb = codec.decode(codes)
    st = SplatCheckpoint(
        SplatParams.of(sp.means, sp.quats_wxyz, sp.log_scales, sp.opacity_logits, latents=latents), codec=codec,
        codec_state=codec.state_dict(), label_embeddings=emb,
        info={"feature_dim": 8, "codec_config": vars(CodecConfig(hidden_dim=8, train_steps=1)),
              "label_names": [f"thing {i}" for i in range(n_labels)], "clip": None},
    )
    return export_compact(st, path, half=False)


# The viewer's command line with each label of the warm-up slowed down by torch work on the warm-up's thread (the
# bundled room's warm-up takes about a minute of such work on a loaded 2-core box). Prints a line per label warmed.
SLOW_WARM_DRIVER = """
import sys, time, torch
import cinenerf_ns.method.semantic_scene as ss
real = ss.SemanticScene._locate_uncached
def slow(self, text, threshold=None):
    print('warming', text, file=sys.stderr, flush=True)
    a, t0 = torch.randn(256, 256), time.perf_counter()
    while time.perf_counter() - t0 < 0.3:
        a = torch.tanh(a @ a)
    return real(self, text, threshold)
ss.SemanticScene._locate_uncached = slow
from cinenerf_ns.viewer.standalone import entrypoint
entrypoint(sys.argv[1:])
print('viewer exited', flush=True)
"""


def _default_sigint() -> None:
    """In the child before exec: SIGINT back to its default action. A shell starts background jobs (`make test &`) with
    SIGINT ignored, exec keeps it ignored, and Python then installs no KeyboardInterrupt for it: the Ctrl+C these tests
    send would be lost (fresh-clone runs started that way timed out here)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


def interrupt_viewer_when(python_args, scene: Path, tmp_path: Path, stream: str, ready):
    """Run the viewer's command line (``python <python_args> --load-config scene ...``), send Ctrl+C once a line of
    ``stream`` ('stdout' | 'stderr') passes ``ready``; returns (exit status, that stream's lines, the other's text)."""
    import signal
    import threading
    import time

    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1")
    p = subprocess.Popen([sys.executable, *python_args, "--load-config", str(scene), "--port", str(free_port()),
                          "--host", "127.0.0.1", "--output-dir", str(tmp_path / "data"), "--grid-resolution", "48"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                         preexec_fn=_default_sigint)
    got: dict = {"stdout": [], "stderr": []}
    readers = [threading.Thread(target=lambda k=k, f=f: got[k].extend(f), daemon=True)
               for k, f in (("stdout", p.stdout), ("stderr", p.stderr))]
    for r in readers:
        r.start()
    lines = got[stream]
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not any(ready(line) for line in lines):
            assert p.poll() is None, "".join(lines)
            time.sleep(0.05)
        assert any(ready(line) for line in lines), "".join(lines)
        p.send_signal(signal.SIGINT)
        p.wait(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    for r in readers:
        r.join(10)
    return p.returncode, lines, "".join(got["stderr" if stream == "stdout" else "stdout"])


def test_ctrl_c_during_the_text_query_warm_up_exits_cleanly(tmp_path):
    """Ctrl+C while the text-query warm-up still runs on its thread: the warm-up stops after its current label, the
    process exits with status 0, no traceback, no C++ abort ('terminate called without an active exception', 134:
    the interpreter's shutdown while the thread ran torch code)."""
    scene = compact_scene_with_labels(tmp_path / "scene_compact.pt", 40)
    code, err, out = interrupt_viewer_when(["-c", SLOW_WARM_DRIVER], scene, tmp_path, "stderr",
                                           lambda line: line.startswith("warming"))
    text = out + "".join(err)
    assert code == 0, text
    assert "terminate called" not in text and "Traceback" not in text, text
    assert "viewer exited" in out, text  # a normal return: the warm-up stopped (no os._exit fallback)
    warmed = sum(line.startswith("warming") for line in err)
    assert warmed < 40, text  # stopped early, not after every label


def test_host_and_port_are_checked_before_loading(tmp_path, capsys):
    """127.0.0.1 by default; an address that is not one (999.1.1.1), or not this machine's, fails at once with the
    option named (viser tried 1,000 ports, silently); a taken port says so; 0.0.0.0 prints a warning."""
    import time

    from cinenerf_ns.viewer.standalone import check_bind, check_config, check_host, entrypoint, exposure_warning

    assert StandaloneConfig().host == "127.0.0.1"
    assert StandaloneConfig().output_dir == Path("cinesplat_viewer_exports")
    for bad in ["999.1.1.1", "", "evil.example", "1.2.3"]:
        with pytest.raises(InvalidInputError, match="--host"):
            check_host(bad)
    t0 = time.monotonic()
    with pytest.raises(SystemExit) as e:
        entrypoint(["--host", "999.1.1.1", "--load-config", "demo-tiny"])
    assert e.value.code == 2 and time.monotonic() - t0 < 10
    err = capsys.readouterr().err
    assert "--host '999.1.1.1' is not an IP address" in err and "Traceback" not in err
    with pytest.raises(InvalidInputError, match="not an address of this machine"):
        check_bind("203.0.113.7", free_port())  # TEST-NET-3: never one of this machine's
    with socket.socket() as s:  # a port in use
        s.bind(("127.0.0.1", 0))
        s.listen(1)
        port = s.getsockname()[1]
        with pytest.raises(InvalidInputError, match=f"--port {port} is already in use"):
            check_bind("127.0.0.1", port)
    (tmp_path / "file").write_text("x")
    with pytest.raises(InvalidInputError, match="--output-dir .* is a file; give a folder"):
        check_config(StandaloneConfig(output_dir=tmp_path / "file"))
    with pytest.raises(InvalidInputError, match="--output-dir .* lies under .*file, which is not a folder"):
        check_config(StandaloneConfig(output_dir=tmp_path / "file" / "sub"))
    if Path("/proc/self").is_dir():  # a folder that takes no files: refused at start, not at the first export
        with pytest.raises(InvalidInputError, match="--output-dir /proc/x: cannot write into /proc"):
            check_config(StandaloneConfig(output_dir=Path("/proc/x")))
    assert exposure_warning("127.0.0.1") is None and exposure_warning("::1") is None
    assert exposure_warning("localhost") is None
    assert "anyone who can reach this port" in exposure_warning("0.0.0.0")


def test_exports_go_to_the_output_folder_never_beside_the_scene(tmp_path, monkeypatch):
    room, sp = room_splat()
    scene_dir = tmp_path / "dataset"
    scene_dir.mkdir()
    write_3dgs_ply(scene_dir / "scene.ply", sp)
    monkeypatch.chdir(tmp_path)
    v = StandaloneViewer(StandaloneConfig(load_config=str(scene_dir / "scene.ply"), port=free_port(),
                                          host="127.0.0.1"), plan_fn=lambda *a, **k: [])
    try:
        assert v.panels.config.output_dir == tmp_path / "cinesplat_viewer_exports"
        assert v.url.startswith("http://127.0.0.1:")
    finally:
        v.close()
    assert sorted(f.name for f in scene_dir.iterdir()) == ["scene.ply"]


def test_a_scene_path_that_looks_like_markup_is_served_and_printed_as_typed(tmp_path):
    """User text is never rich markup (issue 38): a scene in a folder named like rich tags and emoji codes loads, the
    viewer's start-up lines quote its name as typed (it once raised MarkupError there), and Ctrl+C exits 0."""
    folder = tmp_path / "a[/x] [red]:smile:"
    folder.mkdir(parents=True)  # "a[" / "x] [red]:smile:"
    scene = compact_scene_with_labels(folder / "scene [red] :smile: [bold].pt", 3)  # the status names the stem
    code, lines, err = interrupt_viewer_when(["-m", "cinenerf_ns.viewer.standalone"], scene, tmp_path, "stdout",
                                             lambda line: line.startswith("Planner ready"))  # the last status
    out = "".join(lines)
    assert code == 0 and "Traceback" not in out + err, out + err
    assert "running at" in out and "'scene [red] :smile: [bold]'" in " ".join(out.split()), out


def test_the_exit_watchdog_ends_a_process_that_a_thread_keeps_alive():
    """After Ctrl+C the viewer ends within SHUTDOWN_HARD_S whatever still runs: here a non-daemon thread that would keep
    the interpreter's shutdown waiting for 60 s."""
    import time

    code = ("import threading, time\nfrom cinenerf_ns.viewer.standalone import exit_watchdog\n"
            "threading.Thread(target=time.sleep, args=(60,)).start()\nexit_watchdog(0.5)\n"
            "print('main done', flush=True)\n")
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=50,
                       env=dict(os.environ, PYTHONPATH=str(REPO)))
    assert r.returncode == 0 and "main done" in r.stdout and time.monotonic() - t0 < 30, r.stderr
