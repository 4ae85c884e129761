"""Every command reads every scene kind through the one loader (scenes.load_scene): cinesplat-plan, cinesplat-viewer
and cinesplat-preview each accept a compact .npz, a 3DGS .ply, a .ckpt, a run's config.yml, a run folder and
procedural:N; they all see the same Gaussians."""
from __future__ import annotations

import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import yaml

from cinenerf_ns.planner.scene.procedural import procedural_room
from cinenerf_ns.scenes import SCENE_READERS, load_scene, procedural_params

sys.path.insert(0, str(Path(__file__).parent / "preview"))
from _scenes import orbit_camera_path  # noqa: E402

KINDS = ["npz", "ply", "ckpt", "config.yml", "run folder", "procedural"]
N, SEED = 3000, 1  # the room every kind holds


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory) -> dict:
    """kind -> spec of one small procedural room (coloured) written as each kind."""
    from cinenerf_ns.method.checkpoint import SplatCheckpoint, export_compact
    from cinenerf_ns.planner.scene.ply import write_splat_ply

    tmp = tmp_path_factory.mktemp("kinds")
    sp = procedural_params(procedural_room(N, seed=SEED))
    npz = export_compact(SplatCheckpoint(sp), tmp / "room.npz", half=False)
    ply = write_splat_ply(tmp / "room.ply", sp.means, sp.quats_wxyz, sp.log_scales, sp.opacity_logits,
                          colors_dc=sp.colors_dc)
    run = tmp / "outputs" / "room" / "cinesplat" / "ts"
    (run / "nerfstudio_models").mkdir(parents=True)
    data = tmp / "data" / "room"
    data.mkdir(parents=True)
    cfg = SimpleNamespace(data=data, pipeline=SimpleNamespace(datamanager=SimpleNamespace(data=data)))
    (run / "config.yml").write_text(yaml.dump(cfg))
    state = {f"_model.gauss_params.{k}": torch.as_tensor(v) for k, v in dict(
        means=sp.means, quats=sp.quats_wxyz, scales=sp.log_scales, opacities=sp.opacity_logits[:, None],
        features_dc=sp.colors_dc).items()}
    ckpt = run / "nerfstudio_models" / "step-000000999.ckpt"
    torch.save({"pipeline": state}, ckpt)
    return {"npz": str(npz), "ply": str(ply), "ckpt": str(ckpt), "config.yml": str(run / "config.yml"),
            "run folder": str(run), "procedural": f"procedural:{N}:{SEED}"}


def test_one_reader_table():
    """A suffix names its reader in one table; the kinds of the commands' help are all in it."""
    assert {".ply", ".npz", ".pt", ".ckpt", ".yml", ".yaml"} <= set(SCENE_READERS)


@pytest.mark.parametrize("kind", KINDS)
def test_load_scene_reads_each_kind_alike(scene_files, kind):
    ld = load_scene(scene_files[kind])
    ref = procedural_params(procedural_room(N, seed=SEED))
    np.testing.assert_allclose(ld.splat.means, ref.means, atol=1e-6)
    np.testing.assert_allclose(ld.splat.rgb(), ref.rgb(), atol=1e-5)
    assert len(ld.scene) == len(load_scene(scene_files["procedural"]).scene)
    assert load_scene(scene_files[kind], planning=False).scene is None


@pytest.mark.parametrize("kind", KINDS)
def test_cinesplat_viewer_opens_each_kind(scene_files, kind):
    from cinenerf_ns.viewer.standalone import display_gaussians, open_scene

    vs = open_scene(scene_files[kind])
    assert len(display_gaussians(vs.splat)) == N and len(vs.obstacles) > 0
    assert (vs.locate is not None) == (kind == "procedural")  # files without latents answer points only


@pytest.mark.parametrize("kind", KINDS)
def test_cinesplat_preview_renders_each_kind(scene_files, kind, tmp_path):
    from cinenerf_ns.preview.cli import main

    cam = tmp_path / "shot.json"
    cam.write_text(json.dumps(orbit_camera_path(n=4)))
    out = main(["--scene", scene_files[kind], "--camera-path", str(cam), "--output-dir", str(tmp_path / "r"),
                "--width", "32", "--height", "32", "--fps", "4"])
    assert out["frames"] >= 1 and sorted(p.name for p in (tmp_path / "r").iterdir()) == ["shot.mp4", "shot_sheet.png"]


@pytest.mark.parametrize("kind", KINDS)
def test_cinesplat_plan_plans_on_each_kind(scene_files, kind, tmp_path):
    from cinenerf_ns.cli.plan_args import PlanArgs
    from cinenerf_ns.cli.plan_run import run_plan
    from cinenerf_ns.planner.shots.planner import PlannerConfig

    room = procedural_room(N, seed=SEED)
    go = " ".join(f"{v:.4f}" for v in (room.free_lo + room.free_hi) / 2)
    look = " ".join(f"{v:.4f}" for v in room.objects[0].center)
    s = run_plan(PlanArgs(scene=scene_files[kind], go_to=go, look_at=look, candidates=1,
                          workers=0, seed=0, output_dir=tmp_path,
                          planner=PlannerConfig(grid_resolution=40)))
    assert len(s["candidates"]) == 1 and (tmp_path / "shot_0.json").exists()
