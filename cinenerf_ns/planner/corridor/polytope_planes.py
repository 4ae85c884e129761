"""The safe plane of one ellipsoid (paper Prop. 2; the math is in polytope.py's module docstring): the normal rules
(Prop. 2's Q(s*) Delta, the closest-point and the Mahalanobis normal) at a reference point of the seeds, their exact
offsets n.mu - ||diag(a) R^T n|| - r - margin, and the exact support test that decides whether an inflated ellipsoid
lies entirely beyond a plane.

The kernels run in float64 numpy on the host: they are applied to small chunks (tens of ellipsoids) inside a
sequential loop, where numpy's per-call cost beats torch's. polytope_batched.py ports them to torch.
"""
from __future__ import annotations

import math

import numpy as np


def k_sphere(w2: np.ndarray, lam: np.ndarray, kappa: float, s: np.ndarray) -> np.ndarray:
    """Corollary 1: K(s) = sum_i w_i^2 s(1-s) / (kappa + s (lambda_i - kappa)).
    w2, lam [K, 3]; s [K, T] in (0, 1) -> [K, T]."""
    s3 = s[..., None]  # [K, T, 1]
    return (w2[:, None, :] * s3 * (1 - s3) / (kappa + s3 * (lam[:, None, :] - kappa))).sum(-1)


def argmax_k(w2: np.ndarray, lam: np.ndarray, kappa: float, n_samples: int = 64, iters: int = 6) -> np.ndarray:
    """s* = argmax_{s in (0,1)} K(s) per row [K]: K is concave in s, so a coarse grid then golden
    section inside the best bracket converges to the maximiser (~1e-3 in s; only the normal uses it, never the
    offset)."""
    k = w2.shape[0]
    grid = np.linspace(0.0, 1.0, n_samples + 2)[1:-1]  # [T]
    vals = k_sphere(w2, lam, kappa, np.broadcast_to(grid, (k, n_samples)))  # [K, T]
    best = vals.argmax(-1)  # [K]
    step = grid[1] - grid[0]
    lo = np.maximum(grid[best] - step, 1e-9)
    hi = np.minimum(grid[best] + step, 1 - 1e-9)
    g = (math.sqrt(5) - 1) / 2
    for _ in range(iters):
        m1 = hi - g * (hi - lo)
        m2 = lo + g * (hi - lo)
        k12 = k_sphere(w2, lam, kappa, np.stack([m1, m2], -1))  # [K, 2]
        left = k12[:, 0] > k12[:, 1]
        hi = np.where(left, m2, hi)
        lo = np.where(left, lo, m1)
    return 0.5 * (lo + hi)


def closest_t(w2: np.ndarray, lam: np.ndarray, iters: int = 10) -> np.ndarray:
    """t >= 0 with sum_i lambda_i w_i^2 / (lambda_i + t)^2 = 1: the closest point of the ellipsoid to an
    outside body-frame point w is y = lambda w / (lambda + t), its outer normal ∝ w / (lambda + t).

    Newton on phi(t) = (sum_i c_i / (lambda_i + t)^2)^(-1/2) = 1 (c = lambda w^2): phi is a power mean
    with exponent -2 of the affine lambda_i + t, hence concave and increasing, so Newton started left
    of the root (phi(0) = 1/m < 1) stays left and converges monotonically; phi is nearly linear
    (exactly linear for one axis), so ~8 steps reach 1e-12 relative accuracy. t never exceeds the
    root, which callers rely on for lower bounds. Rows with the point inside get t = 0."""
    c = lam * w2  # [K, 3]
    # start from a lower bound of the root: f(t) >= lambda_min |w|^2 / (lambda_max + t)^2
    t = np.maximum(np.sqrt(lam.min(-1) * w2.sum(-1)) - lam.max(-1), 0.0)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # w = 0 rows: no step taken
        t = _closest_t_steps(c, lam, t, iters)
    return t


