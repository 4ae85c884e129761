"""How much of a subject a camera sees through the splat: alpha-composited transmittance to samples of the subject.

The planner's obstacles are hard ellipsoids; what a viewer sees is the splat's semi-transparent Gaussians. Here each
Gaussian j (mean mu_j, rotation R_j, scales sigma_j, opacity o_j) has, along a segment x(t) = p0 + t (p1 - p0),
t in [0, 1], the alpha

    a_j = min(o_j exp(-m_j^2 / 2), ALPHA_MAX),   m_j^2 = min_t |diag(1 / sigma_j) R_j^T (x(t) - mu_j)|^2,

the 3D ray-tracing approximation of the rasteriser's 2D alpha (the Gaussian's peak density along the ray), counted
for m_j < CUT_SIGMA (beyond, a_j < 1.1% of o_j). The transmittance of the segment is prod_j (1 - a_j); in optical
depth tau = sum_j -log(1 - a_j), split by a class per Gaussian (0: other, 1: the subject).

A subject is S samples of its own Gaussians' means (drawn in proportion to opacity x area). Seen from a camera p, sample
s is reached by the light of the subject with weight w_s exp(-tau_subject(p, s)) when the subject is rendered alone
(its own Gaussians in front of it hide it), and with weight w_s exp(-tau_subject - tau_other) through the whole splat.
The visible fraction of the subject is the ratio of the two sums: what a label render of the subject through the
splat divided by the subject rendered alone measures, with S point samples instead of pixels (an approximation: the
alpha of a Gaussian here is its 3D peak along the segment, not gsplat's projected 2D footprint; each sample ignores
its own Gaussian). Against rendered label images of small test scenes it agrees to within 0.10 for a compact subject
and 0.15 for a loose one of large Gaussians (tests/planner/geometry/test_visibility.py).

Gaussians are found through a uniform grid of cells (``SplatVolume``, built once per scene): each cell lists the
Gaussians whose cut-off box meets it; Gaussians spanning more than MAX_CELLS cells are tested for every segment. The
compiled walk (native/visibility.c) and the numpy path give the same sums as the brute-force float64 reference
(``optical_depth_reference``), which tests every Gaussian.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ..errors import InvalidInputError
from ..scene.ellipsoids import EllipsoidScene

CUT_SIGMA = 3.0
"""Gaussians farther than this many sigmas from a segment do not attenuate it (alpha < 1.1% of the opacity)."""
ALPHA_MAX = 0.99
"""Largest alpha of one Gaussian (as in 3DGS rasterisers)."""
STOP_SELF = 12.0
"""subject_visibility stops a sample's walk once the subject hides it from itself by this optical depth (its light is
then below exp(-12) = 6e-6 of its weight)."""
COARSE = 8
"""The coarse grid's cell, in fine cells."""
MIN_SEGMENTS_PER_THREAD = 16
"""The compiled walk starts another thread only for at least this many more segments."""
MAX_CELLS = 512
"""A Gaussian whose cut-off box spans more cells than this is tested for every segment instead of listed in cells."""
CELLS_LONG_SIDE = 128
"""Cells along the volume box's longest side (the cell is never smaller than the median Gaussian's cut-off box)."""
SPHERE_MARGIN = 1e-6
"""The compiled walk's first test leaves a Gaussian out only beyond CUT_SIGMA sigma_max (1 + this) of the segment:
far beyond rounding, so it leaves out only Gaussians the whole test leaves out."""


