import pytest
import torch
from _geom_helpers import random_scene
from hypothesis import example, given, settings, strategies as st

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.geometry.distance import point_ellipsoid_distance
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.spatial_index import GridIndex


def _brute_pairs(index, qlo, qhi):
    m = ((index.lo[None] <= qhi[:, None]) & (index.hi[None] >= qlo[:, None])).all(-1)
    return set(zip(*[t.tolist() for t in torch.nonzero(m, as_tuple=True)]))


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 300), cell=st.sampled_from([None, 0.03, 0.2, 5.0]),
       radius=st.floats(0.0, 0.5), huge=st.booleans())
def test_query_points_equals_brute_force(seed, n, cell, radius, huge):
    sc = random_scene(n, seed, rmin=0.005, rmax=0.1)
    if huge:  # a few huge ellipsoids must land in coarse levels, not blow up memory
        sc.radii[: max(1, n // 10)] *= 30
    idx = GridIndex.build(sc, cell_size=cell)
    g = torch.Generator().manual_seed(seed)
    pts = torch.rand(64, 3, generator=g, dtype=torch.float64) * 3 - 1.5
    pi, gi = idx.query_points(pts, radius)
    got = list(zip(pi.tolist(), gi.tolist()))
    assert len(got) == len(set(got)), "duplicate pairs"
    assert pi.tolist() == sorted(pi.tolist())
    assert set(got) == _brute_pairs(idx, pts - radius, pts + radius)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), tiny=st.sampled_from([1e-4, 1e-3]), radius=st.floats(0.5, 2.0))
@example(seed=229, tiny=1e-4, radius=1.0)
def test_query_points_scans_when_boxes_dwarf_the_cells(seed, tiny, radius):
    """A few tiny ellipsoids (cells of ~1e-3) and boxes 1-4 units wide: the grid lookup would walk millions of
    cells, so query_points scans instead; the pairs are the grid lookup's and the brute-force test's."""
    g = torch.Generator().manual_seed(seed)
    means = torch.rand(5, 3, generator=g, dtype=torch.float64) * 0.2
    # camera radius 0: the default one would pad every box to ~0.06 and make the cells that large (seed 229 then had
    # 36 cells per box, below the scan threshold, and failed); at most 20k cells keep the grid lookup below quick
    sc = EllipsoidScene(means, torch.eye(3, dtype=torch.float64).expand(5, 3, 3).clone(),
                        torch.full((5, 3), tiny, dtype=torch.float64), torch.ones(5, dtype=torch.float64), 0.0)
    idx = GridIndex.build(sc, max_cells=20_000)
    pts = torch.rand(20, 3, generator=g, dtype=torch.float64) * 0.8 - 0.3  # every box covers the whole grid
    scans = []
    real_scan = idx._scan_boxes
    idx._scan_boxes = lambda *a, **k: scans.append(1) or real_scan(*a, **k)  # a spy on this index only
    pi, gi = idx.query_points(pts, radius)
    assert scans, "the grid lookup was used for boxes that visit far more cells than Q x N tests"
    got = set(zip(pi.tolist(), gi.tolist()))
    assert got == _brute_pairs(idx, pts - radius, pts + radius)
    gq, gg = idx.query_boxes(pts - radius, pts + radius, method="grid")
    assert got == set(zip(gq.tolist(), gg.tolist()))
    assert pi.tolist() == sorted(pi.tolist())


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), radius=st.floats(0.0, 0.3))
def test_never_misses_an_ellipsoid_within_radius(seed, radius):
    sc = random_scene(150, seed, camera_radius=0.04)
    idx = GridIndex.build(sc)
    g = torch.Generator().manual_seed(seed + 1)
    pts = torch.rand(100, 3, generator=g, dtype=torch.float64) * 2.6 - 1.3
    d = point_ellipsoid_distance(pts, sc.means, sc.rotations, sc.radii)  # [P, N]
    need = set(zip(*[t.tolist() for t in torch.nonzero(d <= radius + sc.camera_radius, as_tuple=True)]))
    pi, gi = idx.query_points(pts, radius)
    assert need <= set(zip(pi.tolist(), gi.tolist()))


def test_query_box_and_huge_levels():
    sc = random_scene(500, 3, rmin=0.01, rmax=0.05)
    sc.radii[:5] = 50.0  # spans the whole scene many times
    idx = GridIndex.build(sc)
    st_ = idx.stats()
    assert len(st_["levels"]) >= 2
    assert sum(l["entries"] for l in st_["levels"]) < 500 * 27 + 5 * 27
    lo, hi = torch.tensor([-0.2, -0.2, -0.2]), torch.tensor([0.1, 0.3, 0.0])
    ids = idx.query_box(lo, hi)
    want = sorted(g for _, g in _brute_pairs(idx, lo.double()[None], hi.double()[None]))
    assert ids.tolist() == want and set(range(5)) <= set(ids.tolist())
    far = idx.query_box(torch.full((3,), 1e3), torch.full((3,), 1e3 + 1))
    assert far.numel() == 0


