"""cinesplat-preview: a good run writes the outputs; bad input names the option and its range on stderr, exits 2
and writes nothing."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from cinenerf_ns.method.checkpoint import SplatCheckpoint, export_compact
from cinenerf_ns.preview.cli import main

sys.path.insert(0, str(Path(__file__).parent))
from _scenes import orbit_camera_path, random_splat  # noqa: E402

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def inputs(tmp_path):
    scene = export_compact(SplatCheckpoint(random_splat(5)), tmp_path / "scene.npz")
    cam = tmp_path / "shot.json"
    cam.write_text(json.dumps(orbit_camera_path(n=12)))
    return scene, cam


def test_cli_writes_the_preview(inputs, tmp_path, capsys):
    scene, cam = inputs
    out = main(["--scene", str(scene), "--camera-path", str(cam), "--output-dir", str(tmp_path / "r"),
                "--width", "48", "--height", "32", "--fps", "12"])
    assert sorted(os.listdir(tmp_path / "r")) == ["shot.mp4", "shot_sheet.png"]
    assert out["width"] == 48 and out["height"] == 32 and out["fps"] == 12
    assert str(tmp_path / "r" / "shot.mp4") in capsys.readouterr().out


@pytest.mark.parametrize("args,needle", [
    (["--width", "15"], "--width must be in 16..4096"),
    (["--height", "4097"], "--height must be in 16..4096"),
    (["--fps", "0"], "--fps must be in 1..120"),
    (["--fps", "121"], "--fps must be in 1..120"),
    (["--fps", "nan"], "--fps must be in 1..120"),
    (["--width", "abc"], "--width: invalid int value"),
    (["--scene", "missing.npz"], "--scene: file or folder not found"),
    (["--camera-path", "missing.json"], "--camera-path: file not found"),
    (["--camera-path", "BADJSON"], "--camera-path: camera path"),
    (["--scene", "NOTSCENE"], "--scene: could not load"),
    (["--name", "../up"], "--name must be a plain file name"),
])
def test_bad_input_exits_2_and_writes_nothing(inputs, tmp_path, capsys, args, needle):
    scene, cam = inputs
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    args = [str(bad) if a == "BADJSON" else str(cam) if a == "NOTSCENE" else a for a in args]
    base = {"--scene": str(scene), "--camera-path": str(cam), "--output-dir": str(tmp_path / "r")}
    for k in list(base):
        if k in args:
            del base[k]
    argv = [x for kv in base.items() for x in kv] + args
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr()
    assert needle in err.err and err.out == ""
    assert not (tmp_path / "r").exists()


def test_console_entry_exit_status(inputs, tmp_path):
    scene, cam = inputs
    r = subprocess.run([sys.executable, "-m", "cinenerf_ns.preview.cli", "--scene", str(scene), "--camera-path",
                        str(cam), "--output-dir", str(tmp_path / "r"), "--height", "9"], cwd=REPO,
                       capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert r.returncode == 2 and "--height must be in 16..4096" in r.stderr and not (tmp_path / "r").exists()


def test_names_and_paths_that_look_like_markup_are_printed_as_typed(inputs, tmp_path, capsys):
    """User text is never rich markup (issue 38): a name and an output folder holding tags and emoji codes are used and
    printed as typed (the progress bar's description included)."""
    scene, cam = inputs
    out_dir, name = tmp_path / "r[/x] [red]:smile:", "[bold]take :smile: 🎬 [red]"
    out = main(["--scene", str(scene), "--camera-path", str(cam), "--output-dir", str(out_dir), "--name", name,
                "--width", "48", "--height", "32", "--fps", "12"])
    assert sorted(os.listdir(out_dir)) == [f"{name}.mp4", f"{name}_sheet.png"] and out["frames"] > 0
    cap = capsys.readouterr()
    assert str(out_dir / f"{name}.mp4") in cap.out and "Traceback" not in cap.out + cap.err
    assert f"preview {name} 48x32" in cap.out  # the progress bar's line
