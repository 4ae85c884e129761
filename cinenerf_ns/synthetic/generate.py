"""Seeded procedural room layout: non-overlapping furniture on the floor with free space between."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cinenerf_ns.synthetic import furniture
from cinenerf_ns.synthetic.room import FIRST_OBJECT_LABEL, Part, Room, SceneObject, structure_parts


@dataclass
class RoomConfig:
    """Size and contents of a generated room (units: metres, +z up)."""

    width: float = 6.0
    """Interior extent along x (m)."""
    depth: float = 5.0
    """Interior extent along y (m)."""
    height: float = 2.5
    """Interior height (m)."""
    ceiling: bool = True
    """Close the room with a ceiling (cameras inside then see a surface in every direction)."""
    num_objects: int = 8
    """Number of furniture objects (6-10 sensible; at most the catalogue size)."""
    required: tuple[str, ...] = ("red armchair", "floor lamp")
    """Objects always present (the demo shot uses them); the rest are drawn from the catalogue."""
    min_gap: float = 0.55
    """Minimum free gap between the footprints of two objects (m): room for the camera to pass."""
    wall_margin: float = 0.08
    """Minimum gap between an object's footprint and a wall (m)."""
    tries_per_object: int = 300
    """Rejection-sampling attempts per object before the layout is restarted."""
    max_restarts: int = 200
    """Layout restarts before giving up with a LayoutError."""


class LayoutError(RuntimeError):
    """The requested objects do not fit into the room with the requested gaps."""


def generate_room(config: RoomConfig, seed: int = 0) -> Room:
    """A seeded room. Same (config, seed) -> same room; different seeds -> different layouts."""
    names = list(furniture.CATALOGUE)
    if not 1 <= config.num_objects <= len(names):
        raise ValueError(f"num_objects must be in [1, {len(names)}] (catalogue: {names}); got {config.num_objects}")
    unknown = [r for r in config.required if r not in furniture.CATALOGUE]
    if unknown:
        raise ValueError(f"required objects {unknown} are not in the catalogue {names}")
    if len(config.required) > config.num_objects:
        raise ValueError(f"{len(config.required)} required objects but num_objects={config.num_objects}")

    rng = np.random.default_rng(seed)
    rest = [n for n in names if n not in config.required]
    chosen = list(config.required) + [str(x) for x in rng.choice(rest, config.num_objects - len(config.required),
                                                                 replace=False)]
    # place large objects first: they are the hard ones to fit
    specs = {n: furniture.CATALOGUE[n](rng) for n in chosen}

    def area(n):
        lo, hi = furniture.footprint(specs[n])
        return float(np.prod(hi - lo))

    order = sorted(chosen, key=area, reverse=True)
    lo_room = np.array([-config.width / 2, -config.depth / 2]) + config.wall_margin
    hi_room = np.array([config.width / 2, config.depth / 2]) - config.wall_margin

    for _restart in range(config.max_restarts):
        placed = _try_layout(order, specs, lo_room, hi_room, config, rng)
        if placed is not None:
            break
    else:
        raise LayoutError(
            f"could not place {len(chosen)} objects in a {config.width}x{config.depth} m room with "
            f"min_gap={config.min_gap} m after {config.max_restarts} restarts; use a bigger room, fewer objects "
            f"or a smaller gap"
        )

    parts: list[Part] = structure_parts(config.width, config.depth, config.height, config.ceiling)
    objects: list[SceneObject] = []
    for k, n in enumerate(chosen):  # labels in catalogue-draw order (stable per seed)
        label = FIRST_OBJECT_LABEL + k
        ids = []
        for kind, params, colour, pattern, scale, axis in placed[n]:
            ids.append(len(parts))
            parts.append(Part(kind, params, n, label, tuple(colour), pattern, scale, axis,
                              int(rng.integers(1 << 30))))
        flo, fhi = furniture.footprint(placed[n])
        objects.append(SceneObject(n, label, ids, tuple(map(float, flo)), tuple(map(float, fhi))))
    return Room(config.width, config.depth, config.height, config.ceiling, parts, objects, seed)


def _try_layout(order, specs, lo_room, hi_room, config: RoomConfig, rng) -> dict | None:
    """Place objects one by one (rejection sampling); None if one of them finds no spot."""
    placed: dict[str, list] = {}
    rects: list[tuple[np.ndarray, np.ndarray]] = []
    for n in order:
        for _ in range(config.tries_per_object):
            turns = int(rng.integers(4))
            local = furniture.place(specs[n], 0.0, 0.0, turns)
            flo, fhi = furniture.footprint(local)
            if np.any(hi_room - fhi <= lo_room - flo):
                continue
            xy = rng.uniform(lo_room - flo, hi_room - fhi)
            rlo, rhi = flo + xy, fhi + xy
            if all(np.any(rlo >= ohi + config.min_gap) or np.any(olo >= rhi + config.min_gap) for olo, ohi in rects):
                rects.append((rlo, rhi))
                placed[n] = furniture.place(specs[n], float(xy[0]), float(xy[1]), turns)
                break
        else:
            return None
    return placed
