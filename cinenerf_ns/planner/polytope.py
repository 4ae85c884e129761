"""Safe polytopes in the free space of an ellipsoid scene (paper Prop. 2, after Splat-Nav Prop. 2).

A safe polytope P = {x : A x <= b} is a convex set of camera *centres* such that a camera ball of
radius r centred anywhere in P touches no ellipsoid. It is the intersection of a local axis-aligned
box with one halfspace per nearby ellipsoid.

Offsets (why safety does not depend on how the normal was chosen)
-----------------------------------------------------------------
Ellipsoid E_j = {mu + R diag(a) u : |u| <= 1} (a = semi-axes). A camera centred at x touches E_j iff
x is in the Minkowski sum E_j (+) B_r. For any unit vector n the support function of E_j is

    h_E(n) = max_{y in E_j} n.y = n.mu + max_{|u|<=1} (diag(a) R^T n).u = n.mu + ||diag(a) R^T n||

(= n.mu + ||Sigma^{1/2} n||), so every y in E_j satisfies n.y >= n.mu - ||Sigma^{1/2} n|| (apply h_E
to -n). Take the halfspace H = {x : n.x <= n.mu - ||Sigma^{1/2} n|| - r}. For x in H and y in E_j,
n.(y - x) >= r, and since |n| = 1, ||y - x|| >= n.(y - x) >= r (Cauchy-Schwarz). So every centre in H
keeps the ball outside E_j, for EVERY unit n: H is the tangent halfspace of E_j (+) B_r with outer
normal n, whose boundary supports the inflated ellipsoid. The normal only decides how much free
space H keeps, never whether H is safe. We subtract a small extra ``margin`` for rounding.

Normals (which free space we keep)
----------------------------------
Prop. 2 picks n ∝ Q_j (mu_j - x*) with Q_j = R diag(s*(1-s*) / (kappa + s*(lambda_i - kappa))) R^T,
kappa = r^2, lambda_i = a_i^2 and s* = argmax_s K(s) (Corollary 1's K for a sphere camera). Note
Q(s) ∝ (s Sigma + (1-s) kappa I)^{-1}, so these normals are the family (Sigma + t I)^{-1} Delta that
also contains the exact closest-point normal (t solves sum lambda_i w_i^2/(lambda_i+t)^2 = 1) and
the Mahalanobis normal Sigma^{-1} Delta (t = 0). With ``normal="auto"`` we compute all three at the
seed's reference point and keep, per ellipsoid, the one leaving the seeds the most slack. For a
segment seed the reference point is the segment point closest to mu in the ellipsoid metric; there
the Mahalanobis plane contains the whole segment whenever its reference point is inside (the
segment is tangent to the Mahalanobis level set there), which makes segment seeds robust.

Redundancy removal
------------------
Ellipsoids are processed nearest plane first. After adding plane (n, b), every remaining ellipsoid
whose inflated body lies entirely beyond it (min over E (+) B_r of n.x = n.mu - ||Sigma^{1/2} n|| - r
>= b) is dropped: the polytope already excludes it. Dropping changes nothing about safety, because
the polytope is still contained in that plane's halfspace, which excludes the dropped body.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional, Sequence, Union

import numpy as np
import torch
from torch import Tensor

from .errors import InvalidInputError, PlanningError

ArrayLike = Union[Tensor, np.ndarray, Sequence[float]]


class SeedNotFreeError(PlanningError):
    """A seed point (or a seed segment) of a safe polytope is too close to an ellipsoid: no plane of
    that ellipsoid's family separates it. The corridor splits the segment when this happens."""

    def __init__(self, message: str, ellipsoid_ids: Optional[Tensor] = None, min_slack: float = float("nan")):
        super().__init__(message)
        self.ellipsoid_ids = ellipsoid_ids  # [J] scene ids of the ellipsoids that cut the seed
        self.min_slack = min_slack  # most negative (plane offset - seed projection), scene units


