"""tensor_pickle.NumpyPickled: Polytope and Corridor pickle their CPU tensors as numpy arrays and come back equal
(same dtype, shape, values, writable), with torch's pickling kept where numpy cannot hold the tensor."""
from __future__ import annotations

import copy
import pickle

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner.corridor.polytope import Polytope
from cinenerf_ns.planner.corridor.safe_corridor import Corridor
from cinenerf_ns.planner.tensor_pickle import NumpyPickled


def same(a, b) -> None:
    assert type(a) is type(b)
    if isinstance(a, torch.Tensor):
        assert a.dtype == b.dtype and a.shape == b.shape and a.device == b.device and torch.equal(a, b)
    else:
        assert a == b


@settings(max_examples=40, deadline=None)
@given(f=st.integers(0, 12), s=st.integers(1, 2), ids=st.booleans(),
       dtype=st.sampled_from([torch.float64, torch.float32]), proto=st.sampled_from([2, 4, 5]))
def test_polytope_and_corridor_round_trip(f, s, ids, dtype, proto):
    g = torch.Generator().manual_seed(f * 7 + s)
    p = Polytope(torch.randn(f, 3, generator=g, dtype=dtype), torch.randn(f, generator=g, dtype=dtype),
                 torch.randn(s, 3, generator=g, dtype=dtype), torch.arange(f) if ids else None)
    c = Corridor([p, p], torch.randn(3, 3, dtype=torch.float64), torch.tensor([0.5]), thin_joints=[0], n_splits=2,
                 region=(np.zeros(3), np.ones(3)))
    blob = pickle.dumps(c, protocol=proto)
    assert b"_rebuild_tensor" not in blob  # no tensor went through torch's storage pickling
    q = pickle.loads(blob)
    for name in ("A", "b", "seed", "ellipsoid_ids"):
        for k in range(2):
            same(getattr(q.polytopes[k], name), getattr(p, name))
    same(q.waypoints, c.waypoints)
    same(q.overlap_radius, c.overlap_radius)
    assert (q.thin_joints, q.n_splits) == (c.thin_joints, c.n_splits)
    assert all(np.array_equal(x, y) for x, y in zip(q.region, c.region))
    q.polytopes[0].A += 1.0  # writable, and its own memory
    same(p.A, c.polytopes[0].A)
    d = copy.deepcopy(c)
    same(d.waypoints, c.waypoints)


class Holder(NumpyPickled):
    def __init__(self):
        self.half = torch.ones(3, dtype=torch.bfloat16)
        self.grad = torch.ones(2, requires_grad=True)
        self.tag = ("__cinenerf_cpu_tensor__",)  # not a packed tensor: a tuple of one
        self.arr = (np.zeros(2), np.ones(2))  # a tuple whose first item is an array


def test_tensors_numpy_cannot_hold_keep_torch_pickling():
    h = pickle.loads(pickle.dumps(Holder()))
    assert h.half.dtype == torch.bfloat16 and torch.equal(h.half, torch.ones(3, dtype=torch.bfloat16))
    assert h.grad.requires_grad
    assert h.tag == ("__cinenerf_cpu_tensor__",)
    assert np.array_equal(h.arr[1], np.ones(2))


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device (run scripts/gpu_check.sh)")
def test_cuda_tensors_stay_on_their_device():
    p = Polytope(torch.ones(2, 3, device="cuda"), torch.ones(2, device="cuda"), torch.zeros(1, 3, device="cuda"))
    q = pickle.loads(pickle.dumps(p))
    assert q.A.device.type == "cuda" and torch.equal(q.A.cpu(), torch.ones(2, 3))
