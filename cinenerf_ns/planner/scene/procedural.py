"""Procedurally generated splat-like scenes: surfaces covered by flat Gaussians.

Used by the demo (until a trained scene is bundled), by end-to-end planner tests and by the
planner benchmarks (200k / 1M Gaussians). A trained splat looks like this too: thin discs lying on
surfaces, with free space in between. Object names here are ground truth for tests, not semantics.

Layout (z up, scene units): a floor [-W/2, W/2] x [-D/2, D/2] at z = 0, four walls of height H,
no ceiling, and named objects (boxes, spheres, cylinders) standing on the floor.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import InvalidInputError

OBJECT_NAMES = ["armchair", "floor lamp", "table", "vase", "potted plant", "sofa", "bookshelf", "ball"]


@dataclass
class ProceduralObject:
    name: str
    kind: str  # "box" | "sphere" | "cylinder"
    center: np.ndarray  # [3]
    size: np.ndarray  # [3] full extents (box), or (2r, 2r, 2r) sphere, (2r, 2r, h) cylinder


@dataclass
class ProceduralScene:
    means: torch.Tensor  # [N, 3]
    quats: torch.Tensor  # [N, 4] wxyz
    log_scales: torch.Tensor  # [N, 3]
    opacity_logits: torch.Tensor  # [N]
    object_ids: torch.Tensor  # [N] index into objects, -1 for floor / walls
    objects: list[ProceduralObject] = field(default_factory=list)
    room: tuple[float, float, float] = (2.0, 2.0, 1.0)

    def object(self, name: str) -> ProceduralObject:
        for o in self.objects:
            if o.name == name:
                return o
        raise InvalidInputError(f"no object named {name!r}; objects: {[o.name for o in self.objects]}")

    @property
    def free_lo(self) -> np.ndarray:
        w, d, h = self.room
        return np.array([-w / 2, -d / 2, 0.0])

    @property
    def free_hi(self) -> np.ndarray:
        w, d, h = self.room
        return np.array([w / 2, d / 2, h])


def _quat_from_z_to(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """wxyz quaternions rotating +z onto each unit normal [K,3], with a random spin about it."""
    k = normals.shape[0]
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(z, normals)  # [K, 3]
    s = np.linalg.norm(axis, axis=1)
    c = normals @ z
    ang = np.arctan2(s, c)
    safe = s > 1e-9
    axis[safe] /= s[safe, None]
    axis[~safe] = np.array([1.0, 0.0, 0.0])  # normal = +-z: rotate about x by 0 or pi
    q_align = np.concatenate([np.cos(ang / 2)[:, None], np.sin(ang / 2)[:, None] * axis], axis=1)
    spin = rng.uniform(0, 2 * np.pi, k)
    q_spin = np.stack([np.cos(spin / 2), 0 * spin, 0 * spin, np.sin(spin / 2)], axis=1)  # about z
    # q = q_align * q_spin (spin in the disc's own frame first)
    w1, x1, y1, z1 = q_align.T
    w2, x2, y2, z2 = q_spin.T
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=1,
    )


def _sample_box_surface(center, size, n, rng):
    """Points + outward normals uniformly on a box's 5 faces (no bottom: it stands on the floor)."""
    sx, sy, sz = size
    faces = [  # (normal axis, sign, area)
        (2, +1, sx * sy), (0, +1, sy * sz), (0, -1, sy * sz), (1, +1, sx * sz), (1, -1, sx * sz)
    ]
    areas = np.array([f[2] for f in faces])
    counts = rng.multinomial(n, areas / areas.sum())
    pts, nrm = [], []
    for (ax, sg, _), c in zip(faces, counts):
        u = rng.uniform(-0.5, 0.5, (c, 3)) * size
        u[:, ax] = sg * size[ax] / 2
        nn = np.zeros((c, 3))
        nn[:, ax] = sg
        pts.append(center + u)
        nrm.append(nn)
    return np.concatenate(pts), np.concatenate(nrm)


def _sample_sphere_surface(center, radius, n, rng):
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    return center + radius * v, v


