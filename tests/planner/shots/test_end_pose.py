"""End poses (shots/end_pose.py) on a procedural room with ground-truth objects: never inside an object, proven free,
in the framing's size band and whole in frame, distinct for candidates, "a good view of X" facing the start region;
shots planned to them end there and see the subject (checked by rendering label images with the project's
rasteriser); the framing's size measure against brute-force projection."""
from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from cinenerf_ns.planner import native
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.geometry import clearance_queries
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.procedural import procedural_room
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.shots.candidates import plan_candidates
from cinenerf_ns.planner.shots.end_pose import EndPoseConfig, choose_end_poses
from cinenerf_ns.planner.shots.framing import FRAMING_BANDS, FramingConfig, in_band, subject_size
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig
from cinenerf_ns.planner.shots.target_object import TargetObject, scene_members

torch.set_num_threads(1)
_VOL: list = []  # the room's SplatVolume (set by the fixture)


@pytest.fixture(scope="module")
def room():
    r = procedural_room(20_000, seed=0)
    scene = EllipsoidScene.from_splat(r.means, r.quats, r.log_scales, r.opacity_logits, SceneConfig())
    pl = Planner(scene, PlannerConfig(grid_resolution=64, start_region=(r.free_lo + 0.03, r.free_hi - 0.03),
                                      candidate_workers=0))
    pl.prepare()
    from cinenerf_ns.planner.shots.end_pose import visibility_volume

    _VOL[:] = [visibility_volume(pl)]
    return r, scene, pl


def _obj(r, scene, name) -> TargetObject:
    ids = r.object_ids.cpu().numpy() == [o.name for o in r.objects].index(name)
    return TargetObject.of_members(_VOL[0], scene_members(scene, ids), r.object(name).center, name)


def _inside_a_box(p, r, pad=0.0) -> bool:
    return any(np.all(np.abs(p - o.center) <= o.size / 2 + pad) for o in r.objects)


def test_end_poses_are_free_outside_every_object_and_framed(room):
    r, scene, pl = room
    names = [o.name for o in r.objects]
    comp = pl.main_component()
    n_in_band = n_total = 0
    for a in names:
        for b in names:
            if a == b:
                continue
            subject, goto = _obj(r, scene, b), _obj(r, scene, a)
            ch = choose_end_poses(pl, subject, goto, FramingConfig("medium"), comp, k=3)
            for p in ch.poses:
                assert not _inside_a_box(p.point, r), (a, b, p.point)  # never inside an object (ground truth)
                assert pl.clearance(p.point[None])[0] >= 0  # exact clearance: the camera ball is free there
                assert clearance_queries.points_free(pl.space, p.point[None])[0]
                lo, hi = pl.region()
                assert np.all(p.point >= lo) and np.all(p.point <= hi)
                n_total += 1
                n_in_band += bool(in_band(p.size, FramingConfig("medium"))[()]) and p.whole
    assert n_total > 0 and n_in_band / n_total >= 0.9


@pytest.mark.parametrize("framing", list(FRAMING_BANDS))
def test_each_framing_puts_the_subject_in_its_band(room, framing):
    r, scene, pl = room
    ch = choose_end_poses(pl, _obj(r, scene, "floor lamp"), _obj(r, scene, "armchair"), FramingConfig(framing),
                          pl.main_component(), k=1)
    assert ch.poses, ch.why()
    p = ch.poses[0]
    # the planner's own estimate and a brute-force projection of every Gaussian mean of the subject agree
    lamp = _obj(r, scene, "floor lamp")
    means = scene.means.double().numpy()[lamp.members]
    size, whole = subject_size(p.point[None], lamp.centre, np.array([0, 0, 1.0]), means, lamp.pad,
                               FramingConfig(framing))
    assert abs(size[0] - p.size) <= 0.1 * p.size + 1e-9
    assert p.whole and in_band(p.size, FramingConfig(framing), tol=0.05)


def test_candidates_get_distinct_end_poses(room):
    r, scene, pl = room
    cfg = EndPoseConfig(min_separation_deg=25.0)
    ch = choose_end_poses(pl, _obj(r, scene, "sofa"), _obj(r, scene, "table"), FramingConfig("wide"),
                          pl.main_component(), k=4, config=cfg)
    assert len(ch.poses) == 4
    c = _obj(r, scene, "sofa").centre
    dirs = [(p.point - c) / np.linalg.norm(p.point - c) for p in ch.poses]
    # distinct where they can be: the best is at least 25 degrees from most of the others (an alternative that would
    # hide the subject is not taken for distinctness' sake)
    assert sum(math.degrees(math.acos(np.clip(dirs[0] @ d, -1, 1))) >= 25.0 - 1e-6 for d in dirs[1:]) >= 2
    costs = [p.cost for p in ch.poses]
    assert costs[0] == min(costs)


