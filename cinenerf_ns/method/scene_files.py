"""Checks that turn a malformed scene file into one CheckpointError naming the file and what is wrong.

Used by ``checkpoint.py`` before anything large is allocated or any model is built: a file's size and first bytes
are checked before it is parsed, a .npz member's claimed shape is compared with its stored size before it is read,
and numpy's / torch's own advice (allow_pickle, weights_only=False) never reaches the user.
"""
from __future__ import annotations

import json
import math
import pickle
import warnings
import zipfile
import zlib
from pathlib import Path
from typing import Any, Dict, Mapping, Optional, Tuple

import numpy as np
import torch
from torch import Tensor

SUPPORTED = ("a run's config.yml, a run folder, a .ckpt, a compact export (.npz / .pt), a 3DGS .ply, "
             "or procedural[:N[:SEED]]")
COMPACT = "cinesplat compact export"
COMPACT_KEYS = ("means", "quats", "scales", "opacities")
_WIDTH = {"means": 3, "quats": 4, "scales": 3, "rgb": 3}  # per-Gaussian arrays of a fixed width: [N, width]
_ZIP = b"PK\x03\x04"
_MAX_DEFLATE_RATIO = 1100  # deflate cannot compress by more than ~1032:1; a larger claim is a corrupt archive
_MAX_CONFIG_BYTES = 16 << 20


class CheckpointError(ValueError):
    """The path holds no loadable splat checkpoint. Message is user-facing."""


def _short(e: BaseException) -> str:
    """First line of an exception's message, without library advice on unsafe loading."""
    msg = (str(e).strip().splitlines() or [""])[0].split(". ")[0][:160]
    if "weights_only" in msg or "allow_pickle" in msg or "Weights only" in msg:
        msg = ""
    return f"{type(e).__name__}: {msg}" if msg else type(e).__name__


def nonempty_size(path: Path, what: str) -> int:
    """The file's size in bytes; CheckpointError when it cannot be read or is empty."""
    try:
        size = path.stat().st_size
    except OSError as e:
        raise CheckpointError(f"cannot read {path}: {e.strerror}") from None
    if size == 0:
        raise CheckpointError(f"{path} is empty (0 bytes): not a {what}")
    return size


def _head(path: Path, n: int = 8) -> bytes:
    with open(path, "rb") as f:
        return f.read(n)


def torch_read(path: Path, what: str) -> Any:
    """torch.load(weights_only=True) of a file that must be a ``what``; every failure is a CheckpointError."""
    from cinenerf_ns.method.compat import register_torch_safe_globals

    nonempty_size(path, what)
    head = _head(path)
    if not head.startswith(_ZIP) and head[:1] != b"\x80":  # torch.save: a zip archive, or a legacy pickle
        raise CheckpointError(f"{path} is not a PyTorch file (it starts with {head[:4]!r}): not a {what}")
    if head.startswith(_ZIP):
        try:
            with zipfile.ZipFile(path) as zf:
                zip_tail(path, zf, what)
        except (zipfile.BadZipFile, OSError, EOFError) as e:
            raise CheckpointError(f"{path} is truncated or corrupt: not a readable {what} ({_short(e)})") from None
    register_torch_safe_globals()
    try:
        with warnings.catch_warnings():  # a damaged legacy file can claim any pickle protocol
            warnings.filterwarnings("ignore", message="Detected pickle protocol")
            if head.startswith(_ZIP):
                return torch.load(path, map_location="cpu", weights_only=True)
            with open(path, "rb") as f:  # the legacy format is read in order: its end must be the file's end
                blob = torch.load(f, map_location="cpu", weights_only=True)
                rest = len(f.read(1))
    except pickle.UnpicklingError as e:
        if "Weights only" in str(e):
            raise CheckpointError(f"{path} holds Python objects other than tensors, numbers and plain containers: "
                                  f"not a {what} (such files are not loaded: unpickling them could run code)") from None
        raise CheckpointError(f"{path} is truncated or corrupt: not a readable {what} ({_short(e)})") from None
    except Exception as e:  # noqa: BLE001 (torch raises RuntimeError, EOFError, ValueError... for damaged files)
        raise CheckpointError(f"{path} is truncated or corrupt: not a readable {what} ({_short(e)})") from None
    if rest:
        raise CheckpointError(f"{path} has bytes after the end of its data (a padded or concatenated file): not a "
                              f"complete {what}")
    return blob


