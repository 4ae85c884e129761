"""Line of sight from camera positions to target points, against the scene's ellipsoids.

A sight line is the segment x(t) = p + t (q - p), t in [0, t_end], from a camera centre p to a target q.
It is blocked by ellipsoid E_j = {x : |diag(1/a_j) R_j^T (x - mu_j)| <= 1} iff some point of the segment
lies in E_j. In the ellipsoid's unit-sphere frame the segment is w(t) = u + t v with
u = diag(1/a) R^T (p - mu), v = diag(1/a) R^T (q - p), so

    blocked  <=>  min_{t in [0, t_end]} |u + t v|^2 <= 1,   t* = clamp(-u.v / |v|^2, 0, t_end).

This closed form is exact (float64); the brute-force reference below solves the quadratic
|u + t v|^2 = 1 instead and checks its roots / end points.

The target object must not occlude itself (the look-at point is usually the centre of an object whose
surface Gaussians surround it). Two ways, combinable:
  * ``exclude``: bool mask [N] of Gaussians that never occlude (e.g. the object's own Gaussians from the
    semantic query / the procedural ground truth);
  * ``stop_distance``: the sight line stops this far before the target (t_end = 1 - stop / |q - p|),
    i.e. it ends where it enters the target's bounding sphere. Default choice in scoring: the object's
    bounding-sphere radius, because it needs no segmentation and works for any look-at point.
Ellipsoids here are the planner's obstacle ellipsoids (beta * opacity scaled, see scene/ellipsoids.py): the same
notion of "solid" as for collisions. Counting is exact (not conservative in either direction): the
broad phase only ever adds candidates, the narrow phase is the exact closed form.

Broad phase: each sight line is cut into pieces no longer than the finest cell of the spatial index
(GridIndex); the index returns every ellipsoid whose padded AABB meets a piece's AABB (a superset of
those touching the piece), and the narrow phase tests that piece (its t range) only. Pieces are
processed in chunks to bound memory. Same code on CPU and CUDA tensors.
"""
from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np
import torch
from torch import Tensor

from ..errors import InvalidInputError
from ..scene.ellipsoids import EllipsoidScene
from ..scene.spatial_index import GridIndex


def _as_points(x: Any, what: str, device) -> Tensor:
    t = torch.as_tensor(np.asarray(x, dtype=np.float64) if not isinstance(x, Tensor) else x, device=device)
    t = t.to(torch.float64)
    if t.ndim == 1 and t.shape[0] == 3:
        t = t[None]
    if t.ndim != 2 or t.shape[-1] != 3:
        raise InvalidInputError(f"{what} must be [P, 3] points, got shape {tuple(t.shape)}")
    if not bool(torch.isfinite(t).all()):
        raise InvalidInputError(f"{what} contain NaN or inf")
    return t


def _min_dist2_on_piece(u: Tensor, v: Tensor, t0: Tensor, t1: Tensor) -> Tensor:
    """min over t in [t0, t1] of |u + t v|^2; u, v [K, 3], t0, t1 [K] -> [K] (float64)."""
    vv = (v * v).sum(-1)
    t = torch.where(vv > 0, -(u * v).sum(-1) / vv.clamp_min(1e-300), t0)
    t = torch.minimum(torch.maximum(t, t0), t1)
    w = u + t[:, None] * v
    return (w * w).sum(-1)


def _local(x: Tensor, scene: EllipsoidScene, g: Tensor, translate: bool) -> Tensor:
    """diag(1/a) R^T (x - mu) (translate) or diag(1/a) R^T x for rows x [K, 3] and ellipsoids g [K]."""
    rot = scene.rotations.index_select(0, g).double()  # [K, 3, 3]
    rad = scene.radii.index_select(0, g).double()  # [K, 3]
    d = x - scene.means.index_select(0, g).double() if translate else x
    return (d[:, :, None] * rot).sum(-2) / rad


