"""benchmarks/scene_families.py: families and given starts of the planner benchmarks."""
from __future__ import annotations

import numpy as np
import pytest

from benchmarks.scene_families import GIVEN_CLEAR, GIVEN_FROM_GOAL, given_starts, load_family
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig


@pytest.mark.parametrize("family", ["procedural", "blobs"])
def test_given_starts_keep_their_distances_and_plan(family):
    fam = load_family(family, 20_000, 0)
    pl = Planner(fam.scene, PlannerConfig(start_region=fam.start_region, up=fam.up, candidate_workers=0))
    pl.prepare()
    rng = np.random.default_rng(0)
    reqs = [fam.targets(rng, *fam.start_region) for _ in range(3)]
    starts = given_starts(pl, [g for g, _ in reqs], fam.start_region, seed=0)
    means = fam.scene.means.double().numpy()
    for (g, la), s in zip(reqs, starts):
        assert np.linalg.norm(s - g) >= GIVEN_FROM_GOAL
        assert np.linalg.norm(means - s, axis=1).min() >= GIVEN_CLEAR
        shot = pl.plan(g, la, start=s)[0]
        assert np.allclose(shot.positions[0], s) and shot.safety["safe"] and "start_check_ms" in shot.timings


def test_unknown_family_is_refused():
    with pytest.raises(SystemExit, match="expected"):
        load_family("cubes", 1000, 0)


def test_grove_family_carries_reference_searched_pairs(monkeypatch):
    monkeypatch.setattr("benchmarks.scene_families.GROVE_SPACING", 0.06)  # a coarser reference: a quicker test
    fam = load_family("grove", 20_000, 0, n_pairs=3)
    assert fam.kind == "grove" and fam.start_region is None and fam.up == (0.0, 0.0, 1.0)
    assert len(fam.pairs) == 3 and "pairs joined by the reference grid" in fam.description
    g, la = fam.targets(np.random.default_rng(0), None, None)
    assert any(np.array_equal(g, p.goal) and np.array_equal(la, p.look_at) for p in fam.pairs)


def test_grove_variant_spec_is_checked():
    with pytest.raises(SystemExit, match="grove:BACKGROUND:FLOATERS"):
        load_family("grove:lots", 20_000, 0, n_pairs=1)
    with pytest.raises(SystemExit, match="floater_fraction"):
        load_family("grove:0.03:0.9", 20_000, 0, n_pairs=1)


def test_file_families_load_any_scene_spec(tmp_path):
    """scene:SPEC (and ply: / npz:) go through scenes.load_scene: every kind a command reads; a missing file exits
    with the loader's message."""
    from cinenerf_ns.planner.scene.ply import write_splat_ply
    from cinenerf_ns.planner.scene.procedural import procedural_room

    room = procedural_room(2000, seed=0)
    ply = write_splat_ply(tmp_path / "r.ply", room.means, room.quats, room.log_scales, room.opacity_logits)
    a, b = load_family("scene:procedural:2000:0", 0, 0), load_family(f"ply:{ply}", 0, 0)
    assert a.kind == b.kind == "file" and len(a.scene) == len(b.scene) > 0
    assert a.start_region is not None and b.start_region is None  # a .ply has no training cameras
    with pytest.raises(SystemExit, match="scene not found"):
        load_family(f"scene:{tmp_path / 'nope.npz'}", 0, 0)
