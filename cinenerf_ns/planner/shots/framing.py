"""Framing: how large the look-at subject is in the frame, and whether all of it is in the frame.

A subject's size in a frame is its larger relative extent: the height of its projected bounding box over the frame
height, or its width over the frame width, whichever is larger (1: it touches two opposite edges). The camera looks
at the subject's look-at point with the planner's up vector (trajectory/orientation.py's convention: no roll), a
pinhole of vertical field of view ``fov_deg`` and aspect width / height. The subject's extent is that of its
Gaussians' means grown by one median sigma (approximate: a splat's visible edge lies about a sigma beyond its means).

Presets (``FRAMING_BANDS``): the band of sizes a framing accepts and the size it aims for.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, Tuple

import numpy as np

from ..errors import InvalidInputError

FRAMING_BANDS: Dict[str, Tuple[float, float, float]] = {
    "wide": (0.15, 0.25, 0.35),
    "medium": (0.35, 0.45, 0.60),
    "close": (0.60, 0.70, 0.85),
}
"""framing -> (smallest, aimed-for, largest) size of the subject in the last frame (larger relative extent)."""
FRAMINGS = tuple(FRAMING_BANDS)
IN_FRAME = 0.95
"""Every extent point must project within this fraction of the half frame (a margin so nothing is cut off)."""


@dataclass
class FramingConfig:
    """The look of the last frame: the subject's size band and the camera's field of view."""

    framing: str = "medium"
    """wide | medium | close: the subject's size in the last frame (FRAMING_BANDS)."""
    fov_deg: float = 50.0
    """Vertical field of view of the exported camera, degrees."""
    aspect: float = 16.0 / 9.0
    """Width / height of the exported frames."""

    def validate(self) -> None:
        if self.framing not in FRAMING_BANDS:
            raise InvalidInputError(f"framing (--framing) must be one of {', '.join(FRAMINGS)}, got {self.framing!r}")
        if not (isinstance(self.fov_deg, (int, float)) and 1 <= self.fov_deg <= 179):
            raise InvalidInputError(f"fov_deg (--fov) must be in [1, 179] degrees, got {self.fov_deg!r}")
        if not (isinstance(self.aspect, (int, float)) and math.isfinite(self.aspect) and 0.01 <= self.aspect <= 100):
            raise InvalidInputError(f"aspect (width / height) must be in [0.01, 100], got {self.aspect!r}")

    @property
    def band(self) -> Tuple[float, float, float]:
        return FRAMING_BANDS[self.framing]

    def tan_half(self) -> Tuple[float, float]:
        """(tan of half the horizontal fov, tan of half the vertical fov)."""
        tv = math.tan(math.radians(self.fov_deg) / 2)
        return tv * self.aspect, tv


