"""fastnp.clip is np.clip bit for bit (signed zeros, NaN, ties, integer arrays), on the inputs the planner gives it."""
import numpy as np
import torch
from hypothesis import given, settings, strategies as st
from hypothesis.extra import numpy as hnp

from cinenerf_ns.planner.fastnp import clip
from cinenerf_ns.planner.scene.occupancy import OccupancyGrid

_f = st.floats(allow_nan=True, allow_infinity=True, width=64)
_special = st.sampled_from([0.0, -0.0, 1.0, -1.0, np.nan, np.inf, -np.inf, 5e-324])


@settings(max_examples=300, deadline=None)
@given(hnp.arrays(np.float64, st.integers(0, 40), elements=st.one_of(_f, _special)), st.one_of(_f, _special),
       st.one_of(_f, _special))
def test_clip_float_bitwise(x, lo, hi):
    assert np.array_equal(clip(x, lo, hi).view(np.int64), np.clip(x, lo, hi).view(np.int64))


@settings(max_examples=200, deadline=None)
@given(hnp.arrays(np.float64, (5, 3), elements=_f), hnp.arrays(np.float64, 3, elements=_f),
       hnp.arrays(np.float64, (5, 3), elements=_f))
def test_clip_array_bounds_bitwise(x, lo, hi):
    assert np.array_equal(clip(x, lo, hi).view(np.int64), np.clip(x, lo, hi).view(np.int64))


@settings(max_examples=200, deadline=None)
@given(hnp.arrays(np.int64, (7, 3), elements=st.integers(-50, 50)), st.integers(1, 40))
def test_clip_int(x, n):
    shape = np.array([n, n + 1, n + 2])
    a, b = clip(x, 0, shape - 1), np.clip(x, 0, shape - 1)
    assert a.dtype == b.dtype and np.array_equal(a, b)
    a, b = clip(x[:, 0], 0, n - 1), np.clip(x[:, 0], 0, n - 1)
    assert a.dtype == b.dtype and np.array_equal(a, b)


def test_clip_scalar():
    for v in (-0.0, 0.0, 0.3, 2.0, np.nan):
        a, b = clip(v, 0.0, 1.0), np.clip(v, 0.0, 1.0)
        assert type(a) is type(b) and np.array_equal(np.float64(a).view(np.int64), np.float64(b).view(np.int64))


@settings(max_examples=100, deadline=None)
@given(hnp.arrays(np.int64, (st.integers(0, 30)), elements=st.integers(-3, 200)).map(lambda a: a.reshape(-1, 3) if
       a.size % 3 == 0 else a[: a.size - a.size % 3].reshape(-1, 3)),
       st.floats(-100, 100), st.floats(1e-3, 10.0))
def test_voxel_centres_numpy_matches_grid(path, lo0, vs):
    """stages.voxel_centres' numpy spelling of OccupancyGrid.voxel_to_world gives the same bits."""
    lo = np.array([lo0, -0.37 * lo0, 0.1 + lo0 / 7])
    grid = OccupancyGrid(torch.as_tensor(lo), vs, torch.zeros(2, 2, 2, dtype=torch.bool))
    ref = grid.voxel_to_world(torch.as_tensor(path)).cpu().numpy()
    new = lo + (path.astype(np.float64) + 0.5) * vs
    assert ref.shape == new.shape and np.array_equal(ref.view(np.int64), new.view(np.int64))


@settings(max_examples=100, deadline=None)
@given(hnp.arrays(np.float64, st.integers(1, 8), elements=st.floats(1e-3, 50.0)), st.integers(2, 80))
def test_arc_length_grid_matches_per_segment_loop(durations, n):
    """timing.arc_length_table's broadcast grid of curve times equals the former per-segment loop bit for bit."""
    from cinenerf_ns.planner.trajectory.bezier import BezierTrajectory
    from cinenerf_ns.planner.trajectory.timing import arc_length_table

    cp = np.random.default_rng(n).normal(size=(len(durations), 4, 3))
    traj = BezierTrajectory(cp, durations)
    taus = [traj.segment_starts[k] + traj.durations[k] * np.linspace(0.0, 1.0, n + 1)[:-1]
            for k in range(traj.num_segments)]
    ref = np.concatenate(taus + [[traj.total_duration]])
    tau, _ = arc_length_table(traj, n)
    assert np.array_equal(ref.view(np.int64), tau.view(np.int64))
