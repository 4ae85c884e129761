"""The broad phase of a safe polytope: which ellipsoids' camera-inflated bodies may meet its box (a superset: the
spatial index's cells, then a bounding-sphere test), optionally only in the part of the box that planes already kept
leave open (the two-pass query of polytope.py). Also what goal.py asks of the scene near a point or a window."""
from __future__ import annotations

import numpy as np
import torch
from torch import Tensor


def candidate_ids(scene, index, box_lo: Tensor, box_hi: Tensor) -> Tensor:
    """Ids [K] of ellipsoids whose camera-inflated body may meet the box (a superset: bounding-sphere
    test after the index's coarse AABB query). index: anything with query_box(lo[3], hi[3]) ->
    LongTensor, or None (then all ellipsoids are scanned)."""
    return candidates_near(scene, index, box_lo, box_hi)[0]


def candidates_near(scene, index, box_lo, box_hi, box_rot=None, planes=None, ids=None):
    """(ids [K] on the scene device, means [K, 3] float64 numpy, bounding radii [K] float64 numpy).
    box_rot [3, 3] (columns = box axes): the box is {x : lo <= box_rot^T x <= hi}.
    planes: optional (A [F, 3], b [F]) float64 numpy; then only ellipsoids whose inflated body may
    meet box ∩ {A x <= b} need to be returned (index cells beyond a plane are skipped; needs an index
    with ``query_box_in_planes`` and ``pad``, else ignored). ids: a precomputed id subset [K] to filter."""
    r = float(scene.camera_radius)
    dev = scene.means.device
    m = scene.means
    lo = torch.as_tensor(box_lo, device=dev).to(m.dtype)
    hi = torch.as_tensor(box_hi, device=dev).to(m.dtype)
    rot = None if box_rot is None else torch.as_tensor(box_rot, device=dev).to(m.dtype)
    if index is not None or ids is not None:
        if ids is None:
            if rot is None:
                qlo, qhi = lo, hi
            else:  # world AABB of the oriented box: centre +- |R| half-extents
                c = rot @ (0.5 * (lo + hi))
                h = rot.abs() @ (0.5 * (hi - lo))
                qlo, qhi = c - h, c + h
            if planes is not None and hasattr(index, "query_box_in_planes") and hasattr(index, "pad"):
                # padded AABB (pad p) grown by e = max(r - p, 0) contains the inflated body, so query
                # the region grown by e: box +- e and planes shifted by e |A_f|_1 (cube of half-width e)
                e = max(r - float(index.pad), 0.0) * (1 + 1e-9)
                A_p, b_p = planes
                ids = index.query_box_in_planes(qlo - e, qhi + e, torch.as_tensor(A_p, device=dev),
                                                torch.as_tensor(b_p + e * np.abs(A_p).sum(-1), device=dev))
            else:
                ids = index.query_box(qlo - r, qhi + r)
        ids = torch.as_tensor(ids, device=dev).long()
        if ids.numel() == 0:
            return ids, np.zeros((0, 3)), np.zeros(0)
        m = m[ids]
        amax = scene.radii[ids].max(-1).values
    else:
        ids = None
        amax = scene.radii.max(-1).values
    mb = m if rot is None else m @ rot  # means in box coordinates
    # distance from the mean to the box <= bounding-sphere radius + r (+ rounding slack)
    gap = (mb - torch.minimum(torch.maximum(mb, lo), hi)).norm(dim=-1)
    near = gap <= amax + r + 1e-6 * (1 + m.abs().max(-1).values)
    sel = torch.nonzero(near).squeeze(-1)
    out = ids[sel] if ids is not None else sel
    return out, f64_numpy(m[sel]), f64_numpy(amax[sel])


def f64_numpy(x: Tensor) -> np.ndarray:
    return x.detach().cpu().to(torch.float64).numpy()
