"""The compiled safe polytope (native/polytope.c) against float64 brute force and against the Python path.

Safety is checked against ALL ellipsoids of the scene (exact support test, else an exact SOCP distance), never
against the compiled code's own candidate gathering."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, assume, example, given, settings, strategies as st

from cinenerf_ns.planner.corridor.polytope import SeedNotFreeError, safe_polytope
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.native import safe_polytope_c
from cinenerf_ns.planner.scene.spatial_index import GridIndex

sys.path.insert(0, str(Path(__file__).parents[1]))
from _corridor_refs import clearance, make_scene, polytope_min_distance, random_rotations, random_scene  # noqa: E402

pytestmark = pytest.mark.skipif(safe_polytope_c() is None, reason="no C compiler: the compiled polytope is not built")
SETTINGS = dict(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _assert_safe(P, scene, seeds, box_lo, box_hi, box_rot=None):
    """Seeds inside, polytope inside its box, and every inflated ellipsoid of the scene outside (float64)."""
    A, b = P.to_numpy()
    assert (seeds @ A.T <= b + 1e-12).all()
    rot = np.eye(3) if box_rot is None else np.asarray(box_rot)
    assert np.allclose(A[:3], rot.T) and np.allclose(A[3:6], -rot.T)  # the box's own 6 faces come first
    assert np.allclose(b[:3], box_hi) and np.allclose(b[3:6], -np.asarray(box_lo))
    r = scene.camera_radius
    mu, R, a = (t.double().numpy() for t in (scene.means, scene.rotations, scene.radii))
    nb = np.einsum("cji,fj->cfi", R, A)  # [C, F, 3]
    gap = mu @ A.T - np.linalg.norm(a[:, None, :] * nb, axis=-1) - r  # [C, F] exact support function
    rest = np.flatnonzero(~(gap >= b).any(1))
    if rest.size:
        d = polytope_min_distance(A, b, scene.subset(torch.as_tensor(rest)))
        assert (d >= r - 1e-6).all(), (rest[d < r - 1e-6], d.min())


def _segment_blocked(seeds, scene) -> bool:
    """Exact: some point of the seed segment (or the point) is within the camera radius of an ellipsoid."""
    t = np.linspace(0.0, 1.0, 200)[:, None]
    pts = seeds[0] + t * (seeds[-1] - seeds[0])
    return bool((clearance(pts, scene) < 0).any())


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), n_seeds=st.sampled_from([1, 2]), oriented=st.booleans(),
       dtype=st.sampled_from([torch.float32, torch.float64]), cell=st.sampled_from([None, 0.04, 0.25]),
       pad=st.sampled_from([None, 0.0]), near=st.sampled_from([0.0, 0.5]), inside=st.booleans())
def test_native_polytope_is_safe(seed, n_seeds, oriented, dtype, cell, pad, near, inside):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, 300, amin=0.005, amax=0.12, camera_radius=0.03)
    big = make_scene(rng.uniform(-1, 1, (3, 3)), random_rotations(rng, 3), rng.uniform(0.3, 0.6, (3, 3)), 0.03)
    # three huge ones: a coarser index level
    scene = make_scene(torch.cat([scene.means, big.means]), torch.cat([scene.rotations, big.rotations]),
                       torch.cat([scene.radii, big.radii]), scene.camera_radius)
    scene = scene.to(dtype=dtype)
    idx = GridIndex.build(scene, cell_size=cell, pad=pad)  # pad 0: the query grows by e = r (planes shifted)
    seeds = rng.uniform(-0.6, 0.6, (n_seeds, 3))
    if n_seeds == 2:
        seeds[1] = seeds[0] + rng.normal(size=3) * 0.15
    rot = None
    if oriented:
        rot = random_rotations(rng, 1)[0]
        sb = seeds @ rot
        lo, hi = sb.min(0) - rng.uniform(0.05, 0.3, 3), sb.max(0) + rng.uniform(0.05, 0.3, 3)
    else:
        lo, hi = seeds.min(0) - rng.uniform(0.05, 0.3, 3), seeds.max(0) + rng.uniform(0.05, 0.3, 3)
    kw = dict(box_rotation=None if rot is None else torch.as_tensor(rot), two_pass=near > 0, near_fraction=near or 0.5,
              require_seed_inside=inside)
    blocked = _segment_blocked(seeds, scene.to(dtype=torch.float64))
    try:
        P = safe_polytope(seeds, scene, idx, lo, hi, backend="native", **kw)
    except SeedNotFreeError as e:
        assert inside
        assert e.min_slack < 0 and e.ellipsoid_ids is not None and e.ellipsoid_ids.numel() > 0
        # the Python path agrees that no polytope of these planes holds the seeds
        with pytest.raises(SeedNotFreeError):
            safe_polytope(seeds, scene, idx, lo, hi, backend="python", **kw)
        return
    assert not (inside and blocked)  # a seed within the camera radius of an ellipsoid can never be inside
    if not inside:
        A, b = P.to_numpy()
        keep = (seeds @ A.T <= b + 1e-12).all()
        assume(keep)  # without the requirement the planes may exclude the seeds; the safety check needs them inside
    _assert_safe(P, scene.to(dtype=torch.float64), seeds, lo, hi, rot)


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), dtype=st.sampled_from([torch.float32, torch.float64]),
       normal=st.sampled_from(["auto", "prop2"]), near=st.sampled_from([0.0, 0.5]),
       empty=st.sampled_from([None, 0.0, 0.05]), margin=st.sampled_from([1e-6, 0.01]), with_index=st.booleans(),
       n=st.sampled_from([300, 1500]), n_seeds=st.sampled_from([1, 2]), outside=st.booleans())
def test_aabb_polytope_is_safe_polytope(seed, dtype, normal, near, empty, margin, with_index, n, n_seeds, outside):
    """aabb_polytope (the compiled call without safe_polytope's general input handling: the corridor's segments, the
    goal's point) gives safe_polytope's polytope bit for bit, its SeedNotFreeError (same ellipsoids, same slack), its
    explicit empty polytope and its input errors (a seed outside the box); without a grid index both take the Python
    path. 1500 ellipsoids: most seeds are not free, or their polytope is proven empty."""
    from cinenerf_ns.planner.corridor.polytope import aabb_polytope

    rng = np.random.default_rng(seed)
    scene = random_scene(rng, n, amin=0.005, amax=0.12, camera_radius=0.03).to(dtype=dtype)
    idx = GridIndex.build(scene, cell_size=0.1) if with_index else None
    seeds = rng.uniform(-0.6, 0.6, (1, 3))
    if n_seeds == 2:
        seeds = np.concatenate([seeds, seeds + rng.normal(size=(1, 3)) * 0.15])
    box_margin = rng.uniform(0.05, 0.3)
    lo, hi = seeds.min(0) - box_margin, seeds.max(0) + box_margin
    if outside:  # the box misses the last seed: an error when seeds must be inside, else allowed
        lo = lo + np.array([0.0, 0.0, seeds[-1, 2] - lo[2] + 0.01])
    kw = dict(normal=normal, two_pass=near > 0, near_fraction=near or 0.5, margin=margin)
    if empty is not None:
        kw.update(require_seed_inside=False, stop_when_empty=empty)
    got, ref = [], []
    for fn, out in ((lambda: aabb_polytope(seeds, scene, idx, lo, hi, **kw), got),
                    (lambda: safe_polytope(seeds, scene, idx, lo, hi, **kw), ref)):
        try:
            out.append(fn())
        except (SeedNotFreeError, InvalidInputError) as e:
            out.append(e)
    g, r = got[0], ref[0]
    assert type(g) is type(r)
    if isinstance(r, InvalidInputError):
        assert str(g) == str(r)
        return
    if isinstance(r, SeedNotFreeError):
        assert str(g) == str(r) and g.min_slack == r.min_slack and torch.equal(g.ellipsoid_ids, r.ellipsoid_ids)
        return
    for name in ("A", "b", "seed", "ellipsoid_ids"):
        assert torch.equal(getattr(g, name), getattr(r, name)), name
    assert g.proven_empty == r.proven_empty


def test_a_full_output_buffer_is_retried_with_more_room(monkeypatch):
    """A polytope with more planes than the first output buffer holds (FIRST_CAP made tiny) is built again with room
    for all, and equals the one built at once; a SeedNotFreeError names the same ellipsoids either way."""
    from cinenerf_ns.planner.corridor import polytope_native

    rng = np.random.default_rng(3)
    scene = random_scene(rng, 400, amin=0.005, amax=0.05, camera_radius=0.02)
    idx = GridIndex.build(scene, cell_size=0.1)
    free, blocked = None, None
    for _ in range(200):  # a free point seed with many planes, and a segment seed that is not free
        p = rng.uniform(-0.5, 0.5, (1, 3))
        try:
            P = safe_polytope(p, scene, idx, p[0] - 0.4, p[0] + 0.4)
            if free is None and P.num_faces > 10:
                free = (p, P)
        except SeedNotFreeError as e:
            if blocked is None:
                blocked = (p, e)
        if free is not None and blocked is not None:
            break
    assert free is not None and blocked is not None
    monkeypatch.setattr(polytope_native, "FIRST_CAP", 1)
    p, ref = free
    got = safe_polytope(p, scene, idx, p[0] - 0.4, p[0] + 0.4)
    assert torch.equal(got.A, ref.A) and torch.equal(got.b, ref.b) and torch.equal(got.ellipsoid_ids, ref.ellipsoid_ids)
    p, ref_e = blocked
    with pytest.raises(SeedNotFreeError) as e:
        safe_polytope(p, scene, idx, p[0] - 0.4, p[0] + 0.4)
    assert torch.equal(e.value.ellipsoid_ids, ref_e.ellipsoid_ids) and e.value.min_slack == ref_e.min_slack


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), n_seeds=st.sampled_from([1, 2]), normal=st.sampled_from(
    ["auto", "prop2", "mahalanobis", "closest"]))
def test_native_planes_equal_python_planes_when_each_ellipsoid_needs_its_own(seed, n_seeds, normal):
    """Far-apart ellipsoids around the seed: no plane cuts another ellipsoid off, so both paths keep one plane per
    ellipsoid, and the compiled normal rules (Prop. 2's s*, Mahalanobis, closest point, segment retries) must give
    the Python path's planes."""
    rng = np.random.default_rng(seed)
    k = 4
    dirs = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]], dtype=np.float64)
    means = dirs * rng.uniform(0.25, 0.4, (k, 1)) + rng.normal(size=(k, 3)) * 0.02
    scene = make_scene(means, random_rotations(rng, k), rng.uniform(0.02, 0.08, (k, 3)), 0.03)
    idx = GridIndex.build(scene)
    seeds = rng.normal(size=(n_seeds, 3)) * 0.03
    lo, hi = np.full(3, -0.6), np.full(3, 0.6)
    try:
        Pn = safe_polytope(seeds, scene, idx, lo, hi, normal=normal, backend="native")
        Pp = safe_polytope(seeds, scene, idx, lo, hi, normal=normal, backend="python")
    except SeedNotFreeError:
        assume(False)
    assume(Pp.num_faces == 6 + k)
    assert Pn.num_faces == Pp.num_faces
    order_n = torch.argsort(Pn.ellipsoid_ids).numpy()
    order_p = torch.argsort(Pp.ellipsoid_ids).numpy()
    assert torch.equal(Pn.ellipsoid_ids[order_n], Pp.ellipsoid_ids[order_p])
    An, bn = Pn.to_numpy()
    Ap, bp = Pp.to_numpy()
    # s* is found by golden section to ~1e-3 in both; the same arithmetic gives planes equal to rounding
    np.testing.assert_allclose(An[6:][order_n], Ap[6:][order_p], atol=1e-9)
    np.testing.assert_allclose(bn[6:][order_n], bp[6:][order_p], atol=1e-9)


