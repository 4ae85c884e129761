"""A spatial-index stand-in that answers many box queries from ONE batched GridIndex query.

Polytope construction (polytope._candidates) asks the index for the ellipsoids near each corridor
segment's box, one ``query_box`` call per polytope. When the boxes are known in advance (all segments of
all K candidates' shortcut paths), ``PrefetchedIndex`` runs one ``GridIndex.query_boxes`` over slightly
grown versions of them and then answers each ``query_box(lo, hi)`` by filtering the prefetched list of a
box that contains [lo, hi] with the SAME exact padded-AABB overlap test as GridIndex.query_boxes, so the
answer is identical (same ids, ascending) to ``index.query_box(lo, hi)``. A query that no prefetched box
contains (e.g. an unforeseen box) goes to the real index. Everything else is delegated to the index.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torch import Tensor

from .errors import InvalidInputError
from .spatial_index import GridIndex


class PrefetchedIndex:
    """Answers ``query_box`` from one batched query over known boxes lo, hi [B, 3] (see module docstring)."""

    def __init__(self, index: GridIndex, lo: Any, hi: Any, grow: float = 1e-6) -> None:
        lo_t = torch.as_tensor(lo, device=index.device).double().reshape(-1, 3)
        hi_t = torch.as_tensor(hi, device=index.device).double().reshape(-1, 3)
        if lo_t.shape != hi_t.shape or not (torch.isfinite(lo_t).all() and torch.isfinite(hi_t).all()):
            raise InvalidInputError(f"prefetch boxes need finite lo, hi of equal shape [B, 3], got {tuple(lo_t.shape)}, {tuple(hi_t.shape)}")
        self.index = index
        self.pad = index.pad
        # grown so that boxes recomputed in float32 by the caller still fall inside
        g = grow * (1.0 + torch.maximum(lo_t.abs(), hi_t.abs()))
        lo_t, hi_t = lo_t - g, hi_t + g
        q, ids = index.query_boxes(lo_t, hi_t)  # [M] sorted by box
        n = max(len(index), 1)
        order = torch.argsort(q * n + ids)  # by box, then ascending id
        self.ids = ids[order]  # [M]
        counts = torch.bincount(q, minlength=lo_t.shape[0])
        self.offsets = np.concatenate([[0], np.cumsum(counts.cpu().numpy())])  # [B + 1]
        self.lo = lo_t.cpu().numpy()  # [B, 3]
        self.hi = hi_t.cpu().numpy()
        self.hits = 0
        self.misses = 0

    def __len__(self) -> int:
        return len(self.index)

    def __getattr__(self, name: str):  # everything but query_box: the real index
        return getattr(self.index, name)

    def query_box(self, lo: Tensor, hi: Tensor) -> Tensor:
        """Ids [K] (ascending) of the ellipsoids whose padded AABB meets the box [lo, hi] (== index.query_box)."""
        lo_d = torch.as_tensor(lo, device=self.index.device).double().reshape(3)
        hi_d = torch.as_tensor(hi, device=self.index.device).double().reshape(3)
        lo_n, hi_n = lo_d.cpu().numpy(), hi_d.cpu().numpy()
        inside = np.flatnonzero((self.lo <= lo_n).all(1) & (self.hi >= hi_n).all(1))
        if inside.size == 0 or not (np.isfinite(lo_n).all() and np.isfinite(hi_n).all()):
            self.misses += 1
            return self.index.query_box(lo_d, hi_d)
        self.hits += 1
        sizes = self.offsets[inside + 1] - self.offsets[inside]
        b = int(inside[int(np.argmin(sizes))])
        cand = self.ids[int(self.offsets[b]) : int(self.offsets[b + 1])]
        gb = self.index.boxes.index_select(0, cand)  # [C, 6] padded AABBs (float64)
        hit = (gb[:, :3] <= hi_d).all(-1) & (gb[:, 3:] >= lo_d).all(-1)  # GridIndex.query_boxes' exact test
        return cand[hit]


def corridor_prefetch(index: GridIndex, ways, box_margin: float, camera_radius: float) -> PrefetchedIndex:
    """PrefetchedIndex over the boxes build_corridor / safe_polytope will query for the polylines ``ways``
    (list of [K_i, 3]): each segment's AABB grown by box_margin (the polytope box) and the camera radius
    (the candidate query). Sub-boxes of split segments lie inside their segment's box."""
    lo, hi = [], []
    for w in ways:
        w = np.asarray(w, np.float64).reshape(-1, 3)
        if len(w) < 2:
            continue
        a, b = w[:-1], w[1:]
        lo.append(np.minimum(a, b) - box_margin - camera_radius)
        hi.append(np.maximum(a, b) + box_margin + camera_radius)
    if not lo:
        lo, hi = [np.zeros((0, 3))], [np.zeros((0, 3))]
    return PrefetchedIndex(index, np.concatenate(lo), np.concatenate(hi))
