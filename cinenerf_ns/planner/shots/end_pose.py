"""Where a shot ends: a free viewpoint near the go-to object with a good view of the look-at subject.

"Go to X, look at Y" with X and Y objects means: end near X, seeing Y well. The camera is not sent into X's centre;
viewpoints are sampled around the subject Y at the distances that give the framing's size (framing.py), in
directions between slightly below and well above eye level, plus directions toward X. A viewpoint is kept when it is
in a free voxel of the occupancy grid (so the camera ball there is proven clear) of the start's free component,
outside X's and Y's boxes, and inside the planning region. Each is scored (lower is better) by

    w_size * framing.size_cost  +  w_whole * (subject cut off)  +  w_goto * distance to X's box / aim distance
    + w_elevation * ((elevation - eye) / 45 deg)^2  (+ w_facing * (1 - cos(angle to the facing direction)) / 2)

and the best ``evaluated`` of them also by how much of Y is seen through the splat (geometry/visibility.py, the
alpha-composited transmittance to samples of Y's Gaussians) and how much of the frame X fills:

    + w_visibility * (1 - visible fraction)  +  w_goto_fill * max(0, X's frame coverage - GOTO_FILL_FREE).

The best viewpoints, at least ``min_separation_deg`` apart around Y, are the end poses (ranked candidates each get
one). When X and Y are the same object ("a good view of X"), there is no distance term; the facing direction (the
start region's centre as seen from Y) is preferred instead.

Cost per request: the visibility (the walk through the splat) is computed for the cheapest of the evaluated
viewpoints first (by their cost with the go-to coverage), in batches, until no viewpoint left could change the
choice (its total is at least those terms): the same end poses as computing it for all. The subject's size is made
only for the free viewpoints (feasibility needs no size). The sphere's viewpoints and the sizes made from them are
kept with the subject's set-up (target_object.object_parts) for later requests that frame the same object.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, List, Optional

import numpy as np

from ..errors import InvalidInputError
from ..geometry.visibility import MIN_SEGMENTS_PER_THREAD, SplatVolume, SubjectSamples, subject_visibility
from ..native import kernel_threads
from .framing import FramingConfig, project, size_cost, subject_size
from .target_object import TargetObject, subject_samples

if TYPE_CHECKING:
    from .planner import Planner

GOTO_FILL_FREE = 0.25
"""The go-to object may cover this fraction of the last frame at no cost."""
COVERAGE_RASTER = (16, 9)
"""Cells (across, down) of the coarse raster on which the go-to object's frame coverage is counted."""


@dataclass
class EndPoseConfig:
    """How end poses are sampled and scored (module docstring)."""

    directions: int = 160
    """Directions around the subject (a Fibonacci sphere, before the elevation limits)."""
    min_elevation_deg: float = -15.0
    """Lowest view elevation (camera below the subject looking up), degrees."""
    max_elevation_deg: float = 60.0
    """Highest view elevation, degrees."""
    eye_elevation_deg: float = 15.0
    """Preferred elevation (a camera slightly above the subject, looking down a little)."""
    evaluated: int = 12
    """Best viewpoints by the cheap terms whose visibility and go-to coverage are computed."""
    samples: int = 16
    """Samples of the subject's Gaussians for the visibility."""
    min_separation_deg: float = 25.0
    """End poses of different candidates are at least this far apart as seen from the subject."""
    w_visibility: float = 6.0
    """Weight of the subject's hidden fraction, seen through the splat (the evaluated viewpoints only)."""
    w_size: float = 1.0
    """Weight of the subject's size outside the framing's band (framing.size_cost)."""
    w_whole: float = 10.0
    """Weight of a subject cut off by the frame's edge (0 or 1)."""
    w_goto: float = 0.5
    """Weight of the distance to the go-to object's box, in units of the subject's distance from it."""
    w_elevation: float = 0.3
    """Weight of ((elevation - eye_elevation_deg) / 45 deg)^2."""
    w_goto_fill: float = 4.0
    """Weight of the go-to object's frame coverage above GOTO_FILL_FREE (the evaluated viewpoints only)."""
    w_facing: float = 0.5
    """Same go-to and look-at object: weight of (1 - cos(angle to the facing direction)) / 2."""

    def validate(self) -> None:
        for k in ("directions", "evaluated", "samples"):
            v = getattr(self, k)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 1 <= v <= 100_000:
                raise InvalidInputError(f"EndPoseConfig.{k} must be an integer in [1, 100000], got {v!r}")
        for k, v in self.__dict__.items():
            if isinstance(v, float) and not math.isfinite(v):
                raise InvalidInputError(f"EndPoseConfig.{k} must be finite, got {v!r}")
            if k.startswith("w_") and v < 0:
                raise InvalidInputError(f"EndPoseConfig.{k} must be >= 0, got {v!r}")
        if not -90 <= self.min_elevation_deg < self.max_elevation_deg <= 90:
            raise InvalidInputError("EndPoseConfig elevations must satisfy -90 <= min < max <= 90 degrees")


