"""Goal and start positions.

closest_safe_point (paper Sec. IV-C): the go-to target (e.g. an object's centroid) is usually inside
the object. We grow a Prop-2 safe polytope around the target (it may exclude the target itself) and
project the target onto it (projection.py: a 3-variable QP, an active-set method compiled in native/project.c,
Clarabel as fallback); every point of that polytope is safe, so the projection is a safe goal as close to the
target as that polytope allows. When the polytope is empty (target deep inside clutter) we fall back to
the nearest free voxel of the occupancy grid that holds no Gaussian mean, verified with an exact point
clearance test.

sample_free_starts: seeded rejection sampling of camera centres in a region, pre-filtered by the
grid's free voxels and accepted only after an exact clearance test.

The grid is duck-typed: any object with ``occupied`` (bool [X, Y, Z]), ``lo`` [3], ``voxel_size``
(float) and optionally ``voxel_to_world`` / ``world_to_voxel``; without those methods voxel (i,j,k)
is the cube lo + [i, i+1) * voxel_size with centre lo + (i + 0.5) * voxel_size.
"""
from __future__ import annotations

import math
from typing import Callable, Optional, Sequence, Union

import numpy as np
import torch
from torch import Tensor

from ..corridor.polytope import aabb_polytope
from ..corridor.polytope_candidates import candidate_ids
from ..corridor.polytope_planes import closest_t
from ..errors import GoalUnreachableError, InvalidInputError, StartInCollisionError
from ..native import choose, goal_window_c
from ..scene.occupancy import OccupancyGrid
from .projection import INTERIOR_RADIUS, project_onto_polytope


class NoFreeStartError(StartInCollisionError):
    """No collision-free start position could be sampled in the requested region."""


# ------------------------------------------------------------------------------------ grid helpers
def grid_arrays(grid):
    occ = grid.occupied
    occ = occ.detach().cpu().numpy() if isinstance(occ, Tensor) else np.asarray(occ)
    lo = torch.as_tensor(grid.lo).detach().cpu().to(torch.float64).reshape(3)
    vs = float(grid.voxel_size)
    return np.asarray(occ, dtype=bool), lo, vs  # no copy of a bool grid (callers only read it)


class ComponentMask:
    """A ``reachable`` mask for closest_safe_point given lazily: voxel v is reachable iff labels[v] == comp (labels
    [X, Y, Z] int, e.g. the free components of the A* grid). Indexing a window compares only that window, so a
    request does not build the whole-grid mask; ``np.asarray`` gives the whole mask."""

    def __init__(self, labels: np.ndarray, comp: int) -> None:
        self.labels = labels
        self.comp = comp

    @property
    def shape(self) -> tuple:
        return tuple(self.labels.shape)

    def __getitem__(self, idx) -> np.ndarray:
        return np.asarray(self.labels[idx] == self.comp)

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        out = np.asarray(self.labels == self.comp)
        return out if dtype is None else out.astype(dtype, copy=False)


def _reachable_mask(reachable, shape):
    """closest_safe_point's ``reachable`` (bool array or ComponentMask) checked against the grid's shape."""
    if reachable is None:
        return None
    if not isinstance(reachable, ComponentMask):
        reachable = np.asarray(reachable, dtype=bool)
    if tuple(reachable.shape) != tuple(shape):
        raise InvalidInputError(f"reachable mask {tuple(reachable.shape)} does not match the grid {tuple(shape)}")
    return reachable


def _voxel_to_world(grid, ijk: Tensor) -> Tensor:
    if hasattr(grid, "voxel_to_world"):
        return torch.as_tensor(grid.voxel_to_world(ijk)).detach().cpu().to(torch.float64)
    _, lo, vs = grid_arrays(grid)
    return lo + (ijk.to(torch.float64) + 0.5) * vs


def _voxel_centres(grid, ijk: np.ndarray, lo: np.ndarray, vs: float) -> np.ndarray:
    """Voxel centres [K, 3] float64 numpy of indices ijk [K, 3]: OccupancyGrid.voxel_to_world's arithmetic (the same
    floats) without torch's per-call cost, or the duck-typed grid's own voxel_to_world."""
    if hasattr(grid, "voxel_to_world") and not isinstance(grid, OccupancyGrid):
        return _voxel_to_world(grid, torch.as_tensor(ijk)).numpy()
    return lo + (ijk.astype(np.float64) + 0.5) * vs


