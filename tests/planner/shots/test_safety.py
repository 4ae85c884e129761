"""Safety report against brute-force references (spheres: exact point-segment distances; curves:
very dense sampling), and the plots written as valid PNGs."""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from PIL import Image
from test_shot import make_shot  # tests/planner is on sys.path (pytest rootdir-relative import)

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.shots.safety import plot_clearance, plot_paths_topdown, safety_report

CAMERA_RADIUS = 0.03


def sphere_clearance(centres: np.ndarray, radii: np.ndarray):
    """Reference clearance of the camera ball among spheres: min_j |p - c_j| - r_j - camera radius."""

    def fn(points):
        p = np.asarray(points, dtype=np.float64)
        d = np.linalg.norm(p[:, None, :] - centres[None], axis=2) - radii[None]
        return d.min(1) - CAMERA_RADIUS

    return fn


def exact_polyline_min(pos: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> float:
    """Exact minimum clearance over the polyline: closest point of each segment to each centre."""
    a, b = pos[:-1, None], pos[1:, None]  # [S,1,3]
    ab = b - a
    t = np.clip(np.sum((centres[None] - a) * ab, -1) / np.maximum(np.sum(ab * ab, -1), 1e-300), 0, 1)
    closest = a + t[..., None] * ab
    d = np.linalg.norm(closest - centres[None], axis=-1) - radii[None]
    return float(d.min()) - CAMERA_RADIUS


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from([0.05, 0.01, 0.002]))
def test_polyline_report_matches_exact(seed, spacing):
    rng = np.random.default_rng(seed)
    pos = np.cumsum(rng.normal(scale=0.3, size=(12, 3)), axis=0)
    centres = rng.uniform(pos.min(0) - 0.5, pos.max(0) + 0.5, size=(6, 3))
    radii = rng.uniform(0.05, 0.3, size=6)
    fn = sphere_clearance(centres, radii)
    rep = safety_report(pos, fn, times=np.arange(12) * 0.5, max_spacing=spacing)
    exact = exact_polyline_min(pos, centres, radii)
    # samples are points of the path: their min is >= the exact min, and close to it
    assert rep["min_clearance"] >= exact - 1e-12
    assert rep["min_clearance"] - exact <= spacing / 2 + 1e-12
    # the certificate never exceeds the true minimum
    assert rep["lipschitz_lower_bound"] <= exact + 1e-12
    assert rep["max_sample_spacing"] <= spacing + 1e-12
    # internal consistency
    c = np.array(rep["clearance"])
    assert rep["num_samples"] == len(c) == len(rep["times"])
    assert rep["mean_clearance"] == pytest.approx(c.mean())
    assert fn(np.array([rep["argmin_position"]]))[0] == pytest.approx(rep["min_clearance"])
    for th, frac in rep["fraction_below"].items():
        assert frac == pytest.approx(np.mean(c < float(th)))
    assert rep["safe"] == (rep["min_clearance"] > 0)
    assert rep["times"][0] == 0.0 and rep["times"][-1] == pytest.approx(5.5)
    json.dumps(rep, allow_nan=False)


def test_shot_report_samples_the_curve():
    shot = make_shot()
    centres = np.array([[0.0, 0.0, 0.5], [2.0, 0.0, 0.8]])
    radii = np.array([1.0, 0.2])
    fn = sphere_clearance(centres, radii)
    rep = safety_report(shot, fn, max_spacing=0.005, label="arc")
    # brute force: 200k points of the Bezier curve
    dense = shot.trajectory.evaluate(np.linspace(0, shot.trajectory.total_duration, 200_001))
    brute = float(fn(dense).min())
    assert rep["min_clearance"] >= brute - 1e-6
    assert rep["min_clearance"] - brute <= 0.0025 + 1e-6
    assert rep["lipschitz_lower_bound"] <= brute
    assert rep["min_clearance"] - rep["lipschitz_lower_bound"] < 0.01
    # denser than the frames, on the shot's clock
    assert rep["num_samples"] > shot.num_frames
    assert rep["times"][-1] == pytest.approx(shot.times[-1])
    # the argmin time is the shot time of the closest approach (frames near it are close too)
    j = int(np.argmin(np.abs(shot.times - rep["argmin_time_s"])))
    assert np.linalg.norm(shot.positions[j] - rep["argmin_position"]) <= 0.5 / shot.fps + 1e-9
    assert rep["label"] == "arc"


def test_colliding_path_is_reported_unsafe():
    pos = np.array([[-1.0, 0, 0], [1.0, 0, 0]])
    rep = safety_report(pos, sphere_clearance(np.zeros((1, 3)), np.array([0.5])))
    assert not rep["safe"]
    assert rep["min_clearance"] == pytest.approx(-0.5 - CAMERA_RADIUS, abs=1e-9)
    assert rep["argmin_time_s"] == pytest.approx(0.5, abs=0.01)
    assert rep["fraction_below"]["0"] == pytest.approx((2 * 0.53) / 2, abs=0.01)  # |x| < 0.5 + r_cam


def is_png(path) -> tuple:
    with open(path, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    with Image.open(path) as im:
        im.verify()
    with Image.open(path) as im:
        return im.size


def test_plots_are_valid_pngs(tmp_path):
    shot = make_shot()
    fn = sphere_clearance(np.array([[0.0, 0.0, 0.5]]), np.array([1.0]))
    reps = [safety_report(shot, fn, label="A")]
    other = shot.positions + np.array([0.0, 0.0, 0.3])
    reps.append(safety_report(other, fn, times=shot.times, label="B"))
    out = plot_clearance(reps, tmp_path / "plots" / "clearance.png")
    w, h = is_png(out)
    assert w > 300 and h > 150
    assert is_png(plot_clearance(reps[0], tmp_path / "one.png"))
    ellipsoids = SimpleNamespace(
        means=np.array([[0.0, 0.0, 0.5], [2.0, 1.0, 0.5]]),
        rotations=np.stack([np.eye(3), np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])]),
        radii=np.array([[1.0, 1.0, 1.0], [0.5, 0.2, 0.3]]),
    )
    out = plot_paths_topdown(
        [shot, other], tmp_path / "top.png", obstacles=ellipsoids,
        targets={"look at": shot.look_at, "go to": shot.goal}, labels=["A", "B"],
    )
    assert is_png(out)
    assert is_png(plot_paths_topdown([shot.positions], tmp_path / "pts.png", obstacles=np.random.rand(100, 3)))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one.png", "plots", "pts.png", "top.png"]


def test_bad_input():
    fn = sphere_clearance(np.zeros((1, 3)), np.array([0.1]))
    with pytest.raises(InvalidInputError):
        safety_report(np.zeros((3, 2)), fn)
    with pytest.raises(InvalidInputError):
        safety_report(np.zeros((3, 3)), fn, times=np.zeros(2))
    with pytest.raises(InvalidInputError):
        safety_report(np.ones((3, 3)), lambda p: np.full(len(p), np.nan))
    with pytest.raises(InvalidInputError):
        safety_report(np.ones((3, 3)), lambda p: np.zeros(2))
    with pytest.raises(InvalidInputError):
        safety_report(np.ones((3, 3)), fn, max_spacing=0.0)
    with pytest.raises(InvalidInputError):
        plot_clearance([], "x.png")