@dataclass
class EndPose:
    """One chosen viewpoint and why."""

    point: np.ndarray  # [3]
    cost: float
    visibility: float  # fraction of the subject seen through the splat
    size: float  # the subject's size in the frame (framing.py)
    whole: bool  # the subject is whole in the frame
    goto_distance: float  # from the go-to object's box (0 for "a good view of X")
    goto_fill: float  # fraction of the frame the go-to object covers
    elevation_deg: float

    def to_dict(self) -> dict:
        return {"point": self.point.tolist(), "cost": self.cost, "visibility": self.visibility, "size": self.size,
                "whole_in_frame": self.whole, "goto_distance": self.goto_distance, "goto_fill": self.goto_fill,
                "elevation_deg": self.elevation_deg}


@dataclass
class EndPoseChoice:
    """The end poses of a request (best first) and what was considered."""

    poses: List[EndPose]
    considered: int  # viewpoints sampled
    feasible: int  # free, reachable, outside the objects, in the region
    framing: str
    ms: float
    notes: List[str] = field(default_factory=list)

    def why(self, k: int = 0) -> str:
        if not self.poses:
            return (f"no free viewpoint of the {self.considered} sampled around the subject is reachable; "
                    + "; ".join(self.notes))
        p = self.poses[min(k, len(self.poses) - 1)]
        return (f"end pose chosen from {self.feasible} free, reachable viewpoints of {self.considered}: the subject "
                f"{100 * p.visibility:.0f}% visible, size {p.size:.2f} ({self.framing}), "
                + ("whole in frame" if p.whole else "cut off by the frame edge")
                + (f", {p.goto_distance:.2f} from the go-to object" if p.goto_distance > 0 else ""))

    def to_dict(self) -> dict:
        return {"framing": self.framing, "considered": self.considered, "feasible": self.feasible,
                "ms": self.ms, "poses": [p.to_dict() for p in self.poses], "notes": self.notes, "why": self.why()}


def visibility_volume(planner: "Planner") -> SplatVolume:
    """The prepared scene's SplatVolume over the planning region grown by 5% (built once, kept in prep.volume)."""
    prep = planner.ready()
    if prep.volume is None:
        lo, hi = planner.region()
        pad = 0.05 * float((hi - lo).max())
        prep.volume = SplatVolume.build(planner.scene, lo - pad, hi + pad)
    return prep.volume


def fibonacci_directions(n: int) -> np.ndarray:
    """n unit vectors [n, 3] spread evenly on the sphere (z is the pole)."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(np.maximum(0.0, 1 - z * z))
    phi = i * math.pi * (3 - math.sqrt(5))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def _to_up(dirs: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Rotate directions [n, 3] whose pole is +z so that their pole is ``up``."""
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(z, up), float(z @ up)
    if np.linalg.norm(v) < 1e-12:
        return dirs if c > 0 else -dirs
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    rot = np.eye(3) + vx + vx @ vx / (1 + c)
    return dirs @ rot.T


def _directions(subject: TargetObject, goto: Optional[TargetObject], up: np.ndarray,
                cfg: EndPoseConfig) -> tuple:
    """(toward the go-to [D', 3], the sphere's [D, 3]): unit directions from the subject within the elevation limits
    (the viewpoints' directions are the first, then the second)."""
    extra = []
    if goto is not None:
        g = goto.centre - subject.centre
        g = g - (g @ up) * up  # the go-to's bearing, at the eye elevation and around it
        if np.linalg.norm(g) > 1e-9:
            g /= np.linalg.norm(g)
            side = np.cross(up, g)
            for az in (-30, -15, 0, 15, 30):
                for el in (cfg.eye_elevation_deg, cfg.eye_elevation_deg + 20):
                    a, e = math.radians(az), math.radians(el)
                    extra.append(math.cos(e) * (math.cos(a) * g + math.sin(a) * side) + math.sin(e) * up)
    return _in_elevation(np.array(extra).reshape(-1, 3), up, cfg), _in_elevation(
        _to_up(fibonacci_directions(cfg.directions), up), up, cfg)