@dataclass
class SplatVolume:
    """The splat as semi-transparent Gaussians in a cell grid over the box [lo, lo + dims * cell]."""

    means: np.ndarray  # [N, 3] float64
    whiten: np.ndarray  # [N, 3, 3] float64: diag(1 / sigma) R^T (world -> sigma units)
    opacity: np.ndarray  # [N] float64
    lo: np.ndarray  # [3] float64
    cell: float
    dims: np.ndarray  # [3] int64
    cell_start: np.ndarray  # [C + 1] int64 (C = prod(dims), cells in C order)
    cell_ids: np.ndarray  # [E] int32
    ccell: float  # the coarse grid's cell (COARSE x cell, same lo): Gaussians too large for the fine cells
    cdims: np.ndarray  # [3] int64
    ccell_start: np.ndarray  # [C' + 1] int64
    ccell_ids: np.ndarray  # [E'] int32
    big: np.ndarray  # [B] int32: Gaussians tested for every segment (too large for the coarse cells too)
    packed: np.ndarray  # [N, 13] float64: mean, whitening rows, opacity, in the compiled walk's order (by cell)
    rank: np.ndarray  # [N] int64: a Gaussian's row in ``packed`` (cell_ids and big hold rows of ``packed``)
    perm: np.ndarray  # [N] int64: the Gaussian of each row of ``packed`` (rank's inverse)
    half: np.ndarray  # [N, 3] float64: half widths of each Gaussian's cut-off box
    sigma_max: np.ndarray  # [N] float64: each Gaussian's largest sigma
    cover: np.ndarray  # [N] float64: opacity x the area of its two largest axes (what it covers on screen)
    sphere: Optional[np.ndarray] = field(default=None, repr=False)
    """[N, 4] float64 in ``packed``'s row order: mean, sigma_max^2 (1 + SPHERE_MARGIN): the compiled walk's cheap
    first test (a segment farther from the mean than CUT_SIGMA of them misses the Gaussian's cut-off)."""
    memo: dict = field(default_factory=dict, repr=False, compare=False)
    """What callers derive from this volume and keep for later requests (shots/target_object.py: objects' set-up);
    a re-prepared planner builds a new volume, so nothing in it outlives the volume it was derived from."""

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @classmethod
    def build(cls, scene: EllipsoidScene, lo, hi, cut_sigma: float = CUT_SIGMA) -> "SplatVolume":
        """The volume of an obstacle scene's Gaussians (scales = radii / (beta * opacity)) over the box [lo, hi]
        (Gaussians whose cut-off box misses it are left out: segments are clipped to it)."""
        lo = np.asarray(lo, np.float64).reshape(3)
        hi = np.asarray(hi, np.float64).reshape(3)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
            raise InvalidInputError(f"the visibility box must be finite with lo < hi, got {lo.tolist()}, {hi.tolist()}")
        means = scene.means.detach().cpu().double().numpy()  # [N, 3]
        rot = scene.rotations.detach().cpu().double().numpy()  # [N, 3, 3]
        opac = scene.opacities.detach().cpu().double().numpy()  # [N]
        sigma = scene.radii.detach().cpu().double().numpy() / (scene.beta * np.maximum(opac, 1e-6))[:, None]
        whiten = np.transpose(rot, (0, 2, 1)) / sigma[:, :, None]  # rows: R^T scaled by 1 / sigma
        half = cut_sigma * np.sqrt(((rot * sigma[:, None, :]) ** 2).sum(-1))  # [N, 3] cut-off box half widths
        glo, ghi = means - half, means + half
        inside = np.all((ghi >= lo) & (glo <= hi), axis=1)
        ext = float((hi - lo).max())
        med = float(np.median(2 * half[inside].max(1))) if inside.any() else ext
        cell = max(ext / CELLS_LONG_SIDE, min(med, ext / 8))
        dims = np.maximum(np.ceil((hi - lo) / cell).astype(np.int64), 1)
        ids = np.flatnonzero(inside)
        pad = 1e-9 * ext  # rounding: a box is listed in every cell it might touch
        start, listed, rest = _cell_lists(ids, glo, ghi, lo, cell, dims, pad)
        # the Gaussians too large for the fine cells go to a coarse grid (COARSE x the cell, same lo); the few too
        # large even for it are tested for every segment
        ccell = COARSE * cell
        cdims = np.maximum(np.ceil((hi - lo) / ccell).astype(np.int64), 1)
        cstart, clisted, big = _cell_lists(rest, glo, ghi, lo, ccell, cdims, pad)
        # the compiled walk reads Gaussians in the order of their means' cells: a cell's Gaussians lie together in
        # memory (several times faster than scene order on a 400k room)
        home = np.clip(np.floor((means - lo) / cell), 0, dims - 1).astype(np.int64)
        perm = np.argsort((home[:, 0] * dims[1] + home[:, 1]) * dims[2] + home[:, 2], kind="stable")
        rank = np.empty(len(perm), np.int64)
        rank[perm] = np.arange(len(perm))
        packed = np.concatenate([means, whiten.reshape(-1, 9), opac[:, None]], 1)[perm]
        sig_sorted = np.sort(sigma, axis=1)
        sphere = np.concatenate([means, (sig_sorted[:, 2:] ** 2) * (1 + SPHERE_MARGIN)], 1)[perm]
        return cls(means=np.ascontiguousarray(means), whiten=np.ascontiguousarray(whiten), opacity=opac,
                   half=half, sigma_max=sig_sorted[:, 2].copy(), cover=opac * sig_sorted[:, 1] * sig_sorted[:, 2],
                   lo=lo, cell=float(cell), dims=dims, cell_start=start,
                   cell_ids=np.ascontiguousarray(rank[listed].astype(np.int32)), ccell=float(ccell), cdims=cdims,
                   ccell_start=cstart, ccell_ids=np.ascontiguousarray(rank[clisted].astype(np.int32)),
                   big=np.ascontiguousarray(rank[big].astype(np.int32)), packed=np.ascontiguousarray(packed),
                   rank=rank, perm=perm, sphere=np.ascontiguousarray(sphere))


