"""Exact voxel traversal of segments: a segment proven safe by the occupancy grid alone.

Every point of a FREE voxel (a closed cube) keeps the camera ball clear (occupancy.py). So a segment is safe
if every voxel it passes through is free: no Corollary-1 query needed. The voxels a segment p0 -> p1 passes
through are found exactly (a supercover walk, Amanatides-Woo style, vectorised over many segments): in voxel
units u(t) = u0 + t (u1 - u0), the segment crosses a voxel face at t = (k - u0_a) / (u1_a - u0_a) for each
integer k strictly between u0_a and u1_a on each axis a. Between two consecutive crossings the open piece lies
inside ONE voxel, the one holding its midpoint, and the crossing points themselves lie on the faces of those
voxels (closed cubes). So "the midpoint voxel of every piece is free" proves the whole segment lies in free
closed voxels.

Rounding: the crossings and midpoints are float64 in voxel units (|u| <~ 10^3, error <~ 1e-13 voxel). A piece
too short for its midpoint to be placed reliably lies within that error of the computed midpoint, so every
midpoint also claims every voxel within EPS = 1e-9 voxel of it: a voxel
the segment passes through is never missed, whatever the rounding; the price is refusing segments that pass
within 1e-9 voxel of an occupied voxel's face, edge or corner.
"""
from __future__ import annotations

import numpy as np

from .ranges import group_ranks

EPS = 1e-9  # voxel units: a point this close to a voxel counts as touching it (see the module docstring)