def camera_axes(cameras: np.ndarray, look_at: np.ndarray, up: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(forward, right, camera up) [M, 3] each of cameras [M, 3] looking at look_at [3] (or [M, 3]) without roll."""
    f = np.asarray(look_at, np.float64) - cameras
    f = f / np.maximum(np.linalg.norm(f, axis=-1, keepdims=True), 1e-12)
    r = np.cross(f, np.asarray(up, np.float64))
    rn = np.linalg.norm(r, axis=-1, keepdims=True)
    # looking straight along up: any right vector (orientation.py handles the pole the same way in spirit)
    alt = np.cross(f, np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
    r = np.where(rn > 1e-9, r / np.maximum(rn, 1e-12), alt / np.maximum(np.linalg.norm(alt, axis=-1, keepdims=True),
                                                                        1e-12))
    return f, r, np.cross(r, f)


def project(cameras: np.ndarray, look_at: np.ndarray, up: np.ndarray, points: np.ndarray,
            cfg: FramingConfig) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, depth) [M, P] of points [P, 3] seen from cameras [M, 3] aimed at look_at: x, y in units of the half
    frame (-1..1 is inside the frame), depth along the view axis."""
    f, r, u = camera_axes(cameras, look_at, up)
    pts = np.asarray(points, np.float64)

    def along(axis: np.ndarray) -> np.ndarray:  # [M, P]: (points - camera) . axis, as one matrix product
        return axis @ pts.T - np.einsum("mk,mk->m", axis, cameras)[:, None]

    depth = along(f)
    th, tv = cfg.tan_half()
    z = np.maximum(depth, 1e-9)
    return along(r) / (z * th), along(u) / (z * tv), depth


def subject_size(cameras: np.ndarray, look_at: np.ndarray, up: np.ndarray, extent: np.ndarray, pad: float,
                 cfg: FramingConfig, backend: str = "auto") -> Tuple[np.ndarray, np.ndarray]:
    """(size [M], whole [M] bool) of a subject whose extent points are ``extent`` [P, 3] grown by ``pad`` (scene units):
    its larger relative extent in each camera's frame (module docstring), and whether every point lies in front of
    the camera and inside IN_FRAME of the frame. backend: "auto" (native/targets.c when it loads and applies: one
    look-at point, finite inputs; the same up to rounding), "native", "python" (subject_size_reference)."""
    from ..native import choose, subject_size_c

    cam = np.ascontiguousarray(np.asarray(cameras, np.float64).reshape(-1, 3))
    look = np.ascontiguousarray(np.asarray(look_at, np.float64))
    pts = np.ascontiguousarray(np.asarray(extent, np.float64).reshape(-1, 3))
    fn = choose(backend, subject_size_c, "targets", "subject size", applies=look.shape == (3,) and len(pts) > 0,
                needs="one look-at point and at least one extent point")
    if fn is not None:
        upv = np.ascontiguousarray(np.asarray(up, np.float64).reshape(3))
        size, whole = np.empty(len(cam)), np.empty(len(cam), np.uint8)
        th, tv = cfg.tan_half()
        rc = fn(cam.ctypes.data, len(cam), look.ctypes.data, upv.ctypes.data, pts.ctypes.data, len(pts), float(pad),
                th, tv, IN_FRAME, size.ctypes.data, whole.ctypes.data)
        if rc == 0:
            return size, whole.astype(bool)
        if backend == "native":
            raise RuntimeError("the compiled subject size does not apply here (it needs finite inputs)")
    return subject_size_reference(cam, look, up, pts, pad, cfg)


def subject_size_reference(cameras: np.ndarray, look_at: np.ndarray, up: np.ndarray, extent: np.ndarray, pad: float,
                           cfg: FramingConfig) -> Tuple[np.ndarray, np.ndarray]:
    """subject_size in numpy (float64): the reference of the compiled path."""
    x, y, depth = project(cameras, look_at, up, extent, cfg)
    th, tv = cfg.tan_half()
    z = np.maximum(depth, 1e-9)
    px, py = pad / (z * th), pad / (z * tv)  # the pad in half-frame units at each point's depth
    w = ((x + px).max(1) - (x - px).min(1)) / 2
    h = ((y + py).max(1) - (y - py).min(1)) / 2
    whole = ((depth.min(1) > pad) & (np.abs(x).max(1) + px.max(1) <= IN_FRAME)
             & (np.abs(y).max(1) + py.max(1) <= IN_FRAME))
    return np.maximum(w, h), whole


def size_cost(size: np.ndarray, cfg: FramingConfig) -> np.ndarray:
    """How far sizes [M] are from the framing: 0 at the aimed-for size, growing with |log| and 9x as fast outside
    the band."""
    lo, aim, hi = cfg.band
    s = np.maximum(size, 1e-9)
    out = np.maximum(0.0, np.maximum(np.log(lo / s), np.log(s / hi)))
    return np.abs(np.log(s / aim)) + 8.0 * out


def in_band(size, cfg: FramingConfig, tol: float = 0.0) -> np.ndarray:
    lo, _, hi = cfg.band
    s = np.asarray(size, np.float64)
    return (s >= lo * (1 - tol)) & (s <= hi * (1 + tol))
