"""Map ground truth from the room's original coordinates into nerfstudio's normalised coordinates.

nerfstudio's dataparser re-orients, centres and rescales the poses it reads:
``p_ns = scale * (T[:3,:3] @ p + T[:3,3])`` with ``T`` = ``dataparser_transform`` [3,4] and ``scale`` =
``dataparser_scale`` (written by ns-train to ``<run>/dataparser_transforms.json``). The transform is a
rotation + translation and the scale is uniform, so distances (SDF, clearance) scale by ``scale``.

Datasets written by cinesplat-synth set ``orientation_override: "none"`` in transforms.json, so T's
rotation is the identity (the room stays axis-aligned, +z up) and only centring + scaling happen;
the helper below does not rely on that.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from cinenerf_ns.synthetic.room import Room


@dataclass
class NerfstudioTransform:
    transform: Tensor  # [3,4] float64: original -> nerfstudio (before scaling)
    scale: float

    # ---------------------------------------------------------------- construction
    @classmethod
    def from_dataparser_json(cls, path: str | Path) -> "NerfstudioTransform":
        """Read ``dataparser_transforms.json`` (written by ns-train next to the config.yml)."""
        d = json.loads(Path(path).read_text())
        return cls(torch.tensor(d["transform"], dtype=torch.float64)[:3, :4], float(d["scale"]))

    @classmethod
    def from_dataset(
        cls,
        dataset: str | Path,
        orientation_method: str = "up",
        center_method: str = "poses",
        auto_scale_poses: bool = True,
        scale_factor: float = 1.0,
    ) -> "NerfstudioTransform":
        """Recompute what NerfstudioDataParser (defaults as arguments) will apply to this dataset, with
        nerfstudio's own function (float32, like the dataparser). Honours ``orientation_override``."""
        from nerfstudio.cameras import camera_utils

        path = Path(dataset)
        meta = json.loads((path / "transforms.json" if path.is_dir() else path).read_text())
        method = meta.get("orientation_override", orientation_method)
        poses = torch.from_numpy(np.array([f["transform_matrix"] for f in meta["frames"]]).astype(np.float32))
        poses, transform = camera_utils.auto_orient_and_center_poses(poses, method=method, center_method=center_method)
        s = 1.0
        if auto_scale_poses:
            s /= float(torch.max(torch.abs(poses[:, :3, 3])))
        s *= scale_factor
        return cls(transform.to(torch.float64)[:3, :4], s)

    # ---------------------------------------------------------------- mapping
    @property
    def rotation(self) -> Tensor:
        return self.transform[:3, :3]

    def points_to_ns(self, points: Tensor) -> Tensor:
        """[...,3] original -> [...,3] nerfstudio coordinates."""
        p = torch.as_tensor(points, dtype=torch.float64)
        return self.scale * (p @ self.rotation.T + self.transform[:3, 3])

    def points_from_ns(self, points: Tensor) -> Tensor:
        """[...,3] nerfstudio -> [...,3] original coordinates."""
        q = torch.as_tensor(points, dtype=torch.float64)
        # rotation part is orthonormal (nerfstudio builds it from a rotation), so inverse = transpose
        return (q / self.scale - self.transform[:3, 3]) @ self.rotation

    def c2w_to_ns(self, c2w: Tensor) -> Tensor:
        """Camera-to-world [...,3|4,4] original -> [...,3,4] nerfstudio (same camera convention)."""
        c = torch.as_tensor(c2w, dtype=torch.float64)[..., :3, :4]
        R = self.rotation @ c[..., :3, :3]
        t = self.points_to_ns(c[..., :3, 3])
        return torch.cat([R, t[..., None]], dim=-1)


class GroundTruthNS:
    """The room's ground truth expressed in nerfstudio coordinates (what the trained splat lives in)."""

    def __init__(self, room: Room, tf: NerfstudioTransform):
        self.room = room
        self.tf = tf

    def sdf(self, points_ns: Tensor) -> Tensor:
        """Signed distance [...] in nerfstudio units of points [...,3] in nerfstudio coordinates."""
        return self.room.sdf(self.tf.points_from_ns(points_ns)) * self.tf.scale

    def object_sdf(self, name: str, points_ns: Tensor) -> Tensor:
        return self.room.object_sdf(name, self.tf.points_from_ns(points_ns)) * self.tf.scale

    def object_centres(self) -> dict[str, Tensor]:
        return {k: self.tf.points_to_ns(v) for k, v in self.room.object_centres().items()}

    def object_points(self, name: str, n: int, seed: int = 0) -> Tensor:
        return self.tf.points_to_ns(self.room.object_points(name, n, seed))

    def room_size(self) -> float:
        """Largest interior side in nerfstudio units (reference length for relative centroid errors)."""
        return self.room.room_size() * self.tf.scale

    @property
    def labels(self) -> dict[int, str]:
        return self.room.labels

    def part_outlines_xy(self, n_circle: int = 32) -> list[tuple[str, "torch.Tensor"]]:
        """(object name, closed xy polygon [K,2]) per part, in nerfstudio coordinates, for top-down plots."""
        return [(name, self.tf.points_to_ns(poly)[:, :2]) for name, poly in self.room.part_outlines(n_circle)]

    def inside_room(self, points_ns: Tensor) -> Tensor:
        """bool [...]: points [...,3] (nerfstudio coordinates) inside the room's interior box. Outside the walls,
        floor and ceiling slabs the SDF is positive too, but no camera of a capture of this room could be there."""
        p = self.tf.points_from_ns(points_ns)
        lo = torch.as_tensor(self.room.interior_lo, dtype=torch.float64)
        hi = torch.as_tensor(self.room.interior_hi, dtype=torch.float64)
        return ((p >= lo) & (p <= hi)).all(-1)

    def interior_outline_xy(self) -> "torch.Tensor":
        return self.tf.points_to_ns(self.room.interior_outline())[:, :2]