def _sample_cylinder_surface(center, radius, height, n, rng):
    """Side + top of a vertical cylinder whose base centre is center - (0,0,h/2)."""
    side, top = 2 * np.pi * radius * height, np.pi * radius**2
    n_top = int(round(n * top / (side + top)))
    n_side = n - n_top
    th = rng.uniform(0, 2 * np.pi, n_side)
    zz = rng.uniform(-height / 2, height / 2, n_side)
    p_side = np.stack([radius * np.cos(th), radius * np.sin(th), zz], 1)
    n_s = np.stack([np.cos(th), np.sin(th), 0 * th], 1)
    rr = radius * np.sqrt(rng.uniform(0, 1, n_top))
    th2 = rng.uniform(0, 2 * np.pi, n_top)
    p_top = np.stack([rr * np.cos(th2), rr * np.sin(th2), np.full(n_top, height / 2)], 1)
    n_t = np.tile([0.0, 0.0, 1.0], (n_top, 1))
    return center + np.concatenate([p_side, p_top]), np.concatenate([n_s, n_t])


def procedural_room(
    n_gaussians: int = 20_000,
    seed: int = 0,
    room: tuple[float, float, float] = (2.0, 2.0, 1.0),
    n_objects: int = 6,
    opacity: float = 0.9,
) -> ProceduralScene:
    """A seeded room of ``n_gaussians`` flat Gaussians on floor, walls and ``n_objects`` objects.

    Gaussian sizes follow the surface density (disc radius ~ spacing), as a trained splat's do, so
    scenes of 20k and 1M Gaussians cover the same surfaces with finer discs.
    """
    if n_gaussians < 100:
        raise InvalidInputError(f"n_gaussians must be >= 100, got {n_gaussians}")
    if not 1 <= n_objects <= len(OBJECT_NAMES):
        raise InvalidInputError(f"n_objects must be in 1..{len(OBJECT_NAMES)}, got {n_objects}")
    rng = np.random.default_rng(seed)
    w, d, h = room
    objects = _place_objects(rng, n_objects, w, d, h)
    areas = _surface_areas(objects, w, d, h)
    # objects get 3x the density of walls so they read as detailed, as in real captures
    weights = areas * np.array([1.0, 1.0, 1.0] + [3.0] * len(objects))
    counts = rng.multinomial(n_gaussians, weights / weights.sum())
    means, normals, ids, sp = _sample_surfaces(rng, objects, counts, areas, w, d, h)
    # disc radius ~ 0.6 x spacing (overlapping discs, as trained splats), thickness 10% of that;
    # the planner's beta*opacity then scales them (beta=2, opacity 0.9 -> 1.8x).
    sigma_t = 0.6 * sp * rng.uniform(0.7, 1.3, len(sp))
    scales = np.stack([sigma_t, sigma_t * rng.uniform(0.5, 1.0, len(sp)), 0.1 * sigma_t], 1)
    quats = _quat_from_z_to(normals, rng)
    op = np.clip(opacity + rng.normal(0, 0.03, len(sp)), 0.05, 0.999)
    logits = np.log(op / (1 - op))
    return ProceduralScene(
        means=torch.as_tensor(means, dtype=torch.float32),
        quats=torch.as_tensor(quats, dtype=torch.float32),
        log_scales=torch.as_tensor(np.log(scales), dtype=torch.float32),
        opacity_logits=torch.as_tensor(logits, dtype=torch.float32),
        object_ids=torch.as_tensor(ids, dtype=torch.long),
        objects=objects,
        room=room,
    )