def _closest_t_steps(c: np.ndarray, lam: np.ndarray, t: np.ndarray, iters: int) -> np.ndarray:
    for _ in range(iters):
        den = lam + t[:, None]
        q = c / den**2
        S = q.sum(-1)
        phi = 1.0 / np.sqrt(np.maximum(S, 1e-300))
        dphi = phi**3 * (q / den).sum(-1)
        t = t + np.where(phi < 1.0, (1.0 - phi) / np.maximum(dphi, 1e-300), 0.0)
    return t


def plane_candidates(seeds: np.ndarray, mu: np.ndarray, rot: np.ndarray, axes: np.ndarray, r: float,
                      normal: str, margin: float):
    """Per ellipsoid, the best-slack safe plane among the normal rules -> (n [C,3], b [C], slack [C]).
    slack = b - max_s n.seed_s (>= 0: every seed inside)."""
    lam = axes**2  # [C, 3]
    wb = np.einsum("cji,csj->csi", rot, seeds[None, :, :] - mu[:, None, :])  # body coords [C, S, 3]
    if seeds.shape[0] == 2:
        # reference point: the segment point closest to mu in the ellipsoid metric (a 1-D quadratic)
        d = wb[:, 1] - wb[:, 0]  # [C, 3]
        den = (d**2 / lam).sum(-1)
        u = np.clip(-(wb[:, 0] * d / lam).sum(-1) / np.maximum(den, 1e-300), 0.0, 1.0)
        u = np.where(den > 0, u, 0.0)
        w = wb[:, 0] + u[:, None] * d  # [C, 3]
    else:
        w = wb[np.arange(len(mu)), (wb**2 / lam[:, None, :]).sum(-1).argmin(-1)]  # [C, 3]
    n, off, slack = _planes_at(w, seeds, mu, rot, axes, lam, r, normal, margin)
    if seeds.shape[0] == 2 and (slack < 0).any():
        # A segment that grazes a flat ellipsoid can be free while the planes at the metric-closest
        # point cut it; retry those ellipsoids from other segment points (the Euclidean-closest point
        # to the centre and the ends) and keep the best slack. Any normal gives a safe plane.
        bad = np.flatnonzero(slack < 0)
        db = d[bad]
        ue = np.clip(-(wb[bad, 0] * db).sum(-1) / np.maximum((db**2).sum(-1), 1e-300), 0.0, 1.0)
        uc = _segment_closest_u(wb[bad, 0], db, lam[bad])
        for uu in (uc, ue, np.zeros(len(bad)), np.ones(len(bad))):
            n2, o2, s2 = _planes_at(wb[bad, 0] + uu[:, None] * db, seeds, mu[bad], rot[bad], axes[bad], lam[bad], r,
                                    normal, margin)
            better = s2 > slack[bad]
            n[bad[better]], off[bad[better]], slack[bad[better]] = n2[better], o2[better], s2[better]
    return n, off, slack


def _segment_closest_u(w0: np.ndarray, dw: np.ndarray, lam: np.ndarray, iters: int = 30) -> np.ndarray:
    """u in [0, 1] [C] (approximately) minimising the Euclidean distance from w0 + u dw [C, 3] to the
    axis-aligned ellipsoids with squared semi-axes lam [C, 3] (golden section: the distance to a convex
    set is convex along a segment). Only a reference point for choosing normals: no safety relies on it."""

    def dist(u):
        w = w0 + u[:, None] * dw
        t = closest_t(w * w, lam)
        return np.linalg.norm(t[:, None] * w / (lam + t[:, None]), axis=-1)

    g = (math.sqrt(5.0) - 1.0) / 2.0
    lo, hi = np.zeros(len(w0)), np.ones(len(w0))
    x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
    f1, f2 = dist(x1), dist(x2)
    for _ in range(iters):
        left = f1 <= f2  # minimum in [lo, x2]
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        nx = np.where(left, hi - g * (hi - lo), lo + g * (hi - lo))
        fn = dist(nx)
        x1, x2 = np.where(left, nx, x2), np.where(left, x1, nx)
        f1, f2 = np.where(left, fn, f2), np.where(left, f1, fn)
    return 0.5 * (lo + hi)


