"""Where the standalone viewer opens: at a training camera's pose (position, look direction, up) when the scene has
training cameras -- a run folder / config.yml (its transforms.json + dataparser_transforms.json), a compact export
that stores the poses; only the position when an export stores only the centres -- else inside the planner's start
region (generated scenes, which have no cameras). Fakes: a tiny run folder and an injected planner; then the real fox
capture when ../shared is there (skipped with the reason otherwise)."""
from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
import yaml
from _xdist import free_port
from viewer_fakes import camera_looking as camera_c2w

from cinenerf_ns.method.training_cameras import camera_poses
from cinenerf_ns.viewer.demo import demo_scene
from cinenerf_ns.viewer.standalone import StandaloneConfig, StandaloneViewer, open_scene
from cinenerf_ns.viewer.views import TrainingCameras, opening_view

REPO = Path(__file__).resolve().parents[2]


def no_planning(*args, **kwargs):  # the injected planner: these tests never plan
    return []


def viewer_on(source: str, tmp_path: Path) -> StandaloneViewer:
    return StandaloneViewer(StandaloneConfig(load_config=source, port=free_port(), host="127.0.0.1",
                                             output_dir=tmp_path / "out"), plan_fn=no_planning)


def camera_looking(position, forward, roll_deg=0.0) -> np.ndarray:
    """[4, 4] a camera-to-world as transforms.json stores it (OpenGL: x right, y up, looking along -z)."""
    m = np.eye(4)
    m[:3] = camera_c2w(position, forward, roll_deg)
    return m


def write_run(tmp_path: Path) -> Path:
    """A trained run as ns-train leaves it: outputs/.../config.yml naming its data, dataparser_transforms.json (here a
    rotation about z, a shift and a scale), a checkpoint (the tiny demo scene); the data's transforms.json holds five
    cameras in a row, each turned and rolled differently."""
    d = demo_scene().splat
    run = tmp_path / "outputs" / "scene" / "cinesplat" / "ts"
    (run / "nerfstudio_models").mkdir(parents=True)
    data = tmp_path / "data" / "scene"
    data.mkdir(parents=True)
    frames = [{"file_path": f"images/{i}.png",
               "transform_matrix": camera_looking([2.0 * i - 4.0, -6.0, 2.0], [0.2 * (i - 2), 1.0, -0.3],
                                                  roll_deg=8.0 * i).tolist()} for i in range(5)]
    (data / "transforms.json").write_text(json.dumps({"frames": frames}))
    a = np.deg2rad(30.0)
    T = np.array([[np.cos(a), -np.sin(a), 0, 0.1], [np.sin(a), np.cos(a), 0, -0.2], [0, 0, 1, 0.05]])
    (run / "dataparser_transforms.json").write_text(json.dumps({"transform": T.tolist(), "scale": 0.15}))
    cfg = SimpleNamespace(data=data, pipeline=SimpleNamespace(datamanager=SimpleNamespace(data=data)))
    (run / "config.yml").write_text(yaml.dump(cfg))
    sd = {f"_model.gauss_params.{k}": torch.as_tensor(v) for k, v in dict(
        means=d.means, quats=d.quats_wxyz, scales=d.log_scales, opacities=d.opacity_logits[:, None],
        features_dc=d.colors_dc).items()}
    torch.save({"pipeline": sd}, run / "nerfstudio_models" / "step-000000999.ckpt")
    return run


def assert_is_camera_view(view, c2w: np.ndarray) -> None:
    """``view`` is the pose ``c2w`` [3, 4]: its position, looking along its -z, its +y up (a real run's rotations are
    orthonormal to float32 precision, the view's directions to float64)."""
    np.testing.assert_allclose(view.position, c2w[:, 3], atol=1e-9)
    d = (view.look_at - view.position) / np.linalg.norm(view.look_at - view.position)
    np.testing.assert_allclose(d, -c2w[:, 2], atol=1e-6)
    np.testing.assert_allclose(view.up, c2w[:, 1], atol=1e-6)


def test_a_run_opens_at_its_typical_training_camera(tmp_path):
    run = write_run(tmp_path)
    want = camera_poses(tmp_path / "data" / "scene" / "transforms.json", run / "dataparser_transforms.json")
    v = viewer_on(str(run), tmp_path)
    try:
        cams = v.loaded.cameras
        assert cams is not None and cams.c2w is not None
        np.testing.assert_allclose(cams.c2w, want)  # in the run's normalised coordinates, where the splat lives
        assert cams.typical() == 2  # the middle of the row
        assert_is_camera_view(v.panels.home, want[2])
        assert np.rad2deg(np.arccos(np.clip(v.panels.home.up @ [0, 0, 1], -1, 1))) > 10  # its roll is kept
        # the browser starts there, and viser's "Reset View" returns there (viser units: x scale)
        ic, s = v.server.initial_camera, v.cfg.scale
        np.testing.assert_allclose(ic.position, v.panels.home.position * s)
        np.testing.assert_allclose(ic.look_at, v.panels.home.look_at * s)
        np.testing.assert_allclose(ic.up, v.panels.home.up)
    finally:
        v.close()


