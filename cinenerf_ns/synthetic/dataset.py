"""Render a room from many cameras and write a nerfstudio dataset folder.

Layout of the folder::

    images/frame_00000.png      RGB
    labels/frame_00000.png      per-pixel label id (uint8, or uint16 when ids exceed 255)
    depths/frame_00000.png      camera z-depth in millimetres (uint16), nerfstudio's depth convention
    labels.json                 {"0": "background", "1": "floor", ...}
    transforms.json             nerfstudio format, camera_to_world in the ORIGINAL room coordinates
    geometry.json               ground-truth shapes (Room.save), load with Room.load(folder)
    sparse_pc.ply               coloured points on visible surfaces (optional splat initialisation)
    synth_info.json             generator settings and timings
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from PIL import Image

from cinenerf_ns.planner.scene.ply import read_ply_vertices, write_ply_vertices
from cinenerf_ns.synthetic.cameras import CameraSamplingConfig, sample_cameras
from cinenerf_ns.synthetic.generate import RoomConfig, generate_room
from cinenerf_ns.synthetic.render import Intrinsics, RoomRenderer
from cinenerf_ns.synthetic.room import Room


@dataclass
class DatasetConfig:
    """What to render and write."""

    output: Path = Path("data/room0")
    """Dataset folder to write (created; existing files of the same names are overwritten)."""
    seed: int = 0
    """Layout and camera seed."""
    num_views: int = 150
    """Number of training views."""
    width: int = 480
    """Image width (pixels)."""
    height: int = 360
    """Image height (pixels)."""
    fov_x_deg: float = 75.0
    """Horizontal field of view (degrees)."""
    supersample: int = 1
    """Sub-samples per pixel axis for anti-aliasing (s*s rays per pixel; cost grows with s^2)."""
    write_depth: bool = True
    """Write depths/*.png (uint16 millimetres, camera z-depth) and depth_file_path entries."""
    points_per_view: int = 400
    """Surface points per view in sparse_pc.ply (0: no point cloud)."""
    ply_in_transforms: bool = False
    """Reference sparse_pc.ply from transforms.json (splatfacto then initialises from it). nerfstudio
    reads it with open3d, so only enable where open3d is installed."""
    threads: int = 1
    """torch CPU threads for rendering. 1 is fastest on a shared/busy CPU (multi-thread ops spin
    while waiting for a core); on an idle multi-core box 2+ is faster."""
    room: RoomConfig = field(default_factory=RoomConfig)
    """Room size and contents."""
    cameras: CameraSamplingConfig = field(default_factory=CameraSamplingConfig)
    """Camera placement."""


def _write_ply(path: Path, xyz: np.ndarray, rgb: np.ndarray) -> None:
    v = np.empty(len(xyz),
                 dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    v["x"], v["y"], v["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    v["red"], v["green"], v["blue"] = rgb[:, 0], rgb[:, 1], rgb[:, 2]
    write_ply_vertices(path, v)


def write_dataset(config: DatasetConfig, progress: Callable[[int, int], None] | None = None) -> dict:
    """Generate the room, render every view and write the dataset. Returns the info dict (timings)."""
    t_start = time.perf_counter()
    threads_before = torch.get_num_threads()
    torch.set_num_threads(max(1, config.threads))
    try:
        return _write_dataset(config, progress, t_start)
    finally:
        torch.set_num_threads(threads_before)


def _write_dataset(config: DatasetConfig, progress, t_start: float) -> dict:
    out = Path(config.output)
    for sub in ("images", "labels") + (("depths",) if config.write_depth else ()):
        (out / sub).mkdir(parents=True, exist_ok=True)
    room = generate_room(config.room, config.seed)
    c2ws, targets = sample_cameras(room, config.num_views, config.seed, config.cameras)
    intr = Intrinsics.from_fov(config.width, config.height, config.fov_x_deg)
    renderer = RoomRenderer(room)
    label_dtype = np.uint8 if max(room.labels) < 256 else np.uint16
    rng = np.random.default_rng(config.seed + 17)

    frames, pts, cols = [], [], []
    t_render = 0.0
    cpu_render = 0.0
    for i in range(config.num_views):
        t0, c0 = time.perf_counter(), time.process_time()
        r = renderer.render(c2ws[i], intr, config.supersample)
        t_render += time.perf_counter() - t0
        cpu_render += time.process_time() - c0
        stem = f"frame_{i:05d}"
        rgb8 = (r["rgb"].numpy() * 255 + 0.5).astype(np.uint8)
        Image.fromarray(rgb8).save(out / "images" / f"{stem}.png")
        Image.fromarray(r["label"].numpy().astype(label_dtype)).save(out / "labels" / f"{stem}.png")
        frame = {
            "file_path": f"images/{stem}.png",
            "label_path": f"labels/{stem}.png",
            "transform_matrix": c2ws[i].tolist(),
            "look_target": targets[i],
        }
        if config.write_depth:
            depth = r["depth"].numpy()
            mm = np.where(np.isfinite(depth), np.clip(depth * 1000.0 + 0.5, 0, 65535), 0).astype(np.uint16)
            Image.fromarray(mm).save(out / "depths" / f"{stem}.png")
            frame["depth_file_path"] = f"depths/{stem}.png"
        frames.append(frame)
        if config.points_per_view > 0:
            ok = torch.isfinite(r["distance"]).flatten().nonzero(as_tuple=True)[0].numpy()
            pick = rng.choice(ok, size=min(config.points_per_view, len(ok)), replace=False)
            o = c2ws[i][:3, 3].numpy()
            # recompute the pixel-centre ray of each picked pixel (same math as render.camera_rays)
            v_, u_ = np.divmod(pick, config.width)
            d_cam = np.stack([(u_ + 0.5 - intr.cx) / intr.fx, -(v_ + 0.5 - intr.cy) / intr.fy, -np.ones(len(pick))], -1)
            d_cam /= np.linalg.norm(d_cam, axis=-1, keepdims=True)
            dirs = d_cam @ c2ws[i][:3, :3].numpy().T
            dist = r["distance"].flatten().numpy()[pick].astype(np.float64)
            pts.append(o + dirs * dist[:, None])
            cols.append(rgb8.reshape(-1, 3)[pick])
        if progress is not None:
            progress(i + 1, config.num_views)

    transforms = {
        "camera_model": "PINHOLE",
        "fl_x": intr.fx,
        "fl_y": intr.fy,
        "cx": intr.cx,
        "cy": intr.cy,
        "w": intr.width,
        "h": intr.height,
        # keep the room axis-aligned with +z up in nerfstudio (centring + scaling only)
        "orientation_override": "none",
        "frames": frames,
    }
    if pts:
        _write_ply(out / "sparse_pc.ply", np.concatenate(pts), np.concatenate(cols))
        if config.ply_in_transforms:
            transforms["ply_file_path"] = "sparse_pc.ply"
    (out / "transforms.json").write_text(json.dumps(transforms, indent=1))
    (out / "labels.json").write_text(json.dumps({str(k): v for k, v in room.labels.items()}, indent=1))
    room.save(out / "geometry.json")
    info = {
        "generator": "cinesplat-synth",
        "config": json.loads(json.dumps(asdict(config), default=str)),
        "num_views": config.num_views,
        "render_seconds": t_render,
        "render_cpu_seconds": cpu_render,
        "total_seconds": time.perf_counter() - t_start,
        "torch_threads": torch.get_num_threads(),
        "coordinates": "original room frame: metres, +z up, floor z=0, room centred on x,y; "
        "nerfstudio rescales: use cinenerf_ns.synthetic.ns_transform to map ground truth",
    }
    (out / "synth_info.json").write_text(json.dumps(info, indent=1))
    return info


def load_labels(dataset: str | Path) -> dict[int, str]:
    """labels.json of a dataset folder as {id: name}."""
    return {int(k): v for k, v in json.loads((Path(dataset) / "labels.json").read_text()).items()}


def load_room(dataset: str | Path) -> Room:
    return Room.load(dataset)


def load_point_cloud(dataset: str | Path) -> tuple[torch.Tensor, torch.Tensor]:
    """sparse_pc.ply of a dataset without open3d: xyz [N,3] float64 (ORIGINAL room coordinates) and
    rgb [N,3] uint8. Map into nerfstudio coordinates with NerfstudioTransform.points_to_ns (this is what
    nerfstudio's dataparser does with ply_file_path, which needs open3d)."""
    path = Path(dataset) / "sparse_pc.ply"
    if not path.exists():
        raise FileNotFoundError(f"no point cloud at {path} (written by cinesplat-synth unless --points-per-view 0)")
    v = read_ply_vertices(path)
    xyz = torch.tensor(np.stack([v["x"], v["y"], v["z"]], -1), dtype=torch.float64)
    rgb = torch.tensor(np.stack([v["red"], v["green"], v["blue"]], -1), dtype=torch.uint8)
    return xyz, rgb
