"""SplatParams: the one record of raw splat parameters (tensor / array inputs, colour, subsets, torch copies)."""
import numpy as np
import torch

from cinenerf_ns.planner.scene.splat_params import SH_C0, SplatParams, rgb_to_dc


def _splat(n=6):
    g = torch.Generator().manual_seed(0)
    return SplatParams.of(torch.randn(n, 3, generator=g, dtype=torch.float64), torch.randn(n, 4, generator=g),
                          torch.randn(n, 3, generator=g), torch.randn(n, 1, generator=g),
                          colors_dc=torch.randn(n, 3, generator=g), latents=torch.rand(n, 3, generator=g))


def test_of_makes_float32_numpy_copies():
    m = torch.zeros(4, 3)
    p = SplatParams.of(m, torch.ones(4, 4), torch.zeros(4, 3), torch.zeros(4, 1))
    m += 1.0
    assert isinstance(p.means, np.ndarray) and p.means.dtype == np.float32 and (p.means == 0).all()
    assert p.opacity_logits.shape == (4,) and len(p) == 4 and p.colors_dc is None and p.rgb() is None
    np.testing.assert_array_equal(p.rgb(default=0.7), np.full((4, 3), 0.7, np.float32))
    np.testing.assert_allclose(p.opacities(), 0.5)


def test_rgb_is_the_sh_degree_0_colour_and_rgb_to_dc_its_inverse():
    p = _splat()
    np.testing.assert_allclose(p.rgb(), np.clip(0.5 + SH_C0 * p.colors_dc, 0, 1), rtol=0, atol=0)
    rgb = np.random.default_rng(0).uniform(0, 1, (6, 3)).astype(np.float32)
    np.testing.assert_allclose(SplatParams(p.means, p.quats_wxyz, p.log_scales, p.opacity_logits,
                                           colors_dc=rgb_to_dc(rgb)).rgb(), rgb, atol=1e-6)


def test_subset_and_tensors():
    p = _splat()
    p.extra["foo"] = np.arange(6.0)
    keep = np.array([True, False, True, False, False, True])
    s = p.subset(torch.as_tensor(keep))
    assert len(s) == 3 and s.latents.shape == (3, 3) and s.extra["foo"].tolist() == [0.0, 2.0, 5.0]
    np.testing.assert_array_equal(s.colors_dc, p.colors_dc[keep])
    m, q, ls, o = s.tensors(dtype=torch.float64)
    assert m.dtype == torch.float64 and q.shape == (3, 4) and ls.shape == (3, 3) and o.shape == (3,)
    np.testing.assert_array_equal(o.numpy(), s.opacity_logits.astype(np.float64))
