"""torch>=2.6 weights_only loading of nerfstudio-style checkpoints; float schedules; offline LPIPS."""
from __future__ import annotations

import io
import urllib.error

import numpy as np
import pytest
import torch

import cinenerf_ns.method  # noqa: F401  (registers the safe globals, as nerfstudio's yaml load does)
from cinenerf_ns.method import compat
from cinenerf_ns.method.compat import UnavailableLPIPS, make_lpips, offline_safe_lpips


def _roundtrip(obj):
    buf = io.BytesIO()
    torch.save(obj, buf)
    buf.seek(0)
    return torch.load(buf, map_location="cpu", weights_only=True)


def test_stock_nerfstudio_scheduler_state_loads_weights_only():
    """The exact failure: nerfstudio's ExponentialDecayScheduler stores numpy float64 in _last_lr."""
    from nerfstudio.engine.schedulers import ExponentialDecaySchedulerConfig

    p = torch.nn.Parameter(torch.zeros(3))
    opt = torch.optim.Adam([p], lr=1e-3)
    sched = ExponentialDecaySchedulerConfig(lr_final=1e-5, max_steps=100).setup().get_scheduler(opt, 1e-3)
    opt.step()
    sched.step()
    state = {"schedulers": {"means": sched.state_dict()}, "x": np.float64(2.0), "d": np.dtype("float32")}
    assert any(isinstance(v, np.floating) for v in sched.state_dict()["_last_lr"])  # the numpy scalar is there
    back = _roundtrip(state)
    assert float(back["x"]) == 2.0 and back["d"] == np.dtype("float32")
    assert back["schedulers"]["means"]["_last_lr"] == pytest.approx(sched.state_dict()["_last_lr"])


def test_float_scheduler_has_no_numpy_and_same_schedule():
    from nerfstudio.engine.schedulers import ExponentialDecaySchedulerConfig

    from cinenerf_ns.method.schedulers import FloatExponentialDecaySchedulerConfig

    lrs = []
    for cfg in (ExponentialDecaySchedulerConfig, FloatExponentialDecaySchedulerConfig):
        p = torch.nn.Parameter(torch.zeros(3))
        opt = torch.optim.Adam([p], lr=1e-3)
        s = cfg(lr_final=1e-5, max_steps=50, warmup_steps=5, lr_pre_warmup=0).setup().get_scheduler(opt, 1e-3)
        seq = []
        for _ in range(20):
            opt.step()
            s.step()
            seq.append(opt.param_groups[0]["lr"])
        lrs.append(seq)
        if cfg is FloatExponentialDecaySchedulerConfig:
            sd = s.state_dict()
            assert all(type(v) is float for v in sd["_last_lr"] + sd["base_lrs"])
            assert all(type(g["lr"]) is float for g in opt.state_dict()["param_groups"])
    assert lrs[0] == pytest.approx(lrs[1], rel=1e-12)


def test_lpips_fallback_without_network(monkeypatch):
    import torchmetrics.image.lpip as lpip_mod

    def offline(*a, **k):
        raise urllib.error.URLError("Name or service not known")

    monkeypatch.setattr(lpip_mod, "LearnedPerceptualImagePatchSimilarity", offline)
    monkeypatch.setattr(compat, "_LPIPS_WARNED", False)
    printed = []
    import nerfstudio.utils.rich_utils as ru

    monkeypatch.setattr(ru.CONSOLE, "print", lambda *a, **k: printed.append(" ".join(map(str, a))))
    m1 = make_lpips("auto")
    m2 = make_lpips("auto")
    assert isinstance(m1, UnavailableLPIPS) and isinstance(m2, UnavailableLPIPS)
    assert torch.isnan(m1(torch.zeros(1, 3, 8, 8), torch.zeros(1, 3, 8, 8)))
    assert len(printed) == 1 and "LPIPS disabled" in printed[0]  # ONE warning per process


def test_lpips_used_when_available(monkeypatch):
    import torchmetrics.image.lpip as lpip_mod

    class FakeLPIPS(torch.nn.Module):
        def __init__(self, normalize=False):
            super().__init__()
            self.normalize = normalize

    monkeypatch.setattr(lpip_mod, "LearnedPerceptualImagePatchSimilarity", FakeLPIPS)
    m = make_lpips("auto")
    assert isinstance(m, FakeLPIPS) and m.normalize is True
    assert isinstance(make_lpips("off"), UnavailableLPIPS)


def test_offline_safe_lpips_patches_what_splatfacto_imports_and_restores(monkeypatch):
    import torchmetrics.image.lpip as lpip_mod

    orig = lpip_mod.LearnedPerceptualImagePatchSimilarity
    with offline_safe_lpips("off"):
        from torchmetrics.image.lpip import LearnedPerceptualImagePatchSimilarity as L  # as splatfacto does

        assert isinstance(L(normalize=True), UnavailableLPIPS)
    assert lpip_mod.LearnedPerceptualImagePatchSimilarity is orig


def test_cached_mode_never_downloads(monkeypatch):
    import torchmetrics.image.lpip as lpip_mod

    def must_not_be_called(*a, **k):
        raise AssertionError("download attempted")

    monkeypatch.setattr(lpip_mod, "LearnedPerceptualImagePatchSimilarity", must_not_be_called)
    monkeypatch.setattr(compat, "lpips_weights_cached", lambda: False)
    assert isinstance(make_lpips("cached"), UnavailableLPIPS)


def test_seed_points_load_without_open3d(tmp_path):
    """transforms.json `ply_file_path` seeds load through the project's .ply reader with nerfstudio's exact
    transform."""
    pytest.importorskip("nerfstudio")
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import Nerfstudio

    import cinenerf_ns.method.datamanager  # noqa: F401  (installs the patch)
    from cinenerf_ns.planner.scene.ply import write_ply_vertices

    try:
        import open3d  # noqa: F401
        pytest.skip("open3d is installed: nerfstudio's own reader is used")
    except ImportError:
        pass
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(50, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, size=(50, 3)).astype(np.uint8)
    v = np.empty(50, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for i, k in enumerate("xyz"):
        v[k] = xyz[:, i]
    for i, k in enumerate(("red", "green", "blue")):
        v[k] = rgb[:, i]
    path = tmp_path / "pc.ply"
    write_ply_vertices(path, v)
    T = torch.tensor([[0.0, -1.0, 0.0, 0.5], [1.0, 0.0, 0.0, -0.2], [0.0, 0.0, 1.0, 0.1]])
    out = Nerfstudio._load_3D_points(None, path, T, 0.25)
    expect = (torch.from_numpy(xyz).double() @ T[:, :3].double().T + T[:, 3].double()) * 0.25
    torch.testing.assert_close(out["points3D_xyz"].double(), expect, atol=1e-5, rtol=0)
    assert torch.equal(out["points3D_rgb"], torch.from_numpy(rgb))
