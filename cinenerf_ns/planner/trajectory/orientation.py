"""Look-at camera orientations in the nerfstudio / OpenGL convention.

Camera axes in world coordinates: x right, y up, the camera looks along -z. A camera-to-world
rotation has these axes as its columns, so R @ [0, 0, -1] is the viewing direction.

For a camera at p looking at target g:
    z = -(g - p) / |g - p|               (camera looks along -z, i.e. toward g)
    x = normalise(up x z)                (horizontal: y = z x x then has the largest possible up-component)
    y = z x x

Singularity: when the view direction is (nearly) parallel to `up`, up x z vanishes and its direction
jumps by up to 180 degrees. Inside the cone |up x z| < singular_sin we rotate the previous frame's x
axis (projected perpendicular to the new z) part of the way toward the up-derived x, by a weight that
goes from 0 at the cone axis to 1 at its border; the frame therefore never is NaN and turns
continuously (a 180-degree roll through the pole is spread over the frames inside the cone instead of
happening in one frame). The first frame, if singular, starts from a fixed fallback axis.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from ..errors import InvalidInputError
from ..native import choose, look_at_c
from .bezier import is_torch, same_kind_as, to_numpy


def _normalise(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """np.cross(a, b) of [..., 3] arrays (broadcast), bit for bit (the same products and differences): np.cross's
    axis handling cost ~10 us a call, most of this module's time on a few hundred frames."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _fallback_axis(z: np.ndarray, up: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to z from the world axis least aligned with up (first singular frame)."""
    axis = np.eye(3)[int(np.argmin(np.abs(up)))]
    x = axis - (axis @ z) * z
    if np.linalg.norm(x) < 1e-6:
        axis = np.eye(3)[(int(np.argmin(np.abs(up))) + 1) % 3]
        x = axis - (axis @ z) * z
    return x / np.linalg.norm(x)


def _look_at_native(fn, pos: np.ndarray, tgt: np.ndarray, upv: np.ndarray, singular_sin: float):
    """native/orientation.c's rotations [T, 3, 3] for float64 positions [T, 3], target [3] or [T, 3] and a unit up
    [3], or None when a frame needs the Python path (at the target, inside the singular cone, not finite)."""
    p = np.ascontiguousarray(pos)
    g = np.ascontiguousarray(tgt)
    u = np.ascontiguousarray(upv)
    out = np.empty((p.shape[0], 3, 3))
    status = fn(p.ctypes.data, g.ctypes.data, int(g.ndim == 2), p.shape[0], u.ctypes.data, float(singular_sin),
                out.ctypes.data)
    return out if status == 0 else None


