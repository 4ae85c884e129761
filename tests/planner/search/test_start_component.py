"""Which free component random starts come from without a start region (planner.preferred_component)."""
from __future__ import annotations

import functools

import numpy as np
import torch
from _shot_scenes import _discs
from hypothesis import given, settings, strategies as st
from scipy import ndimage

from cinenerf_ns.planner.geometry import clearance_queries
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.search import starts as starts_module
from cinenerf_ns.planner.shots.planner import ENCLOSED_COMPONENT_FRACTION, Planner, PlannerConfig, preferred_component


def _reference(labels: np.ndarray) -> int:
    """preferred_component by its definition, voxel by voxel."""
    X, Y, Z = labels.shape
    size, touches = {}, set()
    for i in range(X):
        for j in range(Y):
            for k in range(Z):
                c = int(labels[i, j, k])
                if c == 0:
                    continue
                size[c] = size.get(c, 0) + 1
                if i in (0, X - 1) or j in (0, Y - 1) or k in (0, Z - 1):
                    touches.add(c)
    total = sum(size.values())
    enclosed = {c: n for c, n in size.items() if c not in touches}
    if enclosed:
        best = max(enclosed.values())
        if best >= ENCLOSED_COMPONENT_FRACTION * total:
            return min(c for c, n in enclosed.items() if n == best)  # argmax: the first of equals
    best = max(size.values())
    return min(c for c, n in size.items() if n == best)


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 10_000), st.integers(3, 9), st.floats(0.2, 0.7), st.booleans())
def test_preferred_component_matches_its_definition(seed, n, density, add_box):
    rng = np.random.default_rng(seed)
    occ = rng.random((n, n + 1, n + 2)) < density
    if add_box and n >= 5:  # a closed shell somewhere: an enclosed component of some size
        occ[1:-1, 1:-1, 1:-1] = False
        a, b = 1, n - 2
        occ[a:b + 1, a:b + 1, a] = occ[a:b + 1, a:b + 1, b] = True
        occ[a:b + 1, a, a:b + 1] = occ[a:b + 1, b, a:b + 1] = True
        occ[a, a:b + 1, a:b + 1] = occ[b, a:b + 1, a:b + 1] = True
    labels, _ = ndimage.label(~occ, structure=np.ones((3, 3, 3), dtype=bool))
    if labels.max() == 0:
        return
    counts = np.bincount(labels.ravel())
    counts[0] = 0
    assert preferred_component(labels, counts) == _reference(labels)


def _closed_room(w=2.0, h=0.5, spacing=0.04):
    """A flat closed room [-w/2, w/2]^2 x [0, h]: floor, ceiling and four walls of flat Gaussians (no gaps)."""
    g = np.arange(-w / 2, w / 2 + 1e-9, spacing)
    gz = np.arange(0.0, h + 1e-9, spacing)
    parts = []
    for z, nz in ((0.0, 1.0), (h, -1.0)):
        fx, fy = np.meshgrid(g, g)
        parts.append(_discs(np.stack([fx.ravel(), fy.ravel(), np.full(fx.size, z)], 1),
                            np.tile([0.0, 0, nz], (fx.size, 1)), spacing))
    for axis in (0, 1):
        for s_ in (-1.0, 1.0):
            a, b = np.meshgrid(g, gz)
            p = np.zeros((a.size, 3))
            p[:, axis] = s_ * w / 2
            p[:, 1 - axis] = a.ravel()
            p[:, 2] = b.ravel()
            nrm = np.zeros((a.size, 3))
            nrm[:, axis] = -s_
            parts.append(_discs(p, nrm, spacing))
    t = lambda a: torch.as_tensor(np.concatenate(a), dtype=torch.float64)  # noqa: E731
    return EllipsoidScene(t([q[0] for q in parts]), t([q[1] for q in parts]), t([q[2] for q in parts]),
                          torch.ones(sum(len(q[0]) for q in parts), dtype=torch.float64), 0.03)


def test_random_starts_in_a_closed_room_without_a_start_region_are_inside_it():
    """A flat closed room: the free shell between its slabs and the padded planning box holds more voxels than the
    room, so "the largest component" would start shots outside the walls; the enclosed interior is taken instead."""
    w, h = 2.0, 0.5
    pl = Planner(_closed_room(w, h), PlannerConfig(grid_resolution=48))
    prep = pl.prepare()
    labels = prep.astar_grid.labels
    counts = np.bincount(labels.ravel())
    counts[0] = 0
    comp = pl.main_component()
    assert comp != int(np.argmax(counts))  # the premise: the outside shell is the largest
    gen = torch.Generator().manual_seed(0)
    starts = starts_module.random_starts(pl.space, 20, gen, np.array([0.5, 0.0, 0.25])).numpy()
    assert (np.abs(starts[:, :2]) < w / 2).all() and (starts[:, 2] > 0).all() and (starts[:, 2] < h).all()
    shot = pl.plan(np.array([0.6, 0.5, 0.25]), np.array([-0.5, -0.5, 0.1]), seed=1)[0]
    assert (np.abs(shot.positions[:, :2]) < w / 2).all() and (shot.positions[:, 2] > 0).all()
    assert (shot.positions[:, 2] < h).all()


def test_random_starts_with_the_cached_blocked_mask_are_those_of_both_masks():
    """starts.random_starts passes one cached mask (occupied | outside the main component); the starts are those that
    sample_free_starts draws from the occupancy grid and the reachable mask, and the mask is built once."""
    from cinenerf_ns.planner.search.goal import sample_free_starts
    from cinenerf_ns.planner.search.starts import start_blocked

    pl = Planner(_closed_room(2.0, 0.5), PlannerConfig(grid_resolution=48))
    prep = pl.prepare()
    look = np.array([0.5, 0.0, 0.25])
    for seed in range(4):
        got = starts_module.random_starts(pl.space, 6, torch.Generator().manual_seed(seed), look)
        want = sample_free_starts(
            6, pl.scene, prep.index, prep.grid, generator=torch.Generator().manual_seed(seed),
            reachable=prep.astar_grid.labels == pl.main_component(),
            clearance_fn=functools.partial(clearance_queries.free_test, pl.space),
            away_from=look, away_fraction=pl.config.start_look_distance)
        assert torch.equal(got, want)
    assert start_blocked(pl.space) is start_blocked(pl.space)
    occ = np.asarray(prep.grid.occupied.cpu().numpy() if torch.is_tensor(prep.grid.occupied) else prep.grid.occupied)
    assert np.array_equal(start_blocked(pl.space), occ | (prep.astar_grid.labels != pl.main_component()))
