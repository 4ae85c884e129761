"""The real planner behind the panel (PreparedPlanner) on a small procedural room: prepared once (in the
background), shots stay out of every obstacle (independent reference: inflated ellipsoids, float64),
per-frame clearance is the planner's exact clearance, planner errors pass through with their messages.
Also the demo scene's label query and the look-at rotation convention."""
from __future__ import annotations

import threading

import numpy as np
import pytest
import torch

from cinenerf_ns.planner.errors import InvalidInputError, StartInCollisionError
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.procedural import procedural_room
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.viewer.backend import NoMatchError, label_locate
from cinenerf_ns.viewer.demo import demo_scene, look_at_rotation
from cinenerf_ns.viewer.planner_backend import PreparedPlanner

torch.set_num_threads(1)


def inside_inflated(points, scene) -> np.ndarray:
    """Reference: p is unsafe if inside the ellipsoid with semi-axes a + r (a superset of
    ellipsoid (+) camera ball), brute force over all obstacles in float64."""
    mu, R = scene.means.double().numpy(), scene.rotations.double().numpy()
    a = scene.radii.double().numpy() + scene.camera_radius
    d = np.einsum("nji,pnj->pni", R, points[:, None, :] - mu[None])  # body coordinates [P, N, 3]
    return ((d / a[None]) ** 2).sum(-1).min(1) <= 1.0


def densify(pos, step=0.01):
    out = [pos[0]]
    for a, b in zip(pos[:-1], pos[1:]):
        n = max(int(np.ceil(np.linalg.norm(b - a) / step)), 1)
        out.extend(a + (b - a) * k / n for k in range(1, n + 1))
    return np.array(out)


@pytest.fixture(scope="module")
def room():
    r = procedural_room(2000, seed=0)
    scene = EllipsoidScene.from_splat(r.means, r.quats, r.log_scales, r.opacity_logits, SceneConfig())
    from cinenerf_ns.planner.shots.planner import PlannerConfig

    cfg = PlannerConfig(grid_resolution=48, start_region=(r.free_lo + 0.03, r.free_hi - 0.03))
    statuses = []
    planner = PreparedPlanner(scene, cfg, on_status=lambda t, lv: statuses.append((t, lv)))
    planner.start(background=True)
    return r, scene, planner, statuses


def test_prepares_once_in_background_and_reports(room):
    r, scene, planner, statuses = room
    assert planner.wait_ready(60) and planner.ready
    assert planner._thread is not None and planner._thread.name == "cine-prepare"
    assert statuses[0][1] == "busy" and "Preparing the planner" in statuses[0][0]
    # its timings go to the details fold; the status says the planning region and the rule that chose it
    assert statuses[-1][1] == "ok" and statuses[-1][0].startswith("Planner ready. It plans in the planning region (")
    note = planner.planner.grid_note  # a grid made finer than asked for is said after the region
    assert statuses[-1][0].endswith("chosen by: automatic: training cameras" + (f" ({note})." if note else "."))
    assert planner.prepare_detail.startswith("Planner prepared in ") and " ms" in planner.prepare_detail
    prepared = planner.planner.prepared
    planner.start()  # a second start does nothing
    assert planner.planner.prepared is prepared


def test_shots_are_safe_and_carry_exact_frame_clearance(room):
    r, scene, planner, _ = room
    goal, look = r.object("armchair").center, r.object("floor lamp").center
    shots = planner.plan(goal, look, seed=3, n_candidates=2)
    assert 1 <= len(shots) <= 2
    for s in shots:
        assert s.clearance.shape == (len(s.times),) and s.clearance.min() >= 0
        # exact up to the cap, the cap above it
        exact = planner.planner.clearance(s.positions)
        np.testing.assert_allclose(s.clearance, np.minimum(exact, planner.clearance_cap), rtol=0, atol=1e-12)
        assert not inside_inflated(densify(s.positions), scene).any()
        fwd = -s.rotations[-1][:, 2]
        to_target = (look - s.positions[-1]) / np.linalg.norm(look - s.positions[-1])
        assert fwd @ to_target > 0.99
        assert "frame_clearance_ms" in s.timings and s.safety["safe"]


def test_random_start_candidates_come_ranked(room):
    r, scene, planner, _ = room
    shots = planner.plan(r.object("armchair").center, r.object("floor lamp").center, seed=1, n_candidates=3)
    assert len(shots) >= 2
    assert [s.rank for s in shots] == list(range(1, len(shots) + 1))
    scores = [s.score for s in shots]
    assert scores == sorted(scores)  # best (lowest cost) first, as the panel lists them
    assert all(abs(s.score_terms["total"] - s.score) < 1e-12 for s in shots)


