"""Safe polytopes from the conservative occupancy grid: a corridor polytope without touching the Gaussians.

Why it is safe. Every point of a FREE voxel (a closed cube) keeps the camera ball clear of every ellipsoid
(occupancy.py). Let S be a segment that lies in free voxels (voxel_traversal.py proves it) and P a convex set
inside the grid that contains S and meets no closed SURFACE voxel (an occupied voxel with a free voxel among
its 26 neighbours). Then every point of P lies in a free voxel: if some x in P lay in an occupied voxel, walk
from a point of S to x (inside P, by convexity); the first point of the walk in an occupied closed voxel V is
also a limit of points in free closed voxels, so it lies in a free voxel F too, F and V touch (26-neighbours),
V is a surface voxel, and that point is in P: a contradiction. So P, used as a corridor polytope, keeps the
camera ball clear, exactly like a Prop-2 polytope of the ellipsoids, and costs no Gaussian query: its
obstacles are the few surface voxels in the segment's box instead of the thousands of Gaussians there.

The price: the grid is conservative (a voxel is occupied when its centre's ball of radius r + half a
diagonal touches an ellipsoid), so these polytopes keep up to about one voxel more distance from the scene
than Prop-2 ones. Segments that are not in free voxels (the last one, ending at a goal right next to an
object; a shortcut squeezing through a gap) keep the exact Prop-2 polytopes (polytope.py).

Construction (greedy, nearest first, as Prop. 2's): in voxel units voxel v is the cube [v, v + 1]. Each time,
the alive surface cube nearest to S is taken, with the exact closest points q (on S) and p (on the cube)
(segment_box_closest: the squared distance is convex and piecewise quadratic in the segment parameter, so its
minimum is at a breakpoint or at a stationary point of one piece; computed lazily, for the cubes at the front
of an order by a cheap lower bound, which proves the taken cube the nearest). The plane with normal
n = (p - q) / |p - q| through the
cube's nearest corner-side, b = min over the cube of n.y - margin, separates the cube from S (p is the
projection of q onto the cube, q of p onto S). Cubes entirely beyond an added plane are dropped. S must
satisfy every plane (checked in floating point: if rounding breaks it, no polytope is returned and the
caller uses the exact path).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np
import torch
from scipy import ndimage

from ..errors import InvalidInputError
from ..geometry.voxel_traversal import EPS, segments_in_free_voxels
from .polytope import AABB_FACES, Polytope


def surface_voxels(occupied: np.ndarray) -> np.ndarray:
    """bool [X, Y, Z]: occupied voxels with at least one free voxel among their 26 neighbours (inside the grid)."""
    occ = np.asarray(occupied, dtype=bool)
    near_free = ndimage.binary_dilation(~occ, structure=np.ones((3, 3, 3), dtype=bool))
    return occ & near_free


def segment_box_closest(u0: np.ndarray, u1: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact closest points between ONE segment u0 -> u1 ([3] float64) and unit cubes [v, v + 1] (v [K, 3]).

    Returns (q [K, 3] on the segment, p [K, 3] on the cube, dist [K]). f(t) = dist(u0 + t d, cube)^2 is convex
    and, between the (at most 6) values of t where a coordinate crosses a slab bound, a quadratic; its minimum on
    [0, 1] is at 0, 1, a crossing, or the stationary point of one piece. Every piece's stationary point (with the
    active set read at the piece's midpoint) and every breakpoint is a candidate; f is evaluated exactly at each
    and the best kept. An extra candidate can only be worse than the minimum, never hide it."""
    u0 = np.asarray(u0, dtype=np.float64).reshape(3)
    d = np.asarray(u1, dtype=np.float64).reshape(3) - u0
    v = np.asarray(v, dtype=np.float64).reshape(-1, 3)
    K = v.shape[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        tb = np.concatenate([(v - u0) / d, (v + 1.0 - u0) / d], axis=1)  # [K, 6] (inf / nan where d_a = 0)
    tb = np.where(np.isfinite(tb), np.clip(tb, 0.0, 1.0), 0.0)
    T = np.sort(np.concatenate([np.zeros((K, 1)), np.ones((K, 1)), tb], axis=1), axis=1)  # [K, 8]
    mid = 0.5 * (T[:, :-1] + T[:, 1:])  # [K, 7]
    qm = u0 + mid[..., None] * d  # [K, 7, 3]
    vb = v[:, None, :]
    bnd = np.where(qm < vb, vb, np.where(qm > vb + 1.0, vb + 1.0, np.nan))  # active bound per axis, nan: inside
    c = np.where(np.isnan(bnd), 0.0, u0 - np.nan_to_num(bnd))  # residual at t = 0 on active axes  [K, 7, 3]
    dd = np.where(np.isnan(bnd), 0.0, d)
    den = (dd * dd).sum(-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ts = np.where(den > 0, -(c * dd).sum(-1) / den, mid)
    ts = np.clip(ts, T[:, :-1], T[:, 1:])  # [K, 7]
    cand = np.concatenate([T, ts], axis=1)  # [K, 15]
    q = u0 + cand[..., None] * d  # [K, 15, 3]
    p = np.clip(q, vb, vb + 1.0)
    f = ((q - p) ** 2).sum(-1)  # [K, 15]
    k = np.argmin(f, axis=1)
    rows = np.arange(K)
    return q[rows, k], p[rows, k], np.sqrt(f[rows, k])


FIRST_CAP = 256  # rows VoxelObstacles.polytope's first output buffer holds; more: built again with 4x the room


def _planes_native(fn, srf: np.ndarray, shp: np.ndarray, u0: np.ndarray, u1: np.ndarray, blo: np.ndarray,
                   bhi: np.ndarray, margin: float) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """One cn_grid_polytope call (grid_polytope_planes' compiled path; the box [blo, bhi] already clipped to the grid
    and holding the segment): srf C-contiguous bool, shp [3] int64, the rest float64 [3]."""
    cap = 256
    while True:
        n_out, b_out = np.empty((cap, 3)), np.empty(cap)
        F = int(fn(srf.ctypes.data, shp.ctypes.data, u0.ctypes.data, u1.ctypes.data, blo.ctypes.data,
                   bhi.ctypes.data, float(margin), cap, n_out.ctypes.data, b_out.ctypes.data))
        if F == -2:
            cap *= 4
            continue
        break
    if F == -3:
        return None
    if F < 0:
        raise MemoryError("the compiled grid polytope ran out of memory")
    return np.concatenate([AABB_FACES, n_out[:F]]), np.concatenate([bhi, -blo, b_out[:F]])


def grid_polytope_planes(
    surface: np.ndarray,  # [X, Y, Z] bool
    u0: np.ndarray,  # [3] voxel units
    u1: np.ndarray,  # [3]
    box_lo: np.ndarray,  # [3] voxel units
    box_hi: np.ndarray,  # [3]
    margin: float,
    backend: str = "auto",
) -> Optional[tuple[np.ndarray, np.ndarray]]:
    """(A [F, 3], b [F]) in voxel units: A u <= b contains the segment u0 -> u1 and meets no surface cube that
    overlaps the box [box_lo, box_hi] (clipped to the grid here; the box's own 6 planes come first); None when
    the segment comes within ``margin`` (voxel units) of a surface cube or rounding breaks a plane.
    backend: "auto" (native/gridpoly.c's cn_grid_polytope, the same construction, when it loads), "native" or
    "python"."""
    from ..native import choose, grid_polytope_c

    fn = choose(backend, grid_polytope_c, "gridpoly", "grid polytope")
    shape = np.array(surface.shape)
    blo = np.clip(np.asarray(box_lo, dtype=np.float64), 0.0, shape.astype(np.float64))
    bhi = np.clip(np.asarray(box_hi, dtype=np.float64), 0.0, shape.astype(np.float64))
    u0 = np.asarray(u0, dtype=np.float64).reshape(3)
    u1 = np.asarray(u1, dtype=np.float64).reshape(3)
    seg = np.stack([u0, u1])  # [2, 3]
    if not ((seg >= blo).all() and (seg <= bhi).all() and (bhi > blo).all()):
        return None
    if fn is not None:
        return _planes_native(fn, np.ascontiguousarray(surface, dtype=bool), shape.astype(np.int64), u0, u1, blo, bhi,
                              margin)
    A = [np.eye(3), -np.eye(3)]
    b = [bhi, -blo]
    # every cube meeting the CLOSED box, also one that only touches a face of it
    a = np.maximum(np.ceil(blo).astype(np.int64) - 1, 0)
    e = np.minimum(np.floor(bhi).astype(np.int64) + 1, shape)
    cubes = np.argwhere(surface[a[0]:e[0], a[1]:e[1], a[2]:e[2]]) + a  # [K, 3] every surface cube meeting the box
    if len(cubes):
        v = cubes.astype(np.float64)
        # visiting order: a cheap lower bound of each cube's distance to the segment (its centre's distance minus
        # half a diagonal); exact closest points are computed lazily, only for the cubes near the front of the
        # order, yet the cube chosen each time is the exact nearest alive one (checked against the next bound)
        d = u1 - u0
        dd = float(d @ d)
        cen = v + 0.5
        t = np.clip((cen - u0) @ d / dd, 0.0, 1.0) if dd > 0 else np.zeros(len(v))
        lb = np.linalg.norm(u0 + t[:, None] * d - cen, axis=1) - 0.5 * np.sqrt(3.0)
        order = np.argsort(lb, kind="stable")
        v, lb = v[order], lb[order]
        dist = np.full(len(v), np.nan)
        q = np.empty((len(v), 3))
        p = np.empty((len(v), 3))
        alive = np.ones(len(v), dtype=bool)
        while True:
            idx = np.flatnonzero(alive)
            if idx.size == 0:
                break
            n = 32
            while True:
                ch = idx[:n]
                need = ch[np.isnan(dist[ch])]
                if need.size:
                    q[need], p[need], dist[need] = segment_box_closest(u0, u1, v[need])
                i = int(ch[np.argmin(dist[ch])])
                if n >= idx.size or dist[i] <= lb[idx[n]]:
                    break  # no alive cube beyond the chunk can be nearer
                n *= 4
            if dist[i] <= margin:
                return None
            n_i = (p[i] - q[i]) / dist[i]  # [3] from the segment toward cube i
            neg = float(np.minimum(n_i, 0.0).sum())
            off = float(n_i @ v[i]) + neg - margin  # min over cube i of n.y, minus the margin
            if max(float(n_i @ u0), float(n_i @ u1)) > off:
                return None  # rounding: the plane does not hold the whole segment
            A.append(n_i[None])
            b.append(np.array([off]))
            # cubes entirely beyond the plane (their minimum of n.y is >= off) need nothing more
            alive[idx] &= (v[idx] @ n_i + neg) < off
    return np.concatenate(A), np.concatenate(b)


@dataclass
class VoxelObstacles:
    """The occupancy grid as seen by grid polytopes: occupied and surface masks, corner and voxel size."""

    occupied: np.ndarray  # [X, Y, Z] bool
    surface: np.ndarray  # [X, Y, Z] bool, surface_voxels(occupied)
    lo: np.ndarray  # [3] float64 world corner of voxel (0, 0, 0)
    voxel_size: float

    @classmethod
    def from_occupied(cls, occupied: np.ndarray, lo, voxel_size: float) -> "VoxelObstacles":
        occ = np.asarray(occupied, dtype=bool)
        return cls(occ, surface_voxels(occ), np.asarray(lo, dtype=np.float64).reshape(3), float(voxel_size))

    def segments_free(self, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
        """bool [P]: segment p0[i] -> p1[i] (world, float64 [P, 3]) lies in free voxels (exact voxel walk:
        segments_in_free_voxels, whose compiled path is called here with the grid's kept pointers)."""
        fast = self._compiled()
        if fast is None:
            return segments_in_free_voxels(self.occupied, self.lo, self.voxel_size, p0, p1)
        a = np.asarray(p0, dtype=np.float64).reshape(-1, 3)
        b = np.asarray(p1, dtype=np.float64).reshape(-1, 3)
        if a.shape != b.shape:
            raise InvalidInputError(f"segments_free needs p0 and p1 of one shape [P, 3], got {a.shape} and {b.shape}")
        P = a.shape[0]
        if P == 0:
            return np.zeros(0, dtype=bool)
        ab = np.concatenate([a, b])  # [2P, 3]: both ends behind one pointer
        ab_p = ab.ctypes.data
        res = np.zeros(P, dtype=np.uint8)
        _, walk, occ_p, _, shp_p, lo_p, _ = fast
        if walk(occ_p, shp_p, lo_p, float(self.voxel_size), ab_p, ab_p + 24 * P, P, EPS, res.ctypes.data) != 0:
            raise MemoryError("the compiled voxel walk ran out of memory")
        return res.view(bool)

    def _compiled(self) -> Optional[tuple]:
        """(cn_grid_polytope_world, cn_segments_free, then pointers to occupied and surface as C-contiguous bool,
        shape [3] int64 and lo [3] float64, with the arrays they point into), kept on the grid, or None when the
        compiled kernels do not load: polytope() and segments_free() then take the Python paths. Why one call, and
        pointers kept: the voxel walk, the box and the planes as separate calls with their argument checks and
        conversions cost more than the ~35 us a grid polytope itself takes at 1M Gaussians (and an array's
        .ctypes.data costs ~0.8 us)."""
        got = self.__dict__.get("_compiled_args")
        if got is None:
            from ..native import choose, grid_polytope_world_c, segments_free_c

            fn = choose("auto", grid_polytope_world_c, "gridpoly", "grid polytope")
            walk = choose("auto", segments_free_c, "gridpoly", "voxel walk")
            if fn is None or walk is None:
                got = (None,)
            else:
                keep = (np.ascontiguousarray(self.occupied, dtype=bool),
                        np.ascontiguousarray(self.surface, dtype=bool),
                        np.asarray(self.occupied.shape, dtype=np.int64),
                        np.ascontiguousarray(self.lo, dtype=np.float64))
                got = (fn, walk, *(a.ctypes.data for a in keep), keep)
            self.__dict__["_compiled_args"] = got
        return None if got[0] is None else got

    def __getstate__(self) -> dict:  # the kept compiled functions are not pickled (workers load their own)
        return {k: v for k, v in self.__dict__.items() if k not in ("_compiled_args", "_compiled_many_args")}

    def polytopes(self, w: np.ndarray, box_margin: float, margin: float = 1e-6, skip=None, device=None,
                  backend: str = "auto") -> list:
        """[Polytope | None] per segment w[i] -> w[i + 1] of the polyline w [M+1, 3] (float64 world): what polytope()
        gives each segment (None where it gives None, or where ``skip`` [M] bool is set). backend "auto": one
        cn_grid_polytopes_world call for the whole polyline (the same rows as polytope()'s call per segment; its
        planes share one buffer); "python": polytope() per segment (its Python construction)."""
        if backend not in ("auto", "python"):
            raise InvalidInputError(f"VoxelObstacles.polytopes backend must be 'auto' or 'python', got {backend!r}")
        pts = np.array(w, dtype=np.float64, order="C").reshape(-1, 3)  # a copy: the seeds are views of it
        M = pts.shape[0] - 1
        skip = np.zeros(max(M, 0), dtype=bool) if skip is None else np.asarray(skip, dtype=bool).reshape(-1)
        many = self._compiled_many() if backend == "auto" else None
        if many is None or M < 1:
            return [None if skip[i] else self.polytope(pts[i], pts[i + 1], box_margin, margin, device=device,
                                                       backend=backend) for i in range(M)]
        fn, occ_p, srf_p, shp_p, lo_p = many
        skip8 = np.ascontiguousarray(skip, dtype=np.uint8)
        counts = np.empty(M, dtype=np.int64)
        cap = FIRST_CAP * M
        while True:
            out = np.empty(4 * cap)  # normals [cap, 3], offsets [cap]
            op = out.ctypes.data
            F = int(fn(occ_p, srf_p, shp_p, lo_p, self.voxel_size, pts.ctypes.data, M, skip8.ctypes.data,
                       float(box_margin), float(margin), EPS, cap, op, op + 8 * 3 * cap, counts.ctypes.data))
            if F != -2:
                break
            cap *= 4
        if F < 0:
            raise MemoryError("the compiled grid polytopes ran out of memory")
        dev = torch.device("cpu") if device is None else torch.device(device)
        An, bn = out[:3 * F].reshape(F, 3), out[3 * cap:3 * cap + F]
        seeds = torch.from_numpy(pts)
        on_cpu = dev.type == "cpu"
        if not on_cpu:
            At, bt, seeds = torch.from_numpy(An).to(dev), torch.from_numpy(bn).to(dev), seeds.to(dev)
        res, s = [], 0
        for i, f in enumerate(counts.tolist()):
            if f <= 0:
                res.append(None)
                continue
            # on the CPU the planes are views of the buffer's rows, kept as numpy too (Polytope.host_arrays)
            res.append(Polytope.from_numpy(An[s:s + f], bn[s:s + f], seeds[i:i + 2]) if on_cpu
                       else Polytope(A=At[s:s + f], b=bt[s:s + f], seed=seeds[i:i + 2], ellipsoid_ids=None))
            s += f
        return res

    def _compiled_many(self) -> Optional[tuple]:
        """(cn_grid_polytopes_world, then _compiled()'s pointers to occupied, surface, shape and lo), kept on the grid,
        or None when the compiled kernels do not load."""
        got = self.__dict__.get("_compiled_many_args")
        if got is None:
            from ..native import choose, grid_polytopes_world_c

            fast = self._compiled()
            fn = choose("auto", grid_polytopes_world_c, "gridpoly", "grid polytopes") if fast is not None else None
            got = (None,) if fn is None else (fn, *fast[2:6])
            self.__dict__["_compiled_many_args"] = got
        return None if got[0] is None else got

    def polytope(self, p0, p1, box_margin: float, margin: float = 1e-6, device=None,
                 backend: str = "auto") -> Optional[Polytope]:
        """Polytope (world units, float64 on ``device``) around the segment p0 -> p1 in its bounding box grown
        by ``box_margin``, excluding every surface voxel; None when the segment is not in free voxels (or a
        plane fails the floating-point check), so the caller must build an exact Prop-2 polytope instead.
        backend: "auto" (native/gridpoly.c's cn_grid_polytope_world: the voxel walk, the box, the planes and the
        conversion to world units in one call, when it loads) or "python" (segments_free, then
        grid_polytope_planes' Python construction; the same planes, offsets within rounding of the conversion)."""
        if backend not in ("auto", "python"):
            raise InvalidInputError(f"VoxelObstacles.polytope backend must be 'auto' or 'python', got {backend!r}")
        a = np.asarray(p0.detach().cpu() if isinstance(p0, torch.Tensor) else p0, dtype=np.float64).reshape(3)
        c = np.asarray(p1.detach().cpu() if isinstance(p1, torch.Tensor) else p1, dtype=np.float64).reshape(3)
        vs = self.voxel_size
        dev = torch.device("cpu") if device is None else torch.device(device)
        fast = self._compiled() if backend == "auto" else None
        if fast is not None:
            fn, _, occ_p, srf_p, shp_p, lo_p, _ = fast
            ac = np.stack([a, c])  # [2, 3] the segment's ends, one pointer for both (and the polytope's seed)
            ac_p = ac.ctypes.data
            cap = FIRST_CAP
            while True:
                out = np.empty(4 * cap)  # normals [cap, 3], offsets [cap]
                op = out.ctypes.data
                F = int(fn(occ_p, srf_p, shp_p, lo_p, vs, ac_p, ac_p + 24, float(box_margin), float(margin), EPS, cap,
                           op, op + 8 * 3 * cap))
                if F != -2:
                    break
                cap *= 4
            if F in (-3, -4):
                return None
            if F < 0:
                raise MemoryError("the compiled grid polytope ran out of memory")
            A, b = torch.from_numpy(out[:3 * F].reshape(F, 3)), torch.from_numpy(out[3 * cap:3 * cap + F])
            seed = torch.from_numpy(ac)
            if dev.type != "cpu":
                A, b, seed = A.to(dev), b.to(dev), seed.to(dev)
            return Polytope(A=A, b=b, seed=seed, ellipsoid_ids=None)
        u0, u1 = (a - self.lo) / vs, (c - self.lo) / vs
        lo_b = (np.minimum(a, c) - box_margin - self.lo) / vs
        hi_b = (np.maximum(a, c) + box_margin - self.lo) / vs
        if not bool(segments_in_free_voxels(self.occupied, self.lo, vs, a[None], c[None], backend="python")[0]):
            return None
        planes = grid_polytope_planes(self.surface, u0, u1, lo_b, hi_b, margin / vs, backend="python")
        if planes is None:
            return None
        Av, bv = planes
        # voxel units -> world: n.u <= b with u = (x - lo) / vs  <=>  n.x <= vs b + n.lo (|n| = 1 stays)
        bw = vs * bv + Av @ self.lo
        return Polytope(
            A=torch.as_tensor(Av, dtype=torch.float64, device=dev),
            b=torch.as_tensor(bw, dtype=torch.float64, device=dev),
            seed=torch.as_tensor(np.stack([a, c]), dtype=torch.float64, device=dev),
            ellipsoid_ids=None,
        )
