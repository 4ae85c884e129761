"""Standalone viewer loading: 3DGS .ply, a run's config.yml + checkpoint, demo; CLI help."""
from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import yaml

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.viewer.demo import demo_scene
from cinenerf_ns.viewer.standalone import SH_C0, StandaloneConfig, StandaloneViewer, load_scene

REPO = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def write_3dgs_ply(path: Path, d) -> None:
    from plyfile import PlyData, PlyElement

    n = len(d.means)
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
             "rot_0", "rot_1", "rot_2", "rot_3"]
    arr = np.empty(n, dtype=[(k, "f4") for k in names])
    dc = (d.colors - 0.5) / SH_C0
    cols = [d.means[:, 0], d.means[:, 1], d.means[:, 2], dc[:, 0], dc[:, 1], dc[:, 2], d.opacity_logits,
            *d.log_scales.T, *d.quats_wxyz.T]
    for k, c in zip(names, cols):
        arr[k] = c
    PlyData([PlyElement.describe(arr, "vertex")]).write(str(path))


def test_load_ply_round_trip(tmp_path):
    d = demo_scene()
    write_3dgs_ply(tmp_path / "scene.ply", d)
    sc = load_scene(str(tmp_path / "scene.ply"))
    np.testing.assert_allclose(sc.splat.means, d.means, atol=1e-6)
    np.testing.assert_allclose(sc.splat.colors, d.colors, atol=1e-5)
    np.testing.assert_allclose(sc.splat.log_scales, d.log_scales, atol=1e-6)
    assert sc.data_dir == tmp_path and sc.config_path is None and sc.locate is None
    g = sc.splat.display_gaussians()
    i = 2000  # an isotropic object Gaussian: covariance = sigma^2 I
    np.testing.assert_allclose(g.covariances[i], np.eye(3) * np.exp(2 * d.log_scales[i, 0]), rtol=1e-4, atol=1e-9)


def test_load_config_and_checkpoint(tmp_path):
    d = demo_scene()
    run = tmp_path / "outputs" / "scene" / "cinesplat" / "ts"
    (run / "nerfstudio_models").mkdir(parents=True)
    data = tmp_path / "data" / "myscene"
    data.mkdir(parents=True)
    cfg = SimpleNamespace(data=data, pipeline=SimpleNamespace(datamanager=SimpleNamespace(data=data)))
    (run / "config.yml").write_text(yaml.dump(cfg))
    sd = {f"_model.gauss_params.{k}": torch.as_tensor(v) for k, v in dict(
        means=d.means, quats=d.quats_wxyz, scales=d.log_scales, opacities=d.opacity_logits[:, None],
        features_dc=(d.colors - 0.5) / SH_C0).items()}
    torch.save({"pipeline": {k: v * 0 for k, v in sd.items()}}, run / "nerfstudio_models" / "step-000000099.ckpt")
    torch.save({"pipeline": sd}, run / "nerfstudio_models" / "step-000000999.ckpt")  # newest wins
    sc = load_scene(str(run / "config.yml"))
    np.testing.assert_allclose(sc.splat.means, d.means)
    assert sc.data_dir == data and sc.config_path == (run / "config.yml").absolute() and sc.name == "myscene"


def test_bad_sources(tmp_path):
    with pytest.raises(InvalidInputError, match="no such file"):
        load_scene(str(tmp_path / "nope.ply"))
    (tmp_path / "x.txt").write_text("hi")
    with pytest.raises(InvalidInputError, match="expected a config.yml"):
        load_scene(str(tmp_path / "x.txt"))
    from plyfile import PlyData, PlyElement

    arr = np.zeros(3, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    PlyData([PlyElement.describe(arr, "vertex")]).write(str(tmp_path / "pts.ply"))
    with pytest.raises(InvalidInputError, match="not a Gaussian-splat .ply"):
        load_scene(str(tmp_path / "pts.ply"))


def test_standalone_on_ply_plans_with_coordinates(tmp_path):
    write_3dgs_ply(tmp_path / "scene.ply", demo_scene())
    v = StandaloneViewer(StandaloneConfig(load_config=str(tmp_path / "scene.ply"), port=free_port(), host="127.0.0.1"))
    try:
        assert "Type targets as x y z" in v.panel.status
        assert v.panel.request_plan("the red box", "0 0 0").result(30) is None
        assert "need a trained cinesplat scene" in v.panel.status
        assert v.panel.request_plan("0.5 0.45 0.5", "0.5 0.45 0.14").result(60) is not None, v.panel.status
        out = v.panel.export("ply-take")
        assert out.path == tmp_path / "camera_paths" / "ply-take.json"
    finally:
        v.close()


def test_cli_help():
    env = dict(os.environ, PYTHONPATH=str(REPO))
    r = subprocess.run([sys.executable, "-m", "cinenerf_ns.viewer.standalone", "--help"], capture_output=True,
                       text=True, env=env, timeout=120)
    assert r.returncode == 0 and "--load-config" in r.stdout and "--port" in r.stdout
