"""Feature codec (paper eq. 2): f_enc: D -> latent_dim, f_dec: latent_dim -> D, P_hat = f_dec(f_enc(P)).

Trained on the cached per-pixel CLIP (or label) features before distillation, then frozen and saved in
the model checkpoint. Backends with one interface and one config:
* "torch": plain ``nn.Sequential`` MLPs (always available, CPU or CUDA).
* "tcnn":  tiny-cuda-nn FullyFusedMLP (as in the paper) when ``tinycudann`` imports and the device is CUDA.
* "auto":  "tcnn" when possible, else "torch".
The encoder output goes through ``tanh`` so latents live in [-1, 1]^3: the rendered latent image is an
alpha blend of per-Gaussian latents, and a bounded code keeps the blend inside the code's domain.
The decoder output is L2-normalised: CLIP compares by cosine, so only the direction of P matters and
the reconstruction loss is ``1 - cos(P_hat, P)`` (= half the squared error of the unit vectors). Both MLPs
work on the residual around the training features' mean (``center`` buffer, saved with the weights).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal, Optional, Tuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from cinenerf_ns.method.seeding import cpu_seeded


@dataclass
class CodecConfig:
    """Architecture and training of the feature codec."""

    latent_dim: int = 3
    """Size of the per-Gaussian code (paper: 3, also gsplat's native colour channel count)."""
    hidden_dim: int = 64
    """Width of the hidden layers of both MLPs (64 fits tinycudann's FullyFusedMLP widths 16..128)."""
    num_layers: int = 2
    """Hidden layers per MLP."""
    backend: Literal["auto", "torch", "tcnn"] = "auto"
    """MLP implementation: tiny-cuda-nn FullyFusedMLP when importable on CUDA ("auto"), or a torch MLP."""
    train_steps: int = 2000
    """Optimisation steps when fitting the codec to the cached features."""
    batch_size: int = 8192
    """Feature vectors per codec training step."""
    lr: float = 3e-3
    """Adam learning rate of the codec."""
    max_samples: int = 1_000_000
    """At most this many feature vectors (random subset) are kept on the device for codec training."""
    seed: int = 0
    """Seed of the codec's initialisation and sampling."""


def tcnn_available(device: torch.device | str) -> bool:
    if torch.device(device).type != "cuda" or not torch.cuda.is_available():
        return False
    try:
        import tinycudann  # noqa: F401
    except Exception:
        return False
    return True


def _torch_mlp(n_in: int, n_out: int, hidden: int, layers: int) -> nn.Module:
    mods = []
    d = n_in
    for _ in range(layers):
        mods += [nn.Linear(d, hidden), nn.ReLU(inplace=True)]
        d = hidden
    mods.append(nn.Linear(d, n_out))
    return nn.Sequential(*mods)


class _TcnnMLP(nn.Module):
    """tinycudann FullyFusedMLP; returns float32 (tcnn computes in half precision)."""

    def __init__(self, n_in: int, n_out: int, hidden: int, layers: int, seed: int):
        super().__init__()
        import tinycudann as tcnn

        self.net = tcnn.Network(
            n_input_dims=n_in,
            n_output_dims=n_out,
            network_config={
                "otype": "FullyFusedMLP",
                "activation": "ReLU",
                "output_activation": "None",
                "n_neurons": hidden,
                "n_hidden_layers": layers,
            },
            seed=seed,
        )

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x).float()


