"""Pure-torch tiled rasteriser of the preview: the reference of the compiled kernel (native/raster.c).

Same semantics as gsplat 1.5.3's classic rasterization (and method/render_reference.py where that is exact):
projection with the clamped EWA Jacobian and eps2d, depth < near dropped, gsplat's opacity-aware box and
off-image cull, 16x16 tiles from gsplat's tile box, per tile the Gaussians in depth order (stable sort),
front-to-back compositing with alpha = min(0.999, o exp(-sigma)), alpha < 1/255 skipped and a pixel stopping
before the Gaussian that would take its transmittance to <= 1e-4. Works in the dtype of its inputs.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Tuple

import torch
from torch import Tensor

from cinenerf_ns.method.render_reference import quat_to_rotmat

TILE = 16
ALPHA_MIN = 1.0 / 255.0
NEAR_PLANE = 0.01  # depth below which a Gaussian is not drawn (every backend; gsplat's default)
EPS2D = 0.3  # added to the projected 2D covariance's diagonal, pixels^2 (every backend; gsplat's default)


@dataclass
class PreviewScene:
    """Activated Gaussians, ready to render (SH degree 0)."""

    means: Tensor  # [N, 3] world
    cov3d: Tensor  # [N, 6] xx xy xz yy yz zz (world)
    opacities: Tensor  # [N] in (0, 1)
    colors: Tensor  # [N, 3] in [0, 1]
    quats: Tensor  # [N, 4] wxyz (for gsplat)
    scales: Tensor  # [N, 3] activated (for gsplat)

    def __len__(self) -> int:
        return int(self.means.shape[0])

    def to(self, device=None, dtype=None) -> "PreviewScene":
        return PreviewScene(*(t.to(device=device, dtype=dtype) for t in
                              (self.means, self.cov3d, self.opacities, self.colors, self.quats, self.scales)))


def covariance6(quats: Tensor, scales: Tensor) -> Tensor:
    """[N, 6] upper triangle (xx xy xz yy yz zz) of R S S R^T from wxyz quats [N, 4] and scales [N, 3]."""
    M = quat_to_rotmat(quats) * scales[:, None, :]  # [N, 3, 3]
    C = M @ M.transpose(1, 2)  # [N, 3, 3]
    return torch.stack([C[:, 0, 0], C[:, 0, 1], C[:, 0, 2], C[:, 1, 1], C[:, 1, 2], C[:, 2, 2]], -1)


def make_scene(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
               dtype: torch.dtype = torch.float32, drop_transparent: bool = True) -> PreviewScene:
    """Scene from activated parameters (scales = exp(log-scales), opacities = sigmoid(logits)). Gaussians with
    opacity < 1/255 are dropped (gsplat culls them in every view) unless drop_transparent is False."""
    keep = opacities.reshape(-1) >= ALPHA_MIN if drop_transparent else slice(None)
    q = quats[keep].to(torch.float64)
    s = scales[keep].to(torch.float64)
    cov = covariance6(q, s)
    return PreviewScene(means[keep].to(dtype).contiguous(), cov.to(dtype).contiguous(),
                        opacities.reshape(-1)[keep].to(dtype).contiguous(), colors[keep].to(dtype).contiguous(),
                        q.to(dtype).contiguous(), s.to(dtype).contiguous())


def project(scene: PreviewScene, viewmat: Tensor, intrinsics: Tuple[float, float, float, float], width: int,
            height: int, near_plane: float = NEAR_PLANE, eps2d: float = EPS2D) -> Dict[str, Tensor]:
    """Visible Gaussians of one camera: index [M], means2d [M, 2], conics [M, 3] (a b c), depths [M],
    radii [M, 2] (pixels, integer valued), in the scene's dtype. viewmat [4, 4] world -> camera (OpenCV)."""
    dt = scene.means.dtype
    V = viewmat.to(dt)
    R, t = V[:3, :3], V[:3, 3]
    fx, fy, cx, cy = (torch.tensor(v, dtype=dt) for v in intrinsics)
    mc = scene.means @ R.T + t  # [N, 3]
    c = scene.cov3d
    S = torch.stack([c[:, 0], c[:, 1], c[:, 2], c[:, 1], c[:, 3], c[:, 4], c[:, 2], c[:, 4], c[:, 5]],
                    -1).reshape(-1, 3, 3)
    C = R @ S @ R.T  # [N, 3, 3]
    x, y, z = mc.unbind(-1)
    W, H = torch.tensor(float(width), dtype=dt), torch.tensor(float(height), dtype=dt)
    tan_x, tan_y = 0.5 * W / fx, 0.5 * H / fy
    lxp, lxn = (W - cx) / fx + 0.3 * tan_x, cx / fx + 0.3 * tan_x
    lyp, lyn = (H - cy) / fy + 0.3 * tan_y, cy / fy + 0.3 * tan_y
    rz = 1.0 / z
    tx = z * torch.minimum(torch.maximum(x * rz, -lxn), lxp)
    ty = z * torch.minimum(torch.maximum(y * rz, -lyn), lyp)
    j00, j02, j11, j12 = fx * rz, -fx * tx * rz * rz, fy * rz, -fy * ty * rz * rz
    a0, a1, a2 = (j00 * C[:, 0, 0] + j02 * C[:, 2, 0], j00 * C[:, 0, 1] + j02 * C[:, 2, 1],
                  j00 * C[:, 0, 2] + j02 * C[:, 2, 2])
    b1, b2 = j11 * C[:, 1, 1] + j12 * C[:, 2, 1], j11 * C[:, 1, 2] + j12 * C[:, 2, 2]
    sxx = a0 * j00 + a2 * j02 + eps2d
    sxy = a1 * j11 + a2 * j12
    syy = b1 * j11 + b2 * j12 + eps2d
    det = sxx * syy - sxy * sxy
    o = scene.opacities
    ext = torch.clamp_max(torch.sqrt(2.0 * torch.log(torch.clamp_min(o, ALPHA_MIN) / ALPHA_MIN)), 3.33)
    rx, ry = torch.ceil(ext * torch.sqrt(sxx.clamp_min(0))), torch.ceil(ext * torch.sqrt(syy.clamp_min(0)))
    mx, my = fx * x * rz + cx, fy * y * rz + cy
    ok = (z >= near_plane) & (det > 0) & (o >= ALPHA_MIN) & ((rx > 0) | (ry > 0))
    ok &= ~((mx + rx <= 0) | (mx - rx >= W) | (my + ry <= 0) | (my - ry >= H))
    idx = torch.nonzero(ok).squeeze(1)  # [M]
    d = det[idx]
    return {
        "index": idx,
        "means2d": torch.stack([mx[idx], my[idx]], -1),  # [M, 2]
        "conics": torch.stack([syy[idx] / d, -sxy[idx] / d, sxx[idx] / d], -1),  # [M, 3]
        "depths": z[idx],  # [M]
        "radii": torch.stack([rx[idx], ry[idx]], -1),  # [M, 2]
    }