def test_native_polytope_on_cell_aligned_boxes():
    """AABB faces exactly on index cell faces (means and sizes on the cell lattice): the dedupe of the compiled
    gather must keep one copy of each, so the polytope stays safe."""
    cell = 0.1
    rng = np.random.default_rng(3)
    g = np.arange(-5, 6) * cell
    means = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    means = means[rng.random(len(means)) < 0.3]
    n = len(means)
    scene = make_scene(means, np.broadcast_to(np.eye(3), (n, 3, 3)).copy(), np.full((n, 3), 0.02), 0.03)
    idx = GridIndex.build(scene, cell_size=cell)
    for s in range(20):
        p = rng.uniform(-0.45, 0.45, 3)
        if _segment_blocked(p[None], scene):
            continue
        lo, hi = p - 0.3, p + 0.3
        P = safe_polytope(p[None], scene, idx, lo, hi, backend="native")
        _assert_safe(P, scene, p[None], lo, hi)


def test_native_backend_refusals():
    rng = np.random.default_rng(0)
    scene = random_scene(rng, 50, amin=0.01, amax=0.05, camera_radius=0.03)
    p = np.zeros((1, 3))
    with pytest.raises(InvalidInputError, match="backend"):
        safe_polytope(p, scene, GridIndex.build(scene), p[0] - 0.2, p[0] + 0.2, backend="fast")
    with pytest.raises(RuntimeError, match="does not apply"):  # no index: only the Python path scans all
        safe_polytope(p, scene, None, p[0] - 0.2, p[0] + 0.2, backend="native")
    with pytest.raises(RuntimeError, match="does not apply"):  # three seeds
        safe_polytope(np.zeros((3, 3)), scene, GridIndex.build(scene), p[0] - 0.2, p[0] + 0.2, backend="native")


