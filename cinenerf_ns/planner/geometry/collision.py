"""Ellipsoid intersection tests of the paper (Sec. IV-A): Theorem 1, Corollary 1, Proposition 1.

Theorem 1 (Gilitschenski & Hanebeck): ellipsoids E_a = {x: (x-mu_a)^T Sigma_a^-1 (x-mu_a) <= 1} and E_b
are disjoint iff some s in (0, 1) has

    K(s) = (mu_b - mu_a)^T [Sigma_a / (1-s) + Sigma_b / s]^-1 (mu_b - mu_a) > 1,

and K is concave in s. Every K value we report is a TRUE evaluation of K at some s, so "free"
(K > 1 + margin) is a proof of separation; sampling can only miss a separating s, i.e. call a free
pair colliding (conservative), never the other way round.

Sphere camera (Corollary 1), derivation. Camera a = ball of radius r: Sigma_a = r^2 I. Ellipsoid b:
Sigma_b = R diag(a_i^2) R^T with R orthonormal. Rotating by R^T (an isometry) leaves K unchanged:
with w = R^T (x - mu_b),

    Sigma_a/(1-s) + Sigma_b/s = R diag(r^2/(1-s) + a_i^2/s) R^T
                              = R diag((s r^2 + (1-s) a_i^2) / (s (1-s))) R^T,

whose inverse is R diag(s(1-s) / (s r^2 + (1-s) a_i^2)) R^T, hence

    K(s) = sum_i w_i^2 * s (1-s) / (s r^2 + (1-s) a_i^2).                        (Cor. 1)

(The paper writes kappa + s(lambda_i - kappa) with the roles of s and 1-s swapped; same max.)
Geometric reading: K(s) > 1 says x lies outside the ellipsoid with semi-axes^2 a_i^2/s + r^2/(1-s),
which contains the Minkowski sum E_b + B(r) (since (h + r)^2 <= h^2/s + r^2/(1-s) for every support
value h), so a true K(s) > 1 proves the ball is clear of E_b.

All pair computations run in float64 whatever the scene dtype (rounding is far below the margin).
Maximisation: K is concave in s, hence unimodal in u = logit(s) (monotone reparametrisation); we
sample u on a grid, bracket the best sample and refine by golden-section search, keeping the best
TRUE value seen.
"""
from __future__ import annotations

import math
from typing import Callable, Optional, Tuple, Union

import torch
from torch import Tensor

from ..errors import InvalidInputError
from ..native import points_collide_c as native_points_collide_c
from ..scene.ellipsoids import EllipsoidScene
from .native_scene import native_applies, native_arrays

DEFAULT_MARGIN = 1e-6
"""'Free' needs K > 1 + margin (relative slack far above float64 rounding of K)."""
_U_MAX = 16.0  # logit range of the s grid: s in [1.1e-7, 1 - 1.1e-7]
_GOLD = (math.sqrt(5.0) - 1.0) / 2.0


# ---------------------------------------------------------------------------- K functions
def k_sphere(delta_local: Tensor, radii: Tensor, r: Union[float, Tensor], s: Tensor) -> Tensor:
    """Corollary 1. delta_local [..., 3] (= R^T (x - mu)), radii [..., 3], r scalar or [...],
    s [S] or [..., S] in (0, 1)  ->  K [..., S]."""
    r = torch.as_tensor(r, dtype=delta_local.dtype, device=delta_local.device)
    r2 = (r * r)[..., None, None] if r.ndim else r * r  # [..., 1, 1] or scalar
    s = s.to(delta_local.dtype)
    sc = s[..., :, None]  # [..., S, 1]
    den = sc * r2 + (1 - sc) * (radii * radii)[..., None, :]  # [..., S, 3]
    return (sc * (1 - sc) * (delta_local * delta_local)[..., None, :] / den).sum(-1)


