"""The compiled occupancy rasterisation (native/occupancy.c) is build_occupancy_reference's torch rasterisation bit for
bit: the same occupied voxels, lo and voxel size, over random scenes and on the bundled room; and the reference runs
where the compiled one does not load, does not apply or hands the build back."""
from __future__ import annotations

import math

import pytest
import torch
from hypothesis import HealthCheck, example, given, settings, strategies as st

from cinenerf_ns.planner import native
from cinenerf_ns.planner.scene import occupancy
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene, quat_wxyz_to_rotmat
from cinenerf_ns.planner.scene.occupancy import (
    OccupancyGrid,
    build_occupancy,
    build_occupancy_reference,
    compiled_applies,
)

needs_native = pytest.mark.skipif(native.occupancy_c() is None,
                                  reason=f"no compiled occupancy: {native.native_status().get('occupancy')}")


def _same(a: OccupancyGrid, b: OccupancyGrid) -> None:
    assert torch.equal(a.occupied, b.occupied), f"{int((a.occupied != b.occupied).sum())} voxels differ"
    assert a.occupied.dtype == b.occupied.dtype == torch.bool and a.shape == b.shape
    assert torch.equal(a.lo, b.lo) and a.lo.dtype == b.lo.dtype and a.voxel_size == b.voxel_size


def _scene(seed: int, n: int, shape: str, radius: float, dtype) -> EllipsoidScene:
    """n random ellipsoids in [-1, 1]^3: round, flat (one axis 1e-4 of the others) or elongated (one axis up to 40x)."""
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g, dtype=torch.float64) * 2 - 1)
    rot = quat_wxyz_to_rotmat(torch.randn(n, 4, generator=g, dtype=torch.float64))
    radii = 0.01 + 0.25 * torch.rand(n, 3, generator=g, dtype=torch.float64)
    if shape == "flat":
        radii[:, 2] = 1e-4 * radii[:, 0]
    elif shape == "elongated":
        radii[:, 0] *= 1 + 39 * torch.rand(n, generator=g, dtype=torch.float64)
    elif shape == "axis-aligned":  # exact zeros in the rotations: signed zeros in the products
        rot = torch.eye(3, dtype=torch.float64).expand(n, 3, 3).clone()
    return EllipsoidScene(means=means.to(dtype), rotations=rot.to(dtype), radii=radii.to(dtype),
                          opacities=torch.ones(n, dtype=dtype), camera_radius=radius)


@needs_native
@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 30),
       shape=st.sampled_from(["round", "flat", "elongated", "axis-aligned"]),
       radius=st.sampled_from([0.0, 0.013, 0.05]) | st.floats(0.0, 0.2), f32=st.booleans(),
       res=st.integers(1, 26), n_s=st.sampled_from([3, 3, 3, 1, 2, 4, 5, 9, 17]),
       box=st.none() | st.tuples(st.lists(st.floats(-1.6, 1.0), min_size=3, max_size=3),
                                 st.lists(st.floats(0.05, 2.5), min_size=3, max_size=3)),
       max_columns=st.sampled_from([2_000_000, 1, 7, 100]))
@example(seed=0, n=1, shape="round", radius=0.0, f32=False, res=1, n_s=3, box=None, max_columns=2_000_000)
@example(seed=5, n=20, shape="flat", radius=0.0, f32=True, res=13, n_s=3, box=([0.9, -1.6, 0.2], [0.05, 2.5, 0.07]),
         max_columns=1)
