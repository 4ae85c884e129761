"""preview_camera_path end to end: mp4 (decoded back), contact sheet, GIF, atomic writes, backends, fallback."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.preview import native, preview_camera_path, render as render_mod, render_frame, scene_from_splat, video
from cinenerf_ns.preview.cameras import path_cameras

sys.path.insert(0, str(Path(__file__).parent))
from _scenes import orbit_camera_path, random_splat  # noqa: E402

REPO = Path(__file__).resolve().parents[2]


def _decode(path: Path):
    import imageio_ffmpeg

    gen = imageio_ffmpeg.read_frames(str(path))
    meta = next(gen)
    w, h = meta["size"]
    frames = [np.frombuffer(f, np.uint8).reshape(h, w, 3) for f in gen]
    return meta, frames


def test_preview_writes_mp4_sheet_and_gif(tmp_path):
    splat, cam = random_splat(1), orbit_camera_path(n=40, fps=30.0)
    out = preview_camera_path(splat, cam, tmp_path / "out", "shot", width=64, height=48, fps=10, gif=True,
                              progress=False)
    n = round(cam["seconds"] * 10)
    assert out["frames"] == n and out["frame_index"][0] == 0 and out["frame_index"][-1] == 39
    names = sorted(os.listdir(tmp_path / "out"))
    assert names == ["shot.gif", "shot.mp4", "shot_sheet.png"]  # no temporary file left
    for p in out["paths"].values():
        assert os.stat(p).st_mode & 0o777 == 0o644
    meta, frames = _decode(Path(out["paths"]["mp4"]))
    assert meta["codec"].startswith("h264") and len(frames) == n and frames[0].shape == (48, 64, 3)
    assert meta["fps"] == pytest.approx(10)
    cams = path_cameras(cam, 64, 48, 10)
    scene = scene_from_splat(splat)
    for k in (0, n - 1):  # the first and last frames of the video are the first and last poses of the path
        ref = render_frame(scene, cams.viewmats[k], cams.intrinsics[k], 64, 48).astype(float)
        other = render_frame(scene, cams.viewmats[n - 1 - k], cams.intrinsics[n - 1 - k], 64, 48).astype(float)
        err = np.abs(frames[k] - ref).mean()
        assert err < 6.0 and err < 0.5 * np.abs(frames[k] - other).mean()  # H.264 loss << the change of view
    sheet = Image.open(out["paths"]["contact_sheet"])
    assert sheet.size == (3 * 64 + 4 * 4, 2 * 48 + 3 * 4)
    gif = Image.open(out["paths"]["gif"])
    assert gif.n_frames == n
    t = out["timings"]
    assert len(t["frame_ms"]) == n and t["total_s"] >= t["render_s"] > 0


def test_bad_input_writes_nothing(tmp_path):
    splat, cam = random_splat(2), orbit_camera_path(n=10)
    for kw, opt in (({"width": 8}, "width"), ({"height": 5000}, "height"), ({"fps": 0.5}, "fps"),
                    ({"name": "../x"}, "name"), ({"backend": "vulkan"}, "backend")):
        with pytest.raises(InvalidInputError, match=opt):
            preview_camera_path(splat, cam, tmp_path / "out", **kw, progress=False)
    bad = dict(cam, camera_path=[])
    with pytest.raises(InvalidInputError, match="no frames"):
        preview_camera_path(splat, bad, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_failures_mid_way_leave_no_partial_file(tmp_path, monkeypatch):
    splat, cam = random_splat(3), orbit_camera_path(n=20)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    (out_dir / "shot.mp4").write_bytes(b"previous")  # an earlier preview stays untouched
    monkeypatch.setattr(video, "ffmpeg_exe", lambda: "/bin/false")
    with pytest.raises(RuntimeError, match="ffmpeg failed"):
        preview_camera_path(splat, cam, out_dir, "shot", width=32, height=32, progress=False)
    assert os.listdir(out_dir) == ["shot.mp4"] and (out_dir / "shot.mp4").read_bytes() == b"previous"
    monkeypatch.undo()
    calls = []
    real = render_mod.render_premultiplied

    def failing(*a, **k):
        calls.append(1)
        if len(calls) == 3:
            raise MemoryError("boom")
        return real(*a, **k)

    monkeypatch.setattr("cinenerf_ns.preview.preview.render_premultiplied", failing)
    with pytest.raises(MemoryError):
        preview_camera_path(splat, cam, out_dir, "other", width=32, height=32, progress=False)
    assert os.listdir(out_dir) == ["shot.mp4"]


def test_backends_give_the_same_frame():
    scene = scene_from_splat(random_splat(4, n=500))
    cams = path_cameras(orbit_camera_path(n=5), 80, 45, 30)
    a = render_frame(scene, cams.viewmats[2], cams.intrinsics[2], 80, 45, backend="torch").astype(int)
    if native.render_fn("float32") is not None:
        b = render_frame(scene, cams.viewmats[2], cams.intrinsics[2], 80, 45, backend="native").astype(int)
        assert np.abs(a - b).max() <= 1
    bg = np.rint(np.array(render_mod.NERFSTUDIO_BACKGROUND) * 255)
    assert (np.abs(a - bg).sum(-1) > 0).mean() > 0.2  # the splat covers part of the frame, background elsewhere


def test_no_compiler_falls_back_to_torch(tmp_path, monkeypatch):
    """A failing compiler (CC) or CINENERF_NATIVE=0: the loader says why and "auto" renders with torch. In this process
    with the loader's state emptied (as a new process has it; tests/planner/test_native.py runs the same environment
    switches in new processes)."""
    from cinenerf_ns.preview import native, render

    monkeypatch.setenv("CINENERF_CACHE", str(tmp_path))
    for env in ({"CC": str(tmp_path / "no-such-cc")}, {"CINENERF_NATIVE": "0"}):
        with monkeypatch.context() as m:
            m.setattr(native, "_FUNCS", {})
            m.setattr(native, "_STATUS", {})
            for k, v in env.items():
                m.setenv(k, v)
            backend, status = render.choose_backend("auto"), native.native_status()["float32"]
        assert backend == "torch" and ("failed" in status or "turned off" in status), (env, status)


def test_imports_stay_light_and_one_way():
    """preview imports no nerfstudio / gsplat / viser at module level, and the planner never imports preview."""
    code = ("import sys, cinenerf_ns.preview, cinenerf_ns.preview.cli, cinenerf_ns.ffmpeg_entry; "
            "print([m for m in ('nerfstudio', 'gsplat', 'viser') if m in sys.modules])")
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(REPO)})
    assert r.returncode == 0 and r.stdout.strip() == "[]", r.stderr
    planner = REPO / "cinenerf_ns" / "planner"
    pat = re.compile(r"^\s*(from\s+\S*preview|import\s+\S*preview)", re.M)
    assert not [p for p in planner.rglob("*.py") if pat.search(p.read_text())]


def test_contact_sheet_tiles_are_thumbnails_of_the_frames():
    """Frames wider than the tile width are scaled down (a 1280x720 sheet stays small and fast to write); each tile is
    the frame itself, scaled."""
    from cinenerf_ns.preview.video import SHEET_TILE_WIDTH, contact_sheet

    rng = np.random.default_rng(0)
    big = [np.repeat(np.repeat(rng.integers(0, 255, (9, 16, 3), dtype=np.uint8), 80, 0), 80, 1) for _ in range(6)]
    sheet = contact_sheet(big, [""] * 6, pad=4)
    tile_h = round(720 * SHEET_TILE_WIDTH / 1280)
    assert sheet.shape == (2 * tile_h + 3 * 4, 3 * SHEET_TILE_WIDTH + 4 * 4, 3)
    tile = sheet[4 + 20: 4 + tile_h - 2, 4 + 2: 4 + SHEET_TILE_WIDTH - 2]  # below the label box
    cell = SHEET_TILE_WIDTH / 16  # each source block is 30 x 30 pixels in the tile
    ys, xs = (np.arange(tile.shape[0]) + 20 + 0.5) / cell, (np.arange(tile.shape[1]) + 2 + 0.5) / cell
    expect = big[0][(ys * 80).astype(int)[:, None], (xs * 80).astype(int)[None, :]]
    inner = (np.abs(ys - np.round(ys))[:, None] > 0.1) & (np.abs(xs - np.round(xs))[None, :] > 0.1)  # off block edges
    assert np.abs(tile.astype(int) - expect.astype(int))[inner].max() <= 2
    small = [f[:90, :160] for f in big]
    assert contact_sheet(small, [""] * 6).shape == (2 * 90 + 12, 3 * 160 + 16, 3)  # small frames stay as they are


def test_gif_keeps_small_frames_and_a_bounded_count():
    """A GIF's frames are held until it is written: kept at its own width (240), at most MAX_GIF_FRAMES of them."""
    from cinenerf_ns.planner.errors import InvalidInputError
    from cinenerf_ns.preview.preview import MAX_GIF_FRAMES, check_gif_frames
    from cinenerf_ns.preview.video import gif_frame

    assert gif_frame(np.zeros((2160, 3840, 3), np.uint8)).shape == (135, 240, 3)
    small = np.zeros((30, 240, 3), np.uint8)
    assert gif_frame(small) is small
    check_gif_frames(MAX_GIF_FRAMES)
    with pytest.raises(InvalidInputError, match=f"at most {MAX_GIF_FRAMES} frames, this one has {MAX_GIF_FRAMES + 1}"):
        check_gif_frames(MAX_GIF_FRAMES + 1)
