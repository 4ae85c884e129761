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
from typing import Any, Dict, Mapping, Tuple

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
    register_torch_safe_globals()
    try:
        with warnings.catch_warnings():  # a damaged legacy file can claim any pickle protocol
            warnings.filterwarnings("ignore", message="Detected pickle protocol")
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        if "Weights only" in str(e):
            raise CheckpointError(f"{path} holds Python objects other than tensors, numbers and plain containers: "
                                  f"not a {what} (such files are not loaded: unpickling them could run code)") from None
        raise CheckpointError(f"{path} is truncated or corrupt: not a readable {what} ({_short(e)})") from None
    except Exception as e:  # noqa: BLE001 (torch raises RuntimeError, EOFError, ValueError... for damaged files)
        raise CheckpointError(f"{path} is truncated or corrupt: not a readable {what} ({_short(e)})") from None


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
        if need > zi.file_size:
            raise CheckpointError(f"{path} is truncated or corrupt: array {key!r} claims shape {tuple(shape)} "
                                  f"({need} bytes) but stores {zi.file_size} bytes")
    with zf.open(zi) as f:
        return key, np.lib.format.read_array(f, allow_pickle=False)


def read_npz(path: Path) -> Dict[str, np.ndarray]:
    """All arrays of an .npz file (never unpickles; bounded by the archive's stored sizes)."""
    nonempty_size(path, f"{COMPACT} (.npz)")
    head = _head(path, 4)
    if head not in (_ZIP, b"PK\x05\x06"):  # a local file header, or the end record of an empty archive
        raise CheckpointError(f"{path} is not a .npz archive (it starts with {head!r}, not a zip signature): "
                              f"not a {COMPACT}")
    try:
        with zipfile.ZipFile(path) as zf:
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
    sr = info.get("start_region")
    if sr is not None:
        try:
            ok = np.asarray(sr, dtype=np.float64).shape == (2, 3) and np.isfinite(np.asarray(sr, np.float64)).all()
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise CheckpointError(f"{path}: info_json's start_region must be [[x, y, z], [x, y, z]] (lo, hi)")
    names = info.get("label_names")
    if names is not None and not (isinstance(names, list) and all(isinstance(n, str) for n in names)):
        raise CheckpointError(f"{path}: info_json's label_names must be a list of strings")
    return info


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
