"""A go-to or look-at target as the planner sees it: a point, or an object (its Gaussians in the obstacle scene)."""
from __future__ import annotations

import threading
import weakref
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from ..errors import InvalidInputError
from ..geometry.visibility import SplatVolume, SubjectSamples
from ..scene.ellipsoids import EllipsoidScene

EXTENT_POINTS = 512
"""At most this many of an object's Gaussian means describe its extent (framing, frame coverage)."""
POINT_RADIUS = 0.1
"""Radius given to a point target's extent when none is said (scene units; cinesplat-plan --object-radius)."""


@dataclass
class TargetObject:
    """A target: ``centre`` [3] (where the camera looks or goes), its Gaussians ``members`` [K] (indices into the
    obstacle scene; empty for a point), ``extent`` [P, 3] points that outline it, grown by ``pad`` (a median sigma of
    its Gaussians; for a point, 0) and ``spacing`` (the typical gap between extent points: ``gap()``)."""

    name: str
    centre: np.ndarray
    members: np.ndarray
    extent: np.ndarray
    pad: float
    spacing: Optional[float] = None  # None: the set-up's, made on first use (gap())
    outline: Optional[np.ndarray] = None  # [H, 3] the extent's convex hull vertices (None: the extent itself)
    parts: Optional["ObjectParts"] = field(default=None, repr=False, compare=False)  # kept set-up (of_members)

    def outline_points(self) -> np.ndarray:
        """The points whose projection bounds the object's: the convex hull's vertices (a perspective projection maps
        the hull onto the hull of the projected vertices, so their box is the extent's, when all are in front)."""
        if self.outline is None and self.parts is not None:
            self.outline = self.parts.hull()  # on first use: a go-to object never needs it
        return self.extent if self.outline is None else self.outline

    def gap(self) -> float:
        """The typical gap between extent points: ``spacing``, else the set-up's, made on first use (only a go-to
        object's frame coverage reads it: a look-at subject's first request skips the nearest-neighbour search)."""
        if self.spacing is None:
            self.spacing = self.parts.spacing if self.parts is not None else _spacing(self.extent)
        return self.spacing

    @property
    def memo(self) -> Optional[dict]:
        """What later stages derive from this object and keep with its set-up (None: not kept)."""
        return None if self.parts is None else self.parts.derived

    @property
    def is_point(self) -> bool:
        return self.members.size == 0

    def box(self) -> tuple:
        """(lo [3], hi [3]) of the extent grown by the pad."""
        return self.extent.min(0) - self.pad, self.extent.max(0) + self.pad

    def radius(self) -> float:
        """Largest distance from the centre to an extent point, pad included."""
        return float(np.linalg.norm(self.extent - self.centre[None], axis=1).max() + self.pad)

    @classmethod
    def point(cls, p, radius: float = POINT_RADIUS, name: str = "point") -> "TargetObject":
        """A point target with a small ball of ``radius`` as its extent (its six axis points)."""
        c = np.asarray(p, np.float64).reshape(3)
        if not (np.all(np.isfinite(c)) and np.isfinite(radius) and radius >= 0):
            raise InvalidInputError(f"a point target must be finite with a radius >= 0, got {c.tolist()}, {radius}")
        ext = c[None] + radius * np.concatenate([np.eye(3), -np.eye(3)])
        return cls(name=name, centre=c, members=np.zeros(0, np.int64), extent=ext, pad=0.0, spacing=max(radius, 1e-6))

    @classmethod
    def of_members(cls, vol: SplatVolume, members, centre, name: str = "object",
                   seed: int = 0) -> "TargetObject":
        """An object from its Gaussians ``members`` (bool [N] mask or indices into the obstacle scene, whose
        SplatVolume ``vol`` holds their means and scales in float64: no tensor conversion per request). What depends
        only on the members (extent, pad, spacing, hull) is kept on the volume for the next request (object_parts)."""
        parts = object_parts(vol, members, name, seed)
        if centre is not None:
            c = np.asarray(centre, np.float64).reshape(3)
        else:
            c = parts.mean_centre(vol)
        return cls(name=name, centre=c, members=parts.members, extent=parts.extent, pad=parts.pad, parts=parts)


OBJECT_MEMO = 8
"""Objects whose set-up (ObjectParts) a volume keeps, least recently used dropped first."""
_MEMO_LOCK = threading.Lock()