def test_a_good_view_of_x_faces_the_start_region(room):
    r, scene, pl = room
    lamp = _obj(r, scene, "floor lamp")
    lo, hi = (np.asarray(v) for v in pl.config.start_region)
    facing = 0.5 * (lo + hi) - lamp.centre
    ch = choose_end_poses(pl, lamp, None, FramingConfig("medium"), pl.main_component(), k=1, facing=facing)
    assert ch.poses and ch.poses[0].goto_distance == 0.0
    d = ch.poses[0].point - lamp.centre
    horiz = lambda v: v[:2] / np.linalg.norm(v[:2])  # noqa: E731
    assert horiz(d) @ horiz(facing) > 0.0  # on the side the start region is on


def test_nothing_feasible_says_why(room):
    r, scene, pl = room
    ch = choose_end_poses(pl, _obj(r, scene, "floor lamp"), _obj(r, scene, "armchair"), FramingConfig("medium"),
                          component=10_000, k=2)  # a component that does not exist: nothing is reachable
    assert ch.poses == [] and "unreachable" in ch.why()
    with pytest.raises(InvalidInputError, match="framing"):
        choose_end_poses(pl, _obj(r, scene, "sofa"), None, FramingConfig("huge"), pl.main_component())
    with pytest.raises(InvalidInputError, match="EndPoseConfig"):
        EndPoseConfig(samples=0).validate()


def _label_visibility(r, scene_params, subject_id, c2w, width=96, height=54, fov=50.0):
    """Visible fraction of a procedural object in one frame by label rendering (the project's rasteriser): its colour
    through the whole splat over its alpha rendered alone."""
    from cinenerf_ns.preview.cameras import viewmat_from_c2w
    from cinenerf_ns.preview.raster_torch import make_scene
    from cinenerf_ns.preview.render import render_premultiplied

    means, quats, scales, opac = scene_params
    ids = r.object_ids.cpu().numpy()
    col = torch.zeros(len(ids), 3)
    col[ids == subject_id, 0] = 1.0
    full = make_scene(means, quats, scales, opac, col, drop_transparent=False)
    sel = torch.as_tensor(ids == subject_id)
    alone = make_scene(means[sel], quats[sel], scales[sel], opac[sel], col[sel], drop_transparent=False)
    f = (height / 2) / math.tan(math.radians(fov) / 2)
    vm = viewmat_from_c2w(c2w)
    rgb, _ = render_premultiplied(full, vm, (f, f, width / 2, height / 2), width, height, backend="torch")
    _, a = render_premultiplied(alone, vm, (f, f, width / 2, height / 2), width, height, backend="torch")
    return float(rgb[..., 0].sum() / max(float(a.sum()), 1e-9))


def test_shots_to_end_poses_end_there_and_see_the_subject(room):
    r, scene, pl = room
    names = [o.name for o in r.objects]
    params = (r.means.float(), r.quats.float(), torch.exp(r.log_scales.float()),
              torch.sigmoid(r.opacity_logits.float()))
    from cinenerf_ns.planner.geometry.visibility import SubjectSamples
    from cinenerf_ns.planner.shots.end_pose import visibility_volume

    seen = []
    for a, b in [("armchair", "floor lamp"), ("table", "sofa"), ("sofa", "vase")]:
        if a not in names or b not in names:
            continue
        subject, goto = _obj(r, scene, b), _obj(r, scene, a)
        ch = choose_end_poses(pl, subject, goto, FramingConfig("medium"), pl.main_component(), k=2)
        goals = np.stack([p.point for p in ch.poses])
        ranked = plan_candidates(pl, goals, subject.centre, k=2, seed=1,
                                 subject=SubjectSamples.of_members(visibility_volume(pl), subject.members))
        assert {rs.candidate % len(goals) for rs in ranked} == set(range(len(goals)))  # each end pose planned to
        for rs in ranked:
            sh = rs.shot
            assert sh.safety["safe"]
            assert np.allclose(sh.positions[-1], goals[rs.candidate % len(goals)], atol=1e-6)  # ends at its pose
            v = _label_visibility(r, params, names.index(b), sh.camera_to_worlds()[-1])
            seen.append((rs.rank, v))
            assert rs.score.terms["visible_last"] == pytest.approx(v, abs=0.25)  # the planner's estimate
    assert seen and min(v for rank, v in seen if rank == 1) >= 0.8  # the best shot of each pair shows the subject
    assert min(v for _, v in seen) >= 0.5


