"""Exact float64 distance references: point <-> ellipsoid surface, scene clearance, ellipsoid pairs.

Point to ellipsoid (Eberly, "Distance from a point to an ellipse, an ellipsoid, or a hyperellipsoid").
In the ellipsoid frame with axes sorted e0 >= e1 >= e2 and y = |w| (first octant, by symmetry), the
closest surface point is x_i = e_i^2 y_i / (t + e_i^2) where the Lagrange multiplier t solves
F(t) = sum (e_i y_i / (t + e_i^2))^2 = 1. In Eberly's scaled variables z_i = y_i/e_i,
r_i = (e_i/e2)^2, s = t/e2^2:  G(s) = sum_i (r_i z_i / (s + r_i))^2 - 1 = 0 on s > -1, and G is convex
and decreasing there. Degenerate case (the point lies on the plane y2 = 0 inside the ellipsoid and
G(-1+) <= 0): the multiplier is s = -1 and the surface point is x_i = e_i r_i z_i/(r_i - 1) on the axes
with r_i > 1, the remaining mass going to axis 2. This covers points inside, on axes, at the centre
and very flat ellipsoids. The root is found by Newton steps from a lower bound (monotone for a
convex decreasing function) safeguarded by bisection.

The ellipsoid is {x : |diag(1/a) R^T (x - mu)| <= 1}; R is taken as orthonormal (a float32 rotation is
orthonormal to ~1e-7, which is the accuracy of "exact" here in world units relative to the scene).
"""
from __future__ import annotations

import math
from typing import Optional, Tuple, Union

import numpy as np
import torch
from torch import Tensor

from ..errors import InvalidInputError
from ..scene.ellipsoids import EllipsoidScene


def _distance_local(w: Tensor, radii: Tensor, max_iter: int = 200, fused: bool = True) -> Tensor:
    """Signed distance [...] from local points w [..., 3] to ellipsoids with semi-axes radii [..., 3]
    centred at the origin, axis-aligned (float64). On CUDA tensors the same root finding runs as one Triton kernel
    (distance_fused.py: a GPU round here is ~45 launches and a host sync); ``fused=False`` forces this eager loop."""
    w, radii = torch.broadcast_tensors(w.double(), radii.double())
    if fused and w.is_cuda and w.numel():
        from . import distance_fused

        if distance_fused.available(w):
            try:
                return distance_fused.distance_local_fused(w, radii, max_iter)
            except Exception as e:  # noqa: BLE001 - any Triton/compile failure: the eager loop below
                distance_fused.disable(e)
    e, order = torch.sort(radii, dim=-1, descending=True)  # e0 >= e1 >= e2
    y = w.abs().gather(-1, order)
    z = y / e
    inside = (z * z).sum(-1) < 1
    r = (e / e[..., 2:3]) ** 2  # [..., 3] r_i >= 1, r_2 = 1
    pos = z > 0
    # G(-1+): infinite when a term with r_i == 1 has z_i > 0, else finite.
    pole = (pos & (r <= 1)).any(-1)
    with torch.no_grad():
        rz = torch.where(pos & (r > 1), r * z / (r - 1).clamp_min(1e-300), torch.zeros_like(z))
        g_m = (rz * rz).sum(-1) - 1
    degenerate = ~pole & (g_m <= 0)

    # Root bracket: lo = max_i r_i (z_i - 1) over z_i > 0 (there term i alone is >= 1, so G >= 0),
    # clipped to > -1; hi = -1 + |r z| (there G <= 0).
    lo = torch.where(pos, r * (z - 1), torch.full_like(z, -math.inf)).max(-1).values
    lo = torch.maximum(lo, torch.full_like(lo, -1.0))
    hi = -1 + (r * z).norm(dim=-1)
    hi = torch.maximum(hi, lo)
    work = ~degenerate & pos.any(-1)
    lo = torch.where(work, lo, torch.zeros_like(lo))
    hi = torch.where(work, hi, torch.zeros_like(hi))
    # at lo == -1 with no pole, G(-1) = g_m > 0 is finite, fine; with a pole lo > -1.
    if w.device.type != "cpu" or w.requires_grad or radii.requires_grad:
        s = _root(torch, lo, hi, r * z, r, pos, ~work, max_iter)
    else:  # numpy: the same float64 operations on these small arrays at a fraction of torch's per-call overhead
        with np.errstate(all="ignore"):
            s = torch.from_numpy(_root(np, *(t.numpy() for t in (lo, hi, r * z, r, pos, ~work)), max_iter))
    # s: the converged lower bound of the root
    x = torch.where(pos, e * r * z / (s[..., None] + r), torch.zeros_like(z))
    # degenerate: s = -1
    xd = e * rz
    rest = (1 - ((xd / e) ** 2).sum(-1)).clamp_min(0)
    xd = torch.cat([xd[..., :2], (e[..., 2] * torch.sqrt(rest))[..., None]], -1)
    x = torch.where(degenerate[..., None], xd, x)
    # centre with all z = 0 is degenerate too (g_m = -1): x = (0, 0, e2), handled above.
    d = (x - y).norm(dim=-1)
    return torch.where(inside, -d, d)