def _native_blocked(fn, a: Tensor, b: Tensor, scene: EllipsoidScene, index, piece_len: float,
                    exclude: Optional[Tensor], free_grid: Optional[tuple] = None) -> Tensor:
    """bool [L]: segment a[l] -> b[l] meets an ellipsoid (not excluded), through native/polytope.c."""
    from .native_scene import native_arrays

    arr = native_arrays(scene, index)
    p0 = np.ascontiguousarray(a.cpu().numpy(), dtype=np.float64)
    p1 = np.ascontiguousarray(b.cpu().numpy(), dtype=np.float64)
    skip = None
    if exclude is not None:  # the compiled code's ids are positions in Morton order (native_arrays' "perm")
        skip = np.ascontiguousarray(exclude.cpu().numpy()[arr["perm"]], dtype=np.uint8)
    out = np.zeros(p0.shape[0], dtype=np.uint8)
    occ = vlo = dims = None
    vs = 0.0
    if free_grid is not None:
        occ, vlo, vs, dims = free_grid
    fn(*arr["args"], p0.ctypes.data, p1.ctypes.data, p0.shape[0], float(piece_len),
       None if skip is None else skip.ctypes.data, out.ctypes.data,
       None if occ is None else occ.ctypes.data, None if vlo is None else vlo.ctypes.data, float(vs),
       None if dims is None else dims.ctypes.data)
    return torch.from_numpy(out.astype(bool)).to(a.device)


def sight_lines_blocked(
    cameras: Any,  # [T, 3]
    targets: Any,  # [S, 3] or [3]
    scene: EllipsoidScene,
    index: Optional[GridIndex] = None,
    exclude: Optional[Tensor] = None,  # [N] bool
    stop_distance: float = 0.0,
    chunk_pieces: int = 200_000,
    backend: str = "auto",
    free_grid: Optional[tuple] = None,
) -> Tensor:
    """bool [T, S]: True where the sight line camera t -> target s passes through an ellipsoid.

    index: the scene's GridIndex (built here if None: pass the planner's to reuse it).
    exclude: Gaussians that never occlude. stop_distance: the line stops this far before the target
    (scene units; lines shorter than it are never blocked). Runs on the scene's device.
    backend: "auto" (a CPU scene with a GridIndex on the CPU: the compiled test, native/polytope.c's
    cn_segments_blocked: the same pieces and the same piece test, one line at a time, stopping at its first hit),
    "native" (error if it does not apply) or "python". free_grid: the scene's occupancy grid as
    clearance_queries.free_voxel_grid gives it (the compiled test then skips the pieces that lie in free voxels: they
    cannot meet an ellipsoid; the same answer, cheaper); only for the occupancy grid of this very scene."""
    dev = scene.device
    cam = _as_points(cameras, "camera positions", dev)  # [T, 3]
    tgt = _as_points(targets, "target points", dev)  # [S, 3]
    if not (math.isfinite(stop_distance) and stop_distance >= 0):
        raise InvalidInputError(f"stop_distance must be finite and >= 0, got {stop_distance}")
    if exclude is not None:
        exclude = torch.as_tensor(exclude, device=dev)
        if exclude.dtype != torch.bool or exclude.shape != (len(scene),):
            raise InvalidInputError(f"exclude must be a bool mask [N={len(scene)}], got {exclude.dtype} "
                                    f"{tuple(exclude.shape)}")
    T, S = cam.shape[0], tgt.shape[0]
    blocked = torch.zeros(T * S, dtype=torch.bool, device=dev)
    if T == 0 or S == 0:
        return blocked.reshape(T, S)
    index = index if index is not None else GridIndex.build(scene)
    p = cam[:, None, :].expand(T, S, 3).reshape(-1, 3)  # [L, 3]
    q = tgt[None, :, :].expand(T, S, 3).reshape(-1, 3)  # [L, 3]
    length = (q - p).norm(dim=-1)  # [L]
    t_end = torch.where(length > stop_distance, 1 - stop_distance / length.clamp_min(1e-300), torch.zeros_like(length))
    live = torch.nonzero(t_end > 0).squeeze(-1)
    if live.numel() == 0:
        return blocked.reshape(T, S)
    piece_len = max(float(index.levels[0].cell), 1e-6)
    from ..native import choose, segments_blocked_c
    from .native_scene import native_applies

    fn = choose(backend, segments_blocked_c, "polytope", "sight-line test", applies=native_applies(scene, index),
                needs="a CPU scene and a GridIndex on the CPU")
    if fn is not None:
        blocked[live] = _native_blocked(fn, p[live], p[live] + t_end[live, None] * (q - p)[live], scene, index,
                                        piece_len, exclude, free_grid)
        return blocked.reshape(T, S)
    n_pieces = torch.clamp(torch.ceil(length[live] * t_end[live] / piece_len), min=1).long()  # [L']
    ends = torch.cumsum(n_pieces, 0)
    total = int(ends[-1])
    for c0 in range(0, total, chunk_pieces):
        pos = torch.arange(c0, min(total, c0 + chunk_pieces), device=dev)
        owner = torch.searchsorted(ends, pos, right=True)  # index into live
        k = pos - (ends - n_pieces).index_select(0, owner)
        line = live.index_select(0, owner)
        n = n_pieces.index_select(0, owner).double()
        te = t_end.index_select(0, line)
        t0 = te * k.double() / n
        t1 = te * (k + 1).double() / n
        pa, d = p.index_select(0, line), (q - p).index_select(0, line)
        a, b = pa + t0[:, None] * d, pa + t1[:, None] * d
        pi, gi = index.query_boxes(torch.minimum(a, b), torch.maximum(a, b))
        if exclude is not None and pi.numel():
            keep = ~exclude.index_select(0, gi)
            pi, gi = pi[keep], gi[keep]
        if pi.numel() == 0:
            continue
        li = line.index_select(0, pi)
        u = _local(p.index_select(0, li), scene, gi, True)
        v = _local(d.index_select(0, pi), scene, gi, False)
        hit = _min_dist2_on_piece(u, v, t0.index_select(0, pi), t1.index_select(0, pi)) <= 1.0
        blocked[li[hit]] = True
    return blocked.reshape(T, S)


