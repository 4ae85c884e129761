"""Where a run's training cameras were, in the run's normalised coordinates (what the splat lives in).

Three consumers: random starts are drawn inside the cameras' box (a captured room's interior; outside its walls the
free space is real but no shot belongs there), the volume centre of an object fills what no camera saw
(object_centre.hidden_voxels), and the standalone viewer opens at a training camera's pose. Read from the run's
config.yml (its data path -> transforms.json, plus the run's dataparser_transforms.json) or from a compact export's
``info["camera_centres"]`` / ``info["camera_poses"]``. No nerfstudio import: the config is read as text.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping, Optional, Tuple

import numpy as np

_LEGACY_COLMAP_APPLIED = [[0, 1, 0, 0], [1, 0, 0, 0], [0, 0, -1, 0]]  # nerfstudio's value for colmap data without one


def camera_poses(transforms_json: Path, dataparser_transforms_json: Path, data: Optional[Path] = None) -> np.ndarray:
    """[F, 3, 4] float64: the camera-to-world poses of a nerfstudio transforms.json's frames in the run's normalised
    coordinates, as nerfstudio's dataparser made them (OpenGL convention: x right, y up, looking along -z).

    The run's dataparser_transforms.json maps the *original* data coordinates: its transform includes the
    transforms.json's ``applied_transform`` (ns-process-data's, or nerfstudio's legacy one when ``data`` has
    colmap/sparse/0 and the file names none) and its scale the ``applied_scale``; the frames are stored after both, so
    those are taken off again (nerfstudio_dataparser.py: transform_matrix @ applied_transform, scale * applied_scale).
    ``data`` is the run's data path (a folder or the transforms.json), only for that legacy rule."""
    dp = json.loads(Path(dataparser_transforms_json).read_text())
    meta = json.loads(Path(transforms_json).read_text())
    T = np.eye(4)
    T[:3] = np.asarray(dp["transform"], dtype=np.float64).reshape(3, 4)
    applied = meta.get("applied_transform")
    if applied is None and data is not None and (Path(data) / "colmap" / "sparse" / "0").exists():
        applied = _LEGACY_COLMAP_APPLIED
    if applied is not None:
        A = np.eye(4)
        A[:3] = np.asarray(applied, dtype=np.float64).reshape(3, 4)
        T = T @ np.linalg.inv(A)  # saved (transforms.json) -> normalised, before the scale
    scale = float(dp["scale"]) / float(meta.get("applied_scale", 1.0))
    poses = np.array([np.asarray(f["transform_matrix"], dtype=np.float64).reshape(4, 4)
                      for f in meta["frames"]]).reshape(-1, 4, 4)  # [F, 4, 4]
    out = (T[None] @ poses)[:, :3, :4]
    out[:, :, 3] *= scale
    return out


def camera_centres(transforms_json: Path, dataparser_transforms_json: Path, data: Optional[Path] = None) -> np.ndarray:
    """[F, 3] float64: the centres of a nerfstudio transforms.json's frames in the run's normalised coordinates
    (:func:`camera_poses`' translations)."""
    return camera_poses(transforms_json, dataparser_transforms_json, data)[:, :, 3]


def read_run_config(config_path: Path) -> dict:
    """A nerfstudio config.yml as plain dicts and lists (the one reader of run configs): its ``!!python/object`` tags
    become dicts, ``pathlib`` tags become Paths, nothing else is constructed (no code from the file runs). YAML
    anchors resolve as usual: ns-train writes the data path once ('data: &id003 !!python/...') and refers to it."""
    import yaml

    class _Loader(yaml.SafeLoader):
        pass

    def _path(loader, suffix, node):
        return Path(*[str(p) for p in loader.construct_sequence(node, deep=True)])

    def _plain(loader, suffix, node):
        if isinstance(node, yaml.MappingNode):
            m = loader.construct_mapping(node, deep=True)
            # "!!python/object/apply:X {args, state}": the object's attributes are its state
            return m["state"] if suffix.startswith("object/apply:") and isinstance(m.get("state"), dict) else m
        if isinstance(node, yaml.SequenceNode):
            return loader.construct_sequence(node, deep=True)
        return loader.construct_scalar(node)

    _Loader.add_multi_constructor("tag:yaml.org,2002:python/object/apply:pathlib.", _path)
    _Loader.add_multi_constructor("tag:yaml.org,2002:python/", _plain)
    out = yaml.load(Path(config_path).read_text(), Loader=_Loader)
    return out if isinstance(out, dict) else {}