def _root(xp, lo, hi, rz, r, pos, stop, max_iter: int):
    """_distance_local's root of G(s) = sum_i (rz_i / (s + r_i))^2 - 1 over z_i > 0 (pos) in [lo, hi]: Newton steps
    from the lower bound (monotone for a convex decreasing G) safeguarded by bisection, until every element converged
    or is stopped; returns the lower bound. xp: torch or numpy, the same float64 operations in the same order (sums
    of the three terms left to right, as torch's sum(-1))."""
    zero = xp.zeros_like(rz)

    def g(s):
        sr = s[..., None] + r
        q = xp.where(pos, rz / sr, zero)
        qq = q * q
        return ((qq[..., 0] + qq[..., 1]) + qq[..., 2]) - 1, q, sr

    for _ in range(max_iter):
        g_lo, q, sr = g(lo)
        t = -2 * q * q / sr
        newton = lo - g_lo / (((0.0 + t[..., 0]) + t[..., 1]) + t[..., 2])
        mid = 0.5 * (lo + hi)
        up = g(mid)[0] > 0
        # bisection step shrinks the bracket; Newton from the (left) lower bound stays left of the root
        lo2 = xp.where(up, mid, lo)
        hi2 = xp.where(up, hi, mid)
        ok = xp.isfinite(newton) & (newton > lo2) & (newton < hi2)
        g_nt = g(xp.where(ok, newton, lo2))[0]
        lo2 = xp.where(ok & (g_nt >= 0), newton, lo2)
        hi2 = xp.where(ok & (g_nt < 0), newton, hi2)
        done = ((hi2 - lo2) <= 1e-15 * (1 + abs(hi2))) | (abs(newton - lo) <= 1e-15 * (1 + abs(lo)))
        lo, hi = lo2, hi2
        if bool((done | stop).all()):
            break
    return lo


def point_ellipsoid_distance(
    points: Tensor,  # [P, 3]
    means: Tensor,  # [N, 3]
    rotations: Tensor,  # [N, 3, 3]
    radii: Tensor,  # [N, 3]
) -> Tensor:
    """Signed Euclidean distance [P, N] (float64) from each point to each ellipsoid surface
    (negative inside). Dense: use for tests and small N; ``clearance`` uses the index."""
    p = torch.as_tensor(points).double()
    d = p[:, None, :] - means.double()[None]  # [P, N, 3]
    w = (d[..., :, None] * rotations.double()[None]).sum(-2)  # R^T d
    return _distance_local(w, radii.double()[None].expand_as(w))


FIRST_BOX_FRACTION = 0.25
"""First search box of clearance(), as a fraction of the index's finest cell: a box of a whole cell gathers
thousands of point-ellipsoid pairs per point in dense scenes; a quarter cell finds a near surface with
~10x fewer, and growing it (x1.5 per round) is cheap (about twice as fast over a shot's frames as a whole cell)."""


PRUNE_SLACK = 1e-6
"""Relative slack of _min_over_pairs' lower-bound prune (as native/polytope.c's): keeping a pair too many costs one root
finding, dropping the nearest one reported inf."""


def native_capped_distance(fn, pts: Tensor, scene: EllipsoidScene, index, cap: float) -> Tensor:
    """min(cap, distance to the nearest ellipsoid) [P] through native/polytope.c (NaN where a point is inside one)."""
    from .native_scene import native_arrays

    p = np.ascontiguousarray(pts.cpu().numpy(), dtype=np.float64)
    out = np.empty(p.shape[0], dtype=np.float64)
    if fn(*native_arrays(scene, index)["args"], p.ctypes.data, p.shape[0], float(cap), out.ctypes.data) != 0:
        raise InvalidInputError(f"bad max_distance {cap}")
    return torch.from_numpy(out).to(pts.device)


