"""Pickling small CPU tensors as numpy arrays (a mixin for the planner's dataclasses that hold them).

Why: candidate workers send their shots back pickled (shots/workers.py), and a shot's corridor holds ~30 small
tensors (each polytope's planes, seed and ids). torch's own tensor pickling goes through its storage serialisation,
slow to load, paid one shot after another in the parent (docs/PLANNER_DEFAULTS.md). A numpy array loads in
microseconds, and torch.from_numpy gives the same tensor back (same
dtype, shape and values; CPU). Tensors on other devices, ones that need grad, and dtypes numpy lacks keep torch's
pickling.
"""
from __future__ import annotations

from typing import Any, Dict

import torch

_TAG = "__cinenerf_cpu_tensor__"


def _packed(v: Any) -> Any:
    if isinstance(v, torch.Tensor) and v.device.type == "cpu" and not v.requires_grad:
        try:
            return (_TAG, v.detach().numpy())
        except TypeError:  # a dtype numpy has no equivalent of (bfloat16, ...)
            return v
    return v


def _unpacked(v: Any) -> Any:
    if type(v) is tuple and len(v) == 2 and type(v[0]) is str and v[0] == _TAG:
        return torch.from_numpy(v[1])
    return v


class NumpyPickled:
    """Pickles its CPU tensor attributes as numpy arrays (module docstring); everything else as usual."""

    def __getstate__(self) -> Dict[str, Any]:
        return {k: _packed(v) for k, v in self.__dict__.items()}

    def __setstate__(self, state: Dict[str, Any]) -> None:
        self.__dict__.update({k: _unpacked(v) for k, v in state.items()})