@dataclass
class Polytope:
    """Convex polytope {x : A x <= b} with unit-norm rows of A."""

    A: Tensor  # [F, 3] unit outward normals
    b: Tensor  # [F]
    seed: Tensor  # [S, 3] points the polytope was grown around (all inside)
    ellipsoid_ids: Optional[Tensor] = field(default=None)  # [F - 6] scene id of each non-box plane

    @property
    def num_faces(self) -> int:
        return int(self.A.shape[0])

    def contains(self, x: ArrayLike, tol: float = 0.0) -> Tensor:
        """bool[...] for points x [..., 3]: A x <= b + tol."""
        x = torch.as_tensor(x, dtype=self.A.dtype, device=self.A.device)
        return ((x @ self.A.T) <= self.b + tol).all(-1)

    def slack(self, x: ArrayLike) -> Tensor:
        """min_f (b_f - A_f x) [...]: Euclidean distance from x to the nearest face plane (negative outside)."""
        x = torch.as_tensor(x, dtype=self.A.dtype, device=self.A.device)
        return (self.b - x @ self.A.T).min(-1).values

    def to_numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """(A [F,3], b [F]) as float64 numpy arrays (for solvers)."""
        return self.A.detach().cpu().double().numpy(), self.b.detach().cpu().double().numpy()

    def to(self, device: Union[str, torch.device]) -> "Polytope":
        return Polytope(
            self.A.to(device), self.b.to(device), self.seed.to(device),
            None if self.ellipsoid_ids is None else self.ellipsoid_ids.to(device),
        )


def chebyshev_center(A: ArrayLike, b: ArrayLike) -> tuple[np.ndarray, float]:
    """Centre and radius of the largest ball inside {x : A x <= b} (LP, HiGHS).

    Returns (center [3], radius); radius is -inf when the polytope is empty and +inf when unbounded
    (the radius is capped at 1e9 in that case).
    """
    from scipy.optimize import linprog

    A = np.asarray(torch.as_tensor(A).detach().cpu().double())
    b = np.asarray(torch.as_tensor(b).detach().cpu().double())
    norms = np.linalg.norm(A, axis=1)  # [F]
    d = A.shape[1]
    # maximise rho  s.t.  A x + rho |a_f| <= b,  0 <= rho <= 1e9
    c = np.zeros(d + 1)
    c[-1] = -1.0
    res = linprog(
        c, A_ub=np.hstack([A, norms[:, None]]), b_ub=b,
        bounds=[(None, None)] * d + [(0.0, 1e9)], method="highs",
    )
    if res.status == 2:  # infeasible even with rho = 0
        return np.full(d, np.nan), -math.inf
    if res.status != 0:
        raise PlanningError(f"Chebyshev-centre LP failed: {res.message}")
    return res.x[:d], float(res.x[-1])


# ---------------------------------------------------------------------------------------- helpers
def _k_sphere(w2: Tensor, lam: Tensor, kappa: float, s: Tensor) -> Tensor:
    """Corollary 1: K(s) = sum_i w_i^2 s(1-s) / (kappa + s (lambda_i - kappa)).
    w2, lam [K, 3]; s [K, T] in (0, 1) -> [K, T]."""
    s3 = s[..., None]  # [K, T, 1]
    return (w2[:, None, :] * s3 * (1 - s3) / (kappa + s3 * (lam[:, None, :] - kappa))).sum(-1)