def clearance(
    points: Tensor,  # [P, 3]
    scene: EllipsoidScene,
    index=None,
    return_index: bool = False,
    max_distance: Optional[float] = None,
    chunk_pairs: int = 2_000_000,
    start_radius: Optional[Tensor] = None,
    backend: str = "auto",
) -> Union[Tensor, Tuple[Tensor, Tensor]]:
    """Exact clearance [P] (float64) = min_j signed_dist(point, E_j) - camera_radius.

    With an index, two phases per point: (1) grow a search box (x1.5 per round) until it holds a candidate,
    and take U = the smallest distance to those candidates (cheap bounds prune most pairs before the exact root
    finding); (2) every ellipsoid closer than U has its padded AABB within the box of half-width U - pad, so
    unless the first box already reached that far, query that box once more and take its exact minimum. Without
    an index all ellipsoids are candidates. ``max_distance``: distances above it are not searched for and are
    reported as max_distance (so the clearance is then max_distance - camera_radius, a lower bound);
    use it to bound the work for points far from everything. ``return_index`` also returns the id [P]
    of the nearest ellipsoid (-1 where capped). ``start_radius`` [P] (optional): the first search box's
    half-width per point, e.g. an estimate of its distance from the occupancy grid, so that most points find
    their nearest ellipsoid in the first round instead of after many growing rounds (each a batched index
    query); any value gives the same exact result, only the number of rounds and pairs changes.
    backend: "auto" (with a finite ``max_distance`` and no ``return_index``, a CPU scene and a GridIndex on the CPU: the
    compiled search, native/polytope.c's cn_points_distance, one point at a time, nearest bounding spheres pruned, the
    same root finding in the unscaled multiplier; points inside an ellipsoid are then measured by the path below),
    "native" (error if it does not apply) or "python"."""
    pts = torch.as_tensor(points, device=scene.device)
    if pts.ndim != 2 or pts.shape[-1] != 3:
        raise InvalidInputError(f"points must be [P, 3], got {tuple(pts.shape)}")
    if not bool(torch.isfinite(pts).all()):
        raise InvalidInputError("points contain NaN or inf")
    pts = pts.double()
    from ..native import choose, points_distance_c
    from .native_scene import native_applies

    fn = choose(backend, points_distance_c, "polytope", "capped distance",
                applies=max_distance is not None and math.isfinite(max_distance) and not return_index
                and native_applies(scene, index),
                needs="a finite max_distance, no return_index, a CPU scene and a GridIndex on the CPU")
    if fn is not None:
        d = native_capped_distance(fn, pts, scene, index, float(max_distance))  # [P]
        inside = torch.nonzero(torch.isnan(d)).squeeze(-1)
        if inside.numel():
            inner = clearance(pts[inside], scene, index, max_distance=max_distance, backend="python")
            d[inside] = inner + scene.camera_radius
        return d - scene.camera_radius
    P = pts.shape[0]
    dev = pts.device
    cap = math.inf if max_distance is None else float(max_distance)
    best = torch.full((P,), math.inf, dtype=torch.float64, device=dev)
    arg = torch.full((P,), -1, dtype=torch.long, device=dev)
    brute = torch.zeros(P, dtype=torch.bool, device=dev)
    if index is not None and P:
        _indexed_search(pts, scene, index, cap, start_radius, best, arg, brute)
        arg[best > cap] = -1
        best = best.clamp_max(cap)
    else:
        brute[:] = True
    _brute_force(pts, scene, torch.nonzero(brute).squeeze(-1), cap, chunk_pairs, best, arg)
    out = best - scene.camera_radius
    return (out, arg) if return_index else out