def body_normals(w, w2, lam, r: float, normal: str, argmax_k, closest_t) -> list:
    """The body-frame normals [C, 3] of the rules ``normal`` names ("auto": all three, in this order), pointing from
    reference points w [C, 3] (w2 = w * w) toward ellipsoids with squared semi-axes lam [C, 3]: Prop. 2's
    Q(s*) w, the Mahalanobis normal w / lam and the closest-point normal w / (lam + t). numpy or torch arrays alike,
    with argmax_k and closest_t of the same kind (this module's, or polytope_batched's torch ports)."""
    cands = []
    if normal in ("auto", "prop2"):
        s = argmax_k(w2, lam, r * r)[:, None]  # [C, 1]
        cands.append(-(s * (1 - s) / (r * r + s * (lam - r * r))) * w)
    if normal in ("auto", "mahalanobis"):
        cands.append(-w / lam)
    if normal in ("auto", "closest"):
        cands.append(-w / (lam + closest_t(w2, lam)[:, None]))
    return cands


def _planes_at(w: np.ndarray, seeds: np.ndarray, mu: np.ndarray, rot: np.ndarray, axes: np.ndarray,
               lam: np.ndarray, r: float, normal: str, margin: float):
    """Best-slack safe plane per ellipsoid among the normal rules evaluated at body-frame reference
    points w [C, 3] -> (n [C, 3], b [C], slack [C])."""
    degenerate = (w**2).sum(-1) < 1e-24  # reference point at the centre: any direction is valid
    w = np.where(degenerate[:, None], np.array([0.0, 0.0, 1e-12]), w)
    nb = np.stack(body_normals(w, w**2, lam, r, normal, argmax_k, closest_t))  # [R, C, 3]
    nb = nb / np.maximum(np.linalg.norm(nb, axis=-1, keepdims=True), 1e-300)
    nw = np.einsum("cij,rcj->rci", rot, nb)  # world normals R nb  [R, C, 3]
    # exact offset: n.mu - ||diag(a) R^T n|| - r (module docstring); R^T n = nb
    offs = (nw * mu).sum(-1) - np.linalg.norm(axes * nb, axis=-1) - r - margin  # [R, C]
    slack = offs - np.einsum("rci,si->rcs", nw, seeds).max(-1)  # [R, C]
    best = slack.argmax(0)
    ar = np.arange(len(mu))
    return nw[best, ar], offs[best, ar], slack[best, ar]


def segment_frame_np(p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """Orthonormal [3, 3] whose first column is the direction p0 -> p1 (p0 != p1)."""
    u = (p1 - p0) / np.linalg.norm(p1 - p0)
    helper = np.zeros(3)
    helper[int(np.argmin(np.abs(u)))] = 1.0
    v = np.cross(u, helper)
    v /= np.linalg.norm(v)
    return np.stack([u, v, np.cross(u, v)], axis=1)


def support_gap(n: np.ndarray, mu: np.ndarray, rot: np.ndarray, axes: np.ndarray, r: float) -> np.ndarray:
    """min over E_c (+) B_r of n_f.x for planes n [F,3] and ellipsoids [C] -> [C, F]."""
    nb = np.einsum("cji,fj->cfi", rot, n)  # R_c^T n_f  [C, F, 3]
    return mu @ n.T - np.linalg.norm(axes[:, None, :] * nb, axis=-1) - r


def cut_by(n: np.ndarray, b: np.ndarray, mu: np.ndarray, amax: np.ndarray, rot: np.ndarray, axes: np.ndarray,
            r: float, block: int = 65536) -> np.ndarray:
    """bool [C]: ellipsoid c's inflated body lies entirely beyond one of the planes n [F, 3], b [F]
    (exact support test; the bounding-sphere test, which implies it, decides most rows cheaply)."""
    cut = ((mu @ n.T - amax[:, None] - r) >= b).any(1)  # [C] sound: sphere beyond => body beyond
    todo = np.flatnonzero(~cut)
    for s in range(0, todo.size, block):
        j = todo[s:s + block]
        cut[j] = (support_gap(n, mu[j], rot[j], axes[j], r) >= b).any(1)
    return cut
