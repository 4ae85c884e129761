"""Label masks as a feature source: per-pixel feature = text embedding of the pixel's label name.

Layout (documented in datamanager.py and the README):
    <data>/labels/<image_stem>.png  (or .npy)  integer label id per pixel, aligned with the image
    <data>/labels.json                          {"<id>": "<name>", ...}
Label names are embedded with the same CLIP text tower that answers queries, so a query equal to a label
name lands exactly on that label's features. Pixels whose id is not in labels.json are invalid (ignored
by the latent loss). Label maps are aligned with the images on disk (any resolution); when nerfstudio
undistorts the training images, the datamanager undistorts the label maps the same way (nearest-neighbour).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor


class LabelDataError(ValueError):
    """Missing / malformed label masks or label table. Message is user-facing."""


def read_label_table(path: Path) -> Dict[int, str]:
    """labels.json -> {id: name}. Accepts {"3": "chair"} or [{"id": 3, "name": "chair"}, ...]."""
    path = Path(path)
    if not path.is_file():
        raise LabelDataError(f"label table not found: {path} (expected JSON {{\"<id>\": \"<name>\"}})")
    try:
        raw = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise LabelDataError(f"label table {path} is not valid JSON: {e}") from None
    table: Dict[int, str] = {}
    items = raw.items() if isinstance(raw, dict) else ((d.get("id"), d.get("name")) for d in raw)
    for k, v in items:
        try:
            i = int(k)
        except (TypeError, ValueError):
            raise LabelDataError(f"label table {path}: id {k!r} is not an integer") from None
        if not isinstance(v, str) or not v.strip():
            raise LabelDataError(f"label table {path}: label {i} has no name")
        table[i] = v.strip()
    if not table:
        raise LabelDataError(f"label table {path} is empty")
    return table


def find_label_map(labels_dir: Path, image_path: Path) -> Path:
    for ext in (".png", ".npy", ".tif", ".tiff"):
        p = Path(labels_dir) / (Path(image_path).stem + ext)
        if p.is_file():
            return p
    raise LabelDataError(f"no label map for image {Path(image_path).name} in {labels_dir} (expected "
                         f"{Path(image_path).stem}.png)")


def load_label_map(path: Path) -> Tensor:
    """Integer label map [H, W] (int64)."""
    path = Path(path)
    if path.suffix == ".npy":
        arr = np.load(path)
    else:
        from PIL import Image

        img = Image.open(path)
        arr = np.array(img)
    if arr.ndim == 3:
        if arr.shape[2] >= 3 and not (np.array_equal(arr[..., 0], arr[..., 1])
                                      and np.array_equal(arr[..., 0], arr[..., 2])):
            raise LabelDataError(f"label map {path} is a colour image; expected one integer id per pixel")
        arr = arr[..., 0]
    if arr.ndim != 2:
        raise LabelDataError(f"label map {path} has shape {arr.shape}; expected [H, W]")
    return torch.from_numpy(arr.astype(np.int64))


def resize_labels(ids: Tensor, hw: Tuple[int, int]) -> Tensor:
    """Nearest-neighbour resize of an id map [H, W] -> [h, w] (ids are categories, never interpolated)."""
    if tuple(ids.shape) == tuple(hw):
        return ids
    return F.interpolate(ids[None, None].double(), size=hw, mode="nearest-exact")[0, 0].long()


def compact_ids(id_maps: Sequence[Tensor], table: Dict[int, str]) -> Tuple[List[Tensor], List[int], List[str]]:
    """Map raw ids to 0..L-1 over the labels that occur in the maps AND are named; others -> -1."""
    present = sorted({int(v) for m in id_maps for v in torch.unique(m).tolist()} & set(table))
    if not present:
        raise LabelDataError("none of the label ids in the label maps is named in the label table")
    lut_size = max(max(present), max(int(m.max()) for m in id_maps)) + 1
    lut = torch.full((lut_size,), -1, dtype=torch.long)
    for j, i in enumerate(present):
        lut[i] = j
    out = []
    for m in id_maps:
        mm = m.clone()
        neg = mm < 0
        mm[neg] = 0
        c = lut[mm]
        c[neg] = -1
        out.append(c)
    return out, present, [table[i] for i in present]


def label_features(ids: Tensor, embeddings: Tensor) -> Tuple[Tensor, Tensor]:
    """ids [h, w] in -1..L-1, embeddings [L, D] -> (features [h, w, D], valid [h, w, 1] bool)."""
    valid = ids >= 0
    feats = embeddings[ids.clamp_min(0)]  # [h, w, D]
    feats = feats * valid[..., None]
    return feats, valid[..., None]


def load_label_maps(
    image_paths: Sequence[Path],
    labels_dir: Path,
    table_path: Path,
    out_sizes: Sequence[Tuple[int, int]],
    transform: Optional[Callable[[int, Tensor], Tensor]] = None,
) -> Tuple[List[Tensor], List[int], List[str]]:
    """Read every image's label map, optionally ``transform(i, ids)`` it (the datamanager resizes to the
    camera and undistorts like the images), resize to its feature size. -> (compact id maps, raw ids, names)."""
    labels_dir = Path(labels_dir)
    if not labels_dir.is_dir():
        raise LabelDataError(f"label folder not found: {labels_dir} (expected one <image_stem>.png per image)")
    table = read_label_table(table_path)
    maps = []
    for i, (p, hw) in enumerate(zip(image_paths, out_sizes)):
        ids = load_label_map(find_label_map(labels_dir, p))
        if transform is not None:
            ids = transform(i, ids)
        maps.append(resize_labels(ids, hw))
    return compact_ids(maps, table)


def embed_label_names(names: Sequence[str], text_encoder: Callable[[Sequence[str]], Tensor]) -> Tensor:
    """[L, D] unit text embeddings of the label names."""
    return F.normalize(text_encoder(list(names)).float(), dim=-1)


def undistort_label_map(ids: Tensor, K: np.ndarray, distortion_params: np.ndarray) -> Tensor:
    """Undistort + crop an id map [H, W] exactly as nerfstudio's FullImageDatamanager undistorts a
    perspective image (``_undistort_image``: OpenCV order, -0.5 principal-point shift,
    ``getOptimalNewCameraMatrix(alpha=0)``, ROI crop), but with nearest-neighbour sampling so ids are never
    blended. Pixels that map outside the source get -1 (ignored by the loss)."""
    import cv2

    p = np.asarray(distortion_params, dtype=np.float64)
    if not np.any(p):
        return ids
    if p[3] != 0:
        raise LabelDataError("label undistortion: the 4th Brown parameter (k4) is not supported (as in nerfstudio)")
    d = np.array([p[0], p[1], p[4], p[5], p[2], p[3], 0, 0], dtype=np.float64)
    K = np.array(K, dtype=np.float64).copy()
    K[0, 2] -= 0.5
    K[1, 2] -= 0.5
    H, W = ids.shape
    newK, roi = cv2.getOptimalNewCameraMatrix(K, d, (W, H), 0)
    map1, map2 = cv2.initUndistortRectifyMap(K, d, None, newK, (W, H), cv2.CV_32FC1)
    out = cv2.remap(ids.numpy().astype(np.float32), map1, map2, interpolation=cv2.INTER_NEAREST,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
    x, y, w, h = roi
    return torch.from_numpy(np.rint(out[y : y + h, x : x + w]).astype(np.int64))