def tile_boxes(means2d: Tensor, radii: Tensor, tiles_x: int, tiles_y: int) -> Tensor:
    """gsplat's tile box of each Gaussian: [M, 4] (x0, x1, y0, y1), max exclusive, clamped to the grid."""
    c, r = means2d / TILE, radii / TILE
    lo, hi = torch.floor(c - r), torch.ceil(c + r)
    x0, x1 = lo[:, 0].clamp(0, tiles_x), hi[:, 0].clamp(0, tiles_x)
    y0, y1 = lo[:, 1].clamp(0, tiles_y), hi[:, 1].clamp(0, tiles_y)
    return torch.stack([x0, x1, y0, y1], -1).long()


def _tile_lists(boxes: Tensor, tiles_x: int, tiles_y: int) -> Tuple[Tensor, Tensor]:
    """(start [T + 1], list [I]): per tile, positions into the depth-sorted Gaussians, in depth order."""
    nx, ny = boxes[:, 1] - boxes[:, 0], boxes[:, 3] - boxes[:, 2]
    counts = nx * ny  # [M]
    g = torch.repeat_interleave(torch.arange(len(boxes)), counts)  # [I] Gaussian (depth position) of each hit
    first = torch.cumsum(counts, 0) - counts
    k = torch.arange(len(g)) - first[g]  # [I] index inside the Gaussian's box
    tx, ty = boxes[g, 0] + k % nx[g].clamp_min(1), boxes[g, 2] + k // nx[g].clamp_min(1)
    tile = ty * tiles_x + tx
    order = torch.sort(tile, stable=True).indices  # keeps depth order within a tile
    start = torch.zeros(tiles_x * tiles_y + 1, dtype=torch.long)
    start[1:] = torch.cumsum(torch.bincount(tile, minlength=tiles_x * tiles_y), 0)
    return start, g[order]