def test_pad_and_errors():
    sc = random_scene(20, 0, camera_radius=0.07)
    idx = GridIndex.build(sc)
    assert idx.pad == 0.07
    h = sc.half_extents()
    assert (idx.hi >= sc.means + h + 0.07).all() and (idx.lo <= sc.means - h - 0.07).all()
    with pytest.raises(InvalidInputError):
        idx.query_points(torch.tensor([[float("nan"), 0, 0]]), 0.1)
    with pytest.raises(InvalidInputError):
        idx.query_points(torch.zeros(2, 3), -1.0)
    with pytest.raises(InvalidInputError):
        GridIndex.build(sc, cell_size=0.0)
    pi, gi = idx.query_points(torch.zeros(0, 3), 0.1)
    assert pi.numel() == 0


def test_float32_scene_and_per_point_radius():
    sc = random_scene(200, 5).to(dtype=torch.float32)
    idx = GridIndex.build(sc)
    pts = torch.rand(50, 3) * 2 - 1
    rad = torch.rand(50) * 0.2
    pi, gi = idx.query_points(pts, rad)
    p64 = pts.double()
    assert set(zip(pi.tolist(), gi.tolist())) == _brute_pairs(idx, p64 - rad.double()[:, None],
                                                              p64 + rad.double()[:, None])


@pytest.mark.gpu
def test_cuda_matches_cpu():
    sc = random_scene(300, 1)
    idx = GridIndex.build(sc)
    idx_c = GridIndex.build(sc.to("cuda"))
    pts = torch.rand(100, 3, dtype=torch.float64) * 2 - 1
    a = idx.query_points(pts, 0.1)
    b = idx_c.query_points(pts.cuda(), 0.1)
    # same (point, gaussian) pairs; CUDA sorts are not stable, so compare them in a canonical order
    pa = sorted(zip(a[0].tolist(), a[1].tolist()))
    pb = sorted(zip(b[0].cpu().tolist(), b[1].cpu().tolist()))
    assert pa == pb


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 300), size=st.floats(0.0, 4.0), huge=st.booleans())
def test_query_box_scan_grid_and_auto_equal_brute_force(seed, n, size, huge):
    sc = random_scene(n, seed, rmin=0.005, rmax=0.1)
    if huge:
        sc.radii[: max(1, n // 10)] *= 30
    idx = GridIndex.build(sc)
    g = torch.Generator().manual_seed(seed)
    c = torch.rand(3, generator=g, dtype=torch.float64) * 3 - 1.5
    ext = torch.rand(3, generator=g, dtype=torch.float64) * size
    lo, hi = c - ext, c + ext
    want = sorted(gg for _, gg in _brute_pairs(idx, lo[None], hi[None]))
    for method in ("grid", "scan", "auto"):
        assert idx.query_box(lo, hi, method=method).tolist() == want
    with pytest.raises(InvalidInputError):
        idx.query_box(lo, hi, method="bogus")


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 300), size=st.floats(0.0, 3.0), q=st.integers(1, 9),
       huge=st.booleans())
def test_query_boxes_scan_grid_and_auto_equal_brute_force(seed, n, size, q, huge):
    sc = random_scene(n, seed, rmin=0.005, rmax=0.1)
    if huge:
        sc.radii[: max(1, n // 10)] *= 30
    idx = GridIndex.build(sc)
    g = torch.Generator().manual_seed(seed)
    c = torch.rand(q, 3, generator=g, dtype=torch.float64) * 3 - 1.5
    ext = torch.rand(q, 3, generator=g, dtype=torch.float64) * size
    lo, hi = c - ext, c + ext
    hi[0, 0] = lo[0, 0] - 0.01  # an inverted box meets nothing
    want = _brute_pairs(idx, lo, hi)
    want = {(a, b) for a, b in want if a != 0}
    for method in ("grid", "scan", "auto"):
        bq, bg = idx.query_boxes(lo, hi, method=method)
        got = list(zip(bq.tolist(), bg.tolist()))
        assert len(got) == len(set(got)) and bq.tolist() == sorted(bq.tolist())
        assert set(got) == want, method
    sq, sg = idx._scan_boxes(lo, hi, max_elems=max(1, n // 2))  # blocked over boxes: same pairs, same order
    assert (sq.tolist(), sg.tolist()) == tuple(t.tolist() for t in idx.query_boxes(lo, hi, method="scan"))
    with pytest.raises(InvalidInputError):
        idx.query_boxes(lo, hi, method="bogus")


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(0, 300), flat=st.booleans())
def test_morton_order_sorts_by_the_interleaved_bits(seed, n, flat):
    """morton_order against a plain bit-by-bit reference: a permutation, and the Z-order codes (x bit i -> 3 i,
    y -> 3 i + 1, z -> 3 i + 2 of the 21-bit quantised coordinates) never decrease along it."""
    import numpy as np

    from cinenerf_ns.planner.scene.spatial_index import morton_order

    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3)) * rng.uniform(0.01, 100.0)
    if flat and n:
        p[:, 2] = 1.5  # a degenerate axis
    perm = morton_order(p)
    assert perm.dtype == np.int64 and sorted(perm.tolist()) == list(range(n))
    if n == 0:
        return
    lo, hi = p.min(0), p.max(0)
    q = ((p - lo) / np.maximum(hi - lo, 1e-300) * float(2**21 - 1)).astype(np.int64)
    codes = [sum(((int(q[k, a]) >> i) & 1) << (3 * i + a) for i in range(21) for a in range(3)) for k in range(n)]
    ordered = [codes[k] for k in perm.tolist()]
    assert all(x <= y for x, y in zip(ordered, ordered[1:]))