def _npz_member(zf: zipfile.ZipFile, zi: zipfile.ZipInfo, path: Path) -> Tuple[str, np.ndarray]:
    """One array of an .npz archive, its claimed shape checked against its stored size before it is read."""
    if not zi.filename.endswith(".npy"):
        raise CheckpointError(f"{path} holds {zi.filename!r}, which is not a numpy array: not a {COMPACT}")
    key = zi.filename[:-4]
    if zi.file_size > _MAX_DEFLATE_RATIO * zi.compress_size + 4096:
        raise CheckpointError(f"{path} is corrupt: array {key!r} claims {zi.file_size} bytes from "
                              f"{zi.compress_size} compressed")
    with zf.open(zi) as f:
        version = np.lib.format.read_magic(f)
        if version not in ((1, 0), (2, 0)):
            raise CheckpointError(f"{path}: array {key!r} has an unsupported .npy version {version}")
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
        shape, _, dtype = read_header(f)
        if dtype.hasobject:
            raise CheckpointError(f"{path}: array {key!r} holds pickled Python objects: not a {COMPACT} "
                                  f"(a compact export holds only numeric arrays and an info_json string)")
        need = math.prod(shape) * dtype.itemsize
        stored = zi.file_size - f.tell()  # the data after the .npy header
        if need != stored:
            what = "truncated or corrupt" if need > stored else "padded or corrupt"
            raise CheckpointError(f"{path} is {what}: array {key!r} claims shape {tuple(shape)} ({need} bytes) but "
                                  f"stores {stored} bytes of data")
    with zf.open(zi) as f:
        return key, np.lib.format.read_array(f, allow_pickle=False)


def zip_tail(path: Path, zf: zipfile.ZipFile, what: str) -> None:
    """CheckpointError when bytes follow a zip archive's end record (a padded or concatenated file; zipfile would
    read the archive and ignore them)."""
    size = path.stat().st_size
    end = 22 + len(zf.comment)  # the end-of-central-directory record and its comment close a zip archive
    with open(path, "rb") as f:
        f.seek(max(size - end, 0))
        tail = f.read(4)
    if tail != b"PK\x05\x06":
        raise CheckpointError(f"{path} has bytes after the end of its zip archive (a padded or concatenated file): "
                              f"not a complete {what}")


def read_npz(path: Path) -> Dict[str, np.ndarray]:
    """All arrays of an .npz file (never unpickles; bounded by the archive's stored sizes)."""
    nonempty_size(path, f"{COMPACT} (.npz)")
    head = _head(path, 4)
    if head not in (_ZIP, b"PK\x05\x06"):  # a local file header, or the end record of an empty archive
        raise CheckpointError(f"{path} is not a .npz archive (it starts with {head!r}, not a zip signature): "
                              f"not a {COMPACT}")
    try:
        with zipfile.ZipFile(path) as zf:
            zip_tail(path, zf, f"{COMPACT} (.npz)")
            names = [zi.filename for zi in zf.infolist()]
            dup = sorted({n for n in names if names.count(n) > 1})
            if dup:
                raise CheckpointError(f"{path} holds {', '.join(map(repr, dup[:4]))} more than once: an inconsistent "
                                      f"archive, not a {COMPACT}")
            return dict(_npz_member(zf, zi, path) for zi in zf.infolist())
    except CheckpointError:
        raise
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, MemoryError) as e:
        raise CheckpointError(f"{path} is truncated or corrupt: not a complete .npz archive ({_short(e)})") from None


def compact_npz(path: Path) -> Tuple[Dict[str, Tensor], Dict[str, Tensor], Dict[str, Any]]:
    """(arrays, codec state, info) of a .npz compact export, checked (see check_splat)."""
    z = read_npz(path)
    want = f"a {COMPACT} holds {', '.join(COMPACT_KEYS)} and info_json"
    if not z:
        raise CheckpointError(f"{path} holds no arrays: not a {COMPACT} ({want})")
    missing = [k for k in (*COMPACT_KEYS, "info_json") if k not in z]
    if missing:
        raise CheckpointError(f"{path} has no {', '.join(missing)}: not a {COMPACT} ({want}; found {sorted(z)[:12]})")
    info_arr = z["info_json"]
    if info_arr.ndim != 0 or info_arr.dtype.kind not in "US":
        raise CheckpointError(f"{path}: info_json must be one text string, got {info_arr.dtype} {info_arr.shape}")
    info = parse_info(str(info_arr[()]), path)
    for k, v in z.items():
        if k != "info_json" and v.dtype.kind not in "fiu":
            raise CheckpointError(f"{path}: array {k!r} holds {v.dtype} values, not numbers")
    arrays = {k: torch.from_numpy(v.astype(np.float32)) for k, v in z.items()
              if k != "info_json" and not k.startswith("codec.")}
    codec = {k[len("codec."):]: torch.from_numpy(v.astype(np.float32)) for k, v in z.items() if k.startswith("codec.")}
    return arrays, codec, info