def _world_to_voxel(grid, x: Tensor) -> Tensor:
    if hasattr(grid, "world_to_voxel"):
        return torch.as_tensor(grid.world_to_voxel(x)).detach().cpu().long()
    _, lo, vs = grid_arrays(grid)
    return ((x.to(torch.float64) - lo) / vs).floor().long()


# ------------------------------------------------------------------------------------ exact checks
def points_clearance_lower(points: Tensor, scene, index=None) -> Tensor:
    """Clearance min_j dist(x, E_j) - camera_radius of points [P, 3] -> [P] float64, over the
    ellipsoids that can come within the camera radius of x (inflated bounding sphere holds x).

    Sign-exact: when the true clearance is negative, the offending ellipsoid is examined and the value
    returned is a lower bound of the truth (tight to the root-finder's tolerance): the closest-point
    multiplier t is approached from below and |t w / (lambda + t)| grows with t. When it is >= 0 the
    value is >= 0 but may exceed the true clearance (far ellipsoids are skipped; +inf when none is
    near). Points inside an ellipsoid get -inf. "Is this camera centre free?" is all callers ask.
    """
    dev = scene.means.device
    pts = torch.as_tensor(points, device=dev).to(torch.float64).reshape(-1, 3)
    r = float(scene.camera_radius)
    out = torch.full((pts.shape[0],), math.inf, dtype=torch.float64, device=dev)
    for p in range(pts.shape[0]):
        ids = candidate_ids(scene, index, pts[p], pts[p])
        if ids.numel() == 0:
            continue
        mu = scene.means[ids].detach().cpu().double().numpy()
        rot = scene.rotations[ids].detach().cpu().double().numpy()
        lam = scene.radii[ids].detach().cpu().double().numpy() ** 2
        w = np.einsum("kji,kj->ki", rot, pts[p].cpu().numpy() - mu)  # body frame [K, 3]
        inside = (w**2 / lam).sum(-1) <= 1
        t = closest_t(w**2, lam, iters=30)
        d = np.linalg.norm(t[:, None] * w / (lam + t[:, None]), axis=-1)
        d = np.where(inside, -math.inf, d)
        out[p] = float(d.min()) - r
    return out


def _default_clear(scene, index, margin):
    def clear(points: Tensor) -> Tensor:
        return points_clearance_lower(points, scene, index) >= margin

    return clear


# ------------------------------------------------------------------------------------ goal


