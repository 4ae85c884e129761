"""Dense, pixel-aligned CLIP features from any open_clip ViT or ModifiedResNet image tower.

Method: MaskCLIP (Zhou et al., ECCV 2022) dense patch tokens, averaged over a few input scales.
* ViT: run the tower with interpolated positional embeddings; in the LAST block replace attention by its
  value path (v-projection + out-projection, no residual, no MLP), then ln_post and the final projection.
  Every patch token then lives in the same joint image-text space as the pooled image embedding, so a
  patch can be compared to a text embedding directly.
* ModifiedResNet: the attention pool's v-projection + c-projection applied at every spatial position.
Why this and not LERF's tile pyramid: one forward pass per image and scale (LERF needs hundreds of crops per
image, minutes per scene), features are pixel-aligned at patch resolution, and the output is a single
map (the pyramid's scale dimension is not needed because the splat latent has no scale input).
Scales: the image is resized so its long side is each of ``input_long_sides`` (snapped to the patch size);
the token grids are bilinearly resized to the feature-map size and averaged, then L2-normalised.

Weights: standard open_clip loading (hub tag, cache, or a local checkpoint file). When they are missing,
``load_clip`` raises ``ClipWeightsError`` with one message saying how to provide them.
``random_weights=True`` builds the real architecture with seeded random weights (tests / no-weight machines).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Sequence, Tuple

import torch
import torch.nn.functional as F
from torch import Tensor

from cinenerf_ns.method.seeding import cpu_seeded


class ClipWeightsError(RuntimeError):
    """CLIP weights could not be loaded; the message says how to provide them for training (ns-train options), and
    ``reason`` says only what failed (query-time callers give their own advice: semantic_scene.build_text_encoder)."""

    def __init__(self, message: str, reason: Optional[str] = None):
        super().__init__(message)
        self.reason = reason or message


@dataclass
class ClipFeatureConfig:
    """Which CLIP model, and how dense features are extracted."""

    model_name: str = "ViT-B-16"
    """open_clip model name (``open_clip.list_models()``), e.g. ViT-B-16 (512-d), ViT-H-14 (1024-d), RN50."""
    pretrained: str = "laion2b_s34b_b88k"
    """open_clip pretrained tag (``open_clip.list_pretrained()``), loaded from the open_clip / HF cache."""
    checkpoint_path: Optional[Path] = None
    """Local open_clip checkpoint file (.bin/.pt/.safetensors) used instead of the pretrained tag."""
    random_weights: bool = False
    """Build the architecture with seeded random weights (pretrained=None): for tests and machines without
    weights. Features are then meaningless but the whole pipeline runs."""
    random_seed: int = 0
    """Seed of the random weights (the text tower must be rebuilt identically at query time)."""
    input_long_sides: Tuple[int, ...] = (448, 672)
    """Scales: the image is resized to each of these long sides (px) for one forward pass each; averaged."""
    feature_long_side: int = 64
    """Long side (px) of the stored feature map = resolution of the latent distillation loss."""
    half_precision: bool = True
    """Run the image tower in float16 on CUDA."""

    def spec(self) -> dict:
        """Plain-python description of the text encoder (stored in checkpoints)."""
        return {
            "model_name": self.model_name,
            "pretrained": self.pretrained,
            "checkpoint_path": str(self.checkpoint_path) if self.checkpoint_path else None,
            "random_weights": bool(self.random_weights),
            "random_seed": int(self.random_seed),
        }


def clip_config_from_spec(spec: dict) -> ClipFeatureConfig:
    cp = spec.get("checkpoint_path")
    return ClipFeatureConfig(
        model_name=spec["model_name"],
        pretrained=spec.get("pretrained") or "",
        checkpoint_path=Path(cp) if cp else None,
        random_weights=bool(spec.get("random_weights", False)),
        random_seed=int(spec.get("random_seed", 0)),
    )


def clip_embed_dim(model_name: str) -> int:
    import open_clip

    cfg = open_clip.get_model_config(model_name)
    if cfg is None:
        raise ClipWeightsError(f"unknown open_clip model '{model_name}' (see open_clip.list_models())")
    return int(cfg["embed_dim"])


def load_clip(cfg: ClipFeatureConfig, device: torch.device | str = "cpu"):
    """(model in eval mode, tokenizer). Raises ClipWeightsError (one readable message) if weights are missing."""
    import open_clip

    if open_clip.get_model_config(cfg.model_name) is None:
        raise ClipWeightsError(f"unknown open_clip model '{cfg.model_name}' (see open_clip.list_models())")
    if cfg.random_weights:
        with cpu_seeded(cfg.random_seed):  # CPU only: the CUDA stream training draws from stays the user's
            model = open_clip.create_model(cfg.model_name, pretrained=None, device="cpu")
    else:
        src = str(cfg.checkpoint_path) if cfg.checkpoint_path else cfg.pretrained
        if cfg.checkpoint_path is not None and not Path(cfg.checkpoint_path).is_file():
            raise ClipWeightsError(f"CLIP checkpoint file not found: {cfg.checkpoint_path}")
        try:
            model = _create_cache_first(cfg.model_name, src, local_file=cfg.checkpoint_path is not None)
        except Exception as e:
            reason = f"could not load CLIP weights '{cfg.model_name}' / '{src}' ({type(e).__name__}: {str(e)[:160]})"
            raise ClipWeightsError(
                f"C{reason[1:]}.\n"
                "Provide them in one of these ways:\n"
                f"  * run once with network so open_clip caches them (python -c \"import open_clip; "
                f"open_clip.create_model('{cfg.model_name}', pretrained='{cfg.pretrained}')\"), or\n"
                "  * download the checkpoint file and pass --pipeline.datamanager.clip.checkpoint-path FILE, or\n"
                "  * for a pipeline test without semantics: --pipeline.datamanager.clip.random-weights True.",
                reason=reason,
            ) from None
    model.eval().to(device)
    tokenizer = open_clip.get_tokenizer(cfg.model_name)
    return model, tokenizer


def _online(host: str = "huggingface.co", timeout_s: float = 3.0) -> bool:
    import socket

    try:
        socket.create_connection((host, 443), timeout=timeout_s).close()
        return True
    except OSError:
        return False


def _create_cache_first(model_name: str, src: str, local_file: bool):
    """open_clip.create_model, first from the local cache only (instant, silent), then, if the hub is
    reachable, with a download. Without network this fails fast instead of huggingface_hub's ~1 minute of
    retries and log lines."""
    import logging

    import open_clip

    if local_file:
        return open_clip.create_model(model_name, pretrained=src, device="cpu")
    try:
        import huggingface_hub.constants as hfc
    except Exception:  # pragma: no cover
        hfc = None
    old = getattr(hfc, "HF_HUB_OFFLINE", None)
    loggers = [logging.getLogger("huggingface_hub"), logging.getLogger()]  # open_clip logs on root
    old_levels = [lg.level for lg in loggers]
    try:
        if hfc is not None:
            hfc.HF_HUB_OFFLINE = True
        for lg in loggers:
            lg.setLevel(logging.CRITICAL)
        return open_clip.create_model(model_name, pretrained=src, device="cpu")
    except Exception as cache_err:
        if hfc is not None:
            hfc.HF_HUB_OFFLINE = old
        for lg, lv in zip(loggers, old_levels):
            lg.setLevel(lv)
        if not _online():
            raise RuntimeError(f"not in the local cache and no network ({cache_err.__class__.__name__})") from None
        return open_clip.create_model(model_name, pretrained=src, device="cpu")
    finally:
        if hfc is not None:
            hfc.HF_HUB_OFFLINE = old
        for lg, lv in zip(loggers, old_levels):
            lg.setLevel(lv)


@torch.no_grad()
def encode_text(model, tokenizer, texts: Sequence[str]) -> Tensor:
    """Unit text embeddings [T, D] (float32)."""
    dev = next(model.parameters()).device
    tok = tokenizer(list(texts)).to(dev)
    return F.normalize(model.encode_text(tok).float(), dim=-1)


def make_text_encoder(cfg: ClipFeatureConfig, device: torch.device | str = "cpu") -> Callable[[Sequence[str]], Tensor]:
    """Callable list[str] -> [T, D] unit embeddings; loads the model once."""
    model, tokenizer = load_clip(cfg, device)
    return lambda texts: encode_text(model, tokenizer, texts)


# ---------------------------------------------------------------------------------------------- dense
def _image_mean_std(model) -> Tuple[Tensor, Tensor]:
    v = model.visual
    mean = getattr(v, "image_mean", None) or (0.48145466, 0.4578275, 0.40821073)
    std = getattr(v, "image_std", None) or (0.26862954, 0.26130258, 0.27577711)
    return torch.tensor(mean), torch.tensor(std)


def _vit_dense(visual, x: Tensor) -> Tensor:
    """MaskCLIP tokens of an open_clip VisionTransformer. x [1,3,H,W] normalised -> [gh, gw, D]."""
    x = visual.conv1(x)  # [1, width, gh, gw]
    gh, gw = x.shape[-2:]
    x = x.reshape(x.shape[0], x.shape[1], -1).permute(0, 2, 1)  # [1, gh*gw, width]
    cls = visual.class_embedding.to(x.dtype).reshape(1, 1, -1).expand(x.shape[0], -1, -1)
    x = torch.cat([cls, x], dim=1)
    pos = visual.positional_embedding.to(x.dtype)  # [1+G, width]
    g0 = int(round(math.sqrt(pos.shape[0] - 1)))
    pos_grid = pos[1:].reshape(1, g0, g0, -1).permute(0, 3, 1, 2).float()
    pos_grid = F.interpolate(pos_grid, size=(gh, gw), mode="bicubic", align_corners=False).to(x.dtype)
    pos = torch.cat([pos[:1], pos_grid[0].permute(1, 2, 0).reshape(gh * gw, -1)], dim=0)
    x = x + pos[None]
    x = visual.ln_pre(x)
    blocks = visual.transformer.resblocks
    batch_first = getattr(visual.transformer, "batch_first", True)
    if not batch_first:
        x = x.transpose(0, 1)
    for blk in blocks[:-1]:
        x = blk(x)
    last = blocks[-1]
    if not isinstance(getattr(last, "attn", None), torch.nn.MultiheadAttention):
        raise NotImplementedError("dense CLIP features: only open_clip blocks with nn.MultiheadAttention are supported")
    y = last.ln_1(x)
    attn = last.attn
    w = attn.embed_dim
    v = F.linear(y, attn.in_proj_weight[2 * w :], attn.in_proj_bias[2 * w :] if attn.in_proj_bias is not None else None)
    x = attn.out_proj(v)
    if not batch_first:
        x = x.transpose(0, 1)
    x = visual.ln_post(x)
    if visual.proj is not None:
        x = x @ visual.proj
    return x[0, 1:].reshape(gh, gw, -1)


def _resnet_dense(visual, x: Tensor) -> Tensor:
    """MaskCLIP for open_clip ModifiedResNet: attnpool v/c projections at every position -> [gh, gw, D]."""
    x = visual.stem(x)
    x = visual.layer1(x)
    x = visual.layer2(x)
    x = visual.layer3(x)
    x = visual.layer4(x)  # [1, C, gh, gw]
    ap = visual.attnpool
    gh, gw = x.shape[-2:]
    t = x.flatten(2).permute(0, 2, 1)  # [1, gh*gw, C]
    pos = ap.positional_embedding[1:].to(t.dtype)  # [G, C]
    g0 = int(round(math.sqrt(pos.shape[0])))
    pos = F.interpolate(pos.reshape(1, g0, g0, -1).permute(0, 3, 1, 2).float(), size=(gh, gw), mode="bicubic",
                        align_corners=False)
    t = t + pos.to(t.dtype)[0].permute(1, 2, 0).reshape(1, gh * gw, -1)
    t = ap.c_proj(ap.v_proj(t))
    return t[0].reshape(gh, gw, -1)


def _dense_fn(model) -> Callable[[Tensor], Tensor]:
    from open_clip.modified_resnet import ModifiedResNet
    from open_clip.transformer import VisionTransformer

    v = model.visual
    if isinstance(v, VisionTransformer):
        if getattr(v, "attn_pool", None) is not None:
            raise NotImplementedError("dense CLIP features: attention-pooled ViTs (CoCa) are not supported")
        return lambda x: _vit_dense(v, x)
    if isinstance(v, ModifiedResNet):
        return lambda x: _resnet_dense(v, x)
    raise NotImplementedError(
        f"dense CLIP features need an open_clip VisionTransformer or ModifiedResNet tower, got {type(v).__name__}"
    )


def _patch_multiple(model) -> int:
    v = model.visual
    ps = getattr(v, "patch_size", None)
    if ps is not None:
        return int(ps[0] if isinstance(ps, (tuple, list)) else ps)
    return 32  # ModifiedResNet: total stride 32


class DenseClipExtractor:
    """``extract(image [H, W, 3] float in [0,1] or uint8) -> unit features [h, w, D]`` at the feature-map size."""

    def __init__(self, cfg: ClipFeatureConfig, device: torch.device | str = "cpu", model=None):
        self.cfg = cfg
        self.device = torch.device(device)
        self.dtype = torch.float16 if (cfg.half_precision and self.device.type == "cuda") else torch.float32
        if model is not None:
            self.model = model.to(self.device).to(self.dtype)
        else:
            # only the image tower goes to the device, cast BEFORE the copy: a float32 ViT-B/16 with its text tower
            # on the GPU (~600 MB) was the peak of a whole cinesplat run, above splatfacto's training peak
            self.model = load_clip(cfg, "cpu")[0]
            self.model.visual.to(self.dtype).to(self.device)
        self.dense = _dense_fn(self.model)
        self.mult = _patch_multiple(self.model)
        mean, std = _image_mean_std(self.model)
        self.mean = mean.to(self.device).view(1, 3, 1, 1)
        self.std = std.to(self.device).view(1, 3, 1, 1)

    @property
    def feature_dim(self) -> int:
        return int(self.model.visual.output_dim)

    @torch.no_grad()
    def extract(self, image: Tensor, out_hw: Optional[Tuple[int, int]] = None) -> Tensor:
        from cinenerf_ns.method.feature_grid import feature_map_size

        if image.dtype == torch.uint8:
            image = image.float() / 255.0
        image = image[..., :3].to(self.device).float()
        H, W = image.shape[:2]
        h, w = out_hw if out_hw is not None else feature_map_size(H, W, self.cfg.feature_long_side)
        x = image.permute(2, 0, 1)[None]  # [1, 3, H, W]
        acc = None
        for long_side in self.cfg.input_long_sides:
            s = long_side / max(H, W)
            th = max(self.mult, int(round(H * s / self.mult)) * self.mult)
            tw = max(self.mult, int(round(W * s / self.mult)) * self.mult)
            xi = F.interpolate(x, size=(th, tw), mode="bilinear", align_corners=False, antialias=True)
            xi = ((xi - self.mean) / self.std).to(self.dtype)
            tok = self.dense(xi).float()  # [gh, gw, D]
            tok = F.normalize(tok, dim=-1)
            tok = F.interpolate(tok.permute(2, 0, 1)[None], size=(h, w), mode="bilinear", align_corners=False)[0]
            acc = tok if acc is None else acc + tok
        return F.normalize(acc.permute(1, 2, 0), dim=-1)  # [h, w, D]
