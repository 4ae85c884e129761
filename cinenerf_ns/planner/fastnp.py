"""Cheaper spellings of numpy calls the per-request hot paths make many times (a plan is thousands of small calls).

``clip(x, lo, hi)`` is the ufunc behind ``np.clip``: the same elementwise rule (NaN kept, ties give the bound), so
bit-identical results for numpy inputs, without np.clip's Python dispatch (a few microseconds a call). Only for
numpy arrays / scalars: np.clip of a torch tensor dispatches to the tensor's own clip, this does not."""
from __future__ import annotations

import numpy as np

try:  # numpy >= 2
    from numpy._core.umath import clip
except ImportError:  # pragma: no cover - numpy 1.x
    try:
        from numpy.core.umath import clip
    except ImportError:
        clip = np.clip

__all__ = ["clip"]
