"""Size of the per-image feature map (shared by feature extraction, label maps and the model's loss)."""

from __future__ import annotations

from typing import Tuple


def feature_map_size(height: int, width: int, long_side: int) -> Tuple[int, int]:
    """Feature-map (h, w) for an image of (height, width): long side = ``long_side`` px (never upsampled),
    aspect ratio kept, at least 1 px."""
    s = min(1.0, long_side / max(height, width))
    return max(1, int(round(height * s))), max(1, int(round(width * s)))
