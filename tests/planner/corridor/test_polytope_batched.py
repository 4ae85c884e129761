"""Batched safe polytopes (cinenerf_ns/planner/corridor/polytope_batched.py) against float64 exact references and
the host path (polytope.safe_polytope)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings, strategies as st
from scipy.spatial import HalfspaceIntersection

from cinenerf_ns.planner.corridor import corridor_options
from cinenerf_ns.planner.corridor.polytope import SeedNotFreeError, chebyshev_center, safe_polytope
from cinenerf_ns.planner.corridor.polytope_batched import safe_polytopes_batched
from cinenerf_ns.planner.corridor.safe_corridor import build_corridor
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.procedural import procedural_room
from cinenerf_ns.planner.scene.spatial_index import GridIndex
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig

sys.path.insert(0, str(Path(__file__).parents[1]))  # our float64 references live beside the tests
from _corridor_refs import clearance, make_scene, polytope_min_distance, random_scene  # noqa: E402


def _support_min(A: np.ndarray, scene) -> np.ndarray:
    """[N, F] min over the inflated ellipsoid E_j (+) B_r of A_f.x (numpy, independent of the package):
    n.mu - ||diag(a) R^T n|| - r."""
    mu = scene.means.double().numpy()
    R = scene.rotations.double().numpy()
    a = scene.radii.double().numpy()
    nb = np.einsum("nji,fj->nfi", R, A)  # R^T n  [N, F, 3]
    return mu @ A.T - np.linalg.norm(a[:, None, :] * nb, axis=-1) - scene.camera_radius


def _check_polytope(P, seg, lo, hi, scene, rng, n_interior=25):
    """P contains the segment, lies in the box, every ellipsoid that could meet the box is entirely beyond one
    of P's own planes (exact support test), and sampled points (vertices, Chebyshev centre, convex
    combinations) have exact clearance >= 0."""
    A, b = P.to_numpy()
    assert np.allclose(np.linalg.norm(A, axis=1), 1.0, atol=1e-12)
    assert (seg @ A.T <= b + 1e-12).all()
    # box planes first, exactly the box
    assert np.allclose(A[:6], np.vstack([np.eye(3), -np.eye(3)])) and np.allclose(b[:6], np.concatenate([hi, -lo]))
    mu = scene.means.double().numpy()
    a = scene.radii.double().numpy()
    R = scene.rotations.double().numpy()
    r = scene.camera_radius
    # ellipsoids whose bounding sphere + r or whose AABB + r stays off the box cannot meet the polytope; all
    # others need to lie beyond one of its planes
    gap = np.linalg.norm(mu - np.clip(mu, lo, hi), axis=1)
    h = np.sqrt(((R * a[:, None, :]) ** 2).sum(-1)) + r  # [N, 3] AABB half-extents + r
    near = (gap <= a.max(-1) + r) & ((mu - h <= hi) & (mu + h >= lo)).all(-1)
    beyond = (_support_min(A[6:], scene) >= b[6:]).any(1) if len(A) > 6 else np.zeros(len(mu), bool)
    assert beyond[near].all(), np.flatnonzero(near & ~beyond)
    c, rad = chebyshev_center(A, b)
    pts = [seg]
    if rad > 1e-9:
        V = HalfspaceIntersection(np.hstack([A, -b[:, None]]), c).intersections
        w = rng.dirichlet(np.ones(len(V)) * 0.3, size=n_interior)
        pts += [V, w @ V, c[None]]
    assert clearance(np.vstack(pts), scene).min() >= -1e-9


def _random_segments(rng, M, spread=0.3):
    p0 = rng.uniform(-0.8, 0.8, (M, 3))
    p1 = p0 + rng.normal(size=(M, 3)) * spread
    return np.stack([p0, p1], 1)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 40), M=st.integers(1, 4),
       r=st.sampled_from([0.0, 0.03, 0.1]), chunk=st.sampled_from([1, 3, 32]),
       normal=st.sampled_from(["auto", "auto", "prop2", "closest", "mahalanobis"]), use_index=st.booleans())
def test_batched_polytopes_are_safe_contain_their_segments_and_fail_like_the_host_path(
        seed, n, M, r, chunk, normal, use_index):
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, n, camera_radius=r)
    segs = _random_segments(rng, M)
    lo, hi = segs.min(1) - 0.2, segs.max(1) + 0.2
    index = GridIndex.build(scene) if use_index else None
    polys, failed = safe_polytopes_batched(torch.as_tensor(segs), scene, index, lo, hi, chunk=chunk, normal=normal)
    assert failed.dtype == torch.bool and failed.shape == (M,)
    for m in range(M):
        try:
            safe_polytope(segs[m], scene, index, lo[m], hi[m], normal=normal)
            host_failed = False
        except SeedNotFreeError:
            host_failed = True
        # flagged wherever the host path raises (the caller then uses the host path)
        assert bool(failed[m]) or not host_failed, m
        if failed[m]:
            assert polys[m] is None
            continue
        assert torch.equal(polys[m].seed, torch.as_tensor(segs[m]))
        _check_polytope(polys[m], segs[m], lo[m], hi[m], scene, rng)


def test_flags_exactly_the_blocked_segments_and_agrees_with_the_host_path():
    """Many random cluttered cases: the flags equal the host path's SeedNotFreeError (both outcomes occur)."""
    flags, host = [], []
    for seed in range(15):
        rng = np.random.default_rng(1000 + seed)
        scene = random_scene(rng, 50, camera_radius=0.05)
        segs = _random_segments(rng, 3)
        lo, hi = segs.min(1) - 0.15, segs.max(1) + 0.15
        _, failed = safe_polytopes_batched(segs, scene, None, lo, hi)
        for m in range(3):
            flags.append(bool(failed[m]))
            try:
                safe_polytope(segs[m], scene, None, lo[m], hi[m])
                host.append(False)
            except SeedNotFreeError:
                host.append(True)
    assert flags == host
    assert 5 < sum(flags) < len(flags) - 5, sum(flags)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 8))
