"""Load a splatfacto / cinesplat checkpoint into raw splat parameters without building nerfstudio's trainer.

``load_splat(path)`` accepts a run's ``config.yml``, the run folder, a ``nerfstudio_models`` folder, a
``.ckpt`` file, or a compact export (``.pt`` / ``.npz`` written by ``export_compact``). It reads the
checkpoint with ``torch.load(weights_only=True)`` (numpy scalars of nerfstudio's scheduler state allowed via
compat's safe globals) and never imports nerfstudio, gsplat or the CLIP model.

Returns a ``SplatCheckpoint``: the Gaussians as ``planner.splat_params.SplatParams`` (numpy: means, quats_wxyz,
log_scales, opacity_logits, colors_dc as SH DC coefficients, latents [N,3] or None) plus codec (FeatureCodec, frozen,
on the load device) or None, info (dict), label_embeddings [L,D] (on the load device) or None.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Optional

import numpy as np
import torch
from torch import Tensor

from cinenerf_ns.method.scene_files import (
    COMPACT,
    SUPPORTED,
    CheckpointError,
    check_config_yml,
    check_info,
    check_semantics,
    check_splat,
    compact_blob,
    compact_npz,
    torch_read,
)
from cinenerf_ns.planner.scene.splat_params import SplatParams, rgb_to_dc

PREFIX = "_model.gauss_params."


@dataclass
class SplatCheckpoint:
    """A loaded checkpoint or compact export: its Gaussians and, for cinesplat runs, their semantics."""

    params: SplatParams  # the Gaussians (numpy, SH degree 0 colour as colors_dc, latents if distilled)
    codec: Any = None  # FeatureCodec decoding latents (frozen, on the load device), or None
    codec_state: Optional[Dict[str, Tensor]] = None  # the codec's weights as stored (written back by export_compact)
    info: Dict[str, Any] = field(default_factory=dict)  # the run's cine_info / a compact export's info_json
    label_embeddings: Optional[Tensor] = None  # [L, D] CLIP embeddings of info["label_names"], or None
    step: int = -1
    path: Optional[Path] = None

    def __len__(self) -> int:
        return len(self.params)


def find_checkpoint(path: str | Path) -> Path:
    """Resolve config.yml / run folder / models folder / .ckpt to the newest .ckpt file (a config.yml is checked)."""
    p = Path(path)
    if not p.exists():
        raise CheckpointError(f"{p} does not exist (not a checkpoint, run folder or config.yml)")
    if p.is_file():
        suffix = p.suffix.lower()
        if suffix in (".ckpt", ".pt", ".npz"):
            return p
        if suffix not in (".yml", ".yaml"):
            raise CheckpointError(f"{p} is not a checkpoint or scene file this tool reads (suffix "
                                  f"{p.suffix or 'none'!r}); give {SUPPORTED}")
        check_config_yml(p)
        return _newest_ckpt(p.parent, p)
    if p.is_dir():
        cfg = p / "config.yml"
        if cfg.is_file():
            check_config_yml(cfg)
        return _newest_ckpt(p, cfg if cfg.is_file() else None)
    raise CheckpointError(f"{p} is neither a file nor a folder: give {SUPPORTED}")


def _newest_ckpt(folder: Path, config: Optional[Path]) -> Path:
    """The newest (highest step) .ckpt in folder/nerfstudio_models or folder."""
    models = folder / "nerfstudio_models"
    cands = [f for f in list(models.glob("*.ckpt")) + list(folder.glob("*.ckpt")) if f.is_file()]
    if cands:
        def step_of(f: Path) -> int:
            m = re.search(r"(\d+)", f.stem)
            return int(m.group(1)) if m else -1

        return max(cands, key=step_of)
    where = f"no .ckpt in {models} or {folder}"
    if config is not None:
        raise CheckpointError(f"no checkpoint found for {config}: {where} (has training saved a checkpoint?)")
    if models.is_dir():
        raise CheckpointError(f"no checkpoint found in {folder}: {where} and no config.yml "
                              f"(has training saved a checkpoint?)")
    raise CheckpointError(f"{folder} is a folder with no config.yml and {where}: not a run folder; give {SUPPORTED}")


def _codec_from(info: Dict[str, Any], state: Dict[str, Tensor], device, path: Optional[Path] = None) -> Any:
    try:
        return _build_codec(info, state, device)
    except (KeyError, TypeError, ValueError, RuntimeError) as e:
        raise CheckpointError(f"{path}: its feature codec cannot be rebuilt from the stored codec_config and weights "
                              f"({type(e).__name__}: {str(e).strip().splitlines()[0][:160] if str(e).strip() else ''})"
                              ) from None


def _build_codec(info: Dict[str, Any], state: Dict[str, Tensor], device) -> Any:
    from cinenerf_ns.method.codec import CodecConfig, FeatureCodec

    cfg = CodecConfig(**info["codec_config"])
    cfg.backend = info.get("codec_backend", "torch")  # the trained backend (tcnn weights need CUDA + tinycudann)
    codec = FeatureCodec(int(info["feature_dim"]), cfg, device="cuda" if cfg.backend == "tcnn" else "cpu")
    codec.load_state_dict({k: v.float() for k, v in state.items()})
    codec.to(device).eval()
    for prm in codec.parameters():
        prm.requires_grad_(False)
    return codec


def load_splat(path: str | Path, device: torch.device | str = "cpu") -> SplatCheckpoint:
    """A checkpoint, run folder, config.yml or compact export -> SplatCheckpoint (CheckpointError if malformed)."""
    ckpt = find_checkpoint(path)
    if ckpt.suffix.lower() == ".npz":
        return load_compact(ckpt, device)
    what = COMPACT if ckpt.suffix.lower() == ".pt" else "splatfacto/cinesplat checkpoint"
    blob = torch_read(ckpt, what)
    if isinstance(blob, dict) and blob.get("format") == "cinesplat-compact":
        return _compact_checkpoint(*compact_blob(blob, ckpt), ckpt, device)
    sd = blob.get("pipeline", blob) if isinstance(blob, dict) else blob
    if not isinstance(sd, dict) or PREFIX + "means" not in sd:
        if ckpt.suffix.lower() == ".pt":
            compact_blob(blob, ckpt)  # says why it is not a compact export either
        keys = f"; keys: {sorted(map(str, sd))[:8]}" if isinstance(sd, dict) else f"; it holds a {type(sd).__name__}"
        raise CheckpointError(f"{ckpt} is not a splatfacto/cinesplat checkpoint (no {PREFIX}means in its "
                              f"pipeline state{keys})")
    check_splat({k: sd.get(PREFIX + k) for k in ("means", "quats", "scales", "opacities", "features_dc", "latents")},
                ckpt)

    def g(name: str) -> Optional[Tensor]:
        t = sd.get(PREFIX + name)
        return None if t is None else t.float()

    extra = sd.get("_model._extra_state")
    info = dict(extra.get("cine_info", {})) if isinstance(extra, dict) else {}
    check_info(info, ckpt, "cine_info")
    codec_state = {k[len("_model.codec.") :]: v for k, v in sd.items() if k.startswith("_model.codec.")}
    codec = _codec_from(info, codec_state, device, ckpt) if (codec_state and info) else None
    lab = sd.get("_model.label_embeddings")
    lab = lab if isinstance(lab, Tensor) and lab.ndim == 2 else None
    check_semantics(ckpt, sd.get(PREFIX + "latents"), codec, info, lab)
    dc = g("features_dc")
    if dc is not None and info.get("sh_degree", 3) == 0:  # splatfacto's colour at SH degree 0: sigmoid(features_dc)
        dc = rgb_to_dc(torch.sigmoid(dc))
    return SplatCheckpoint(
        params=SplatParams.of(g("means"), g("quats"), g("scales"), g("opacities"), colors_dc=dc, latents=g("latents")),
        codec=codec,
        codec_state=codec_state or None,
        info=info,
        label_embeddings=lab.float().to(device) if lab is not None and lab.numel() > 0 else None,
        step=int(blob.get("step", -1)) if isinstance(blob, dict) else -1,
        path=ckpt,
    )


def _is_compact(path: Path) -> bool:
    """Whether a scene path is a compact export: any .npz file, a .pt file saved by export_compact."""
    path = Path(path)
    if not path.is_file() or path.suffix.lower() not in (".npz", ".pt"):
        return False  # a .ckpt is not loaded twice to tell
    if path.suffix.lower() == ".npz":
        return True
    try:
        blob = torch_read(path, COMPACT)
    except CheckpointError:
        return False  # load_splat says why
    return isinstance(blob, dict) and blob.get("format") == "cinesplat-compact"


def export_compact(ck: SplatCheckpoint, path: str | Path, half: bool = True,
                   planning_region: Optional[tuple] = None) -> Path:
    """Write a small self-contained scene (SH degree 0 colour): .pt (torch) or .npz (numpy).

    Keys: means, quats, scales (log), opacities (logit), rgb [N,3], latents?, codec state, info (JSON),
    label_embeddings?. ``half``: float16 for the per-Gaussian arrays (means stay float32: positions need it).
    ``planning_region`` (lo [3], hi [3]): stored as info["planning_region"] {"lo", "hi"}; cinenerf_ns.scenes.load_scene
    gives it back (stored_region) and cinesplat-plan plans in it unless --region says otherwise.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ht = torch.float16 if half else torch.float32
    p = ck.params
    t = lambda a: torch.as_tensor(np.asarray(a, np.float32))  # noqa: E731
    arrays: Dict[str, Tensor] = {
        "means": t(p.means),
        "quats": t(p.quats_wxyz).to(ht),
        "scales": t(p.log_scales).to(ht),
        "opacities": t(p.opacity_logits).to(ht),
    }
    rgb = p.rgb()
    if rgb is not None:
        arrays["rgb"] = t(rgb).to(ht)
    if p.latents is not None:
        arrays["latents"] = t(p.latents).to(ht)
    if ck.label_embeddings is not None:
        arrays["label_embeddings"] = ck.label_embeddings.to(ht).cpu()
    codec_state = {k: v.float().cpu() for k, v in (ck.codec_state or {}).items()}
    info = dict(ck.info)
    if planning_region is not None:
        lo, hi = (np.asarray(v, dtype=np.float64).reshape(3) for v in planning_region)
        info["planning_region"] = {"lo": lo.tolist(), "hi": hi.tolist()}
    info_json = json.dumps(info, default=str)
    tmp = path.with_name(path.name + ".tmp")
    if path.suffix == ".npz":
        flat = {k: v.numpy() for k, v in arrays.items()}
        flat.update({"codec." + k: v.numpy() for k, v in codec_state.items()})
        flat["info_json"] = np.array(info_json)
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **flat)
    else:
        torch.save({"format": "cinesplat-compact", "arrays": arrays, "codec": codec_state, "info_json": info_json}, tmp)
    tmp.replace(path)
    return path


