"""Float64 exact references used by the corridor/polytope/goal tests (independent of the package code).

point_ellipsoid_distance: Euclidean distance from points to ellipsoid surfaces, negative inside, by
bracketed root finding (vectorised bisection; scipy brentq for a cross-check) on the closest-point
Lagrange condition in the body frame:
the closest point is y = (I + t L^-1)^-1 w with sum_i lam_i w_i^2 / (lam_i + t)^2 = 1 (lam = a^2),
t > 0 outside. Inside points get the Mahalanobis-based sign only (the tests need "inside" and the
exact distance outside).
"""
from __future__ import annotations

import numpy as np
import torch
from scipy.optimize import brentq


def random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    R = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    ).reshape(n, 3, 3)
    return R


def make_scene(means, rotations, radii, camera_radius):
    from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene

    means = torch.as_tensor(np.asarray(means), dtype=torch.float64)
    return EllipsoidScene(
        means=means,
        rotations=torch.as_tensor(np.asarray(rotations), dtype=torch.float64),
        radii=torch.as_tensor(np.asarray(radii), dtype=torch.float64),
        opacities=torch.ones(means.shape[0], dtype=torch.float64),
        camera_radius=float(camera_radius),
    )


def random_scene(rng: np.random.Generator, n: int, lo=-1.0, hi=1.0, amin=0.02, amax=0.4, camera_radius=0.05):
    means = rng.uniform(lo, hi, size=(n, 3))
    radii = rng.uniform(amin, amax, size=(n, 3))
    return make_scene(means, random_rotations(rng, n), radii, camera_radius)


def _dist_one(w: np.ndarray, a: np.ndarray) -> float:
    """Distance from body-frame point w to the axis-aligned ellipsoid with semi-axes a (>= 0 outside)."""
    lam = a * a
    m2 = float(np.sum(w * w / lam))
    if m2 <= 1.0:
        return -1.0  # inside (sign only)
    f = lambda t: float(np.sum(lam * w * w / (lam + t) ** 2)) - 1.0  # noqa: E731
    hi = 1.0
    while f(hi) > 0:
        hi *= 2.0
    t = brentq(f, 0.0, hi, xtol=1e-15, rtol=1e-15, maxiter=500)
    y = lam * w / (lam + t)
    return float(np.linalg.norm(w - y))


def point_ellipsoid_distance_brentq(points, scene) -> np.ndarray:
    """[P, N] exact distance, one scalar brentq per pair (slow; cross-checks the vectorised one)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    mu = scene.means.double().numpy()
    R = scene.rotations.double().numpy()
    a = scene.radii.double().numpy()
    out = np.empty((pts.shape[0], mu.shape[0]))
    for j in range(mu.shape[0]):
        wb = (pts - mu[j]) @ R[j]  # R^T (x - mu) for each point  [P, 3]
        for i in range(pts.shape[0]):
            out[i, j] = _dist_one(wb[i], a[j])
    return out


def _body_frame(points, scene):
    """(w [P, N, 3] body-frame points, lam [1, N, 3] squared semi-axes, a [N, 3] semi-axes, inside [P, N])."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    mu = scene.means.double().numpy()
    R = scene.rotations.double().numpy()
    a = scene.radii.double().numpy()
    lam = (a * a)[None]  # [1, N, 3]
    w = np.einsum("nji,pnj->pni", R, pts[:, None, :] - mu[None])  # body frame [P, N, 3]
    return w, lam, a, (w * w / lam).sum(-1) <= 1.0


