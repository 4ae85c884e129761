"""Per-Gaussian text relevancy (paper eq. 4) and object extraction. Pure torch (no nerfstudio / gsplat).

    rel_j = min_i  exp(t * q.d_j) / (exp(t * q.d_j) + exp(t * n_i.d_j)),   d_j = f_dec(l_j) (unit)

q: unit text embedding of the query, n_i: unit embeddings of the negatives, t: temperature (LERF uses 10,
t = 1 is eq. 4 as printed). The pairwise softmax is computed as sigmoid(t * (q.d - n_i.d)), which is the
same number without overflow.
"""

from __future__ import annotations

from typing import Callable, Optional, Tuple

import torch
import torch.nn.functional as F
from torch import Tensor

DEFAULT_NEGATIVES: Tuple[str, ...] = ("object", "things", "stuff", "texture")


class QueryError(ValueError):
    """A text query that cannot be answered (empty text, nothing relevant...). Message is user-facing."""


def relevancy_from_features(
    feats: Tensor,  # [N, D] decoded unit features
    text_emb: Tensor,  # [D]
    neg_emb: Tensor,  # [K, D]
    temperature: float = 10.0,
) -> Tensor:
    """Eq. 4 on already decoded features. Returns [N] in (0, 1)."""
    if neg_emb.ndim == 1:
        neg_emb = neg_emb[None]
    if neg_emb.shape[0] == 0:
        raise QueryError("relevancy needs at least one negative phrase")
    q = F.normalize(text_emb.to(feats).reshape(-1), dim=-1)  # [D]
    n = F.normalize(neg_emb.to(feats), dim=-1)  # [K, D]
    # one matmul: [N, D] x [D, 1+K]
    sims = feats @ torch.cat([q[:, None], n.T], dim=1)  # [N, 1+K]
    pair = torch.sigmoid(temperature * (sims[:, :1] - sims[:, 1:]))  # [N, K]
    return pair.min(dim=1).values  # [N]


def relevancy_from_cosines(sims: Tensor, temperature: float = 10.0) -> Tensor:
    """sims [N, 1+K]: cosine with the query (column 0) and the K negatives -> relevancy [N]."""
    if sims.shape[1] < 2:
        raise QueryError("relevancy needs at least one negative phrase")
    return torch.sigmoid(temperature * (sims[:, :1] - sims[:, 1:])).min(dim=1).values


CHUNK = 1 << 20
"""Gaussians decoded at once by relevancy (and by SemanticScene's sq_norms, so that both round alike)."""


def relevancy(
    latents: Tensor,  # [N, 3]
    codec,  # FeatureCodec (decode: [M,3] -> unit [M,D]) or any callable doing that
    text_emb: Tensor,  # [D]
    neg_emb: Tensor,  # [K, D]
    temperature: float = 10.0,
    chunk: int = CHUNK,
    fast: bool = True,
    sq_norms: Optional[Tensor] = None,  # [N]
) -> Tensor:
    """Eq. 4: decode each Gaussian's latent and compare with the query and the negatives -> [N].

    fast: use ``codec.decoded_cosines`` when the codec has it (same numbers without materialising the
    decoded [N, D] features; see FeatureCodec.decoded_cosines). sq_norms: ``codec.decoded_sq_norms(latents)``, the
    part of the fast path that does not depend on the text (SemanticScene keeps it for its queries)."""
    if neg_emb.ndim == 1:
        neg_emb = neg_emb[None]
    if neg_emb.shape[0] == 0:
        raise QueryError("relevancy needs at least one negative phrase")
    if fast and hasattr(codec, "decoded_cosines"):
        emb = torch.cat([text_emb.reshape(1, -1), neg_emb], dim=0)  # [1+K, D]
        out = [relevancy_from_cosines(codec.decoded_cosines(
                   latents[i : i + chunk], emb, None if sq_norms is None else sq_norms[i : i + chunk]), temperature)
               for i in range(0, latents.shape[0], chunk)]
        return torch.cat(out) if out else latents.new_zeros(0)
    decode: Callable[[Tensor], Tensor] = codec.decode if hasattr(codec, "decode") else codec
    out = []
    for i in range(0, latents.shape[0], chunk):
        d = decode(latents[i : i + chunk])  # [n, D]
        out.append(relevancy_from_features(d, text_emb, neg_emb, temperature))
    if not out:
        return latents.new_zeros(0)
    return torch.cat(out)


def relevancy_mask(rel: Tensor, threshold: float = 0.5, opacities: Optional[Tensor] = None,
                   min_opacity: float = 0.0) -> Tensor:
    """Gaussians that belong to the object: rel > threshold (and opacity >= min_opacity). -> bool [N]."""
    mask = rel > threshold
    if opacities is not None and min_opacity > 0:
        mask = mask & (opacities >= min_opacity)
    return mask


CORE_MIN_FRACTION = 0.25  # a core smaller than this share of the selection is not trusted (see centre_core)
CORE_MIN_COUNT = 4  # ... nor one of fewer Gaussians


def centre_core(
    rel: Tensor,  # [N] relevancy
    mask: Tensor,  # [N] bool, the object's selection
    core_threshold: float,
    selection_threshold: float,
    min_fraction: float = CORE_MIN_FRACTION,
    min_count: int = CORE_MIN_COUNT,
) -> Tensor:
    """The selection's confident core: the Gaussians of ``mask`` with relevancy above ``core_threshold``. -> bool [N].

    Why: Gaussians that only ever show through an object's pixels (behind it, beside it in a wall) carry its label
    weakly, just above the selection threshold; they belong in the selection (its extent), but they pull the
    estimated centre off (synthetic room 1: 146 armchair Gaussians behind the wall beside it). The centre is
    estimated from the core only. Returns ``mask`` itself (the rule is off) when ``core_threshold`` is at or below
    ``selection_threshold``, and falls back to ``mask`` when the core holds fewer than ``min_count`` Gaussians or less
    than ``min_fraction`` of the selection: an object selected only weakly has no core to trust."""
    if core_threshold <= selection_threshold:
        return mask
    core = mask & (rel > core_threshold)
    k, n = int(core.sum()), int(mask.sum())
    if k < min_count or k < min_fraction * n:
        return mask
    return core


def object_centroid_extent(
    means: Tensor,  # [N, 3]
    opacities: Tensor,  # [N] in [0, 1] (activated)
    mask: Tensor,  # bool [N]
    weights: Optional[Tensor] = None,  # [N] extra weights (e.g. relevancy)
) -> Tuple[Tensor, Tensor, Tensor]:
    """Opacity-weighted centroid [3], and the axis-aligned extent (lo [3], hi [3]) of the masked means."""
    if mask.sum() == 0:
        raise QueryError("no Gaussian passes the relevancy threshold")
    m = means[mask].double()
    w = opacities[mask].double().clamp_min(0)
    if weights is not None:
        w = w * weights[mask].double().clamp_min(0)
    if float(w.sum()) <= 0:
        w = torch.ones_like(w)
    c = (m * w[:, None]).sum(0) / w.sum()
    return c.to(means.dtype), m.min(0).values.to(means.dtype), m.max(0).values.to(means.dtype)