def compact_blob(blob: Any, path: Path) -> Tuple[Dict[str, Tensor], Dict[str, Tensor], Dict[str, Any]]:
    """(arrays, codec state, info) of a torch.save'd compact export, checked."""
    if not isinstance(blob, dict):
        raise CheckpointError(f"{path} holds a {type(blob).__name__}: not a {COMPACT} "
                              f"(a dict with format 'cinesplat-compact')")
    if blob.get("format") != "cinesplat-compact":
        raise CheckpointError(f"{path} is not a {COMPACT} (no format 'cinesplat-compact'; keys: "
                              f"{sorted(map(str, blob))[:12]})")
    arrays, codec = blob.get("arrays"), blob.get("codec") or {}
    for name, d in (("arrays", arrays), ("codec", codec)):
        if not isinstance(d, dict) or not all(isinstance(v, Tensor) for v in d.values()):
            raise CheckpointError(f"{path}: '{name}' must be a dict of tensors in a {COMPACT}")
    missing = [k for k in COMPACT_KEYS if k not in arrays]
    if missing:
        raise CheckpointError(f"{path} has no {', '.join(missing)} array: not a complete {COMPACT}")
    if not isinstance(blob.get("info_json"), str):
        raise CheckpointError(f"{path} has no info_json text: not a complete {COMPACT}")
    return arrays, codec, parse_info(blob["info_json"], path)


def parse_info(text: str, path: Path) -> Dict[str, Any]:
    """A compact export's info_json: a JSON object whose optional start_region is two 3-vectors."""
    try:
        info = json.loads(text)
    except ValueError as e:
        raise CheckpointError(f"{path}: info_json is not valid JSON ({_short(e)})") from None
    if not isinstance(info, dict):
        raise CheckpointError(f"{path}: info_json must be a JSON object, got {type(info).__name__}")
    check_info(info, path, "info_json")
    return info


def _numbers(v: Any, shape: Tuple[int, ...]) -> Optional[np.ndarray]:
    """``v`` as a finite float64 array whose shape matches ``shape`` (-1: any length >= 1), else None."""
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        return None
    ok = a.ndim == len(shape) and all(w in (-1, d) for w, d in zip(shape, a.shape)) and a.size > 0
    return a if ok and np.isfinite(a).all() else None


def check_info(info: Mapping[str, Any], path: Path, where: str) -> None:
    """A scene's metadata (a compact export's info_json, a run's cine_info): start_region two finite 3-vectors with
    lo < hi, planning_region {"lo", "hi"} a box by the planner's rules (check_planning_region), camera_centres
    [F, 3] and camera_poses [F, 3, 4] finite, label_names a list of strings. CheckpointError
    naming the field otherwise (none of it is replaced silently)."""
    sr = info.get("start_region")
    if sr is not None:
        a = _numbers(sr, (2, 3))
        if a is None:
            raise CheckpointError(f"{path}: {where}'s start_region must be [[x, y, z], [x, y, z]] (lo, hi), finite")
        if not (a[0] < a[1]).all():
            axes = ", ".join("xyz"[i] for i in np.flatnonzero(a[0] >= a[1]))
            raise CheckpointError(f"{path}: {where}'s start_region is inverted or empty along {axes} (lo "
                                  f"{a[0].tolist()} must be below hi {a[1].tolist()} on every axis)")
    if info.get("planning_region") is not None:
        check_planning_region(info["planning_region"], path, where)
    for key, shape, want in (("camera_centres", (-1, 3), "[F, 3] finite camera centres"),
                             ("camera_poses", (-1, 3, 4), "[F, 3, 4] finite camera-to-world poses")):
        if info.get(key) is not None and _numbers(info[key], shape) is None:
            raise CheckpointError(f"{path}: {where}'s {key} must be {want}")
    names = info.get("label_names")
    if names is not None and not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
        raise CheckpointError(f"{path}: {where}'s label_names must be a list of strings")


def check_planning_region(reg: Any, path: Path, where: str) -> None:
    """A stored planning region (export_compact's planning_region): {"lo": [x, y, z], "hi": [x, y, z]}, finite, lo
    below hi on every axis (the planner's rule for a user box, user_box.user_box); CheckpointError naming the
    field otherwise."""
    from cinenerf_ns.planner.errors import InvalidInputError
    from cinenerf_ns.planner.scene.user_box import user_box

    if not isinstance(reg, Mapping) or not {"lo", "hi"} <= set(reg):
        raise CheckpointError(f'{path}: {where}\'s planning_region must be {{"lo": [x, y, z], "hi": [x, y, z]}}, got '
                              f"{str(reg)[:80]}")
    try:
        user_box((reg["lo"], reg["hi"]), f"{where}'s planning_region")
    except InvalidInputError as e:
        raise CheckpointError(f"{path}: {e}") from None


