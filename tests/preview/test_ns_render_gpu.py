"""Stock ``ns-render camera-path`` writes an mp4 of a planned shot with no system ffmpeg (needs CUDA and the fox data).

A tiny cinesplat run on the fox capture (300 steps), a shot planned on it with ``cinesplat-plan``, then nerfstudio's own
renderer to mp4 with a PATH whose only ffmpeg is this package's console script (cinenerf_ns.ffmpeg_entry)."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.gpu, pytest.mark.fox, pytest.mark.slow]
REPO = Path(__file__).resolve().parents[2]


def _ffmpeg_script(bin_dir: Path) -> Path:
    """The wrapper pip writes for ``ffmpeg = "cinenerf_ns.ffmpeg_entry:main"``."""
    bin_dir.mkdir(parents=True, exist_ok=True)
    p = bin_dir / "ffmpeg"
    p.write_text(f"#!{sys.executable}\nimport sys\nfrom cinenerf_ns.ffmpeg_entry import main\nsys.exit(main())\n")
    p.chmod(0o755)
    return p


def _env(bin_dir: Path) -> dict:
    """PATH: our ffmpeg, the interpreter's bin (ns-train / ns-render / cinesplat-plan), the system's; no other
    ffmpeg."""
    tool_dirs = {str(Path(shutil.which("ns-train")).parent)} if shutil.which("ns-train") else set()
    keep = [d for d in os.environ.get("PATH", "").split(os.pathsep)
            if d and (d in tool_dirs or not Path(d, "ffmpeg").exists())]
    return {**os.environ, "PATH": os.pathsep.join([str(bin_dir)] + keep), "PYTHONPATH": os.pathsep.join(
        [str(REPO)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])}


def test_planned_shot_renders_to_mp4_with_stock_ns_render(tmp_path, fox_dir):
    if not shutil.which("ns-train") or not shutil.which("ns-render"):
        pytest.skip("nerfstudio's ns-train / ns-render are not on PATH")
    bin_dir = tmp_path / "bin"
    script = _ffmpeg_script(bin_dir)
    env = _env(bin_dir)
    assert shutil.which("ffmpeg", path=env["PATH"]) == str(script)
    data = tmp_path / "fox"
    shutil.copytree(fox_dir, data, ignore=shutil.ignore_patterns("images", "images_2"))
    run = lambda *cmd: subprocess.run(list(cmd), env=env, capture_output=True, text=True, timeout=600)  # noqa: E731
    r = run("ns-train", "cinesplat", "--data", str(data), "--output-dir", str(tmp_path / "outputs"), "--timestamp", "t",
            "--max-num-iterations", "300", "--steps-per-save", "300", "--vis", "tensorboard",
            "--pipeline.datamanager.clip.random-weights", "True", "nerfstudio-data", "--downscale-factor", "4")
    assert r.returncode == 0, r.stderr[-2000:]
    cfg = next((tmp_path / "outputs").glob("*/cinesplat/t/config.yml"))
    r = run(sys.executable, "-m", "cinenerf_ns.cli.plan", "--scene", str(cfg), "--go-to", "0.3 0 0", "--look-at",
            "0 0 0", "--output-dir", str(tmp_path / "plans"), "--width", "320", "--height", "180")
    assert r.returncode == 0, r.stderr[-2000:]
    path = tmp_path / "plans" / "shot_0.json"
    frames = len(json.loads(path.read_text())["camera_path"])
    mp4 = tmp_path / "renders" / "shot.mp4"
    r = run("ns-render", "camera-path", "--load-config", str(cfg), "--camera-path-filename", str(path),
            "--output-path", str(mp4))
    assert r.returncode == 0, (r.stdout[-1500:], r.stderr[-1500:])
    assert mp4.read_bytes()[4:8] == b"ftyp"
    import mediapy

    mediapy.set_ffmpeg(str(script))
    video = mediapy.read_video(mp4)
    assert video.shape[0] == frames and video.shape[1:3] == (180, 320)
    assert video.std() > 1.0  # the fox, not a blank frame
