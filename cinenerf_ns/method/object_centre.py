"""Where an object *is*: the centroid of its volume, estimated from the Gaussians on its surface.

A trained splat puts its Gaussians on visible surfaces, so the mean of an object's Gaussians is a *surface*
centroid. For a floor lamp (a wide shade on a long thin pole) that is far from the object's middle: the pole
and the base own many Gaussians but little volume (synthetic room: the lamp's own true Gaussians average 7.8%
of the room size away from its volume centroid; sofa and armchair ~4%). The camera should look at the object,
not at the surface-weighted middle of its parts.

Estimate (approximate; documented in the README):

1. voxelise the selection in a frame whose third axis is the world up. Voxel = the longest side / ``resolution``,
   but never finer than ``spacing_voxels`` x the median distance between neighbouring Gaussians: a voxel finer than
   the Gaussians' spacing turns a sparsely covered surface (a small vase: ~1500 Gaussians) into a sieve that no
   rule can fill. Every Gaussian marks the voxels its 1-sigma ellipsoid touches (capped at ``max_extent_voxels``,
   so one huge Gaussian cannot smear the object); a morphological closing (``close`` voxels) seals small holes
   between Gaussians. These are the *surface* voxels.
2. a voxel is *inside* if, within its horizontal slice, a surface voxel lies along at least ``min_horizontal`` of
   the 16 horizontal rays (22.5 degrees apart), and one lies on at least one side vertically. Why many rays and a
   vote: a reconstructed side wall always has a few holes, and a rule that needs every ray to hit leaves an
   unfilled column behind each hole (a lampshade came out ~20% empty with 4 of 4 axis rays); a small hole lets
   one or two neighbouring rays out. Why not fewer hits: a concave pocket (the seat of an armchair between its
   arms and back, the air under a table, an open shelf) is open over a wide angle and lets 3 or more of the 16
   rays out, and must stay outside (with 8 rays and 6 hits the armchair's seat pocket was filled: 1.4% of the
   room off). Why one vertical side: captures rarely see the top of a tall object or the underside of anything,
   so those faces are often missing.
   With the training cameras (``cameras``), a voxel inside the box of the surface voxels is also filled when no
   camera can see it: the segment from it toward every camera meets a surface voxel of the object (``hidden_voxels``).
   Why: a capture rarely sees every side of an object (the back of a cabinet that faces away from every camera, the
   underside of an armchair's seat), the splat puts few Gaussians there, and the ray vote leaves what lies behind
   such a thin face empty (trained room 2: 28% of a cabinet's true volume, its centre 1.4% of the room off; with
   the cameras 0.4%). Unseen space is filled as if it were the object: a space-carving estimate, which overfills
   a pocket that no camera looks into (room 1's armchair: 1.0 -> 1.4%). Only the object's own surface voxels
   occlude (another object between it and a camera does not hide anything: a conservative choice toward "seen").
3. the centroid of the filled voxels' centres (weights: volume, not Gaussian count). Voxels on the boundary of the
   filled set (a face-neighbour outside it) count ``surface_weight`` = 1/2: a boundary voxel is about half inside
   the object. (Not every voxel a Gaussian touches: splats also put Gaussians inside objects.)

Limits: thin parts (a lamp pole) are thickened to about a voxel, which biases the estimate toward them; an
object whose horizontal faces are open is under-filled; objects that are not closed on the sides (a hollow
tube seen from inside) are filled as if they were. The floor or table an object stands on must not be in the
selection (object_support.py drops such a layer before this runs). Brute-force reference of step 2 in the tests.
"""
from __future__ import annotations

import math
from typing import Optional, Sequence, Union

import numpy as np
import torch
from torch import Tensor

from cinenerf_ns.planner.native import choose, hidden_voxels_c, kernel_threads
from cinenerf_ns.planner.scene.ellipsoids import quat_wxyz_to_rotmat

ArrayLike = Union[Tensor, np.ndarray, Sequence]


def _np64(x: ArrayLike) -> np.ndarray:
    if isinstance(x, Tensor):
        x = x.detach().cpu()
    return np.asarray(x, dtype=np.float64)


