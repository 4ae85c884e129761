"""The ground-truth room: a list of analytic parts grouped into labelled objects.

Coordinates (the "original" / ground-truth frame, written to transforms.json and geometry.json):
units are metres, +z is up, the floor is z = 0, the room interior is
x in [-width/2, width/2], y in [-depth/2, depth/2], z in [0, height].
Walls, floor and ceiling are 0.2 m thick slabs *outside* that interior box, so the SDF is positive in
the free space of the room and the distance to a wall is exact.

Labels: 0 = background (rays that hit nothing; only possible without a ceiling), 1 = floor, 2 = wall,
3 = ceiling, 4.. = objects in the order of ``Room.objects``.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from torch import Tensor

from cinenerf_ns.synthetic import primitives as prim

BACKGROUND, FLOOR, WALL, CEILING = 0, 1, 2, 3
FIRST_OBJECT_LABEL = 4
STRUCTURE_NAMES = {BACKGROUND: "background", FLOOR: "floor", WALL: "wall", CEILING: "ceiling"}
SLAB = 0.2  # wall / floor / ceiling thickness (m)


@dataclass
class Part:
    """One analytic primitive of the room."""

    kind: str  # "box" | "sphere" | "cylinder"
    params: dict  # box: centre, half; sphere: centre, radius; cylinder: centre, radius, half_height
    object: str  # name of the object it belongs to ("floor", "wall", "ceiling" for the structure)
    label: int
    colour: tuple[float, float, float]  # linear albedo in [0, 1]
    pattern: str = "plain"  # plain | stripes | checker | noise | wood | planks
    pattern_scale: float = 0.1  # period of the pattern (m)
    pattern_axis: int = 2  # axis the stripes run across
    pattern_seed: int = 0


@dataclass
class SceneObject:
    name: str
    label: int
    part_ids: list[int]
    footprint_lo: tuple[float, float]  # xy rectangle the object stands on (placement, free space)
    footprint_hi: tuple[float, float]


@dataclass
class Room:
    width: float
    depth: float
    height: float
    ceiling: bool
    parts: list[Part]
    objects: list[SceneObject]
    seed: int = 0

    # ------------------------------------------------------------------ structure
    @property
    def labels(self) -> dict[int, str]:
        out = dict(STRUCTURE_NAMES)
        if not self.ceiling:
            out.pop(CEILING)
        for o in self.objects:
            out[o.label] = o.name
        return out

    def object(self, name: str) -> SceneObject:
        for o in self.objects:
            if o.name == name:
                return o
        raise KeyError(f"no object named {name!r} in this room; objects: {[o.name for o in self.objects]}")

    @property
    def interior_lo(self) -> Tensor:
        return torch.tensor([-self.width / 2, -self.depth / 2, 0.0], dtype=torch.float64)

    @property
    def interior_hi(self) -> Tensor:
        return torch.tensor([self.width / 2, self.depth / 2, self.height], dtype=torch.float64)

    def room_size(self) -> float:
        """Largest interior side (m): the reference length for relative centroid errors."""
        return float(max(self.width, self.depth, self.height))

    # ------------------------------------------------------------------ signed distance
    def part_sdf(self, points: Tensor, part_ids: list[int] | None = None) -> Tensor:
        """Exact signed distance of points [P,3] to each selected part -> [P,K] (in points' dtype)."""
        ids = list(range(len(self.parts))) if part_ids is None else list(part_ids)
        pts = points.reshape(-1, 3)
        out = torch.empty(pts.shape[0], len(ids), dtype=pts.dtype, device=pts.device)
        for kind in prim.KINDS:
            cols = [j for j, i in enumerate(ids) if self.parts[i].kind == kind]
            if not cols:
                continue
            ps = [self.parts[ids[j]].params for j in cols]
            t = lambda key: torch.tensor([p[key] for p in ps], dtype=pts.dtype, device=pts.device)  # noqa: E731
            if kind == "box":
                d = prim.sdf_box(pts, t("centre"), t("half"))
            elif kind == "sphere":
                d = prim.sdf_sphere(pts, t("centre"), t("radius"))
            else:
                d = prim.sdf_cylinder(pts, t("centre"), t("radius"), t("half_height"))
            out[:, cols] = d
        return out

    def sdf(self, points: Tensor) -> Tensor:
        """Signed distance [...] of points [...,3] to the room geometry (walls, floor, ceiling, objects).

        Exact Euclidean distance wherever it is >= 0 (distance to a union = min of distances);
        where negative (inside solids) it is the min of the parts' exact SDFs: sign exact, magnitude a
        valid bound."""
        shape = points.shape[:-1]
        return self.part_sdf(points).min(dim=-1).values.reshape(shape)

    def object_sdf(self, name: str, points: Tensor) -> Tensor:
        """Signed distance [...] of points [...,3] to one object (union of its parts; same exactness as sdf)."""
        shape = points.shape[:-1]
        return self.part_sdf(points, self.object(name).part_ids).min(dim=-1).values.reshape(shape)

    # ------------------------------------------------------------------ object ground truth
    def object_volume(self, name: str) -> float:
        # parts of one object never overlap (generator guarantees; tested), so volumes add up
        return sum(prim.volume(self.parts[i].kind, self.parts[i].params) for i in self.object(name).part_ids)

    def object_centre(self, name: str) -> Tensor:
        """Volume centroid [3] (float64) of an object: exact, from the parts' volumes and centres."""
        ids = self.object(name).part_ids
        vols = torch.tensor([prim.volume(self.parts[i].kind, self.parts[i].params) for i in ids], dtype=torch.float64)
        cs = torch.tensor([self.parts[i].params["centre"] for i in ids], dtype=torch.float64)
        return (vols[:, None] * cs).sum(0) / vols.sum()

    def object_centres(self) -> dict[str, Tensor]:
        return {o.name: self.object_centre(o.name) for o in self.objects}

    def object_aabb(self, name: str) -> tuple[Tensor, Tensor]:
        lo = torch.full((3,), math.inf, dtype=torch.float64)
        hi = torch.full((3,), -math.inf, dtype=torch.float64)
        for i in self.object(name).part_ids:
            plo, phi = prim.aabb(self.parts[i].kind, self.parts[i].params)
            lo = torch.minimum(lo, torch.tensor(plo, dtype=torch.float64))
            hi = torch.maximum(hi, torch.tensor(phi, dtype=torch.float64))
        return lo, hi

    def object_points(self, name: str, n: int, seed: int = 0) -> Tensor:
        """n points [n,3] (float64) uniformly distributed inside the object's volume."""
        ids = self.object(name).part_ids
        g = torch.Generator().manual_seed(seed)
        vols = torch.tensor([prim.volume(self.parts[i].kind, self.parts[i].params) for i in ids], dtype=torch.float64)
        which = torch.multinomial(vols / vols.sum(), n, replacement=True, generator=g)
        out = torch.empty(n, 3, dtype=torch.float64)
        for j, i in enumerate(ids):
            m = which == j
            k = int(m.sum())
            if k:
                out[m] = prim.sample_inside(self.parts[i].kind, self.parts[i].params, k, g)
        return out

    # ------------------------------------------------------------------ drawing helpers
    def part_outlines(self, n_circle: int = 32) -> list[tuple[str, Tensor]]:
        """(object name, closed 3-D polygon [K,3] at the part's mid-height) per object part: its xy outline."""
        out = []
        for o in self.objects:
            for i in o.part_ids:
                p = self.parts[i]
                c = torch.tensor(p.params["centre"], dtype=torch.float64)
                if p.kind == "box":
                    hx, hy = p.params["half"][0], p.params["half"][1]
                    xy = torch.tensor([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy], [-hx, -hy]], dtype=torch.float64)
                else:
                    a = torch.linspace(0, 2 * math.pi, n_circle + 1, dtype=torch.float64)
                    xy = p.params["radius"] * torch.stack([torch.cos(a), torch.sin(a)], -1)
                poly = torch.cat([xy + c[:2], c[2].expand(len(xy), 1)], -1)
                out.append((o.name, poly))
        return out

    def part_outlines_xy(self, n_circle: int = 32) -> list[tuple[str, Tensor]]:
        return [(n, poly[:, :2]) for n, poly in self.part_outlines(n_circle)]

    def interior_outline_xy(self) -> Tensor:
        return self.interior_outline()[:, :2]

    def interior_outline(self) -> Tensor:
        """Closed floor outline [5,3] of the room interior (at z = 0)."""
        lo, hi = self.interior_lo, self.interior_hi
        return torch.tensor(
            [[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0], [lo[0], lo[1], 0]],
            dtype=torch.float64,
        )

    # ------------------------------------------------------------------ io
    def to_dict(self) -> dict:
        return {
            "format": "cinenerf_ns.synthetic.room/1",
            "units": "metres; +z up; floor at z=0; interior x in [-width/2, width/2], y in [-depth/2, depth/2]",
            "seed": self.seed,
            "room": {"width": self.width, "depth": self.depth, "height": self.height, "ceiling": self.ceiling},
            "labels": {str(k): v for k, v in self.labels.items()},
            "parts": [asdict(p) for p in self.parts],
            "objects": [
                {
                    **asdict(o),
                    "centre": self.object_centre(o.name).tolist(),
                    "aabb": [t.tolist() for t in self.object_aabb(o.name)],
                    "volume": self.object_volume(o.name),
                }
                for o in self.objects
            ],
        }

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=1))

    @classmethod
    def from_dict(cls, d: dict) -> "Room":
        parts = [Part(**{**p, "colour": tuple(p["colour"])}) for p in d["parts"]]
        objects = [
            SceneObject(
                name=o["name"],
                label=o["label"],
                part_ids=list(o["part_ids"]),
                footprint_lo=tuple(o["footprint_lo"]),
                footprint_hi=tuple(o["footprint_hi"]),
            )
            for o in d["objects"]
        ]
        r = d["room"]
        return cls(r["width"], r["depth"], r["height"], r["ceiling"], parts, objects, d.get("seed", 0))

    @classmethod
    def load(cls, path: str | Path) -> "Room":
        """Load geometry.json (or a dataset folder containing it)."""
        path = Path(path)
        if path.is_dir():
            path = path / "geometry.json"
        if not path.exists():
            raise FileNotFoundError(f"no room geometry at {path} (expected geometry.json written by cinesplat-synth)")
        return cls.from_dict(json.loads(path.read_text()))


