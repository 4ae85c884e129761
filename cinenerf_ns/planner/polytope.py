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
from .polytope_native import native_applies, native_arrays, native_safe_polytope
from .polytope_planes import cut_by, plane_candidates, segment_frame_np, support_gap

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


# ---------------------------------------------------------------------------------------- candidates
def candidate_ids(scene, index, box_lo: Tensor, box_hi: Tensor) -> Tensor:
    """Ids [K] of ellipsoids whose camera-inflated body may meet the box (a superset: bounding-sphere
    test after the index's coarse AABB query). index: anything with query_box(lo[3], hi[3]) ->
    LongTensor, or None (then all ellipsoids are scanned)."""
    return _candidates(scene, index, box_lo, box_hi)[0]


def _candidates(scene, index, box_lo, box_hi, box_rot=None, planes=None, ids=None):
    """(ids [K] on the scene device, means [K, 3] float64 numpy, bounding radii [K] float64 numpy).
    box_rot [3, 3] (columns = box axes): the box is {x : lo <= box_rot^T x <= hi}.
    planes: optional (A [F, 3], b [F]) float64 numpy; then only ellipsoids whose inflated body may
    meet box ∩ {A x <= b} need to be returned (index cells beyond a plane are skipped; needs an index
    with ``query_box_in_planes`` and ``pad``, else ignored). ids: a precomputed id subset [K] to filter."""
    r = float(scene.camera_radius)
    dev = scene.means.device
    m = scene.means
    lo = torch.as_tensor(box_lo, device=dev).to(m.dtype)
    hi = torch.as_tensor(box_hi, device=dev).to(m.dtype)
    rot = None if box_rot is None else torch.as_tensor(box_rot, device=dev).to(m.dtype)
    if index is not None or ids is not None:
        if ids is None:
            if rot is None:
                qlo, qhi = lo, hi
            else:  # world AABB of the oriented box: centre +- |R| half-extents
                c = rot @ (0.5 * (lo + hi))
                h = rot.abs() @ (0.5 * (hi - lo))
                qlo, qhi = c - h, c + h
            if planes is not None and hasattr(index, "query_box_in_planes") and hasattr(index, "pad"):
                # padded AABB (pad p) grown by e = max(r - p, 0) contains the inflated body, so query
                # the region grown by e: box +- e and planes shifted by e |A_f|_1 (cube of half-width e)
                e = max(r - float(index.pad), 0.0) * (1 + 1e-9)
                A_p, b_p = planes
                ids = index.query_box_in_planes(qlo - e, qhi + e, torch.as_tensor(A_p, device=dev),
                                                torch.as_tensor(b_p + e * np.abs(A_p).sum(-1), device=dev))
            else:
                ids = index.query_box(qlo - r, qhi + r)
        ids = torch.as_tensor(ids, device=dev).long()
        if ids.numel() == 0:
            return ids, np.zeros((0, 3)), np.zeros(0)
        m = m[ids]
        amax = scene.radii[ids].max(-1).values
    else:
        ids = None
        amax = scene.radii.max(-1).values
    mb = m if rot is None else m @ rot  # means in box coordinates
    # distance from the mean to the box <= bounding-sphere radius + r (+ rounding slack)
    gap = (mb - torch.minimum(torch.maximum(mb, lo), hi)).norm(dim=-1)
    near = gap <= amax + r + 1e-6 * (1 + m.abs().max(-1).values)
    sel = torch.nonzero(near).squeeze(-1)
    out = ids[sel] if ids is not None else sel
    return out, _np(m[sel]), _np(amax[sel])


def _np(x: Tensor) -> np.ndarray:
    return x.detach().cpu().to(torch.float64).numpy()


# ---------------------------------------------------------------------------------------- compiled path
def prepare_native(scene, index) -> bool:
    """Load the compiled polytope and build the arrays it reads for this scene and index (once; otherwise the first
    safe_polytope call does it). False when the compiled path does not apply or did not load."""
    from .native import safe_polytope_c

    if not native_applies(scene, index) or safe_polytope_c() is None:
        return False
    native_arrays(scene, index)
    return True


