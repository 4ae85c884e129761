"""Per-image feature maps computed once before training and cached on disk; then codec + latent targets.

Cache key = sha256 over (for every train image in order: file name, size, mtime_ns; the in-memory image
shape) + feature source + every setting that changes the features (CLIP model / weights / scales / feature
resolution; label folder files' names, sizes, mtimes and the label table's content). Any change -> new key
-> recompute; same key -> reuse. One file per key: <cache_dir>/<source>-<key16>.pt, loaded with
``weights_only=True``. Feature maps are stored in float16 (unit vectors: 1e-3 precision is plenty).
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import torch
from torch import Tensor

from cinenerf_ns.method.clip_features import ClipFeatureConfig, DenseClipExtractor, make_text_encoder
from cinenerf_ns.method.codec import CodecConfig, FeatureCodec, train_codec
from cinenerf_ns.method.feature_grid import feature_map_size

CACHE_VERSION = 1


def _stat_entry(p: Path) -> list:
    try:
        st = os.stat(p)
        return [Path(p).name, int(st.st_size), int(st.st_mtime_ns)]
    except OSError:
        return [Path(p).name, -1, -1]


def cache_key(image_paths: Sequence[Path], image_sizes: Sequence[Tuple[int, int]], settings: dict) -> str:
    h = hashlib.sha256()
    h.update(json.dumps({"v": CACHE_VERSION, "settings": settings}, sort_keys=True, default=str).encode())
    for p, hw in zip(image_paths, image_sizes):
        h.update(json.dumps([_stat_entry(p), list(hw)]).encode())
    return h.hexdigest()


def _progress(desc: str, total: int):
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    bar = Progress(TextColumn(desc, style="bold", markup=False), BarColumn(), MofNCompleteColumn(),
                   TimeRemainingColumn())
    return bar, total


@dataclass
class FeatureMaps:
    """What the cache stores for one key."""

    source: str
    features: List[Tensor] = field(default_factory=list)  # clip: per image [h, w, D] float16
    label_ids: List[Tensor] = field(default_factory=list)  # labels: per image [h, w] int (-1 = unnamed)
    label_names: List[str] = field(default_factory=list)
    label_raw_ids: List[int] = field(default_factory=list)
    label_embeddings: Optional[Tensor] = None  # labels: [L, D]
    feature_dim: int = 0
    seconds: float = 0.0

    def feature_map(self, i: int) -> Tuple[Tensor, Tensor]:
        """(features [h, w, D] float32, valid [h, w, 1] bool) of image i."""
        if self.source == "labels":
            from cinenerf_ns.method.label_features import label_features

            return label_features(self.label_ids[i], self.label_embeddings.float())  # type: ignore[union-attr]
        f = self.features[i].float()
        return f, torch.ones(*f.shape[:2], 1, dtype=torch.bool)

    def to_dict(self) -> dict:
        return {
            "source": self.source,
            "features": self.features,
            "label_ids": self.label_ids,
            "label_names": self.label_names,
            "label_raw_ids": self.label_raw_ids,
            "label_embeddings": self.label_embeddings,
            "feature_dim": self.feature_dim,
            "seconds": self.seconds,
        }


def compute_clip_maps(
    images: Sequence[Callable[[], Tensor]],
    sizes: Sequence[Tuple[int, int]],
    clip_config: ClipFeatureConfig,
    device: torch.device | str,
    progress: bool = True,
    extractor: Optional[DenseClipExtractor] = None,
) -> FeatureMaps:
    ext = extractor or DenseClipExtractor(clip_config, device)
    feats: List[Tensor] = []
    t0 = time.perf_counter()
    bar = None
    if progress:
        bar, _ = _progress(f"CLIP features ({clip_config.model_name})", len(images))
        bar.start()
        task = bar.add_task("", total=len(images))
    try:
        for i, (get, hw) in enumerate(zip(images, sizes)):
            f = ext.extract(get(), out_hw=feature_map_size(hw[0], hw[1], clip_config.feature_long_side))
            feats.append(f.half().cpu())
            if bar is not None:
                bar.update(task, completed=i + 1)
    finally:
        if bar is not None:
            bar.stop()
    if torch.device(device).type == "cuda":
        torch.cuda.synchronize()
    return FeatureMaps(source="clip", features=feats, feature_dim=ext.feature_dim, seconds=time.perf_counter() - t0)


def compute_label_maps(
    image_paths: Sequence[Path],
    sizes: Sequence[Tuple[int, int]],
    feature_long_side: int,
    labels_dir: Path,
    labels_json: Path,
    text_encoder: Callable[[Sequence[str]], Tensor],
    label_transform: Optional[Callable[[int, Tensor], Tensor]] = None,
) -> FeatureMaps:
    from cinenerf_ns.method.label_features import embed_label_names, load_label_maps

    t0 = time.perf_counter()
    out_sizes = [feature_map_size(h, w, feature_long_side) for h, w in sizes]
    ids, raw, names = load_label_maps(image_paths, labels_dir, labels_json, out_sizes, transform=label_transform)
    emb = embed_label_names(names, text_encoder).cpu()
    return FeatureMaps(
        source="labels",
        label_ids=[m.to(torch.int16) for m in ids],
        label_names=list(names),
        label_raw_ids=[int(i) for i in raw],
        label_embeddings=emb,
        feature_dim=int(emb.shape[1]),
        seconds=time.perf_counter() - t0,
    )


def load_or_compute(
    key: str, cache_dir: Path, source: str, compute: Callable[[], FeatureMaps], log: Callable[[str], None] = print
) -> Tuple[FeatureMaps, bool]:
    """(maps, hit). Reuses <cache_dir>/<source>-<key16>.pt when its stored key matches, else computes + writes."""
    cache_dir = Path(cache_dir)
    path = cache_dir / f"{source}-{key[:16]}.pt"
    if path.is_file():
        try:
            blob = torch.load(path, map_location="cpu", weights_only=True)
            if blob.get("key") == key:
                d = blob["maps"]
                d["label_ids"] = [m.long() for m in d["label_ids"]]
                log(f"cinesplat: reusing cached {source} features {path}")
                return FeatureMaps(**d), True
        except Exception as e:  # corrupt / old format: recompute
            log(f"cinesplat: ignoring unreadable feature cache {path} ({type(e).__name__})")
    maps = compute()
    cache_dir.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    d = maps.to_dict()
    torch.save({"key": key, "maps": d}, tmp)
    os.replace(tmp, path)  # atomic: a killed run never leaves a half-written cache under the real name
    log(f"cinesplat: wrote {source} feature cache {path} ({maps.seconds:.1f}s)")
    maps.label_ids = [m.long() for m in maps.label_ids]
    return maps, False


@dataclass
class SemanticTargets:
    latent_targets: List[Tensor]  # per image [h, w, 3] float32
    latent_valid: List[Tensor]  # per image [h, w, 1] bool
    codec: FeatureCodec
    info: dict  # plain python: stored in the model checkpoint (extra state)
    label_embeddings: Optional[Tensor]
    stats: dict
    cache_hit: bool = False


def prepare_semantic_targets(
    images: Sequence[Callable[[], Tensor]],
    image_paths: Sequence[Path],
    image_sizes: Sequence[Tuple[int, int]],
    source: str,
    clip_config: ClipFeatureConfig,
    codec_config: CodecConfig,
    cache_dir: Path,
    data_dir: Path,
    labels_dir: str = "labels",
    labels_json: str = "labels.json",
    device: torch.device | str = "cpu",
    progress: bool = True,
    log: Callable[[str], None] = print,
    label_transform: Optional[Callable[[int, Tensor], Tensor]] = None,
    label_transform_key: str = "",
) -> SemanticTargets:
    """Features (cached) -> codec (eq. 2) -> per-image latent targets f_enc(P)."""
    settings: Dict = {"source": source}
    if source == "clip":
        c = asdict(clip_config)
        c.pop("half_precision", None)  # fp16 vs fp32 on another device: same features within tolerance
        settings["clip"] = c
        compute = lambda: compute_clip_maps(images, image_sizes, clip_config, device, progress)  # noqa: E731
        label_dir_path = None
    elif source == "labels":
        label_dir_path = Path(labels_dir) if Path(labels_dir).is_absolute() else Path(data_dir) / labels_dir
        table_path = Path(labels_json) if Path(labels_json).is_absolute() else Path(data_dir) / labels_json
        settings["text"] = clip_config.spec()
        settings["feature_long_side"] = clip_config.feature_long_side
        settings["table"] = table_path.read_text() if table_path.is_file() else None
        settings["label_files"] = (sorted(_stat_entry(p) for p in label_dir_path.glob("*"))
                                   if label_dir_path.is_dir() else [])
        settings["label_transform"] = label_transform_key  # e.g. the cameras' distortion (undistortion changes ids)

        def compute() -> FeatureMaps:
            # a few label names: the text tower runs on the CPU, so setup never holds a float32 CLIP on the GPU
            enc = make_text_encoder(clip_config, "cpu")
            return compute_label_maps(
                image_paths, image_sizes, clip_config.feature_long_side, label_dir_path, table_path, enc,
                label_transform
            )

    else:
        raise ValueError(f"unknown feature_source {source!r} (expected 'clip' or 'labels')")
    key = cache_key(image_paths, image_sizes, settings)
    maps, hit = load_or_compute(key, cache_dir, source, compute, log=log)

    # ---- codec (eq. 2) on the features
    if source == "labels":
        # every label that occurs, equally weighted: a small object's label must decode as well as the
        # wall's (pixel-count weighting starved rare labels in tests)
        train_x, weights = maps.label_embeddings.float(), None  # type: ignore[union-attr]
    else:
        train_x = torch.cat([f.reshape(-1, f.shape[-1]) for f in maps.features]).float()
        weights = None
    codec, stats = train_codec(train_x, codec_config, device=device, progress=progress, weights=weights)
    stats["feature_seconds"] = maps.seconds
    stats["cache_hit"] = hit

    # ---- latent targets f_enc(P)
    targets, valids = [], []
    with torch.no_grad():
        for i in range(len(image_sizes)):
            f, v = maps.feature_map(i)
            lat = codec.encode(f.to(device)).cpu() * v  # invalid pixels -> 0 (masked in the loss anyway)
            targets.append(lat)
            valids.append(v)
    info = {
        "feature_dim": int(maps.feature_dim),
        "codec_config": asdict(codec_config),
        "codec_backend": codec.backend,
        "feature_long_side": int(clip_config.feature_long_side),
        "source": source,
        "clip": clip_config.spec(),
        "label_names": list(maps.label_names) if source == "labels" else [],
        "label_ids": [int(i) for i in maps.label_raw_ids] if source == "labels" else [],
        "cache_key": key,
    }
    return SemanticTargets(
        latent_targets=targets,
        latent_valid=valids,
        codec=codec,
        info=info,
        label_embeddings=maps.label_embeddings if source == "labels" else None,
        stats=stats,
        cache_hit=hit,
    )
