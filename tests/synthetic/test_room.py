"""Room generation: layouts, ground-truth objects, SDF, save/load."""
import pytest
import torch

from cinenerf_ns.synthetic import furniture
from cinenerf_ns.synthetic.generate import LayoutError, RoomConfig, generate_room
from cinenerf_ns.synthetic.room import FIRST_OBJECT_LABEL, Room, room_sdf


@pytest.fixture(scope="module")
def room():
    return generate_room(RoomConfig(), seed=0)


def test_same_seed_same_room_different_seed_different_layout():
    a = generate_room(RoomConfig(), 0).to_dict()
    b = generate_room(RoomConfig(), 0).to_dict()
    assert a == b
    layouts = set()
    for seed in range(4):
        r = generate_room(RoomConfig(), seed)
        layouts.add(tuple((o.name, round(r.object_centre(o.name)[0].item(), 3)) for o in r.objects))
    assert len(layouts) == 4


def test_objects_named_labelled_and_required_present(room):
    names = [o.name for o in room.objects]
    assert len(names) == len(set(names)) == 8
    assert {"red armchair", "floor lamp"} <= set(names)
    assert all(n in furniture.CATALOGUE for n in names)
    labels = room.labels
    assert labels[1] == "floor" and labels[2] == "wall" and labels[3] == "ceiling"
    assert sorted(o.label for o in room.objects) == list(range(FIRST_OBJECT_LABEL, FIRST_OBJECT_LABEL + 8))
    for o in room.objects:
        assert all(room.parts[i].label == o.label and room.parts[i].object == o.name for i in o.part_ids)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_objects_disjoint_with_gaps_on_floor_inside_room(seed):
    cfg = RoomConfig()
    r = generate_room(cfg, seed)
    for o in r.objects:
        pts = r.object_points(o.name, 3000, seed=1)
        lo, hi = r.object_aabb(o.name)
        assert lo[2].item() == pytest.approx(0.0, abs=1e-9)  # stands on the floor
        assert (lo[:2] >= r.interior_lo[:2] + cfg.wall_margin - 1e-9).all()
        assert (hi <= r.interior_hi).all()
        for other in r.objects:
            if other.name == o.name:
                continue
            # every point of o is at least min_gap away from other (footprints are separated by it)
            assert r.object_sdf(other.name, pts).min().item() >= cfg.min_gap - 1e-9


@pytest.mark.parametrize("turn_seed", [0, 1])
def test_parts_of_an_object_do_not_overlap(turn_seed):
    from cinenerf_ns.synthetic import primitives as prim

    room = generate_room(RoomConfig(num_objects=len(furniture.CATALOGUE)), seed=turn_seed)  # every template
    assert {o.name for o in room.objects} == set(furniture.CATALOGUE)
    for o in room.objects:
        for i in o.part_ids:
            pts = prim.sample_inside(room.parts[i].kind, room.parts[i].params, 2000, torch.Generator().manual_seed(i))
            others = [j for j in o.part_ids if j != i]
            if others:
                assert room.part_sdf(pts, others).min().item() >= -1e-9, (o.name, i)


def test_object_points_inside_and_centre_is_their_mean(room):
    for o in room.objects:
        pts = room.object_points(o.name, 20000, seed=3)
        assert (room.object_sdf(o.name, pts) <= 1e-9).all()
        lo, hi = room.object_aabb(o.name)
        assert torch.allclose(pts.mean(0), room.object_centre(o.name), atol=0.02 * (hi - lo).norm().item())


def test_sdf_is_min_over_parts_and_walls_exact(room):
    g = torch.Generator().manual_seed(0)
    pts = (room.interior_lo
           + torch.rand(500, 3, generator=g, dtype=torch.float64) * (room.interior_hi - room.interior_lo))
    d = room_sdf(room, pts)
    assert torch.equal(d, room.part_sdf(pts).min(-1).values)
    # distance to the walls/floor/ceiling alone is the distance to the interior box faces
    wall_d = torch.minimum(pts - room.interior_lo, room.interior_hi - pts).min(-1).values
    assert (d <= wall_d + 1e-12).all()
    structure = [i for i, p in enumerate(room.parts) if p.label < FIRST_OBJECT_LABEL]
    assert torch.allclose(room.part_sdf(pts, structure).min(-1).values, wall_d)
    assert room.sdf(pts.reshape(25, 20, 3)).shape == (25, 20)


def test_save_load_roundtrip(room, tmp_path):
    room.save(tmp_path / "geometry.json")
    r2 = Room.load(tmp_path)
    assert r2.to_dict() == room.to_dict()
    with pytest.raises(FileNotFoundError, match="geometry.json"):
        Room.load(tmp_path / "nope")
    with pytest.raises(KeyError, match="no object named"):
        room.object("grand piano")


def test_impossible_layout_is_a_clear_error():
    with pytest.raises(LayoutError, match="could not place"):
        generate_room(RoomConfig(width=2.0, depth=2.0, num_objects=10, max_restarts=3), 0)
    with pytest.raises(ValueError, match="not in the catalogue"):
        generate_room(RoomConfig(required=("piano",)), 0)


def test_walls_of_a_long_room_bound_its_own_sides():
    """A 4 x 1 room (not square, unlike the bundled ones): the walls at x = +-W/2 are D x H slabs, those at y = +-D/2
    W x H (procedural_room once swapped these two areas; structure_parts has them right). Every wall's inner face
    lies on the interior box and the corners are closed."""
    from cinenerf_ns.synthetic.room import SLAB, structure_parts

    w, d, h = 4.0, 1.0, 2.5
    room = Room(w, d, h, True, structure_parts(w, d, h, True), [])
    walls = [p for p in room.parts if p.object == "wall"]
    x_walls = [p for p in walls if abs(abs(p.params["centre"][0]) - (w / 2 + SLAB / 2)) < 1e-12]
    y_walls = [p for p in walls if abs(abs(p.params["centre"][1]) - (d / 2 + SLAB / 2)) < 1e-12]
    assert len(x_walls) == len(y_walls) == 2
    for p in x_walls:  # D x H (+ the slabs at the corners, floor and ceiling)
        assert p.params["half"][:2] == [SLAB / 2, d / 2 + SLAB]
    for p in y_walls:  # W x H
        assert p.params["half"][:2] == [w / 2, SLAB / 2]
    g = torch.linspace(-0.49, 0.49, 9, dtype=torch.float64)
    z = torch.full_like(g, 1.0)
    faces = torch.cat([torch.stack([torch.full_like(g, s * w / 2), g * d, z], -1) for s in (-1, 1)]
                      + [torch.stack([g * w, torch.full_like(g, s * d / 2), z], -1) for s in (-1, 1)])
    assert room.sdf(faces).abs().max() < 1e-9  # on every wall's inner face
    corners = torch.tensor([[s * (w / 2 + SLAB / 2), t * (d / 2 + SLAB / 2), 1.0] for s in (-1, 1) for t in (-1, 1)],
                           dtype=torch.float64)
    assert (room.sdf(corners) < 0).all()  # closed corners: inside a wall
    inside = torch.tensor([[1.9, 0.0, 1.0], [0.0, 0.45, 1.0]], dtype=torch.float64)
    assert torch.allclose(room.sdf(inside), torch.tensor([0.1, 0.05], dtype=torch.float64), atol=1e-9)
