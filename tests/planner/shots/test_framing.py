"""Framing (shots/framing.py): the compiled subject size (native/targets.c) against the numpy reference and a
point-by-point float64 reference."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner import native
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.shots.framing import (
    IN_FRAME,
    FramingConfig,
    subject_size,
    subject_size_reference,
)


def _size_by_points(cam, look, up, pts, pad, cfg) -> tuple:
    """One camera, point by point: its axes (no roll), each point's frame coordinates and its pad, float64; whole: in
    front by more than the pad, and the largest |x| plus the largest pad within IN_FRAME (framing.subject_size's
    rule)."""
    f = (look - cam) / max(np.linalg.norm(look - cam), 1e-12)
    r = np.cross(f, up)
    if np.linalg.norm(r) <= 1e-9:
        r = np.cross(f, [1.0, 0, 0] if abs(up[0]) < 0.9 else [0, 1.0, 0])
    r = r / np.linalg.norm(r)
    u = np.cross(r, f)
    th, tv = cfg.tan_half()
    xs, ys, ax, ay, pxs, pys, ok = [], [], [], [], [], [], True
    for p in pts:
        d = float((p - cam) @ f)
        z = max(d, 1e-9)
        x, y, px, py = float((p - cam) @ r) / (z * th), float((p - cam) @ u) / (z * tv), pad / (z * th), pad / (z * tv)
        xs += [x - px, x + px]
        ys += [y - py, y + py]
        ok &= d > pad
        ax, ay, pxs, pys = ax + [abs(x)], ay + [abs(y)], pxs + [px], pys + [py]
    ok &= max(ax) + max(pxs) <= IN_FRAME and max(ay) + max(pys) <= IN_FRAME
    return max(max(xs) - min(xs), max(ys) - min(ys)) / 2, ok


@pytest.mark.skipif(native.subject_size_c() is None, reason="the compiled subject size did not load here")
@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), m=st.integers(1, 40), p=st.integers(1, 80), pole=st.booleans(),
       framing=st.sampled_from(["wide", "medium", "close"]), up_axis=st.sampled_from([0, 1, 2]))
def test_compiled_subject_size_is_the_reference(seed, m, p, pole, framing, up_axis):
    rng = np.random.default_rng(seed)
    up = np.eye(3)[up_axis] * (1 if rng.random() < 0.5 else -1)
    look = rng.uniform(-1, 1, 3)
    pts = look + rng.normal(size=(p, 3)) * rng.uniform(0.01, 0.5)
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    if pole:  # straight above or below the look-at point: the camera's right axis from the other fallback
        d[0] = up * (1 if rng.random() < 0.5 else -1)
    cam = look + d * rng.uniform(0.05, 4.0, (m, 1))
    pad = float(rng.uniform(0, 0.05))
    cfg = FramingConfig(framing, fov_deg=float(rng.uniform(20, 100)), aspect=float(rng.uniform(0.5, 2.5)))
    size, whole = subject_size(cam, look, up, pts, pad, cfg, backend="native")
    size_p, whole_p = subject_size_reference(cam, look, up, pts, pad, cfg)
    np.testing.assert_allclose(size, size_p, rtol=1e-12)
    for i in range(m):
        want, ok = _size_by_points(cam[i], look, up, pts, pad, cfg)
        assert math.isclose(size[i], want, rel_tol=1e-9, abs_tol=1e-12)
        if whole[i] != whole_p[i] or whole[i] != ok:  # only within rounding of a limit
            x = subject_size(cam[i:i + 1], look, up, pts, pad * (1 + 1e-9), cfg, backend="python")[1][0]
            y = subject_size(cam[i:i + 1], look, up, pts, pad * (1 - 1e-9), cfg, backend="python")[1][0]
            assert x != y


def test_subject_size_falls_back_and_checks_its_backend():
    cfg = FramingConfig("medium")
    cam, up, pts = np.array([[2.0, 0, 0], [0, 2.0, 1.0]]), np.array([0, 0, 1.0]), np.zeros((1, 3))
    looks = np.zeros((2, 3))  # one look-at point per camera: the numpy path
    size, whole = subject_size(cam, looks, up, pts, 0.1, cfg)
    np.testing.assert_array_equal(size, subject_size_reference(cam, looks, up, pts, 0.1, cfg)[0])
    with pytest.raises(InvalidInputError):
        subject_size(cam, np.zeros(3), up, pts, 0.1, cfg, backend="gpu")
    if native.subject_size_c() is not None:
        with pytest.raises(RuntimeError):
            subject_size(cam, looks, up, pts, 0.1, cfg, backend="native")
        bad = cam.copy()
        bad[0, 0] = np.nan  # a non-finite camera: the numpy path answers (NaN) under "auto"
        assert np.isnan(subject_size(bad, np.zeros(3), up, pts, 0.1, cfg)[0][0])
