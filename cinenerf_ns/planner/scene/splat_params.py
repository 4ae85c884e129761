"""The one record of a splat's raw (not activated) per-Gaussian parameters, as 3DGS and splatfacto store them.

Every source of Gaussians becomes a ``SplatParams``: a 3DGS .ply (``ply.read_splat_ply``), a checkpoint or compact
export (``cinenerf_ns.method.checkpoint.load_splat``), a live model's snapshot, the viewer's demo scene and the
procedural room. numpy arrays on the CPU; ``tensors()`` gives the torch copies the planner and renderers take.

Activations (the conventions of gsplat / splatfacto): opacity = sigmoid(opacity_logits), scale = exp(log_scales),
rotation = the normalised quaternion (w, x, y, z), base colour = clip(0.5 + SH_C0 * colors_dc, 0, 1) (``rgb()``).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Dict, Optional, Tuple

import numpy as np
import torch
from torch import Tensor

SH_C0 = 0.28209479177387814  # degree-0 spherical-harmonic constant (base colour = 0.5 + SH_C0 * SH DC coefficient)
NO_COLOUR_GREY = 0.7  # what the viewer and the previews draw Gaussians of a splat without colour in


def to_float32(x: Any) -> np.ndarray:
    """A torch tensor (any device) or array-like -> a float32 numpy copy (detached, on the CPU)."""
    if isinstance(x, Tensor):
        return x.detach().to("cpu", torch.float32, copy=True).numpy()
    return np.array(x, dtype=np.float32)


def rgb_to_dc(rgb: Any) -> np.ndarray:
    """Colours in [0, 1] [N, 3] -> SH DC coefficients [N, 3] (float32) whose ``rgb()`` gives them back."""
    return (to_float32(rgb) - np.float32(0.5)) / np.float32(SH_C0)


@dataclass
class SplatParams:
    """N Gaussians' raw parameters (numpy; float32 unless a file stores another type)."""

    means: np.ndarray  # [N, 3] centres, scene units
    quats_wxyz: np.ndarray  # [N, 4] rotations (w, x, y, z), not necessarily unit length
    log_scales: np.ndarray  # [N, 3] log of the 1-sigma scales along the Gaussian's axes
    opacity_logits: np.ndarray  # [N] logit of the opacity
    colors_dc: Optional[np.ndarray] = None  # [N, 3] SH DC coefficients (3DGS f_dc_*); None: no colour
    sh_rest: Optional[np.ndarray] = None  # [N, K] higher SH bands (3DGS f_rest_* in file order); None: absent
    latents: Optional[np.ndarray] = None  # [N, C] cinesplat's distilled semantic codes; None: no semantics
    extra: Dict[str, np.ndarray] = field(default_factory=dict)  # any other per-Gaussian property [N] (.ply files)

    @classmethod
    def of(cls, means: Any, quats_wxyz: Any, log_scales: Any, opacity_logits: Any, colors_dc: Any = None,
           latents: Any = None) -> "SplatParams":
        """From tensors (any device) or arrays, as float32 numpy copies; opacity_logits [N] or [N, 1]."""
        opt = lambda x: None if x is None else to_float32(x)  # noqa: E731
        return cls(to_float32(means), to_float32(quats_wxyz), to_float32(log_scales),
                   to_float32(opacity_logits).reshape(-1), colors_dc=opt(colors_dc), latents=opt(latents))

    def __len__(self) -> int:
        return int(self.means.shape[0])

    def rgb(self, default: Optional[float] = None) -> Optional[np.ndarray]:
        """Base colour [N, 3] in [0, 1] (SH degree 0, float32); without colors_dc: grey ``default``, or None."""
        if self.colors_dc is None:
            return None if default is None else np.full((len(self), 3), default, np.float32)
        return np.clip(0.5 + SH_C0 * self.colors_dc.astype(np.float32), 0.0, 1.0)

    def opacities(self) -> np.ndarray:
        """Activated opacities [N] in (0, 1) (float32)."""
        return (1.0 / (1.0 + np.exp(-self.opacity_logits.astype(np.float32)))).astype(np.float32)

    def subset(self, keep: Any) -> "SplatParams":
        """The Gaussians a bool mask [N] or an index array [K] selects (every per-Gaussian array)."""
        keep = keep.detach().cpu().numpy() if isinstance(keep, Tensor) else np.asarray(keep)
        pick = lambda a: None if a is None else a[keep]  # noqa: E731
        return replace(self, means=self.means[keep], quats_wxyz=self.quats_wxyz[keep],
                       log_scales=self.log_scales[keep], opacity_logits=self.opacity_logits[keep],
                       colors_dc=pick(self.colors_dc), sh_rest=pick(self.sh_rest), latents=pick(self.latents),
                       extra={k: v[keep] for k, v in self.extra.items()})

    def tensors(self, device: Any = None, dtype: torch.dtype = torch.float32) -> Tuple[Tensor, Tensor, Tensor, Tensor]:
        """(means [N, 3], quats_wxyz [N, 4], log_scales [N, 3], opacity_logits [N]) as torch tensors on ``device``."""
        t = lambda a: torch.as_tensor(np.asarray(a), device=device).to(dtype)  # noqa: E731
        return t(self.means), t(self.quats_wxyz), t(self.log_scales), t(self.opacity_logits).reshape(-1)
