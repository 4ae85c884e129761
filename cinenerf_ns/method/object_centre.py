"""Where an object *is*: the centroid of its volume, estimated from the Gaussians on its surface.

A trained splat puts its Gaussians on visible surfaces, so the mean of an object's Gaussians is a *surface*
centroid. For a floor lamp (a wide shade on a long thin pole) that is far from the object's middle: the pole
and the base own many Gaussians but little volume (synthetic room: the lamp's own true Gaussians average 7.8%
of the room size away from its volume centroid; sofa and armchair ~4%). The camera should look at the object,
not at the surface-weighted middle of its parts.

Estimate (approximate; documented in the README):

1. voxelise the selection in a frame whose third axis is the world up, voxel = longest side / ``resolution``:
   every Gaussian marks the voxels its 1-sigma ellipsoid touches (capped at ``max_extent_voxels``, so one
   huge Gaussian cannot smear the object); a morphological closing (``close`` voxels) seals small holes
   between Gaussians. These are the *surface* voxels.
2. a voxel is *inside* if surface voxels lie on both sides of it along both horizontal axes, and on at least
   one side vertically. Why one vertical side: captures rarely see the top of a tall object or the underside
   of anything, so those faces are often missing. Why both horizontal sides: open-fronted parts (the air
   under a table, an empty shelf) must stay outside.
3. the centroid of the filled voxels' centres (weights: volume, not Gaussian count). Voxels on the boundary of the
   filled set (a face-neighbour outside it) count ``surface_weight`` = 1/2: a boundary voxel is about half inside
   the object. (Not every voxel a Gaussian touches: splats also put Gaussians inside objects.)

Limits: thin parts (a lamp pole) are thickened to about a voxel, which biases the estimate toward them; an
object whose horizontal faces are open is under-filled; objects that are not closed on the sides (a hollow
tube seen from inside) are filled as if they were. Brute-force reference of step 2 in the tests.
"""
from __future__ import annotations

from typing import Optional, Sequence, Union

import numpy as np
import torch
from torch import Tensor

from cinenerf_ns.planner.scene import quat_wxyz_to_rotmat

ArrayLike = Union[Tensor, np.ndarray, Sequence]


def _np64(x: ArrayLike) -> np.ndarray:
    if isinstance(x, Tensor):
        x = x.detach().cpu()
    return np.asarray(x, dtype=np.float64)