def _native_polytope(fn, scene, index, seeds, seeds_t, lo, hi, rot, A_box, b_box, r, margin, normal,
                     require_seed_inside, near_fraction) -> Polytope:
    """safe_polytope through native/polytope.c (float64 numpy seeds [S, 3], box lo/hi [3], rot [3, 3] or None)."""
    dev = scene.means.device
    n_planes, b_planes, ids_planes, bad_ids, bad_slack = native_safe_polytope(
        fn, scene, index, seeds, lo, hi, rot, r, margin, normal, require_seed_inside, near_fraction)
    if bad_slack.size:
        worst = float(bad_slack.min())
        raise SeedNotFreeError(
            f"seed {'segment' if seeds.shape[0] == 2 else 'point(s)'} is within the camera radius {r:g} of "
            f"{len(bad_ids)} ellipsoid(s) (worst slack {worst:.3g}); no safe polytope contains it",
            ellipsoid_ids=torch.as_tensor(bad_ids, device=dev), min_slack=worst,
        )
    A = np.vstack([A_box, n_planes])
    b = np.concatenate([b_box, b_planes])
    kept = torch.as_tensor(ids_planes, device=dev)
    return Polytope(torch.as_tensor(A, device=dev), torch.as_tensor(b, device=dev), seeds_t, kept)


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
    chunk: int = 32,
    box_rotation: Optional[ArrayLike] = None,
    two_pass: bool = True,
    near_fraction: float = 0.5,
    backend: str = "auto",
) -> Polytope:
    """Safe polytope around seed points [S, 3] inside the box [box_lo, box_hi].

    Every point of the returned polytope, used as a camera centre, keeps the camera ball
    (scene.camera_radius) at distance >= ``margin`` outside every ellipsoid of the scene (exact, see
    module docstring) and lies in the box. All seed points are inside (else SeedNotFreeError when
    ``require_seed_inside``; with False the polytope is returned anyway and may exclude them or be
    empty, which ``closest_safe_point`` uses). Planes are float64 on the scene's device.

    normal: "auto" (best of the three below per ellipsoid), "prop2" (paper: Q(s*) Delta),
    "closest" (normal at the closest ellipsoid point), "mahalanobis" (Sigma^{-1} Delta).
    prune: nearest-first redundancy removal (False: one plane per ellipsoid meeting the box).
    chunk: ellipsoids are visited in order of a distance lower bound, ``chunk`` at a time; planes are
    only computed for ellipsoids not already cut off by earlier planes, so far clutter costs ~nothing.
    box_rotation: optional orthonormal [3, 3] whose columns are the box axes; the box is then
    {x : box_lo <= box_rotation^T x <= box_hi} (an oriented box, e.g. aligned with a segment).
    two_pass: with a grid index (and prune), first decide the ellipsoids near the seeds, then gather
    only those in index cells not already cut off by the kept planes (far fewer candidates in dense
    scenes; same safety guarantee). False: gather every ellipsoid meeting the box at once.
    near_fraction: the first pass looks at ellipsoids within this fraction of the seeds' distance to
    the box (a box around the seed set / an oriented box around a seed segment).
    backend: "auto" (the compiled path, native/polytope.c, when it loads and applies: a CPU scene, a GridIndex
    on the CPU, prune, one or two seeds; else Python), "native" (error if it does not apply) or "python". Both
    give safe polytopes holding the seeds with the same normal rules and exact offsets; the compiled one visits
    ellipsoids in buckets of ~16 by distance instead of chunks of ``chunk``, so its planes can differ a little
    (native/polytope.c's header); two_pass and near_fraction apply to both.
    """
    dev = scene.means.device
    seeds_t = torch.as_tensor(seed_points, device=dev).to(torch.float64).reshape(-1, 3)  # [S, 3]
    if seeds_t.shape[0] == 0 or not torch.isfinite(seeds_t).all():
        raise InvalidInputError(f"safe_polytope needs finite seed points [S, 3], got {tuple(seeds_t.shape)}")
    if box_lo is None or box_hi is None:
        raise InvalidInputError("safe_polytope needs a local box (box_lo, box_hi)")
    lo_t = torch.as_tensor(box_lo, device=dev).to(torch.float64).reshape(3)
    hi_t = torch.as_tensor(box_hi, device=dev).to(torch.float64).reshape(3)
    if not (torch.isfinite(lo_t).all() and torch.isfinite(hi_t).all() and (hi_t > lo_t).all()):
        raise InvalidInputError(f"bad polytope box lo={lo_t.tolist()} hi={hi_t.tolist()}")
    rot_t = None
    if box_rotation is not None:
        rot_t = torch.as_tensor(box_rotation, device=dev).to(torch.float64).reshape(3, 3)
        if not torch.allclose(rot_t.T @ rot_t, torch.eye(3, dtype=torch.float64, device=dev), atol=1e-9):
            raise InvalidInputError("box_rotation must be orthonormal")
    seeds_box = seeds_t if rot_t is None else seeds_t @ rot_t
    if require_seed_inside and not ((seeds_box >= lo_t - 1e-12).all() and (seeds_box <= hi_t + 1e-12).all()):
        raise InvalidInputError("seed points must lie inside the polytope box")
    if normal not in ("auto", "prop2", "closest", "mahalanobis"):
        raise InvalidInputError(f"unknown normal rule {normal!r}")
    from .native import choose, safe_polytope_c

    fn = choose(backend, safe_polytope_c, "polytope", "safe polytope",
                applies=prune and seeds_t.shape[0] in (1, 2) and native_applies(scene, index),
                needs="a CPU scene, a GridIndex on the CPU, prune and one or two seeds")
    r = float(scene.camera_radius)
    seeds = _np(seeds_t)
    lo, hi = _np(lo_t), _np(hi_t)
    axes_t = np.eye(3) if rot_t is None else _np(rot_t).T  # rows = box axes
    A_box = np.vstack([axes_t, -axes_t])  # [6, 3]
    b_box = np.concatenate([hi, -lo])
    if fn is not None:
        return _native_polytope(fn, scene, index, seeds, seeds_t, lo, hi, None if rot_t is None else _np(rot_t),
                                A_box, b_box, r, margin, normal, require_seed_inside, near_fraction if two_pass else 0.0)

    planes_n, planes_b, planes_id = [], [], []  # kept planes; planes_id: scene ids [f] on the device
    bad = []  # (scene ids [J] cpu, mu, rot, axes, slack) of ellipsoids no plane of their own family cuts off

    def add_planes(ids, mu_all, amax):
        """Decide candidates ids [K] (means [K, 3], bounding radii [K]): each is either cut off
        (exact support test) by a kept plane, gets its own plane, or goes to ``bad``."""
        K = int(ids.numel())
        if not K:
            return
        # visiting order: lower bound of the distance from the seed set to the inflated body
        if seeds.shape[0] == 2:
            d = seeds[1] - seeds[0]
            u = np.clip((mu_all - seeds[0]) @ d / max(float(d @ d), 1e-300), 0, 1)
            dist = np.linalg.norm(seeds[0] + u[:, None] * d - mu_all, axis=1)
        else:
            dist = np.linalg.norm(mu_all[:, None, :] - seeds[None], axis=-1).min(1)
        key = dist - amax
        rot_all = _np(scene.rotations[ids])  # [K, 3, 3] one gather, not one per chunk
        axes_all = _np(scene.radii[ids])  # [K, 3]
        queue = np.arange(K)  # undecided candidates, unordered: only each chunk is sorted
        if prune and planes_n:
            # already cut off by a kept plane (exact support test): decided, needs no plane of its own
            queue = queue[~cut_by(np.vstack(planes_n), np.concatenate(planes_b), mu_all, amax, rot_all, axes_all, r)]
        ids_cpu = ids.cpu()
        step = chunk if prune else K
        while queue.size:
            if queue.size > step:
                # the `step` nearest by the lower bound (O(K) partition instead of a full sort)
                part = np.argpartition(key[queue], step - 1)[:step]
                ch = queue[part]
                left = np.ones(queue.size, dtype=bool)
                left[part] = False
                rest = queue[left]
            else:
                ch, rest = queue, queue[:0]
            ch = ch[np.argsort(key[ch], kind="stable")]
            # (every queued candidate is not cut off by the kept planes: filtered when they were added)
            rot, axes, mu = rot_all[ch], axes_all[ch], mu_all[ch]
            n_c, b_c, slack_c = plane_candidates(seeds, mu, rot, axes, r, normal, margin)
            if require_seed_inside and (slack_c < 0).any():
                # no plane of this ellipsoid's family keeps all seeds; it is only fatal if no other
                # plane cuts it off either, which is decided once all planes are known
                neg = slack_c < 0
                bad.append((ids_cpu[torch.as_tensor(ch[neg])], mu[neg], rot[neg], axes[neg], slack_c[neg]))
                keep_c = ~neg
                ch, mu, rot, axes = ch[keep_c], mu[keep_c], rot[keep_c], axes[keep_c]
                n_c, b_c, slack_c = n_c[keep_c], b_c[keep_c], slack_c[keep_c]
            if not prune:
                planes_n.append(n_c), planes_b.append(b_c), planes_id.append(ids[torch.as_tensor(ch).to(dev)])
                break
            # redundancy inside the chunk, vectorised: beyond[i, j] = ellipsoid i lies beyond plane j
            # (exact support test) for the chunk's own planes and for the planes kept so far
            beyond_own = support_gap(n_c, mu, rot, axes, r) >= b_c  # [C, C]
            taken = np.zeros(len(ch), dtype=bool)
            for i in np.argsort(slack_c, kind="stable"):  # nearest plane first
                if beyond_own[i, taken].any():
                    continue  # already cut off by a kept plane: needs no plane of its own
                taken[i] = True
            if taken.any():
                nn, nbv = n_c[taken], b_c[taken]
                planes_n.append(nn)
                planes_b.append(nbv)
                planes_id.append(ids[torch.as_tensor(ch[taken]).to(dev)])
                if rest.size:
                    # drop the rest that lie beyond a new plane (exact support test, bounding sphere first)
                    rest = rest[~cut_by(nn, nbv, mu_all[rest], amax[rest], rot_all[rest], axes_all[rest], r)]
            queue = rest

    if index is not None and prune and two_pass and hasattr(index, "query_box_in_planes"):
        # Pass 1: the ellipsoids near the seeds (a tube of half-width rho around the seed set, rho =
        # the seeds' distance to the box) give the planes that bound the polytope in practice.
        # Pass 2: only ellipsoids in index cells that are not entirely beyond one of those planes (or
        # the box) can still meet the polytope; all others are excluded by planes that are kept, so
        # the result is as safe as deciding every ellipsoid of the box (see query_box_in_planes).
        rho = near_fraction * float(torch.minimum(seeds_box - lo_t, hi_t - seeds_box).min().clamp_min(1e-9))
        if seeds_t.shape[0] == 2:  # oriented box around the segment: [-rho, L + rho] x [-rho, rho]^2
            frame = segment_frame_np(seeds[0], seeds[1])  # [3, 3] columns u, v, w
            proj = seeds @ frame  # [2, 3]
            t_lo, t_hi = proj.min(0) - rho, proj.max(0) + rho
        else:
            frame = np.eye(3)
            t_lo, t_hi = seeds.min(0) - rho, seeds.max(0) + rho
        A_near = np.vstack([A_box, frame.T, -frame.T])
        b_near = np.concatenate([b_box, t_hi, -t_lo])
        ids0, mu0, am0 = _candidates(scene, index, lo_t, hi_t, rot_t, planes=(A_near, b_near))
        add_planes(ids0, mu0, am0)
        ids1, mu1, am1 = _candidates(scene, index, lo_t, hi_t, rot_t,
                                     planes=(np.vstack([A_box] + planes_n), np.concatenate([b_box] + planes_b)))
        if ids0.numel() and ids1.numel():
            new1 = ~torch.isin(ids1, ids0)
            new1_np = new1.cpu().numpy()
            ids1, mu1, am1 = ids1[new1], mu1[new1_np], am1[new1_np]
        add_planes(ids1, mu1, am1)
    else:
        add_planes(*_candidates(scene, index, lo_t, hi_t, rot_t))
    if bad:
        b_ids, b_mu, b_rot, b_axes, b_slack = (
            torch.cat([x[0] for x in bad]), *(np.concatenate([x[i] for x in bad]) for i in range(1, 5)))
        if planes_n:
            kn, kb = np.vstack(planes_n), np.concatenate(planes_b)
            cut = ~(support_gap(kn, b_mu, b_rot, b_axes, r) >= kb).any(1)
            b_ids, b_slack = b_ids[torch.as_tensor(cut)], b_slack[cut]
        if b_slack.size:
            worst = float(b_slack.min())
            raise SeedNotFreeError(
                f"seed {'segment' if seeds.shape[0] == 2 else 'point(s)'} is within the camera radius {r:g} of "
                f"{len(b_ids)} ellipsoid(s) (worst slack {worst:.3g}); no safe polytope contains it",
                ellipsoid_ids=b_ids, min_slack=worst,
            )
    A = np.vstack([A_box] + planes_n)
    b = np.concatenate([b_box] + planes_b)
    kept = torch.cat(planes_id) if planes_id else torch.zeros(0, dtype=torch.long, device=dev)  # [F - 6]
    return Polytope(torch.as_tensor(A, device=dev), torch.as_tensor(b, device=dev), seeds_t, kept)