class FeatureCodec(nn.Module):
    """f_enc / f_dec pair. ``encode(P[..., D]) -> l[..., latent_dim]``, ``decode(l) -> unit P_hat[..., D]``."""

    def __init__(self, feature_dim: int, config: Optional[CodecConfig] = None, device: torch.device | str = "cpu"):
        super().__init__()
        self.config = config or CodecConfig()
        self.feature_dim = int(feature_dim)
        cfg = self.config
        use_tcnn = cfg.backend == "tcnn" or (cfg.backend == "auto" and tcnn_available(device))
        if cfg.backend == "tcnn" and not tcnn_available(device):
            raise RuntimeError("codec backend 'tcnn' requested but tinycudann is not importable on a CUDA device")
        self.backend = "tcnn" if use_tcnn else "torch"
        with cpu_seeded(cfg.seed):  # the CUDA stream training draws from stays the user's (--machine.seed)
            if use_tcnn:
                self.enc = _TcnnMLP(self.feature_dim, cfg.latent_dim, cfg.hidden_dim, cfg.num_layers, cfg.seed)
                self.dec = _TcnnMLP(cfg.latent_dim, self.feature_dim, cfg.hidden_dim, cfg.num_layers, cfg.seed + 1)
            else:
                self.enc = _torch_mlp(self.feature_dim, cfg.latent_dim, cfg.hidden_dim, cfg.num_layers)
                self.dec = _torch_mlp(cfg.latent_dim, self.feature_dim, cfg.hidden_dim, cfg.num_layers)
        # mean of the training features: the MLPs model the residual around it. CLIP features of one scene
        # share a large common component (pairwise cosines 0.6-0.9), so without centring the decoder first
        # learns the mean and the semantic differences converge much later.
        self.register_buffer("center", torch.zeros(self.feature_dim))
        self.to(device)

    def encode(self, feats: Tensor) -> Tensor:
        shape = feats.shape
        x = feats.reshape(-1, shape[-1]).float() - self.center  # [M, D]
        return torch.tanh(self.enc(x)).reshape(*shape[:-1], self.config.latent_dim)  # [..., 3]

    def decode(self, latents: Tensor) -> Tensor:
        shape = latents.shape
        x = latents.reshape(-1, shape[-1]).float()  # [M, 3]
        return F.normalize(self.dec(x) + self.center, dim=-1).reshape(*shape[:-1], self.feature_dim)  # [..., D]

    def forward(self, feats: Tensor) -> Tensor:
        return self.decode(self.encode(feats))

    def decoded_cosines(self, latents: Tensor, emb: Tensor, sq_norms: Optional[Tensor] = None) -> Tensor:
        """cos(f_dec(l), e) for latents [N, 3] and unit embeddings emb [T, D] -> [N, T], without building the
        [N, D] decoded features (the 1M-Gaussian relevancy would otherwise write 2 GB per query).

        Torch backend: with hidden h [N, H] and the last layer y = h W^T + c (c = bias + center),
            y.e   = h (W e) + c.e
            |y|^2 = sum((h G) * h) + 2 h (W c) + c.c,   G = W W^T   [H, H]
        Exact algebra (float32 rounding differs from decode(): ~1e-6). tcnn backend: falls back to decode().
        sq_norms [N]: |y|^2 of these latents from ``decoded_sq_norms`` (it does not depend on the text: a scene asked
        many queries computes it once); the same numbers as computing it here.
        """
        if self.backend != "torch":
            return self.decode(latents) @ F.normalize(emb.float(), dim=-1).T
        last = self.dec[-1]
        h = self.dec[:-1](latents.float())  # [N, H]
        W = last.weight  # [D, H]
        c = last.bias + self.center  # [D]
        e = F.normalize(emb.to(W), dim=-1)  # [T, D]
        dots = h @ (e @ W).T + (e @ c)[None]  # [N, T]
        sq = self._sq_norms(h) if sq_norms is None else sq_norms  # [N]
        return dots * torch.rsqrt(sq.clamp_min(1e-24))[:, None]

    def decoded_sq_norms(self, latents: Tensor) -> Optional[Tensor]:
        """|y|^2 [N] of decoded_cosines for latents [N, 3] (None for the tcnn backend, which decodes in full)."""
        if self.backend != "torch":
            return None
        return self._sq_norms(self.dec[:-1](latents.float()))

    def _sq_norms(self, h: Tensor) -> Tensor:
        last = self.dec[-1]
        W = last.weight  # [D, H]
        c = last.bias + self.center  # [D]
        G = W.T @ W  # [H, H]
        return ((h @ G) * h).sum(-1) + 2 * (h @ (W.T @ c)) + c @ c  # [N]