def load_compact(path: str | Path, device: torch.device | str = "cpu") -> SplatCheckpoint:
    """A compact export (.npz or .pt, see export_compact) -> SplatCheckpoint (CheckpointError if malformed)."""
    path = Path(path)
    if path.suffix.lower() == ".npz":
        parts = compact_npz(path)
    else:
        parts = compact_blob(torch_read(path, COMPACT), path)
    return _compact_checkpoint(*parts, path, device)


def _compact_checkpoint(arrays: Dict[str, Tensor], codec_state: Dict[str, Tensor], info: Dict[str, Any], path: Path,
                     device: torch.device | str) -> SplatCheckpoint:
    check_splat(arrays, path)
    f = lambda k: arrays[k].float() if k in arrays else None  # noqa: E731
    rgb = f("rgb")
    info = dict(info)
    info["sh_degree"] = 0
    codec = _codec_from(info, codec_state, device, path) if (codec_state and info.get("codec_config")) else None
    lab = f("label_embeddings")
    check_semantics(path, f("latents"), codec, info, lab)
    return SplatCheckpoint(
        params=SplatParams.of(f("means"), f("quats"), f("scales"), f("opacities"),
                              colors_dc=None if rgb is None else rgb_to_dc(rgb), latents=f("latents")),
        codec=codec,
        codec_state=codec_state or None,
        info=info,
        label_embeddings=None if lab is None else lab.to(device),
        path=path,
    )