@dataclass
class ObjectParts:
    """What an object's set-up derives from its members alone (arrays read-only: shared by every request that names
    the same Gaussians), and what later stages derive from them (``derived``: e.g. the subject's visibility samples,
    end_pose's viewpoint sizes), kept with it."""

    members: np.ndarray  # [K] int64, sorted, unique
    extent: np.ndarray  # [P, 3]
    pad: float
    derived: dict = field(default_factory=dict, repr=False)
    _hull: Any = field(default=False, repr=False)  # False: not yet computed
    _mean: Optional[np.ndarray] = field(default=None, repr=False)
    _gap: Optional[float] = field(default=None, repr=False)

    @property
    def spacing(self) -> float:
        """The typical gap between extent points (_spacing), made on first use."""
        if self._gap is None:
            self._gap = _spacing(self.extent)
        return self._gap

    def hull(self) -> Optional[np.ndarray]:
        """The extent's convex hull vertices [H, 3] (read-only), or None when too few or flat; made on first use."""
        if self._hull is False:
            h = _hull(self.extent)
            if h is not None:
                h.setflags(write=False)
            self._hull = h
        return self._hull

    def mean_centre(self, vol: SplatVolume) -> np.ndarray:
        """The members' mean [3] (a copy), one column at a time (numpy's axis-0 mean of [K, 3] is ~10x slower)."""
        if self._mean is None:
            self._mean = np.array([np.take(vol.means[:, a], self.members).mean() for a in range(3)])
        return self._mean.copy()