def test_compiled_is_the_reference(seed, n, shape, radius, f32, res, n_s, box, max_columns):
    """Random scenes (round / flat / elongated / axis-aligned ellipsoids, camera radius 0 or not, float32 or float64),
    small and odd grids (1 voxel up; boxes of any proportions, partly or wholly away from the ellipsoids), 1 to 17 s
    samples (past 3 the compiled build takes torch's powers), the reference in chunks down to 1 column."""
    sc = _scene(seed, n, shape, radius, torch.float32 if f32 else torch.float64)
    bounds = None if box is None else (torch.tensor(box[0], dtype=torch.float64),
                                       torch.tensor(box[0], dtype=torch.float64) + torch.tensor(box[1]).double())
    assert compiled_applies(sc, n_s)
    got = build_occupancy(sc, resolution=res, bounds=bounds, n_s=n_s, max_columns=max_columns, backend="native")
    ref = build_occupancy_reference(sc, resolution=res, bounds=bounds, n_s=n_s, max_columns=max_columns)
    _same(got, ref)
    # the compiled rasterisation itself made it (it did not hand the build back to the reference)
    lo, voxel, dims = occupancy._grid_geometry(sc, res, bounds, None)
    if not occupancy._one_covers_the_box(sc, lo, lo + dims.double() * voxel):  # (then no rasterisation at all)
        assert torch.equal(occupancy._rasterise_compiled(native.occupancy_c(), sc, lo, voxel, dims, n_s,
                                                         max_columns), ref.occupied)
    _same(got, build_occupancy(sc, resolution=res, bounds=bounds, n_s=n_s))  # "auto" takes the compiled build


def _terms_equal(sc: EllipsoidScene, res: int, bounds, n_s: int) -> None:
    """native/occupancy.c's intermediate values are the reference's bit for bit: footprints, the float64 matrices and
    their float32 voxel-unit copies, the centres, and each column's z-interval (a 1-ulp difference seldom moves a
    voxel: the grids alone would hardly see it)."""
    import numpy as np

    footprints_c, discs_c, mark_c, _ = native.occupancy_c()
    lo, voxel, dims = occupancy._grid_geometry(sc, res, bounds, None)
    X, Y, Z = (int(d) for d in dims)
    rho = sc.camera_radius + 0.5 * math.sqrt(3.0) * voxel
    t = torch.linspace(0, 1, n_s, dtype=torch.float64)
    span, i_lo, ncol = occupancy._footprints(sc, lo, voxel, dims, rho)
    n, cols, f32 = len(sc), int(ncol.sum()), int(sc.means.dtype == torch.float32)
    means, rot, radii, ext = (np.ascontiguousarray(a.numpy()) for a in
                              (sc.means, sc.rotations, sc.radii, sc.half_extents()))
    lo_np, t_np = lo.numpy().copy(), t.numpy().copy()
    ilo_c, span_c = np.zeros((n, 3), np.int64), np.zeros((n, 2), np.int64)
    assert footprints_c(means.ctypes.data, ext.ctypes.data, f32, n, lo_np.ctypes.data, voxel, X, Y, Z, rho,
                        ilo_c.ctypes.data, span_c.ctypes.data) == 0
    assert np.array_equal(ilo_c, i_lo.numpy()) and np.array_equal(span_c, span.numpy())
    pw = None
    if n_s > occupancy._LIBM_POW_S:
        amin, amax = sc.radii.double().min(-1).values, sc.radii.double().max(-1).values
        pw = np.ascontiguousarray(((amax / amin)[:, None] ** t[None]).numpy())
    out = dict(mc=np.zeros((n, n_s, 6), np.float32), m6=np.zeros((n, n_s, 6)), mu=np.zeros((n, 3)),
               disc=np.zeros(max(cols * n_s, 1), np.float32))
    k = discs_c(means.ctypes.data, rot.ctypes.data, radii.ctypes.data, f32, 0, n, ilo_c.ctypes.data,
                span_c.ctypes.data, lo_np.ctypes.data, voxel, rho, t_np.ctypes.data, n_s,
                None if pw is None else pw.ctypes.data, 1 + occupancy._MARGIN,
                *[out[key].ctypes.data for key in ("mc", "m6", "mu", "disc")], out["disc"].size)
    assert k >= 0
    has = (ncol > 0).numpy()
    m6, mc, mu_v = occupancy._coefficients_reference(sc, 0, n, lo, voxel, rho, t)
    for name, ref in (("m6", m6), ("mc", mc), ("mu", mu_v)):
        assert np.array_equal(out[name][has].view(np.uint8), ref.numpy()[has].view(np.uint8)), name  # signed zeros too
    sq = torch.sqrt(torch.from_numpy(out["disc"][:k]).clamp_min(0)).numpy()
    z = dict(z0=np.zeros(max(cols, 1), np.float32), z1=np.zeros(max(cols, 1), np.float32),
             ok=np.zeros(max(cols, 1), np.uint8))
    assert mark_c(0, n, ilo_c.ctypes.data, span_c.ctypes.data, out["mc"].ctypes.data, out["mu"].ctypes.data, n_s,
                  sq.ctypes.data, k, Y, Z, None, *[z[key].ctypes.data for key in ("z0", "z1", "ok")]) == 0
    ref_cols = occupancy._column_roots_reference(sc, 0, n, span, i_lo, lo, voxel, rho, t)
    if ref_cols is None:
        assert cols == 0
        return
    ok = ref_cols[5].numpy()
    assert np.array_equal(z["ok"][:cols].astype(bool), ok)
    for name, ref in (("z0", ref_cols[3]), ("z1", ref_cols[4])):
        assert np.array_equal(z[name][:cols][ok], ref.numpy()[ok]), name


