"""Range checks of user options, shared by cinesplat-plan and cinesplat-viewer: a message naming the option and its
allowed range, raised before any expensive work."""
from __future__ import annotations

import math
import re
from typing import Any

import numpy as np

from cinenerf_ns.planner.errors import InvalidInputError


def check_number(value: Any, option: str, lo: float, hi: float, lo_open: bool = False, integer: bool = False) -> None:
    """InvalidInputError unless ``value`` is a finite number (an integer with ``integer``) in [lo, hi] ((lo, hi] with
    lo_open)."""
    ok = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    ok = ok and math.isfinite(float(value)) and (float(value) > lo if lo_open else float(value) >= lo)
    ok = ok and float(value) <= hi and (not integer or float(value) == int(value))
    if not ok:
        kind = "an integer" if integer else "a number"
        rng = f"({lo:g}, {hi:g}]" if lo_open else f"[{lo:g}, {hi:g}]"
        raise InvalidInputError(f"{option} must be {kind} in {rng}, got {value!r}")


def check_device(device: Any, option: str = "--device") -> str:
    """The torch device a command renders or plans on: 'cpu', 'cuda' or 'cuda:N' (N a CUDA device here);
    InvalidInputError otherwise ('tpu', 'mps', 'cuda' without CUDA) instead of running on the CPU without a word."""
    d = str(device).strip().lower()
    m = re.fullmatch(r"cuda(?::(\d{1,3}))?", d)
    if d != "cpu" and m is None:
        raise InvalidInputError(f"{option} must be 'cpu', 'cuda' or 'cuda:N', got {device!r}")
    if m is not None:
        import torch

        if not torch.cuda.is_available():
            raise InvalidInputError(f"{option} {device}: no CUDA device here; use {option} cpu")
        if m.group(1) is not None and int(m.group(1)) >= torch.cuda.device_count():
            raise InvalidInputError(f"{option} {device}: this machine has {torch.cuda.device_count()} CUDA "
                                    f"device(s), numbered from 0")
    return d