def test_a_generated_scene_opens_in_its_start_region(tmp_path):
    """A procedural room has no training cameras: the opening view stays the start region's, z up."""
    v = viewer_on("procedural:2000", tmp_path)
    try:
        assert v.loaded.cameras is None
        lo, hi = v.loaded.start_region
        assert np.all(v.panels.home.position >= lo) and np.all(v.panels.home.position <= hi)
        np.testing.assert_array_equal(v.panels.home.up, [0, 0, 1])
        np.testing.assert_allclose(v.server.initial_camera.position, v.panels.home.position * v.cfg.scale)
    finally:
        v.close()


def test_go_to_view_sets_position_look_at_and_up():
    """The panel moves a client's camera to a view with its up (a training camera's roll; z up for the overview)."""
    from cinenerf_ns.viewer.views import View
    from cinenerf_ns.viewer.viser_ui import ViserPanelUI

    class Camera:
        def __init__(self):
            self.set = []

        def __setattr__(self, name, value):
            if name != "set":
                self.set.append((name, np.array(value, float)))
            object.__setattr__(self, name, value)

    class Client:
        client_id = 1

        def __init__(self):
            self.camera = Camera()

        def atomic(self):
            import contextlib

            return contextlib.nullcontext()

    ui = ViserPanelUI.__new__(ViserPanelUI)  # only go_to_view's state: the scale
    ui.scale = 10.0
    c = Client()
    up = np.array([0.1, 0.0, 1.0]) / np.linalg.norm([0.1, 0.0, 1.0])
    ui.go_to_view(View(np.array([1.0, 2.0, 3.0]), np.array([1.0, 3.0, 3.0]), up), c)
    names = [n for n, _ in c.camera.set]
    assert names == ["position", "look_at", "up_direction"]  # one atomic update, up last
    np.testing.assert_allclose(c.camera.set[0][1], [10, 20, 30])
    np.testing.assert_allclose(c.camera.set[1][1], [10, 30, 30])
    np.testing.assert_allclose(c.camera.set[2][1], up)  # a direction: not scaled


@pytest.mark.fox
def test_the_fox_capture_opens_at_a_training_camera(fox_dir, fox_splat, tmp_path):
    """The real capture: nerfstudio's own dataparser on fox/ (as the run was trained: nerfstudio-data
    --downscale-factor 4) gives the run's dataparser transform; camera_poses then finds the cameras the export's
    centres were stored from (the splat's coordinates). fox3000.npz stores only the centres, so the viewer opens at
    the typical camera's position; with the poses stored (scripts/add_camera_centres.py, on a copy) it opens at that
    camera's full pose, which looks at the fox."""
    from nerfstudio.data.dataparsers.nerfstudio_dataparser import NerfstudioDataParserConfig

    from cinenerf_ns.method.checkpoint import load_compact
    from cinenerf_ns.method.training_cameras import info_camera_centres, info_camera_poses

    out = NerfstudioDataParserConfig(data=fox_dir, downscale_factor=4).setup().get_dataparser_outputs("train")
    out.save_dataparser_transform(tmp_path / "run" / "dataparser_transforms.json")
    poses = camera_poses(fox_dir / "transforms.json", tmp_path / "run" / "dataparser_transforms.json", fox_dir)
    names = [Path(f["file_path"]).name for f in json.loads((fox_dir / "transforms.json").read_text())["frames"]]
    train = [names.index(Path(p).name) for p in out.image_filenames]
    np.testing.assert_allclose(poses[train], out.cameras.camera_to_worlds.double().numpy(), atol=1e-5)

    info = load_compact(fox_splat).info
    np.testing.assert_allclose(info_camera_centres(info), poses[:, :, 3], atol=1e-6)  # the export's coordinates
    assert info_camera_poses(info) is None  # exported before the poses were stored
    means = load_compact(fox_splat).params.means.astype(np.float64)
    only = TrainingCameras.of(info_camera_centres(info), None)
    v = opening_view(means, None, only)
    np.testing.assert_allclose(v.position, only.centres[only.typical()])  # a training camera's position

    copy = tmp_path / "fox.npz"
    shutil.copyfile(fox_splat, copy)
    spec = importlib.util.spec_from_file_location("acc", REPO / "scripts" / "add_camera_centres.py")
    acc = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(acc)
    acc.main(["--scene", str(copy), "--transforms", str(fox_dir / "transforms.json"),
              "--dataparser-transforms", str(tmp_path / "run" / "dataparser_transforms.json")])
    loaded = open_scene(str(copy))  # as the viewer opens it
    cams = loaded.cameras
    np.testing.assert_allclose(cams.c2w, poses)
    home = opening_view(loaded.splat.means, loaded.start_region, cams)
    k = cams.typical()
    assert_is_camera_view(home, poses[k])
    # it sees the fox: the point every camera's optical axis passes closest to lies inside its narrower half-angle
    A, b = np.zeros((3, 3)), np.zeros(3)
    for p in poses:
        m = np.eye(3) - np.outer(p[:, 2], p[:, 2])
        A, b = A + m, b + m @ p[:, 3]
    fox = np.linalg.solve(A, b)
    to_fox = (fox - home.position) / np.linalg.norm(fox - home.position)
    half_fov = 0.5 * json.loads((fox_dir / "transforms.json").read_text())["camera_angle_x"]  # portrait: x narrower
    assert np.arccos(to_fox @ -poses[k][:, 2]) < half_fov