def up_frame(up: ArrayLike = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Orthonormal [3, 3] (columns e1, e2, up/|up|): world -> frame coordinates are ``x @ F``."""
    u = _np64(up).reshape(3)
    n = float(np.linalg.norm(u))
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError(f"up must be a finite non-zero 3-vector, got {u.tolist()}")
    u = u / n
    helper = np.zeros(3)
    helper[int(np.argmin(np.abs(u)))] = 1.0
    e1 = np.cross(helper, u)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    return np.stack([e1, e2, u], axis=1)


def _unit_ball_stencil(n: int = 5) -> np.ndarray:
    """Points [S, 3] of an n^3 lattice on [-1, 1]^3 that lie in the unit ball (S = 33 for n = 5)."""
    g = np.linspace(-1.0, 1.0, n)
    p = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return p[np.linalg.norm(p, axis=1) <= 1.0 + 1e-9]


def enclosed_voxels(surface: np.ndarray) -> np.ndarray:  # noqa: D401
    """bool [X, Y, Z]: voxels with surface voxels on both sides along axes 0 and 1 and on at least one side
    along axis 2 (the up axis). ``surface`` itself counts as enclosed wherever it is set."""
    occ = np.asarray(surface, dtype=bool)
    out = occ.copy()
    enc = np.ones_like(occ)
    for ax in range(3):
        before = np.maximum.accumulate(occ, axis=ax)  # a surface voxel at or before this one along ax
        after = np.flip(np.maximum.accumulate(np.flip(occ, ax), axis=ax), ax)  # at or after
        enc &= (before | after) if ax == 2 else (before & after)
    return out | enc


def surface_voxels(
    points_frame: np.ndarray,  # [K, 3] Gaussian means in the up frame
    radii_frame: Optional[np.ndarray],  # [K, 3, 3] columns = the Gaussians' 1-sigma axes in the up frame, or None
    resolution: int,
    close: int,
    max_extent_voxels: float,
) -> tuple[np.ndarray, np.ndarray, float, int]:
    """(surface [X, Y, Z] bool: voxels the Gaussians touch, holes closed; lo [3]; voxel size; pad) of a selection
    (steps 1 of the module docstring; enclosed_voxels does step 2)."""
    from scipy import ndimage

    lo, hi = points_frame.min(0), points_frame.max(0)
    h = max(float((hi - lo).max()) / resolution, 1e-9)
    pad = 2 + close
    pts = points_frame
    if radii_frame is not None:
        axes = radii_frame.copy()  # [K, 3, 3]
        length = np.linalg.norm(axes, axis=1)  # [K, 3] per-axis sigma
        cap = max_extent_voxels * h
        keep = np.minimum(length, cap)
        axes *= (keep / np.maximum(length, 1e-300))[:, None, :]
        big = np.flatnonzero(keep.max(1) > 0.5 * h)  # smaller ones touch ~one voxel
        if big.size:
            st = _unit_ball_stencil()
            pts = np.concatenate([points_frame, (points_frame[big, None, :] + np.einsum("kij,sj->ksi", axes[big], st)).reshape(-1, 3)])
    lo = pts.min(0)  # the stencils may reach past the means (by <= max_extent_voxels voxels)
    ijk = np.floor((pts - lo) / h).astype(np.int64) + pad
    shape = tuple(ijk.max(0) + pad + 1)
    occ = np.zeros(shape, dtype=bool)
    occ[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = True
    if close > 0:
        occ |= ndimage.binary_closing(occ, iterations=int(close), border_value=0)
    return occ, lo, h, pad


def _eroded(solid: np.ndarray) -> np.ndarray:
    """bool: solid voxels whose 6 face-neighbours are all solid (outside the array counts as empty)."""
    p = np.pad(solid, 1, constant_values=False)
    out = p[1:-1, 1:-1, 1:-1].copy()
    for ax in range(3):
        for sh in (1, -1):
            out &= np.roll(p, sh, axis=ax)[1:-1, 1:-1, 1:-1]
    return out


def volume_centroid(
    means: ArrayLike,  # [K, 3]
    scales: Optional[ArrayLike] = None,  # [K, 3] activated (not log) 1-sigma scales, world units
    quats: Optional[ArrayLike] = None,  # [K, 4] wxyz
    up: ArrayLike = (0.0, 0.0, 1.0),
    resolution: int = 64,
    close: int = 1,
    max_extent_voxels: float = 4.0,
    surface_weight: float = 0.5,
) -> np.ndarray:
    """Estimated volume centroid [3] (float64, world units) of the object whose surface Gaussians are given.

    Without scales/quats only the means are voxelised (fine for dense selections). Fewer than 4 Gaussians:
    their mean. See the module docstring for the rule and its limits."""
    m = _np64(means).reshape(-1, 3)
    if m.shape[0] == 0:
        raise ValueError("volume_centroid needs at least one Gaussian")
    if not np.isfinite(m).all():
        raise ValueError("volume_centroid: means contain NaN/inf")
    if int(resolution) < 4:
        raise ValueError(f"resolution must be >= 4, got {resolution}")
    if m.shape[0] < 4:
        return m.mean(0)
    F = up_frame(up)
    pf = m @ F  # [K, 3]
    axes_f = None
    if scales is not None and quats is not None:
        s = _np64(scales).reshape(-1, 3)
        q = _np64(quats).reshape(-1, 4)
        if s.shape[0] != m.shape[0] or q.shape[0] != m.shape[0]:
            raise ValueError(f"volume_centroid: {m.shape[0]} means but {s.shape[0]} scales / {q.shape[0]} quats")
        ok = np.isfinite(s).all(1) & np.isfinite(q).all(1) & (np.linalg.norm(q, axis=1) > 0)
        s = np.where(ok[:, None], np.abs(s), 0.0)
        q = np.where(ok[:, None], q, np.array([1.0, 0.0, 0.0, 0.0]))
        R = quat_wxyz_to_rotmat(torch.from_numpy(q)).numpy()  # [K, 3, 3] world
        axes_f = np.einsum("ji,kjl->kil", F, R * s[:, None, :])  # F^T R diag(s): columns = axes in the frame
    surf, lo, h, pad = surface_voxels(pf, axes_f, int(resolution), int(close), float(max_extent_voxels))
    solid = enclosed_voxels(surf)
    boundary = solid & ~_eroded(solid)  # solid voxels with an outside face-neighbour: about half inside
    idx = np.argwhere(solid)  # [V, 3]
    w = np.where(boundary[idx[:, 0], idx[:, 1], idx[:, 2]], float(surface_weight), 1.0)
    c_frame = lo + ((idx * w[:, None]).sum(0) / w.sum() - pad + 0.5) * h
    return F @ c_frame
