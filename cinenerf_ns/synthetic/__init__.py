"""Synthetic ground-truth rooms: seeded layout, analytic geometry + SDF, ray-cast renderer, dataset export.

Public API:
    RoomConfig, generate_room(config, seed) -> Room         (generate.py)
    Room: sdf, object_sdf, object_centres, object_points, object_aabb, labels, save/load   (room.py)
    room_sdf(room, points)                                     (room.py)
    RoomRenderer(room).render(c2w, Intrinsics) -> rgb/label/depth/distance   (render.py)
    sample_cameras(room, n, seed) -> c2w [n,4,4]               (cameras.py)
    DatasetConfig, write_dataset(config)                       (dataset.py)
    NerfstudioTransform, GroundTruthNS                         (ns_transform.py)
"""
from cinenerf_ns.synthetic.cameras import CameraSamplingConfig, look_at_c2w, sample_cameras
from cinenerf_ns.synthetic.generate import LayoutError, RoomConfig, generate_room
from cinenerf_ns.synthetic.render import Intrinsics, RoomRenderer, render_view
from cinenerf_ns.synthetic.room import Room, room_sdf

__all__ = [
    "CameraSamplingConfig",
    "Intrinsics",
    "LayoutError",
    "Room",
    "RoomConfig",
    "RoomRenderer",
    "generate_room",
    "look_at_c2w",
    "render_view",
    "room_sdf",
    "sample_cameras",
]