def _in_elevation(d: np.ndarray, up: np.ndarray, cfg: EndPoseConfig) -> np.ndarray:
    el = np.degrees(np.arcsin(np.clip(d @ up, -1, 1)))
    return d[(el >= cfg.min_elevation_deg) & (el <= cfg.max_elevation_deg)]


def _fills(framing: FramingConfig) -> tuple:
    """The sizes viewpoints are placed for: the aimed-for size, sizes in the band, and beyond it (rooms too small for
    a wide view of a large subject still get the closest size they allow)."""
    lo_b, aim, hi_b = framing.band
    return (aim, 0.5 * (lo_b + aim), 0.5 * (aim + hi_b), lo_b, hi_b, min(0.95, 1.15 * hi_b))


@dataclass
class _Ring:
    """Viewpoints along directions [D, 3] from the subject: ``d`` [D] the distance for the aimed-for size, ``pts``
    [F, D, 3] at the distances of each of _fills (read-only); the subject's size and wholeness from each viewpoint are
    made on first use (sizes(): a request sizes only its free viewpoints) and kept."""

    d: np.ndarray
    pts: np.ndarray
    size: np.ndarray  # [F * D]; valid where done
    whole: np.ndarray  # [F * D] bool; valid where done
    done: np.ndarray  # [F * D] bool
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def __getstate__(self) -> dict:  # a lock is not pickled: a copy gets its own
        return {k: v for k, v in self.__dict__.items() if k != "lock"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state, lock=threading.Lock())

    def sizes(self, rows: np.ndarray, subject: TargetObject, up: np.ndarray, framing: FramingConfig) -> tuple:
        """(size, whole) of the viewpoints ``rows`` (flat indices into pts [F * D]): each camera's answer depends on
        nothing else in the call, so sizing a few now and others later gives what sizing all at once does."""
        rows = np.asarray(rows, np.int64)
        with self.lock:  # viewer clients may share a kept ring
            todo = np.unique(rows[~self.done[rows]])
            if todo.size:
                sz, wh = subject_size(self.pts.reshape(-1, 3)[todo], subject.centre, up, subject.outline_points(),
                                      subject.pad, framing)
                self.size[todo], self.whole[todo], self.done[todo] = sz, wh, True
            return self.size[rows].copy(), self.whole[rows].copy()


def _ring(subject: TargetObject, dirs: np.ndarray, up: np.ndarray, framing: FramingConfig) -> _Ring:
    """The _Ring of directions dirs [D, 3] from the subject: d from a first guess and two corrections (size ~
    1 / distance), its sizes not yet made."""
    c = subject.centre
    aim = framing.band[1]
    th, tv = framing.tan_half()
    d = np.full(len(dirs), subject.radius() / (aim * min(th, tv)))
    for _ in range(2):
        s, _ = subject_size(c[None] + d[:, None] * dirs, c, up, subject.outline_points(), subject.pad, framing)
        d = d * np.clip(s / aim, 0.25, 4.0)
    pts = np.stack([c[None] + (d * aim / f)[:, None] * dirs for f in _fills(framing)])  # [F, D, 3]
    for a in (d, pts):
        a.setflags(write=False)
    n = pts.shape[0] * pts.shape[1]
    return _Ring(d, pts, np.zeros(n), np.zeros(n, bool), np.zeros(n, bool))


def _sphere_ring(subject: TargetObject, dirs: np.ndarray, up: np.ndarray, framing: FramingConfig,
                 cfg: EndPoseConfig) -> _Ring:
    """_ring of the sphere's directions, kept with the subject's set-up (subject.memo) for the next request that
    frames the same object from the same look-at point the same way."""
    if subject.memo is None:
        return _ring(subject, dirs, up, framing)
    key = ("ring", framing.framing, float(framing.fov_deg), float(framing.aspect), up.tobytes(),
           subject.centre.tobytes(), cfg.directions, float(cfg.min_elevation_deg), float(cfg.max_elevation_deg))
    got = subject.memo.get(key)
    if got is None:
        got = _ring(subject, dirs, up, framing)
        subject.memo[key] = got
    return got