def reconstruction_error(codec: FeatureCodec, feats: Tensor, batch: int = 16384) -> float:
    """Mean ``1 - cos(f_dec(f_enc(P)), P)`` over rows of feats [M, D]."""
    tot, n = 0.0, 0
    with torch.no_grad():
        for i in range(0, feats.shape[0], batch):
            x = F.normalize(feats[i : i + batch].float(), dim=-1)
            tot += float((1 - (codec(x) * x).sum(-1)).sum())
            n += x.shape[0]
    return tot / max(n, 1)


def train_codec(
    feats: Tensor,
    config: Optional[CodecConfig] = None,
    device: torch.device | str = "cpu",
    progress: bool = True,
    weights: Optional[Tensor] = None,
) -> Tuple[FeatureCodec, dict]:
    """Fit a codec to feature vectors feats [M, D] (any scale; rows are L2-normalised first).

    weights [M] (optional): sampling weights, e.g. pixel counts when feats are distinct label embeddings.
    Returns (codec in eval mode with frozen params, stats dict with error_before/after, seconds).
    """
    cfg = config or CodecConfig()
    if feats.ndim != 2 or feats.shape[0] == 0:
        raise ValueError(f"train_codec: expected a non-empty [M, D] feature matrix, got {tuple(feats.shape)}")
    gen = torch.Generator(device="cpu").manual_seed(cfg.seed)
    if feats.shape[0] > cfg.max_samples and weights is None:
        idx = torch.randperm(feats.shape[0], generator=gen)[: cfg.max_samples]
        feats = feats[idx]
    x = F.normalize(feats.float(), dim=-1)  # [M, D], on feats' device
    w = None if weights is None else (weights.float() / weights.float().sum()).to(x.device)
    codec = FeatureCodec(x.shape[1], cfg, device=device)
    with torch.no_grad():
        codec.center.copy_(x.mean(0) if w is None else (x * w[:, None]).sum(0))
    # on a GPU the samples wait in float16 (batches are widened to float32): 1M x 512 floats would otherwise be
    # 2 GB next to the training, and the fox's 154k of them (315 MB) made setup cinesplat's memory peak
    x = x.to(device, torch.float16 if torch.device(device).type == "cuda" else torch.float32)
    w = None if w is None else w.to(device)
    t0 = time.perf_counter()
    err0 = reconstruction_error(codec, x)
    opt = torch.optim.Adam(codec.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(cfg.train_steps, 1), eta_min=cfg.lr * 0.05)
    dgen = torch.Generator(device=x.device).manual_seed(cfg.seed)
    bar = None
    if progress:
        from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

        bar = Progress(TextColumn("[bold]codec (eq. 2)"), BarColumn(), TextColumn("{task.description}"),
                       TimeRemainingColumn())
        bar.start()
        task = bar.add_task("", total=cfg.train_steps)
    codec.train()
    try:
        for it in range(cfg.train_steps):
            if w is None:
                idx = torch.randint(0, x.shape[0], (min(cfg.batch_size, x.shape[0]),), device=x.device, generator=dgen)
            else:
                idx = torch.multinomial(w, cfg.batch_size, replacement=True, generator=dgen)
            xb = x[idx].float()
            rec = codec(xb)
            loss = (1 - (rec * xb).sum(-1)).mean()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            if bar is not None and (it % 50 == 0 or it == cfg.train_steps - 1):
                bar.update(task, completed=it + 1, description=f"1-cos {float(loss.detach()):.4f}")
    finally:
        if bar is not None:
            bar.stop()
    codec.eval()
    for p in codec.parameters():
        p.requires_grad_(False)
    if x.device.type == "cuda":
        torch.cuda.synchronize()
    secs = time.perf_counter() - t0
    err1 = reconstruction_error(codec, x)
    return codec, {"error_before": err0, "error_after": err1, "seconds": secs, "samples": int(x.shape[0])}
