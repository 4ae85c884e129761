"""Ground-truth evaluation helpers (benchmarks/eval_synthetic.py) on synthetic inputs."""
import json
import math

import pytest
import torch

from benchmarks import eval_synthetic as ev
from cinenerf_ns.synthetic.cameras import look_at_c2w
from cinenerf_ns.synthetic.generate import RoomConfig, generate_room
from cinenerf_ns.synthetic.ns_transform import GroundTruthNS, NerfstudioTransform


@pytest.fixture(scope="module")
def room():
    return generate_room(RoomConfig(), seed=0)


@pytest.fixture(scope="module")
def gt_ns(room):
    # a generic similarity (rotation about z + shift + scale) as nerfstudio might apply
    a = 0.3
    R = torch.tensor([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]], dtype=torch.float64)
    T = torch.cat([R, torch.tensor([[0.1], [-0.2], [-1.0]], dtype=torch.float64)], 1)
    return GroundTruthNS(room, NerfstudioTransform(T, 0.35))


def _splat_like_means(room, n_per=400):
    """Fake Gaussian centres: points on/in every object plus floor points."""
    pts = [room.object_points(o.name, n_per, seed=i) for i, o in enumerate(room.objects)]
    g = torch.Generator().manual_seed(0)
    floor = (room.interior_lo
             + torch.rand(2000, 3, generator=g, dtype=torch.float64) * (room.interior_hi - room.interior_lo))
    floor[:, 2] = 0.0
    return torch.cat(pts + [floor])


@pytest.mark.parametrize("frame", ["room", "ns"])
def test_perfect_selection_iou_one_and_centroid_error_small(room, gt_ns, frame):
    means = _splat_like_means(room)
    gt = room if frame == "room" else gt_ns
    if frame == "ns":
        means = gt_ns.tf.points_to_ns(means)
    for o in room.objects:
        truth = ev.gaussians_in_object(means, gt, o.name, 1e-6)
        m = ev.selection_metrics(means, truth, gt, o.name, surface_tol=1e-6)
        assert m["iou"] == 1.0 and m["precision"] == 1.0 and m["recall"] == 1.0
        # selected points are uniform in the volume, so their mean approaches the volume centroid
        assert m["centroid_error_frac"] < 0.02
    # wrong object: IoU 0
    a, b = room.objects[0].name, room.objects[1].name
    m = ev.selection_metrics(means, ev.gaussians_in_object(means, gt, a, 1e-6), gt, b, surface_tol=1e-6)
    assert m["iou"] == 0.0 and m["centroid_error"] > 0.3 * (1 if frame == "room" else gt_ns.tf.scale)