def segment_voxels(u0: np.ndarray, u1: np.ndarray, eps: float = EPS) -> tuple[np.ndarray, np.ndarray]:
    """(owner [M] int64, voxel [M, 3] int64): a superset of the voxels that segments u0[i] -> u1[i] ([P, 3]
    float64, voxel units: voxel v spans [v, v + 1]) pass through (rows may repeat).

    Probes: the midpoint of every piece between consecutive face crossings (and the ends); each contributes every
    voxel within ``eps`` of it (1 voxel, or 2-8 at a face, edge or corner). A piece lies in the voxel of its
    midpoint; a piece too short for float64 to place its midpoint (shorter than ~1e-13 voxel) lies within eps of
    the computed midpoint. So no voxel the segment passes through is missed; the extra ones are within eps of
    the segment (conservative)."""
    u0 = np.asarray(u0, dtype=np.float64).reshape(-1, 3)
    u1 = np.asarray(u1, dtype=np.float64).reshape(-1, 3)
    P = u0.shape[0]
    if P == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3), dtype=np.int64)
    d = u1 - u0  # [P, 3]
    lo = np.minimum(u0, u1)
    hi = np.maximum(u0, u1)
    first = np.floor(lo) + 1.0  # first integer strictly above lo  [P, 3]
    count = np.maximum(np.ceil(hi) - first, 0.0).astype(np.int64)  # integers k with lo < k < hi  [P, 3]
    m = count.sum(1)  # crossings per segment  [P]
    M = int(m.max())
    t = np.full((P, M + 2), np.inf)  # 0, crossings, 1, then +inf padding
    t[:, 0] = 0.0
    col = np.ones(P, dtype=np.int64)
    for a in range(3):
        c = count[:, a]
        if not c.any():
            continue
        owner, rank = group_ranks(c)
        k = first[owner, a] + rank  # the integer planes  [C]
        pos = col[owner] + rank
        t[owner, pos] = np.clip((k - u0[owner, a]) / d[owner, a], 0.0, 1.0)
        col += c
    t[np.arange(P), col] = 1.0
    t.sort(axis=1)
    n_piece = m + 1  # pieces between 0, the crossings and 1
    owner, j = group_ranks(n_piece)
    tm = 0.5 * (t[owner, j] + t[owner, j + 1])  # piece midpoints  [R]
    probe_owner = owner
    u = u0[owner] + tm[:, None] * d[owner]  # [R, 3]
    a = np.floor(u - eps).astype(np.int64)
    b = np.floor(u + eps).astype(np.int64)
    corners = np.array(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij")).reshape(3, 8).T.astype(bool)  # [8, 3]
    vox = np.where(corners[None], b[:, None], a[:, None]).reshape(-1, 3)  # [R * 8, 3]
    own = np.repeat(probe_owner, 8)
    keep = np.ones(len(own), dtype=bool)
    dup = (a == b).all(1)  # the common case: one voxel, keep one copy of the 8
    keep.reshape(-1, 8)[dup, 1:] = False
    return own[keep], vox[keep]


def segments_free_native(fn, occ: np.ndarray, shape: np.ndarray, lo: np.ndarray, voxel_size: float, a: np.ndarray,
                         b: np.ndarray) -> np.ndarray:
    """One cn_segments_free call (native/gridpoly.c): occ [X, Y, Z] C-contiguous bool, shape [3] int64, lo [3] float64,
    a / b [P, 3] float64 -> bool [P] (segments_in_free_voxels' compiled path; a grid keeps occ and shape)."""
    a, b = np.ascontiguousarray(a, dtype=np.float64), np.ascontiguousarray(b, dtype=np.float64)
    res = np.zeros(a.shape[0], dtype=np.uint8)
    if fn(occ.ctypes.data, shape.ctypes.data, lo.ctypes.data, float(voxel_size), a.ctypes.data, b.ctypes.data,
          a.shape[0], EPS, res.ctypes.data) != 0:
        raise MemoryError("the compiled voxel walk ran out of memory")
    return res.view(bool)


def segments_in_free_voxels(occupied: np.ndarray, lo: np.ndarray, voxel_size: float, p0, p1,
                            backend: str = "auto") -> np.ndarray:
    """bool [P]: every point of segment p0[i] -> p1[i] (world, [P, 3]) lies in a free voxel of ``occupied``
    ([X, Y, Z] bool, voxel (i, j, k) spans lo + voxel_size * [i, i + 1] x ...); outside the grid counts as
    occupied. True proves the segment safe for the camera (module docstring); False proves nothing.
    backend: "auto" (native/gridpoly.c's cn_segments_free, the same probes, when it loads), "native" or "python"
    (segments_in_free_voxels_reference)."""
    a = np.asarray(p0, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(p1, dtype=np.float64).reshape(-1, 3)
    lo = np.asarray(lo, dtype=np.float64).reshape(3)
    out = np.zeros(a.shape[0], dtype=bool)
    from ..native import choose, segments_free_c

    fn = choose(backend, segments_free_c, "gridpoly", "voxel walk")
    if a.shape[0] == 0:
        return out
    if fn is not None:
        occ = np.ascontiguousarray(occupied, dtype=bool)
        return segments_free_native(fn, occ, np.asarray(occ.shape, dtype=np.int64), lo, voxel_size, a, b)
    return segments_in_free_voxels_reference(occupied, lo, voxel_size, a, b)


def segments_in_free_voxels_reference(occupied: np.ndarray, lo: np.ndarray, voxel_size: float, a: np.ndarray,
                                      b: np.ndarray) -> np.ndarray:
    """segments_in_free_voxels in numpy for segments a [P, 3] -> b [P, 3] (P >= 1): the reference of
    native/gridpoly.c's cn_segments_free (the same probes)."""
    owner, vox = segment_voxels((a - lo) / voxel_size, (b - lo) / voxel_size)
    shape = np.asarray(occupied.shape)
    inside = ((vox >= 0) & (vox < shape)).all(1)
    c = np.clip(vox, 0, shape - 1)
    bad = ~inside | occupied[c[:, 0], c[:, 1], c[:, 2]]
    blocked = np.zeros(a.shape[0], dtype=bool)
    np.logical_or.at(blocked, owner, bad)
    return ~blocked
