"""Tiny open_clip architectures (random weights, real code paths and tokenizer) so CPU tests are fast."""
from __future__ import annotations

import json

import pytest
import torch

# The CI / dev box has 2 cores shared by several jobs: one intra-op thread avoids heavy oversubscription
# (a 2-thread codec fit ran ~9x slower than a 1-thread one under load).
torch.set_num_threads(1)

TINY_VIT = "CineTiny-ViT"
TINY_RN = "CineTiny-RN"
_TEXT = {"context_length": 77, "vocab_size": 49408, "width": 64, "heads": 2, "layers": 1}


@pytest.fixture(scope="session")
def tiny_clip_models(tmp_path_factory):
    import open_clip

    d = tmp_path_factory.mktemp("open_clip_cfg")
    (d / f"{TINY_VIT}.json").write_text(
        json.dumps({"embed_dim": 32, "vision_cfg": {"image_size": 64, "layers": 2, "width": 64, "patch_size": 16}, "text_cfg": _TEXT})
    )
    (d / f"{TINY_RN}.json").write_text(
        json.dumps({"embed_dim": 32, "vision_cfg": {"image_size": 64, "layers": [1, 1, 1, 1], "width": 8, "patch_size": None}, "text_cfg": _TEXT})
    )
    open_clip.add_model_config(d)
    return TINY_VIT, TINY_RN
