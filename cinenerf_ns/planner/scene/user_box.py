"""A box the user gives (cinesplat-plan's --region, the viewers' region fold, a region stored in an export): six
numbers checked into two corners, with messages naming where the box came from. Torch-free: the commands check it
before torch loads."""
from __future__ import annotations

import numpy as np

from ..errors import InvalidInputError


def format_point(p: np.ndarray) -> str:
    """A point for an error message: "(x, y, z)" with 3 significant digits."""
    return "(" + ", ".join(f"{v:.3g}" for v in np.asarray(p, dtype=np.float64).reshape(-1)) + ")"


def user_box(bounds, what: str = "the planning region (--region)") -> tuple[np.ndarray, np.ndarray]:
    """(lo [3], hi [3]) float64 of a user box (lo, hi) or 6 numbers x0 y0 z0 x1 y1 z1; InvalidInputError naming
    ``what`` unless they are 6 finite numbers with lo < hi on every axis."""
    try:
        v = np.asarray([np.asarray(b, dtype=np.float64).reshape(-1) for b in bounds], dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as e:
        raise InvalidInputError(f"{what} must be 6 numbers 'x0 y0 z0 x1 y1 z1', got {bounds!r}") from e
    if v.shape != (6,):
        raise InvalidInputError(f"{what} must be 6 numbers 'x0 y0 z0 x1 y1 z1' (two corners), got {v.size} numbers")
    if not np.all(np.isfinite(v)):
        raise InvalidInputError(f"{what} must be 6 finite numbers, got {v.tolist()}")
    lo, hi = v[:3], v[3:]
    if not (hi > lo).all():
        axes = ", ".join("xyz"[i] for i in np.flatnonzero(hi <= lo))
        raise InvalidInputError(f"{what} is empty or inverted along {axes}: each of x0 y0 z0 must be below x1 y1 z1, "
                                f"got {format_point(lo)}..{format_point(hi)}")
    return lo, hi