def closest_safe_point(
    target,  # [3]
    scene,
    index=None,
    grid=None,
    *,
    box_half: Optional[float] = None,
    margin: float = 1e-6,
    reachable: Optional[np.ndarray] = None,
    clearance_fn: Optional[Callable[[Tensor], Tensor]] = None,
    max_fallback_candidates: int = 256,
    mean_voxels: Optional[np.ndarray] = None,
) -> Tensor:
    """Safe camera centre closest to ``target`` (as far as the method below can tell) -> [3] float64.

    1. target already safe (exact clearance >= margin) -> target.
    2. Prop-2 polytope in the box target +- box_half (default 8 voxels, or 0.2 without a grid), target
       projected onto it (QP), verified inside -> that point (safe by construction of the polytope).
    3. fallback: free voxels of ``grid`` holding no Gaussian mean (and inside ``reachable`` [X,Y,Z]
       if given, e.g. the start's connected component; a ComponentMask is compared per window), nearest first,
       the first whose centre passes the exact clearance test.
    Raises GoalUnreachableError when all three fail. ``clearance_fn(points[P,3]) -> bool[P]`` replaces
    the built-in exact test (e.g. a closure over distance.clearance(...) >= 0). ``mean_voxels`` [X,Y,Z] bool:
    mean_voxel_mask(scene, grid), computed once per scene (step 3 then gathers no Gaussians: the same voxels, without
    a box query that grows with the window: ~40 ms of a request inside a blob of 200k Gaussians on the CPU box).
    """
    dev = scene.means.device
    # the target as float64 numpy on the host, one tensor of it on the scene's device: the steps below are a few
    # small numpy calls each, where torch calls on a 3-vector cost more than what they compute
    if isinstance(target, Tensor):
        t_np = target.detach().to("cpu", torch.float64).numpy().reshape(-1)
    else:
        try:
            t_np = np.asarray(target, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise InvalidInputError(f"goal target must be 3 finite numbers, got {target!r}") from None
    if t_np.shape != (3,) or not np.isfinite(t_np).all():
        raise InvalidInputError(f"goal target must be 3 finite numbers, got {t_np.tolist()}")
    t = torch.from_numpy(t_np.copy())
    t = t if dev.type == "cpu" else t.to(dev)
    clear = clearance_fn or _default_clear(scene, index, margin)
    if bool(torch.as_tensor(clear(t[None])).reshape(-1)[0]):
        return t
    if box_half is None:
        box_half = 8 * float(grid.voxel_size) if grid is not None else 0.2
    # stop_when_empty: a target deep in a blob gets an empty polytope; its first pass's planes usually prove that
    # already (half the projection's INTERIOR_RADIUS: a proof the projection's own emptiness rule agrees with)
    P = aabb_polytope(t_np[None], scene, index, t_np - box_half, t_np + box_half, margin=margin,
                      require_seed_inside=False, stop_when_empty=0.5 * INTERIOR_RADIUS)
    # a proven-empty polytope has no point to project onto (the projection would answer None after ~0.25 ms)
    x = None if P.proven_empty else project_onto_polytope(*P.to_numpy(), t_np)
    if x is not None:
        x = torch.from_numpy(np.asarray(x, dtype=np.float64))
        return x if dev.type == "cpu" else x.to(dev)
    if grid is None:
        raise GoalUnreachableError(
            f"no safe camera position found near the goal {t.tolist()} (it is buried in the scene) and no "
            f"occupancy grid was given for the fallback"
        )
    return _nearest_free_voxel_centre(t, scene, index, grid, reachable, clear, max_fallback_candidates,
                                      mean_voxels).to(dev)


def mean_voxel_mask(scene, grid) -> np.ndarray:
    """bool [X, Y, Z]: the grid's voxels that hold at least one Gaussian mean of ``scene`` (never goals, see
    closest_safe_point step 3). One pass over the means; computed once per prepared scene."""
    occ, _, _ = grid_arrays(grid)
    v = _world_to_voxel(grid, scene.means.detach().cpu().to(torch.float64)).numpy()  # [N, 3]
    v = v[((v >= 0) & (v < np.asarray(occ.shape))).all(1)]
    out = np.zeros(occ.shape, dtype=bool)
    out[v[:, 0], v[:, 1], v[:, 2]] = True
    return out


def _nearest_chunks(centres: np.ndarray, d: np.ndarray, limit: int, chunk: int):
    """(k, centres [<= chunk, 3] as a tensor) of the ``limit`` nearest centres (distances d [K]) in chunks, in the order
    of a stable argsort of d. The first chunk is selected by a partition (usually the only one looked at: a full sort
    of a large window cost ~0.1 ms a goal); the rest by the full sort."""
    limit = min(limit, len(d))
    k0 = min(chunk, limit)
    if k0 <= 0:
        return
    if len(d) > 4 * chunk:
        thr = np.partition(d, k0 - 1)[k0 - 1]
        sel = np.flatnonzero(d <= thr)  # ascending index: the stable sort below keeps argsort's tie order
        first = sel[np.argsort(d[sel], kind="stable")[:k0]]
    else:
        first = np.argsort(d, kind="stable")[:k0]
    yield 0, torch.from_numpy(centres[first])
    if limit > k0:
        order = np.argsort(d, kind="stable")[:limit]
        for k in range(k0, limit, chunk):
            yield k, torch.from_numpy(centres[order[k:k + chunk]])


def _window_native_args(grid, occ, reachable, mean_voxels):
    """(occ, labels or None, comp, reach or None, mean) as the C arrays goalwindow.c reads, or None when the inputs are
    not in that form (the numpy window then): an OccupancyGrid (its centre arithmetic), a mean mask, and a reachable
    mask that is None, a bool array or a ComponentMask over C-contiguous int32 labels."""
    if mean_voxels is None or not isinstance(grid, OccupancyGrid) or mean_voxels.shape != occ.shape:
        return None
    labels, comp, reach = None, 0, None
    if isinstance(reachable, ComponentMask):
        labels, comp = reachable.labels, int(reachable.comp)
        if not (isinstance(labels, np.ndarray) and labels.dtype == np.int32 and labels.flags.c_contiguous):
            return None
    elif reachable is not None:
        reach = np.ascontiguousarray(reachable, dtype=bool).view(np.uint8)
    return (np.ascontiguousarray(occ).view(np.uint8), labels, comp, reach,
            np.ascontiguousarray(mean_voxels, dtype=bool).view(np.uint8))


class _NativeWindow:
    """goalwindow.c's arguments for one goal (arrays that do not change between its windows, made once, with their
    pointers: an array's .ctypes.data costs ~0.8 us, and a window call needed twelve)."""

    def __init__(self, fn, arrays, lo_np, vs, t_np, limit):
        self.fn, self.limit, self.vs = fn, int(limit), float(vs)
        occ, labels, self.comp, reach, mean = arrays
        dims = np.asarray(occ.shape, dtype=np.int64)
        lo = np.ascontiguousarray(lo_np, dtype=np.float64)
        t = np.ascontiguousarray(t_np, dtype=np.float64)
        self.ae = np.empty((2, 3), dtype=np.int64)  # the window [a, e), written per call
        self.dmin = np.empty(1)
        self._keep = (occ, labels, reach, mean, dims, lo, t)  # what the pointers point into
        ptr = lambda x: None if x is None else x.ctypes.data  # noqa: E731
        self._p = (ptr(occ), ptr(labels), ptr(reach), ptr(mean), ptr(dims), ptr(self.ae), ptr(lo), ptr(t),
                   ptr(self.dmin))

    def __call__(self, a, e):
        """One window [a, e): (any voxel free and reachable, candidates' centres [<= limit, 3] in stable distance
        order, their smallest distance)."""
        self.ae[0], self.ae[1] = a, e
        centres = np.empty((self.limit, 3))
        occ_p, labels_p, reach_p, mean_p, dims_p, ae_p, lo_p, t_p, dmin_p = self._p
        k = self.fn(occ_p, labels_p, self.comp, reach_p, mean_p, dims_p, ae_p, ae_p + 24, lo_p, self.vs, t_p,
                    self.limit, centres.ctypes.data, dmin_p)
        if k == -3:
            raise MemoryError("native/goalwindow.c could not allocate its work arrays")
        return k >= 0, centres[: max(min(k, self.limit), 0)], float(self.dmin[0])


def _nearest_free_voxel_centre(t, scene, index, grid, reachable, clear, max_candidates, mean_voxels=None,
                               backend: str = "auto") -> Tensor:
    """closest_safe_point's step 3. backend: "auto" (native/goalwindow.c for each window when the inputs fit:
    _window_native_args), "native" or "python" (the numpy windows, the reference); the same candidates in the same
    order either way."""
    occ, lo, vs = grid_arrays(grid)
    shape = np.asarray(occ.shape)
    reachable = _reachable_mask(reachable, occ.shape)  # free and reachable voxels: computed per window below
    native_args = _window_native_args(grid, occ, reachable, mean_voxels) if backend != "python" else None
    fn = choose(backend, goal_window_c, "goalwindow", "goal window scan",
                applies=native_args is not None and max_candidates > 0,
                needs="an OccupancyGrid, a mean-voxel mask and a reachable mask as int32 labels or bool")
    tc = t.cpu()
    t_np, lo_np = tc.numpy(), lo.numpy()
    if isinstance(grid, OccupancyGrid):
        v = grid.voxel_of(t_np)
    else:
        v = _world_to_voxel(grid, tc).numpy()
    vc = np.clip(v, 0, shape - 1)
    window = _NativeWindow(fn, native_args, lo_np, vs, t_np, max_candidates) if fn is not None else None
    R = 2
    while True:
        a = np.maximum(vc - R, 0)
        e = np.minimum(vc + R + 1, shape)
        covers_all = (a == 0).all() and (e == shape).all()
        if fn is not None:
            any_free, ordered, dmin = window(a, e)
            if any_free and len(ordered) == 0:  # every free voxel of the window holds a mean: a wider window
                if covers_all:
                    break
                R *= 2
                continue
            chunks = ((k, torch.from_numpy(ordered[k:k + 16])) for k in range(0, len(ordered), 16))
        else:
            any_free, centres, d = _window_reference(grid, scene, index, occ, reachable, mean_voxels, a, e, lo_np, vs,
                                                 t_np)
            if any_free and centres is None:
                if covers_all:
                    break
                R *= 2
                continue
            dmin = float(d.min()) if any_free else np.inf
            chunks = _nearest_chunks(centres, d, max_candidates, 16) if any_free else iter(())
        if any_free:
            # every voxel outside the window is at least R voxels away (target inside the grid)
            if dmin <= R * vs or covers_all:
                for k, cand in chunks:  # a few exact tests at a time
                    ok = torch.as_tensor(clear(cand.to(scene.means.device))).reshape(-1).cpu()
                    if bool(ok.any()):
                        return cand[int(torch.nonzero(ok)[0, 0])]
                if covers_all:
                    break
        elif covers_all:
            break
        R *= 2
    raise GoalUnreachableError(
        f"no safe camera position found near the goal {t.tolist()}: the projection polytope is empty and "
        f"no free voxel without Gaussian means passed the clearance test"
    )


def _window_reference(grid, scene, index, occ, reachable, mean_voxels, a, e, lo_np, vs, t_np):
    """One window in numpy (the reference): (any voxel free and reachable, candidates' centres [K, 3] or None when
    every free one holds a mean, their distances [K])."""
    win = (slice(a[0], e[0]), slice(a[1], e[1]), slice(a[2], e[2]))
    sub = ~occ[win]
    if reachable is not None:
        sub &= reachable[win]
    if not sub.any():
        return False, None, None
    # voxels holding a Gaussian mean are not goals (paper): mark them in this window only
    if mean_voxels is not None:
        sub &= ~mean_voxels[a[0]:e[0], a[1]:e[1], a[2]:e[2]]
    ids = None
    if mean_voxels is None:  # the means in the window's box, from the index
        wlo = _voxel_to_world(grid, torch.as_tensor(a)) - 0.5 * vs
        whi = _voxel_to_world(grid, torch.as_tensor(e - 1)) + 0.5 * vs
        ids = candidate_ids(scene, index, wlo.to(scene.means.device), whi.to(scene.means.device))
    if ids is not None and ids.numel():
        mv = _world_to_voxel(grid, scene.means[ids].detach().cpu().to(torch.float64)).numpy() - a
        ok = ((mv >= 0) & (mv < (e - a))).all(1)
        mv = mv[ok]
        sub[mv[:, 0], mv[:, 1], mv[:, 2]] = False
    ijk = np.argwhere(sub) + a
    if len(ijk) == 0:
        return True, None, None
    centres = _voxel_centres(grid, ijk, lo_np, vs)  # [K, 3] float64
    return True, centres, np.sqrt(((centres - t_np) ** 2).sum(1))


# ------------------------------------------------------------------------------------ starts
def sample_free_starts(
    n: int,
    scene,
    index=None,
    grid=None,
    generator: Union[torch.Generator, int, None] = 0,
    region_lo=None,
    region_hi=None,
    max_tries: int = 50,
    *,
    batch: Optional[int] = None,
    margin: float = 1e-6,
    reachable: Optional[np.ndarray] = None,
    clearance_fn: Optional[Callable[[Tensor], Tensor]] = None,
    away_from: Optional[Union[Tensor, np.ndarray, Sequence[float]]] = None,
    away_fraction: float = 0.0,
    blocked: Optional[np.ndarray] = None,
) -> Tensor:
    """n collision-free camera centres [n, 3] float64, uniformly sampled in the region (seeded).

    region_lo/hi default to the grid's extent (or the scene bounds without a grid); with a grid the
    region is clipped to it and samples in occupied voxels (or outside ``reachable``) are rejected
    before the exact clearance test. ``generator``: a torch.Generator (CPU) or an int seed; the same
    seed gives the same starts. Raises NoFreeStartError (a StartInCollisionError) after ``max_tries``
    batches without n free points.

    ``away_from`` [3] (e.g. the look-at point) with ``away_fraction`` > 0: samples closer to it than
    away_fraction x the region's longest side are rejected too (before the clearance test). Preferred, not
    required: when ``max_tries`` batches give fewer than n such starts, the missing ones are drawn again
    without this rule (same generator), so it never makes a request fail.

    ``blocked`` [X,Y,Z] bool: occupied | ~reachable when the caller keeps it (starts.random_starts, once per
    prepared scene); it replaces both masks.
    """
    if int(n) != n or n < 1:
        raise InvalidInputError(f"number of starts must be a positive integer, got {n}")
    n = int(n)
    if not (math.isfinite(float(away_fraction)) and 0.0 <= float(away_fraction) < 1.0):
        raise InvalidInputError(f"away_fraction must be in [0, 1), got {away_fraction}")
    dev = scene.means.device
    gen = generator if isinstance(generator, torch.Generator) else torch.Generator().manual_seed(int(generator or 0))
    occ = None
    if grid is not None:
        occ, glo, vs = grid_arrays(grid)
        ghi = glo + torch.as_tensor(occ.shape, dtype=torch.float64) * vs
        if blocked is not None:
            if blocked.shape != occ.shape:
                raise InvalidInputError(f"blocked mask {blocked.shape} does not match the grid {occ.shape}")
            occ = blocked
        elif reachable is not None:
            reachable = np.asarray(reachable, dtype=bool)
            if reachable.shape != occ.shape:
                raise InvalidInputError(f"reachable mask {reachable.shape} does not match the grid {occ.shape}")
            occ = occ | ~reachable
    else:
        glo, ghi = (x.detach().cpu().to(torch.float64) for x in scene.bounds())
    lo = glo if region_lo is None else torch.maximum(torch.as_tensor(region_lo, dtype=torch.float64).reshape(3), glo)
    hi = ghi if region_hi is None else torch.minimum(torch.as_tensor(region_hi, dtype=torch.float64).reshape(3), ghi)
    if not (torch.isfinite(lo).all() and torch.isfinite(hi).all()) or (hi <= lo).any():
        raise InvalidInputError(f"start region is empty: lo={lo.tolist()} hi={hi.tolist()} "
                                "(after clipping to the grid)")
    clear = clearance_fn or _default_clear(scene, index, margin)
    batch = batch or max(4 * n, 32)
    away = None
    if away_from is not None and float(away_fraction) > 0:
        away = torch.as_tensor(np.asarray(away_from, dtype=np.float64)).reshape(3)
        if not torch.isfinite(away).all():
            raise InvalidInputError(f"away_from must be a finite 3-vector, got {away.tolist()}")
        away_d = float(away_fraction) * float((hi - lo).max())
    found = []
    tried = 0
    rounds = [True, False] if away is not None else [False]
    for use_away in rounds:
        for _ in range(max_tries):
            x = lo + torch.rand(batch, 3, generator=gen, dtype=torch.float64) * (hi - lo)  # [B, 3]
            tried += batch
            if use_away:
                x = x[(x - away).norm(dim=1) >= away_d]
            if occ is not None:
                v = _world_to_voxel(grid, x).numpy()
                inside = ((v >= 0) & (v < np.asarray(occ.shape))).all(1)
                vcl = np.clip(v, 0, np.asarray(occ.shape) - 1)
                keep = inside & ~occ[vcl[:, 0], vcl[:, 1], vcl[:, 2]]
                x = x[torch.as_tensor(keep)]
            if x.shape[0] == 0:
                continue
            x = x[: max(2 * (n - len(found)), 8)]  # bound the exact checks per batch
            ok = torch.as_tensor(clear(x.to(dev))).reshape(-1).cpu()
            found.extend(x[ok])
            if len(found) >= n:
                return torch.stack(found[:n]).to(dev)
    raise NoFreeStartError(
        f"found only {len(found)} of {n} collision-free start positions after {tried} random samples in the "
        f"region lo={lo.tolist()} hi={hi.tolist()}; widen the region or lower the camera radius"
    )
