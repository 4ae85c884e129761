"""Dataset export: nerfstudio's dataparser loads it; ground truth maps into nerfstudio coordinates."""
import json

import numpy as np
import pytest
import torch
from PIL import Image

from cinenerf_ns.synthetic.cli import main
from cinenerf_ns.synthetic.dataset import DatasetConfig, load_labels, load_point_cloud, load_room, write_dataset
from cinenerf_ns.synthetic.ns_transform import GroundTruthNS, NerfstudioTransform
from cinenerf_ns.synthetic.room import Room


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("room")
    cfg = DatasetConfig(output=out, seed=3, num_views=8, width=64, height=48, points_per_view=50)
    info = write_dataset(cfg)
    return out, cfg, info


def _parse(out, split="train"):
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    return NerfstudioDataParserConfig(data=out).setup().get_dataparser_outputs(split)


def test_files_written(dataset):
    out, cfg, info = dataset
    meta = json.loads((out / "transforms.json").read_text())
    assert meta["camera_model"] == "PINHOLE" and meta["w"] == 64 and meta["h"] == 48
    assert len(meta["frames"]) == 8
    labels = load_labels(out)
    room = load_room(out)
    assert labels == room.labels
    for f in meta["frames"]:
        img = np.asarray(Image.open(out / f["file_path"]))
        lab = np.asarray(Image.open(out / f["label_path"]))
        dep = np.asarray(Image.open(out / f["depth_file_path"]))
        assert img.shape == (48, 64, 3) and img.dtype == np.uint8
        assert lab.shape == (48, 64) and set(np.unique(lab).tolist()) <= set(labels)
        assert dep.shape == (48, 64) and dep.min() > 0
        c2w = np.asarray(f["transform_matrix"])
        assert np.allclose(c2w[3], [0, 0, 0, 1]) and np.allclose(np.linalg.det(c2w[:3, :3]), 1.0)
    assert (out / "sparse_pc.ply").exists() and "ply_file_path" not in meta
    assert info["render_seconds"] > 0


def test_point_cloud_on_surfaces(dataset):
    out, _, _ = dataset
    xyz, rgb = load_point_cloud(out)
    assert len(xyz) == 8 * 50 and rgb.shape == (400, 3) and rgb.dtype == torch.uint8
    assert rgb.float().std() > 5  # coloured, not constant
    assert load_room(out).sdf(xyz).abs().max() < 1e-3  # float32 storage


def test_nerfstudio_dataparser_loads_and_transform_helper_agrees(dataset):
    out, cfg, _ = dataset
    outputs = _parse(out)
    n_train = len(outputs.image_filenames)
    assert 0 < n_train <= 8
    assert outputs.cameras.width[0].item() == 64
    tf = NerfstudioTransform.from_dataset(out)
    assert torch.allclose(tf.transform, outputs.dataparser_transform.to(torch.float64), atol=1e-6)
    assert tf.scale == pytest.approx(outputs.dataparser_scale, rel=1e-6)
    # room stays axis-aligned with +z up (orientation_override none)
    assert torch.allclose(tf.rotation, torch.eye(3, dtype=torch.float64))
    # original poses mapped by the helper equal nerfstudio's cameras (train split = sorted frames, subset)
    meta = json.loads((out / "transforms.json").read_text())
    by_name = {(out / f["file_path"]).name: np.asarray(f["transform_matrix"]) for f in meta["frames"]}
    for k, fname in enumerate(outputs.image_filenames):
        mine = tf.c2w_to_ns(torch.tensor(by_name[fname.name]))
        assert torch.allclose(mine.float(), outputs.cameras.camera_to_worlds[k], atol=1e-5)
    # the saved-json route (what ns-train writes) gives the same mapping
    (out / "dp.json").write_text(json.dumps({"transform": outputs.dataparser_transform.tolist(),
                                             "scale": outputs.dataparser_scale}))
    tf2 = NerfstudioTransform.from_dataparser_json(out / "dp.json")
    p = torch.randn(10, 3, dtype=torch.float64)
    assert torch.allclose(tf.points_to_ns(p), tf2.points_to_ns(p), atol=1e-6)
    assert torch.allclose(tf.points_from_ns(tf.points_to_ns(p)), p, atol=1e-12)


def test_ground_truth_in_ns_coordinates(dataset):
    out, _, _ = dataset
    room = Room.load(out)
    tf = NerfstudioTransform.from_dataset(out)
    gt = GroundTruthNS(room, tf)
    p = room.object_points(room.objects[0].name, 50)
    assert torch.allclose(gt.sdf(tf.points_to_ns(p)), room.sdf(p) * tf.scale)
    c = gt.object_centres()
    assert set(c) == {o.name for o in room.objects}
    # all cameras within nerfstudio's +-1 box after the transform
    meta = json.loads((out / "transforms.json").read_text())
    pos = torch.tensor([f["transform_matrix"] for f in meta["frames"]], dtype=torch.float64)[:, :3, 3]
    assert tf.points_to_ns(pos).abs().max().item() == pytest.approx(1.0, abs=1e-5)


def test_nerfstudio_rotation_helper_with_up_orientation(dataset, tmp_path):
    """Without the override nerfstudio rotates the scene; the helper must follow it."""
    out, _, _ = dataset
    meta = json.loads((out / "transforms.json").read_text())
    meta.pop("orientation_override")
    meta["frames"] = [{**f, "file_path": str(out / f["file_path"])} for f in meta["frames"]]
    for f in meta["frames"]:
        f.pop("depth_file_path")
    (tmp_path / "transforms.json").write_text(json.dumps(meta))
    outputs = _parse(tmp_path)
    tf = NerfstudioTransform.from_dataset(tmp_path)
    assert torch.allclose(tf.transform, outputs.dataparser_transform.double(), atol=1e-6)
    assert tf.scale == pytest.approx(outputs.dataparser_scale, rel=1e-6)


def test_cli_main_small(tmp_path):
    info = main(DatasetConfig(output=tmp_path / "r", seed=5, num_views=2, width=32, height=24, write_depth=False))
    assert info["num_views"] == 2
    meta = json.loads((tmp_path / "r" / "transforms.json").read_text())
    assert "depth_file_path" not in meta["frames"][0]
    assert (tmp_path / "r" / "geometry.json").exists()


def test_cli_prints_an_output_path_that_looks_like_markup_as_typed(tmp_path, capsys):
    out = tmp_path / "r[/x] [red]:smile:"
    main(DatasetConfig(output=out, seed=5, num_views=2, width=32, height=24, write_depth=False))
    assert (out / "transforms.json").exists()
    assert f"train with: ns-train cinesplat --data {out}\n" in capsys.readouterr().out  # one line, to copy