def k_general(mu_a: Tensor, cov_a: Tensor, mu_b: Tensor, cov_b: Tensor, s: Tensor) -> Tensor:
    """Theorem 1, direct matrix form (a linear solve per s). mu [..., 3], cov [..., 3, 3],
    s [S] or [..., S]  ->  K [..., S]."""
    d = (mu_b - mu_a)[..., None, :]  # [..., 1, 3]
    sc = s.to(mu_a.dtype)[..., :, None, None]  # [..., S, 1, 1]
    m = cov_a[..., None, :, :] / (1 - sc) + cov_b[..., None, :, :] / sc  # [..., S, 3, 3]
    d = d.expand(m.shape[:-1])  # [..., S, 3]
    y = torch.linalg.solve(m, d)
    return (d * y).sum(-1)


def k_sherman_morrison(
    mu_a: Tensor, rot_a: Tensor, radii_a: Tensor, mu_b: Tensor, rot_b: Tensor, radii_b: Tensor, s: Tensor
) -> Tensor:
    """Proposition 1: K(s) = d^T V_3(s) d with V_0 = R_a diag((1-s)/lambda_a) R_a^T and three
    Sherman-Morrison rank-1 updates adding (lambda_b,i / s) r_b,i r_b,i^T (no eigen-decomposition,
    no matrix inverse). mu [..., 3], rot [..., 3, 3] (columns = axes), radii [..., 3] (lambda = radii^2),
    s [S] or [..., S]  ->  K [..., S]."""
    sc = s.to(mu_a.dtype)[..., :, None]  # [..., S, 1]
    lam_a = (radii_a * radii_a)[..., None, :]  # [..., 1, 3]
    ra = rot_a[..., None, :, :]  # [..., 1, 3, 3]
    v = (ra * ((1 - sc) / lam_a)[..., None, :]) @ ra.transpose(-1, -2)  # [..., S, 3, 3] V_0
    lam_b = radii_b * radii_b  # [..., 3]
    for i in range(3):
        rb = rot_b[..., None, :, i]  # [..., 1, 3] i-th axis of b
        db = lam_b[..., None, i : i + 1] / sc  # [..., S, 1]
        vr = (v @ rb[..., :, None])[..., 0]  # [..., S, 3]  V r  (V symmetric)
        denom = 1 + db * (rb * vr).sum(-1, keepdim=True)  # [..., S, 1]
        v = v - (db / denom)[..., None] * vr[..., :, None] * vr[..., None, :]
    d = (mu_a - mu_b)[..., None, :]  # [..., 1, 3]
    return ((v @ d[..., :, None])[..., 0] * d).sum(-1)


# ---------------------------------------------------------------------------- maximisation
def maximize_concave(
    fn: Callable[[Tensor], Tensor],
    batch_shape: Tuple[int, ...],
    device: Union[str, torch.device] = "cpu",
    dtype: torch.dtype = torch.float64,
    n_grid: int = 17,
    n_golden: int = 24,
) -> Tuple[Tensor, Tensor]:
    """Max over s in (0,1) of a concave K given by ``fn(s[..., m]) -> K[..., m]`` (batched).

    Returns (kmax [batch], s_star [batch]); kmax = fn(s_star) is a true value (a lower bound of the
    true maximum, within float rounding of it after refinement)."""
    u = torch.linspace(-_U_MAX, _U_MAX, n_grid, device=device, dtype=dtype)
    u = u.expand(*batch_shape, n_grid).contiguous()  # [..., G]
    k = fn(torch.sigmoid(u))  # [..., G]
    k = torch.nan_to_num(k, nan=-math.inf)
    best_k, i = k.max(-1)  # [...]
    best_u = u.gather(-1, i[..., None])[..., 0]
    step = 2 * _U_MAX / (n_grid - 1)
    lo = best_u - step
    hi = best_u + step
    # golden section on [lo, hi] (unimodal in u)
    x1 = hi - _GOLD * (hi - lo)
    x2 = lo + _GOLD * (hi - lo)
    f = fn(torch.sigmoid(torch.stack([x1, x2], -1)))  # [..., 2]
    f1, f2 = f[..., 0], f[..., 1]
    for _ in range(n_golden):
        left = f1 >= f2  # max lies in [lo, x2]
        hi = torch.where(left, x2, hi)
        lo = torch.where(left, lo, x1)
        nx = torch.where(left, hi - _GOLD * (hi - lo), lo + _GOLD * (hi - lo))
        fn_x = fn(torch.sigmoid(nx[..., None]))[..., 0]
        x1, x2, f1, f2 = (
            torch.where(left, nx, x2),
            torch.where(left, x1, nx),
            torch.where(left, fn_x, f2),
            torch.where(left, f1, fn_x),
        )
        for xx, ff in ((x1, f1), (x2, f2)):
            better = ff > best_k
            best_k = torch.where(better, ff, best_k)
            best_u = torch.where(better, xx, best_u)
    return best_k, torch.sigmoid(best_u)


