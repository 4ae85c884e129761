"""The float64 rasterization reference against closed-form cases (it is the oracle for the GPU latent pass)."""
from __future__ import annotations

import math

import pytest
import torch

from cinenerf_ns.method.render_reference import quat_to_rotmat, render_reference

EYE = torch.eye(4)
K = torch.tensor([[20.0, 0, 8.5], [0, 20.0, 8.5], [0, 0, 1]])  # pixel (8, 8)'s centre is the principal point


def _g(x, y, z, s, o, c):
    return (
        torch.tensor([[x, y, z]]),
        torch.tensor([[1.0, 0, 0, 0]]),
        torch.tensor([[s, s, s]]),
        torch.tensor([o]),
        torch.tensor([c]),
    )


def test_single_isotropic_gaussian_closed_form():
    means, quats, scales, op, col = _g(0, 0, 2.0, 0.1, 0.6, [1.0, 2.0, 3.0])
    img, acc = render_reference(means, quats, scales, op, col, EYE, K, 17, 17)
    var = (20.0 * 0.1 / 2.0) ** 2 + 0.3  # (f s / z)^2 + eps2d
    assert acc[8, 8, 0].item() == pytest.approx(0.6)
    assert img[8, 8].tolist() == pytest.approx([0.6, 1.2, 1.8])
    assert acc[8, 9, 0].item() == pytest.approx(0.6 * math.exp(-0.5 / var))
    assert acc[10, 11, 0].item() == pytest.approx(0.6 * math.exp(-0.5 * (4 + 9) / var))
    far = 0.6 * math.exp(-0.5 * 64 / var)
    assert far < 1 / 255 and acc[0, 0, 0].item() == 0.0  # below 1/255: skipped like gsplat


def test_front_to_back_compositing_and_near_plane():
    a = _g(0, 0, 1.0, 0.1, 0.5, [1.0, 0, 0])
    b = _g(0, 0, 3.0, 0.3, 0.8, [0, 1.0, 0])  # behind a
    c = _g(0, 0, 0.005, 0.1, 0.9, [0, 0, 1.0])  # in front of the near plane: dropped
    # pass them in the "wrong" order: the renderer must sort by depth
    parts = [torch.cat(t) for t in zip(b, c, a)]
    img, acc = render_reference(*parts, EYE, K, 17, 17)
    assert img[8, 8].tolist() == pytest.approx([0.5, 0.5 * 0.8, 0.0])
    assert acc[8, 8, 0].item() == pytest.approx(0.5 + 0.5 * 0.8)


def test_early_termination_and_alpha_clamp():
    parts = [torch.cat(t) for t in zip(*(_g(0, 0, 1.0 + i, 0.2, 1.0, [float(i)]) for i in range(3)))]
    img, acc = render_reference(*parts, EYE, K, 17, 17)
    # first Gaussian: alpha clamped to 0.999, T -> 1e-3; the second would take T to 1e-6 <= 1e-4: stop
    assert acc[8, 8, 0].item() == pytest.approx(0.999)
    assert img[8, 8, 0].item() == pytest.approx(0.0)


def test_quat_to_rotmat_orthonormal():
    q = torch.randn(20, 4, dtype=torch.float64)
    R = quat_to_rotmat(q)
    assert torch.allclose(R @ R.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(20, 3, 3), atol=1e-12)
    assert torch.allclose(torch.linalg.det(R), torch.ones(20, dtype=torch.float64))
