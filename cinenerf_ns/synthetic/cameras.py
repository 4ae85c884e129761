"""Training camera placement: positions in the room's free space, looking at objects / the room centre."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from cinenerf_ns.synthetic.room import Room


@dataclass
class CameraSamplingConfig:
    """Where the dataset cameras go (metres, room coordinates)."""

    clearance: float = 0.3
    """Minimum distance from the camera centre to any surface (objects, walls, floor, ceiling)."""
    z_range: tuple[float, float] = (0.4, 2.0)
    """Allowed camera heights."""
    min_target_distance: float = 0.8
    """Cameras at least this far from what they look at (keeps objects in frame)."""
    centre_fraction: float = 0.2
    """Fraction of views aimed at the room centre / a random wall point instead of an object."""
    target_jitter: float = 0.15
    """Uniform jitter of the look-at point (m), so views are not all centred on object centres."""
    max_pitch_deg: float = 65.0
    """Views steeper than this (up or down) are rejected."""
    roll_jitter_deg: float = 2.0
    """Small random roll (deg) so the set is not perfectly horizon-aligned."""


def look_at_c2w(position: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0), roll_rad: float = 0.0) -> np.ndarray:
    """4x4 camera-to-world (OpenGL: x right, y up, camera looks along -z) at position looking at target."""
    fwd = np.asarray(target, float) - np.asarray(position, float)
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(up, float))
    nr = np.linalg.norm(right)
    if nr < 1e-6:
        raise ValueError("look_at_c2w: view direction parallel to up")
    right /= nr
    cam_up = np.cross(right, fwd)
    if roll_rad:
        c, s = np.cos(roll_rad), np.sin(roll_rad)
        right, cam_up = c * right + s * cam_up, -s * right + c * cam_up
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, cam_up, -fwd, position
    return m


def sample_cameras(room: Room, n: int, seed: int = 0,
                   config: CameraSamplingConfig | None = None) -> tuple[Tensor, list[str]]:
    """n camera-to-world matrices [n,4,4] (float64) in the room's free space, and what each looks at.

    Targets cycle over the objects (shuffled) so every object is seen from many sides; a fraction
    looks at the room centre or a random wall point."""
    cfg = config or CameraSamplingConfig()
    rng = np.random.default_rng(seed + 7919)
    lo = room.interior_lo.numpy().copy()
    hi = room.interior_hi.numpy().copy()
    lo[:2] += cfg.clearance
    hi[:2] -= cfg.clearance
    lo[2] = max(lo[2] + cfg.clearance, cfg.z_range[0])
    hi[2] = min(hi[2] - cfg.clearance, cfg.z_range[1])
    if np.any(hi <= lo):
        raise ValueError(f"room too small for camera clearance {cfg.clearance} m and heights {cfg.z_range}")
    centres = {k: v.numpy() for k, v in room.object_centres().items()}
    names = list(centres)
    room_centre = ((room.interior_lo + room.interior_hi) / 2).numpy()

    out, what = [], []
    order: list[str] = []
    tries = 0
    while len(out) < n:
        tries += 1
        if tries > 200 * n + 10000:
            raise RuntimeError(f"could only place {len(out)}/{n} cameras with clearance {cfg.clearance} m")
        if not order:
            order = list(rng.permutation(names))
        if rng.uniform() < cfg.centre_fraction:
            if rng.uniform() < 0.5:
                target = room_centre + rng.uniform(-0.5, 0.5, 3) * [room.width / 2, room.depth / 2, 0.5]
                label = "room centre"
            else:
                target = rng.uniform(room.interior_lo.numpy(), room.interior_hi.numpy())
                ax = rng.integers(2)
                target[ax] = room.interior_lo[ax] if rng.uniform() < 0.5 else room.interior_hi[ax]
                label = "wall"
            pop = False
        else:
            label = order[-1]
            target = centres[label] + rng.uniform(-cfg.target_jitter, cfg.target_jitter, 3)
            pop = True
        pos = rng.uniform(lo, hi)
        v = target - pos
        dist = np.linalg.norm(v)
        if dist < cfg.min_target_distance:
            continue
        if abs(np.degrees(np.arcsin(v[2] / dist))) > cfg.max_pitch_deg:
            continue
        if float(room.sdf(torch.tensor(pos[None], dtype=torch.float64))[0]) < cfg.clearance:
            continue
        roll = np.radians(rng.uniform(-cfg.roll_jitter_deg, cfg.roll_jitter_deg))
        out.append(look_at_c2w(pos, target, roll_rad=roll))
        what.append(label)
        if pop:
            order.pop()
    return torch.tensor(np.stack(out)), what