def _cell_lists(ids: np.ndarray, glo: np.ndarray, ghi: np.ndarray, lo: np.ndarray, cell: float, dims: np.ndarray,
                pad: float) -> tuple:
    """(cell starts [C + 1], listed Gaussians [E] (ids, by cell), the ids left out [R]) of the Gaussians ``ids`` whose
    cut-off boxes [glo, ghi] span at most MAX_CELLS cells of the grid (lo, cell, dims)."""
    i0 = np.clip(np.floor((glo[ids] - pad - lo) / cell), 0, dims - 1).astype(np.int64)  # [K, 3]
    i1 = np.clip(np.floor((ghi[ids] + pad - lo) / cell), 0, dims - 1).astype(np.int64)
    span = i1 - i0 + 1
    count = span.prod(1)
    rest = ids[count > MAX_CELLS]
    small = count <= MAX_CELLS
    ids, i0, span, count = ids[small], i0[small], span[small], count[small]
    owner = np.repeat(np.arange(len(ids)), count)  # [E]
    k = np.arange(len(owner)) - np.repeat(np.cumsum(count) - count, count)  # position inside its box
    sy, sz = span[owner, 1], span[owner, 2]
    cx = i0[owner, 0] + k // (sy * sz)
    cy = i0[owner, 1] + (k // sz) % sy
    cz = i0[owner, 2] + k % sz
    cid = (cx * dims[1] + cy) * dims[2] + cz
    order = np.argsort(cid, kind="stable")
    n_cells = int(dims.prod())
    start = np.zeros(n_cells + 1, np.int64)
    np.cumsum(np.bincount(cid, minlength=n_cells), out=start[1:])
    return start, ids[owner[order]], rest


def _contributions(vol_means, whiten, opac, gid: np.ndarray, p0: np.ndarray, d: np.ndarray, cut2: float) -> np.ndarray:
    """-log(1 - alpha) [K] of Gaussians gid [K] on segments p0 [K, 3] + t d [K, 3] (0 beyond the cut-off)."""
    w = whiten[gid]  # [K, 3, 3]
    u = np.einsum("kij,kj->ki", w, p0 - vol_means[gid])
    v = np.einsum("kij,kj->ki", w, d)
    vv = (v * v).sum(1)
    t = np.clip(np.where(vv > 0, -(u * v).sum(1) / np.where(vv > 0, vv, 1.0), 0.0), 0.0, 1.0)
    q = u + t[:, None] * v
    m2 = (q * q).sum(1)
    a = np.minimum(opac[gid] * np.exp(-0.5 * m2), ALPHA_MAX)
    return np.where(m2 < cut2, -np.log1p(-a), 0.0)


def _checked_segments(p0, p1, skip, n: int) -> tuple:
    p0 = np.ascontiguousarray(np.asarray(p0, np.float64).reshape(-1, 3))
    p1 = np.ascontiguousarray(np.asarray(p1, np.float64).reshape(-1, 3))
    if p0.shape != p1.shape:
        raise InvalidInputError(f"segment ends disagree: {p0.shape} vs {p1.shape}")
    if not (np.all(np.isfinite(p0)) and np.all(np.isfinite(p1))):
        raise InvalidInputError("segment ends contain NaN or inf")
    skip = np.full(len(p0), -1, np.int64) if skip is None else np.ascontiguousarray(np.asarray(skip, np.int64))
    if skip.shape != (len(p0),) or np.any(skip >= n):
        raise InvalidInputError(f"skip must be [L={len(p0)}] Gaussian ids < {n} or -1")
    return p0, p1, skip


def _checked_classes(classes, n: int) -> np.ndarray:
    cls = np.zeros(n, np.uint8) if classes is None else np.ascontiguousarray(np.asarray(classes).astype(np.uint8))
    if cls.shape != (n,):
        raise InvalidInputError(f"classes must be [N={n}], got {cls.shape}")
    return cls


def optical_depth_reference(vol: SplatVolume, p0, p1, classes=None, skip=None,
                            cut_sigma: float = CUT_SIGMA) -> np.ndarray:
    """Brute-force float64 reference of optical_depth: every segment against every Gaussian of the volume (the grid
    and its box are not used: no clipping). Returns tau [L, 2]."""
    n = len(vol)
    p0, p1, skip = _checked_segments(p0, p1, skip, n)
    cls = _checked_classes(classes, n)
    tau = np.zeros((len(p0), 2))
    for l in range(len(p0)):
        gid = np.arange(n)
        c = _contributions(vol.means, vol.whiten, vol.opacity, gid, np.broadcast_to(p0[l], (n, 3)),
                           np.broadcast_to(p1[l] - p0[l], (n, 3)), cut_sigma ** 2)
        if skip[l] >= 0:
            c[skip[l]] = 0.0
        tau[l, 0] = c[cls == 0].sum()
        tau[l, 1] = c[cls == 1].sum()
    return tau


def _cells_along(vol: SplatVolume, a: np.ndarray, b: np.ndarray, cell: Optional[float] = None,
                 dims: Optional[np.ndarray] = None) -> np.ndarray:
    """Every cell id a segment a -> b (each [3], inside the box) may pass in the grid (vol.lo, cell, dims; default
    the fine one): the cells of each piece's box, pieces no longer than a cell (a superset of the compiled walk's)."""
    cell = vol.cell if cell is None else cell
    dims = vol.dims if dims is None else dims
    n = max(1, int(np.ceil(np.linalg.norm(b - a) / cell)))
    t = np.linspace(0.0, 1.0, n + 1)
    pts = a[None] + t[:, None] * (b - a)[None]  # [n + 1, 3]
    lo = np.minimum(pts[:-1], pts[1:])
    hi = np.maximum(pts[:-1], pts[1:])
    pad = 1e-9 * cell
    i0 = np.clip(np.floor((lo - pad - vol.lo) / cell), 0, dims - 1).astype(np.int64)
    i1 = np.clip(np.floor((hi + pad - vol.lo) / cell), 0, dims - 1).astype(np.int64)
    cells = []
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                c = np.minimum(i0 + np.array([dx, dy, dz]), i1)
                cells.append((c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2])
    return np.unique(np.concatenate(cells))


def _clip_to_box(vol: SplatVolume, p0: np.ndarray, p1: np.ndarray) -> Optional[tuple]:
    """The part of segment p0 -> p1 inside the volume's box as (a, b), or None when it misses the box."""
    hi = vol.lo + vol.dims * vol.cell
    d = p1 - p0
    t0, t1 = 0.0, 1.0
    for k in range(3):
        if d[k] == 0.0:
            if p0[k] < vol.lo[k] or p0[k] > hi[k]:
                return None
            continue
        ta, tb = sorted(((vol.lo[k] - p0[k]) / d[k], (hi[k] - p0[k]) / d[k]))
        t0, t1 = max(t0, ta), min(t1, tb)
        if t0 > t1:
            return None
    return p0 + t0 * d, p0 + t1 * d


def optical_depth_walk_reference(vol: SplatVolume, p0, p1, classes=None, skip=None,
                         cut_sigma: float = CUT_SIGMA) -> np.ndarray:
    """optical_depth without the compiled walk: the cells of each segment's pieces, their Gaussians once each."""
    n = len(vol)
    p0, p1, skip = _checked_segments(p0, p1, skip, n)
    cls = _checked_classes(classes, n)
    tau = np.zeros((len(p0), 2))
    perm = vol.perm
    for l in range(len(p0)):
        clip = _clip_to_box(vol, p0[l], p1[l])
        rows = vol.big.astype(np.int64)
        if clip is not None:
            cells = _cells_along(vol, *clip)
            parts = [vol.cell_ids[vol.cell_start[c]:vol.cell_start[c + 1]] for c in cells]
            coarse = _cells_along(vol, *clip, cell=vol.ccell, dims=vol.cdims)
            parts += [vol.ccell_ids[vol.ccell_start[c]:vol.ccell_start[c + 1]] for c in coarse]
            rows = np.concatenate([rows] + [p.astype(np.int64) for p in parts])
        gid = np.unique(perm[rows])
        if skip[l] >= 0:
            gid = gid[gid != skip[l]]
        if gid.size == 0:
            continue
        c = _contributions(vol.means, vol.whiten, vol.opacity, gid, np.broadcast_to(p0[l], (len(gid), 3)),
                           np.broadcast_to(p1[l] - p0[l], (len(gid), 3)), cut_sigma ** 2)
        tau[l, 0] = c[cls[gid] == 0].sum()
        tau[l, 1] = c[cls[gid] == 1].sum()
    return tau


def optical_depth(vol: SplatVolume, p0, p1, classes=None, skip=None, backend: str = "auto",
                  cut_sigma: float = CUT_SIGMA, stop1: float = math.inf, stop0: float = math.inf,
                  after1: Optional[np.ndarray] = None, threads: Optional[int] = None,
                  packed_classes: Optional[np.ndarray] = None) -> np.ndarray:
    """tau [L, 2]: optical depth of each segment p0[l] -> p1[l] ([L, 3] each) through the volume's Gaussians of class 0
    and of class 1 (``classes`` [N] 0/1, default all 0); ``skip`` [L]: a Gaussian each segment ignores (-1: none).
    backend: "auto" (the compiled walk when it loads), "native", "python" (optical_depth_walk_reference: whole sums).
    stop1: the compiled walk of a segment may stop once its class-1 depth exceeds this (both sums are then partial;
    its light is below exp(-stop1) anyway): a segment from a subject's sample toward a camera stops inside the subject
    when the subject hides that sample itself. stop0 / after1 [L]: it may also stop once its class-0 depth exceeds
    stop0 beyond the parameter after1[l] past which no class-1 Gaussian lies (class 1's sum stays whole).
    threads: of the compiled walk (None: native.kernel_threads(); the sums do not depend on it). packed_classes:
    ``classes`` already in the volume's row order (vol.packed_classes), which saves an O(N) gather per call."""
    from ..native import choose, kernel_threads, optical_depth_c

    if threads is not None and not int(threads) >= 1:
        raise InvalidInputError(f"threads must be >= 1, got {threads}")
    fn = choose(backend, optical_depth_c, "visibility", "optical depth")
    if fn is None:
        if classes is None and packed_classes is not None:
            classes = np.asarray(packed_classes)[vol.rank]
        return optical_depth_walk_reference(vol, p0, p1, classes, skip, cut_sigma)
    n = len(vol)
    p0, p1, skip = _checked_segments(p0, p1, skip, n)
    if len(p0) >= 2**31 - 1:
        raise InvalidInputError(f"too many segments in one call ({len(p0)}); split them")
    if packed_classes is not None:
        cls = np.ascontiguousarray(_checked_classes(packed_classes, n))
    else:
        cls = np.ascontiguousarray(_checked_classes(classes, n)[vol.perm])  # in packed's row order
    n_threads = kernel_threads() if threads is None else int(threads)
    # a thread walks at least MIN_SEGMENTS_PER_THREAD segments: starting one costs more than a few walks
    n_threads = max(1, min(n_threads, len(p0) // MIN_SEGMENTS_PER_THREAD))
    skip = np.ascontiguousarray(np.where(skip >= 0, vol.rank[np.maximum(skip, 0)], -1))
    tau = np.zeros((len(p0), 2))
    if len(p0) == 0:
        return tau
    dims = np.ascontiguousarray(vol.dims, np.int64)
    cdims = np.ascontiguousarray(vol.cdims, np.int64)
    rc = fn(vol.packed.ctypes.data, None if vol.sphere is None else vol.sphere.ctypes.data, cls.ctypes.data, n,
            vol.lo.ctypes.data, vol.cell, dims.ctypes.data, vol.cell_start.ctypes.data, vol.cell_ids.ctypes.data,
            vol.ccell, cdims.ctypes.data, vol.ccell_start.ctypes.data, vol.ccell_ids.ctypes.data,
            vol.big.ctypes.data, len(vol.big), float(cut_sigma) ** 2, p0.ctypes.data, p1.ctypes.data,
            skip.ctypes.data, len(p0), float(stop1), float(stop0),
            None if after1 is None else np.ascontiguousarray(after1, np.float64).ctypes.data, tau.ctypes.data,
            n_threads)
    if rc != 0:
        raise MemoryError("the compiled optical depth could not allocate its work space")
    return tau


@dataclass
class SubjectSamples:
    """Points of a subject to look at: S samples of its Gaussians (or one point for a point subject)."""

    points: np.ndarray  # [S, 3] float64
    weights: np.ndarray  # [S] float64 > 0
    ids: np.ndarray  # [S] int64: the volume Gaussian each sample is the mean of (-1: not a Gaussian)
    members: np.ndarray  # [K] int64: the subject's own Gaussians (class 1); empty for a point
    box: Optional[tuple] = None  # (lo [3], hi [3]) of the members' cut-off boxes (subject_box); None for a point
    _packed: Optional[tuple] = field(default=None, repr=False, compare=False)  # (vol, packed_classes(vol))
    _seen: Optional[tuple] = field(default=None, repr=False, compare=False)  # (vol, {camera bytes: visible fraction})

    @classmethod
    def of_point(cls, point) -> "SubjectSamples":
        p = np.asarray(point, np.float64).reshape(1, 3)
        return cls(points=p, weights=np.ones(1), ids=np.full(1, -1, np.int64), members=np.zeros(0, np.int64))

    @classmethod
    def of_members(cls, vol: SplatVolume, members, n_samples: int = 32, seed: int = 0) -> "SubjectSamples":
        """n_samples of the Gaussians ``members`` (indices [K] into the volume), at their means, drawn with
        probability proportional to opacity x the area of their two largest axes (what they cover on screen),
        deterministic for a seed; repeated draws add weight. (Points drawn within each Gaussian instead agreed worse
        with rendered label images: tests/planner/geometry/test_visibility.py.)"""
        ids = np.asarray(members, np.int64).reshape(-1)
        if ids.size > 1 and not bool(np.all(ids[1:] > ids[:-1])):  # sorted and unique already: skip the sort
            ids = np.unique(ids)
        if ids.size == 0:
            raise InvalidInputError("the subject has no Gaussians")
        if ids[0] < 0 or ids[-1] >= len(vol):
            raise InvalidInputError(f"subject Gaussian ids must be in [0, {len(vol)})")
        box, c = _member_box(vol, ids, cover=True)  # the members' box and their cover's running sum: one pass
        # inverse-CDF draws (what Generator.choice(p=...) does, without its O(K) checks per call)
        pick = np.minimum(np.searchsorted(c, np.random.default_rng(seed).random(int(n_samples)) * c[-1],
                                          side="right"), ids.size - 1)
        u, counts = np.unique(pick, return_counts=True)
        return cls(points=vol.means[ids[u]].copy(), weights=counts.astype(np.float64), ids=ids[u].astype(np.int64),
                   members=ids, box=box)

    def classes(self, n: int) -> np.ndarray:
        """uint8 [n]: 1 for the subject's own Gaussians."""
        c = np.zeros(n, np.uint8)
        c[self.members] = 1
        return c

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_packed"] = None  # O(N) bytes, rebuilt in O(K) where needed: never pickled
        state["_seen"] = None
        return state

    def packed_classes(self, vol: SplatVolume) -> np.ndarray:
        """uint8 [N]: classes(N) in the volume's row order (what the compiled walk reads), built from the members'
        rows in O(K) and kept for the next call with the same volume (end poses, then the candidates' scores)."""
        # the volume itself, not its id: a re-prepared planner's new volume may reuse a freed one's address
        if self._packed is None or self._packed[0] is not vol:
            c = np.zeros(len(vol), np.uint8)
            c[vol.rank[self.members]] = 1
            self._packed = (vol, c)
        return self._packed[1]


def subject_box(vol: SplatVolume, members: np.ndarray, backend: str = "auto") -> tuple:
    """(lo [3], hi [3]): the box of the members' cut-off boxes, at the volume's cut-off (every point where one of
    them attenuates). backend: "auto" (native/targets.c when it loads: the same bits), "native", "python"."""
    return _member_box(vol, members, False, backend)[0]


def _member_box(vol: SplatVolume, members: np.ndarray, cover: bool = False, backend: str = "auto") -> tuple:
    """(subject_box, np.cumsum(vol.cover[members]) when ``cover``, else None), members [K] valid ids, K >= 1: in one
    compiled pass when it loads (the same bits as numpy: the same subtractions, additions and sequential sum)."""
    from ..native import choose, member_box_c

    arrays = (vol.means, vol.half, vol.cover)
    fn = choose(backend, member_box_c, "targets", "member box",
                applies=all(a.dtype == np.float64 and a.flags.c_contiguous for a in arrays),
                needs="the volume's arrays C-contiguous float64")
    if fn is not None:
        ids = np.ascontiguousarray(members, np.int64)
        lo, hi = np.empty(3), np.empty(3)
        cum = np.empty(ids.size) if cover else None
        rc = fn(ids.ctypes.data, ids.size, vol.means.ctypes.data, vol.half.ctypes.data,
                vol.cover.ctypes.data if cover else None, lo.ctypes.data, hi.ctypes.data,
                cum.ctypes.data if cover else None)
        if rc == 0:
            return (lo, hi), cum
    return _member_box_reference(vol, members), (np.cumsum(vol.cover[members]) if cover else None)


def _member_box_reference(vol: SplatVolume, members: np.ndarray) -> tuple:
    m = np.take(vol.means, members, axis=0)  # [K, 3] (np.take: several times faster than fancy indexing here)
    half = np.take(vol.half, members, axis=0)
    # per column: numpy's reductions along axis 0 of a [K, 3] array are about 10x slower than over a column
    lo = np.array([(m[:, a] - half[:, a]).min() for a in range(3)])
    hi = np.array([(m[:, a] + half[:, a]).max() for a in range(3)])
    return lo, hi


def box_exit(p0: np.ndarray, p1: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """[L] the parameter t in [0, 1] beyond which segment p0 -> p1 ([L, 3] each) stays outside the box [lo, hi]
    (0 when it never enters, 1 when it ends inside)."""
    d = p1 - p0
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - p0) / d, (hi - p0) / d
    t_near = np.where(d == 0, np.where((p0 >= lo) & (p0 <= hi), -np.inf, np.inf), np.minimum(ta, tb)).max(1)
    t_far = np.where(d == 0, np.where((p0 >= lo) & (p0 <= hi), np.inf, -np.inf), np.maximum(ta, tb)).min(1)
    hit = (t_near <= t_far) & (t_far >= 0) & (t_near <= 1)
    return np.where(hit, np.clip(t_far, 0.0, 1.0), 0.0)


SEEN_MAX = 4096
"""subject_visibility keeps at most this many cameras' visible fractions per subject (then starts afresh)."""


def subject_visibility(vol: SplatVolume, cameras, subject: SubjectSamples, backend: str = "auto") -> np.ndarray:
    """Visible fraction [M] in [0, 1] of the subject from each camera [M, 3] (module docstring): through the whole splat
    relative to the subject rendered alone. A camera from which the subject alone shows nothing (inside it) gets 0.
    A camera's fraction depends on nothing else in the call, so those of cameras at exactly the same point as one
    asked before (for this volume; e.g. a shot's last frame at the end pose the search scored) are taken as kept."""
    cam = np.asarray(cameras, np.float64).reshape(-1, 3)
    if subject._seen is None or subject._seen[0] is not vol or len(subject._seen[1]) > SEEN_MAX:
        subject._seen = (vol, {})
    seen = subject._seen[1]
    keys = [(backend, row.tobytes()) for row in cam]
    out = np.array([seen.get(key, np.nan) for key in keys], np.float64)
    todo = np.flatnonzero(np.isnan(out))
    if todo.size:
        out[todo] = _visibility(vol, cam[todo], subject, backend)
        for i in todo:
            seen[keys[i]] = float(out[i])
    return out


def _visibility(vol: SplatVolume, cam: np.ndarray, subject: SubjectSamples, backend: str) -> np.ndarray:
    """subject_visibility of cameras cam [M, 3], all walked."""
    m, s = len(cam), len(subject.points)
    # from each sample toward the camera: the subject's own Gaussians come first, and a sample the subject hides
    # itself stops there (STOP_SELF) instead of walking the whole way
    p0 = np.tile(subject.points, (m, 1))  # [M * S, 3]
    p1 = np.repeat(cam, s, axis=0)
    skip = np.tile(subject.ids, m)
    after1 = None
    if subject.members.size:  # past the subject's cut-off box no subject Gaussian attenuates: stop hidden samples there
        lo, hi = subject.box if subject.box is not None else subject_box(vol, subject.members)
        after1 = box_exit(p0, p1, lo, hi)
    tau = optical_depth(vol, p0, p1, None, skip, backend=backend, stop1=STOP_SELF, stop0=STOP_SELF, after1=after1,
                        packed_classes=subject.packed_classes(vol)).reshape(m, s, 2)
    alone = subject.weights[None] * np.exp(-tau[:, :, 1])  # [M, S]
    seen = alone * np.exp(-tau[:, :, 0])
    den = alone.sum(1)
    return np.where(den > 1e-12 * subject.weights.sum(), seen.sum(1) / np.maximum(den, 1e-300), 0.0)
