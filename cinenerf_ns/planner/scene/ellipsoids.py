"""A Gaussian splat seen as a union of ellipsoidal obstacles (paper Sec. III eq. 1, Sec. V).

Each Gaussian j becomes the ellipsoid E_j = {x : (x - mu_j)^T Sigma_j^{-1} (x - mu_j) <= 1} with
Sigma_j = R_j diag(radii_j^2) R_j^T and radii_j = beta * opacity_j * exp(log_scale_j).

Why the axes and not the covariance are scaled by beta*opacity: beta is a confidence multiple of
sigma (beta = 2 is the 2-sigma ellipsoid), which scales lengths. The paper's wording "scale the
covariances by beta*alpha" read literally would give axes sqrt(beta*alpha)*sigma; we take the length
reading and say so here and in the README.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Optional, Union

import torch
from torch import Tensor

from ..errors import EmptySceneError, InvalidInputError
from .scene_config import SceneConfig
from .splat_params import SplatParams


def quat_wxyz_to_rotmat(quats: Tensor) -> Tensor:
    """Unit quaternions (w, x, y, z) [..., 4] -> rotation matrices [..., 3, 3] (normalises first)."""
    q = quats / quats.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    rot = torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    )
    return rot.reshape(*q.shape[:-1], 3, 3)


@dataclass
class EllipsoidScene:
    """Obstacles of a scene: N ellipsoids plus the camera body radius."""

    means: Tensor  # [N, 3]
    rotations: Tensor  # [N, 3, 3] columns = principal axes in world coordinates
    radii: Tensor  # [N, 3] semi-axis lengths (already scaled by beta * opacity)
    opacities: Tensor  # [N]
    camera_radius: float = SceneConfig.camera_radius
    source_index: Optional[Tensor] = field(default=None)  # [N] index of each kept Gaussian in the input
    beta: float = SceneConfig.beta  # radii = beta * opacity * scale: the Gaussians' scales are radii / (beta * opacity)

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        if self.means.shape != (n, 3) or self.rotations.shape != (n, 3, 3) or self.radii.shape != (n, 3):
            raise InvalidInputError(
                f"EllipsoidScene shapes disagree: means {tuple(self.means.shape)}, rotations "
                f"{tuple(self.rotations.shape)}, radii {tuple(self.radii.shape)} (want [N,3], [N,3,3], [N,3])"
            )
        if self.opacities.shape != (n,):
            raise InvalidInputError(f"opacities must be [N]={n}, got {tuple(self.opacities.shape)}")
        if not (math.isfinite(self.camera_radius) and self.camera_radius >= 0):
            raise InvalidInputError(f"camera_radius must be a finite number >= 0, got {self.camera_radius}")

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_splat(
        cls,
        means: Tensor,  # [N, 3]
        quats_wxyz: Tensor,  # [N, 4]
        log_scales: Tensor,  # [N, 3]
        opacity_logits: Tensor,  # [N] or [N, 1]
        config: Optional[SceneConfig] = None,
    ) -> "EllipsoidScene":
        """Build obstacles from raw splat parameters (as stored by splatfacto / 3DGS).

        Degenerate Gaussians are repaired or dropped with ONE warning that counts them:
        non-finite parameters or zero/NaN quaternions are dropped, semi-axes are clamped up to
        ``min_axis``, Gaussians with an axis above ``max_axis`` or opacity below the floor are dropped.
        """
        cfg = config or SceneConfig()
        means = torch.as_tensor(means)
        if means.ndim != 2 or means.shape[-1] != 3:
            raise InvalidInputError(f"means must be [N, 3], got {tuple(means.shape)}")
        dtype = means.dtype if means.dtype in (torch.float32, torch.float64) else torch.float32
        means = means.to(dtype)
        quats = torch.as_tensor(quats_wxyz, device=means.device).to(dtype)
        log_scales = torch.as_tensor(log_scales, device=means.device).to(dtype)
        opacity_logits = torch.as_tensor(opacity_logits, device=means.device).to(dtype).reshape(-1)
        n = means.shape[0]
        if quats.shape != (n, 4) or log_scales.shape != (n, 3) or opacity_logits.shape != (n,):
            raise InvalidInputError(
                f"splat parameter shapes disagree: means {tuple(means.shape)}, quats {tuple(quats.shape)}, "
                f"log_scales {tuple(log_scales.shape)}, opacities {tuple(opacity_logits.shape)}"
            )
        qnorm = quats.norm(dim=-1)  # [N]
        finite = (
            torch.isfinite(means).all(-1)
            & torch.isfinite(quats).all(-1)
            & torch.isfinite(opacity_logits)
            & ~torch.isnan(log_scales).any(-1)
            & (qnorm > 1e-12)
        )
        opac = torch.sigmoid(opacity_logits)  # [N]
        # exp(+inf) = inf is caught by the max_axis / finiteness test below.
        radii = cfg.beta * opac[:, None] * torch.exp(log_scales)  # [N, 3]
        n_clamped = int(((radii < cfg.min_axis) & finite[:, None]).any(-1).sum())
        radii = radii.clamp_min(cfg.min_axis)
        huge = ~torch.isfinite(radii).all(-1)
        if cfg.max_axis is not None:
            huge |= (radii > cfg.max_axis).any(-1)
        faint = opac < cfg.opacity_floor
        keep = finite & ~huge & ~faint
        n_bad, n_huge = int((~finite).sum()), int((finite & huge).sum())
        if n_bad or n_huge or n_clamped:
            warnings.warn(
                f"splat repair: dropped {n_bad} Gaussians with NaN/inf parameters or zero quaternions, "
                f"dropped {n_huge} with huge scales, clamped {n_clamped} tiny semi-axes to {cfg.min_axis} "
                f"(of {n}); {int((finite & ~huge & faint).sum())} more are below the opacity floor "
                f"{cfg.opacity_floor} and are not obstacles",
                stacklevel=2,
            )
        idx = torch.nonzero(keep).squeeze(-1)
        if idx.numel() == 0:
            n_faint = int((finite & ~huge & faint).sum())
            why = [f"{k} {what}" for k, what in (
                (n_bad, "have NaN/inf positions, rotations or opacities (or zero quaternions)"),
                (n_huge, "have infinite scales" + ("" if cfg.max_axis is None else f" or a semi-axis over "
                                                   f"max_axis {cfg.max_axis:g}")),
                (n_faint, f"are fainter than the opacity floor {cfg.opacity_floor:g} (--opacity-floor)")) if k]
            fix = ("lower --opacity-floor" if n_faint == n else
                   "the scene file's values are unusable: check or re-export it")
            raise EmptySceneError(f"no obstacle left: of {n} Gaussians, {'; '.join(why)}; {fix}")
        return cls(
            means=means[idx],
            rotations=quat_wxyz_to_rotmat(quats[idx]),
            radii=radii[idx],
            opacities=opac[idx],
            camera_radius=float(cfg.camera_radius),
            source_index=idx,
            beta=float(cfg.beta),
        )

    @classmethod
    def from_params(
        cls,
        params: SplatParams,
        config: Optional[SceneConfig] = None,
        device: Union[str, torch.device, None] = None,
        dtype: torch.dtype = torch.float32,
    ) -> "EllipsoidScene":
        """Obstacles of a splat's parameters (see from_splat), built on ``device`` in ``dtype``."""
        return cls.from_splat(*params.tensors(device, dtype), config)

    @classmethod
    def from_ply(
        cls,
        path,
        config: Optional[SceneConfig] = None,
        device: Union[str, torch.device, None] = None,
        dtype: torch.dtype = torch.float32,
    ) -> "EllipsoidScene":
        """Obstacles from a standard 3DGS .ply (x,y,z, scale_* log, rot_* wxyz, opacity logit)."""
        from .ply import read_splat_ply

        return cls.from_params(read_splat_ply(path), config, device, dtype)

    # ------------------------------------------------------------------ helpers
    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def device(self) -> torch.device:
        return self.means.device

    @property
    def dtype(self) -> torch.dtype:
        return self.means.dtype

    def to(self, device: Union[str, torch.device, None] = None,
           dtype: Optional[torch.dtype] = None) -> "EllipsoidScene":
        def mv(t: Optional[Tensor]) -> Optional[Tensor]:
            if t is None:
                return None
            if t.is_floating_point():
                return t.to(device=device, dtype=dtype or t.dtype)
            return t.to(device=device)

        return EllipsoidScene(
            means=mv(self.means), rotations=mv(self.rotations), radii=mv(self.radii),
            opacities=mv(self.opacities), camera_radius=self.camera_radius, source_index=mv(self.source_index),
            beta=self.beta,
        )

    def subset(self, sel: Tensor) -> "EllipsoidScene":
        """Ellipsoids selected by a bool mask [N] or an index tensor [K]."""
        return EllipsoidScene(
            means=self.means[sel], rotations=self.rotations[sel], radii=self.radii[sel],
            opacities=self.opacities[sel], camera_radius=self.camera_radius,
            source_index=None if self.source_index is None else self.source_index[sel], beta=self.beta,
        )

    def covariances(self) -> Tensor:
        """Sigma_j = R diag(radii^2) R^T  [N, 3, 3]."""
        return (self.rotations * self.radii[:, None, :] ** 2) @ self.rotations.transpose(-1, -2)

    def half_extents(self) -> Tensor:
        """Exact half-widths of each ellipsoid's axis-aligned bounding box [N, 3]:
        h_k = sqrt(sum_i (R_ki r_i)^2) (support function along the world axes)."""
        return torch.sqrt(((self.rotations * self.radii[:, None, :]) ** 2).sum(-1))

    def aabb(self, pad: float = 0.0) -> tuple[Tensor, Tensor]:
        """Per-ellipsoid AABBs (lo [N,3], hi [N,3]) grown by ``pad``."""
        h = self.half_extents() + pad
        return self.means - h, self.means + h

    def bounds(self) -> tuple[Tensor, Tensor]:
        """Scene AABB (lo [3], hi [3]) of all ellipsoids."""
        lo, hi = self.aabb()
        return lo.min(0).values, hi.max(0).values
