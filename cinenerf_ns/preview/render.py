"""Render preview frames of a splat: compiled CPU kernel, pure-torch tiled renderer or gsplat on CUDA.

Colour is SH degree 0 (SplatParams.rgb(): 0.5 + C0 * sh_dc clamped to [0, 1]; a compact export's stored colour); the
background is composited as ns-render does (rgb + (1 - alpha) * background, clamped to [0, 1]).
gsplat is imported only when the CUDA path is used.
"""
from __future__ import annotations

from typing import Optional, Sequence, Tuple

import numpy as np
import torch
from torch import Tensor

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.splat_params import SplatParams

from . import native
from .raster_torch import EPS2D, NEAR_PLANE, PreviewScene, make_scene, raster_reference

# splatfacto's background_color "random" (cinesplat's default) renders over this colour outside training
NERFSTUDIO_BACKGROUND = (0.1490, 0.1647, 0.2157)
BACKENDS = ("auto", "native", "torch", "gsplat")


def scene_from_splat(splat: SplatParams, dtype: torch.dtype = torch.float32,
                     grey: Optional[float] = None) -> PreviewScene:
    """Activated, SH-degree-0 scene of a splat's parameters (CPU). A splat without colour is drawn in ``grey``; with
    ``grey`` None it is refused (InvalidInputError)."""
    rgb = splat.rgb(default=grey)
    if rgb is None:
        raise InvalidInputError("the splat has no colour (features_dc); the preview needs it.")
    means, quats, log_scales, logits = splat.tensors()
    return make_scene(means, quats, torch.exp(log_scales), torch.sigmoid(logits), torch.from_numpy(rgb), dtype=dtype)


def choose_backend(backend: str, device: str = "cpu") -> str:
    """The backend that will render: "native" (compiled), "torch" or "gsplat" (CUDA)."""
    if backend not in BACKENDS:
        raise InvalidInputError(f"preview backend must be one of {BACKENDS}, got {backend!r}.")
    if str(device).startswith("cuda"):
        if not torch.cuda.is_available():
            raise InvalidInputError(f"device {device!r} asked for but CUDA is not available.")
        if backend in ("auto", "gsplat"):
            return "gsplat"
        raise InvalidInputError(f"backend {backend!r} renders on the CPU; use device='cpu'.")
    if backend == "gsplat":
        raise InvalidInputError("backend 'gsplat' needs device='cuda'.")
    if backend == "auto":
        return "native" if native.render_fn("float32") is not None else "torch"
    return backend


def render_premultiplied(scene: PreviewScene, viewmat: np.ndarray, intrinsics: Sequence[float], width: int, height: int,
                         backend: str = "native", near_plane: float = NEAR_PLANE, eps2d: float = EPS2D,
                         threads: int = 0) -> Tuple[Tensor, Tensor]:
    """(premultiplied rgb [H, W, 3], alpha [H, W, 1]) on the CPU, in the scene's dtype; backend "native" | "torch"."""
    intr = tuple(float(v) for v in intrinsics)
    if backend == "native":
        rgb, alpha, _ = native.render_native(scene.means.numpy(), scene.cov3d.numpy(), scene.opacities.numpy(),
                                             scene.colors.numpy(), np.asarray(viewmat), intr, width, height,
                                             near_plane, eps2d, threads)
        return torch.from_numpy(rgb), torch.from_numpy(alpha)
    if backend == "torch":
        return raster_reference(scene, torch.as_tensor(np.asarray(viewmat)), intr, width, height, near_plane, eps2d)
    raise InvalidInputError(f"CPU backend must be 'native' or 'torch', got {backend!r}.")


def render_gsplat(scene: PreviewScene, viewmats: np.ndarray, Ks: np.ndarray, width: int, height: int,
                  near_plane: float = NEAR_PLANE, eps2d: float = EPS2D, device: str = "cuda") -> Tuple[Tensor, Tensor]:
    """(premultiplied rgb [C, H, W, 3], alpha [C, H, W, 1]) from gsplat.rasterization (classic mode), on ``device``."""
    from gsplat import rasterization  # lazily: CUDA only

    s = scene.to(device=device, dtype=torch.float32)
    rgb, alpha, _ = rasterization(
        means=s.means, quats=s.quats, scales=s.scales, opacities=s.opacities, colors=s.colors,
        viewmats=torch.as_tensor(np.asarray(viewmats), dtype=torch.float32, device=device),  # [C, 4, 4]
        Ks=torch.as_tensor(np.asarray(Ks), dtype=torch.float32, device=device),  # [C, 3, 3]
        width=int(width), height=int(height), near_plane=near_plane, eps2d=eps2d, packed=False,
        render_mode="RGB", rasterize_mode="classic", sh_degree=None,
    )
    return rgb, alpha


def composite(rgb: Tensor, alpha: Tensor, background: Optional[Sequence[float]] = NERFSTUDIO_BACKGROUND) -> Tensor:
    """rgb + (1 - alpha) * background, clamped to [0, 1] ([..., H, W, 3])."""
    bg = torch.zeros(3, dtype=rgb.dtype, device=rgb.device) if background is None else \
        torch.as_tensor(background, dtype=rgb.dtype, device=rgb.device)
    return torch.clamp(rgb + (1 - alpha) * bg, 0.0, 1.0)


def to_uint8(img: Tensor) -> np.ndarray:
    """[..., H, W, 3] in [0, 1] -> uint8 array."""
    return (img.clamp(0, 1) * 255.0 + 0.5).to(torch.uint8).cpu().numpy()


def render_frame(scene: PreviewScene, viewmat: np.ndarray, intrinsics: Sequence[float], width: int, height: int,
                 backend: str = "auto", background: Optional[Sequence[float]] = NERFSTUDIO_BACKGROUND,
                 device: str = "cpu") -> np.ndarray:
    """One frame as uint8 [H, W, 3]."""
    b = choose_backend(backend, device)
    if b == "gsplat":
        fx, fy, cx, cy = (float(v) for v in intrinsics)
        K = np.array([[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]], dtype=np.float64)
        rgb, alpha = render_gsplat(scene, np.asarray(viewmat)[None], K, width, height, device=device)
        return to_uint8(composite(rgb[0], alpha[0], background))
    rgb, alpha = render_premultiplied(scene, viewmat, intrinsics, width, height, backend=b)
    return to_uint8(composite(rgb, alpha, background))