def _ring_sizes(rings: list, idx: np.ndarray, subject: TargetObject, up: np.ndarray, framing: FramingConfig) -> tuple:
    """(size, whole) [len(idx)] of viewpoints idx (flat indices into the rings' points concatenated along the
    directions, [F, sum D, 3]), each from its ring (sized on first use)."""
    widths = [r.pts.shape[1] for r in rings]
    f, j = np.divmod(idx, sum(widths))
    size, whole = np.zeros(len(idx)), np.zeros(len(idx), bool)
    off = 0
    for r, w in zip(rings, widths):
        sel = (j >= off) & (j < off + w)
        if sel.any():
            size[sel], whole[sel] = r.sizes(f[sel] * w + j[sel] - off, subject, up, framing)
        off += w
    return size, whole


def _box_distance(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Euclidean distance [P] from points [P, 3] to the box [lo, hi] (0 inside)."""
    return np.linalg.norm(np.maximum(0.0, np.maximum(lo - points, points - hi)), axis=1)


def frame_coverage(cameras: np.ndarray, look_at: np.ndarray, up: np.ndarray, obj: TargetObject,
                   framing: FramingConfig, max_points: int = 128, backend: str = "auto") -> np.ndarray:
    """Approximate fraction [M] of each camera's frame that an object covers: cells of a COVERAGE_RASTER whose centre
    lies within (pad + spacing) of one of its extent points, projected (points behind the camera are left out).
    backend: of the raster ("auto": native/targets.c when it loads, the same cells; "native"; "python")."""
    from ..native import choose, coverage_c

    pts = obj.extent if len(obj.extent) <= max_points else obj.extent[:: int(math.ceil(len(obj.extent) / max_points))]
    x, y, depth = project(cameras, look_at, up, pts, framing)  # [M, P]
    th, tv = framing.tan_half()
    r = obj.pad + obj.gap()
    nx, ny = COVERAGE_RASTER
    cx = (np.arange(nx) + 0.5) / nx * 2 - 1
    cy = (np.arange(ny) + 0.5) / ny * 2 - 1
    front = depth > 1e-6  # [M, P]
    z = np.where(front, depth, 1.0)
    rx, ry = r / (z * th), r / (z * tv)  # [M, P] the disc's half axes in half-frame units
    fn = choose(backend, coverage_c, "targets", "frame coverage")
    if fn is not None:
        m, p = x.shape
        arrs = [np.ascontiguousarray(a, np.float64) for a in (x, y, rx, ry, cx, cy)]
        f8 = np.ascontiguousarray(front, np.uint8)
        out, scratch = np.empty(m), np.empty(nx * ny, np.uint8)
        fn(*(a.ctypes.data for a in arrs[:4]), f8.ctypes.data, m, p, arrs[4].ctypes.data, nx, arrs[5].ctypes.data,
           ny, scratch.ctypes.data, out.ctypes.data)
        return out
    dx = (cx[None, :, None] - x[:, None, :]) / rx[:, None, :]  # [M, nx, P]
    dy = (cy[None, :, None] - y[:, None, :]) / ry[:, None, :]  # [M, ny, P]
    inside = ((dx[:, None, :, :] ** 2 + dy[:, :, None, :] ** 2 <= 1.0) & front[:, None, None, :]).any(-1)
    return inside.mean(axis=(1, 2))  # [M]


def _feasible(planner: "Planner", pts: np.ndarray, objects: tuple, component: int) -> np.ndarray:
    """bool [V]: viewpoints pts [V, 3] inside the region, in a free voxel of ``component`` (the camera ball is proven
    clear there) and outside the boxes of the objects (TargetObject or None) by the camera radius."""
    prep = planner.ready()
    lo, hi = planner.region()
    r = float(planner.scene.camera_radius)
    keep = np.all((pts >= lo + r) & (pts <= hi - r), axis=1)
    ijk = np.floor((pts - lo) / float(prep.grid.voxel_size)).astype(np.int64)
    shape = np.array(prep.astar_grid.labels.shape)
    ijk_c = np.clip(ijk, 0, shape - 1)
    keep &= np.all((ijk >= 0) & (ijk < shape), axis=1)
    keep &= prep.astar_grid.labels[ijk_c[:, 0], ijk_c[:, 1], ijk_c[:, 2]] == component
    for obj in objects:
        if obj is not None and not obj.is_point:
            blo, bhi = obj.box()
            keep &= _box_distance(pts, blo, bhi) > r
    return keep


def _to_evaluate(cost: np.ndarray, dirs: np.ndarray, n_eval: int, cos_sep: float) -> np.ndarray:
    """int64 [n_eval] the viewpoints whose visibility is computed, by cost: half of them the cheapest far apart from
    each other (directions dirs [V, 3] at cosines below cos_sep: candidates need distinct end poses that still show
    the subject), the rest the cheapest of all."""
    by_cost = np.argsort(cost, kind="stable")
    picked: List[int] = []
    for i in by_cost:
        if len(picked) >= (n_eval + 1) // 2:
            break
        if all(float(dirs[i] @ dirs[j]) < cos_sep for j in picked):
            picked.append(int(i))
    seen = set(picked)
    picked += [int(i) for i in by_cost if int(i) not in seen][: n_eval - len(picked)]
    return np.array(sorted(picked, key=lambda i: (cost[i], i)), dtype=np.int64)


def _greedy(order: np.ndarray, vis: np.ndarray, dirs: np.ndarray, k: int, cos_sep: float) -> List[int]:
    """Up to k positions of ``order`` (best first): the best, then the next best far enough (directions dirs, cosines
    below cos_sep) from those chosen that still show the subject (at least half of it, and not much less than the
    best pose does)."""
    chosen: List[int] = []
    if len(order) == 0:
        return chosen
    floor = min(float(vis[order[0]]), max(0.5, float(vis[order[0]]) - 0.25))
    for i in order:
        if len(chosen) >= k:
            break
        if (not chosen or vis[i] >= floor) and all(float(dirs[i] @ dirs[j]) < cos_sep for j in chosen):
            chosen.append(int(i))
    return chosen


def _choose_lazily(cost: np.ndarray, gfill: np.ndarray, visibility, dirs: np.ndarray, k: int, cfg: EndPoseConfig,
                   cos_sep: float, first: int = 2) -> tuple:
    """(chosen, total, vis): the k end poses among E viewpoints (cost [E] ascending, go-to coverage gfill [E], view
    directions dirs [E, 3]) as if every one had its total = cost + w_visibility (1 - visibility) + w_goto_fill
    (coverage above GOTO_FILL_FREE) computed, with ``visibility(positions) -> [len]`` called on as few as decide it:
    a viewpoint j not yet evaluated has a total of at least base_j = cost_j + its coverage term (floating-point sums
    are monotone), so an evaluated one whose total is below every unevaluated base (or equal with an earlier
    position: ties keep the order of positions) comes before all of them, whatever they give. Viewpoints are
    evaluated by base, max(2, k, first) first, each next batch twice as many. total, vis [E]: NaN where not
    evaluated."""
    n = len(cost)
    fill = cfg.w_goto_fill * np.maximum(0.0, gfill - GOTO_FILL_FREE)
    base = cost + fill
    by_base = np.argsort(base, kind="stable")
    total, vis = np.full(n, np.nan), np.full(n, np.nan)
    e, step = 0, max(2, k, int(first))
    while True:
        rows = by_base[e: e + step]
        vis[rows] = visibility(rows)
        total[rows] = cost[rows] + cfg.w_visibility * (1 - vis[rows]) + fill[rows]
        e, step = e + len(rows), 2 * step
        done = by_base[:e]
        order = done[np.lexsort((done, total[done]))]  # by total, ties by position (as a stable sort of all)
        rest = by_base[e:]
        if len(rest):  # settled: below every unevaluated base, or equal to those with a later position only
            t_o = total[order][:, None]
            ok = np.all((base[rest][None] > t_o) | ((base[rest][None] == t_o) & (rest[None] > order[:, None])), 1)
            settled = order[: int(np.argmin(ok)) if not ok.all() else len(order)]  # a prefix of the full order
        else:
            settled = order
        chosen = _greedy(settled, vis, dirs, k, cos_sep)
        if len(chosen) >= k or e == n:
            break
    for i in order:  # too few distinct ones (everything evaluated): the next best in order
        if len(chosen) >= k:
            break
        if int(i) not in chosen:
            chosen.append(int(i))
    return chosen, total, vis


def choose_end_poses(planner: "Planner", subject: TargetObject, goto: Optional[TargetObject], framing: FramingConfig,
                     component: int, k: int = 1, config: Optional[EndPoseConfig] = None,
                     facing: Optional[np.ndarray] = None,
                     samples: Optional[SubjectSamples] = None) -> EndPoseChoice:
    """Up to ``k`` end poses (best first, module docstring) for a shot that looks at ``subject`` and ends near
    ``goto`` (None: "a good view of the subject"), reachable in free component ``component`` of the prepared grid.
    ``facing`` [3]: a unit direction from the subject that views are preferred from when there is no go-to object.
    ``samples``: the subject's visibility samples when the caller has them (else drawn here, config.samples)."""
    t0 = time.perf_counter()
    cfg = config or EndPoseConfig()
    cfg.validate()
    framing.validate()
    planner.ready()  # prepared before anything is sampled (raises a clear error otherwise)
    up = np.asarray(planner.config.up, np.float64)
    up = up / np.linalg.norm(up)
    extra, sphere = _directions(subject, goto, up, cfg)  # [D', 3], [D, 3]
    c = subject.centre
    # the viewpoints: for each of the framing's sizes, toward the go-to, then around the sphere
    rings = [_ring(subject, extra, up, framing)] if len(extra) else []
    rings.append(_sphere_ring(subject, sphere, up, framing, cfg))
    d = np.concatenate([r.d for r in rings])
    pts = np.concatenate([r.pts for r in rings], axis=1).reshape(-1, 3)  # [len(fills) * D, 3]
    dir_all = np.concatenate([np.concatenate([extra, sphere])] * len(_fills(framing)))
    considered = len(pts)
    notes: List[str] = []
    keep = _feasible(planner, pts, (subject, goto), component)
    size, whole = _ring_sizes(rings, np.flatnonzero(keep), subject, up, framing)  # the free viewpoints only
    pts, dir_all = pts[keep], dir_all[keep]
    if len(pts) == 0:
        notes.append("every sampled viewpoint is occupied, unreachable from the start, inside the go-to or subject, "
                     "or outside the planning region")
        return EndPoseChoice([], considered, 0, framing.framing, 1e3 * (time.perf_counter() - t0), notes)
    elev = np.degrees(np.arcsin(np.clip(dir_all @ up, -1, 1)))
    cost = (cfg.w_size * size_cost(size, framing) + cfg.w_whole * (~whole)
            + cfg.w_elevation * ((elev - cfg.eye_elevation_deg) / 45.0) ** 2)
    gdist = np.zeros(len(pts))
    if goto is not None:
        glo, ghi = goto.box()
        gdist = _box_distance(pts, glo, ghi)
        # in units of the subject's distance from the go-to object: halfway between them costs w_goto / 2
        scale = max(float(_box_distance(c[None], glo, ghi)[0]), float(np.median(d)), 1e-6)
        cost = cost + cfg.w_goto * gdist / scale
    elif facing is not None:
        f = np.asarray(facing, np.float64)
        if np.linalg.norm(f) > 1e-9:
            cost = cost + cfg.w_facing * 0.5 * (1 - dir_all @ (f / np.linalg.norm(f)))
    cos_sep = math.cos(math.radians(cfg.min_separation_deg))
    top = _to_evaluate(cost, dir_all, min(len(pts), cfg.evaluated + 2 * (k - 1)), cos_sep)
    vol = visibility_volume(planner)
    if samples is None:
        samples = (SubjectSamples.of_point(c) if subject.is_point
                   else subject_samples(vol, subject.members, cfg.samples))

    gfill = (frame_coverage(pts[top], c, up, goto, framing) if goto is not None and not goto.is_point
             else np.zeros(len(top)))
    # the first batch keeps every thread of the compiled walk busy (MIN_SEGMENTS_PER_THREAD segments each)
    first = -(-kernel_threads() * MIN_SEGMENTS_PER_THREAD // len(samples.points))
    chosen, total, vis = _choose_lazily(cost[top], gfill, lambda rows: subject_visibility(vol, pts[top[rows]], samples),
                                        dir_all[top], k, cfg, cos_sep, first)
    poses = [EndPose(point=pts[top[i]].copy(), cost=float(total[i]), visibility=float(vis[i]), size=float(size[top[i]]),
                     whole=bool(whole[top[i]]), goto_distance=float(gdist[top[i]]), goto_fill=float(gfill[i]),
                     elevation_deg=float(elev[top[i]])) for i in chosen]
    return EndPoseChoice(poses, considered, int(keep.sum()), framing.framing, 1e3 * (time.perf_counter() - t0), notes)
