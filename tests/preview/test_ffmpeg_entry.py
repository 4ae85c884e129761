"""The ``ffmpeg`` console script (cinenerf_ns.ffmpeg_entry) that lets stock ns-render / mediapy write mp4s without a
system ffmpeg. These tests never use a system ffmpeg: the only ffmpeg on the PATH they build is the entry's."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tomllib

from cinenerf_ns import ffmpeg_entry

REPO = Path(__file__).resolve().parents[2]


def _pythonpath() -> str:
    """The repo first, then whatever PYTHONPATH already holds (a GPU machine's packages live in a --target folder)."""
    return os.pathsep.join([str(REPO)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])


def _console_script(bin_dir: Path) -> Path:
    """The wrapper pip writes for ``ffmpeg = "cinenerf_ns.ffmpeg_entry:main"`` (same form as pip's template)."""
    bin_dir.mkdir(parents=True, exist_ok=True)
    p = bin_dir / "ffmpeg"
    p.write_text(f"#!{sys.executable}\nimport sys\nfrom cinenerf_ns.ffmpeg_entry import main\n"
                 "if __name__ == '__main__':\n    sys.exit(main())\n")
    p.chmod(0o755)
    return p


def test_pyproject_installs_the_entry():
    meta = tomllib.loads((REPO / "pyproject.toml").read_text())
    assert meta["project"]["scripts"]["ffmpeg"] == "cinenerf_ns.ffmpeg_entry:main"
    assert any(d.startswith("imageio-ffmpeg") for d in meta["project"]["dependencies"])
    assert os.access(ffmpeg_entry.bundled_ffmpeg(), os.X_OK)


def test_entry_runs_the_bundled_ffmpeg():
    r = subprocess.run([sys.executable, "-c", "from cinenerf_ns.ffmpeg_entry import main; main()", "-version"],
                       cwd=REPO, capture_output=True, text=True, timeout=60,
                       env={**os.environ, "PYTHONPATH": _pythonpath()})
    assert r.returncode == 0 and r.stdout.startswith("ffmpeg version")


def test_nerfstudio_check_and_mediapy_find_it(tmp_path, monkeypatch):
    media = pytest.importorskip("mediapy")
    script = _console_script(tmp_path / "bin")
    monkeypatch.setenv("PATH", str(script.parent) + os.pathsep + os.environ.get("PATH", ""))
    monkeypatch.setenv("PYTHONPATH", _pythonpath())
    assert shutil.which("ffmpeg") == str(script)
    install_checks = pytest.importorskip("nerfstudio.utils.install_checks")
    install_checks.check_ffmpeg_installed()  # sys.exit(1) when shutil.which finds none
    assert media.video_is_available() and media._search_for_ffmpeg_path() == str(script)
    frames = np.zeros((6, 32, 48, 3), np.uint8)
    frames[:, :, :, 0] = np.linspace(0, 250, 6, dtype=np.uint8)[:, None, None]  # red ramp over time
    out = tmp_path / "tiny.mp4"
    media.write_video(out, frames, fps=6)  # what ns-render's media.VideoWriter does, through our ffmpeg
    back = media.read_video(out)
    assert back.shape == (6, 32, 48, 3) and out.read_bytes()[4:8] == b"ftyp"
    assert np.abs(back[..., 0].astype(int).mean(axis=(1, 2)) - frames[:, 0, 0, 0]).max() < 12


def test_vsync_is_rewritten_for_new_ffmpeg():
    assert ffmpeg_entry.translate_args(["-i", "a.mp4", "-vsync", "0", "-f", "null", "-"]) == \
        ["-i", "a.mp4", "-fps_mode", "passthrough", "-f", "null", "-"]
    assert ffmpeg_entry.translate_args(["-vsync", "vfr", "-vsync"]) == ["-fps_mode", "vfr", "-vsync"]


def test_loading_the_method_puts_the_env_ffmpeg_on_path(tmp_path, monkeypatch):
    """.venv/bin/ns-render run without an activated venv: importing the method (eval_setup does, before nerfstudio's
    ffmpeg check) puts the interpreter's bin folder, which holds the ffmpeg script, on PATH."""
    import importlib

    import cinenerf_ns.method

    bin_dir = tmp_path / "venv" / "bin"
    script = _console_script(bin_dir)
    monkeypatch.setenv("PATH", "/nonexistent-bin")
    monkeypatch.setattr(sys, "executable", str(bin_dir / "python"))
    assert shutil.which("ffmpeg") is None
    importlib.reload(cinenerf_ns.method)
    assert shutil.which("ffmpeg") == str(script)
    install_checks = pytest.importorskip("nerfstudio.utils.install_checks")
    install_checks.check_ffmpeg_installed()  # sys.exit(1) when it finds none
    monkeypatch.setenv("PATH", "/nonexistent-bin")
    monkeypatch.setattr(sys, "executable", str(tmp_path / "elsewhere" / "python"))  # no script beside it: left alone
    assert ffmpeg_entry.ensure_on_path() is False and os.environ["PATH"] == "/nonexistent-bin"


@pytest.mark.parametrize("name,version,rewritten", [("ffmpeg-linux64-v4.2.2", (4, 2), False),
                                                    ("ffmpeg-linux-x86_64-v9.0.2", (9, 0), True)])
def test_vsync_rewritten_only_for_an_ffmpeg_that_knows_fps_mode(name, version, rewritten, monkeypatch):
    """imageio-ffmpeg 0.5 ships ffmpeg 4.2 (no -fps_mode), 0.8 ships 9.0 (no -vsync): the script passes what the
    binary understands."""
    seen = {}
    monkeypatch.setattr(ffmpeg_entry, "bundled_ffmpeg", lambda: f"/bin/{name}")
    monkeypatch.setattr(ffmpeg_entry.os, "execv", lambda exe, argv: seen.update(exe=exe, argv=argv))
    assert ffmpeg_entry.binary_version(f"/bin/{name}") == version
    ffmpeg_entry.main(["-i", "x.mp4", "-vsync", "0", "-f", "rawvideo", "-"])
    assert ("-fps_mode" in seen["argv"]) is rewritten and ("-vsync" in seen["argv"]) is not rewritten
