"""The floor (or table) under an object is not the object: drop the support layer from a text selection.

Features distilled into a splat bleed across contact: the floor Gaussians around a lamp's base carry some "lamp"
(synthetic room: the lamp's selection held ~10% floor Gaussians, and the volume estimate of its centre sank
0.06 scene units toward the floor: 2.9% of the room size). They are recognisable by their surroundings: the
selection's lowest Gaussians continue, outside the object's footprint, as a layer of *unselected* Gaussians at
the same height (the rest of the floor). So:

1. ring = unselected Gaussians whose horizontal distance to the selection's footprint is in [inner, outer] and
   whose height lies in the selection's bottom band [z_min - 5% H, z_min + ``band`` H] (H: the selection's
   height, heights along ``up``);
2. if the ring holds at least ``min_ring`` Gaussians, its ``top_quantile`` height is the top of the support
   layer, and the selected Gaussians at or below it are dropped, unless that would drop more than
   ``max_fraction`` of the selection (then the "layer" is something else, e.g. a wall beside the object, and
   nothing is dropped).

Approximate (documented in the README): an object whose own bottom part is flat and as wide as its
surroundings' layer (a rug) loses that part; a support surface with no free space around the object (an object
wedged into a corner on a narrow shelf) is not recognised.
"""
from __future__ import annotations

from typing import Sequence, Union

import numpy as np
import torch
from torch import Tensor

from cinenerf_ns.method.object_centre import up_frame


def drop_support_layer(
    means: Union[Tensor, np.ndarray],  # [N, 3] every Gaussian of the scene
    mask: Union[Tensor, np.ndarray],  # [N] bool: the selection
    up: Sequence[float] = (0.0, 0.0, 1.0),
    inner: float = 0.02,
    outer: float = 0.06,
    band: float = 0.15,
    top_quantile: float = 0.95,
    min_ring: int = 20,
    max_fraction: float = 0.2,
) -> Union[Tensor, np.ndarray]:
    """The selection [N] (same type and device as ``mask``) without the support layer it stands on (module
    docstring). inner, outer: the ring's horizontal distances to the footprint (scene units); band: fraction of
    the selection's height searched for the layer; returns ``mask`` unchanged when no layer is recognised."""
    if not (0.0 <= inner < outer):
        raise ValueError(f"drop_support_layer: need 0 <= inner < outer, got {inner}, {outer}")
    if not (0.0 < band <= 1.0 and 0.0 < top_quantile <= 1.0 and 0.0 <= max_fraction < 1.0):
        raise ValueError("drop_support_layer: band, top_quantile in (0, 1], max_fraction in [0, 1)")
    is_torch = isinstance(mask, Tensor)
    m_np = (mask.detach().cpu().numpy() if is_torch else np.asarray(mask)).astype(bool).reshape(-1)
    x = means.detach().cpu().double().numpy() if isinstance(means, Tensor) else np.asarray(means, dtype=np.float64)
    if x.shape != (m_np.shape[0], 3):
        raise ValueError(f"drop_support_layer: means {x.shape} and mask {m_np.shape} disagree")
    sel = np.flatnonzero(m_np)
    if sel.size < 4:
        return mask
    from scipy.spatial import cKDTree

    f = x @ up_frame(up)  # [N, 3] (e1, e2, up) coordinates
    z_sel = f[sel, 2]  # [S]
    z_min = float(z_sel.min())
    H = float(z_sel.max()) - z_min
    if H <= 0:
        return mask
    lo2, hi2 = f[sel, :2].min(0) - outer, f[sel, :2].max(0) + outer
    cand = np.flatnonzero(
        ~m_np & (f[:, 2] >= z_min - 0.05 * H) & (f[:, 2] <= z_min + band * H)
        & (f[:, 0] >= lo2[0]) & (f[:, 0] <= hi2[0]) & (f[:, 1] >= lo2[1]) & (f[:, 1] <= hi2[1])
    )  # [C] unselected, in the bottom band and near the footprint's box
    if cand.size < min_ring:
        return mask
    d, _ = cKDTree(f[sel, :2]).query(f[cand, :2])  # [C] horizontal distance to the footprint
    ring = cand[(d >= inner) & (d <= outer)]
    if ring.size < min_ring:
        return mask
    z_top = float(np.quantile(f[ring, 2], top_quantile))
    drop = sel[z_sel <= z_top]
    if drop.size == 0 or drop.size > max_fraction * sel.size:
        return mask
    out = m_np.copy()
    out[drop] = False
    if is_torch:
        return torch.from_numpy(out).to(mask.device)
    return out
