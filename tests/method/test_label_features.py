"""Label masks -> compact ids -> per-pixel text-embedding features."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from PIL import Image

from cinenerf_ns.method.label_features import (
    LabelDataError,
    compact_ids,
    find_label_map,
    label_features,
    load_label_map,
    load_label_maps,
    read_label_table,
    resize_labels,
)


def test_table_formats_and_errors(tmp_path):
    p = tmp_path / "labels.json"
    p.write_text(json.dumps({"0": "floor", "7": "palm tree"}))
    assert read_label_table(p) == {0: "floor", 7: "palm tree"}
    p.write_text(json.dumps([{"id": 2, "name": " chair "}]))
    assert read_label_table(p) == {2: "chair"}
    for bad, msg in [("{}", "empty"), ('{"x": "a"}', "not an integer"), ('{"1": ""}', "no name"),
                     ("{", "not valid JSON")]:
        p.write_text(bad)
        with pytest.raises(LabelDataError, match=msg):
            read_label_table(p)
    with pytest.raises(LabelDataError, match="not found"):
        read_label_table(tmp_path / "missing.json")


def test_png_16bit_and_npy_roundtrip(tmp_path):
    arr = (np.arange(12).reshape(3, 4) * 1000).astype(np.uint16)
    Image.fromarray(arr).save(tmp_path / "a.png")
    np.save(tmp_path / "b.npy", arr.astype(np.int32))
    assert torch.equal(load_label_map(tmp_path / "a.png"), torch.from_numpy(arr.astype(np.int64)))
    assert torch.equal(load_label_map(tmp_path / "b.npy"), torch.from_numpy(arr.astype(np.int64)))
    assert find_label_map(tmp_path, tmp_path / "images" / "a.jpg").name == "a.png"
    with pytest.raises(LabelDataError, match="no label map"):
        find_label_map(tmp_path, tmp_path / "zzz.jpg")
    rgb = np.zeros((3, 4, 3), np.uint8)
    rgb[..., 1] = 5
    Image.fromarray(rgb).save(tmp_path / "c.png")
    with pytest.raises(LabelDataError, match="colour"):
        load_label_map(tmp_path / "c.png")


def test_resize_is_nearest_and_compact_ids():
    ids = torch.tensor([[0, 0, 5, 5], [0, 0, 5, 5], [9, 9, 3, 3], [9, 9, 3, 3]])
    small = resize_labels(ids, (2, 2))
    assert small.tolist() == [[0, 5], [9, 3]]
    comp, raw, names = compact_ids([small], {0: "floor", 5: "lamp", 3: "cat"})  # 9 is unnamed
    assert raw == [0, 3, 5] and names == ["floor", "cat", "lamp"]
    assert comp[0].tolist() == [[0, 2], [-1, 1]]
    with pytest.raises(LabelDataError, match="none of the label ids"):
        compact_ids([small], {42: "x"})


def test_label_features_lookup():
    ids = torch.tensor([[0, 1], [-1, 1]])
    emb = torch.tensor([[1.0, 0.0], [0.0, 1.0]])
    f, v = label_features(ids, emb)
    assert f.tolist() == [[[1, 0], [0, 1]], [[0, 0], [0, 1]]]
    assert v[..., 0].tolist() == [[True, True], [False, True]]


def test_load_label_maps_folder(tmp_path):
    (tmp_path / "labels").mkdir()
    Image.fromarray(np.array([[1, 2], [2, 2]], np.uint8)).save(tmp_path / "labels" / "frame_001.png")
    (tmp_path / "labels.json").write_text(json.dumps({"1": "sofa", "2": "rug"}))
    ids, raw, names = load_label_maps([tmp_path / "images" / "frame_001.jpg"], tmp_path / "labels",
                                      tmp_path / "labels.json", [(2, 2)])
    assert names == ["sofa", "rug"] and ids[0].tolist() == [[0, 1], [1, 1]]
    with pytest.raises(LabelDataError, match="label folder not found"):
        load_label_maps([tmp_path / "x.jpg"], tmp_path / "nolabels", tmp_path / "labels.json", [(2, 2)])


def test_undistortion_matches_nerfstudio_image_undistortion():
    """Label maps go through the same undistortion + crop as nerfstudio's training images (nearest, not linear)."""
    from nerfstudio.cameras.cameras import Cameras, CameraType
    from nerfstudio.data.datamanagers.full_images_datamanager import _undistort_image

    from cinenerf_ns.method.label_features import undistort_label_map

    H, W = 48, 64
    dist = torch.tensor([0.06, -0.08, 0.0, 0.0, -0.001, 0.0002])  # nerfstudio order k1 k2 k3 k4 p1 p2
    cam = Cameras(camera_to_worlds=torch.eye(4)[:3], fx=50.0, fy=50.0, cx=31.0, cy=25.0, width=W, height=H,
                  distortion_params=dist, camera_type=CameraType.PERSPECTIVE)
    yy, xx = torch.meshgrid(torch.arange(H), torch.arange(W), indexing="ij")
    ids = (yy // 12) * 10 + (xx // 16)  # 4 x 4 blocks
    img = ids[..., None].repeat(1, 1, 3).float().numpy()
    K = cam.get_intrinsics_matrices().numpy()
    _, ref_img, _ = _undistort_image(cam, dist.numpy(), {}, img, K.copy())
    ours = undistort_label_map(ids, K.copy(), dist.numpy())
    assert tuple(ours.shape) == ref_img.shape[:2]
    ref = torch.from_numpy(ref_img[..., 0])
    interior = (ref - ref.round()).abs() < 1e-3  # linear interpolation inside a block: an exact id
    assert interior.float().mean() > 0.8
    assert (ours[interior] == ref[interior].round().long()).float().mean() > 0.99
    # no distortion: unchanged
    assert torch.equal(undistort_label_map(ids, K, np.zeros(6)), ids)
