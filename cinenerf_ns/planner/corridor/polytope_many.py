"""All of a corridor's Prop-2 (host) segment polytopes in one compiled call (native/polytope.c:
cn_safe_polytopes_aabb).

``aabb_polytopes`` gives, per segment p0 -> p1, what ``polytope.aabb_polytope(np.stack([p0, p1]), scene, index,
np.minimum(p0, p1) - box_margin, np.maximum(p0, p1) + box_margin, ...)`` returns, bit for bit (planes, offsets, ids),
or None where that call would raise SeedNotFreeError or would not take the compiled path: the caller builds those
segments its own way (safe_corridor._segment_polytopes, which splits them). One ctypes call instead of one per
segment: ~20 us of Python and ctypes glue a polytope (the input and output blocks, 31 converted arguments, the
checks), with the box rows written by the compiled call. Its reference is aabb_polytope (tests/planner/test_native.py).
"""
from __future__ import annotations

import numpy as np
import torch

from ..geometry.native_scene import native_applies, native_arrays
from .polytope import Polytope, resolved_options
from .polytope_native import FIRST_CAP, NORMAL_CODE


def _fits(seeds: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """[K] bool: aabb_polytope's compiled-path test (polytope._box_fits with the seeds inside) per segment."""
    fin = np.isfinite(seeds).all(axis=(1, 2)) & np.isfinite(lo).all(axis=1) & np.isfinite(hi).all(axis=1)
    inside = ((seeds >= lo[:, None]) & (seeds <= hi[:, None])).all(axis=(1, 2))
    return fin & (hi > lo).all(axis=1) & inside


def aabb_polytopes(segments: list, scene, index, box_margin: float, **option_fields) -> list:
    """[Polytope | None] per (p0, p1) of ``segments`` (float64 numpy [3] each): aabb_polytope's polytope of the seeds
    [p0, p1] in their bounding box grown by ``box_margin``, or None (see the module docstring). option_fields: as
    aabb_polytope's (PolytopeOptions fields)."""
    K = len(segments)
    opts = resolved_options(None, option_fields)
    from ..native import safe_polytopes_aabb_c

    fn = safe_polytopes_aabb_c() if opts.backend == "auto" and opts.prune and native_applies(scene, index) else None
    if fn is None or K == 0:
        return [None] * K
    seeds = np.empty((K, 2, 3))
    for k, (p0, p1) in enumerate(segments):
        seeds[k, 0], seeds[k, 1] = p0, p1
    lo = np.minimum(seeds[:, 0], seeds[:, 1]) - box_margin  # as _segment_polytopes' boxes, row by row
    hi = np.maximum(seeds[:, 0], seeds[:, 1]) + box_margin
    ok = _fits(seeds, lo, hi) if opts.require_seed_inside else np.zeros(K, dtype=bool)
    out: list = [None] * K
    todo = np.flatnonzero(ok)
    if todo.size == 0:
        return out
    s_c, lo_c, hi_c = (np.ascontiguousarray(a[todo]) for a in (seeds, lo, hi))
    n_planes, b_planes, ids_planes, seg = _call(fn, scene, index, s_c, lo_c, hi_c, opts)
    perm = native_arrays(scene, index)["perm"]
    o = 0
    for j, k in enumerate(todo.tolist()):
        rows, F, nbad = seg[j].tolist()
        if nbad > 0:
            continue
        ids = perm[ids_planes[o + 6:o + 6 + F]]
        if rows > 6 + F:  # the stopped polytope's contradiction row
            ids = np.concatenate([ids, [-1]])
        out[k] = Polytope.from_numpy(n_planes[o:o + rows], b_planes[o:o + rows], torch.from_numpy(s_c[j]),
                                     torch.from_numpy(ids))
        o += rows
    return out


def _call(fn, scene, index, seeds: np.ndarray, lo: np.ndarray, hi: np.ndarray, opts):
    """One cn_safe_polytopes_aabb call (retried with a larger buffer until its rows fit) -> planes n [R, 3], b [R],
    ids [R] (native positions; box rows unset) and seg [K, 3]."""
    arr = native_arrays(scene, index)
    K = seeds.shape[0]
    r = float(scene.camera_radius)
    shrink = -1.0 if opts.stop_when_empty is None else float(opts.stop_when_empty)
    near = opts.near_fraction if opts.two_pass else 0.0
    seg = np.zeros((K, 3), dtype=np.int64)
    info = np.zeros(5, dtype=np.int64)
    cap = (FIRST_CAP + 7) * K
    while True:
        out = np.empty(7 * cap)  # planes n [cap, 3], b [cap], ids [cap], bad ids [cap], bad slacks [cap]
        op = out.ctypes.data
        R = int(fn(*arr["args"], seeds.ctypes.data, K, lo.ctypes.data, hi.ctypes.data, r, float(opts.margin),
                   NORMAL_CODE[opts.normal], int(bool(opts.require_seed_inside)), float(near), shrink, cap, op,
                   op + 8 * 3 * cap, op + 8 * 4 * cap, op + 8 * 5 * cap, op + 8 * 6 * cap, seg.ctypes.data,
                   info.ctypes.data))
        if R == -2:
            cap = max(2 * cap, int(info[2]) + 7 * K)
            continue
        if R < 0:
            raise MemoryError(f"the compiled safe polytopes failed (code {R})")
        break
    return out[:3 * cap].reshape(cap, 3), out[3 * cap:4 * cap], out[4 * cap:5 * cap].view(np.int64), seg