def test_whole_batched_polytope_is_safe_socp(seed, n):
    """Exact min distance over the WHOLE polytope (SOCP per ellipsoid) >= r."""
    rng = np.random.default_rng(seed)
    scene = random_scene(rng, n, camera_radius=0.05)
    segs = _random_segments(rng, 2, spread=0.2)
    polys, failed = safe_polytopes_batched(segs, scene, None, segs.min(1) - 0.3, segs.max(1) + 0.3)
    for P in polys:
        if P is not None:
            A, b = P.to_numpy()
            assert polytope_min_distance(A, b, scene).min() >= 0.05 - 1e-6


def test_hidden_wall_needs_no_planes_and_blocked_segment_is_flagged():
    yy, zz = np.meshgrid(np.linspace(-0.45, 0.45, 10), np.linspace(-0.45, 0.45, 10))
    wall = np.stack([np.full(100, 0.5), yy.ravel(), zz.ravel()], -1)
    means = np.vstack([wall, wall + np.array([0.2, 0.0, 0.0])])  # a second wall hidden behind the first
    scene = make_scene(means, np.tile(np.eye(3), (200, 1, 1)), np.full((200, 3), 0.06), 0.03)
    segs = np.array([[[0.0, -0.2, 0.0], [0.0, 0.2, 0.0]],  # free, in front of the wall
                     [[0.3, 0.0, 0.0], [0.9, 0.0, 0.0]]])  # through both walls
    lo, hi = segs.min(1) - 0.6, segs.max(1) + 0.6
    polys, failed = safe_polytopes_batched(segs, scene, GridIndex.build(scene), lo, hi, chunk=8)
    assert failed.tolist() == [False, True] and polys[1] is None
    P = polys[0]
    assert P.num_faces <= 6 + 30, P.num_faces
    assert not set(P.ellipsoid_ids.tolist()) & set(range(100, 200))  # the hidden wall needs no plane
    _check_polytope(P, segs[0], lo[0], hi[0], scene, np.random.default_rng(0))
    with pytest.raises(SeedNotFreeError):
        safe_polytope(segs[1], scene, None, lo[1], hi[1])


def test_bad_inputs_raise():
    scene = random_scene(np.random.default_rng(0), 5)
    seg = np.array([[[0.0, 0, 0], [0.1, 0, 0]]])
    with pytest.raises(InvalidInputError):
        safe_polytopes_batched(seg, scene, None, np.full((1, 3), 0.05), np.full((1, 3), 1.0))  # seed outside
    with pytest.raises(InvalidInputError):
        safe_polytopes_batched(seg[:, :1], scene, None, -np.ones((1, 3)), np.ones((1, 3)))
    with pytest.raises(InvalidInputError):
        safe_polytopes_batched(seg, scene, None, -np.ones((1, 3)), np.ones((1, 3)), normal="nope")
    with pytest.raises(InvalidInputError):
        build_corridor(seg[0], scene, None, backend="batched", box="oriented")