def test_torch_inputs_and_errors_pass_through(room):
    r, scene, planner, _ = room
    goal = torch.as_tensor(r.object("table").center)
    shots = planner.plan(goal, torch.as_tensor(r.object("vase").center), seed=0)
    assert len(shots) == 1
    inside = scene.means[0].double().numpy()
    with pytest.raises(StartInCollisionError, match="inside the scene"):
        planner.plan(r.object("table").center, r.object("vase").center, start=inside)
    with pytest.raises(InvalidInputError, match="finite"):
        planner.plan(np.array([np.nan, 0, 0]), r.object("vase").center)
    with pytest.raises(InvalidInputError, match=r"integer in \[1, 64\]"):
        planner.plan(r.object("table").center, r.object("vase").center, n_candidates=0)


def test_prepare_failure_is_reported_and_raised_by_plan():
    from cinenerf_ns.planner.shots.planner import PlannerConfig

    r = procedural_room(500, seed=1)
    scene = EllipsoidScene.from_splat(r.means, r.quats, r.log_scales, r.opacity_logits, SceneConfig())
    statuses = []
    bad = PlannerConfig(bounds=((0.0, 0.0, 0.0), (-1.0, 1.0, 1.0)))  # lo > hi on x: prepare() refuses
    p = PreparedPlanner(scene, bad, on_status=lambda t, lv: statuses.append((t, lv)))
    p.start(background=False)
    assert not p.ready and statuses[-1][1] == "error" and "could not prepare" in statuses[-1][0]
    for _ in range(2):  # every Plan gets the readable error
        with pytest.raises(InvalidInputError, match="planning region .* is empty or inverted along x"):
            p.plan(np.zeros(3), np.ones(3))


def test_concurrent_plans_are_serialised(room):
    r, scene, planner, _ = room
    out, errs = [], []

    def go(seed):
        try:
            out.append(planner.plan(r.object("sofa").center, r.object("table").center, seed=seed))
        except Exception as e:  # pragma: no cover - reported below
            errs.append(e)

    th = [threading.Thread(target=go, args=(s,)) for s in range(2)]
    [t.start() for t in th]
    [t.join(120) for t in th]
    assert not errs and len(out) == 2


def test_label_locate():
    d = demo_scene()
    locate = label_locate(d.splat.means, d.labels, d.label_of)
    c, m, what = locate("the Red Box")
    assert what == "the label 'red box'"
    assert m.sum() == (d.label_of == 0).sum()
    np.testing.assert_allclose(c, d.splat.means[d.label_of == 0].mean(0), atol=1e-6)
    assert locate("pillar")[1].sum() == (d.label_of == 2).sum()
    assert locate("boxes")[2] == "the label 'red box'"  # whole words, singular or plural
    with pytest.raises(NoMatchError, match="known: red box"):
        locate("sofa")
    for fragment in ("ox", "pill", "the red box on the left"):  # a part of a word, or words no label holds
        with pytest.raises(NoMatchError, match="matches no object"):
            locate(fragment)


def test_look_at_rotation_convention():
    R = look_at_rotation(np.zeros(3), np.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(R, [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-12)  # -z forward, +y up
    R = look_at_rotation(np.zeros(3), np.array([0.0, 0.0, -1.0]))  # straight down: no NaN
    assert np.all(np.isfinite(R)) and np.allclose(R @ R.T, np.eye(3))


def test_object_targets_end_at_end_poses_and_report_the_view(room):
    """With the panel's resolved targets (their masks) the backend chooses end poses as cinesplat-plan does: each shot
    ends at its end pose, outside both objects, and carries end_pose / subject_view for the status."""
    from cinenerf_ns.viewer.panel_types import Target

    r, scene, planner, _ = room
    names = [o.name for o in r.objects]
    ids = r.object_ids.cpu().numpy()
    goto = Target("go to", "armchair", r.object("armchair").center, ids == names.index("armchair"))
    look = Target("look at", "floor lamp", r.object("floor lamp").center, ids == names.index("floor lamp"))
    shots = planner.plan(goto.point, look.point, seed=2, n_candidates=3, targets=(goto, look), framing="close")
    assert shots
    for s in shots:
        assert s.end_pose is not None and np.allclose(s.positions[-1], s.end_pose["point"], atol=1e-6)
        assert not s.goal_moved  # it ends where it was sent
        for name in ("armchair", "floor lamp"):
            o = r.object(name)
            assert not np.all(np.abs(s.positions[-1] - o.center) <= o.size / 2)
        v = s.subject_view
        assert v["framing"] == "close" and 0 <= v["visible_last"] <= 1 and v["size_last"] > 0
    assert len({tuple(np.round(s.positions[-1], 6)) for s in shots}) == len(shots)  # distinct end poses
    from cinenerf_ns.viewer.shot_text import shot_summary

    assert "visible at the end" in shot_summary(shots[0]) and "close" in shot_summary(shots[0])
    # the same object twice: a good view of it (no go-to distance)
    same = planner.plan(look.point, look.point, seed=2, n_candidates=1, targets=(look, look))
    assert same[0].end_pose is not None and same[0].end_pose["goto_distance"] == 0.0
