"""Safety report against brute-force references (spheres: exact point-segment distances; curves:
very dense sampling), the plots written as valid PNGs, and the compiled dense sampling (native/timing.c) against the
numpy reference."""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from PIL import Image
from test_shot import make_shot  # tests/planner is on sys.path (pytest rootdir-relative import)
from test_timing import bezier_curves  # tests/planner/trajectory: random piecewise Bezier curves

from cinenerf_ns.planner import native
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.shots import safety
from cinenerf_ns.planner.shots.safety import (
    dense_samples,
    plot_clearance,
    plot_paths_topdown,
    safety_report,
    verify_shot,
)
from cinenerf_ns.planner.shots.shot import Shot
from cinenerf_ns.planner.trajectory.timing import TimingConfig, arc_length_table, time_parametrize

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


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 300), st.integers(2, 40), st.integers(0, 2**31 - 1), st.floats(1e-3, 1e3))
def test_point_density_marks_exactly_the_bins_that_hold_points(n, bins, seed, scale):
    """The top view's obstacle image against a per-point loop: a bin is opaque iff some point falls in it (its index
    by floor division), more opaque with more points, and the image covers every point."""
    rng = np.random.default_rng(seed)
    xy = rng.normal(0, scale, (n, 2)) * rng.uniform(0.01, 1, 2)  # [N, 2], anisotropic
    if n > 3:
        xy[: n // 3] = xy[0]  # repeated points: counts above 1
    rgba, lo, step = safety._point_density_rgba(xy, bins)
    h, w = rgba.shape[:2]
    np.testing.assert_array_equal(lo, xy.min(0))
    # the image covers every point (to rounding: (hi - lo) / step may land an ulp below a whole number of bins)
    assert max(h, w) <= bins + 1 and np.all(xy.max(0) <= lo + step * np.array([w, h]) + 1e-9 * step)
    counts = np.zeros((h, w), int)
    for x, y in xy:
        i = min(int(np.floor((y - lo[1]) / step)), h - 1)  # the top edge's points: in the last bin
        j = min(int(np.floor((x - lo[0]) / step)), w - 1)
        counts[i, j] += 1
    alpha = rgba[..., 3]
    np.testing.assert_array_equal(alpha > 0, counts > 0)
    if counts.max() > counts[counts > 0].min():
        assert alpha[counts == counts.max()].min() > alpha[counts == counts[counts > 0].min()].max()


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


# ---------------------------------------------------------------- the compiled dense sampling (native/timing.c)
needs_native = pytest.mark.skipif(native.dense_counts_c() is None or native.dense_fill_c() is None,
                                  reason=f"no compiled dense sampling: {native.native_status().get('timing')}")


def curve_shot(traj, curve_times: np.ndarray, times: np.ndarray = None) -> Shot:
    """A Shot of traj with frames at curve_times (positions on the curve), on the clock times (default 0, 1, ...)."""
    n = len(curve_times)
    return Shot(np.arange(n, dtype=float) if times is None else times, traj.evaluate(curve_times),
                np.broadcast_to(np.eye(3), (n, 3, 3)), np.zeros(3), traj.end, traj.start, trajectory=traj,
                curve_times=curve_times)


@st.composite
def curve_shots(draw) -> Shot:
    """Shots of random curves (test_timing.bezier_curves: degree 3-7, 1-12 segments, uneven durations, at rest at
    the ends or not, joins with corners or jumps) with frames from time_parametrize or at random monotone curve
    times: repeated times, times on the segment joins and at both ends, sometimes beyond them (clamped)."""
    traj = draw(bezier_curves())
    if draw(st.booleans()):  # the planner's frames: time_parametrize at about 60 frames whatever the curve's length
        length = float(arc_length_table(traj, 8, backend="python")[1][-1])
        vmax = max(length, 1e-9) / 2.0
        cfg = TimingConfig(max_speed=vmax, max_acceleration=draw(st.sampled_from([None, vmax])), fps=30.0)
        path = time_parametrize(traj, cfg, backend="python")
        return Shot(path.times, path.positions, np.broadcast_to(np.eye(3), (len(path.times), 3, 3)), np.zeros(3),
                    traj.end, traj.start, trajectory=traj, curve_times=path.curve_times)
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    total, joins = traj.total_duration, traj.segment_starts[1:]
    parts = [rng.uniform(0, total, draw(st.integers(0, 40))), rng.choice(np.concatenate([joins, [0.0, total]]),
                                                                          draw(st.integers(0, 12)))]
    if draw(st.booleans()):
        parts.append([-0.3 * total, total * 1.2])
    tau = np.sort(np.concatenate(parts + [[0.0, total]]))  # repeats: the joins drawn twice, 0 and total
    uneven = rng.choice([0.01, 1.0, 50.0], len(tau)) * rng.uniform(0.5, 1.5, len(tau))
    return curve_shot(traj, tau, np.cumsum(uneven))


def approx_lengths(shot: Shot) -> np.ndarray:
    """dense_samples' approx_len [T-1] by the numpy reference's own helpers (to size max_spacing)."""
    traj, tau = shot.trajectory, shot.curve_times
    vb = safety._speed_bounds(traj)
    return np.maximum(np.linalg.norm(np.diff(shot.positions, axis=0), axis=1),
                      safety._piece_speed_bound(traj, vb, tau[:-1], tau[1:]) * np.abs(np.diff(tau)))


def spacing_for(shot: Shot, kind) -> float:
    """max_spacing that gives about `kind` samples in all (an int), or ("exact", n): one interval's approx_len / n,
    so its ceil(approx_len / max_spacing) sits at an integer (counts must not differ by rounding)."""
    approx = approx_lengths(shot)
    if isinstance(kind, tuple):
        return float(approx.max() / kind[1]) if approx.max() > 0 else 1.0
    return float(approx.sum() / kind) if approx.sum() > 0 else 1.0


def assert_dense_equal(got, ref, traj):
    """The tolerances of the brief: counts identical, times ~1e-15 relative, positions ~1e-12 x the control points'
    scale, piece lengths ~1e-12 relative. On the CPU box the two backends agree bit for bit (timing.c's header)."""
    (t, pos, lengths), (t_ref, pos_ref, lengths_ref) = got, ref
    assert len(t) == len(t_ref) and pos.shape == pos_ref.shape and lengths.shape == lengths_ref.shape
    np.testing.assert_allclose(t, t_ref, rtol=1e-15, atol=0)
    scale = max(1.0, float(np.abs(traj.control_points).max()))
    np.testing.assert_allclose(pos, pos_ref, rtol=0, atol=1e-12 * scale)
    # a length that is the chord of two sample positions is only as close as they are (absolute)
    np.testing.assert_allclose(lengths, lengths_ref, rtol=1e-12, atol=1e-14 * scale)


@needs_native
@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(shot=curve_shots(), kind=st.sampled_from([1, 10, 300, 3000, ("exact", 1), ("exact", 7)]))
def test_native_dense_samples_are_the_numpy_ones(shot, kind):
    max_spacing = spacing_for(shot, kind)
    ref = dense_samples(shot, None, max_spacing, backend="python")
    got = dense_samples(shot, None, max_spacing, backend="native")
    traj, tau = shot.trajectory, shot.curve_times
    assert_dense_equal(got, ref, traj)
    t, pos, _ = got
    # the frames are samples, on the shot's clock; the curve's end points and joins are exact control points
    assert t[0] == shot.times[0] and t[-1] == shot.times[-1]
    np.testing.assert_array_equal(pos[-1], traj.evaluate(tau[-1:])[0])
    if tau[0] <= 0.0:
        np.testing.assert_array_equal(pos[0], traj.control_points[0, 0])
    if tau[-1] >= traj.total_duration:
        np.testing.assert_array_equal(pos[-1], traj.control_points[-1, -1])
    starts = traj.segment_starts
    for j in np.flatnonzero(np.isin(tau, starts[1:])):  # a frame on a join: the later segment, u = 0
        k = int(np.searchsorted(starts, tau[j]))
        assert np.any(np.all(pos == traj.control_points[k, 0], axis=1))


@needs_native
@pytest.mark.parametrize("max_spacing", [0.05, 0.005, 0.001])
def test_native_dense_samples_of_a_planned_shot(max_spacing):
    """make_shot (an arc from time_parametrize, at rest at its ends) at the verification's spacings."""
    shot = make_shot()
    ref = dense_samples(shot, None, max_spacing, backend="python")
    assert_dense_equal(dense_samples(shot, None, max_spacing, backend="native"), ref, shot.trajectory)
    assert len(ref[0]) >= shot.num_frames


def test_auto_uses_the_compiled_dense_sampling_when_it_loads(monkeypatch):
    """backend="auto" (dense_samples' default, so verify_shot's and safety_report's) takes native/timing.c for a Shot
    with its curve; "python" and a polyline never do; "native" for a polyline is an error."""
    if native.dense_counts_c() is None or native.dense_fill_c() is None:
        pytest.skip(f"no compiled dense sampling (no C compiler?): {native.native_status().get('timing')}")
    calls = []
    fn = native.dense_counts_c()
    monkeypatch.setattr(native, "dense_counts_c", lambda: calls.append("dense_counts_c") or fn)
    shot = make_shot()
    ref = dense_samples(shot, None, 0.01, backend="python")
    assert calls == []
    assert_dense_equal(dense_samples(shot, None, 0.01), ref, shot.trajectory)
    assert calls == ["dense_counts_c"]
    rep = verify_shot(shot, lambda p: np.ones(len(p), bool), lambda p: np.zeros(len(p)), max_spacing=0.01)
    assert rep["num_samples"] == len(ref[0]) and calls == ["dense_counts_c"] * 2
    calls.clear()
    dense_samples(shot.positions, shot.times, 0.01)
    assert calls == []
    with pytest.raises(RuntimeError, match="trajectory"):
        dense_samples(shot.positions, shot.times, 0.01, backend="native")
    with pytest.raises(InvalidInputError, match="backend"):
        dense_samples(shot, None, 0.01, backend="fast")
