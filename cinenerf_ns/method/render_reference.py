"""Pure-torch (float64) reference of gsplat's classic 3DGS rasterization, for testing the latent pass.

Follows gsplat 1.5.3 ``rasterization(..., rasterize_mode="classic", packed=False)``:
* world -> camera with the 4x4 ``viewmat``; EWA projection with the clamped Jacobian of ``_persp_proj``;
  ``eps2d`` (0.3 px^2) added to the 2D covariance;
* Gaussians with camera depth <= ``near_plane`` are dropped; front-to-back by depth;
* pixel centres at (x + 0.5, y + 0.5); alpha = min(0.999, o * exp(-0.5 d^T Sigma2d^-1 d)), skipped when
  alpha < 1/255; compositing stops *before* the Gaussian that would take transmittance to <= 1e-4.
Approximation: gsplat only evaluates a Gaussian inside the 16x16 tiles its 3-sigma box touches; here every
pixel sees every Gaussian. The two agree exactly when the image is a single tile (<= 16 x 16 px) and the
Gaussians project inside it, which is how the tests use it.
"""

from __future__ import annotations

from typing import Tuple

import torch
import torch.nn.functional as F
from torch import Tensor


def quat_to_rotmat(quats: Tensor) -> Tensor:
    """wxyz quaternions [N, 4] (any norm) -> rotation matrices [N, 3, 3]."""
    w, x, y, z = F.normalize(quats, dim=-1).unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        dim=-1,
    ).reshape(-1, 3, 3)


def render_reference(
    means: Tensor,  # [N, 3] world
    quats: Tensor,  # [N, 4] wxyz
    scales: Tensor,  # [N, 3] activated (exp of log-scales)
    opacities: Tensor,  # [N] activated (sigmoid of logits)
    colors: Tensor,  # [N, C]
    viewmat: Tensor,  # [4, 4] world -> camera (OpenCV: x right, y down, z forward)
    K: Tensor,  # [3, 3]
    width: int,
    height: int,
    near_plane: float = 0.01,
    eps2d: float = 0.3,
) -> Tuple[Tensor, Tensor]:
    """Returns (image [H, W, C], alpha [H, W, 1]) in float64."""
    d = torch.float64
    means, quats, scales, opacities, colors = (t.to(d) for t in (means, quats, scales, opacities, colors))
    viewmat, K = viewmat.to(d), K.to(d)
    R, t = viewmat[:3, :3], viewmat[:3, 3]
    mc = means @ R.T + t  # [N, 3]
    Rq = quat_to_rotmat(quats)
    M = Rq * scales[:, None, :]
    cov = M @ M.transpose(1, 2)  # [N, 3, 3]
    covc = R @ cov @ R.T
    tx, ty, tz = mc.unbind(-1)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    tan_fovx, tan_fovy = 0.5 * width / fx, 0.5 * height / fy
    lim_x_pos = (width - cx) / fx + 0.3 * tan_fovx
    lim_x_neg = cx / fx + 0.3 * tan_fovx
    lim_y_pos = (height - cy) / fy + 0.3 * tan_fovy
    lim_y_neg = cy / fy + 0.3 * tan_fovy
    txc = tz * torch.clamp(tx / tz, min=-lim_x_neg, max=lim_x_pos)
    tyc = tz * torch.clamp(ty / tz, min=-lim_y_neg, max=lim_y_pos)
    O = torch.zeros_like(tz)
    J = torch.stack([fx / tz, O, -fx * txc / tz**2, O, fy / tz, -fy * tyc / tz**2], -1).reshape(-1, 2, 3)
    cov2d = J @ covc @ J.transpose(1, 2) + eps2d * torch.eye(2, dtype=d, device=J.device)
    conic = torch.linalg.inv(cov2d)  # [N, 2, 2]
    m2d = torch.stack([fx * tx / tz + cx, fy * ty / tz + cy], -1)  # [N, 2]

    keep = tz > near_plane
    order = torch.argsort(tz[keep])
    idx = torch.nonzero(keep).squeeze(1)[order]
    m2d, conic, op, col = m2d[idx], conic[idx], opacities[idx], colors[idx]

    ys, xs = torch.meshgrid(torch.arange(height, dtype=d, device=J.device),
                            torch.arange(width, dtype=d, device=J.device), indexing="ij")
    pix = torch.stack([xs + 0.5, ys + 0.5], -1).reshape(-1, 2)  # [P, 2]
    delta = pix[:, None, :] - m2d[None]  # [P, N, 2]
    sigma = 0.5 * torch.einsum("pni,nij,pnj->pn", delta, conic, delta)
    alpha = torch.clamp_max(op[None] * torch.exp(-sigma), 0.999)  # [P, N]
    alpha = torch.where(alpha < 1.0 / 255.0, torch.zeros_like(alpha), alpha)
    t_incl = torch.cumprod(1 - alpha, dim=1)  # transmittance after each Gaussian
    t_excl = torch.cat([torch.ones_like(t_incl[:, :1]), t_incl[:, :-1]], dim=1)
    alive = t_incl > 1e-4  # monotone: once a Gaussian would end the ray, it and all later ones are skipped
    w = alpha * t_excl * alive
    img = (w @ col).reshape(height, width, -1)
    acc = w.sum(1).reshape(height, width, 1)
    return img, acc
