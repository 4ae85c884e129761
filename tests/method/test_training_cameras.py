"""training_cameras.py: camera centres from a transforms.json + dataparser transform, a config.yml, or an export's
info."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from cinenerf_ns.method.training_cameras import (
    camera_box,
    camera_centres,
    camera_info,
    camera_poses,
    info_camera_centres,
    info_camera_poses,
    run_data_path,
    scene_camera_poses,
    training_camera_centres,
    training_camera_poses,
)


def _write(tmp_path, centres, transform, scale):
    frames = []
    for c in centres:
        m = np.eye(4)
        m[:3, 3] = c
        frames.append({"file_path": "images/x.png", "transform_matrix": m.tolist()})
    (tmp_path / "transforms.json").write_text(json.dumps({"frames": frames}))
    (tmp_path / "dataparser_transforms.json").write_text(json.dumps({"transform": np.asarray(transform).tolist(),
                                                                     "scale": scale}))


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 9), st.floats(0.05, 5.0))
def test_camera_centres_apply_the_dataparser_transform_then_its_scale(tmp_path_factory, seed, n, scale):
    """Against the definition, one camera at a time: scale * (R c + t), with a random rotation R and translation t."""
    tmp = tmp_path_factory.mktemp("cams")
    rng = np.random.default_rng(seed)
    c = rng.uniform(-3, 3, (n, 3))
    R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    t = rng.uniform(-1, 1, 3)
    _write(tmp, c, np.concatenate([R, t[:, None]], 1), scale)
    got = camera_centres(tmp / "transforms.json", tmp / "dataparser_transforms.json")
    want = np.array([scale * (R @ ci + t) for ci in c])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    lo, hi = camera_box(got, pad=0.25)
    np.testing.assert_allclose(lo, want.min(0) - 0.25)
    np.testing.assert_allclose(hi, want.max(0) + 0.25)


def _random_dataset(folder: Path, n: int, seed: int, **meta) -> np.ndarray:
    """A transforms.json of ``n`` random camera poses (nerfstudio's format, 100 x 80 pinhole) plus ``meta``; returns the
    stored poses [n, 4, 4]."""
    rng = np.random.default_rng(seed)
    poses = []
    for _ in range(n):
        R, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        R[:, 0] *= np.sign(np.linalg.det(R))  # a rotation
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = R, rng.uniform(-3, 3, 3)
        poses.append(m)
    frames = [{"file_path": f"images/{i:03d}.png", "transform_matrix": m.tolist()} for i, m in enumerate(poses)]
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "transforms.json").write_text(json.dumps(
        {"fl_x": 100.0, "fl_y": 100.0, "cx": 50.0, "cy": 40.0, "w": 100, "h": 80, "frames": frames, **meta}))
    return np.stack(poses)


@pytest.mark.parametrize("case", ["plain", "applied", "legacy-colmap"])
def test_camera_poses_are_nerfstudio_s_training_cameras(tmp_path, case):
    """camera_poses from the files a run leaves (transforms.json + dataparser_transforms.json) equal the cameras
    nerfstudio's own dataparser trains with, also when ns-process-data stored an applied_transform / applied_scale
    (the run's saved transform includes them, the frames are stored after them) and for nerfstudio's legacy colmap rule
    (data with colmap/sparse/0 and no applied_transform: a fixed axis swap)."""
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    data = tmp_path / "data"
    meta = {"applied_transform": [[0, 1, 0, 0.5], [1, 0, 0, -0.2], [0, 0, -1, 0.1]], "applied_scale": 0.7} \
        if case == "applied" else {}
    _random_dataset(data, 8, seed=3, **meta)
    if case == "legacy-colmap":
        (data / "colmap" / "sparse" / "0").mkdir(parents=True)
    out = NerfstudioDataParserConfig(data=data, downscale_factor=1,
                                     eval_mode="all").setup().get_dataparser_outputs("train")
    out.save_dataparser_transform(tmp_path / "run" / "dataparser_transforms.json")
    want = out.cameras.camera_to_worlds.double().numpy()  # [8, 3, 4]
    got = camera_poses(data / "transforms.json", tmp_path / "run" / "dataparser_transforms.json", data)
    np.testing.assert_allclose(got, want, atol=1e-6)
    np.testing.assert_allclose(camera_centres(data / "transforms.json", tmp_path / "run" / "dataparser_transforms.json",
                                              data), want[:, :, 3], atol=1e-6)
    if case != "plain":  # the rule matters: the saved transform applied to the stored frames as they are is elsewhere
        dp = json.loads((tmp_path / "run" / "dataparser_transforms.json").read_text())
        stored = np.array([f["transform_matrix"] for f in json.loads((data / "transforms.json").read_text())["frames"]])
        naive = ((np.asarray(dp["transform"])[None, :, :3] @ stored[:, :3, 3:])[:, :, 0]
                 + np.asarray(dp["transform"])[:, 3])
        assert np.abs(naive * dp["scale"] - want[:, :, 3]).max() > 0.1
    # a run's config.yml finds the same poses through its data path
    (tmp_path / "run" / "config.yml").write_text(
        f"data: !!python/object/apply:pathlib.PosixPath {json.dumps(list(data.parts))}\nmethod_name: cinesplat\n")
    np.testing.assert_allclose(training_camera_poses(tmp_path / "run" / "config.yml"), want, atol=1e-6)
    np.testing.assert_allclose(scene_camera_poses(tmp_path / "run" / "config.yml", {}), want, atol=1e-6)


def test_info_camera_poses_reads_only_well_formed_lists():
    poses = np.arange(24, dtype=float).reshape(2, 3, 4)
    info = camera_info(poses[:, :, 3], poses)
    np.testing.assert_array_equal(info_camera_poses(info), poses)
    np.testing.assert_array_equal(info_camera_centres(info), poses[:, :, 3])
    assert "camera_poses" not in camera_info(poses[:, :, 3])  # centres only: no poses key
    assert info_camera_poses({}) is None and info_camera_poses({"camera_poses": []}) is None
    assert info_camera_poses({"camera_poses": [[0, 1, 2]]}) is None  # not [F, 3, 4]
    assert info_camera_poses({"camera_poses": np.full((1, 3, 4), np.inf).tolist()}) is None
    assert info_camera_poses({"camera_poses": "x"}) is None
    np.testing.assert_array_equal(scene_camera_poses(None, info), poses)  # no run: the export's


def test_info_camera_centres_reads_only_well_formed_lists():
    assert info_camera_centres({}) is None
    assert info_camera_centres({"camera_centres": []}) is None
    assert info_camera_centres({"camera_centres": [[0, 1]]}) is None  # not [F, 3]
    assert info_camera_centres({"camera_centres": [[0, float("nan"), 1]]}) is None
    assert info_camera_centres({"camera_centres": "x"}) is None
    np.testing.assert_array_equal(info_camera_centres({"camera_centres": [[0, 1, 2], [3, 4, 5]]}),
                                  [[0, 1, 2], [3, 4, 5]])


def test_training_camera_centres_without_data_is_none(tmp_path):
    """A config that names no data, or whose data is gone: None (the caller plans without), never an exception."""
    assert training_camera_centres(tmp_path / "missing.yml") is None
    (tmp_path / "config.yml").write_text("method_name: cinesplat\n")
    assert run_data_path(tmp_path / "config.yml") is None
    assert training_camera_centres(tmp_path / "config.yml") is None
    (tmp_path / "config.yml").write_text(
        "data: !!python/object/apply:pathlib.PosixPath\n- /\n- nowhere\n- room\nmethod_name: cinesplat\n")
    assert str(run_data_path(tmp_path / "config.yml")) == "/nowhere/room"
    assert training_camera_centres(tmp_path / "config.yml") is None


@pytest.mark.parametrize("suffix", [".npz", ".pt"])
def test_add_camera_centres_script_keeps_the_arrays(tmp_path, suffix):
    """scripts/add_camera_centres.py stores info["camera_centres"] and the box (start_region) in a compact export and
    leaves every array as it was (no re-quantisation); load_compact then reads them."""
    import importlib.util
    from pathlib import Path

    from cinenerf_ns.method.checkpoint import SplatCheckpoint, export_compact, load_compact
    from cinenerf_ns.planner.scene.splat_params import SplatParams

    script = Path(__file__).resolve().parents[2] / "scripts" / "add_camera_centres.py"
    spec = importlib.util.spec_from_file_location("acc", script)
    acc = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(acc)
    rng = np.random.default_rng(1)
    n = 50
    st_ = SplatCheckpoint(SplatParams.of(rng.normal(size=(n, 3)), rng.normal(size=(n, 4)), rng.normal(size=(n, 3)),
                                         rng.normal(size=n)), info={"label_names": ["a"]})
    path = export_compact(st_, tmp_path / f"s{suffix}")
    before = load_compact(path)
    _write(tmp_path, rng.uniform(-2, 2, (6, 3)), np.concatenate([np.eye(3), np.zeros((3, 1))], 1), 0.5)
    acc.main(["--scene", str(path), "--transforms", str(tmp_path / "transforms.json"),
              "--dataparser-transforms", str(tmp_path / "dataparser_transforms.json")])
    after = load_compact(path)
    for k in ("means", "quats_wxyz", "log_scales", "opacity_logits"):
        assert np.array_equal(getattr(before.params, k), getattr(after.params, k)), k
    want = camera_centres(tmp_path / "transforms.json", tmp_path / "dataparser_transforms.json")
    np.testing.assert_allclose(info_camera_centres(after.info), want)
    np.testing.assert_allclose(info_camera_poses(after.info),  # and the poses, where cinesplat-viewer opens
                               camera_poses(tmp_path / "transforms.json", tmp_path / "dataparser_transforms.json"))
    np.testing.assert_allclose(after.info["start_region"][0], want.min(0) - 0.1)
    assert after.info["label_names"] == ["a"]
    with pytest.raises(SystemExit, match="not found"):
        acc.main(["--scene", str(tmp_path / "none.pt"), "--transforms", str(tmp_path / "transforms.json"),
                  "--dataparser-transforms", str(tmp_path / "dataparser_transforms.json")])


def test_run_config_reader_constructs_nothing(tmp_path):
    """The one config.yml reader turns python tags into plain data: a tag naming a function is never called."""
    from cinenerf_ns.method.training_cameras import read_run_config, run_data_path

    marker = tmp_path / "ran"
    (tmp_path / "config.yml").write_text(
        "!!python/object:nerfstudio.engine.trainer.TrainerConfig\n"
        f"hook: !!python/object/apply:os.system ['touch {marker}']\n"
        "data: !!python/object/apply:pathlib.PosixPath ['/', 'srv', 'scene']\n")
    cfg = read_run_config(tmp_path / "config.yml")
    assert not marker.exists() and cfg["hook"] == [f"touch {marker}"]
    assert run_data_path(tmp_path / "config.yml") == Path("/srv/scene")
