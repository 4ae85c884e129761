"""Checkpoint loading without the nerfstudio trainer, compact export round trip."""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch

from cinenerf_ns.method.checkpoint import CheckpointError, export_compact, find_checkpoint, load_splat
from cinenerf_ns.method.codec import CodecConfig, FeatureCodec

REPO = Path(__file__).resolve().parents[2]


def _fake_run(tmp_path, with_semantics=True, n=50):
    """A run folder like ns-train writes: config.yml + nerfstudio_models/step-*.ckpt (pipeline state)."""
    g = torch.Generator().manual_seed(0)
    sd = {
        "_model.gauss_params.means": torch.randn(n, 3, generator=g),
        "_model.gauss_params.quats": torch.randn(n, 4, generator=g),
        "_model.gauss_params.scales": torch.randn(n, 3, generator=g) - 3,
        "_model.gauss_params.opacities": torch.randn(n, 1, generator=g),
        "_model.gauss_params.features_dc": torch.randn(n, 3, generator=g),
        "_model.gauss_params.features_rest": torch.zeros(n, 15, 3),
    }
    codec = None
    if with_semantics:
        cc = CodecConfig(hidden_dim=16, backend="torch")
        codec = FeatureCodec(24, cc)
        sd["_model.gauss_params.latents"] = torch.rand(n, 3, generator=g) * 2 - 1
        sd.update({"_model.codec." + k: v for k, v in codec.state_dict().items()})
        sd["_model.label_embeddings"] = torch.randn(2, 24, generator=g)
        sd["_model._extra_state"] = {
            "cine_info": {
                "feature_dim": 24,
                "codec_config": vars(cc),
                "codec_backend": "torch",
                "label_names": ["a", "b"],
                "clip": None,
                "sh_degree": 3,
            }
        }
    run = tmp_path / "outputs" / "fox" / "cinesplat" / "2026-01-01_000000"
    (run / "nerfstudio_models").mkdir(parents=True)
    (run / "config.yml").write_text("# placeholder\n")
    blob = {"step": 1999, "pipeline": sd, "schedulers": {"means": {"_last_lr": [np.float64(1e-4)]}}}  # stock numpy
    torch.save({**blob, "step": 999}, run / "nerfstudio_models" / "step-000000999.ckpt")
    torch.save(blob, run / "nerfstudio_models" / "step-000001999.ckpt")
    return run, sd, codec


def test_load_from_config_yml_picks_latest(tmp_path):
    run, sd, codec = _fake_run(tmp_path)
    assert find_checkpoint(run / "config.yml").name == "step-000001999.ckpt"
    st = load_splat(run / "config.yml")
    assert st.step == 1999 and len(st) == 50
    p = st.params
    assert np.array_equal(p.means, sd["_model.gauss_params.means"].numpy())
    assert p.opacity_logits.shape == (50,) and p.log_scales.shape == (50, 3) and p.quats_wxyz.shape == (50, 4)
    assert np.array_equal(p.latents, sd["_model.gauss_params.latents"].numpy())
    x = torch.rand(4, 3)
    assert torch.allclose(st.codec.decode(x), codec.decode(x))
    assert st.info["label_names"] == ["a", "b"] and st.label_embeddings.shape == (2, 24)
    assert torch.allclose(torch.as_tensor(p.rgb()),
                          (sd["_model.gauss_params.features_dc"] * 0.28209479177387814 + 0.5).clamp(0, 1))


def test_plain_splatfacto_checkpoint(tmp_path):
    run, sd, _ = _fake_run(tmp_path, with_semantics=False)
    st = load_splat(run)
    assert st.params.latents is None and st.codec is None and len(st) == 50


def test_errors(tmp_path):
    with pytest.raises(CheckpointError, match="no .ckpt"):
        find_checkpoint(tmp_path)
    with pytest.raises(CheckpointError, match="not a checkpoint"):
        find_checkpoint(tmp_path / "nothing.txt")
    torch.save({"pipeline": {"foo": torch.zeros(1)}}, tmp_path / "x.ckpt")
    with pytest.raises(CheckpointError, match="not a splatfacto"):
        load_splat(tmp_path / "x.ckpt")


@pytest.mark.parametrize("suffix", [".pt", ".npz"])
def test_export_compact_roundtrip(tmp_path, suffix):
    run, sd, codec = _fake_run(tmp_path)
    st = load_splat(run)
    out = export_compact(st, tmp_path / f"scene{suffix}")
    back = load_splat(out)
    assert np.array_equal(back.params.means, st.params.means)  # positions stay float32
    for name in ("quats_wxyz", "log_scales", "opacity_logits", "latents"):
        np.testing.assert_allclose(getattr(back.params, name), getattr(st.params, name), atol=2e-3, rtol=2e-3,
                                   err_msg=name)
    np.testing.assert_allclose(back.params.rgb(), st.params.rgb(), atol=2e-3, rtol=0)
    x = torch.rand(4, 3) * 2 - 1
    assert torch.allclose(back.codec.decode(x), st.codec.decode(x), atol=1e-6)
    assert back.info["label_names"] == ["a", "b"]
    assert out.stat().st_size < (run / "nerfstudio_models" / "step-000001999.ckpt").stat().st_size


def test_semantic_scene_from_checkpoint(tmp_path):
    from cinenerf_ns.method.semantic_scene import SemanticScene

    run, sd, _ = _fake_run(tmp_path)
    s = SemanticScene.from_checkpoint(run / "config.yml", negatives=("b",))  # label names only: no CLIP
    rel = s.query("a")  # a label name: answered from the stored table, no CLIP needed
    assert rel.shape == (50,) and ((rel >= 0) & (rel <= 1)).all()


def test_loader_never_imports_nerfstudio(tmp_path):
    run, _, _ = _fake_run(tmp_path)
    code = textwrap.dedent(
        f"""
        import sys
        from cinenerf_ns.method.checkpoint import load_splat
        st = load_splat(r"{run}")
        bad = [m for m in ("nerfstudio", "gsplat", "open_clip", "viser") if m in sys.modules]
        print("LEN", len(st), "BAD", bad)
        """
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "LEN 50 BAD []" in out.stdout