def object_parts(vol: SplatVolume, members, name: str = "object", seed: int = 0) -> ObjectParts:
    """The set-up of the object whose Gaussians are ``members`` (bool [N] mask or ids): taken from the volume's memo
    when the same members (same ids, compared in full) were set up before with the same seed, built otherwise."""
    m = np.asarray(members)
    if m.dtype == bool:
        if m.shape != (len(vol),):
            raise InvalidInputError(f"an object mask must be [N={len(vol)}], got {m.shape}")
        m = np.flatnonzero(m)
    m = _sorted_unique(m.astype(np.int64).reshape(-1))
    if m.size == 0:
        raise InvalidInputError(f"the object '{name}' has no Gaussians among the obstacles")
    if m[0] < 0 or m[-1] >= len(vol):
        raise InvalidInputError(f"object member ids must be in [0, {len(vol)}), got {m[0]}..{m[-1]}")
    key = (int(seed), m.size, int(m[0]), int(m[-1]), int(m[:: max(1, m.size // 64)].sum()))
    with _MEMO_LOCK:  # requests of several viewer clients may run at once
        memo = vol.memo.setdefault("objects", OrderedDict())
        hit = memo.get(key)
        if hit is not None and np.array_equal(hit.members, m):
            memo.move_to_end(key)
            return hit
    parts = _build_parts(vol, m, seed)  # outside the lock: the slow part
    with _MEMO_LOCK:
        memo[key] = parts
        while len(memo) > OBJECT_MEMO:
            memo.popitem(last=False)
    return parts


def _build_parts(vol: SplatVolume, m: np.ndarray, seed: int) -> ObjectParts:
    """ObjectParts of sorted unique member ids m [K] (their arrays made read-only)."""
    pick = None if m.size <= EXTENT_POINTS else np.sort(np.random.default_rng(seed).choice(
        m.size, EXTENT_POINTS, replace=False))
    ext = np.take(vol.means, m if pick is None else m[pick], axis=0)  # [P, 3] (np.take: faster than m-indexing)
    for a in (m, ext):
        a.setflags(write=False)
    return ObjectParts(members=m, extent=ext, pad=exact_median(np.take(vol.sigma_max, m)))


def subject_samples(vol: SplatVolume, members, n_samples: int, seed: int = 0) -> SubjectSamples:
    """SubjectSamples.of_members of an object's Gaussians, kept with its ObjectParts (the same draw, its box and its
    packed classes for the next request that looks at the same object; arrays read-only)."""
    parts = object_parts(vol, members)
    key = ("samples", int(n_samples), int(seed))
    got = parts.derived.get(key)
    if got is None:
        got = SubjectSamples.of_members(vol, parts.members, n_samples, seed)
        for a in (got.points, got.weights, got.ids):
            a.setflags(write=False)
        parts.derived[key] = got
    return got


def exact_median(v: np.ndarray, sample: int = 1024, backend: str = "auto") -> float:
    """np.median(v) of a 1-d float array, exactly (the same value, the same arithmetic for an even count), in a
    fraction of its time for large v: two values of a strided sample of ``sample`` bracket the middle, one pass counts
    what lies below and above the bracket and keeps what lies in it, and only that is partitioned; when the bracket
    misses the middle (or v has NaN), np.median itself. backend: of the pass ("auto": native/targets.c when it loads,
    "native", "python")."""
    from ..native import bracket_c, choose

    n = v.size
    if n <= 4 * sample:
        return float(np.median(v))
    smp = np.sort(v[:: n // sample])
    q = smp.size
    w = int(2 * np.sqrt(q)) + 2  # the sample's middle +- 4 of its standard deviations (in ranks)
    lo, hi = smp[max(0, q // 2 - w)], smp[min(q - 1, q // 2 + w)]
    fn = choose(backend, bracket_c, "targets", "median bracket")
    if fn is not None:
        vc = np.ascontiguousarray(v, np.float64)
        mid, counts = np.empty(n), np.zeros(2, np.int64)
        mid = mid[: fn(vc.ctypes.data, n, float(lo), float(hi), mid.ctypes.data, counts.ctypes.data)]
        below, above = int(counts[0]), int(counts[1])
    else:
        mid = v[(v >= lo) & (v <= hi)]
        below, above = int(np.count_nonzero(v < lo)), int(np.count_nonzero(v > hi))
    k1, k2 = (n - 1) // 2 - below, n // 2 - below  # the middle ranks (equal for an odd n) within the bracket
    if not (0 <= k1 and k2 < mid.size) or below + mid.size + above != n:  # missed, or NaN
        return float(np.median(v))
    part = np.partition(mid, (k1, k2))
    return float(part[k2] if n % 2 else np.mean(part[k1: k2 + 1]))


def _sorted_unique(ids: np.ndarray) -> np.ndarray:
    """ids [K] sorted without repeats (no sort when they already are: masks' flatnonzero)."""
    if ids.size > 1 and not bool(np.all(ids[1:] > ids[:-1])):
        return np.unique(ids)
    return ids


def _hull(points: np.ndarray) -> Optional[np.ndarray]:
    """The convex hull vertices [H, 3] of points [P, 3], or None when they are too few or flat."""
    if len(points) < 5:
        return None
    from scipy.spatial import ConvexHull, QhullError

    try:
        return points[ConvexHull(points).vertices]
    except (QhullError, ValueError):
        return None


def _spacing(points: np.ndarray, backend: str = "auto") -> float:
    """Median distance from each point [P, 3] to its nearest other point (0 for fewer than two points). backend:
    "auto" (native/targets.c's sweep along x when it loads), "native", "python" (a k-d tree)."""
    if len(points) < 2:
        return 0.0
    from ..native import choose, nearest_gaps_c

    fn = choose(backend, nearest_gaps_c, "targets", "nearest gaps")
    if fn is not None and np.all(np.isfinite(points)):
        pts = np.ascontiguousarray(points, np.float64)
        order = np.ascontiguousarray(np.argsort(pts[:, 0], kind="stable"), np.int64)
        d = np.empty(len(pts))
        fn(pts.ctypes.data, len(pts), order.ctypes.data, d.ctypes.data)
        return float(np.median(d))
    from scipy.spatial import cKDTree

    d, _ = cKDTree(points).query(points, k=2)
    return float(np.median(d[:, 1]))


def scene_members(scene: EllipsoidScene, source_mask: Optional[np.ndarray]) -> Optional[np.ndarray]:
    """Indices [K] of the obstacle scene's Gaussians whose source Gaussian (scene.source_index) is in ``source_mask``
    (bool over the splat the scene was built from); None when there is no mask."""
    if source_mask is None:
        return None
    mask = np.asarray(source_mask, bool).reshape(-1)
    if scene.source_index is None:
        if mask.shape != (len(scene),):
            raise InvalidInputError(f"object mask has {mask.shape[0]} entries for a scene of {len(scene)} Gaussians")
        return np.flatnonzero(mask)
    src, top, inv, ascending = _source_on_host(scene.source_index)
    if src.size and top >= mask.shape[0]:
        raise InvalidInputError(f"object mask has {mask.shape[0]} entries, the scene's Gaussians come from more")
    if inv is None:  # a source Gaussian behind several obstacles: the gather over all of them
        return np.flatnonzero(mask[src])
    ids = inv[np.flatnonzero(mask[: top + 1])]  # each selected source Gaussian's obstacle (-1: none)
    ids = ids[ids >= 0]
    return ids if ascending else np.sort(ids)


_SOURCES: dict = {}  # id(tensor) -> (weak reference, _source_on_host's answer)


def _source_on_host(source_index) -> tuple:
    """(scene.source_index as a host array [N] int64, its largest value, its inverse inv [top + 1] (the obstacle of
    each source Gaussian, -1: none; None when a source Gaussian has several), whether the source ids grow with the
    obstacle index), made once per tensor: on a GPU scene the copy and its max are a device sync and an 8 MB
    transfer at 1M Gaussians, per object per request otherwise; the inverse turns a mask's selection into obstacle
    ids in O(K) after one pass over the mask, instead of a gather over all N obstacles."""
    key = id(source_index)
    hit = _SOURCES.get(key)
    if hit is not None and hit[0]() is source_index:
        return hit[1]
    src = source_index.detach().cpu().numpy().astype(np.int64, copy=False)
    top = int(src.max()) if src.size else -1
    ascending = bool(np.all(src[1:] > src[:-1]))
    inv = None
    if src.size and int(src.min()) >= 0:
        inv = np.full(top + 1, -1, np.int64)
        inv[src] = np.arange(src.size)
        if int(np.count_nonzero(inv >= 0)) != src.size:  # not one obstacle per source Gaussian
            inv = None
    for k in [k for k, v in _SOURCES.items() if v[0]() is None]:  # forget tensors that are gone
        del _SOURCES[k]
    _SOURCES[key] = (weakref.ref(source_index), (src, top, inv, ascending))
    return src, top, inv, ascending