def run_data_path(config_path: Path) -> Optional[Path]:
    """The data path a nerfstudio config.yml was trained on, or None when the config names none or is unreadable."""
    try:
        cfg = read_run_config(config_path)
    except Exception:  # noqa: BLE001 - any malformed YAML: no data path
        return None
    data = cfg.get("data")
    if data is None:
        dm = (cfg.get("pipeline") or {}).get("datamanager") if isinstance(cfg.get("pipeline"), dict) else None
        data = dm.get("data") if isinstance(dm, dict) else None
    return data if isinstance(data, Path) else None


def training_camera_poses(config_path: Path) -> Optional[np.ndarray]:
    """[F, 3, 4] the training cameras' poses of a nerfstudio run (config.yml, see :func:`camera_poses`), or None when
    its data or dataparser transform cannot be read (a run whose dataset moved)."""
    try:
        data = run_data_path(Path(config_path))
        if data is None:
            return None
        tj = data / "transforms.json" if data.is_dir() else data
        p = camera_poses(tj, Path(config_path).parent / "dataparser_transforms.json", data)
    except (OSError, KeyError, ValueError, TypeError, IndexError, AttributeError):  # any malformed file: no cameras
        return None
    return p if len(p) and np.isfinite(p).all() else None


def training_camera_centres(config_path: Path) -> Optional[np.ndarray]:
    """[F, 3] the training cameras' centres of a nerfstudio run (config.yml), or None when its data or
    dataparser transform cannot be read (a run whose dataset moved)."""
    p = training_camera_poses(config_path)
    return None if p is None else p[:, :, 3]


def info_camera_centres(info: Mapping[str, Any]) -> Optional[np.ndarray]:
    """[F, 3] a compact export's ``info["camera_centres"]``, or None when absent or malformed."""
    v = info.get("camera_centres") if info else None
    if v is None:
        return None
    try:
        c = np.asarray(v, dtype=np.float64).reshape(-1, 3)
    except (TypeError, ValueError):
        return None
    return c if len(c) and np.isfinite(c).all() else None


def info_camera_poses(info: Mapping[str, Any]) -> Optional[np.ndarray]:
    """[F, 3, 4] a compact export's ``info["camera_poses"]`` (written by :func:`camera_info` when given poses), or None
    when absent or malformed (older exports carry only the centres)."""
    v = info.get("camera_poses") if info else None
    if v is None:
        return None
    try:
        p = np.asarray(v, dtype=np.float64).reshape(-1, 3, 4)
    except (TypeError, ValueError):
        return None
    return p if len(p) and np.isfinite(p).all() else None


def run_config_path(path: Path) -> Optional[Path]:
    """The nerfstudio config.yml a scene path stands for (the file itself, or a run folder's), or None (a checkpoint
    file, a compact export, a .ply)."""
    p = Path(path)
    if p.suffix in (".yml", ".yaml"):
        return p
    return p / "config.yml" if (p / "config.yml").is_file() else None


def scene_camera_centres(config_path: Optional[Path], info: Mapping[str, Any]) -> Optional[np.ndarray]:
    """[F, 3] a loaded scene's training cameras: the run's (config.yml -> its dataset), else what a compact export
    carries in ``info``; None when neither is there."""
    cams = training_camera_centres(config_path) if config_path is not None else None
    return cams if cams is not None else info_camera_centres(info)


def scene_camera_poses(config_path: Optional[Path], info: Mapping[str, Any]) -> Optional[np.ndarray]:
    """[F, 3, 4] a loaded scene's training-camera poses: the run's, else a compact export's ``info``; None when
    neither is there (a compact export that stores only the centres included)."""
    p = training_camera_poses(config_path) if config_path is not None else None
    return p if p is not None else info_camera_poses(info)


def camera_info(centres: np.ndarray, poses: Optional[np.ndarray] = None) -> dict:
    """What a compact export stores of its training cameras: ``camera_centres`` [F, 3] and their box grown by 0.1,
    ``start_region`` (where random starts are drawn), and ``camera_poses`` [F, 3, 4] when given, as JSON-ready lists."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    lo, hi = camera_box(c)
    out = {"camera_centres": c.tolist(), "start_region": [lo.tolist(), hi.tolist()]}
    if poses is not None:
        out["camera_poses"] = np.asarray(poses, dtype=np.float64).reshape(-1, 3, 4).tolist()
    return out


def camera_box(centres: np.ndarray, pad: float = 0.1) -> Tuple[np.ndarray, np.ndarray]:
    """(lo [3], hi [3]): the centres' bounding box grown by ``pad``."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    return c.min(0) - pad, c.max(0) + pad
