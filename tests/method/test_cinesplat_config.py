"""cinesplat configs: yaml round trip (as ns-train's config.yml) and docstrings on every new field. The import chain
that registers the torch safe globals before stock eval_setup's torch.load: tests/method/test_ns_train_cli.py."""
from __future__ import annotations

import dataclasses

import pytest
import yaml

from cinenerf_ns.method.cinesplat_config import cinesplat, cinesplat_lite
from cinenerf_ns.method.clip_features import ClipFeatureConfig
from cinenerf_ns.method.codec import CodecConfig
from cinenerf_ns.method.datamanager import CineSplatDatamanagerConfig
from cinenerf_ns.method.model import CineSplatModelConfig


def test_yaml_roundtrip():
    for spec in (cinesplat, cinesplat_lite):
        cfg = spec.config
        text = yaml.dump(cfg)  # what TrainerConfig.save_config writes
        back = yaml.load(text, Loader=yaml.Loader)
        assert back == cfg
        assert "cinenerf_ns.method.model.CineSplatModelConfig" in text
    assert cinesplat_lite.config.max_num_iterations < cinesplat.config.max_num_iterations
    assert "latents" in cinesplat.config.optimizers


@pytest.mark.parametrize("cls", [CineSplatModelConfig, CineSplatDatamanagerConfig, ClipFeatureConfig, CodecConfig])
def test_every_new_field_has_a_docstring(cls):
    from tyro._docstrings import get_field_docstring

    parent_fields = set()
    for base in cls.__mro__[1:]:
        if dataclasses.is_dataclass(base):
            parent_fields |= {f.name for f in dataclasses.fields(base)}
    new = [f.name for f in dataclasses.fields(cls) if f.name not in parent_fields and not f.name.startswith("_")]
    assert new
    for name in new:
        doc = get_field_docstring(cls, name, ())
        assert doc and len(doc.strip()) > 10, f"{cls.__name__}.{name} has no docstring"


# test_yaml_load_of_config_registers_safe_globals and test_ns_train_help_lists_cinesplat: tests/method/
# test_ns_train_cli.py (one Python process for them and ns-train's range stop)