def max_k_sphere(
    delta_local: Tensor, radii: Tensor, r: Union[float, Tensor], n_grid: int = 17, n_golden: int = 24
) -> Tuple[Tensor, Tensor]:
    """max_s K(s) of Corollary 1 for a ball of radius r (scalar or [...]) vs ellipsoids.
    delta_local [..., 3], radii [..., 3]  ->  (kmax [...], s_star [...])."""
    delta_local, radii = delta_local.double(), radii.double()
    r = torch.as_tensor(r, dtype=torch.float64, device=delta_local.device)
    return maximize_concave(
        lambda s: k_sphere(delta_local, radii, r, s), delta_local.shape[:-1], delta_local.device, torch.float64,
        n_grid, n_golden,
    )


def max_k_sherman_morrison(
    mu_a: Tensor, rot_a: Tensor, radii_a: Tensor, mu_b: Tensor, rot_b: Tensor, radii_b: Tensor,
    n_grid: int = 17, n_golden: int = 24,
) -> Tuple[Tensor, Tensor]:
    """max_s K(s) of Proposition 1 (general ellipsoidal camera body). Batched [...]."""
    args = [t.double() for t in (mu_a, rot_a, radii_a, mu_b, rot_b, radii_b)]
    return maximize_concave(
        lambda s: k_sherman_morrison(*args, s), args[0].shape[:-1], args[0].device, torch.float64, n_grid, n_golden
    )


def ellipsoids_collide(
    mu_a: Tensor, rot_a: Tensor, radii_a: Tensor, mu_b: Tensor, rot_b: Tensor, radii_b: Tensor,
    margin: float = DEFAULT_MARGIN,
) -> Tensor:
    """Conservative ellipsoid-ellipsoid test (Prop. 1): True unless a true K(s) > 1 + margin. [...] bool."""
    kmax, _ = max_k_sherman_morrison(mu_a, rot_a, radii_a, mu_b, rot_b, radii_b)
    return ~(kmax > 1 + margin)


# ---------------------------------------------------------------------------- scene queries
def _as_points(points: Tensor, device) -> Tensor:
    points = torch.as_tensor(points, device=device)
    if points.ndim != 2 or points.shape[-1] != 3:
        raise InvalidInputError(f"points must be [P, 3], got {tuple(points.shape)}")
    if not bool(torch.isfinite(points).all()):
        raise InvalidInputError("points contain NaN or inf")
    return points.double()


