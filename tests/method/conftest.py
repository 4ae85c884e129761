"""Tiny open_clip architectures (random weights, real code paths and tokenizer) so CPU tests are fast."""
from __future__ import annotations

import json
import math

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
        json.dumps({"embed_dim": 32, "vision_cfg": {"image_size": 64, "layers": 2, "width": 64, "patch_size": 16},
                    "text_cfg": _TEXT})
    )
    (d / f"{TINY_RN}.json").write_text(
        json.dumps({"embed_dim": 32, "vision_cfg": {"image_size": 64, "layers": [1, 1, 1, 1], "width": 8,
                                                    "patch_size": None}, "text_cfg": _TEXT})
    )
    open_clip.add_model_config(d)
    return TINY_VIT, TINY_RN


@pytest.fixture
def tiny_scene():
    """Factory: write a tiny nerfstudio-format capture (random images, cameras on a circle) into a folder."""
    import numpy as np
    from PIL import Image

    def make(root, n=5, w=32, h=24):
        (root / "images").mkdir(parents=True)
        g = np.random.default_rng(0)
        frames = []
        for i in range(n):
            Image.fromarray(g.integers(0, 255, (h, w, 3), dtype=np.uint8)).save(root / "images" / f"frame_{i:03d}.png")
            a = 2 * math.pi * i / n
            c2w = np.eye(4)
            c2w[:3, 3] = [3 * math.cos(a), 3 * math.sin(a), 0.5]
            z = c2w[:3, 3] / np.linalg.norm(c2w[:3, 3])  # camera looks along -z: z points away from the origin
            x = np.cross([0, 0, 1], z)
            x /= np.linalg.norm(x)
            c2w[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
            frames.append({"file_path": f"images/frame_{i:03d}.png", "transform_matrix": c2w.tolist()})
        meta = {"fl_x": 30.0, "fl_y": 30.0, "cx": w / 2, "cy": h / 2, "w": w, "h": h, "camera_model": "OPENCV",
                "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0, "frames": frames}
        (root / "transforms.json").write_text(json.dumps(meta))
        return root

    return make
