"""Hostile input for cinesplat-plan: every case ends with exit status 2, a message on stderr that names the problem,
no traceback, within a bounded time, and nothing written. The cases are generated here (no shared data needed)."""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from cinenerf_ns.cli.plan import main

SCENE = ["--scene", "procedural:3000:1", "--grid-resolution", "48"]
TARGETS = ["--go-to", "armchair", "--look-at", "floor lamp"]
HANG_GUARD_S = 60.0  # not a performance figure: a case that needs this long is hanging (RESULTS has the real times)

# (case id, extra argv (after the scene and targets; later options win), message regex)
OPTION_CASES = [
    ("fps-zero", ["--fps", "0"], r"--fps must be a number in \[1, 240\]"),
    ("fps-huge", ["--fps", "100000"], r"--fps must be a number in \[1, 240\]"),
    ("fps-nan", ["--fps", "nan"], r"--fps must be"),
    ("fps-inf", ["--fps", "inf"], r"--fps must be"),
    ("fps-negative", ["--fps", "-30"], r"--fps must be"),
    ("speed-zero", ["--max-speed", "0"], r"--max-speed must be a number in \(0, 100\]"),
    ("speed-negative", ["--max-speed", "-1"], r"--max-speed must be"),
    ("speed-nan", ["--max-speed", "nan"], r"--max-speed must be"),
    ("speed-huge", ["--max-speed", "1e9"], r"--max-speed must be"),
    ("speed-tiny", ["--max-speed", "1e-6"], r"--max-speed 1e-06 is too slow .* use --max-speed >= "),
    ("fov-zero", ["--fov", "0"], r"--fov must be a number in \[1, 179\]"),
    ("fov-180", ["--fov", "180"], r"--fov must be"),
    ("width-zero", ["--width", "0"], r"--width must be an integer in \[16, 8192\]"),
    ("width-huge", ["--width", "100000"], r"--width must be"),
    ("height-small", ["--height", "5"], r"--height must be"),
    ("radius-negative", ["--camera-radius", "-0.1"], r"--camera-radius must be"),
    ("radius-nan", ["--camera-radius", "nan"], r"--camera-radius must be"),
    ("radius-room-size", ["--camera-radius", "5"], r"camera sphere .* too large for this scene"),
    ("margin-negative", ["--safety-margin", "-1"], r"--safety-margin must be"),
    ("beta-zero", ["--beta", "0"], r"--beta must be"),
    ("beta-inf", ["--beta", "inf"], r"--beta must be"),
    ("opacity-floor", ["--opacity-floor", "1.5"], r"--opacity-floor must be"),
    ("grid-zero", ["--grid-resolution", "0"], r"--grid-resolution must be an integer in \[8, 1024\]"),
    ("grid-huge", ["--grid-resolution", "100000"], r"--grid-resolution must be"),
    ("grid-over-budget", ["--grid-resolution", "1000", "--memory-budget-mb", "256"],
     r"--grid-resolution 1000 needs about .* memory budget 256 MB .* at most \d+ fits"),
    ("budget-tiny", ["--memory-budget-mb", "1"], r"--memory-budget-mb must be"),
    ("candidates-zero", ["--candidates", "0"], r"--candidates must be an integer in \[1, 64\]"),
    ("candidates-256", ["--candidates", "256"], r"--candidates must be"),
    ("candidates-negative", ["--candidates", "-3"], r"--candidates must be"),
    ("time-budget-zero", ["--time-budget", "0"], r"--time-budget must be"),
    ("seed-negative", ["--seed", "-1"], r"--seed must be"),
    ("threshold-above-one", ["--threshold", "1.5"], r"--threshold must be"),
    ("threshold-zero", ["--threshold", "0"], r"--threshold must be"),
    ("smoothing-negative", ["--semantic-smoothing", "-1"], r"--semantic-smoothing must be"),
    ("cluster-two", ["--object-cluster", "2"], r"--object-cluster must be"),
    ("centre-relevancy-one", ["--centre-relevancy", "1"], r"--centre-relevancy must be in \[0, 1\)"),
    ("start-look-distance-one", ["--start-look-distance", "1"], r"--start-look-distance must be"),
    ("workers-negative", ["--workers", "-1"], r"--workers must be"),
    ("acceleration-zero", ["--max-acceleration", "0"], r"--max-acceleration must be"),
    ("angular-rate-negative", ["--max-angular-rate", "-5"], r"--max-angular-rate must be"),
    ("object-radius-negative", ["--object-radius", "-1"], r"--object-radius must be"),
    ("up-zero", ["--up", "0", "0", "0"], r"--up must be three finite numbers"),
    ("up-nan", ["--up", "nan", "0", "1"], r"--up must be"),
    ("device-tpu", ["--device", "tpu"], r"--device must be 'cpu' or 'cuda'"),
    ("name-path", ["--name", "../evil"], r"--name must be 1-100 letters"),
    ("name-empty", ["--name", ""], r"--name must be"),
    ("preview-size", ["--preview", "--preview-size", "8", "270"],
     r"--preview-size \(width\) must be an integer in \[16, 4096\]"),
    ("preview-fps", ["--preview", "--preview-fps", "500"], r"--preview-fps must be a number in \[1, 120\]"),
    ("then-look-at-count", ["--then-go-to", "sofa", "--then-look-at", "table", "bookshelf"],
     r"--then-look-at needs one look-at per --then-go-to"),
    ("go-to-huge", ["--go-to", "1e30 0 0"], r"go-to point .* units outside the planning region"),
    ("go-to-far", ["--go-to", "50 50 50"], r"go-to point .* units outside the planning region"),
    ("go-to-nan", ["--go-to", "nan 0 0"], r"go-to point 'nan 0 0' is not finite"),
    ("look-at-far", ["--look-at", "0 0 1e300"], r"look-at point .* outside the planning region"),
    ("start-far", ["--start", "5 5 5"], r"start point .* units outside the planning region"),
    ("start-outside-region", ["--start", "1.9 0 0.5"], r"start point .* outside the planning region .* --force-start"),
    ("start-not-a-point", ["--start", "abc"], r"--start must be a point 'x y z'"),
    ("start-two-numbers", ["--start", "1 2"], r"--start must be a point"),
    ("start-in-an-object", ["--start", "@object"], r"puts the camera inside the scene"),
    ("region-nan", ["--region", "0 0 0 1 1 nan"], r"planning region \(--region\) must be 6 finite numbers"),
    ("region-inverted", ["--region", "1 0 0 0 1 1"], r"--region\) is empty or inverted along x"),
    ("region-empty", ["--region", "0 0 0.2 1 1 0.2"], r"--region\) is empty or inverted along z"),
    ("region-five-numbers", ["--region", "0 0 0 1 1"], r"--region\) must be 6 numbers .* got 5 numbers"),
    ("region-text", ["--region", "everywhere"], r"--region must be 6 numbers 'x0 y0 z0 x1 y1 z1'"),
    ("region-outside-the-scene", ["--region", "10 10 10 11 11 11"], r"--region\) .* lies outside the scene"),
    ("region-too-thin", ["--region", "-1 -1 0.5 1 1 0.52"], r"--region\) .* too small for the camera along z"),
    ("go-to-empty", ["--go-to", ""], r"go-to target is empty"),
    ("look-at-blank", ["--look-at", "   "], r"look-at target is empty"),
    ("go-to-nonsense", ["--go-to", "xyzzy"], r"no object matches 'xyzzy' .* objects: "),
    ("go-to-shared-adjective", ["--go-to", "the red elephant"], r"no object matches 'the red elephant'"),
    ("then-go-to-nonsense", ["--then-go-to", "purple elephant"], r"no object matches 'purple elephant'"),
]


