"""The text a user types for a point ('x y z'), read the same by cinesplat-plan, both viewers and the scene loader:
a target box holds either three numbers or an object's name. Torch-free, so the commands check options before torch
loads."""
from __future__ import annotations

import re
from typing import Optional

import numpy as np

_SEPARATORS = re.compile(r"[\s,;\[\]()]+")


def parse_point(text: str) -> Optional[np.ndarray]:
    """'x y z' / 'x, y, z' / '[x, y, z]' / '(x; y; z)' -> [3] float64, non-finite values such as 'nan' kept for the
    caller to refuse with its own words (``finite_point``); None when the text is not three numbers (then it names an
    object)."""
    tokens = [t for t in _SEPARATORS.split((text or "").strip()) if t]
    if len(tokens) != 3:
        return None
    try:
        return np.array([float(t) for t in tokens], dtype=np.float64)
    except ValueError:
        return None