@needs_native
@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 30),
       shape=st.sampled_from(["round", "flat", "elongated", "axis-aligned"]),
       radius=st.sampled_from([0.0, 0.05]) | st.floats(0.0, 0.2), f32=st.booleans(), res=st.integers(1, 26),
       n_s=st.sampled_from([3, 3, 1, 2, 5, 17]), boxed=st.booleans())
def test_compiled_terms_are_the_references(seed, n, shape, radius, f32, res, n_s, boxed):
    sc = _scene(seed, n, shape, radius, torch.float32 if f32 else torch.float64)
    bounds = (torch.tensor([-0.7, -0.2, -1.1], dtype=torch.float64), torch.tensor([0.5, 1.3, 0.2], dtype=torch.float64))
    _terms_equal(sc, res, bounds if boxed else None, n_s)


@needs_native
def test_bundled_room_at_the_planners_resolution():
    """The demo room's float32 ellipsoids over the planning region cinesplat-plan / make demo grid it in, at the
    planner's default resolution: the same 96 x 85 x 54 grid. Every 8th of the room's ~400k ellipsoids: the room's own
    values and grid, at an eighth of the reference's cost (~8 s of CPU for the whole room on the 2-core box)."""
    import numpy as np

    from cinenerf_ns.method.checkpoint import load_compact
    from cinenerf_ns.planner.scene import planning_region
    from cinenerf_ns.planner.scene.scene_config import SceneConfig
    from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig
    from cinenerf_ns.scenes import DEMO_SCENE

    if not DEMO_SCENE.exists():
        pytest.skip("the bundled demo scene is missing")
    st_ = load_compact(DEMO_SCENE, device="cpu")
    with pytest.warns(UserWarning, match="splat repair"):
        sc = EllipsoidScene.from_params(st_.params, SceneConfig.with_margin(), device="cpu")
    region = tuple(np.asarray(v, dtype=np.float64) for v in st_.info["start_region"])
    pl = Planner(sc, PlannerConfig(start_region=region))
    lo, hi = pl.planning_bounds()
    res = planning_region.grid_resolution_for(pl.config, float(sc.camera_radius), lo.numpy(), hi.numpy())
    sc = sc.subset(torch.arange(0, len(sc), 8))
    got = build_occupancy(sc, None, res, bounds=(lo, hi), backend="native")
    assert got.shape == (96, 85, 54) and sc.means.dtype == torch.float32
    _same(got, build_occupancy_reference(sc, None, res, bounds=(lo, hi)))
    _terms_equal(sc, res, (lo, hi), 3)


@needs_native
def test_edge_scenes_are_the_reference():
    """Zero and huge semi-axes (NaN and overflowing float32 roots, footprints out of int64's reach: the compiled build
    hands those back to the reference), a scene with no ellipsoid in the grid, one that covers it."""
    base = _scene(3, 12, "round", 0.02, torch.float64)
    cases = {}
    zero = _scene(3, 12, "round", 0.02, torch.float64)
    zero.radii[0] = 0.0
    zero.radii[1, 1] = 0.0
    cases["zero semi-axes"] = zero
    huge = _scene(3, 12, "round", 0.02, torch.float32)
    huge.radii[2] = torch.tensor([1e-3, 1e20, 1e20])
    cases["huge flat"] = huge
    cases["outside"] = base
    cases["covering"] = _scene(3, 1, "round", 0.0, torch.float64)
    cases["covering"].radii.fill_(50.0)
    box = (torch.full((3,), 5.0, dtype=torch.float64), torch.full((3,), 6.0, dtype=torch.float64))
    unit = (torch.full((3,), -1.2, dtype=torch.float64), torch.full((3,), 1.2, dtype=torch.float64))
    for name, sc in cases.items():
        bounds = {"outside": box, "huge flat": unit}.get(name)
        got = build_occupancy(sc, resolution=17, bounds=bounds, backend="native")
        _same(got, build_occupancy_reference(sc, resolution=17, bounds=bounds))
    # the huge one is handed back (its footprint is ~1e22 voxels away): None from the compiled rasterisation
    lo, voxel, dims = occupancy._grid_geometry(huge, 17, unit, None)
    assert occupancy._rasterise_compiled(native.occupancy_c(), huge, lo, voxel, dims, 3, 2_000_000) is None
    assert not build_occupancy(cases["outside"], resolution=17, bounds=box).occupied.any()