def _place_objects(rng: np.random.Generator, n_objects: int, w: float, d: float, h: float) -> list[ProceduralObject]:
    """Objects standing on the floor, on a jittered grid so that they do not overlap and leave corridors."""
    objects: list[ProceduralObject] = []
    cols = int(math.ceil(math.sqrt(n_objects)))
    rows = int(math.ceil(n_objects / cols))
    cell_w, cell_d = w / cols, d / rows
    slots = rng.permutation(rows * cols)[:n_objects]
    kinds = ["box", "cylinder", "box", "cylinder", "sphere", "box", "box", "sphere"]
    for i, slot in enumerate(slots):
        r, c = divmod(int(slot), cols)
        cx = -w / 2 + (c + 0.5) * cell_w + rng.uniform(-0.1, 0.1) * cell_w
        cy = -d / 2 + (r + 0.5) * cell_d + rng.uniform(-0.1, 0.1) * cell_d
        kind = kinds[i % len(kinds)]
        foot = min(cell_w, cell_d) * rng.uniform(0.25, 0.4)
        if kind == "box":
            size = np.array([foot, foot * rng.uniform(0.6, 1.0), h * rng.uniform(0.25, 0.55)])
        elif kind == "sphere":
            size = np.full(3, foot)
        else:
            size = np.array([foot, foot, h * rng.uniform(0.3, 0.7)])
        zc = size[2] / 2
        objects.append(ProceduralObject(OBJECT_NAMES[i], kind, np.array([cx, cy, zc]), size))
    return objects


def _surface_areas(objects: list[ProceduralObject], w: float, d: float, h: float) -> np.ndarray:
    """[3 + O]: floor, the two walls at x = +-w/2, the two at y = +-d/2, then each object's visible surface."""
    areas = [w * d, 2 * d * h, 2 * w * h]  # floor, walls at x = +-w/2 (d x h each), walls at y = +-d/2 (w x h each)
    for o in objects:
        if o.kind == "box":
            sx, sy, sz = o.size
            areas.append(sx * sy + 2 * sy * sz + 2 * sx * sz)
        elif o.kind == "sphere":
            areas.append(4 * np.pi * (o.size[0] / 2) ** 2)
        else:
            rr = o.size[0] / 2
            areas.append(2 * np.pi * rr * o.size[2] + np.pi * rr**2)
    return np.array(areas)


def _sample_surfaces(rng: np.random.Generator, objects: list[ProceduralObject], counts: np.ndarray,
                     areas: np.ndarray, w: float, d: float, h: float):
    """Surface points [N, 3], unit normals [N, 3], object ids [N] (-1: floor / walls) and point spacing [N]
    (sqrt(area / count) of each surface) for counts [3 + O] points per surface (``_surface_areas``' order)."""
    pts, nrm, ids, spacing = [], [], [], []

    def add(p, n_, oid, area, count):
        pts.append(p)
        nrm.append(n_)
        ids.append(np.full(len(p), oid))
        spacing.append(np.full(len(p), math.sqrt(area / max(count, 1))))

    # floor
    c0 = counts[0]
    p = np.stack([rng.uniform(-w / 2, w / 2, c0), rng.uniform(-d / 2, d / 2, c0), np.zeros(c0)], 1)
    add(p, np.tile([0.0, 0.0, 1.0], (c0, 1)), -1, areas[0], c0)
    # walls at x = +-w/2 (normals point inward)
    c1 = counts[1]
    side = rng.integers(0, 2, c1) * 2 - 1
    p = np.stack([side * w / 2, rng.uniform(-d / 2, d / 2, c1), rng.uniform(0, h, c1)], 1)
    add(p, np.stack([-side, 0 * side, 0 * side], 1).astype(float), -1, areas[1], c1)
    c2 = counts[2]
    side = rng.integers(0, 2, c2) * 2 - 1
    p = np.stack([rng.uniform(-w / 2, w / 2, c2), side * d / 2, rng.uniform(0, h, c2)], 1)
    add(p, np.stack([0 * side, -side, 0 * side], 1).astype(float), -1, areas[2], c2)
    for k, o in enumerate(objects):
        ck = counts[3 + k]
        if ck == 0:
            continue
        if o.kind == "box":
            p, n_ = _sample_box_surface(o.center, o.size, ck, rng)
        elif o.kind == "sphere":
            p, n_ = _sample_sphere_surface(o.center, o.size[0] / 2, ck, rng)
        else:
            p, n_ = _sample_cylinder_surface(o.center, o.size[0] / 2, o.size[2], ck, rng)
        add(p, n_, k, areas[3 + k], ck)
    return np.concatenate(pts), np.concatenate(nrm), np.concatenate(ids), np.concatenate(spacing)
