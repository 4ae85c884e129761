"""Renderer: culled cast equals brute force; depth lies on the surface; labels match geometry; cameras free."""
import math

import pytest
import torch

from cinenerf_ns.synthetic.cameras import CameraSamplingConfig, look_at_c2w, sample_cameras
from cinenerf_ns.synthetic.generate import RoomConfig, generate_room
from cinenerf_ns.synthetic.render import Intrinsics, RoomRenderer, camera_rays
from cinenerf_ns.synthetic.room import BACKGROUND


@pytest.fixture(scope="module")
def setup():
    room = generate_room(RoomConfig(), seed=1)
    c2w, what = sample_cameras(room, 8, seed=1)
    return room, c2w, what, RoomRenderer(room, dtype=torch.float64)


def test_cameras_in_free_space_looking_at_targets(setup):
    room, c2w, what, _ = setup
    cfg = CameraSamplingConfig()
    pos = c2w[:, :3, 3]
    assert (room.sdf(pos) >= cfg.clearance - 1e-9).all()
    assert ((pos >= room.interior_lo) & (pos <= room.interior_hi)).all()
    R = c2w[:, :3, :3]
    assert torch.allclose(R.transpose(1, 2) @ R, torch.eye(3, dtype=R.dtype).expand(8, 3, 3), atol=1e-9)
    assert torch.allclose(torch.linalg.det(R), torch.ones(8, dtype=R.dtype))
    centres = room.object_centres()
    for i, w in enumerate(what):
        if w in centres:
            v = centres[w] - pos[i]
            fwd = -R[i, :, 2]
            ang = math.degrees(math.acos((v @ fwd / v.norm()).clamp(-1, 1).item()))
            assert ang < 15.0  # target jitter is 0.15 m at >= 0.8 m


def _tile_ids(height: int, width: int) -> torch.Tensor:
    """[height * width] the 16x16 tile of every pixel, row-major (the renderer's culling tiles)."""
    vv, uu = torch.meshgrid(torch.arange(height), torch.arange(width), indexing="ij")
    return ((vv // 16) * (width // 16) + uu // 16).reshape(-1)


def test_culled_cast_equals_brute_force(setup):
    room, c2w, _, r = setup
    intr = Intrinsics.from_fov(64, 48, 75)
    for i in range(3):
        o, d, _ = camera_rays(c2w[i], intr)
        o, d = o.reshape(-1, 3), d.reshape(-1, 3)
        tile = _tile_ids(48, 64)
        t1, p1, n1 = r.cast(o, d, tile)
        t0, p0, n0 = r.cast_reference(o, d)
        assert torch.equal(p1, p0)
        assert torch.allclose(t1, t0)
        assert torch.allclose(n1, n0, atol=1e-9)


def test_culled_cast_float32_matches_brute_force():
    room = generate_room(RoomConfig(), seed=4)
    c2w, _ = sample_cameras(room, 4, seed=4)
    r = RoomRenderer(room)  # float32, as the dataset writer uses it
    intr = Intrinsics.from_fov(96, 72, 75)
    for i in range(4):
        o, d, _ = camera_rays(c2w[i].float(), intr)
        o, d = o.reshape(-1, 3), d.reshape(-1, 3)
        tile = _tile_ids(72, 96)
        t1, p1, _ = r.cast(o, d, tile)
        t0, p0, _ = r.cast_reference(o, d)
        assert torch.equal(t1, t0)
        assert torch.equal(r.labels[p1], r.labels[p0])


def test_depth_on_surface_and_labels_match_geometry(setup):
    room, c2w, _, r = setup
    intr = Intrinsics.from_fov(64, 48, 75)
    for i in range(len(c2w)):
        out = r.render(c2w[i], intr)
        o, d, cos = camera_rays(c2w[i], intr)
        dist = out["distance"]
        assert torch.isfinite(dist).all()  # closed room: every ray hits something
        pts = o + dist[..., None] * d  # [H,W,3]
        assert room.sdf(pts).abs().max().item() < 1e-9
        assert torch.allclose(out["depth"], dist * cos)
        # label = label of the part the point lies on (the part with the smallest |sdf|)
        ps = room.part_sdf(pts.reshape(-1, 3)).abs()
        near = ps.argmin(-1)
        labels = torch.tensor([room.parts[k].label for k in near.tolist()])
        ok = ps.min(-1).values < 1e-9
        assert torch.equal(out["label"].reshape(-1)[ok], labels[ok])
        # just in front of the hit is free space
        before = o + (dist - 1e-3)[..., None] * d
        assert (room.sdf(before) > 0).all()
        assert out["rgb"].shape == (48, 64, 3) and 0 <= out["rgb"].min() and out["rgb"].max() <= 1


def test_every_object_is_seen_and_labels_complete():
    room = generate_room(RoomConfig(), seed=2)
    c2w, _ = sample_cameras(room, 24, seed=2)
    r = RoomRenderer(room)
    intr = Intrinsics.from_fov(64, 48, 75)
    seen = set()
    for i in range(len(c2w)):
        lab = r.render(c2w[i], intr)["label"]
        assert (lab != BACKGROUND).all()
        seen |= set(lab.unique().tolist())
    assert set(room.labels) - {BACKGROUND} <= seen


def test_no_ceiling_gives_background_label():
    room = generate_room(RoomConfig(ceiling=False), seed=0)
    assert 3 not in room.labels
    c2w = torch.tensor(look_at_c2w([0.0, 0.0, 1.2], [0.5, 0.0, 3.0]))
    out = RoomRenderer(room).render(c2w, Intrinsics.from_fov(32, 24, 60))
    assert (out["label"] == BACKGROUND).any()
    assert torch.isinf(out["distance"][out["label"] == BACKGROUND]).all()


def test_supersampling_keeps_labels_and_shapes():
    room = generate_room(RoomConfig(), seed=0)
    c2w, _ = sample_cameras(room, 1, seed=0)
    r = RoomRenderer(room)
    out = r.render(c2w[0], Intrinsics.from_fov(40, 30, 75), supersample=3)
    ref = r.render(c2w[0], Intrinsics.from_fov(40, 30, 75), supersample=1)
    assert out["rgb"].shape == (30, 40, 3)
    assert torch.equal(out["label"], ref["label"])  # odd s: the centre sub-sample is the pixel centre
    assert (out["rgb"] - ref["rgb"]).abs().mean() < 0.05