def candidate_pairs(points: Tensor, scene: EllipsoidScene, index, radius: Tensor) -> Tuple[Tensor, Tensor]:
    """(pt_idx [K], g_idx [K]) containing every ellipsoid within Euclidean distance radius[p] of
    point p (points [P, 3] float64, radius [P]). Through the index when given, else brute force."""
    if index is not None:
        return index.query_points(points, (radius - index.pad).clamp_min(0))
    # brute force (tests, tiny scenes): exact AABB test, chunked over points
    h = scene.half_extents().double()
    mu = scene.means.double()
    out_p, out_g = [], []
    chunk = max(1, 4_000_000 // max(1, len(scene)))
    for i in range(0, points.shape[0], chunk):
        p = points[i : i + chunk]
        reach = h[None] * (1 + 1e-9) + radius[i : i + chunk, None, None] + 1e-12
        m = ((p[:, None, :] - mu[None]).abs() <= reach).all(-1)
        pi, gi = torch.nonzero(m, as_tuple=True)
        out_p.append(pi + i)
        out_g.append(gi)
    if not out_p:  # no points: no pairs
        return (torch.zeros(0, dtype=torch.long, device=points.device),) * 2
    return torch.cat(out_p), torch.cat(out_g)


def _pair_locals(points: Tensor, scene: EllipsoidScene, pi: Tensor, gi: Tensor) -> Tuple[Tensor, Tensor]:
    """w = R^T (x - mu) [K, 3] and radii [K, 3] in float64 (gather first: no O(N) conversion)."""
    rot = scene.rotations.index_select(0, gi).double()  # [K, 3, 3]
    mu = scene.means.index_select(0, gi).double()
    w = ((points.index_select(0, pi) - mu)[:, :, None] * rot).sum(-2)  # [K, 3] = R^T d
    return w, scene.radii.index_select(0, gi).double()


def pairs_free(w: Tensor, radii: Tensor, r: Tensor, margin: float = DEFAULT_MARGIN) -> Tensor:
    """Ball (radius r [K]) vs ellipsoid pairs proven disjoint [K] bool (conservative).

    Fast path: one evaluation at the s that is optimal for the support direction of w
    (s = h/(h+r), h = |a * n|, n = w/|w|); only undecided pairs get the full maximisation."""
    n = w / w.norm(dim=-1, keepdim=True).clamp_min(1e-300)
    h = (radii * n).norm(dim=-1)
    s0 = (h / (h + r)).clamp(1e-12, 1 - 1e-12)
    r2 = r * r
    k0 = (s0 * (1 - s0))[:, None] * w * w / (s0[:, None] * r2[:, None] + (1 - s0)[:, None] * radii * radii)
    free = k0.sum(-1) > 1 + margin
    und = torch.nonzero(~free).squeeze(-1)
    if und.numel():
        kmax, _ = max_k_sphere(w[und], radii[und], r[und])
        free[und] = kmax > 1 + margin
    return free


def _native_points_collide(fn, scene: EllipsoidScene, index, pts: Tensor, rad: Tensor, margin: float) -> Tensor:
    """points_collide through native/polytope.c (float64 CPU points [P, 3], radii [P])."""
    import numpy as np

    from .native_scene import native_arrays

    p = np.ascontiguousarray(pts.cpu().numpy(), dtype=np.float64)
    rr = np.ascontiguousarray(rad.cpu().numpy(), dtype=np.float64)
    hit = np.zeros(p.shape[0], dtype=np.uint8)
    fn(*native_arrays(scene, index)["args"], p.ctypes.data, rr.ctypes.data, p.shape[0], float(margin), hit.ctypes.data)
    return torch.from_numpy(hit.astype(bool)).to(pts.device)


def points_collide(
    points: Tensor,  # [P, 3]
    scene: EllipsoidScene,
    index=None,
    radius: Union[float, Tensor, None] = None,
    margin: float = DEFAULT_MARGIN,
    backend: str = "auto",
) -> Tensor:
    """bool [P]: True unless the camera ball (radius ``scene.camera_radius`` or ``radius``, scalar or
    [P]) at the point is proven clear of every ellipsoid. Conservative (never False when touching).

    backend: "auto" (the compiled test, native/polytope.c's cn_points_collide, for a CPU scene with a GridIndex
    on the CPU when it loads; the same pair rule below, one point at a time, stopping at its first collision),
    "native" (error if it does not apply) or "python"."""
    from ..native import choose, points_collide_c
    from .native_scene import native_applies

    fn = choose(backend, points_collide_c, "polytope", "point test", applies=native_applies(scene, index),
                needs="a CPU scene and a GridIndex on the CPU")
    pts = _as_points(points, scene.device)
    P = pts.shape[0]
    rad = torch.as_tensor(scene.camera_radius if radius is None else radius, device=pts.device).double()
    rad = rad.expand(P) if rad.ndim == 0 else rad
    if rad.shape != (P,):
        raise InvalidInputError(f"radius must be a scalar or [P]={P}, got {tuple(rad.shape)}")
    if fn is not None:
        return _native_points_collide(fn, scene, index, pts, rad, margin)
    pi, gi = candidate_pairs(pts, scene, index, rad)
    hit = torch.zeros(P, dtype=torch.bool, device=pts.device)
    if pi.numel():
        w, radii = _pair_locals(pts, scene, pi, gi)
        rr = rad.index_select(0, pi)
        # Sure collisions first (cheap): the radial surface point mu + (x - mu)/m (m = Mahalanobis norm)
        # is within r, or x is inside. Points with one sure collision need no K maximisation.
        m = (w / radii).norm(dim=-1)
        sure = (m <= 1) | (w.norm(dim=-1) * (1 - 1 / m.clamp_min(1e-300)) <= rr)
        hit[pi[sure]] = True
        rest = torch.nonzero(~sure & ~hit.index_select(0, pi)).squeeze(-1)
        if rest.numel():
            coll = ~pairs_free(w[rest], radii[rest], rr[rest], margin)
            hit[pi[rest][coll]] = True
    return hit


def points_collide_arrays(points, scene: EllipsoidScene, index, radius, margin: float = DEFAULT_MARGIN):
    """points_collide (backend "auto") for numpy points [P, 3] and radii (scalar or [P]), answered as numpy bool [P].
    When the compiled test applies it reads the float64 arrays directly: no torch round trip for callers that ask a
    few hundred points at a time (the shortcut's Corollary-1 pieces, ~9 calls a request at ~20 us of compiled work
    each: the checks and conversions here are kept to a few numpy calls). Same answers as points_collide."""
    import numpy as np

    fn = native_points_collide_c() if native_applies(scene, index) else None
    if fn is None:
        rad = torch.as_tensor(radius, device=scene.device)
        return points_collide(torch.as_tensor(points, device=scene.device), scene, index, radius=rad,
                              margin=margin).cpu().numpy()
    p = np.ascontiguousarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[-1] != 3:
        raise InvalidInputError(f"points must be [P, 3], got {tuple(p.shape)}")
    P = p.shape[0]
    if not np.isfinite(p).all():
        raise InvalidInputError("points contain NaN or inf")
    r = np.asarray(radius, dtype=np.float64)
    if r.ndim:
        if r.shape != (P,):
            raise InvalidInputError(f"radius must be a scalar or [P]={P}, got {tuple(r.shape)}")
        rr = np.ascontiguousarray(r)  # [P]
    else:
        rr = np.full(P, float(r))  # [P]
    hit = np.zeros(P, dtype=np.uint8)
    fn(*native_arrays(scene, index)["args"], p.ctypes.data, rr.ctypes.data, P, float(margin), hit.ctypes.data)
    return hit.view(bool)


def k_segment_sphere(w0: Tensor, dw: Tensor, radii: Tensor, r: Tensor, s: Tensor) -> Tensor:
    """min over t in [0, 1] of Corollary 1's K(s) at the point w0 + t dw (ellipsoid frame).

    For fixed s, K(s) at x is the quadratic form x^T D_s x with D_s = diag(s(1-s)/(s r^2 + (1-s) a_i^2)),
    so along the segment it is A t^2 + 2 B t + C, minimised in closed form. As a minimum of concave
    functions of s it is concave in s. w0, dw, radii [..., 3], r [...], s [..., S] -> [..., S]."""
    sc = s[..., :, None]  # [..., S, 1]
    d = sc * (1 - sc) / (sc * (r * r)[..., None, None] + (1 - sc) * (radii * radii)[..., None, :])  # [..., S, 3]
    w0e, dwe = w0[..., None, :], dw[..., None, :]
    A = (d * dwe * dwe).sum(-1)
    B = (d * w0e * dwe).sum(-1)
    C = (d * w0e * w0e).sum(-1)
    t = torch.where(A > 0, -B / A.clamp_min(1e-300), torch.zeros_like(A)).clamp(0, 1)
    return A * t * t + 2 * B * t + C


def segments_collide(
    p0: Tensor,  # [P, 3]
    p1: Tensor,  # [P, 3]
    scene: EllipsoidScene,
    index=None,
    radius: Optional[float] = None,
    margin: float = DEFAULT_MARGIN,
) -> Tensor:
    """bool [P]: True unless the ball swept along segment p0 -> p1 (a capsule) is proven clear of every
    ellipsoid (conservative).

    Test per (segment, ellipsoid) pair: f(s) = min_t K_t(s) over the segment's points. f(s) > 1 means the
    whole segment lies outside the ellipsoid E_s ⊇ E + B(r), a proof that the capsule is clear. f is
    concave in s (min of concave functions) and K_t(s) is convex in t, so by Sion's minimax theorem
    max_s min_t K = min_t max_s K: the test is exact up to the sampling of s (no subdivision needed)."""
    a = _as_points(p0, scene.device)
    b = _as_points(p1, scene.device)
    if a.shape != b.shape:
        raise InvalidInputError(f"segment ends disagree: {tuple(a.shape)} vs {tuple(b.shape)}")
    r = float(scene.camera_radius if radius is None else radius)
    P = a.shape[0]
    hit = torch.zeros(P, dtype=torch.bool, device=a.device)
    if P == 0:
        return hit
    # candidates: ellipsoids whose AABB grown by r meets the segment's AABB
    lo, hi = torch.minimum(a, b), torch.maximum(a, b)
    if index is not None:
        grow = max(r - index.pad, 0.0)
        pi, gi = index.query_boxes(lo - grow, hi + grow)
    else:
        h = scene.half_extents().double() * (1 + 1e-9) + r + 1e-12
        mu = scene.means.double()
        m = ((mu[None] - h[None] <= hi[:, None]) & (mu[None] + h[None] >= lo[:, None])).all(-1)
        pi, gi = torch.nonzero(m, as_tuple=True)
    if pi.numel() == 0:
        return hit
    rot = scene.rotations.index_select(0, gi).double()
    mu = scene.means.index_select(0, gi).double()
    radii = scene.radii.index_select(0, gi).double()
    w0 = ((a.index_select(0, pi) - mu)[:, :, None] * rot).sum(-2)  # [K, 3]
    dw = ((b - a).index_select(0, pi)[:, :, None] * rot).sum(-2)
    rr = torch.full((pi.numel(),), r, dtype=torch.float64, device=a.device)
    # fast path: s optimal for the support direction at the segment point closest in Mahalanobis sense
    A = ((dw / radii) ** 2).sum(-1)
    t = torch.where(A > 0, -((w0 * dw) / radii**2).sum(-1) / A.clamp_min(1e-300), torch.zeros_like(A)).clamp(0, 1)
    wc = w0 + t[:, None] * dw
    hdir = (radii * wc / wc.norm(dim=-1, keepdim=True).clamp_min(1e-300)).norm(dim=-1)
    s0 = (hdir / (hdir + r)).clamp(1e-12, 1 - 1e-12)
    free = k_segment_sphere(w0, dw, radii, rr, s0[:, None])[:, 0] > 1 + margin
    und = torch.nonzero(~free).squeeze(-1)
    if und.numel():
        w0u, dwu, ru, rru = w0[und], dw[und], radii[und], rr[und]
        kmax, _ = maximize_concave(
            lambda s: k_segment_sphere(w0u, dwu, ru, rru, s), (und.numel(),), a.device, torch.float64
        )
        free[und] = kmax > 1 + margin
    hit[pi[~free]] = True
    return hit