def _scene_file_cases(tmp: Path):
    """(id, --scene value, message regex) for files made here."""
    (tmp / "empty.npz").write_bytes(b"")
    (tmp / "noise.npz").write_bytes(os.urandom(2048))
    (tmp / "noise.ply").write_bytes(os.urandom(512))
    (tmp / "notes.txt").write_text("not a scene")
    (tmp / "empty_dir").mkdir()
    from cinenerf_ns.planner.scene.ply import write_splat_ply
    from cinenerf_ns.planner.scene.procedural import procedural_room

    r = procedural_room(1000, seed=2)
    pts = write_splat_ply(tmp / "room.ply", r.means.numpy(), r.quats.numpy(), r.log_scales.numpy(),
                          r.opacity_logits.numpy().reshape(-1))
    return [
        ("scene-empty-string", "", r"--scene is empty"),
        ("scene-missing", str(tmp / "nope.npz"), r"nope\.npz"),
        ("scene-procedural-bad", "procedural:abc", r"bad procedural scene 'procedural:abc'"),
        ("scene-procedural-small", "procedural:5", r"bad procedural scene .* N a whole number in \[1000, "),
        ("scene-empty-npz", str(tmp / "empty.npz"), r"empty\.npz"),
        ("scene-noise-npz", str(tmp / "noise.npz"), r"noise\.npz"),
        ("scene-noise-ply", str(tmp / "noise.ply"), r"noise\.ply"),
        ("scene-text-file", str(tmp / "notes.txt"), r"notes\.txt"),
        ("scene-empty-folder", str(tmp / "empty_dir"), r"empty_dir"),
        ("text-on-a-splat-ply", str(pts), r"is text, but this scene \(ply\) has no semantics"),
    ]


