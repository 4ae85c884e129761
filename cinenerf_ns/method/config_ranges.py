"""The allowed range of every number `ns-train cinesplat` adds to splatfacto's options (``--pipeline.model.*``,
``--pipeline.datamanager.clip.*``, ``--pipeline.datamanager.codec.*``), checked when the trainer is set up: before the
dataset is read, CLIP features are extracted or the codec is fitted. A test holds every numeric field of these
configs to an entry here, so a new one cannot arrive unchecked. splatfacto's own options are nerfstudio's."""
from __future__ import annotations

import dataclasses
from typing import Any, Dict, Iterator, NamedTuple, Tuple

from cinenerf_ns.options import check_number

from .clip_features import ClipFeatureConfig
from .codec import CodecConfig
from .model import CineSplatModelConfig


class Range(NamedTuple):
    lo: float
    hi: float
    integer: bool = False
    lo_open: bool = False  # (lo, hi] instead of [lo, hi]


SEED = Range(0, 2**31 - 1, integer=True)

RANGES: Dict[Tuple[type, str], Range] = {
    (CineSplatModelConfig, "latent_start_step"): Range(0, 10**9, integer=True),
    (CineSplatModelConfig, "latent_loss_weight"): Range(0.0, 1e6),
    (CineSplatModelConfig, "latent_every"): Range(1, 10**6, integer=True),
    (CineSplatModelConfig, "relevancy_temperature"): Range(0.0, 1e4, lo_open=True),
    (CineSplatModelConfig, "relevancy_threshold"): Range(0.0, 1.0, lo_open=True),
    (ClipFeatureConfig, "random_seed"): SEED,
    # a feature map of one pixel carries no layout; beyond 4096 px a map outgrows any GPU's memory per image
    (ClipFeatureConfig, "feature_long_side"): Range(2, 4096, integer=True),
    (CodecConfig, "latent_dim"): Range(1, 64, integer=True),
    (CodecConfig, "hidden_dim"): Range(1, 4096, integer=True),
    (CodecConfig, "num_layers"): Range(0, 64, integer=True),
    (CodecConfig, "train_steps"): Range(0, 10**7, integer=True),
    (CodecConfig, "batch_size"): Range(1, 2**24, integer=True),
    (CodecConfig, "lr"): Range(0.0, 10.0, lo_open=True),
    (CodecConfig, "max_samples"): Range(1, 10**9, integer=True),
    (CodecConfig, "seed"): SEED,
}
"""(config, field) -> allowed values of the numbers cinesplat adds to ns-train."""

# ClipFeatureConfig.input_long_sides: a tuple of sizes, each in this range
INPUT_LONG_SIDE = Range(16, 8192, integer=True)


def _checked(prefix: str, cfg: Any) -> Iterator[Tuple[str, Any, Range]]:
    for f in dataclasses.fields(cfg):
        rng = RANGES.get((type(cfg), f.name))
        if rng is not None:
            yield f"{prefix}.{f.name.replace('_', '-')}", getattr(cfg, f.name), rng


def check_training_config(model: Any, datamanager: Any) -> None:
    """InvalidInputError naming the ns-train flag and its range for the first number out of RANGES in the model's
    and the datamanager's cinesplat configs."""
    items = list(_checked("--pipeline.model", model)) if isinstance(model, CineSplatModelConfig) else []
    clip, codec = getattr(datamanager, "clip", None), getattr(datamanager, "codec", None)
    if isinstance(clip, ClipFeatureConfig):
        items += _checked("--pipeline.datamanager.clip", clip)
        sides = tuple(clip.input_long_sides) if isinstance(clip.input_long_sides, (tuple, list)) else ()
        if not sides:
            check_number(None, "--pipeline.datamanager.clip.input-long-sides (at least one size)",
                         INPUT_LONG_SIDE.lo, INPUT_LONG_SIDE.hi, integer=True)
        items += [("--pipeline.datamanager.clip.input-long-sides", s, INPUT_LONG_SIDE) for s in sides]
    if isinstance(codec, CodecConfig):
        items += _checked("--pipeline.datamanager.codec", codec)
    for flag, value, rng in items:
        check_number(value, flag, rng.lo, rng.hi, rng.lo_open, rng.integer)