def test_what_the_compiled_build_takes():
    sc = _scene(1, 5, "round", 0.02, torch.float64)
    assert compiled_applies(sc, 3) and compiled_applies(sc, 64) and not compiled_applies(sc, 65)
    assert not compiled_applies(sc, 0)
    half = EllipsoidScene(sc.means.half(), sc.rotations.half(), sc.radii.half(), sc.opacities.half(), 0.02)
    assert not compiled_applies(half, 3)
    mixed = EllipsoidScene(sc.means.float(), sc.rotations, sc.radii, sc.opacities, 0.02)
    assert not compiled_applies(mixed, 3)
    _same(build_occupancy(half, resolution=9), build_occupancy_reference(half, resolution=9))
    _same(build_occupancy(mixed, resolution=9), build_occupancy_reference(mixed, resolution=9))
    with pytest.raises(RuntimeError, match="does not apply"):
        build_occupancy(half, resolution=9, backend="native")
    with pytest.raises(Exception, match="backend"):
        build_occupancy(sc, resolution=9, backend="fast")
    if torch.cuda.is_available():
        _same(build_occupancy(sc.to("cuda"), resolution=9).to("cpu"),
              build_occupancy_reference(sc.to("cuda"), resolution=9).to("cpu"))


def _fresh_loader(monkeypatch, tmp_path, **env):
    """This process's native loader as a new process sees it (nothing loaded yet), with ``env`` set and the compile
    cache in tmp_path: the loader reads both when it loads a library."""
    for name in ("_LIBS", "_STATUS", "_FUNCS"):
        monkeypatch.setattr(native, name, {})
    monkeypatch.setenv("CINENERF_CACHE", str(tmp_path))
    for k, v in env.items():
        monkeypatch.setenv(k, v)


def _probe() -> list:
    g = torch.Generator().manual_seed(0)
    n = 30
    sc = EllipsoidScene(torch.rand(n, 3, generator=g) * 2 - 1, torch.eye(3).expand(n, 3, 3).clone(),
                        0.02 + 0.2 * torch.rand(n, 3, generator=g), torch.ones(n), 0.03)
    a, b = build_occupancy(sc, resolution=21), build_occupancy_reference(sc, resolution=21)
    return [torch.equal(a.occupied, b.occupied), int(a.occupied.sum()) > 0, native.occupancy_c() is None,
            native.native_status().get("occupancy")]


def test_turned_off_falls_back_to_the_reference(monkeypatch, tmp_path):
    _fresh_loader(monkeypatch, tmp_path, CINENERF_NATIVE_OFF="occupancy")
    assert _probe() == [True, True, True, "turned off (CINENERF_NATIVE_OFF)"]
    assert not any(tmp_path.iterdir())  # nothing was compiled


def test_broken_compiler_falls_back_to_the_reference(monkeypatch, tmp_path):
    _fresh_loader(monkeypatch, tmp_path, CC="/bin/false")
    out = _probe()
    assert out[:3] == [True, True, True] and out[3].startswith("compiling occupancy.c failed")


@needs_native
def test_compiled_by_default(monkeypatch, tmp_path):
    _fresh_loader(monkeypatch, tmp_path)
    out = _probe()
    assert out[:3] == [True, True, False] and out[3].startswith("compiled: ")
    assert [p.name.split("-")[0] for p in tmp_path.iterdir()] == ["occupancy"]