def _composite_tile(pix: Tensor, m2d: Tensor, con: Tensor, op: Tensor, col: Tensor, chunk: int = 2048):
    """Front-to-back compositing of pixel centres pix [P, 2] over depth-ordered Gaussians; (rgb [P, 3], T [P])."""
    P, dt = pix.shape[0], pix.dtype
    T = torch.ones(P, dtype=dt)
    rgb = torch.zeros(P, 3, dtype=dt)
    done = torch.zeros(P, dtype=torch.bool)
    for s in range(0, len(op), chunk):
        d = m2d[None, s:s + chunk] - pix[:, None]  # [P, K, 2]
        dx, dy = d[..., 0], d[..., 1]
        a, b, c = con[s:s + chunk].unbind(-1)
        sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy  # [P, K]
        alpha = torch.clamp_max(op[s:s + chunk] * torch.exp(-sigma), 0.999)
        alpha = torch.where((sigma < 0) | (alpha < ALPHA_MIN), torch.zeros_like(alpha), alpha)
        t_incl = T[:, None] * torch.cumprod(1 - alpha, dim=1)  # transmittance after each Gaussian
        alive = (t_incl > 1e-4) & ~done[:, None]  # a prefix of the chunk: t_incl never increases
        t_excl = torch.cat([T[:, None], t_incl[:, :-1]], dim=1)
        w = torch.where(alive, alpha * t_excl, torch.zeros_like(alpha))
        rgb = rgb + w @ col[s:s + chunk]
        T = torch.where(done, T, T * torch.prod(torch.where(alive, 1 - alpha, torch.ones_like(alpha)), dim=1))
        done = done | ~alive.all(dim=1)
        if bool(done.all()):
            break
    return rgb, T


def raster_reference(scene: PreviewScene, viewmat: Tensor, intrinsics: Tuple[float, float, float, float], width: int,
                 height: int, near_plane: float = NEAR_PLANE, eps2d: float = EPS2D) -> Tuple[Tensor, Tensor]:
    """(premultiplied rgb [H, W, 3], alpha [H, W, 1]) of one camera, in the scene's dtype (CPU)."""
    dt = scene.means.dtype
    pr = project(scene, viewmat, intrinsics, width, height, near_plane, eps2d)
    order = torch.sort(pr["depths"], stable=True).indices  # ties keep the Gaussian order (as gsplat's radix sort)
    idx = pr["index"][order]
    m2d, con = pr["means2d"][order], pr["conics"][order]
    op, col = scene.opacities[idx], scene.colors[idx]
    tiles_x, tiles_y = (width + TILE - 1) // TILE, (height + TILE - 1) // TILE
    start, lst = _tile_lists(tile_boxes(m2d, pr["radii"][order], tiles_x, tiles_y), tiles_x, tiles_y)
    rgb = torch.zeros(height, width, 3, dtype=dt)
    T = torch.ones(height, width, dtype=dt)
    for tile in range(tiles_x * tiles_y):
        ids = lst[start[tile]:start[tile + 1]]
        if len(ids) == 0:
            continue
        x0, y0 = (tile % tiles_x) * TILE, (tile // tiles_x) * TILE
        x1, y1 = min(x0 + TILE, width), min(y0 + TILE, height)
        ys, xs = torch.meshgrid(torch.arange(y0, y1, dtype=dt), torch.arange(x0, x1, dtype=dt), indexing="ij")
        pix = torch.stack([xs + 0.5, ys + 0.5], -1).reshape(-1, 2)  # [P, 2]
        c, t = _composite_tile(pix, m2d[ids], con[ids], op[ids], col[ids])
        rgb[y0:y1, x0:x1] = c.reshape(y1 - y0, x1 - x0, 3)
        T[y0:y1, x0:x1] = t.reshape(y1 - y0, x1 - x0)
    return rgb, (1 - T)[..., None]