def _argmax_k(w2: Tensor, lam: Tensor, kappa: float, n_samples: int = 24, iters: int = 20) -> Tensor:
    """s* = argmax_{s in (0,1)} K(s) per row [K]: K is concave in s, so a coarse grid then golden
    section inside the best bracket converges to the maximiser (only the normal depends on it)."""
    k = w2.shape[0]
    grid = torch.linspace(0.0, 1.0, n_samples + 2, dtype=w2.dtype, device=w2.device)[1:-1]  # [T]
    vals = _k_sphere(w2, lam, kappa, grid.expand(k, -1))  # [K, T]
    best = vals.argmax(-1)  # [K]
    step = grid[1] - grid[0]
    lo = (grid[best] - step).clamp_min(1e-9)
    hi = (grid[best] + step).clamp_max(1 - 1e-9)
    g = (math.sqrt(5) - 1) / 2
    for _ in range(iters):
        m1 = hi - g * (hi - lo)
        m2 = lo + g * (hi - lo)
        k12 = _k_sphere(w2, lam, kappa, torch.stack([m1, m2], -1))  # [K, 2]
        left = k12[:, 0] > k12[:, 1]
        hi = torch.where(left, m2, hi)
        lo = torch.where(left, lo, m1)
    return 0.5 * (lo + hi)


def _closest_t(w2: Tensor, lam: Tensor, iters: int = 25) -> Tensor:
    """t >= 0 with sum_i lambda_i w_i^2 / (lambda_i + t)^2 = 1 (closest point of the ellipsoid to an
    outside point: y - mu = Sigma (Sigma + t I)^{-1} Delta). f is convex decreasing in t, so Newton from
    t = 0 increases monotonically to the root. Rows with the point inside (f(0) <= 0) get t = 0."""
    # start from a lower bound of the root: f(t) >= lambda_min |w|^2 / (lambda_max + t)^2
    t = (torch.sqrt(lam.min(-1).values * w2.sum(-1)) - lam.max(-1).values).clamp_min(0)
    for _ in range(iters):
        den = lam + t[:, None]  # [K, 3]
        f = (lam * w2 / den**2).sum(-1) - 1
        df = (-2 * lam * w2 / den**3).sum(-1)
        step = torch.where(f > 0, -f / df.clamp(max=-1e-300), torch.zeros_like(f))
        t = t + step
    return t


def _gather(scene, ids: Tensor, device, dtype=torch.float64):
    mu = scene.means[ids].to(device=device, dtype=dtype)  # [K, 3]
    rot = scene.rotations[ids].to(device=device, dtype=dtype)  # [K, 3, 3]
    axes = scene.radii[ids].to(device=device, dtype=dtype)  # [K, 3]
    return mu, rot, axes


def _support_gap(n: Tensor, mu: Tensor, rot: Tensor, axes: Tensor, r: float) -> Tensor:
    """min over E (+) B_r of n.x = n.mu - ||diag(a) R^T n|| - r, for unit n [K,3] -> [K]."""
    nb = torch.einsum("kji,kj->ki", rot, n)  # R^T n  [K, 3]
    return (n * mu).sum(-1) - (axes * nb).norm(dim=-1) - r


def candidate_ids(scene, index, box_lo: Tensor, box_hi: Tensor) -> Tensor:
    """Ids [K] of ellipsoids whose camera-inflated body can meet the box (exact AABB test after the
    index's coarse query). index: anything with query_box(lo[3], hi[3]) -> LongTensor, or None."""
    r = float(scene.camera_radius)
    dev = scene.means.device
    if index is not None:
        ids = torch.as_tensor(
            index.query_box(box_lo.to(dev, scene.means.dtype) - r, box_hi.to(dev, scene.means.dtype) + r),
            device=dev,
        ).long()
    else:
        # no index: coarse filter on the means with the largest semi-axis, then the exact AABB test
        grow = float(scene.radii.max()) + r if len(scene) else 0.0
        m = scene.means
        near = ((m >= box_lo.to(dev, m.dtype) - grow - 1e-6) & (m <= box_hi.to(dev, m.dtype) + grow + 1e-6)).all(-1)
        ids = torch.nonzero(near).squeeze(-1)
    if ids.numel() == 0:
        return ids
    mu = scene.means[ids].double()
    h = torch.sqrt(((scene.rotations[ids].double() * scene.radii[ids].double()[:, None, :]) ** 2).sum(-1)) + r
    lo, hi = box_lo.to(dev, torch.float64), box_hi.to(dev, torch.float64)
    meets = ((mu - h) <= hi).all(-1) & ((mu + h) >= lo).all(-1)
    return ids[meets]