def test_native_segment_tangent_to_elongated_ellipsoid():
    """polytope.py's Mahalanobis-normal case through the compiled path: the whole segment along a long thin
    ellipsoid stays inside."""
    scene = make_scene([[0.0, 0, 0]], np.eye(3)[None], [[0.5, 0.02, 0.02]], 0.03)
    seg = np.array([[-0.45, 0.07, 0.0], [0.45, 0.07, 0.0]])
    P = safe_polytope(seg, scene, GridIndex.build(scene), seg.min(0) - 0.2, seg.max(0) + 0.2, backend="native")
    assert bool(P.contains(seg).all())



@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), dtype=st.sampled_from([torch.float32, torch.float64]),
       cell=st.sampled_from([None, 0.04, 0.25]), pad=st.sampled_from([None, 0.0]), per_point=st.booleans())
def test_native_points_collide_is_conservative_and_matches_python(seed, dtype, cell, pad, per_point):
    """cn_points_collide: never "free" when the exact clearance (float64 brute force) is negative, and the same
    answer as the Python points_collide (same pair rule) away from the 1e-6 decision margin."""
    from cinenerf_ns.planner.geometry.collision import points_collide

    rng = np.random.default_rng(seed)
    scene = random_scene(rng, 200, amin=0.005, amax=0.12, camera_radius=0.03).to(dtype=dtype)
    idx = GridIndex.build(scene, cell_size=cell, pad=pad)
    pts = rng.uniform(-1.1, 1.1, (400, 3))
    rad = torch.as_tensor(rng.uniform(0.0, 0.08, len(pts))) if per_point else None
    hit_n = points_collide(torch.as_tensor(pts), scene, idx, radius=rad, backend="native").numpy()
    hit_p = points_collide(torch.as_tensor(pts), scene, idx, radius=rad, backend="python").numpy()
    s64 = scene.to(dtype=torch.float64)
    from _corridor_refs import min_distance

    r = (np.full(len(pts), s64.camera_radius) if rad is None else rad.numpy())
    exact = min_distance(pts, s64) - r  # [P]
    assert hit_n[exact < 0].all()  # conservative
    clear = np.abs(exact) > 1e-4
    assert (hit_n[clear] == hit_p[clear]).all()
    assert (~hit_n).sum() > 0 and hit_n.sum() > 0  # both answers occur in these scenes


