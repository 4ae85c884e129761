"""The text a user types for a point ('x y z'), read the same by cinesplat-plan, both viewers and the scene loader:
a target box holds either three numbers or an object's name. Torch-free, so the commands check options before torch
loads."""
from __future__ import annotations

import re
from typing import List, Optional

import numpy as np

_SEPARATORS = re.compile(r"[\s,;\[\]()]+")


def number_tokens(text: str) -> List[str]:
    """The words of a typed list of numbers, split at spaces, commas, semicolons and brackets: '[1, 2; 3]' ->
    ['1', '2', '3'] (a point here, a box's six numbers in cli/plan_args.parse_region)."""
    return [t for t in _SEPARATORS.split(str(text or "").strip()) if t]


def parse_point(text: str) -> Optional[np.ndarray]:
    """'x y z' / 'x, y, z' / '[x, y, z]' / '(x; y; z)' -> [3] float64, non-finite values such as 'nan' kept for the
    caller to refuse in its own words (naming its option or box); None when the text is not three numbers (then it
    names an object)."""
    tokens = number_tokens(text)
    if len(tokens) != 3:
        return None
    try:
        return np.array([float(t) for t in tokens], dtype=np.float64)
    except ValueError:
        return None