def look_at_rotations(
    positions: Any,
    target: Any,
    up: Sequence[float] = (0.0, 0.0, 1.0),
    singular_sin: float = 0.2,
    backend: str = "auto",
):
    """Camera-to-world rotations looking from positions [T,3] at target [3] or [T,3] -> [T,3,3].

    Columns are the camera x (right), y (up), z (backward) axes in world coordinates. Numpy in, numpy
    float64 out; torch in (positions), torch float64 out on the same device. Frames are processed in
    order, so pass the samples of one continuous path. Frames whose position equals the target reuse
    the nearest valid view direction; if none is valid an InvalidInputError is raised.
    singular_sin: sine of the half-angle of the cone around +-up inside which the previous frame's x axis
    is carried along (default 0.2, ~11.5 deg; larger spreads a pole crossing over more frames).
    backend: "auto" (native/orientation.c when it loads, for paths with every frame away from the target and outside
    the cone: the same arithmetic), "native" (the same; other paths still take numpy) or "python".
    """
    pos = to_numpy(positions)
    tgt = to_numpy(target)
    upv = to_numpy(up).reshape(-1)
    if upv.shape == (3,) and np.isfinite(upv).all() and np.abs(upv).max() > 0:
        upv = upv / np.abs(upv).max()  # scaled before any norm: (0, 1e300, 0) is +y, not an overflowed zero vector
    if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] == 0:
        raise InvalidInputError(f"positions must have shape [T, 3] with T >= 1, got {tuple(pos.shape)}.")
    tgt_given = tgt  # [3] or [T, 3]: the compiled path reads either without a broadcast copy
    if tgt.shape == (3,):
        tgt = np.broadcast_to(tgt, pos.shape)
    if tgt.shape != pos.shape:
        raise InvalidInputError(f"target must have shape [3] or {tuple(pos.shape)}, got {tuple(tgt.shape)}.")
    if upv.shape != (3,) or np.linalg.norm(upv) < 1e-12:
        raise InvalidInputError(f"up must be a nonzero 3D vector, got {upv.tolist()}.")
    fn = choose(backend, look_at_c, "orientation", "look-at rotations")
    if fn is not None and np.isfinite(upv).all():
        rot = _look_at_native(fn, pos, tgt_given, upv / np.linalg.norm(upv), singular_sin)
        if rot is not None:
            return same_kind_as(rot, positions)
    if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(tgt)) and np.all(np.isfinite(upv))):
        raise InvalidInputError("positions, target and up must be finite (found NaN or inf).")
    upv = upv / np.linalg.norm(upv)

    back = pos - tgt  # [T, 3] points from the target to the camera = +z direction
    dist = np.linalg.norm(back, axis=1)  # [T]
    scale = max(1.0, float(np.abs(pos).max()), float(np.abs(tgt).max()))
    valid = dist > 1e-9 * scale
    if not valid.any():
        raise InvalidInputError("every camera position coincides with the look-at target; nothing to look at.")
    z = np.zeros_like(back)
    z[valid] = back[valid] / dist[valid, None]
    if not valid.all():  # copy the nearest valid direction (previous, else next)
        idx = np.where(valid, np.arange(len(z)), -1)
        prev = np.maximum.accumulate(idx)
        first = int(np.flatnonzero(valid)[0])
        prev[prev < 0] = first
        z = z[prev]

    cross = _cross(upv, z)  # [T, 3]
    s = np.linalg.norm(cross, axis=1)  # [T] sine of the angle between view axis and up
    x = np.zeros_like(z)
    regular = s >= singular_sin
    x[regular] = cross[regular] / s[regular, None]
    for t in np.flatnonzero(~regular):  # few frames: near straight up/down only
        if t == 0:
            prev_x = _fallback_axis(z[0], upv)
        else:
            prev_x = x[t - 1] - (x[t - 1] @ z[t]) * z[t]
            n = np.linalg.norm(prev_x)
            prev_x = prev_x / n if n > 1e-9 else _fallback_axis(z[t], upv)
        if s[t] < 1e-12:
            x[t] = prev_x
            continue
        want = cross[t] / s[t]
        # signed angle from prev_x to want about z[t]; rotate by w * angle (Rodrigues about z, both _|_ z)
        angle = np.arctan2(_cross(prev_x, want) @ z[t], prev_x @ want)
        w = s[t] / singular_sin  # 0 on the cone axis, 1 on its border
        a = w * angle
        x[t] = np.cos(a) * prev_x + np.sin(a) * _cross(z[t], prev_x)
    x = _normalise(x)
    y = _cross(z, x)
    rot = np.stack([x, y, z], axis=-1)  # [T, 3, 3] columns x, y, z
    return same_kind_as(rot, positions)


def view_directions(rotations: Any):
    """Viewing direction (-z column) of camera-to-world rotations [T,3,3] -> [T,3]."""
    r = to_numpy(rotations)
    return same_kind_as(-r[..., :, 2], rotations)


def look_at_error_deg(positions: Any, rotations: Any, target: Any):
    """Angle in degrees between each camera's view direction and the direction to the target, [T]."""
    pos = to_numpy(positions)
    to_target = to_numpy(target) - pos
    view = -to_numpy(rotations)[..., :, 2]
    # atan2(|a x b|, a.b): accurate near 0, where arccos(dot) loses half the digits
    out = np.degrees(np.arctan2(np.linalg.norm(np.cross(to_target, view), axis=-1), np.sum(to_target * view, axis=-1)))
    return same_kind_as(out, positions) if is_torch(positions) else out
