"""Conservative voxel occupancy of the inflated ellipsoids (initial-path grid for A*).

A voxel is FREE only if every point of it keeps the camera ball (radius r) clear of every
ellipsoid. We test the voxel centre c with the ball of radius rho = r + half the voxel diagonal:
if that ball is clear of E, every point p of the voxel has dist(p, E) >= dist(c, E) - |p - c| > r.

Clearance of the ball is proven with true Corollary-1 values: for a fixed s, K(s) > 1 says c lies
outside the ellipsoid E_s with semi-axes^2 a_i^2/s + rho^2/(1-s), which contains E + B(rho). So
the voxels an ellipsoid occupies are (a superset of) those whose centre lies in the intersection
of E_s over a few s values. Rasterisation is ellipsoid-driven and per COLUMN: for each (x, y) voxel
column in the ellipsoid's footprint, each E_s cuts the column's line in a z-interval (a quadratic),
the intersection of the intervals is a run of voxels, marked with a difference array along z.
The s values are s = h/(h + rho) for h log-spaced in [a_min, a_max] (the optimal s for a support
value h), so the test is tight up to the sampling of s and never optimistic.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Tuple, Union

import numpy as np
import torch
from torch import Tensor

from ..errors import GoalUnreachableError, InvalidInputError
from .ellipsoids import EllipsoidScene

_MARGIN = 1e-4  # relative slack on K (free needs K(s) > 1 + margin); covers float32 column maths


@dataclass
class OccupancyGrid:
    """Voxel grid: voxel (i, j, k) spans lo + voxel_size * [i, i+1] x [j, j+1] x [k, k+1]."""

    lo: Tensor  # [3] float64, world position of the grid corner
    voxel_size: float
    occupied: Tensor  # [X, Y, Z] bool

    @property
    def shape(self) -> Tuple[int, int, int]:
        return tuple(self.occupied.shape)  # type: ignore[return-value]

    @property
    def hi(self) -> Tensor:
        return self.lo + self.voxel_size * torch.tensor(self.shape, dtype=torch.float64, device=self.lo.device)

    @property
    def device(self) -> torch.device:
        return self.occupied.device

    def to(self, device: Union[str, torch.device]) -> "OccupancyGrid":
        return OccupancyGrid(self.lo.to(device), self.voxel_size, self.occupied.to(device))

    def numpy(self) -> np.ndarray:
        """occupied as a numpy bool array [X, Y, Z] (what astar() takes)."""
        return self.occupied.cpu().numpy()

    def world_to_voxel(self, points: Tensor) -> Tensor:
        """Voxel indices [..., 3] long of world points [..., 3] (not clamped: check in_bounds)."""
        p = torch.as_tensor(points, device=self.device).double()
        return torch.floor((p - self.lo) / self.voxel_size).long()

    def _lo_numpy(self) -> np.ndarray:
        """lo [3] as numpy (a view on the CPU; voxel_of and centre_of are the single-point host paths)."""
        return self.lo.detach().numpy() if self.lo.device.type == "cpu" else self.lo.detach().cpu().numpy()

    def voxel_of(self, point: np.ndarray) -> np.ndarray:
        """world_to_voxel of one point [3] as int64 numpy [3]: the same float64 arithmetic, without torch's per-call
        cost (~40 us on the CPU box for the tensor round trip, 4 us here; a request looks up several points)."""
        return np.floor((np.asarray(point, dtype=np.float64).reshape(3) - self._lo_numpy()) / self.voxel_size).astype(
            np.int64)

    def centre_of(self, ijk: np.ndarray) -> np.ndarray:
        """voxel_to_world of one voxel [3] as float64 numpy [3]: the same float64 arithmetic, without torch's per-call
        cost (as voxel_of)."""
        return self._lo_numpy() + (np.asarray(ijk).reshape(3).astype(np.float64) + 0.5) * self.voxel_size

    def voxel_to_world(self, ijk: Tensor) -> Tensor:
        """Voxel centres [..., 3] float64 of indices [..., 3]."""
        ijk = torch.as_tensor(ijk, device=self.device)
        return self.lo + (ijk.double() + 0.5) * self.voxel_size

    def in_bounds(self, ijk: Tensor) -> Tensor:
        ijk = torch.as_tensor(ijk, device=self.device)
        dims = torch.tensor(self.shape, device=self.device)
        return ((ijk >= 0) & (ijk < dims)).all(-1)

    def is_occupied(self, points: Tensor) -> Tensor:
        """bool [...] for world points [..., 3]; points outside the grid count as occupied."""
        ijk = self.world_to_voxel(points)
        inb = self.in_bounds(ijk)
        dims = torch.tensor(self.shape, device=self.device)
        c = torch.minimum(ijk.clamp_min(0), dims - 1)
        return ~inb | self.occupied[c[..., 0], c[..., 1], c[..., 2]]

    def free_fraction(self) -> float:
        return float((~self.occupied).float().mean())

    def nearest_free_voxel(self, point: Tensor, allowed: Optional[Tensor] = None) -> Tensor:
        """Index [3] long of the free voxel whose centre is nearest to ``point`` [3] (optionally only
        among ``allowed`` [X, Y, Z] bool voxels, e.g. a connected component)."""
        p = torch.as_tensor(point, device=self.device).double().reshape(3)
        if not bool(torch.isfinite(p).all()):
            raise InvalidInputError(f"nearest_free_voxel: point must be finite, got {p.tolist()}")
        free = ~self.occupied if allowed is None else (~self.occupied & allowed)
        ijk = torch.nonzero(free)
        if ijk.numel() == 0:
            raise GoalUnreachableError(
                "no free voxel in the occupancy grid: the camera radius is too large for this scene "
                "or the grid is too coarse (raise the resolution)"
            )
        d = ((self.voxel_to_world(ijk) - p) ** 2).sum(-1)
        return ijk[torch.argmin(d)]


def _grid_geometry(scene: EllipsoidScene, resolution: int, bounds, padding: Optional[float]):
    if bounds is None:
        lo, hi = scene.bounds()
        lo, hi = lo.double(), hi.double()
        if padding is None:
            padding = 0.05 * float((hi - lo).max()) + scene.camera_radius
        lo, hi = lo - padding, hi + padding
    else:
        lo = torch.as_tensor(bounds[0], device=scene.device).double().reshape(3)
        hi = torch.as_tensor(bounds[1], device=scene.device).double().reshape(3)
        if not (torch.isfinite(lo).all() and torch.isfinite(hi).all() and (hi > lo).all()):
            raise InvalidInputError(f"occupancy bounds must be finite with hi > lo, got {lo.tolist()}, {hi.tolist()}")
    if int(resolution) < 1:
        raise InvalidInputError(f"occupancy resolution must be >= 1, got {resolution}")
    voxel = float((hi - lo).max()) / int(resolution)
    dims = torch.ceil((hi - lo) / voxel - 1e-9).long().clamp_min(1)
    return lo, voxel, dims


def build_occupancy(
    scene: EllipsoidScene,
    index=None,
    resolution: int = 100,
    bounds: Optional[Tuple[Tensor, Tensor]] = None,
    padding: Optional[float] = None,
    n_s: int = 3,
    max_columns: int = 2_000_000,
    backend: str = "auto",
) -> OccupancyGrid:
    """Conservative occupancy grid (see module docstring).

    resolution: voxels along the longest side of ``bounds`` (cubic voxels). bounds: (lo [3], hi [3]);
    default the scene's ellipsoid bounds grown by ``padding`` (default 5% of the largest extent +
    the camera radius). ``index`` is accepted for API symmetry and unused (rasterisation is
    ellipsoid-driven). n_s: s values per ellipsoid (more = tighter, slower). max_columns: columns per chunk (the
    memory of the column maths). backend: "auto" (the compiled rasterisation,
    native/occupancy.c, for a CPU scene when it loads; the very same grid), "native" or "python"
    (build_occupancy_reference's torch rasterisation; always for a GPU scene)."""
    from ..native import choose, occupancy_c

    fn = choose(backend, occupancy_c, "occupancy", "occupancy rasterisation", applies=compiled_applies(scene, n_s),
                needs=f"a CPU scene of float32 or float64 tensors and 1 <= n_s <= {MAX_COMPILED_S}")
    lo, voxel, dims = _grid_geometry(scene, resolution, bounds, padding)
    X, Y, Z = (int(d) for d in dims)
    if _one_covers_the_box(scene, lo, lo + dims.double() * voxel):
        # every voxel is occupied; rasterising would cost one column per ellipsoid and grid column (a splat whose
        # Gaussians are all larger than the scene: minutes of work for this same answer)
        full = torch.ones(X, Y, Z, dtype=torch.bool, device=scene.device)
        return OccupancyGrid(lo=lo, voxel_size=voxel, occupied=full)
    occ = None if fn is None else _rasterise_compiled(fn, scene, lo, voxel, dims, n_s, max_columns)
    if occ is None:
        occ = _rasterise_reference(scene, lo, voxel, dims, n_s, max_columns)
    return OccupancyGrid(lo=lo, voxel_size=voxel, occupied=occ)


def build_occupancy_reference(
    scene: EllipsoidScene,
    index=None,
    resolution: int = 100,
    bounds: Optional[Tuple[Tensor, Tensor]] = None,
    padding: Optional[float] = None,
    n_s: int = 3,
    max_columns: int = 2_000_000,
) -> OccupancyGrid:
    """build_occupancy by the torch rasterisation (any device): what the compiled one is tested against."""
    return build_occupancy(scene, index, resolution, bounds, padding, n_s, max_columns, backend="python")


def _rasterise_reference(scene: EllipsoidScene, lo: Tensor, voxel: float, dims: Tensor, n_s: int,
                         max_columns: int) -> Tensor:
    """occupied [X, Y, Z] bool by the torch rasterisation, in chunks of ellipsoids of about max_columns columns."""
    dev = scene.device
    X, Y, Z = (int(d) for d in dims)
    rho = _column_reach(scene, voxel)
    diff = torch.zeros(X * Y * (Z + 1), dtype=torch.int32, device=dev)
    # s samples per ellipsoid: s = h / (h + rho), h log-spaced in [a_min, a_max]
    t = torch.linspace(0, 1, n_s, dtype=torch.float64, device=dev)
    n = len(scene)
    span, i_lo, ncol = _footprints(scene, lo, voxel, dims, rho)
    # chunks of ellipsoids with at most ~max_columns columns each
    csum = torch.cumsum(ncol, 0)
    start = 0
    while start < n:
        base = int(csum[start - 1]) if start else 0
        end = int(torch.searchsorted(csum, torch.tensor(base + max_columns, device=dev), right=True))
        end = min(max(end, start + 1), n)
        _mark_chunk_reference(scene, start, end, span, i_lo, lo, voxel, dims, rho, t, diff)
        start = end
    return torch.cumsum(diff.view(X, Y, Z + 1), dim=2)[:, :, :Z] > 0


MAX_COMPILED_S = 64
"""Most s samples per ellipsoid the compiled rasterisation takes (native/occupancy.c: MAX_S)."""
_LIBM_POW_S = 3
"""Up to this many s samples, the compiled rasterisation raises a_max / a_min to the powers t itself (libm's pow, as
torch's scalar loop does for such short rows); past it, it takes torch's powers (vectorised ones round otherwise)."""


def compiled_applies(scene: EllipsoidScene, n_s: int) -> bool:
    """Whether the compiled rasterisation takes this build: a CPU scene whose means, rotations and radii are all float32
    or all float64 (the reference's precision is theirs), 1 <= n_s <= MAX_COMPILED_S."""
    dtypes = {scene.means.dtype, scene.rotations.dtype, scene.radii.dtype}
    return scene.device.type == "cpu" and len(dtypes) == 1 and dtypes <= {torch.float32, torch.float64} \
        and 1 <= int(n_s) <= MAX_COMPILED_S


def _rasterise_compiled(fns, scene: EllipsoidScene, lo: Tensor, voxel: float, dims: Tensor, n_s: int,
                        max_columns: int):
    """occupied [X, Y, Z] bool by native/occupancy.c (the reference's operations in the same order and precision, the
    square roots by torch), in chunks of about max_columns columns, or None when the reference must run (a bound or an
    index out of int64's reach: see occupancy.c)."""
    footprints_c, discs_c, mark_c, sum_c = fns
    X, Y, Z = (int(d) for d in dims)
    rho = _column_reach(scene, voxel)
    n, f32 = len(scene), int(scene.means.dtype == torch.float32)
    means, rot, radii, ext = (np.ascontiguousarray(a.detach().numpy()) for a in
                              (scene.means, scene.rotations, scene.radii, scene.half_extents()))  # torch's sqrt
    lo_np = np.ascontiguousarray(lo.detach().numpy(), dtype=np.float64)
    ilo, span = np.empty((n, 3), np.int64), np.zeros((n, 2), np.int64)
    if footprints_c(means.ctypes.data, ext.ctypes.data, f32, n, lo_np.ctypes.data, voxel, X, Y, Z, rho,
                    ilo.ctypes.data, span.ctypes.data) != 0:
        return None
    t = torch.linspace(0, 1, n_s, dtype=torch.float64)
    pw = None
    if n_s > _LIBM_POW_S:
        radii_t = scene.radii.double()
        amin, amax = radii_t.min(-1).values, radii_t.max(-1).values
        pw = np.ascontiguousarray(((amax / amin)[:, None] ** t[None]).numpy())
    t_np = np.ascontiguousarray(t.numpy())
    csum = np.cumsum(span[:, 0] * span[:, 1])
    diff = np.zeros(X * Y * (Z + 1), dtype=np.int32)
    start = 0
    while start < n:
        base = int(csum[start - 1]) if start else 0
        end = min(max(int(np.searchsorted(csum, base + max_columns, side="right")), start + 1), n)
        cols = int(csum[end - 1]) - base
        if cols:
            mc, mu = np.empty((end - start, n_s, 6), np.float32), np.empty((end - start, 3))
            disc = np.empty(cols * n_s, np.float32)
            k = discs_c(means.ctypes.data, rot.ctypes.data, radii.ctypes.data, f32, start, end, ilo.ctypes.data,
                        span.ctypes.data, lo_np.ctypes.data, voxel, rho, t_np.ctypes.data, n_s,
                        None if pw is None else pw.ctypes.data, 1 + _MARGIN, mc.ctypes.data, None, mu.ctypes.data,
                        disc.ctypes.data, disc.size)
            sq = torch.sqrt(torch.from_numpy(disc[:max(k, 0)]).clamp_min(0)).numpy()  # the reference's square roots
            rc = mark_c(start, end, ilo.ctypes.data, span.ctypes.data, mc.ctypes.data, mu.ctypes.data, n_s,
                        sq.ctypes.data, k, Y, Z, diff.ctypes.data, None, None, None) if k >= 0 else -1
            if rc == 1:
                return None
            if rc != 0:
                raise RuntimeError(f"occupancy.c: inconsistent columns (discs {k}, mark {rc})")
        start = end
    occ = np.empty((X, Y, Z), dtype=np.uint8)
    sum_c(diff.ctypes.data, X, Y, Z, occ.ctypes.data)
    return torch.from_numpy(occ.view(np.bool_))


def _column_reach(scene: EllipsoidScene, voxel: float) -> float:
    """rho: how far an ellipsoid is grown before it marks a voxel (the camera radius plus half a voxel's diagonal).
    One expression for the footprints, the reference and the compiled rasterisation, which must agree bit for bit."""
    return scene.camera_radius + 0.5 * math.sqrt(3.0) * voxel


def _one_covers_the_box(scene: EllipsoidScene, lo: Tensor, hi: Tensor) -> bool:
    """Whether one ellipsoid holds the whole box [lo, hi] (its 8 corners; an ellipsoid is convex)."""
    if len(scene) == 0:
        return False
    c = torch.stack(torch.meshgrid(*[torch.stack([lo[k], hi[k]]) for k in range(3)], indexing="ij"), -1).reshape(8, 3)
    big = scene.radii.double().min(-1).values >= 0.5 * float((hi - lo).min())  # narrower ones cannot
    if not bool(big.any()):
        return False
    d = (c[None] - scene.means[big].double()[:, None]) @ scene.rotations[big].double()  # [B, 8, 3] in the axes
    return bool((((d / scene.radii[big].double()[:, None]) ** 2).sum(-1) <= 1.0).all(-1).any())


def _footprints(scene: EllipsoidScene, lo: Tensor, voxel: float, dims: Tensor, rho: float):
    """(span [N, 2] footprint columns along x and y, i_lo [N, 3] first voxel, ncol [N] columns) of each ellipsoid grown
    by rho on the grid (0 columns for those outside it)."""
    ext = scene.half_extents().double() + rho  # [N, 3] half-extents of E + B(rho)
    i_lo = torch.ceil((scene.means.double() - ext - lo) / voxel - 0.5).long()
    i_hi = torch.floor((scene.means.double() + ext - lo) / voxel - 0.5).long()
    i_lo = i_lo.clamp_min(0)
    i_hi = torch.minimum(i_hi, dims - 1)
    span = (i_hi[:, :2] - i_lo[:, :2] + 1).clamp_min(0)  # [N, 2] footprint columns along x, y
    span[(i_hi[:, 2] < i_lo[:, 2])] = 0  # z-range outside the grid: nothing to mark
    return span, i_lo, span[:, 0] * span[:, 1]


def occupancy_columns(scene: EllipsoidScene, resolution: int, bounds: Tuple[Tensor, Tensor]) -> int:
    """How many voxel columns build_occupancy(scene, resolution=resolution, bounds=bounds) rasterises (its work)."""
    lo, voxel, dims = _grid_geometry(scene, resolution, bounds, None)
    return int(_footprints(scene, lo, voxel, dims, _column_reach(scene, voxel))[2].sum())


def _mark_chunk_reference(scene, a, b, span, i_lo, lo, voxel, dims, rho, t, diff) -> None:
    """Rasterise ellipsoids a..b-1: span [N, 2] footprint columns along x and y, i_lo [N, 3] first index."""
    X, Y, Z = (int(d) for d in dims)
    cols = _column_roots_reference(scene, a, b, span, i_lo, lo, voxel, rho, t)
    if cols is None:
        return
    ci, cj, mu_z, z0, z1, ok = cols
    eps = 1e-3  # index rounding may only add voxels
    k0 = torch.ceil(mu_z + z0.double() - eps).long().clamp_min(0)
    k1 = torch.floor(mu_z + z1.double() + eps).long().clamp_max(Z - 1)
    ok &= k1 >= k0
    base = ((ci * Y + cj) * (Z + 1))[ok]
    one = torch.ones(base.numel(), dtype=torch.int32, device=scene.device)
    diff.index_add_(0, base + k0[ok], one)
    diff.index_add_(0, base + k1[ok] + 1, -one)


def _coefficients_reference(scene, a, b, lo, voxel, rho, t):
    """Per ellipsoid a..b-1 and s sample: (m6 [E, S, 6] float64, the 6 distinct entries m00, m01, m11, m02, m12, m22 of
    E_s's matrix over 1 + margin; mc [E, S, 6] float32, the same in voxel units; mu_v [E, 3] float64, the centre in
    voxel-index coordinates)."""
    rot = scene.rotations[a:b].double()
    radii = scene.radii[a:b].double()
    amin, amax = radii.min(-1).values, radii.max(-1).values  # [E]
    h = amin[:, None] * (amax / amin)[:, None] ** t[None]  # [E, S] log-spaced support values
    s = h / (h + rho)
    q = radii[:, None, :] ** 2 / s[..., None] + rho * rho / (1 - s[..., None])  # [E, S, 3] semi-axes^2 of E_s
    m = (rot[:, None] / q[:, :, None, :]) @ rot[:, None].transpose(-1, -2)  # [E, S, 3, 3] R diag(1/q) R^T
    m = m / (1 + _MARGIN)  # membership K(s) <= 1 + margin: free needs a clear K > 1 + margin
    # only the 6 distinct entries, gathered per column
    m6 = torch.stack([m[..., 0, 0], m[..., 0, 1], m[..., 1, 1], m[..., 0, 2], m[..., 1, 2], m[..., 2, 2]], -1)
    # Per-column arithmetic in float32 (bandwidth): offsets are measured in voxels from the column
    # centre so values stay O(10); the K margin (1e-4) and index slack (1e-3 voxel) cover rounding.
    mc = (m6 * voxel * voxel).float()  # [E, S, 6] in voxel units
    mu_v = (scene.means[a:b].double() - lo) / voxel - 0.5  # [E, 3] centre in voxel-index coordinates
    return m6, mc, mu_v


def _column_roots_reference(scene, a, b, span, i_lo, lo, voxel, rho, t):
    """The footprint columns of ellipsoids a..b-1 (ellipsoid by ellipsoid, then x, then y): (ci, cj [C] long, mu_z [C]
    the centre's z in voxel-index coordinates, z0, z1 [C] float32 the z-interval from it, ok [C] bool where it is
    one); None without columns."""
    dev = scene.device
    sy = span[a:b, 1]
    cnt = span[a:b, 0] * sy  # columns per ellipsoid
    total = int(cnt.sum())
    if total == 0:
        return None
    ends = torch.cumsum(cnt, 0)
    pos = torch.arange(total, device=dev)
    e_loc = torch.searchsorted(ends, pos, right=True)  # [C] chunk-local ellipsoid of each column
    k = pos - (ends - cnt).index_select(0, e_loc)
    sy_c = sy.index_select(0, e_loc)
    il = i_lo[a:b].index_select(0, e_loc)  # [C, 3]
    ci = il[:, 0] + k // sy_c
    cj = il[:, 1] + k % sy_c
    _, mc, mu_v = _coefficients_reference(scene, a, b, lo, voxel, rho, t)
    mc = mc.index_select(0, e_loc)  # [C, S, 6]
    mu_v = mu_v.index_select(0, e_loc)  # [C, 3]
    dx = (ci.double() - mu_v[:, 0]).float()[:, None]  # [C, 1]
    dy = (cj.double() - mu_v[:, 1]).float()[:, None]
    A = mc[..., 5]
    B = mc[..., 3] * dx + mc[..., 4] * dy
    Cc = mc[..., 0] * dx * dx + 2 * mc[..., 1] * dx * dy + mc[..., 2] * dy * dy - 1
    disc = B * B - A * Cc  # [C, S]
    sq = torch.sqrt(disc.clamp_min(0))
    z0 = ((-B - sq) / A).max(-1).values  # intersection of the z-intervals over s
    z1 = ((-B + sq) / A).min(-1).values
    ok = (disc >= 0).all(-1) & (z1 >= z0)
    return ci, cj, mu_v[:, 2], z0, z1, ok