def test_half_selection_iou_half(room):
    means = _splat_like_means(room)
    name = room.objects[2].name
    truth = ev.gaussians_in_object(means, room, name, 1e-6)
    idx = truth.nonzero(as_tuple=True)[0]
    sel = torch.zeros_like(truth)
    sel[idx[: len(idx) // 2]] = True
    m = ev.selection_metrics(means, sel, room, name, surface_tol=1e-6)
    assert m["iou"] == pytest.approx(0.5, abs=1 / len(idx))
    assert m["precision"] == 1.0
    empty = ev.selection_metrics(means, torch.zeros_like(truth), room, name)
    assert empty["iou"] == 0.0 and math.isinf(empty["centroid_error"])
    with pytest.raises(ValueError, match="entries"):
        ev.selection_metrics(means, truth[:-1], room, name)


def test_straight_path_clearance_matches_geometry(room, gt_ns):
    # a path along x at the height of nothing tall? use z = 2.3 (above all furniture, below ceiling 2.5)
    xs = torch.linspace(-2.5, 2.5, 101, dtype=torch.float64)
    p = torch.stack([xs, torch.zeros_like(xs), torch.full_like(xs, 2.3)], -1)
    c = ev.clearance_along(p, room, camera_radius=0.05)
    # nearest surface: the ceiling (0.2 away) or an end wall (0.5 away at the ends), lamp top is < 1.9
    expected = torch.minimum(torch.full_like(xs, 0.2), 3.0 - xs.abs()) - 0.05
    assert torch.allclose(c, expected, atol=1e-12)
    assert (ev.clearance_lower_bound(p, c) <= torch.minimum(c[1:], c[:-1]) + 1e-12).all()
    # in nerfstudio units everything scales
    c_ns = ev.clearance_along(gt_ns.tf.points_to_ns(p), gt_ns, camera_radius=0.05 * gt_ns.tf.scale)
    assert torch.allclose(c_ns, c * gt_ns.tf.scale, atol=1e-12)


def test_path_through_object_is_unsafe(room):
    name = room.objects[0].name
    c = room.object_centres()[name]
    p = torch.stack([c + torch.tensor([-2.0, 0, 0], dtype=torch.float64) * s for s in torch.linspace(1, -1, 50)])
    p[:, 2] = c[2]
    m = ev.shot_metrics(torch.linspace(0, 5, 50), _c2w_along(p, c + torch.tensor([0, 0, 5.0], dtype=torch.float64)),
                        room, 0.03)
    assert not m["safe"] and m["min_clearance"] < 0


def test_segment_bound_is_a_true_lower_bound(room):
    g = torch.Generator().manual_seed(1)
    for _ in range(20):
        a = room.interior_lo + torch.rand(3, generator=g, dtype=torch.float64) * (room.interior_hi - room.interior_lo)
        b = room.interior_lo + torch.rand(3, generator=g, dtype=torch.float64) * (room.interior_hi - room.interior_lo)
        ends = torch.stack([a, b])
        c = ev.clearance_along(ends, room, 0.0)
        bound = ev.clearance_lower_bound(ends, c)[0]
        dense = torch.stack([a + s * (b - a) for s in torch.linspace(0, 1, 400, dtype=torch.float64)])
        assert room.sdf(dense).min() >= bound - 1e-12


def _c2w_along(p, target):
    return torch.stack([torch.tensor(look_at_c2w(q.numpy(), target.numpy())) for q in p])


def test_look_at_errors(room):
    target = room.object_centres()[room.objects[0].name]
    p = torch.tensor([[0.0, 0.0, 1.5], [1.0, 1.0, 1.2]], dtype=torch.float64)
    c2w = _c2w_along(p, target)
    assert ev.look_at_errors_deg(c2w, target).max() < 1e-6
    # rotate the first camera by 5 degrees about its up axis
    a = math.radians(5)
    Ry = torch.tensor([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]], dtype=torch.float64)
    c2w[0, :3, :3] = c2w[0, :3, :3] @ Ry
    err = ev.look_at_errors_deg(c2w, target)
    assert err[0].item() == pytest.approx(5.0, abs=1e-9) and err[1] < 1e-6


def test_camera_path_roundtrip_cli_and_plots(room, tmp_path):
    room.save(tmp_path / "geometry.json")
    # a transforms.json is not needed when the dataparser transform is given
    (tmp_path / "dp.json").write_text(json.dumps({"transform": torch.eye(4)[:3].tolist(), "scale": 1.0}))
    target = room.object_centres()["floor lamp"]
    xs = torch.linspace(-2.0, 2.0, 40, dtype=torch.float64)
    p = torch.stack([xs, torch.full_like(xs, 0.1), torch.full_like(xs, 2.2)], -1)
    c2w = _c2w_along(p, target)
    cp = {"fps": 10, "seconds": 4.0,
          "camera_path": [{"camera_to_world": m.reshape(-1).tolist(), "fov": 60, "aspect": 1.33} for m in c2w]}
    (tmp_path / "shot0.json").write_text(json.dumps(cp))
    times, c2w_read = ev.read_camera_path(tmp_path / "shot0.json")
    assert torch.allclose(c2w_read, c2w) and times[1].item() == pytest.approx(0.1)
    res = ev.main(["--dataset", str(tmp_path), "--dataparser-transforms", str(tmp_path / "dp.json"),
                   "--camera-paths", str(tmp_path / "shot0.json"), "--look-at", "floor lamp",
                   "--go-to", "red armchair", "--out", str(tmp_path / "out")])
    row = res["rows"][0]
    assert row["look_at_error_max_deg"] < 1e-6
    assert row["min_clearance"] == pytest.approx(float(room.sdf(p).min()) - 0.03)
    assert row["final_surface_distance"] > 0
    for f in ("topdown.png", "clearance.png", "shots.md"):
        assert (tmp_path / "out" / f).stat().st_size > 0
    assert "| shot |" in (tmp_path / "out" / "shots.md").read_text()
    with pytest.raises(SystemExit, match="unknown object"):
        ev.main(["--dataset", str(tmp_path), "--dataparser-transforms", str(tmp_path / "dp.json"), "--look-at", "piano",
                 "--out", str(tmp_path / "o2")])


def test_topdown_in_ns_frame(gt_ns, tmp_path):
    path = gt_ns.tf.points_to_ns(torch.tensor([[-2.0, -1.0, 1.0], [2.0, 1.5, 1.0]], dtype=torch.float64))
    png = ev.plot_topdown(gt_ns, {"a": path}, tmp_path / "t.png")
    assert png.stat().st_size > 1000
    assert ev.markdown_table([]) == "(no rows)\n"
    t = ev.markdown_table([{"a": 1, "b": 0.5, "c": "x", "d": torch.zeros(3)}])
    assert t.splitlines()[0] == "| a | b | c |"


def test_inside_room_separates_the_interior_from_the_free_space_outside_the_slabs(room, gt_ns):
    """Beyond a wall slab the SDF is positive again (free space outside the building), so a positive true clearance
    alone cannot tell a camera inside the room from one outside it: inside_room can (eval_room's success needs both)."""
    g = torch.Generator().manual_seed(1)
    lo, hi = room.interior_lo.double(), room.interior_hi.double()
    p = lo - 1.0 + torch.rand(4000, 3, generator=g, dtype=torch.float64) * (hi - lo + 2.0)  # the room and around it
    ref = torch.tensor([all(lo[k] <= q[k] <= hi[k] for k in range(3)) for q in p.tolist()])
    assert torch.equal(gt_ns.inside_room(gt_ns.tf.points_to_ns(p)), ref)
    assert ref.any() and (~ref).any()
    out = torch.tensor([[hi[0] + 0.5, 0.0, 1.0]], dtype=torch.float64)  # 0.3 m beyond the 0.2 m wall slab
    out_ns = gt_ns.tf.points_to_ns(out)
    assert float(gt_ns.sdf(out_ns)[0]) > 0 and not bool(gt_ns.inside_room(out_ns)[0])