def test_native_points_collide_refusals():
    from cinenerf_ns.planner.geometry.collision import points_collide

    rng = np.random.default_rng(0)
    scene = random_scene(rng, 20, amin=0.01, amax=0.05, camera_radius=0.03)
    with pytest.raises(InvalidInputError, match="backend"):
        points_collide(torch.zeros(1, 3), scene, GridIndex.build(scene), backend="fast")
    with pytest.raises(RuntimeError, match="does not apply"):
        points_collide(torch.zeros(1, 3), scene, None, backend="native")


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), dtype=st.sampled_from([torch.float32, torch.float64]),
       per_point=st.booleans(), with_index=st.booleans())
@example(seed=4539, dtype=torch.float32, per_point=False, with_index=False)  # no points, no index (was a ValueError)
def test_points_collide_arrays_is_points_collide(seed, dtype, per_point, with_index):
    """collision.points_collide_arrays (numpy in and out; the compiled test on the arrays directly, or points_collide
    without a GridIndex) == points_collide, bit for bit."""
    from cinenerf_ns.planner.geometry.collision import points_collide, points_collide_arrays

    rng = np.random.default_rng(seed)
    scene = random_scene(rng, 200, amin=0.005, amax=0.12, camera_radius=0.03).to(dtype=dtype)
    idx = GridIndex.build(scene) if with_index else None
    pts = rng.uniform(-1.1, 1.1, (int(rng.integers(0, 300)), 3))
    rad = rng.uniform(0.0, 0.08, len(pts)) if per_point else 0.05
    got = points_collide_arrays(pts, scene, idx, rad)
    want = points_collide(torch.as_tensor(pts), scene, idx, radius=torch.as_tensor(rad)).numpy()
    assert isinstance(got, np.ndarray) and got.dtype == bool and np.array_equal(got, want)