def test_scene_members_through_source_index_and_its_host_copy():
    """A scene built from a splat with dropped Gaussians maps masks over the splat through source_index; the host copy
    of source_index is made once per tensor and a new tensor is read anew."""
    from cinenerf_ns.planner.shots import target_object as T

    scene = EllipsoidScene.from_splat(torch.zeros(6, 3), torch.tensor([[1.0, 0, 0, 0]] * 6), torch.zeros(6, 3),
                                      torch.tensor([5.0, -10.0, 5.0, 5.0, -10.0, 5.0]), SceneConfig(opacity_floor=0.05))
    assert scene.source_index is not None and scene.source_index.tolist() == [0, 2, 3, 5]
    mask = np.array([1, 1, 0, 1, 0, 0], bool)  # splat Gaussians 0, 1 (dropped), 3
    np.testing.assert_array_equal(scene_members(scene, mask), [0, 2])
    first = T._SOURCES[id(scene.source_index)][1][0]
    np.testing.assert_array_equal(scene_members(scene, mask), [0, 2])
    assert T._SOURCES[id(scene.source_index)][1][0] is first  # not copied again
    scene.source_index = torch.tensor([1, 2, 3, 4])
    np.testing.assert_array_equal(scene_members(scene, mask), [0, 2])  # the new tensor's own copy: splat 1 and 3
    with pytest.raises(InvalidInputError, match="the scene's Gaussians come from more"):
        scene_members(scene, mask[:4])
    assert scene_members(scene, None) is None


def _frame_coverage_reference(cameras, look_at, up, obj, framing):
    """Cell by cell, point by point (float64): a cell counts when its centre lies in the disc of radius pad + spacing
    (in half-frame units at the point's depth) around a projected extent point in front of the camera."""
    from cinenerf_ns.planner.shots.end_pose import COVERAGE_RASTER
    from cinenerf_ns.planner.shots.framing import project

    x, y, depth = project(cameras, look_at, up, obj.extent, framing)
    th, tv = framing.tan_half()
    r = obj.pad + obj.gap()
    nx, ny = COVERAGE_RASTER
    out = []
    for m in range(len(cameras)):
        hit = 0
        for j in range(ny):
            for i in range(nx):
                cx, cy = (i + 0.5) / nx * 2 - 1, (j + 0.5) / ny * 2 - 1
                hit += any(depth[m, p] > 1e-6 and ((cx - x[m, p]) / (r / (depth[m, p] * th))) ** 2
                           + ((cy - y[m, p]) / (r / (depth[m, p] * tv))) ** 2 <= 1.0 for p in range(len(obj.extent)))
        out.append(hit / (nx * ny))
    return np.array(out)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 40), pad=st.sampled_from([0.0, 0.02, 0.2]),
       backend=st.sampled_from(["python"] + (["native"] if native.coverage_c() is not None else [])))
def test_frame_coverage_matches_a_cell_by_cell_reference(seed, n, pad, backend):
    """numpy's and the compiled raster (native/targets.c) against a cell-by-cell reference: the same cells."""
    from cinenerf_ns.planner.shots.end_pose import frame_coverage

    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 3)) * rng.uniform(0.05, 0.5)
    obj = TargetObject(name="o", centre=pts.mean(0), members=np.arange(n), extent=pts, pad=pad,
                       spacing=float(rng.uniform(0.0, 0.1)))
    cams = rng.normal(size=(7, 3)) * 1.5
    cams[0] = pts[0]  # a camera among the points: some behind it
    look = pts.mean(0) + rng.normal(size=3) * 0.1
    up = np.array([0.0, 0.0, 1.0])
    got = frame_coverage(cams, look, up, obj, FramingConfig("medium"), backend=backend)
    np.testing.assert_array_equal(got, _frame_coverage_reference(cams, look, up, obj, FramingConfig("medium")))