# ---------------------------------------------------------------------------------------- main
def safe_polytope(
    seed_points: ArrayLike,
    scene,
    index=None,
    box_lo: Optional[ArrayLike] = None,
    box_hi: Optional[ArrayLike] = None,
    *,
    margin: float = 1e-6,
    normal: str = "auto",
    require_seed_inside: bool = True,
    prune: bool = True,
) -> Polytope:
    """Safe polytope around seed points [S, 3] inside the box [box_lo, box_hi].

    Every point of the returned polytope, used as a camera centre, keeps the camera ball
    (scene.camera_radius) at distance >= ``margin`` outside every ellipsoid of the scene (exact, see
    module docstring) and lies in the box. All seed points are inside (else SeedNotFreeError when
    ``require_seed_inside``; with False the polytope is returned anyway and may exclude them or be empty,
    which ``closest_safe_point`` uses). Planes are float64 on the scene's device.

    normal: "auto" (best of the three below per ellipsoid), "prop2" (paper: Q(s*) Delta),
    "closest" (normal at the closest ellipsoid point), "mahalanobis" (Sigma^{-1} Delta).
    """
    dev = scene.means.device
    seeds = torch.as_tensor(seed_points, device=dev).to(torch.float64).reshape(-1, 3)  # [S, 3]
    if seeds.shape[0] == 0 or not torch.isfinite(seeds).all():
        raise InvalidInputError(f"safe_polytope needs finite seed points [S, 3], got {tuple(seeds.shape)}")
    if box_lo is None or box_hi is None:
        raise InvalidInputError("safe_polytope needs a local box (box_lo, box_hi)")
    lo = torch.as_tensor(box_lo, device=dev).to(torch.float64).reshape(3)
    hi = torch.as_tensor(box_hi, device=dev).to(torch.float64).reshape(3)
    if not (torch.isfinite(lo).all() and torch.isfinite(hi).all() and (hi > lo).all()):
        raise InvalidInputError(f"bad polytope box lo={lo.tolist()} hi={hi.tolist()}")
    if require_seed_inside and not ((seeds >= lo).all() and (seeds <= hi).all()):
        raise InvalidInputError("seed points must lie inside the polytope box")
    if normal not in ("auto", "prop2", "closest", "mahalanobis"):
        raise InvalidInputError(f"unknown normal rule {normal!r}")
    r = float(scene.camera_radius)
    eye = torch.eye(3, dtype=torch.float64, device=dev)
    A_box = torch.cat([eye, -eye])  # [6, 3]
    b_box = torch.cat([hi, -lo])  # [6]

    ids = candidate_ids(scene, index, lo, hi)  # [K]
    if ids.numel() == 0:
        return Polytope(A_box, b_box, seeds, ids)
    mu, rot, axes = _gather(scene, ids, dev)  # [K,3], [K,3,3], [K,3]
    lam = axes**2  # [K, 3]

    # reference point per ellipsoid: the seed closest in the ellipsoid metric (segment: closest point)
    wb = torch.einsum("kji,ksj->ksi", rot, seeds[None, :, :] - mu[:, None, :])  # [K, S, 3]
    mah = (wb**2 / lam[:, None, :]).sum(-1)  # [K, S]
    if seeds.shape[0] == 2:
        # minimise m(u) = |L^{-1}(w0 + u (w1 - w0))|^2 over u in [0, 1] (a quadratic)
        d = wb[:, 1] - wb[:, 0]  # [K, 3]
        den = (d**2 / lam).sum(-1)
        u = (-(wb[:, 0] * d / lam).sum(-1) / den.clamp_min(1e-300)).clamp(0, 1)
        u = torch.where(den > 0, u, torch.zeros_like(u))
        w = wb[:, 0] + u[:, None] * d  # [K, 3]
    else:
        w = wb[torch.arange(len(ids), device=dev), mah.argmin(-1)]  # [K, 3]
    w2 = w**2
    degenerate = w2.sum(-1) < 1e-24  # reference point at the centre: any direction is valid
    w = torch.where(degenerate[:, None], torch.tensor([0.0, 0.0, 1e-12], dtype=w.dtype, device=dev), w)
    w2 = w**2

    cands = []  # body-frame normals pointing from the seed toward the ellipsoid, [K, 3] each
    if normal in ("auto", "prop2"):
        s = _argmax_k(w2, lam, r * r)
        q = s[:, None] * (1 - s[:, None]) / (r * r + s[:, None] * (lam - r * r))
        cands.append(-q * w)
    if normal in ("auto", "mahalanobis"):
        cands.append(-w / lam)
    if normal in ("auto", "closest"):
        t = _closest_t(w2, lam)
        cands.append(-w / (lam + t[:, None]))
    nb = torch.stack(cands)  # [C, K, 3]
    nb = nb / nb.norm(dim=-1, keepdim=True).clamp_min(1e-300)
    n_world = torch.einsum("kij,ckj->cki", rot, nb)  # R nb  [C, K, 3]
    offs = (n_world * mu).sum(-1) - (axes * nb).norm(dim=-1) - r - margin  # [C, K]
    proj = torch.einsum("cki,si->cks", n_world, seeds).max(-1).values  # [C, K]
    slack_c = offs - proj  # [C, K]  >= 0: all seeds inside this plane
    best = slack_c.argmax(0)  # [K]
    ar = torch.arange(len(ids), device=dev)
    n_sel = n_world[best, ar]  # [K, 3]
    b_sel = offs[best, ar]  # [K]
    slack = slack_c[best, ar]  # [K]

    if require_seed_inside and bool((slack < 0).any()):
        bad = slack < 0
        raise SeedNotFreeError(
            f"seed {'segment' if seeds.shape[0] == 2 else 'point(s)'} is within the camera radius {r:g} of "
            f"{int(bad.sum())} ellipsoid(s) (worst slack {float(slack.min()):.3g}); no safe polytope contains it",
            ellipsoid_ids=ids[bad], min_slack=float(slack.min()),
        )

    if prune:
        keep = _prune(n_sel, b_sel, slack, mu, rot, axes, r)
    else:
        keep = torch.arange(len(ids), device=dev)
    A = torch.cat([A_box, n_sel[keep]])
    b = torch.cat([b_box, b_sel[keep]])
    return Polytope(A, b, seeds, ids[keep])


