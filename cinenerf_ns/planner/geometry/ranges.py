"""Ragged ranges laid end to end (numpy): group k holds counts[k] consecutive flat positions.

Used wherever per-item pieces or samples are generated in one vectorised batch (segment pieces, dense
samples along frame intervals, voxel-walk crossings). The torch twin for index queries is
spatial_index._expand_ranges.
"""
from __future__ import annotations

import numpy as np


def group_ranks(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """counts int [K] (>= 0) -> (owner [S], rank [S]) with S = sum(counts): flat position j belongs to group
    owner[j] and is its rank[j]-th member (0 .. counts[owner[j]] - 1)."""
    counts = np.asarray(counts, dtype=np.int64)
    owner = np.repeat(np.arange(len(counts)), counts)  # [S]
    rank = np.arange(owner.size) - (np.cumsum(counts) - counts)[owner]  # [S]
    return owner, rank