def _bisect_pairs(w, lam, a, pi, ni) -> np.ndarray:
    """Exact distance [K] of the K outside pairs (pi, ni) of _body_frame's w: see point_ellipsoid_distance. Each pair's
    result depends on that pair alone (elementwise halvings until its fixed point or 200)."""
    wo = w[pi, ni]  # [K, 3]
    lam_o = np.broadcast_to(lam, w.shape)[pi, ni]  # [K, 3]
    c = lam_o * wo * wo
    l0, l1, l2 = (np.ascontiguousarray(lam_o[:, k]) for k in range(3))
    c0, c1, c2 = (np.ascontiguousarray(c[:, k]) for k in range(3))
    lo_all = np.zeros(pi.size)
    hi_all = a[ni].max(-1) * np.linalg.norm(wo, axis=-1) + 1e-300
    act = np.arange(pi.size)  # pairs whose bracket still moves
    lo, hi = lo_all.copy(), hi_all.copy()
    for _ in range(200):
        if act.size == 0:
            break
        mid = 0.5 * (lo + hi)
        pos = c0 / (l0 + mid) ** 2 + c1 / (l1 + mid) ** 2 + c2 / (l2 + mid) ** 2 > 1.0
        nlo = np.where(pos, mid, lo)
        nhi = np.where(pos, hi, mid)
        moved = (nlo != lo) | (nhi != hi)
        lo, hi = nlo, nhi
        if not moved.all():  # fixed points: store and drop them
            lo_all[act[~moved]] = lo[~moved]
            hi_all[act[~moved]] = hi[~moved]
            act, lo, hi = act[moved], lo[moved], hi[moved]
            l0, l1, l2, c0, c1, c2 = l0[moved], l1[moved], l2[moved], c0[moved], c1[moved], c2[moved]
    lo_all[act] = lo
    hi_all[act] = hi
    t = 0.5 * (lo_all + hi_all)
    return np.linalg.norm(wo - lam_o * wo / (lam_o + t[:, None]), axis=-1)


def point_ellipsoid_distance(points, scene) -> np.ndarray:
    """[P, N] exact Euclidean distance (float64) from each point to each ellipsoid; -1 inside.

    Vectorised bisection on f(t) = sum_i lam_i w_i^2 / (lam_i + t)^2 - 1 over [0, a_max |w|]
    (f(0) > 0 outside, f(a_max |w|) <= 0), up to 200 halvings: the bracket shrinks below float64
    resolution, so the root is exact to rounding (no Newton: independent of the package's solver).
    Only the pairs outside are bisected, and a pair leaves the loop once a halving leaves its bracket unchanged: the
    halving is a fixed map of (lo, hi), so every later one would too (bit-for-bit the result of 200 full halvings)."""
    w, lam, a, inside = _body_frame(points, scene)
    pi, ni = np.nonzero(~inside)  # the K pairs outside
    out = np.full(w.shape[:2], -1.0)
    out[pi, ni] = _bisect_pairs(w, lam, a, pi, ni)
    return out


def min_distance(points, scene) -> np.ndarray:
    """[P] point_ellipsoid_distance(points, scene).min(1), bit for bit (test_polytope.py checks), bisecting only the
    pairs that can hold the minimum: E_j lies in the ball of radius max(a_j) about mu_j and E_k holds the ball of
    radius min(a_k), so an outside pair j with |p - mu_j| - max(a_j) > U + 1e-9 (U: the smallest of -1 over the pairs
    inside and |p - mu_k| - min(a_k) over those outside; 1e-9: far above rounding) is farther than the minimum."""
    w, lam, a, inside = _body_frame(points, scene)
    dc = np.linalg.norm(w, axis=-1)  # the bounds hold in the body frame, where the distance is measured
    u = np.where(inside, -1.0, dc - a.min(-1)[None]).min(1)  # [P] >= the minimum
    pi, ni = np.nonzero(~inside & (dc - a.max(-1)[None] <= u[:, None] + 1e-9))
    d = _bisect_pairs(w, lam, a, pi, ni)
    out = np.full(w.shape[0], np.inf)
    np.minimum.at(out, pi, d)
    return np.where(inside.any(1), -1.0, out)


def clearance(points, scene) -> np.ndarray:
    """[P] min_j dist(point, E_j) - camera_radius (exact, float64)."""
    return min_distance(points, scene) - scene.camera_radius


def polytope_min_distance(A, b, scene) -> np.ndarray:
    """[N] exact min over x in {A x <= b} of dist(x, E_j), via one SOCP per ellipsoid (cvxpy + Clarabel).
    Independent reference for "the whole polytope keeps the camera ball outside every ellipsoid"."""
    import cvxpy as cp

    mu = scene.means.double().numpy()
    R = scene.rotations.double().numpy()
    a = scene.radii.double().numpy()
    out = np.empty(mu.shape[0])
    x = cp.Variable(3)
    y = cp.Variable(3)
    Mmu = cp.Parameter(3)  # M mu (keeps the problem DPP)
    M = cp.Parameter((3, 3))  # diag(1/a) R^T
    prob = cp.Problem(cp.Minimize(cp.norm(x - y)), [A @ x <= b, cp.norm(M @ y - Mmu) <= 1])
    for j in range(mu.shape[0]):
        M.value = (R[j] / a[j][None, :]).T
        Mmu.value = M.value @ mu[j]
        prob.solve(solver=cp.CLARABEL)
        out[j] = prob.value
    return out