def _choose_all_reference(cost, vis, gfill, dirs, k, cfg, cos_sep):
    """The choice with every viewpoint's total computed (what choose_end_poses did before evaluating lazily)."""
    from cinenerf_ns.planner.shots.end_pose import GOTO_FILL_FREE

    total = cost + cfg.w_visibility * (1 - vis) + cfg.w_goto_fill * np.maximum(0.0, gfill - GOTO_FILL_FREE)
    order = np.argsort(total, kind="stable")
    chosen = []
    floor = min(float(vis[order[0]]), max(0.5, float(vis[order[0]]) - 0.25))
    for i in order:
        if len(chosen) >= k:
            break
        if (not chosen or vis[i] >= floor) and all(float(dirs[i] @ dirs[j]) < cos_sep for j in chosen):
            chosen.append(int(i))
    for i in order:
        if len(chosen) >= k:
            break
        if int(i) not in chosen:
            chosen.append(int(i))
    return chosen, total


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 30), k=st.integers(1, 8), ties=st.booleans(),
       first=st.integers(1, 12))
def test_lazy_choice_is_the_choice_with_every_viewpoint_evaluated(seed, n, k, ties, first):
    from cinenerf_ns.planner.shots.end_pose import _choose_lazily

    rng = np.random.default_rng(seed)
    cost = np.sort(rng.uniform(0, 3, n) if not ties else rng.integers(0, 3, n).astype(float))
    vis = rng.choice([0.0, 0.3, 0.6, 1.0], n) if ties else rng.uniform(0, 1, n)
    gfill = rng.choice([0.0, 0.25, 0.5], n) if ties else rng.uniform(0, 0.6, n)
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    cfg, cos_sep = EndPoseConfig(), math.cos(math.radians(25.0))
    asked = []

    def visibility(pos):
        asked.extend(int(i) for i in pos)
        return vis[pos]

    chosen, total, v = _choose_lazily(cost, gfill, visibility, dirs, k, cfg, cos_sep, first)
    want, want_total = _choose_all_reference(cost, vis, gfill, dirs, k, cfg, cos_sep)
    assert chosen == want
    assert len(asked) == len(set(asked))  # each evaluated once
    np.testing.assert_array_equal(total[chosen], want_total[chosen])
    np.testing.assert_array_equal(v[chosen], vis[chosen])


def test_the_sphere_ring_kept_with_the_subject_equals_a_fresh_one(room):
    from cinenerf_ns.planner.shots.end_pose import _directions, _ring, _sphere_ring

    r, scene, pl = room
    subject = _obj(r, scene, r.objects[1].name)
    up = np.array([0.0, 0.0, 1.0])
    cfg, framing = EndPoseConfig(), FramingConfig("wide")
    _, sphere = _directions(subject, None, up, cfg)
    first = _sphere_ring(subject, sphere, up, framing, cfg)
    assert _sphere_ring(subject, sphere, up, framing, cfg) is first  # kept
    fresh = _ring(subject, sphere, up, framing)
    np.testing.assert_array_equal(first.d, fresh.d)
    np.testing.assert_array_equal(first.pts, fresh.pts)
    assert not first.pts.flags.writeable
    # sized a few at a time, in any order and with repeats, as requests with different free viewpoints do: what
    # sizing all at once gives
    n = first.pts.shape[0] * first.pts.shape[1]
    rng = np.random.default_rng(0)
    for part in np.array_split(rng.permutation(n), 5):
        first.sizes(np.concatenate([part, part[:3]]), subject, up, framing)
    assert first.done.all()
    size, whole = fresh.sizes(np.arange(n), subject, up, framing)
    # (bit for bit with the compiled sizes; numpy's matrix products may round another batch size differently)
    np.testing.assert_allclose(first.sizes(np.arange(n), subject, up, framing)[0], size, rtol=1e-13)
    np.testing.assert_array_equal(first.whole, whole)
    want = subject_size(first.pts.reshape(-1, 3), subject.centre, up, subject.outline_points(), subject.pad, framing)
    np.testing.assert_allclose(size, want[0], rtol=1e-13)
    np.testing.assert_array_equal(whole, want[1])
    assert _sphere_ring(subject, sphere, up, FramingConfig("close"), cfg) is not first
    copy = pickle.loads(pickle.dumps(first))  # kept with the subject: picklable, with its own lock
    np.testing.assert_array_equal(copy.sizes(np.arange(n), subject, up, framing)[0], first.size)
    assert copy.lock is not first.lock