def check_semantics(path: Path, latents: Optional[Tensor], codec: Any, info: Mapping[str, Any],
                    label_embeddings: Optional[Tensor]) -> None:
    """The semantic parts agree: latents as wide as the codec's input, one label embedding per label name, label
    embeddings as wide as the codec's features. CheckpointError naming the fields otherwise."""
    if codec is not None and latents is not None:
        width = int(getattr(codec.config, "latent_dim", latents.shape[-1]))
        if latents.ndim != 2 or latents.shape[1] != width:
            raise CheckpointError(f"{path}: latents are {tuple(latents.shape)} but the codec decodes latents of width "
                                  f"{width} (codec_config.latent_dim): the scene's latents and codec do not belong "
                                  f"together")
    names = info.get("label_names") or []
    if label_embeddings is not None and label_embeddings.numel() > 0:
        if names and label_embeddings.shape[0] != len(names):
            raise CheckpointError(f"{path}: label_embeddings has {label_embeddings.shape[0]} rows but label_names "
                                  f"lists {len(names)} names (one embedding per name)")
        dim = getattr(codec, "feature_dim", None)
        if dim is not None and label_embeddings.shape[-1] != dim:
            raise CheckpointError(f"{path}: label_embeddings are {label_embeddings.shape[-1]} wide but the codec's "
                                  f"features are {dim} wide (feature_dim)")


def check_splat(arrays: Mapping[str, Any], path: Path) -> int:
    """Check per-Gaussian tensors (means, quats, scales, opacities; rgb, features_dc, latents if present): numeric,
    of the right shape and row count, at least one Gaussian whose parameters are all finite. Returns N."""
    for k in COMPACT_KEYS:
        if not isinstance(arrays.get(k), Tensor):
            raise CheckpointError(f"{path} has no {k} tensor (a splat needs {', '.join(COMPACT_KEYS)})")
    for k, t in arrays.items():
        if t is not None and (not isinstance(t, Tensor) or t.dtype in (torch.bool,) or t.is_complex()):
            raise CheckpointError(f"{path}: {k} must be a tensor of numbers, got {getattr(t, 'dtype', type(t))}")
    means = arrays["means"]
    if means.ndim != 2 or means.shape[1] != 3:
        raise CheckpointError(f"{path}: means must be [N, 3] (one 3D position per Gaussian), got {tuple(means.shape)}")
    n = int(means.shape[0])
    if n == 0:
        raise CheckpointError(f"{path} holds 0 Gaussians (means is empty)")
    for k in ("quats", "scales", "opacities", "rgb", "features_dc", "latents"):
        t = arrays.get(k)
        if t is None:
            continue
        if t.ndim == 0 or t.shape[0] != n:
            raise CheckpointError(f"{path}: {k} has {t.shape[0] if t.ndim else 0} rows but means has {n} "
                                  f"(one row per Gaussian)")
        w = _WIDTH.get(k)
        bad = (k == "opacities" and t.numel() != n) or (w is not None and tuple(t.shape) != (n, w))
        if bad or (k == "latents" and t.ndim != 2):
            want = "[N] or [N, 1]" if k == "opacities" else f"[N, {w}]" if w else "[N, D]"
            raise CheckpointError(f"{path}: {k} must be {want}, got {tuple(t.shape)}")
    lab = arrays.get("label_embeddings")
    if lab is not None and lab.ndim != 2:
        raise CheckpointError(f"{path}: label_embeddings must be [L, D], got {tuple(lab.shape)}")
    q = arrays["quats"].float()
    usable = (torch.isfinite(means).all(-1) & torch.isfinite(q).all(-1) & (q.norm(dim=-1) > 1e-12)
              & torch.isfinite(arrays["opacities"].reshape(n)) & ~torch.isnan(arrays["scales"]).any(-1))
    if not bool(usable.any()):
        raise CheckpointError(f"{path} has no usable Gaussians: all {n} have NaN/inf positions or parameters "
                              f"(or zero rotations)")
    return n


def check_config_yml(path: Path) -> None:
    """A run's config.yml must be non-empty, readable text and valid YAML (its nerfstudio tags are not built)."""
    size = nonempty_size(path, "nerfstudio config.yml (ns-train writes it into the run folder)")
    if size > _MAX_CONFIG_BYTES:
        raise CheckpointError(f"{path} is {size} bytes: too large to be a nerfstudio config.yml")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise CheckpointError(f"{path} is not a text file (not UTF-8): not a nerfstudio config.yml") from None
    if not text.strip():
        raise CheckpointError(f"{path} is empty (only whitespace): not a nerfstudio config.yml")
    try:
        import yaml
    except ImportError:  # pragma: no cover (pyyaml is a dependency)
        return
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)  # syntax only: tags are not constructed
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(e, "problem", None) or "parse error"
        raise CheckpointError(f"{path} is not valid YAML ({problem}{where})") from None
    if node is not None and not isinstance(node, yaml.MappingNode):
        raise CheckpointError(f"{path} is not a nerfstudio config.yml (its top level is not a mapping)")