def test_points_collide_arrays_refusals():
    from cinenerf_ns.planner.geometry.collision import points_collide_arrays

    rng = np.random.default_rng(0)
    scene = random_scene(rng, 20, amin=0.01, amax=0.05, camera_radius=0.03)
    idx = GridIndex.build(scene)
    with pytest.raises(InvalidInputError, match="NaN"):
        points_collide_arrays(np.array([[0.0, np.nan, 0.0]]), scene, idx, 0.1)
    with pytest.raises(InvalidInputError, match=r"\[P, 3\]"):
        points_collide_arrays(np.zeros((2, 2)), scene, idx, 0.1)
    with pytest.raises(InvalidInputError, match="radius"):
        points_collide_arrays(np.zeros((2, 3)), scene, idx, np.ones(3))


@settings(**SETTINGS)
@given(seed=st.integers(0, 2**31 - 1), cell=st.sampled_from([None, 0.04, 0.1, 0.25]), pad=st.sampled_from([None, 0.0]))
def test_home_bits_say_whether_the_previous_cell_lists_the_ellipsoid(seed, cell, pad):
    """native_scene's home bits against their definition, by brute force over the index's CSR lists: bit i of an
    entry (cell c, ellipsoid g) is set exactly when the level does not list g in the cell c - e_i."""
    from cinenerf_ns.planner.geometry.native_scene import native_arrays

    rng = np.random.default_rng(seed)
    scene = random_scene(rng, 120, amin=0.005, amax=0.2, camera_radius=0.03)
    idx = GridIndex.build(scene, cell_size=cell, pad=pad)
    arr = native_arrays(scene, idx)
    for L, lv in enumerate(idx.levels):
        dims = lv.dims.tolist()
        off = lv.offsets.long().numpy()
        ids, homes = arr["ids_t"][L].numpy().astype(np.int64), arr["homes_t"][L].numpy()
        lin = np.repeat(np.arange(len(off) - 1), np.diff(off))  # each entry's cell (linear, C order)
        c = np.stack(np.unravel_index(lin, dims), -1)  # [E, 3]
        n_ids = int(ids.max()) + 1 if ids.size else 1
        listed = lin * n_ids + ids  # the (cell, ellipsoid) pairs the level lists, as one integer each
        for i in range(3):
            prev = c.copy()
            prev[:, i] -= 1
            has = prev[:, i] >= 0  # a previous cell in the grid (none before cell 0: it lists nothing)
            in_prev = np.zeros(len(lin), dtype=bool)
            in_prev[has] = np.isin(np.ravel_multi_index(tuple(prev[has].T), dims) * n_ids + ids[has], listed)
            bad = np.flatnonzero(((homes >> i & 1) != 0) != ~in_prev)
            assert bad.size == 0, (L, tuple(c[bad[0]]), int(ids[bad[0]]), i)


_EDGE = st.sampled_from([0.0, -0.0, 1.0, -1.0, 1e-300, np.nan, np.inf, -np.inf])


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(st.floats(-2, 2), _EDGE), min_size=12, max_size=12), st.sampled_from([1, 2]), st.booleans(),
       st.integers(0, 3))
def test_box_fits_matches_its_numpy_expression(vals, n_seeds, inside, tie):
    """aabb_polytope's fast-path test on Python floats (polytope._box_fits) decides as the numpy expression it replaced
    (NaN, infinities, empty boxes, seeds on and outside the faces); other shapes and types take the general path."""
    from cinenerf_ns.planner.corridor.polytope import _box_fits

    v = np.array(vals)
    seeds, lo, hi = v[:3 * n_seeds].reshape(n_seeds, 3), v[6:9].copy(), v[9:12].copy()
    if tie == 1:  # a seed on the faces
        lo[0], hi[1] = seeds[0, 0], seeds[-1, 1]
    with np.errstate(invalid="ignore"):
        ref = bool(np.isfinite(seeds).all() and np.isfinite(lo).all() and np.isfinite(hi).all() and (hi > lo).all()
                   and (not inside or ((seeds >= lo).all() and (seeds <= hi).all())))
    assert _box_fits(seeds, lo, hi, inside) is ref
    assert _box_fits(seeds, lo.tolist(), hi, inside) is False and _box_fits(seeds, lo[None], hi[None], inside) is False
