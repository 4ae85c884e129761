"""`ns-train cinesplat`'s own numbers: every numeric field has a range, and a number out of it stops ns-train with one
line naming the flag before config.yml is written or any data is read."""
from __future__ import annotations

import dataclasses

import pytest

from cinenerf_ns.method.clip_features import ClipFeatureConfig
from cinenerf_ns.method.codec import CodecConfig
from cinenerf_ns.method.config_ranges import RANGES, check_training_config
from cinenerf_ns.method.model import CineSplatModelConfig
from cinenerf_ns.planner.errors import InvalidInputError


def _own_numeric_fields(cls, base=None):
    skip = {f.name for f in dataclasses.fields(base)} if base is not None else set()
    for f in dataclasses.fields(cls):
        if f.name not in skip and f.type in ("int", "float", int, float):
            yield f.name


def test_every_number_cinesplat_adds_has_a_range():
    from nerfstudio.models.splatfacto import SplatfactoModelConfig

    missing = [(c.__name__, n) for c, base in ((CineSplatModelConfig, SplatfactoModelConfig), (ClipFeatureConfig, None),
                                               (CodecConfig, None))
               for n in _own_numeric_fields(c, base) if (c, n) not in RANGES]
    assert missing == []


def test_the_defaults_are_in_range():
    from cinenerf_ns.method.cinesplat_config import make_cinesplat_config

    for lite in (False, True):
        cfg = make_cinesplat_config(lite)
        check_training_config(cfg.pipeline.model, cfg.pipeline.datamanager)


@pytest.mark.parametrize("where,name,value,flag", [
    ("model", "latent_every", 0, "--pipeline.model.latent-every"),
    ("model", "latent_every", 1.5, "--pipeline.model.latent-every"),
    ("model", "latent_loss_weight", float("nan"), "--pipeline.model.latent-loss-weight"),
    ("model", "relevancy_threshold", 0.0, "--pipeline.model.relevancy-threshold"),
    ("clip", "feature_long_side", -5, "--pipeline.datamanager.clip.feature-long-side"),
    ("clip", "input_long_sides", (448, 0), "--pipeline.datamanager.clip.input-long-sides"),
    ("clip", "input_long_sides", (), "--pipeline.datamanager.clip.input-long-sides"),
    ("codec", "batch_size", 0, "--pipeline.datamanager.codec.batch-size"),
    ("codec", "lr", float("inf"), "--pipeline.datamanager.codec.lr"),
])
def test_out_of_range_names_the_flag(where, name, value, flag):
    from cinenerf_ns.method.cinesplat_config import make_cinesplat_config

    cfg = make_cinesplat_config()
    target = {"model": cfg.pipeline.model, "clip": cfg.pipeline.datamanager.clip,
              "codec": cfg.pipeline.datamanager.codec}[where]
    setattr(target, name, value)
    with pytest.raises(InvalidInputError, match=flag.replace(".", r"\.")):
        check_training_config(cfg.pipeline.model, cfg.pipeline.datamanager)
    with pytest.raises(SystemExit) as e:
        cfg.setup()
    assert e.value.code == 2


# ns-train itself stopping before it writes anything: tests/method/test_ns_train_cli.py