def _first_radius(pts: Tensor, index, cap: float, start_radius: Optional[Tensor]) -> Tuple[Tensor, Tensor, float]:
    """(first search-box half-width [P], distance to the scene box [P], half-width beyond which a box covers the
    scene) for clearance's indexed search."""
    P, dev = pts.shape[0], pts.device
    lo_s, hi_s = index.lo.min(0).values, index.hi.max(0).values
    # distance from each point to the scene box: no search box smaller than this can hit
    gap = torch.maximum(lo_s - pts, pts - hi_s).clamp_min(0).max(-1).values
    far_r = float((hi_s - lo_s).max()) + 1.0
    first = max(FIRST_BOX_FRACTION * index.levels[0].cell, 1e-6)
    rad = torch.maximum(torch.full((P,), first, dtype=torch.float64, device=dev), gap)
    if start_radius is not None:
        sr = torch.as_tensor(start_radius, device=dev).double().reshape(-1)
        if sr.shape != (P,):
            raise InvalidInputError(f"start_radius must be [P={P}], got {tuple(sr.shape)}")
        sr = torch.where(torch.isfinite(sr), sr, torch.zeros_like(sr))
        if math.isfinite(cap):  # a box beyond the cap is never needed: reach >= cap already caps the point
            sr = sr.clamp_max(max(cap - float(index.pad), 0.0))
        rad = torch.maximum(rad, sr)
    return rad, gap, far_r


def _indexed_search(pts: Tensor, scene: EllipsoidScene, index, cap: float, start_radius: Optional[Tensor],
                    best: Tensor, arg: Tensor, brute: Tensor) -> None:
    """clearance's search with an index, filling best [P] / arg [P] in place (best = cap where capped; brute [P] set
    for points whose growing box came to cover the whole scene without a candidate)."""
    rad, gap, far_r = _first_radius(pts, index, cap, start_radius)
    todo = torch.arange(pts.shape[0], device=pts.device)
    while todo.numel():
        pi, gi = index.query_points(pts[todo], rad[todo])
        d, g_best = _min_over_pairs(pts[todo], scene, pi, gi, todo.numel())
        reach = rad[todo] + index.pad  # every ellipsoid closer than this was a candidate
        exact = d <= reach
        capped = ~exact & (reach >= cap)
        best[todo[exact]], arg[todo[exact]] = d[exact], g_best[exact]
        best[todo[capped]] = cap
        # found something farther than the search box: one more query, exactly as large as needed
        redo = torch.nonzero(~exact & ~capped & torch.isfinite(d)).squeeze(-1)
        if redo.numel():
            t = todo[redo]
            u = torch.minimum(d[redo], torch.full_like(d[redo], cap))
            pi2, gi2 = index.query_points(pts[t], (u - index.pad).clamp_min(0))
            d2, g2 = _min_over_pairs(pts[t], scene, pi2, gi2, t.numel(), u)
            # d2 is exact (all ellipsoids closer than u were candidates); the first-round d is a
            # true distance too, kept where it is smaller (last-bit rounding differences)
            first = d[redo] < d2
            best[t] = torch.where(first, d[redo], d2)
            arg[t] = torch.where(first, g_best[redo], g2)
        todo = todo[~exact & ~capped & ~torch.isfinite(d)]  # nothing found yet: grow the box
        rad[todo] *= 1.5
        whole = rad[todo] > far_r + gap[todo]  # the box covers the scene: brute force
        brute[todo[whole]] = True
        todo = todo[~whole]


