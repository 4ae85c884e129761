"""The floor (or table) under an object is not the object: drop the support layer from a text selection.

Features distilled into a splat bleed across contact: the floor Gaussians around a lamp's base carry some "lamp"
(synthetic room 0: the lamp's selection held ~10% floor Gaussians, and the volume estimate of its centre sank
0.06 scene units toward the floor: 2.9% of the room size), and floaters *below* a floor can carry the label of
what stands on it (room 1: 3% of the sofa's selection lay up to 0.36 units under the floor, 2.4% error). Both are
recognisable by the object's surroundings: around its footprint, the *unselected* Gaussians form a dense
horizontal layer at the support's height (the rest of the floor). So:

1. ring = unselected Gaussians whose horizontal distance to the selection's footprint is in [inner, outer] and
   whose height lies between the selection's lowest point and its median height (a support is below the
   object's middle; heights along ``up``);
2. histogram the ring's heights in bins of ``inner`` / 2; the layer is the run of bins around the fullest bin
   that hold at least a quarter of its count. It counts as a support layer only if it holds ``min_ring``
   Gaussians, its peak is ``prominence`` times the mean of the other bins (walls and clutter beside an object
   spread over all heights) and it is at most ``max_thickness`` of the selection's height thick;
3. the selected Gaussians at or below the layer's ``top_quantile`` height are dropped, unless that would drop
   more than ``max_fraction`` of the selection (then the "layer" is something else and nothing is dropped).

Approximate (documented in the README): an object whose own bottom part is flat and as wide as its
surroundings' layer (a rug) is never trimmed; a support surface with no free space around the object (an object
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
    top_quantile: float = 0.95,
    min_ring: int = 20,
    prominence: float = 4.0,
    max_thickness: float = 0.25,
    max_fraction: float = 0.2,
) -> Union[Tensor, np.ndarray]:
    """The selection [N] (same type and device as ``mask``) without the support layer it stands on and anything
    below it (module docstring). inner, outer: the ring's horizontal distances to the footprint (scene units);
    returns ``mask`` itself when no layer is recognised."""
    if not (0.0 < inner < outer):
        raise ValueError(f"drop_support_layer: need 0 < inner < outer, got {inner}, {outer}")
    if not (0.0 < top_quantile <= 1.0 and 0.0 <= max_fraction < 1.0 and max_thickness > 0 and prominence >= 1):
        raise ValueError("drop_support_layer: top_quantile in (0, 1], max_fraction in [0, 1), max_thickness > 0, "
                         "prominence >= 1")
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
    z_min, z_med = float(z_sel.min()), float(np.median(z_sel))
    H = float(z_sel.max()) - z_min
    if H <= 0 or z_med <= z_min:
        return mask
    lo2, hi2 = f[sel, :2].min(0) - outer, f[sel, :2].max(0) + outer
    cand = np.flatnonzero(
        ~m_np & (f[:, 2] >= z_min) & (f[:, 2] <= z_med)
        & (f[:, 0] >= lo2[0]) & (f[:, 0] <= hi2[0]) & (f[:, 1] >= lo2[1]) & (f[:, 1] <= hi2[1])
    )  # [C] unselected, below the selection's middle, near the footprint's box
    if cand.size < min_ring:
        return mask
    # [C] horizontal distance to the footprint, exact up to `outer` and inf beyond: the bound prunes the search (a
    # wall's footprint, a thin line of 136k points, took 1.8 s to query without it on the bundled room); scipy's bound
    # is strict, so it lies just above `outer`, which the ring includes
    d, _ = cKDTree(f[sel, :2]).query(f[cand, :2], distance_upper_bound=np.nextafter(outer, np.inf) * (1 + 1e-9))
    zr = f[cand[(d >= inner) & (d <= outer)], 2]  # [R] the ring's heights
    if zr.size < min_ring:
        return mask
    step = 0.5 * inner
    nb = max(1, int(np.ceil((z_med - z_min) / step)))
    counts, edges = np.histogram(zr, bins=nb, range=(z_min, z_min + nb * step))
    p = int(np.argmax(counts))
    a = b = p
    while a > 0 and counts[a - 1] >= 0.25 * counts[p]:
        a -= 1
    while b < nb - 1 and counts[b + 1] >= 0.25 * counts[p]:
        b += 1
    in_layer = int(counts[a:b + 1].sum())
    rest = np.concatenate([counts[:a], counts[b + 1:]])
    background = float(rest.mean()) if rest.size else 0.0
    if in_layer < min_ring or counts[p] < prominence * background or (b + 1 - a) * step > max_thickness * H:
        return mask
    layer = zr[(zr >= edges[a]) & (zr <= edges[b + 1])]
    z_top = float(np.quantile(layer, top_quantile))
    drop = sel[z_sel <= z_top]
    if drop.size == 0 or drop.size > max_fraction * sel.size:
        return mask
    out = m_np.copy()
    out[drop] = False
    if is_torch:
        return torch.from_numpy(out).to(mask.device)
    return out