def up_frame(up: ArrayLike = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Orthonormal [3, 3] (columns e1, e2, up/|up|): world -> frame coordinates are ``x @ F``."""
    u = _np64(up).reshape(3)
    n = float(np.linalg.norm(u))
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError(f"up must be a finite non-zero 3-vector, got {u.tolist()}")
    u = u / n
    helper = np.zeros(3)
    helper[int(np.argmin(np.abs(u)))] = 1.0
    e1 = np.cross(helper, u)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    return np.stack([e1, e2, u], axis=1)


def _unit_ball_stencil(n: int = 5) -> np.ndarray:
    """Points [S, 3] of an n^3 lattice on [-1, 1]^3 that lie in the unit ball (S = 33 for n = 5)."""
    g = np.linspace(-1.0, 1.0, n)
    p = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return p[np.linalg.norm(p, axis=1) <= 1.0 + 1e-9]


# the 16 horizontal ray directions (axes 0, 1 of the up frame) of step 2, 22.5 degrees apart (lattice steps)
HORIZONTAL_RAYS = ((1, 0), (2, 1), (1, 1), (1, 2), (0, 1), (-1, 2), (-1, 1), (-2, 1),
                   (-1, 0), (-2, -1), (-1, -1), (-1, -2), (0, -1), (1, -2), (1, -1), (2, -1))


def _shifted(a: np.ndarray, sx: int, sy: int) -> np.ndarray:
    """out[i, j] = a[i + sx, j + sy] (False past the border)."""
    X, Y, _ = a.shape
    out = np.zeros_like(a)
    if abs(sx) < X and abs(sy) < Y:
        out[max(0, -sx):X - max(0, sx), max(0, -sy):Y - max(0, sy)] = a[max(0, sx):X + min(0, sx),
                                                                        max(0, sy):Y + min(0, sy)]
    return out


def ray_cells(d: tuple[int, int], k: int) -> set[tuple[int, int]]:
    """The cells of a ray's k-th step (k >= 1) along the lattice direction d = (dx, dy): with n = max(|dx|, |dy|),
    every (floor or ceil of k dx / n, floor or ceil of k dy / n). A ray between lattice points covers both cells it
    passes between, so it cannot slip through a one-voxel wall (conservative toward "hit")."""
    n = max(abs(d[0]), abs(d[1]))
    fx, fy = k * d[0] / n, k * d[1] / n
    return {(x, y) for x in {math.floor(fx), math.ceil(fx)} for y in {math.floor(fy), math.ceil(fy)}}


def _ray_hits(occ: np.ndarray, d: tuple[int, int]) -> np.ndarray:
    """bool [X, Y, Z]: a set voxel at or beyond each voxel along the horizontal ray d (same slice; ray_cells)."""
    X, Y, _ = occ.shape
    hit = occ.copy()
    k = 1
    while True:
        cells = ray_cells(d, k)
        if all(abs(x) >= X or abs(y) >= Y for x, y in cells):
            return hit
        for x, y in cells:
            hit |= _shifted(occ, x, y)
        k += 1


def enclosed_voxels(surface: np.ndarray, min_horizontal: int = 14) -> np.ndarray:  # noqa: D401
    """bool [X, Y, Z]: voxels with a surface voxel along at least ``min_horizontal`` of the 16 horizontal rays
    (``HORIZONTAL_RAYS`` in the plane of axes 0 and 1) and on at least one side along axis 2 (the up axis).
    ``surface`` itself counts as enclosed wherever it is set."""
    occ = np.asarray(surface, dtype=bool)
    if not 1 <= int(min_horizontal) <= len(HORIZONTAL_RAYS):
        raise ValueError(f"min_horizontal must be in 1..{len(HORIZONTAL_RAYS)}, got {min_horizontal}")
    votes = np.zeros(occ.shape, dtype=np.int16)
    for d in HORIZONTAL_RAYS:
        votes += _ray_hits(occ, d)
    below = np.maximum.accumulate(occ, axis=2)  # a surface voxel at or below this one
    above = np.flip(np.maximum.accumulate(np.flip(occ, 2), axis=2), 2)  # at or above
    return occ | ((votes >= int(min_horizontal)) & (below | above))


def hidden_voxels(
    surface: np.ndarray,  # [X, Y, Z] bool: the occluders
    candidates: np.ndarray,  # [X, Y, Z] bool: the voxels to test
    cameras: np.ndarray,  # [C, 3] camera centres in voxel-index coordinates (voxel (i, j, k)'s centre is (i, j, k))
    step: float = 0.5,
    backend: str = "auto",
    threads: Optional[int] = None,
) -> np.ndarray:
    """bool [X, Y, Z]: the candidate voxels (surface voxels excluded) that no camera sees: for every camera, the
    segment from the voxel's centre toward it meets a surface voxel. The segment is sampled every ``step`` voxels
    (sample n at distance n * step; its voxel is the nearest centre, rounding half up) and ends at the camera or
    where it leaves the grid (the grid holds the object: nothing else occludes). Sampling can step past the corner
    of a surface voxel, so a ray may slip through a diagonal gap: an error toward "seen" (less fill).

    backend: "auto" (the compiled kernel, planner/native/voxelrays.c, when it loads; same arithmetic, same result),
    "native" (it or RuntimeError) or "python" (numpy: voxels are tested camera by camera and dropped once one
    camera sees them, so most of the cost is the truly hidden voxels' rays, each ending at its first surface voxel;
    benchmarks/bench_hidden_voxels.py compares the two). threads: the compiled kernel's (default
    planner.native.kernel_threads(); each voxel's answer is its own, so any number gives the same result)."""
    surf = np.asarray(surface, dtype=bool)
    cams = np.asarray(cameras, dtype=np.float64).reshape(-1, 3)
    if surf.ndim != 3 or np.shape(candidates) != surf.shape:
        raise ValueError(f"hidden_voxels: surface {surf.shape} and candidates {np.shape(candidates)} must be one 3-D "
                         "shape")
    if not (step > 0 and np.isfinite(cams).all()):
        raise ValueError("hidden_voxels: step must be > 0 and the cameras finite")
    fn = choose(backend, hidden_voxels_c, "voxelrays", "sight-line test")
    idx = np.argwhere(np.asarray(candidates, dtype=bool) & ~surf)  # [V, 3]
    if fn is not None:
        occ = np.ascontiguousarray(surf, dtype=np.uint8)
        ii = np.ascontiguousarray(idx, dtype=np.int64)
        cc = np.ascontiguousarray(cams, dtype=np.float64)
        flag = np.zeros(len(ii), dtype=np.uint8)  # [V]
        rc = fn(occ.ctypes.data, *surf.shape, ii.ctypes.data, len(ii), cc.ctypes.data, len(cc), float(step),
                flag.ctypes.data, int(threads or kernel_threads()))
        if rc != 0:
            raise RuntimeError(f"cn_hidden_voxels failed ({rc})")
        out = np.zeros(surf.shape, dtype=bool)
        out[tuple(ii[flag.astype(bool)].T)] = True
        return out
    shape = np.asarray(surf.shape)
    hidden = np.ones(len(idx), dtype=bool)  # [V] no camera has seen it yet
    if len(cams) == 0:
        hidden[:] = False  # nothing is known to be hidden without a camera
    for c in cams:
        v = np.flatnonzero(hidden)
        if v.size == 0:
            break
        p = idx[v].astype(np.float64)  # [W, 3]
        d = c - p
        length = np.linalg.norm(d, axis=1)  # [W]
        d /= np.maximum(length, 1e-300)[:, None]
        blocked = np.zeros(v.size, dtype=bool)
        live = np.arange(v.size)  # rays still in the grid, short of the camera, not yet blocked
        n = 1
        while live.size:
            t = n * step
            q = np.floor(p[live] + t * d[live] + 0.5).astype(np.int64)  # [L, 3]
            ok = (q >= 0).all(1) & (q < shape).all(1) & (t <= length[live])
            live, q = live[ok], q[ok]
            hit = surf[q[:, 0], q[:, 1], q[:, 2]]
            blocked[live[hit]] = True
            live = live[~hit]
            n += 1
        hidden[v[~blocked]] = False  # this camera sees it
    out = np.zeros(surf.shape, dtype=bool)
    out[tuple(idx[hidden].T)] = True
    return out


def neighbour_spacing(points: np.ndarray) -> float:
    """Median distance [scalar] from each point [K, 3] to its nearest other point (0 for fewer than 2).

    Exact, and cheaper than querying every point without a bound (a selection's ~10^5 points): the k-d tree is built
    unbalanced (faster, the same exact neighbours) and queried in its own point order (nearby queries one after
    another; the median does not depend on the order), with a bound U (the 90th percentile over ~512 points spread
    through that order): a distance >= U comes back inf, which leaves the median alone while more than half of them
    are below U (checked; else the query runs again without the bound)."""
    from scipy.spatial import cKDTree

    if points.shape[0] < 2:
        return 0.0
    tree = cKDTree(points, balanced_tree=False, compact_nodes=False)
    q = tree.data[tree.indices]
    bound = float(np.quantile(tree.query(q[:: max(1, len(q) // 512)], k=2)[0][:, 1], 0.9))
    d = tree.query(q, k=2, distance_upper_bound=bound)[0][:, 1] if bound > 0 else np.full(len(q), np.inf)
    if np.count_nonzero(np.isfinite(d)) <= len(d) // 2:
        d = tree.query(q, k=2)[0][:, 1]
    return float(np.median(d))


def surface_voxels(
    points_frame: np.ndarray,  # [K, 3] Gaussian means in the up frame
    radii_frame: Optional[np.ndarray],  # [K, 3, 3] columns = the Gaussians' 1-sigma axes in the up frame, or None
    resolution: int,
    close: int,
    max_extent_voxels: float,
    min_voxel: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, float, int]:
    """(surface [X, Y, Z] bool: voxels the Gaussians touch, holes closed; lo [3]; voxel size; pad) of a selection
    (steps 1 of the module docstring; enclosed_voxels does step 2). min_voxel: the voxel is never smaller."""
    from scipy import ndimage

    lo, hi = points_frame.min(0), points_frame.max(0)
    h = max(float((hi - lo).max()) / resolution, float(min_voxel), 1e-9)
    pad = 2 + close
    pts = points_frame
    if radii_frame is not None:
        axes = radii_frame.copy()  # [K, 3, 3]
        length = np.linalg.norm(axes, axis=1)  # [K, 3] per-axis sigma
        cap = max_extent_voxels * h
        keep = np.minimum(length, cap)
        axes *= (keep / np.maximum(length, 1e-300))[:, None, :]
        big = np.flatnonzero(keep.max(1) > 0.5 * h)  # smaller ones touch ~one voxel
        if big.size:
            st = _unit_ball_stencil()
            pts = np.concatenate([points_frame, (points_frame[big, None, :]
                                                 + np.einsum("kij,sj->ksi", axes[big], st)).reshape(-1, 3)])
    lo = pts.min(0)  # the stencils may reach past the means (by <= max_extent_voxels voxels)
    ijk = np.floor((pts - lo) / h).astype(np.int64) + pad
    shape = tuple(ijk.max(0) + pad + 1)
    occ = np.zeros(shape, dtype=bool)
    occ[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = True
    if close > 0:
        occ |= ndimage.binary_closing(occ, iterations=int(close), border_value=0)
    return occ, lo, h, pad


def _eroded(solid: np.ndarray) -> np.ndarray:
    """bool: solid voxels whose 6 face-neighbours are all solid (outside the array counts as empty)."""
    p = np.pad(solid, 1, constant_values=False)
    out = p[1:-1, 1:-1, 1:-1].copy()
    for ax in range(3):
        for sh in (1, -1):
            out &= np.roll(p, sh, axis=ax)[1:-1, 1:-1, 1:-1]
    return out


def volume_centroid(
    means: ArrayLike,  # [K, 3]
    scales: Optional[ArrayLike] = None,  # [K, 3] activated (not log) 1-sigma scales, world units
    quats: Optional[ArrayLike] = None,  # [K, 4] wxyz
    up: ArrayLike = (0.0, 0.0, 1.0),
    resolution: int = 64,
    close: int = 1,
    max_extent_voxels: float = 4.0,
    surface_weight: float = 0.5,
    spacing_voxels: float = 2.0,
    min_horizontal: int = 14,
    cameras: Optional[ArrayLike] = None,  # [C, 3] the training cameras' centres (world units), or None
) -> np.ndarray:
    """Estimated volume centroid [3] (float64, world units) of the object whose surface Gaussians are given.

    Without scales/quats only the means are voxelised (fine for dense selections). Fewer than 4 Gaussians:
    their mean. resolution: voxels along the longest side at most; spacing_voxels: the voxel is at least this
    many times the Gaussians' median neighbour spacing (0: off). min_horizontal: rays of 16 that must hit (step 2).
    cameras: also fill the voxels of the surface voxels' box that none of these cameras sees (step 2, hidden_voxels).
    See the module docstring for the rule and its limits."""
    m = _np64(means).reshape(-1, 3)
    if m.shape[0] == 0:
        raise ValueError("volume_centroid needs at least one Gaussian")
    if not np.isfinite(m).all():
        raise ValueError("volume_centroid: means contain NaN/inf")
    if int(resolution) < 4:
        raise ValueError(f"resolution must be >= 4, got {resolution}")
    if m.shape[0] < 4:
        return m.mean(0)
    F = up_frame(up)
    pf = m @ F  # [K, 3]
    axes_f = None
    if scales is not None and quats is not None:
        s = _np64(scales).reshape(-1, 3)
        q = _np64(quats).reshape(-1, 4)
        if s.shape[0] != m.shape[0] or q.shape[0] != m.shape[0]:
            raise ValueError(f"volume_centroid: {m.shape[0]} means but {s.shape[0]} scales / {q.shape[0]} quats")
        ok = np.isfinite(s).all(1) & np.isfinite(q).all(1) & (np.linalg.norm(q, axis=1) > 0)
        s = np.where(ok[:, None], np.abs(s), 0.0)
        q = np.where(ok[:, None], q, np.array([1.0, 0.0, 0.0, 0.0]))
        R = quat_wxyz_to_rotmat(torch.from_numpy(q)).numpy()  # [K, 3, 3] world
        axes_f = np.einsum("ji,kjl->kil", F, R * s[:, None, :])  # F^T R diag(s): columns = axes in the frame
    min_voxel = float(spacing_voxels) * neighbour_spacing(pf) if spacing_voxels > 0 else 0.0
    surf, lo, h, pad = surface_voxels(pf, axes_f, int(resolution), int(close), float(max_extent_voxels), min_voxel)
    solid = enclosed_voxels(surf, min_horizontal)
    if cameras is not None:
        cams = _np64(cameras).reshape(-1, 3)
        if not np.isfinite(cams).all():
            raise ValueError("volume_centroid: cameras contain NaN/inf")
        ii = np.argwhere(surf)
        a, b = ii.min(0), ii.max(0) + 1
        box = np.zeros_like(surf)
        box[a[0]:b[0], a[1]:b[1], a[2]:b[2]] = True  # unseen space is filled only up to the seen surfaces' extent
        solid |= hidden_voxels(surf, box & ~solid, (cams @ F - lo) / h + pad - 0.5)
    boundary = solid & ~_eroded(solid)  # solid voxels with an outside face-neighbour: about half inside
    idx = np.argwhere(solid)  # [V, 3]
    w = np.where(boundary[idx[:, 0], idx[:, 1], idx[:, 2]], float(surface_weight), 1.0)
    c_frame = lo + ((idx * w[:, None]).sum(0) / w.sum() - pad + 0.5) * h
    return F @ c_frame