def sight_lines_blocked_reference(
    cameras: np.ndarray, targets: np.ndarray, means: np.ndarray, rotations: np.ndarray, radii: np.ndarray,
    exclude: Optional[np.ndarray] = None, stop_distance: float = 0.0,
) -> np.ndarray:
    """Brute-force float64 reference of sight_lines_blocked: every line against every ellipsoid, by the
    roots of the quadratic |u + t v|^2 = 1 (no index, no closed-form minimum). Returns bool [T, S]."""
    cam = np.asarray(cameras, np.float64).reshape(-1, 3)
    tgt = np.asarray(targets, np.float64).reshape(-1, 3)
    out = np.zeros((len(cam), len(tgt)), dtype=bool)
    for i, p in enumerate(cam):
        for j, q in enumerate(tgt):
            L = np.linalg.norm(q - p)
            if L <= stop_distance:
                continue
            te = 1 - stop_distance / L
            for g in range(len(means)):
                if exclude is not None and exclude[g]:
                    continue
                u = (rotations[g].T @ (p - means[g])) / radii[g]
                v = (rotations[g].T @ (q - p)) / radii[g]
                A, B, C = v @ v, 2 * u @ v, u @ u - 1
                if C <= 0:  # the camera itself is inside
                    out[i, j] = True
                    break
                if A <= 0:
                    continue
                disc = B * B - 4 * A * C
                if disc < 0:
                    continue
                r0 = (-B - math.sqrt(disc)) / (2 * A)  # entry; exit r1 >= r0
                r1 = (-B + math.sqrt(disc)) / (2 * A)
                if r0 <= te and r1 >= 0:
                    out[i, j] = True
                    break
    return out


def occluded_fraction(blocked: Tensor) -> float:
    """Fraction of frames whose sight line(s) are blocked, averaged over target samples: blocked [T, S]."""
    return float(blocked.double().mean()) if blocked.numel() else 0.0