def room_sdf(room: Room, points: Tensor) -> Tensor:
    """Signed distance [...] of points [...,3] (original coordinates) to the room. See Room.sdf."""
    return room.sdf(points)


def structure_parts(width: float, depth: float, height: float, ceiling: bool) -> list[Part]:
    """Floor, 4 walls (and ceiling) as slabs outside the interior box."""
    w2, d2, t = width / 2, depth / 2, SLAB
    zc = height / 2
    hz = height / 2 + t  # walls cover floor and ceiling slabs too (closed corners)
    parts = [
        Part("box", {"centre": [0.0, 0.0, -t / 2], "half": [w2 + t, d2 + t, t / 2]}, "floor", FLOOR,
             (0.55, 0.42, 0.30), "planks", 0.25, 0, 11),
        Part("box", {"centre": [-w2 - t / 2, 0.0, zc], "half": [t / 2, d2 + t, hz]}, "wall", WALL,
             (0.80, 0.78, 0.70), "stripes", 0.3, 1, 21),
        Part("box", {"centre": [w2 + t / 2, 0.0, zc], "half": [t / 2, d2 + t, hz]}, "wall", WALL,
             (0.70, 0.78, 0.82), "stripes", 0.3, 1, 22),
        Part("box", {"centre": [0.0, -d2 - t / 2, zc], "half": [w2, t / 2, hz]}, "wall", WALL,
             (0.82, 0.74, 0.74), "stripes", 0.3, 0, 23),
        Part("box", {"centre": [0.0, d2 + t / 2, zc], "half": [w2, t / 2, hz]}, "wall", WALL,
             (0.76, 0.80, 0.70), "stripes", 0.3, 0, 24),
    ]
    if ceiling:
        parts.append(
            Part("box", {"centre": [0.0, 0.0, height + t / 2], "half": [w2 + t, d2 + t, t / 2]}, "ceiling", CEILING,
                 (0.92, 0.92, 0.90), "checker", 0.6, 0, 31)  # ceiling tiles
        )
    return parts
