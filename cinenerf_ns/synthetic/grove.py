"""An open outdoor scene family: a grove of thin trees on a ground plane, with faint floaters in the air and
a far background shell, z up, no training cameras. What real outdoor captures look like to the planner, and what a
planning region from the extreme Gaussians gets wrong.

    ground     discs on z = 0 over [-GROUND, GROUND]^2 (jittered off the plane, as a trained splat's surfaces)
    trunks     ``n_trees`` thin vertical cylinders (radius 0.025-0.06, height 1.1-1.6) on a jittered 6 x 6 grid
               over [-GROVE, GROVE]^2 (spacing ~0.7: gaps of 0.3-0.6 between trunks)
    canopies   an ellipsoidal ball of Gaussians on each trunk's top (horizontal radius 0.25-0.4, vertical 0.2-0.3)
    rocks      ``n_rocks`` half-buried round blobs on the ground (radius 0.08-0.25)
    floaters   ``floater_fraction`` of the Gaussians: small (sigma 0.003-0.015), faint (opacity 0.06-0.35), anywhere
               in the air above the grove (z 0.05-2.2): a capture's noise
    background ``background_fraction``: huge Gaussians (sigma 0.3-0.9, opaque) on a shell of radius 6-7.5 around the
               grove, 70% in a band around the horizon (far scenery), 30% on the sky dome: what a capture
               reconstructs as large splats far away

``grove_pairs`` draws seeded start / go-to pairs in the free air between the trunks (z 0.25-0.8, below the canopies)
and decides each pair's reachability with a fine-grid reference search (``reference_search``): A* over the voxel
centres of a fine grid (``spacing``) whose free voxels have exact clearance (float64, the planner's exact distance)
>= spacing * sqrt(3) / 2, so every step of a reference path is collision-free (a point of a step lies within
spacing * sqrt(3) / 2 of one of its ends); its length is the reference path length.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np
import torch

from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.procedural import _quat_from_z_to, _sample_cylinder_surface
from cinenerf_ns.planner.scene.splat_params import SplatParams
from cinenerf_ns.synthetic.blobs import _random_quats

GROVE = 2.1  # trunks within [-GROVE, GROVE]^2
GROUND = 3.0  # the ground plane covers [-GROUND, GROUND]^2
PAIR_Z = (0.25, 0.8)  # pairs fly between the trunks, below the canopies
PAIR_XY = 2.3  # pairs within [-PAIR_XY, PAIR_XY]^2
MIN_PAIR_DISTANCE = 1.0  # a pair's start and go-to are at least this far apart


@dataclass
class Tree:
    base: np.ndarray  # [3] trunk base on the ground
    radius: float  # trunk radius
    height: float  # trunk height (the canopy's centre)
    canopy: np.ndarray  # [3] canopy semi-axes (x, y, z)


@dataclass
class GroveScene:
    splat: SplatParams  # the Gaussians (no colour)
    kind: np.ndarray  # [N] int8: 0 ground, 1 trunk, 2 canopy, 3 rock, 4 floater, 5 background
    trees: List[Tree] = field(default_factory=list)
    up: tuple = (0.0, 0.0, 1.0)

    KINDS = ("ground", "trunk", "canopy", "rock", "floater", "background")

    @property
    def content_lo(self) -> np.ndarray:
        """[3] the box the grove's content fills (ground to the highest canopy top)."""
        return np.array([-GROUND, -GROUND, 0.0])

    @property
    def content_hi(self) -> np.ndarray:
        top = max(t.height + t.canopy[2] for t in self.trees)
        return np.array([GROUND, GROUND, top])

    def write_ply(self, path) -> "object":
        """The scene as a plain 3DGS .ply (no training cameras: what a user brings from elsewhere)."""
        from cinenerf_ns.planner.scene.ply import write_splat_ply

        s = self.splat
        return write_splat_ply(path, s.means, s.quats_wxyz, s.log_scales, s.opacity_logits)


