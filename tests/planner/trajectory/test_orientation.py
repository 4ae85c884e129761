"""Look-at rotations: aim, orthonormality, best possible up vector, and no NaN/flip at the poles."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st
from hypothesis.extra.numpy import arrays

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.trajectory.orientation import look_at_error_deg, look_at_rotations, view_directions


def frame_step_deg(rot: np.ndarray) -> np.ndarray:
    """Geodesic angle between consecutive rotations, [T-1] degrees."""
    rel = np.einsum("tji,tjk->tik", rot[:-1], rot[1:])  # R_t^T R_{t+1}
    cos = (np.trace(rel, axis1=1, axis2=2) - 1) / 2
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def check_frames(rot: np.ndarray):
    assert np.all(np.isfinite(rot))
    np.testing.assert_allclose(np.einsum("tji,tjk->tik", rot, rot), np.broadcast_to(np.eye(3), rot.shape), atol=1e-10)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-10)


coords = st.floats(-10, 10, allow_nan=False, allow_infinity=False)


@settings(max_examples=150, deadline=None)
@given(arrays(np.float64, (7, 3), elements=coords), arrays(np.float64, (3,), elements=coords))
def test_aims_at_target_and_is_orthonormal(pos, target):
    far = np.linalg.norm(pos - target, axis=1) > 1e-3
    pos = pos[far]
    if len(pos) == 0:
        return
    rot = look_at_rotations(pos, target)
    check_frames(rot)
    np.testing.assert_allclose(look_at_error_deg(pos, rot, target), 0.0, atol=1e-5)
    # independent check of the aim: -z column is the unit vector to the target
    d = (target - pos) / np.linalg.norm(target - pos, axis=1, keepdims=True)
    np.testing.assert_allclose(view_directions(rot), d, atol=1e-9)
    # y has the largest up-component a frame with this view direction can have (regular frames)
    up = np.array([0.0, 0, 1])
    horiz = np.sqrt(np.clip(1 - (d @ up) ** 2, 0, None))
    regular = horiz >= 0.2
    np.testing.assert_allclose(rot[regular][:, :, 1] @ up, horiz[regular], atol=1e-9)
    # x is horizontal (no roll)
    np.testing.assert_allclose(rot[regular][:, :, 0] @ up, 0.0, atol=1e-9)


def test_known_frame_nerfstudio_convention():
    # camera at origin looking along +y with z up: x right = +x world, y = +z world
    rot = look_at_rotations(np.zeros((1, 3)), np.array([0.0, 5.0, 0.0]))[0]
    np.testing.assert_allclose(rot, [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)


def test_per_frame_targets_and_other_up():
    rng = np.random.default_rng(0)
    pos = rng.normal(size=(20, 3))
    tgt = rng.normal(size=(20, 3)) + 5
    rot = look_at_rotations(pos, tgt, up=(0.0, 1.0, 0.0))
    check_frames(rot)
    np.testing.assert_allclose(look_at_error_deg(pos, rot, tgt), 0.0, atol=1e-5)


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_passing_under_or_over_target_has_no_flip(sign):
    """The camera passes straight below (above) the target: the up-derived x axis would flip 180 deg
    in one frame; the returned frames stay finite and turn by a bounded angle per frame."""
    t = np.linspace(-1, 1, 401)
    pos = np.stack([t, np.zeros_like(t), np.full_like(t, -sign)], 1)  # straight line through the pole
    target = np.zeros(3)
    rot = look_at_rotations(pos, target)
    check_frames(rot)
    np.testing.assert_allclose(look_at_error_deg(pos, rot, target), 0.0, atol=1e-5)
    steps = frame_step_deg(rot)
    assert steps.max() < 20.0, steps.max()
    # the naive formula really does flip here (the test can fail)
    naive = np.cross([0, 0, 1.0], pos - target)
    naive /= np.linalg.norm(naive, axis=1, keepdims=True) + 1e-300
    assert np.degrees(np.arccos(np.clip(np.sum(naive[199] * naive[201]), -1, 1))) > 170


def test_exactly_vertical_first_frame_and_static_view():
    pos = np.array([[0.0, 0, -1], [0.0, 0, -2], [0.0, 0, 3]])  # straight up, straight up, straight down
    rot = look_at_rotations(pos, np.zeros(3))
    check_frames(rot)
    np.testing.assert_allclose(look_at_error_deg(pos, rot, np.zeros(3)), 0.0, atol=1e-6)


def test_position_on_target_reuses_neighbour_and_all_on_target_raises():
    pos = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]])
    rot = look_at_rotations(pos, np.array([1.0, 0, 0]))
    check_frames(rot)
    np.testing.assert_allclose(rot[1], rot[0])
    with pytest.raises(InvalidInputError):
        look_at_rotations(np.ones((2, 3)), np.ones(3))


def test_bad_input():
    with pytest.raises(InvalidInputError):
        look_at_rotations(np.zeros((3, 2)), np.zeros(3))
    with pytest.raises(InvalidInputError):
        look_at_rotations(np.array([[np.nan, 0, 0]]), np.ones(3))
    with pytest.raises(InvalidInputError):
        look_at_rotations(np.zeros((1, 3)), np.ones(3), up=(0, 0, 0))
    with pytest.raises(InvalidInputError):
        look_at_rotations(np.zeros((2, 3)), np.ones((3, 3)))


def test_torch_in_torch_out():
    pos = torch.randn(5, 3, dtype=torch.float32)
    rot = look_at_rotations(pos, torch.tensor([5.0, 5.0, 5.0]))
    assert isinstance(rot, torch.Tensor) and rot.dtype == torch.float64 and rot.shape == (5, 3, 3)
    np.testing.assert_allclose(rot.numpy(), look_at_rotations(pos.double().numpy(), np.full(3, 5.0)))


def test_smooth_path_gives_smooth_rotations():
    s = np.linspace(0, 2 * np.pi, 300)
    pos = np.stack([np.cos(s) * 3, np.sin(s) * 3, 0.5 * np.sin(3 * s)], 1)
    rot = look_at_rotations(pos, np.array([0.0, 0.0, 0.2]))
    steps = frame_step_deg(rot)
    assert steps.max() < 3.0  # ~1.2 deg of yaw per frame, no jumps


@settings(max_examples=100, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([(3,), (1, 3), (7, 3), (2, 5, 3)]), st.booleans())
def test_cross_is_numpy_cross_bit_for_bit(seed, shape, broadcast_one):
    """orientation._cross against np.cross (the same products and differences, so the same bits), with one
    argument a single vector broadcast against many, tiny and huge values included."""
    from cinenerf_ns.planner.trajectory.orientation import _cross

    rng = np.random.default_rng(seed)
    a = rng.normal(size=shape) * 10.0 ** rng.integers(-150, 150, size=shape)
    b = rng.normal(size=(3,) if broadcast_one else shape)
    got, ref = _cross(a, b), np.cross(a, b)
    assert got.shape == ref.shape and np.array_equal(got, ref, equal_nan=True)
    assert np.array_equal(_cross(b, a), np.cross(b, a), equal_nan=True)


# ---------------------------------------------------------------- the compiled rotations (native/orientation.c)
def _native_calls(monkeypatch) -> list:
    """Record each status native/orientation.c returns (0: it wrote the rotations; else the Python path ran)."""
    from cinenerf_ns.planner import native
    from cinenerf_ns.planner.trajectory import orientation

    fn = native.look_at_c()
    if fn is None:
        pytest.skip(f"no compiled orientation kernel: {native.native_status().get('orientation')}")
    calls = []

    def counted(*a):
        calls.append(fn(*a))
        return calls[-1]

    monkeypatch.setattr(orientation, "look_at_c", lambda: counted)
    return calls


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 200), st.sampled_from(["z", "y", "random"]),
       st.sampled_from(["one", "per frame"]), st.sampled_from(["regular", "pole", "at target"]))
def test_native_rotations_are_the_numpy_ones(seed, T, up_kind, tgt_kind, case):
    """The compiled path gives look_at_rotations' numpy result, bit for bit on the CPU box (the header of
    native/orientation.c), to rounding elsewhere; paths with a frame at the target or inside the cone around up go to
    the numpy path whole (their frames depend on their neighbours)."""
    from cinenerf_ns.planner import native

    if native.look_at_c() is None:
        pytest.skip("no compiled orientation kernel")
    rng = np.random.default_rng(seed)
    up = {"z": np.array([0.0, 0, 1]), "y": np.array([0.0, 1, 0]), "random": rng.normal(size=3)}[up_kind]
    pos = np.cumsum(rng.normal(size=(T, 3)) * 0.05, axis=0)
    tgt = rng.normal(size=3) * 2 if tgt_kind == "one" else pos + rng.normal(size=(T, 3))
    k = int(rng.integers(T))
    if case == "pole":  # one frame straight above its target
        g = tgt if tgt.ndim == 1 else tgt[k]
        pos[k] = g + 0.7 * up / np.linalg.norm(up)
    elif case == "at target":
        pos[k] = tgt if tgt.ndim == 1 else tgt[k]
        if T == 1:  # nothing left to look from: the same error either way
            for backend in ("python", "auto"):
                with pytest.raises(InvalidInputError, match="coincides"):
                    look_at_rotations(pos, tgt, up, backend=backend)
            return
    ref = look_at_rotations(pos, tgt, up, backend="python")
    got = look_at_rotations(pos, tgt, up)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-14)
    check_frames(got)


def test_native_rotations_cover_regular_paths_and_hand_the_rest_to_numpy(monkeypatch):
    calls = _native_calls(monkeypatch)
    pos = np.array([[1.0, 0, 0], [1.0, 1, 0], [0.0, 1, 0.5]])
    look_at_rotations(pos, np.zeros(3))
    look_at_rotations(torch.as_tensor(pos), torch.zeros(3))  # torch in: the same compiled path
    assert calls == [0, 0]
    look_at_rotations(np.array([[0.0, 0, 1], [1.0, 0, 0]]), np.zeros(3))  # straight above: the cone
    look_at_rotations(np.array([[0.0, 0, 0], [1.0, 0, 0]]), np.zeros(3))  # at the target
    with pytest.raises(InvalidInputError, match="finite"):
        look_at_rotations(np.array([[np.nan, 0, 0]]), np.zeros(3))
    assert calls == [0, 0, 1, 1, 2]
    look_at_rotations(pos, np.zeros(3), backend="python")
    assert len(calls) == 5


def test_unknown_backend_is_refused():
    with pytest.raises(InvalidInputError, match="look-at rotations backend must be 'auto', 'native' or 'python'"):
        look_at_rotations(np.array([[1.0, 0, 0]]), np.zeros(3), backend="fast")


@pytest.mark.parametrize("backend", ["python", "native"])
@pytest.mark.parametrize("scale", [1e300, 1e-300, 5e-320])
def test_huge_or_tiny_up_is_the_same_direction(backend, scale):
    """up = (0, 1e300, 0) is +y (its norm once overflowed to inf: up became 0 and the camera rolled)."""
    from cinenerf_ns.planner.native import look_at_c

    if backend == "native" and look_at_c() is None:
        pytest.skip("the compiled kernel is not available here")
    pos = np.array([[0.0, 0.0, 2.0], [0.5, 0.1, 2.0]])
    want = look_at_rotations(pos, np.zeros(3), up=(0.0, 1.0, 0.0), backend=backend)
    got = look_at_rotations(pos, np.zeros(3), up=(0.0, scale, 0.0), backend=backend)
    np.testing.assert_allclose(got, want, atol=1e-12)
