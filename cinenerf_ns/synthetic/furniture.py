"""Furniture catalogue: each template builds an object from non-overlapping analytic parts.

A template returns parts in *local* coordinates (object stands on z = 0, footprint centred at the
origin) as ``(kind, params, colour, pattern, pattern_scale, pattern_axis)`` tuples. ``place``
rotates them by a multiple of 90 degrees about +z (keeps every part axis-aligned, so ground truth
stays exact) and moves them to their spot.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

PartSpec = tuple  # (kind, params, colour, pattern, pattern_scale, pattern_axis)


def _box(cx, cy, z0, z1, hx, hy, colour, pattern="plain", scale=0.1, axis=2) -> PartSpec:
    return ("box", {"centre": [cx, cy, (z0 + z1) / 2], "half": [hx, hy, (z1 - z0) / 2]}, colour, pattern, scale, axis)


def _cyl(cx, cy, z0, z1, r, colour, pattern="plain", scale=0.1, axis=2) -> PartSpec:
    return ("cylinder", {"centre": [cx, cy, (z0 + z1) / 2], "radius": r, "half_height": (z1 - z0) / 2},
            colour, pattern, scale, axis)


def _sph(cx, cy, cz, r, colour, pattern="plain", scale=0.1, axis=2) -> PartSpec:
    return ("sphere", {"centre": [cx, cy, cz], "radius": r}, colour, pattern, scale, axis)


def _jit(rng: np.random.Generator, x: float, rel: float = 0.08) -> float:
    return float(x * (1.0 + rng.uniform(-rel, rel)))


def red_armchair(rng):
    w, d, seat = _jit(rng, 0.42), _jit(rng, 0.42), _jit(rng, 0.42)
    col = (0.78, 0.10, 0.10)
    arm, back = 0.12, 0.14
    return [
        _box(0, 0, 0.0, seat, w - arm, d, col, "checker", 0.08),  # seat block between the arms
        _box(-w + arm / 2, 0, 0.0, seat + 0.22, arm / 2, d, col, "checker", 0.08),  # left arm
        _box(w - arm / 2, 0, 0.0, seat + 0.22, arm / 2, d, col, "checker", 0.08),  # right arm
        _box(0, d + back / 2, 0.0, seat + 0.5, w, back / 2, col, "checker", 0.08),  # back (behind the seat)
    ]


def green_sofa(rng):
    w, d, seat = _jit(rng, 0.95), _jit(rng, 0.42), 0.42
    col = (0.12, 0.55, 0.20)
    arm, back = 0.15, 0.16
    return [
        _box(0, 0, 0.0, seat, w - arm, d, col, "stripes", 0.12, 0),
        _box(-w + arm / 2, 0, 0.0, seat + 0.2, arm / 2, d, col, "stripes", 0.12, 0),
        _box(w - arm / 2, 0, 0.0, seat + 0.2, arm / 2, d, col, "stripes", 0.12, 0),
        _box(0, d + back / 2, 0.0, seat + 0.45, w, back / 2, col, "stripes", 0.12, 0),
    ]


def wooden_table(rng):
    hx, hy, top = _jit(rng, 0.6), _jit(rng, 0.4), _jit(rng, 0.74, 0.04)
    col = (0.55, 0.33, 0.14)
    leg = 0.035
    parts = [_box(0, 0, top - 0.05, top, hx, hy, col, "wood", 0.05)]
    for sx in (-1, 1):
        for sy in (-1, 1):
            parts.append(_cyl(sx * (hx - 0.07), sy * (hy - 0.07), 0.0, top - 0.05, leg, col, "wood", 0.05))
    return parts


def potted_plant(rng):
    r_pot, h_pot, r_leaf = _jit(rng, 0.17), _jit(rng, 0.34), _jit(rng, 0.33)
    return [
        _cyl(0, 0, 0.0, h_pot, r_pot, (0.72, 0.38, 0.22), "stripes", 0.06, 2),  # terracotta pot
        _sph(0, 0, h_pot + r_leaf, r_leaf, (0.10, 0.40, 0.08), "noise", 0.05),  # foliage
    ]


def floor_lamp(rng):
    pole_top = _jit(rng, 1.45, 0.05)
    r_shade = _jit(rng, 0.22)
    return [
        _cyl(0, 0, 0.0, 0.04, 0.17, (0.12, 0.12, 0.12), "plain"),  # base
        _cyl(0, 0, 0.04, pole_top, 0.022, (0.15, 0.15, 0.15), "plain"),  # pole
        _cyl(0, 0, pole_top, pole_top + 0.32, r_shade, (0.95, 0.88, 0.62), "stripes", 0.05, 2),  # shade
    ]


def blue_vase(rng):
    r_body = _jit(rng, 0.2)
    neck = _jit(rng, 0.25)
    return [
        _sph(0, 0, r_body, r_body, (0.10, 0.25, 0.85), "stripes", 0.05, 2),
        _cyl(0, 0, 2 * r_body, 2 * r_body + neck, 0.075, (0.10, 0.25, 0.85), "stripes", 0.05, 2),
    ]


def bookshelf(rng):
    hx, hy, h = _jit(rng, 0.5), 0.18, _jit(rng, 1.75, 0.05)
    wood = (0.36, 0.22, 0.12)
    parts = [_box(0, hy - 0.02, 0.0, h, hx, 0.02, wood, "wood", 0.06)]  # back panel
    books = [(0.7, 0.15, 0.15), (0.15, 0.3, 0.7), (0.85, 0.75, 0.2), (0.2, 0.55, 0.3)]
    n_shelf = 4
    shelf_h = h / n_shelf
    for k in range(n_shelf):
        # a shelf board, then a block of books on it (front of the back panel)
        z0 = k * shelf_h
        parts.append(_box(0, -0.02, z0, z0 + 0.04, hx, hy - 0.02, wood, "wood", 0.06))
        parts.append(_box(0, -0.04, z0 + 0.04, z0 + 0.04 + 0.7 * shelf_h, hx - 0.03, hy - 0.04,
                          books[k % len(books)], "stripes", 0.04, 0))
    return parts


def yellow_ball(rng):
    r = _jit(rng, 0.25)
    return [_sph(0, 0, r, r, (0.95, 0.82, 0.08), "checker", 0.1)]


def purple_stool(rng):
    h = _jit(rng, 0.5, 0.05)
    col = (0.45, 0.15, 0.60)
    return [
        _cyl(0, 0, 0.0, 0.03, 0.2, col, "noise", 0.05),
        _cyl(0, 0, 0.03, h - 0.06, 0.04, col, "noise", 0.05),
        _cyl(0, 0, h - 0.06, h, 0.22, col, "checker", 0.06),
    ]


def orange_cabinet(rng):
    hx, hy, h = _jit(rng, 0.35), _jit(rng, 0.25), _jit(rng, 1.0, 0.1)
    return [
        _box(0, 0, 0.0, 0.08, hx - 0.03, hy - 0.03, (0.2, 0.12, 0.05), "plain"),  # plinth
        _box(0, 0, 0.08, h, hx, hy, (0.92, 0.45, 0.08), "noise", 0.08),
    ]


CATALOGUE: dict[str, Callable[[np.random.Generator], list[PartSpec]]] = {
    "red armchair": red_armchair,
    "green sofa": green_sofa,
    "wooden table": wooden_table,
    "potted plant": potted_plant,
    "floor lamp": floor_lamp,
    "blue vase": blue_vase,
    "bookshelf": bookshelf,
    "yellow ball": yellow_ball,
    "purple stool": purple_stool,
    "orange cabinet": orange_cabinet,
}


def _rot_xy(v: list[float], quarter_turns: int) -> list[float]:
    x, y = v[0], v[1]
    for _ in range(quarter_turns % 4):
        x, y = -y, x
    return [x, y, *v[2:]]


def place(specs: list[PartSpec], x: float, y: float, quarter_turns: int) -> list[PartSpec]:
    """Rotate local parts by quarter_turns * 90 deg about +z and move them to (x, y)."""
    out = []
    for kind, params, colour, pattern, scale, axis in specs:
        p = {k: (list(v) if isinstance(v, list) else v) for k, v in params.items()}
        c = _rot_xy(p["centre"], quarter_turns)
        p["centre"] = [c[0] + x, c[1] + y, c[2]]
        if kind == "box" and quarter_turns % 2:
            p["half"] = [p["half"][1], p["half"][0], p["half"][2]]
        if axis in (0, 1) and quarter_turns % 2:
            axis = 1 - axis
        out.append((kind, p, colour, pattern, scale, axis))
    return out


def footprint(specs: list[PartSpec]) -> tuple[np.ndarray, np.ndarray]:
    """xy bounding rectangle (lo [2], hi [2]) of parts."""
    lo = np.full(2, np.inf)
    hi = np.full(2, -np.inf)
    for kind, p, *_ in specs:
        c = np.asarray(p["centre"][:2])
        h = np.asarray(p["half"][:2]) if kind == "box" else np.full(2, p["radius"])
        lo = np.minimum(lo, c - h)
        hi = np.maximum(hi, c + h)
    return lo, hi