def _place_trees(n_trees: int, rng: np.random.Generator) -> List[Tree]:
    cols = int(math.ceil(math.sqrt(n_trees)))
    rows = int(math.ceil(n_trees / cols))
    cell = 2 * GROVE / max(cols, rows)
    trees = []
    for slot in rng.permutation(rows * cols)[:n_trees]:
        r, c = divmod(int(slot), cols)
        x = -GROVE + (c + 0.5) * cell + rng.uniform(-0.2, 0.2) * cell
        y = -GROVE + (r + 0.5) * cell + rng.uniform(-0.2, 0.2) * cell
        h = rng.uniform(1.1, 1.6)
        trees.append(Tree(np.array([x, y, 0.0]), float(rng.uniform(0.025, 0.06)), float(h),
                          np.array([*(rng.uniform(0.25, 0.4, 1).repeat(2) * rng.uniform(0.85, 1.0, 2)),
                                    rng.uniform(0.2, 0.3)])))
    return trees


def grove_scene(n_gaussians: int = 200_000, seed: int = 0, n_trees: int = 36, n_rocks: int = 12,
                floater_fraction: float = 0.03, background_fraction: float = 0.03) -> GroveScene:
    """A seeded grove of exactly ``n_gaussians`` Gaussians (see the module docstring)."""
    if n_gaussians < 1000:
        raise InvalidInputError(f"n_gaussians must be >= 1000, got {n_gaussians}")
    if not 1 <= n_trees <= 100:
        raise InvalidInputError(f"n_trees must be in [1, 100], got {n_trees}")
    for name, v in (("floater_fraction", floater_fraction), ("background_fraction", background_fraction)):
        if not 0.0 <= v <= 0.2:
            raise InvalidInputError(f"{name} must be in [0, 0.2], got {v}")
    n_float, n_back = (int(round(f * n_gaussians)) for f in (floater_fraction, background_fraction))
    n_solid = n_gaussians - n_float - n_back
    rng = np.random.default_rng(seed)
    trees = _place_trees(n_trees, rng)
    # surface areas decide the counts: ground, trunks (x2 density), canopies, rocks
    rocks = [(np.array([*rng.uniform(-GROUND + 0.3, GROUND - 0.3, 2), 0.0]), float(rng.uniform(0.08, 0.25)))
             for _ in range(n_rocks)]
    a_ground = (2 * GROUND) ** 2
    a_trunk = [2 * 2 * np.pi * t.radius * t.height for t in trees]
    a_canopy = [4 * np.pi * (t.canopy.prod() ** (2 / 3)) for t in trees]
    a_rock = [2 * np.pi * r * r for _, r in rocks]
    areas = np.array([a_ground, *a_trunk, *a_canopy, *a_rock])
    counts = rng.multinomial(n_solid, areas / areas.sum())
    means, quats, scales, kind = [], [], [], []

    def discs(p, normals, area, count, k, thin=0.1):
        sp = math.sqrt(area / max(count, 1))
        s = 0.6 * sp * rng.uniform(0.7, 1.3, len(p))
        means.append(p)
        scales.append(np.stack([s, s * rng.uniform(0.5, 1.0, len(p)), thin * s], 1))
        quats.append(_quat_from_z_to(normals, rng))
        kind.append(np.full(len(p), k, dtype=np.int8))

    c = counts[0]
    p = np.stack([rng.uniform(-GROUND, GROUND, c), rng.uniform(-GROUND, GROUND, c), rng.normal(0, 0.004, c)], 1)
    discs(p, np.tile([0.0, 0.0, 1.0], (c, 1)), a_ground, c, 0)
    for t, c, a in zip(trees, counts[1:1 + n_trees], a_trunk):
        p, nrm = _sample_cylinder_surface(t.base + [0, 0, t.height / 2], t.radius, t.height, c, rng)
        discs(p, nrm, a / 2, c, 1)
    for t, c, a in zip(trees, counts[1 + n_trees:1 + 2 * n_trees], a_canopy):
        d = rng.normal(size=(c, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        shell = rng.uniform(0, 1, c) < 0.7
        rad = np.where(shell, 1 + rng.normal(0, 0.05, c), rng.uniform(0, 1, c) ** (1 / 3))
        p = t.base + [0, 0, t.height] + d * rad[:, None] * t.canopy
        sp = math.sqrt(a / max(c, 1))
        means.append(p)
        scales.append((0.8 * sp * np.exp(rng.normal(0, 0.3, c)))[:, None] * rng.uniform(0.4, 1.0, (c, 3)))
        quats.append(_random_quats(c, rng))
        kind.append(np.full(c, 2, dtype=np.int8))
    for (ctr, r), c, a in zip(rocks, counts[1 + 2 * n_trees:], a_rock):
        d = rng.normal(size=(c, 3))
        d[:, 2] = np.abs(d[:, 2])  # the upper half: the rest is under the ground
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        discs(ctr + r * d * (1 + rng.normal(0, 0.03, (c, 1))), d, a, c, 3, thin=0.3)
    # floaters: small and faint, anywhere in the air above the grove
    p = np.stack([rng.uniform(-GROUND, GROUND, n_float), rng.uniform(-GROUND, GROUND, n_float),
                  rng.uniform(0.05, 2.2, n_float)], 1)
    means.append(p)
    scales.append(np.exp(rng.uniform(np.log(0.003), np.log(0.015), (n_float, 1))) * rng.uniform(0.5, 1.0, (n_float, 3)))
    quats.append(_random_quats(n_float, rng))
    kind.append(np.full(n_float, 4, dtype=np.int8))
    # background: huge opaque Gaussians on a far shell (upper hemisphere mostly: sky and distant scenery)
    d = rng.normal(size=(n_back, 3))
    d[:, 2] = np.abs(d[:, 2])  # the sky dome
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    band = rng.uniform(0, 1, n_back) < 0.7  # 70% in a band around the horizon: the far scenery
    d[band, 2] = rng.uniform(-0.1, 0.35, int(band.sum()))
    d[band, :2] /= np.linalg.norm(d[band, :2], axis=1, keepdims=True)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    means.append(d * rng.uniform(6.0, 7.5, (n_back, 1)))
    scales.append(rng.uniform(0.3, 0.9, (n_back, 1)) * rng.uniform(0.3, 1.0, (n_back, 3)))
    quats.append(_random_quats(n_back, rng))
    kind.append(np.full(n_back, 5, dtype=np.int8))

    kind_all = np.concatenate(kind)
    op = np.clip(rng.beta(5, 1.2, n_gaussians), 0.3, 0.995)
    op[kind_all == 4] = rng.uniform(0.06, 0.35, n_float)
    t = lambda a: torch.as_tensor(np.concatenate(a), dtype=torch.float32)  # noqa: E731
    return GroveScene(SplatParams.of(t(means), t(quats), torch.log(t(scales)), np.log(op / (1 - op))),
                      kind=kind_all, trees=trees)


# ------------------------------------------------------------------ the fine-grid reference
@dataclass
class ReferenceGrid:
    """A fine grid of voxel centres lo + (ijk + 0.5) * spacing; ``free`` [X, Y, Z] where the exact clearance of the
    centre is >= spacing * sqrt(3) / 2 (every 26-neighbour step between free centres is collision-free)."""

    lo: np.ndarray
    spacing: float
    free: np.ndarray
    astar_grid: Optional[object] = None

    def voxel_of(self, p: np.ndarray) -> np.ndarray:
        return np.floor((np.asarray(p, dtype=np.float64) - self.lo) / self.spacing).astype(np.int64)

    def centre_of(self, ijk) -> np.ndarray:
        return self.lo + (np.asarray(ijk, dtype=np.float64) + 0.5) * self.spacing


def reference_grid(scene, index, lo: np.ndarray, hi: np.ndarray, spacing: float, chunk: int = 200_000) -> ReferenceGrid:
    """ReferenceGrid of ``scene`` (an EllipsoidScene with its camera radius; ``index`` its GridIndex) over [lo, hi]."""
    from cinenerf_ns.planner.geometry.distance import clearance
    from cinenerf_ns.planner.search.astar import AStarGrid

    lo = np.asarray(lo, dtype=np.float64)
    shape = np.maximum(1, np.floor((np.asarray(hi, dtype=np.float64) - lo) / spacing).astype(np.int64))
    need = spacing * math.sqrt(3) / 2
    axes = [lo[d] + (np.arange(shape[d]) + 0.5) * spacing for d in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    cap = float(scene.camera_radius) + 2 * need
    free = np.empty(len(pts), dtype=bool)
    for a in range(0, len(pts), chunk):
        c = clearance(torch.as_tensor(pts[a:a + chunk], device=scene.device), scene, index, max_distance=cap)
        free[a:a + chunk] = (c >= need).cpu().numpy()
    free = free.reshape(tuple(shape))
    return ReferenceGrid(lo, float(spacing), free, AStarGrid(~free))


def reference_search(ref: ReferenceGrid, start: np.ndarray, goal: np.ndarray) -> Optional[float]:
    """Length of the reference path start -> (start's voxel centre) -> ... -> (goal's voxel centre) -> goal, or None
    when the reference finds no path (either end's voxel not free, or not connected). The end segments are within
    their free voxel (distance <= spacing * sqrt(3) / 2 of its centre: collision-free too)."""
    from cinenerf_ns.planner.errors import GoalUnreachableError
    from cinenerf_ns.planner.search.astar import astar, path_cost

    shape = np.array(ref.free.shape)
    a, b = ref.voxel_of(start), ref.voxel_of(goal)
    if not (((a >= 0) & (a < shape)).all() and ((b >= 0) & (b < shape)).all()):
        return None
    if not (ref.free[tuple(a)] and ref.free[tuple(b)]):
        return None
    lab = ref.astar_grid.labels
    if lab[tuple(a)] != lab[tuple(b)]:
        return None
    try:
        path = astar(ref.astar_grid, a, b)
    except GoalUnreachableError:
        return None
    inner = path_cost(path) * ref.spacing
    return float(inner + np.linalg.norm(ref.centre_of(a) - start) + np.linalg.norm(ref.centre_of(b) - goal))


@dataclass
class GrovePair:
    start: np.ndarray  # [3]
    goal: np.ndarray  # [3]
    look_at: np.ndarray  # [3]
    reference_length: Optional[float]  # the fine reference path's length; None: the reference finds no path
    straight: float  # |goal - start|


def grove_pairs(grove: GroveScene, scene, index, n_pairs: int, seed: int = 0, spacing: float = 0.025,
                ref: Optional[ReferenceGrid] = None) -> tuple:
    """(pairs [GrovePair], the ReferenceGrid): ``n_pairs`` seeded start / go-to pairs in the air between the trunks
    (PAIR_XY, PAIR_Z), both ends with exact clearance >= spacing * sqrt(3) (so their reference voxels are free), at
    least MIN_PAIR_DISTANCE apart; look-at: a
    random trunk's mid-height. Reachability and length from reference_search on a grid of ``spacing`` over the pair
    slab (z 0 to the lowest canopy bottom + 0.1: paths under the canopies)."""
    from cinenerf_ns.planner.geometry.distance import clearance

    if ref is None:
        top = min(t.height - t.canopy[2] for t in grove.trees) + 0.1
        ref = reference_grid(scene, index, np.array([-PAIR_XY - 0.2, -PAIR_XY - 0.2, 0.0]),
                             np.array([PAIR_XY + 0.2, PAIR_XY + 0.2, max(top, PAIR_Z[1] + 0.1)]), spacing)
    rng = np.random.default_rng(20_011 + seed)
    pairs: List[GrovePair] = []
    tries = 0
    while len(pairs) < n_pairs:
        tries += 1
        if tries > 200 * n_pairs:
            raise InvalidInputError(f"could not draw {n_pairs} free grove pairs in {tries} tries")
        lo, hi = np.array([-PAIR_XY, -PAIR_XY, PAIR_Z[0]]), np.array([PAIR_XY, PAIR_XY, PAIR_Z[1]])
        s, g = rng.uniform(lo, hi), rng.uniform(lo, hi)
        if np.linalg.norm(g - s) < MIN_PAIR_DISTANCE:
            continue
        c = clearance(torch.as_tensor(np.stack([s, g]), device=scene.device), scene, index, max_distance=1.0)
        if not bool((c >= math.sqrt(3) * ref.spacing).all()):  # the ends' reference voxels are free
            continue
        t = grove.trees[int(rng.integers(len(grove.trees)))]
        look = t.base + [0.0, 0.0, 0.5 * t.height]
        pairs.append(GrovePair(s, g, look, reference_search(ref, s, g), float(np.linalg.norm(g - s))))
    return pairs, ref
