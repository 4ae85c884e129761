"""Coordinate conventions between nerfstudio scene space and the viser scene the browser shows.

nerfstudio (1.1.5, ``nerfstudio/viewer/viewer.py``) draws everything in viser at
``VISER_NERFSTUDIO_SCALE_RATIO = 10`` times the scene coordinates, and viser cameras follow OpenCV
(+x right, +y down, +z forward) while nerfstudio cameras follow OpenGL (+x right, +y up, -z forward).
nerfstudio converts with ``R_viser = R_ns @ Rx(pi)`` (``Viewer.init_scene`` / ``get_camera_state``);
a rotation by pi about x is ``diag(1, -1, -1)``, so the conversion only flips the camera y and z columns.

Pure numpy on purpose: the panel logic and its tests do not need viser.
"""
from __future__ import annotations

from typing import Tuple

import numpy as np

VISER_NERFSTUDIO_SCALE_RATIO: float = 10.0
"""Same value as ``nerfstudio.viewer.viewer.VISER_NERFSTUDIO_SCALE_RATIO`` (a test checks they agree)."""

_FLIP_YZ = np.diag([1.0, -1.0, -1.0])  # Rx(pi): OpenGL camera axes <-> OpenCV camera axes


def rotmat_to_wxyz(rot: np.ndarray) -> np.ndarray:
    """Rotation matrices [..., 3, 3] -> unit quaternions (w, x, y, z) [..., 4] with w >= 0.

    Shepperd's method: pick the largest of (w, x, y, z) to divide by, so it is stable for every
    rotation (including 180 degree turns, where w = 0)."""
    r = np.asarray(rot, dtype=np.float64)
    m00, m01, m02 = r[..., 0, 0], r[..., 0, 1], r[..., 0, 2]
    m10, m11, m12 = r[..., 1, 0], r[..., 1, 1], r[..., 1, 2]
    m20, m21, m22 = r[..., 2, 0], r[..., 2, 1], r[..., 2, 2]
    tr = m00 + m11 + m22
    cands = np.stack(
        [
            np.stack([1.0 + tr, m21 - m12, m02 - m20, m10 - m01], -1),
            np.stack([m21 - m12, 1.0 + m00 - m11 - m22, m01 + m10, m02 + m20], -1),
            np.stack([m02 - m20, m01 + m10, 1.0 - m00 + m11 - m22, m12 + m21], -1),
            np.stack([m10 - m01, m02 + m20, m12 + m21, 1.0 - m00 - m11 + m22], -1),
        ],
        -2,
    )  # [..., 4 choices, 4]
    diag = np.stack([1.0 + tr, 1.0 + m00 - m11 - m22, 1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22], -1)
    best = np.argmax(diag, axis=-1)  # [...]
    q = np.take_along_axis(cands, best[..., None, None].repeat(4, -1), axis=-2)[..., 0, :]  # [..., 4]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0.0, -q, q)


def wxyz_to_rotmat(wxyz: np.ndarray) -> np.ndarray:
    """Quaternions (w, x, y, z) [..., 4] (normalised first) -> rotation matrices [..., 3, 3]."""
    q = np.asarray(wxyz, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rot = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        -1,
    )
    return rot.reshape(*q.shape[:-1], 3, 3)


def nerfstudio_c2w_to_viser(
    c2w: np.ndarray,  # [..., 3, 4] or [..., 4, 4] nerfstudio camera-to-world (OpenGL camera axes)
    scale: float = VISER_NERFSTUDIO_SCALE_RATIO,
) -> Tuple[np.ndarray, np.ndarray]:
    """nerfstudio camera pose -> (wxyz [..., 4], position [..., 3]) of a viser camera / frustum.

    Matches nerfstudio's own ``R = SO3.from_matrix(c2w[:3, :3]) @ SO3.from_x_radians(pi)`` and
    ``position = c2w[:3, 3] * VISER_NERFSTUDIO_SCALE_RATIO``."""
    c2w = np.asarray(c2w, dtype=np.float64)
    if c2w.shape[-2:] not in ((3, 4), (4, 4)):
        raise ValueError(f"c2w must be [..., 3, 4] or [..., 4, 4], got {c2w.shape}")
    rot_viser = c2w[..., :3, :3] @ _FLIP_YZ  # [..., 3, 3]
    return rotmat_to_wxyz(rot_viser), c2w[..., :3, 3] * scale


def viser_to_nerfstudio_c2w(
    wxyz: np.ndarray,  # [..., 4] viser camera orientation (OpenCV camera axes)
    position: np.ndarray,  # [..., 3] viser position
    scale: float = VISER_NERFSTUDIO_SCALE_RATIO,
) -> np.ndarray:
    """Inverse of :func:`nerfstudio_c2w_to_viser`: -> nerfstudio c2w [..., 3, 4]
    (what ``Viewer.get_camera_state`` computes from ``client.camera``)."""
    rot = wxyz_to_rotmat(wxyz) @ _FLIP_YZ  # [..., 3, 3]
    pos = np.asarray(position, dtype=np.float64) / scale  # [..., 3]
    return np.concatenate([rot, pos[..., :, None]], axis=-1)


def world_to_viser(points: np.ndarray, scale: float = VISER_NERFSTUDIO_SCALE_RATIO) -> np.ndarray:
    """Scene points [..., 3] (nerfstudio units) -> viser scene points [..., 3]."""
    return np.asarray(points, dtype=np.float64) * scale


def viser_to_world(points: np.ndarray, scale: float = VISER_NERFSTUDIO_SCALE_RATIO) -> np.ndarray:
    """viser scene points [..., 3] -> nerfstudio scene points [..., 3]."""
    return np.asarray(points, dtype=np.float64) / scale


def interpolate_pose(
    times: np.ndarray,  # [T] increasing
    positions: np.ndarray,  # [T, 3]
    rotations: np.ndarray,  # [T, 3, 3]
    t: float,
) -> np.ndarray:
    """Camera-to-world [3, 4] at time ``t`` (clamped to the shot): linear in position, slerp in
    rotation between the two bracketing samples. The planner samples densely (fps), so this only
    fills the gaps between samples for a smooth live preview; the exported path uses the samples."""
    times = np.asarray(times, dtype=np.float64)
    t = float(np.clip(t, times[0], times[-1]))
    i = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)) if len(times) > 1 else 0
    if len(times) == 1:
        return np.concatenate([np.asarray(rotations[0], np.float64), np.asarray(positions[0], np.float64)[:, None]], 1)
    dt = times[i + 1] - times[i]
    a = 0.0 if dt <= 0 else (t - times[i]) / dt
    pos = (1 - a) * np.asarray(positions[i], np.float64) + a * np.asarray(positions[i + 1], np.float64)
    q0 = rotmat_to_wxyz(rotations[i])
    q1 = rotmat_to_wxyz(rotations[i + 1])
    rot = wxyz_to_rotmat(_slerp(q0, q1, a))
    return np.concatenate([rot, pos[:, None]], axis=1)


def _slerp(q0: np.ndarray, q1: np.ndarray, a: float) -> np.ndarray:
    dot = float(q0 @ q1)
    if dot < 0.0:  # shortest arc
        q1, dot = -q1, -dot
    if dot > 0.9995:  # nearly equal: normalised lerp avoids dividing by sin(~0)
        q = q0 + a * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(dot)
    return (np.sin((1 - a) * theta) * q0 + np.sin(a * theta) * q1) / np.sin(theta)