def test_batched_corridor_sends_flagged_segments_to_the_host_path(monkeypatch):
    """Segments the batched builder flags get the host path's polytope; a blocked polyline fails the same way."""
    import cinenerf_ns.planner.corridor.safe_corridor as corridor_mod

    rng = np.random.default_rng(4)
    scene = random_scene(rng, 30, lo=-0.5, hi=0.5, amax=0.2, camera_radius=0.03)  # clutter near the middle
    way = np.array([[-0.9, -0.9, -0.9], [-0.9, -0.9, 0.9], [-0.9, 0.9, 0.9], [0.9, 0.9, 0.9]])
    real = corridor_mod.safe_polytopes_batched

    def flag_segment_1(*a, **kw):
        polys, failed = real(*a, **kw)
        polys[1], failed[1] = None, True
        return polys, failed

    try:
        host = build_corridor(way, scene, None, box_margin=0.1)
    except Exception:  # noqa: BLE001 - the fixed polyline must be coverable in this scene
        pytest.fail("fixture polyline not coverable")
    bat = build_corridor(way, scene, None, box_margin=0.1, backend="batched")
    assert bat.n_host_segments == 0 and len(bat) == len(host)
    monkeypatch.setattr(corridor_mod, "safe_polytopes_batched", flag_segment_1)
    bat = build_corridor(way, scene, None, box_margin=0.1, backend="batched")
    assert bat.n_host_segments == 1
    assert torch.equal(bat.polytopes[1].A, host.polytopes[1].A) and torch.equal(bat.polytopes[1].b, host.polytopes[1].b)
    monkeypatch.undo()
    # through an ellipsoid: flagged, then the host path splits and gives up like backend "cpu"
    blocked = np.stack([way[0], scene.means[0].numpy(), way[3]])
    for backend in ("cpu", "batched"):
        with pytest.raises(corridor_mod.CorridorError):
            build_corridor(blocked, scene, None, box_margin=0.1, backend=backend)


def test_planner_with_batched_corridor_on_cpu_tensors():
    s = procedural_room(4000, seed=1)
    e = EllipsoidScene.from_splat(s.means, s.quats, s.log_scales, s.opacity_logits)
    with pytest.raises(InvalidInputError):
        Planner(e, PlannerConfig(corridor_backend="gpu"))
    pl = Planner(e, PlannerConfig(grid_resolution=64, corridor_backend="batched", candidate_workers=0))
    pl.prepare()
    assert corridor_options.corridor_backend(pl.space) == "batched"
    auto = Planner(e, PlannerConfig(corridor_backend="auto"))
    assert corridor_options.corridor_backend(auto.space) == "cpu"  # CPU scene
    for seed in range(3):
        sh = pl.plan(s.objects[0].center, s.objects[1].center, seed=seed)[0]
        assert sh.safety["safe"]
        pts = torch.as_tensor(sh.positions, dtype=torch.float64)
        from cinenerf_ns.planner.geometry.distance import clearance as exact_clearance

        assert float(exact_clearance(pts, e, pl.prepared.index).min()) >= 0
        for P in sh.corridor.polytopes:  # every polytope is a valid one for its segment
            assert P.A.dtype == torch.float64


@pytest.mark.gpu
def test_cuda_batched_polytopes_match_cpu_and_plan():
    rng = np.random.default_rng(7)
    scene = random_scene(rng, 400, lo=-2, hi=2, amax=0.15, camera_radius=0.03)
    segs = _random_segments(rng, 12, spread=0.4) * 2
    lo, hi = segs.min(1) - 0.2, segs.max(1) + 0.2
    cpu_p, cpu_f = safe_polytopes_batched(segs, scene, GridIndex.build(scene), lo, hi)
    gs = scene.to("cuda")
    gpu_p, gpu_f = safe_polytopes_batched(segs, gs, GridIndex.build(gs), lo, hi, out_device="cpu")
    assert torch.equal(cpu_f, gpu_f)
    for m in range(len(segs)):
        if gpu_p[m] is None:
            continue
        _check_polytope(gpu_p[m], segs[m], lo[m], hi[m], scene, rng, n_interior=10)
        # same greedy decisions up to rounding: the same planes
        if gpu_p[m].num_faces == cpu_p[m].num_faces:
            assert torch.allclose(gpu_p[m].b, cpu_p[m].b, atol=1e-9)
    room = procedural_room(50_000, seed=3)
    e = EllipsoidScene.from_splat(room.means.cuda(), room.quats.cuda(), room.log_scales.cuda(),
                                  room.opacity_logits.cuda())
    pl = Planner(e, PlannerConfig(candidate_workers=0))  # requests on the CPU mirror
    pl.prepare()
    # auto: host polytopes on the CPU mirror for one request, batched for many corridors
    assert corridor_options.corridor_backend(pl.space) == "cpu"
    assert corridor_options.corridor_backend(pl.space, many=True) == "batched"
    assert pl.scene.device.type == "cpu"
    sh = pl.plan(room.objects[0].center, room.objects[1].center, seed=0)[0]
    assert sh.safety["safe"] and all(P.A.device.type == "cpu" for P in sh.corridor.polytopes)