def _run(argv, capsys, out: Path):
    t0 = time.perf_counter()
    with pytest.raises(SystemExit) if False else _no_exit():
        code = main(argv)
    dt = time.perf_counter() - t0
    cap = capsys.readouterr()
    return code, cap.out, cap.err, dt


class _no_exit:
    def __enter__(self):
        return self

    def __exit__(self, et, e, tb):
        if et is SystemExit:  # tyro's own parse errors exit 2 with usage on stderr: fine for a user error
            raise AssertionError(f"tyro exited ({e.code}) instead of cinesplat-plan's message")
        return False


def _check(code, out, err, dt, regex, outdir: Path):
    import re

    assert code == 2, f"exit {code}; stdout {out[-400:]!r} stderr {err[-400:]!r}"
    assert "Traceback" not in err and "Traceback" not in out
    assert re.search(regex, " ".join(err.split())), f"message {err!r} does not match {regex!r}"
    assert dt < HANG_GUARD_S
    assert not outdir.exists() or not any(outdir.iterdir()), f"left {list(outdir.iterdir())}"


@pytest.fixture(scope="module")
def object_point():
    """A point deep inside one of the test room's Gaussians (a start in collision)."""
    import torch

    from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
    from cinenerf_ns.planner.scene.procedural import procedural_room

    s = procedural_room(3000, seed=1)
    e = EllipsoidScene.from_splat(s.means, s.quats, s.log_scales, s.opacity_logits)
    m = e.means.double().numpy()
    ok = ((m > s.free_lo + 0.1) & (m < s.free_hi - 0.1)).all(1)
    i = np.flatnonzero(ok)[int(torch.argmax(e.radii[torch.as_tensor(ok)].min(-1).values))]
    return " ".join(f"{v:.6f}" for v in m[i])


@pytest.mark.parametrize("case,extra,regex", OPTION_CASES, ids=[c[0] for c in OPTION_CASES])
def test_option_cases(case, extra, regex, tmp_path, capsys, object_point):
    out = tmp_path / "out"
    extra = [object_point if a == "@object" else a for a in extra]
    code, o, e, dt = _run(SCENE + TARGETS + ["--output-dir", str(out)] + extra, capsys, out)
    _check(code, o, e, dt, regex, out)


def test_scene_file_cases(tmp_path, capsys):
    cases = _scene_file_cases(tmp_path)
    for case, scene, regex in cases:
        out = tmp_path / f"out-{case}"
        code, o, e, dt = _run(["--scene", scene, "--go-to", "sofa", "--look-at", "0 0 0", "--output-dir", str(out)],
                              capsys, out)
        _check(code, o, e, dt, regex, out)


@pytest.mark.parametrize("where", ["file", "under-file"])
def test_output_dir_that_is_not_a_folder(where, tmp_path, capsys):
    f = tmp_path / "taken"
    f.write_text("keep me")
    out = f if where == "file" else f / "sub"
    code, o, e, dt = _run(SCENE + TARGETS + ["--output-dir", str(out)], capsys, tmp_path / "never")
    _check(code, o, e, dt, r"--output-dir .* (is a file|not a folder)", tmp_path / "never")
    assert f.read_text() == "keep me"


def test_suite_is_at_least_sixty_cases(tmp_path):
    assert len(OPTION_CASES) + len(_scene_file_cases(tmp_path)) + 2 >= 60  # + the two output-folder cases


@pytest.mark.parametrize("text", ["the purple elephant", "xyzzy"])
def test_text_that_matches_nothing_on_the_bundled_scene(text, tmp_path, capsys):
    """The bundled room was trained without real CLIP weights: text naming none of its labels is refused with the
    list of what it can answer (it once planned a shot to the purple stool / the armchair)."""
    from cinenerf_ns.scenes import DEMO_SCENE

    if not DEMO_SCENE.exists():
        pytest.skip("the bundled scene is not in this checkout")
    out = tmp_path / "out"
    code, o, e, dt = _run(["--scene", str(DEMO_SCENE), "--go-to", text, "--look-at", "floor lamp", "--output-dir",
                           str(out)], capsys, out)
    _check(code, o, e, dt, rf"nothing in the scene matches '{text}': .* red armchair, floor lamp", out)