def _prune(n_sel: Tensor, b_sel: Tensor, slack: Tensor, mu: Tensor, rot: Tensor, axes: Tensor, r: float) -> Tensor:
    """Greedy nearest-first redundancy removal; returns the kept rows (indices into the K candidates).

    Runs in numpy on the host: the loop is sequential and per-step arrays are small, so host numpy
    beats per-op device launches; the inputs are only K x 15 numbers."""
    order = torch.argsort(slack).cpu().numpy()
    n = n_sel.detach().cpu().numpy()[order]  # [K, 3]
    b = b_sel.detach().cpu().numpy()[order]
    m = mu.detach().cpu().numpy()[order]
    R = rot.detach().cpu().numpy()[order]
    a = axes.detach().cpu().numpy()[order]
    alive_idx = np.arange(len(order))  # positions (in sorted order) still undecided
    kept = []
    while alive_idx.size:
        i = alive_idx[0]
        kept.append(i)
        rest = alive_idx[1:]
        if rest.size == 0:
            break
        ni = n[i]
        # min over E_j (+) B_r of ni.x for all remaining j
        nbody = np.einsum("kji,j->ki", R[rest], ni)  # R_j^T ni  [J, 3]
        gap = m[rest] @ ni - np.linalg.norm(a[rest] * nbody, axis=1) - r  # [J]
        alive_idx = rest[gap < b[i]]
    return torch.as_tensor(order[np.asarray(kept, dtype=np.int64)], device=n_sel.device)