def _brute_force(pts: Tensor, scene: EllipsoidScene, todo: Tensor, cap: float, chunk_pairs: int, best: Tensor,
                 arg: Tensor) -> None:
    """Exact distance of the points todo [T] to every ellipsoid, in chunks of ~chunk_pairs pairs, into best / arg
    (capped at cap, arg -1 there)."""
    if not todo.numel():
        return
    dev = pts.device
    n = len(scene)
    step = max(1, chunk_pairs // max(n, 1))
    for i in range(0, todo.numel(), step):
        t = todo[i : i + step]
        pi = torch.arange(t.numel(), device=dev).repeat_interleave(n)
        gi = torch.arange(n, device=dev).repeat(t.numel())
        d, g_best = _min_over_pairs(pts[t], scene, pi, gi, t.numel())
        if not math.isinf(cap):
            g_best = torch.where(d <= cap, g_best, torch.full_like(g_best, -1))
            d = d.clamp_max(cap)
        best[t], arg[t] = d, g_best


def _pair_geometry(pts: Tensor, scene: EllipsoidScene, pi: Tensor, gi: Tensor):
    mu = scene.means.index_select(0, gi).double()
    rad = scene.radii.index_select(0, gi).double()
    rot = scene.rotations.index_select(0, gi).double()
    dvec = pts.index_select(0, pi) - mu
    w = (dvec[:, :, None] * rot).sum(-2)  # R^T (p - mu)
    return w, rad, dvec.norm(dim=-1)


def _bounds(w: Tensor, rad: Tensor, dist_c: Tensor) -> Tuple[Tensor, Tensor]:
    """(lb, ub) of the signed distance, cheap (no root finding).

    lb: E lies in its local box |w_i| <= a_i and in the ball of radius a_max, so the distance to the
    box (when > 0, the point is outside E) and |p - mu| - a_max are lower bounds.
    ub: distance to any surface point; the min of two: the radial point w/m (m = Mahalanobis norm)
    and, for flat ellipsoids, the point above w on the surface (w with the shortest-axis coordinate
    moved onto the surface, or the rim point if w lies outside the ellipse of the two long axes).
    Inside points: ub = |p - mu| - a_min (the ball of radius a_min is inside E)."""
    box = (w.abs() - rad).clamp_min(0).norm(dim=-1)
    lb = torch.where(box > 0, torch.maximum(box, dist_c - rad.max(-1).values), dist_c - rad.max(-1).values)
    m = (w / rad).norm(dim=-1)
    ub_radial = dist_c * (1 - 1 / m.clamp_min(1e-300))
    k = rad.argmin(-1, keepdim=True)  # shortest axis
    q = w.scatter(-1, k, torch.zeros_like(k, dtype=w.dtype))
    rho2 = ((q / rad) ** 2).sum(-1)
    wk = w.gather(-1, k)[..., 0]
    ak = rad.gather(-1, k)[..., 0]
    lift = torch.where(wk < 0, -ak, ak) * torch.sqrt((1 - rho2).clamp_min(0))
    x = torch.where((rho2 <= 1)[..., None], q.scatter(-1, k, lift[..., None]),
                    q / torch.sqrt(rho2.clamp_min(1e-300))[..., None])
    ub_flat = (w - x).norm(dim=-1)
    ub = torch.where(m > 1, torch.minimum(ub_radial, ub_flat), dist_c - rad.min(-1).values)
    return lb, ub


def _min_over_pairs(
    pts: Tensor, scene: EllipsoidScene, pi: Tensor, gi: Tensor, P: int, known_ub: Optional[Tensor] = None
) -> Tuple[Tensor, Tensor]:
    """min over candidate pairs of the exact signed distance, per point: ([P] (inf if none), arg [P])."""
    dev = pts.device
    best = torch.full((P,), math.inf, dtype=torch.float64, device=dev)
    arg = torch.full((P,), -1, dtype=torch.long, device=dev)
    if pi.numel() == 0:
        return best, arg
    # sphere pre-prune from the means and radii alone (no rotations gathered): the signed distance lies in
    # [|p - mu| - a_max, |p - mu| - a_min] (E holds the ball of radius a_min, lies in the ball of a_max)
    rad0 = scene.radii.index_select(0, gi).double()  # [K, 3]
    dc = (pts.index_select(0, pi) - scene.means.index_select(0, gi).double()).norm(dim=-1)  # [K]
    u0 = torch.full((P,), math.inf, dtype=torch.float64, device=dev).scatter_reduce(0, pi, dc - rad0.min(-1).values,
                                                                                    "amin")
    if known_ub is not None:
        u0 = torch.minimum(u0, known_ub)
    near = torch.nonzero(dc - rad0.max(-1).values <= u0.index_select(0, pi) + 1e-12).squeeze(-1)
    if near.numel() < pi.numel():
        pi, gi = pi.index_select(0, near), gi.index_select(0, near)
    w, rad, dist_c = _pair_geometry(pts, scene, pi, gi)
    lb, ub = _bounds(w, rad, dist_c)
    u_best = torch.full((P,), math.inf, dtype=torch.float64, device=dev).scatter_reduce(0, pi, ub, "amin")
    if known_ub is not None:
        u_best = torch.minimum(u_best, known_ub)
    # Relative slack: lb (local frame, |R^T d|) and ub (world frame, |d|) disagree by up to ~1e-7 |d| when a float32
    # rotation is not exactly orthonormal; an absolute 1e-12 then dropped every pair of a point whose nearest
    # ellipsoid is tiny (lb == ub up to rounding) and the point's clearance came out inf (a real capture did this).
    keep = torch.nonzero(lb <= u_best.index_select(0, pi) + PRUNE_SLACK * (1 + dist_c)).squeeze(-1)
    d = _distance_local(w[keep], rad[keep])
    best = best.scatter_reduce(0, pi[keep], d, "amin")
    is_min = d <= best.index_select(0, pi[keep])  # argmin: a pair achieving the min
    arg[pi[keep][is_min]] = gi[keep][is_min]
    return best, arg


# ---------------------------------------------------------------------------- ellipsoid pairs
def _mahal2(x: np.ndarray, mu: np.ndarray, rot: np.ndarray, radii: np.ndarray) -> float:
    w = rot.T @ (x - mu) / radii
    return float(w @ w)


def _mahal2_grad(x: np.ndarray, mu: np.ndarray, rot: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """d _mahal2 / dx [3]: the references give SLSQP exact gradients (finite differences cost 4-7 evaluations each)."""
    return 2.0 * rot @ (rot.T @ (x - mu) / radii**2)


def ellipsoid_scaling_factor(mu_a, rot_a, radii_a, mu_b, rot_b, radii_b) -> float:
    """lambda* = min_x max(|x|_A, |x|_B) (Mahalanobis norms about each centre), by convex optimisation
    (scipy SLSQP, float64). Scaling both ellipsoids about their centres by lambda* makes them touch:
    lambda* < 1 <=> they overlap, > 1 <=> disjoint. Theorem 1 states max_s K(s) = lambda*^2, so this is an
    independent reference for Theorem 1 / Proposition 1."""
    from scipy.optimize import minimize

    A = [np.asarray(torch.as_tensor(t).double().cpu()) for t in (mu_a, rot_a, radii_a)]
    B = [np.asarray(torch.as_tensor(t).double().cpu()) for t in (mu_b, rot_b, radii_b)]
    ha = np.sqrt(((A[1] * A[2][None, :]) ** 2).sum(-1)).max()
    hb = np.sqrt(((B[1] * B[2][None, :]) ** 2).sum(-1)).max()
    x0 = (A[0] * hb + B[0] * ha) / (ha + hb)
    scale = max(ha, hb)
    fun = lambda v: v[3]
    fun_grad = lambda v: np.array([0.0, 0.0, 0.0, 1.0])
    cons = [
        {"type": "ineq", "fun": lambda v, E=E: v[3] - _mahal2(A[0] + scale * v[:3], *E),
         "jac": lambda v, E=E: np.append(-scale * _mahal2_grad(A[0] + scale * v[:3], *E), 1.0)}
        for E in (A, B)
    ]
    v0 = np.concatenate([(x0 - A[0]) / scale, [max(_mahal2(x0, *A), _mahal2(x0, *B))]])
    res = minimize(fun, v0, jac=fun_grad, constraints=cons, method="SLSQP", options={"ftol": 1e-15, "maxiter": 500})
    x = A[0] + scale * res.x[:3]
    return math.sqrt(max(_mahal2(x, *A), _mahal2(x, *B)))


def ellipsoid_ellipsoid_distance(mu_a, rot_a, radii_a, mu_b, rot_b, radii_b) -> float:
    """Euclidean distance between two ellipsoids (0 when they overlap), scipy SLSQP in float64 on
    min |x - y|^2 s.t. x in A, y in B (a convex problem, so the local optimum is global)."""
    from scipy.optimize import minimize

    A = [np.asarray(torch.as_tensor(t).double().cpu()) for t in (mu_a, rot_a, radii_a)]
    B = [np.asarray(torch.as_tensor(t).double().cpu()) for t in (mu_b, rot_b, radii_b)]
    if ellipsoid_scaling_factor(*A, *B) <= 1:
        return 0.0
    scale = float(max(A[2].max(), B[2].max()))
    fun = lambda v: float(((v[:3] - v[3:]) ** 2).sum())
    fun_grad = lambda v: np.concatenate([2 * (v[:3] - v[3:]), 2 * (v[3:] - v[:3])])
    cons = [
        {"type": "ineq", "fun": lambda v: 1 - _mahal2(scale * v[:3], *A),
         "jac": lambda v: np.concatenate([-scale * _mahal2_grad(scale * v[:3], *A), np.zeros(3)])},
        {"type": "ineq", "fun": lambda v: 1 - _mahal2(scale * v[3:], *B),
         "jac": lambda v: np.concatenate([np.zeros(3), -scale * _mahal2_grad(scale * v[3:], *B)])},
    ]
    v0 = np.concatenate([A[0], B[0]]) / scale
    res = minimize(fun, v0, jac=fun_grad, constraints=cons, method="SLSQP", options={"ftol": 1e-16, "maxiter": 1000})
    return scale * math.sqrt(max(res.fun, 0.0))
