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

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Optional, Sequence, Union

import numpy as np
import torch
from torch import Tensor

from ..errors import InvalidInputError, PlanningError
from ..geometry.native_scene import native_applies, native_arrays
from ..tensor_pickle import NumpyPickled
from .polytope_candidates import candidates_near, f64_numpy
from .polytope_native import native_safe_polytope
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
class Polytope(NumpyPickled):
    """Convex polytope {x : A x <= b} with unit-norm rows of A. Pickles its CPU tensors as numpy (tensor_pickle.py)."""

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

    @property
    def proven_empty(self) -> bool:
        """True when safe_polytope's ``stop_when_empty`` proved that no ball of its radius fits: the polytope then ends
        with an explicit contradicting plane (scene id -1), so it is empty."""
        ids = self.ellipsoid_ids
        return ids is not None and ids.numel() > 0 and int(ids[-1]) == -1

    @classmethod
    def from_numpy(cls, A: np.ndarray, b: np.ndarray, seed: Tensor,
                   ellipsoid_ids: Optional[Tensor] = None) -> "Polytope":
        """The CPU polytope whose planes are torch.from_numpy(A [F, 3]), torch.from_numpy(b [F]) (the same memory),
        with host_arrays() already holding A and b."""
        p = cls(torch.from_numpy(A), torch.from_numpy(b), seed, ellipsoid_ids)
        p.__dict__["_host"] = (p.A, p.b, A, b)
        return p

    def host_arrays(self) -> Optional[tuple[np.ndarray, np.ndarray]]:
        """(A, b) as numpy views of the planes (the same memory, any dtype) when both are CPU tensors, else None. Kept
        on the polytope while A and b are the same tensor objects: the corridor reads every polytope's planes two or
        three times a request (junction slacks, QP rows), ~3.6 us of detach / numpy a polytope each time."""
        got = self.__dict__.get("_host")
        if got is not None and got[0] is self.A and got[1] is self.b:
            return got[2], got[3]
        a, b = self.A, self.b
        if a.device.type != "cpu" or b.device.type != "cpu":
            return None
        got = (a, b, a.detach().numpy(), b.detach().numpy())
        self.__dict__["_host"] = got
        return got[2], got[3]

    def __getstate__(self) -> dict:  # the kept numpy views are not pickled (host_arrays makes them again)
        return {k: v for k, v in super().__getstate__().items() if k != "_host"}

    def to_numpy(self) -> tuple[np.ndarray, np.ndarray]:
        """(A [F,3], b [F]) as float64 numpy arrays (for solvers)."""
        return self.A.detach().cpu().double().numpy(), self.b.detach().cpu().double().numpy()

    def to(self, device: Union[str, torch.device]) -> "Polytope":
        return Polytope(
            self.A.to(device), self.b.to(device), self.seed.to(device),
            None if self.ellipsoid_ids is None else self.ellipsoid_ids.to(device),
        )


NORMAL_RULES = ("auto", "prop2", "closest", "mahalanobis")
EMPTY_PROBE_FRACTION = 0.125
"""PolytopeOptions.stop_when_empty: the probe pass's near box is this x the first pass's (native/polytope.c uses
the same): in a dense blob the first pass's box holds thousands of ellipsoids while the planes of a far smaller box
already prove the polytope empty (docs/PLANNER_DEFAULTS.md)."""


@dataclass(frozen=True)
class PolytopeOptions:
    """How safe_polytope builds its planes. Every choice gives a safe polytope (module docstring); they change how
    much free space it keeps, what it costs, and whether seeds that are not free raise.

    margin: extra distance (scene units) every plane keeps between the camera ball and its ellipsoid.
    normal: "auto" (best of the three below per ellipsoid), "prop2" (paper: Q(s*) Delta),
    "closest" (normal at the closest ellipsoid point), "mahalanobis" (Sigma^{-1} Delta).
    require_seed_inside: raise SeedNotFreeError when no polytope holds every seed (False: return it anyway; it may
    then exclude them or be empty).
    prune: nearest-first redundancy removal (False: one plane per ellipsoid meeting the box).
    chunk: ellipsoids are visited in order of a distance lower bound, ``chunk`` at a time; planes are
    only computed for ellipsoids not already cut off by earlier planes, so far clutter costs ~nothing.
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
    stop_when_empty: None, or a radius rho >= 0 (with require_seed_inside False and two_pass): a probe pass first
    decides the ellipsoids in a much smaller box around the seeds (EMPTY_PROBE_FRACTION) and stops there when the
    box and its planes hold no ball of radius rho (else the probe's planes are dropped: the passes below give the
    same polytope as without the option); when the box and the first pass's planes hold no such ball, the second
    pass is skipped (more planes only shrink the
    polytope, so the full one holds no such ball either) and the polytope returned is made explicitly empty (one
    more plane contradicting a box face; scene id -1). closest_safe_point's projection counts a polytope without a
    ball of its INTERIOR_RADIUS as empty, so it asks for this. The proof: the compiled LP (native/polytope.c
    cn_planes_empty) on the compiled path, the Chebyshev radius (HiGHS, chebyshev_center) on the Python one.
    """

    margin: float = 1e-6
    normal: str = "auto"
    require_seed_inside: bool = True
    prune: bool = True
    chunk: int = 32
    two_pass: bool = True
    near_fraction: float = 0.5
    backend: str = "auto"
    stop_when_empty: Optional[float] = None

    def __post_init__(self):
        if self.normal not in NORMAL_RULES:
            raise InvalidInputError(f"unknown normal rule {self.normal!r}")
        if self.stop_when_empty is not None and (self.require_seed_inside or not self.stop_when_empty >= 0):
            raise InvalidInputError("stop_when_empty needs a radius >= 0 and require_seed_inside=False")


_OPTION_NAMES = frozenset(f.name for f in dataclasses.fields(PolytopeOptions))


def resolved_options(options: Optional[PolytopeOptions], fields: dict) -> PolytopeOptions:
    """``options`` (default PolytopeOptions()) with the named ``fields`` replaced (TypeError for unknown names)."""
    if not fields.keys() <= _OPTION_NAMES:
        raise TypeError(f"safe_polytope() got unexpected keyword arguments {sorted(fields.keys() - _OPTION_NAMES)}")
    if options is None:
        return PolytopeOptions(**fields)
    return dataclasses.replace(options, **fields) if fields else options


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


# ---------------------------------------------------------------------------------------- input checks, the box
@dataclass
class _Box:
    """A polytope's local box {x : lo <= rot^T x <= hi} (rot None: axis-aligned), float64 on the scene's device."""

    lo: Tensor  # [3]
    hi: Tensor  # [3]
    rot: Optional[Tensor]  # [3, 3] columns = box axes, or None
    A: np.ndarray  # [6, 3] its faces as planes A x <= b (float64 numpy, the first six planes of the polytope)
    b: np.ndarray  # [6] (hi, -lo)

    def polytope(self, n: list, b: list, kept: Tensor, seeds_t: Tensor, empty: bool = False) -> Polytope:
        """The box's six faces then the planes n [f, 3], b [f] of each list entry; kept [F - 6] their scene ids.
        empty: one more plane (scene id -1), the first box axis <= lo - (hi - lo), contradicting the face >= lo."""
        dev = self.lo.device
        if empty:
            n = n + [self.A[:1]]
            b = b + [np.array([-self.b[3] - (self.b[0] + self.b[3])])]
            kept = torch.cat([kept, torch.full((1,), -1, dtype=kept.dtype, device=kept.device)])
        A = np.vstack([self.A] + n)
        b = np.concatenate([self.b] + b)
        return Polytope(torch.as_tensor(A, device=dev), torch.as_tensor(b, device=dev), seeds_t, kept)


def _f64(x: ArrayLike) -> np.ndarray:
    """x (tensor on any device, array or sequence) as a float64 numpy array."""
    return f64_numpy(x) if isinstance(x, Tensor) else np.asarray(x, dtype=np.float64)


def _checked_seeds(seed_points: ArrayLike, dev) -> Tensor:
    seeds_t = torch.as_tensor(seed_points, device=dev).to(torch.float64).reshape(-1, 3)  # [S, 3]
    if seeds_t.shape[0] == 0 or not np.isfinite(_f64(seeds_t)).all():
        raise InvalidInputError(f"safe_polytope needs finite seed points [S, 3], got {tuple(seeds_t.shape)}")
    return seeds_t


def _checked_box(box_lo, box_hi, box_rotation, seeds_t: Tensor, require_seed_inside: bool) -> _Box:
    """The checked box. The checks run in numpy (float64, the same values): ~10 torch calls on 3-vectors cost ~50 us,
    a fifth of a compiled segment polytope at 1M Gaussians."""
    dev = seeds_t.device
    if box_lo is None or box_hi is None:
        raise InvalidInputError("safe_polytope needs a local box (box_lo, box_hi)")
    lo, hi = _f64(box_lo).reshape(3), _f64(box_hi).reshape(3)
    if not (np.isfinite(lo).all() and np.isfinite(hi).all() and (hi > lo).all()):
        raise InvalidInputError(f"bad polytope box lo={lo.tolist()} hi={hi.tolist()}")
    rot = None
    if box_rotation is not None:
        rot = _f64(box_rotation).reshape(3, 3)
        eye = np.eye(3)
        # np.allclose(rot^T rot, I, atol=1e-9)'s test (rtol 1e-5 of |I|; NaN fails), written out: 3 us instead of 15
        if not (np.abs(rot.T @ rot - eye) <= 1e-9 + 1e-5 * eye).all():
            raise InvalidInputError("box_rotation must be orthonormal")
    if require_seed_inside:
        seeds_box = _f64(seeds_t) if rot is None else _f64(seeds_t) @ rot
        if not ((seeds_box >= lo - 1e-12).all() and (seeds_box <= hi + 1e-12).all()):
            raise InvalidInputError("seed points must lie inside the polytope box")
    axes = np.eye(3) if rot is None else rot.T  # rows = box axes
    return _Box(torch.from_numpy(lo).to(dev), torch.from_numpy(hi).to(dev),
                None if rot is None else torch.from_numpy(rot).to(dev), np.vstack([axes, -axes]),
                np.concatenate([hi, -lo]))


def _seed_not_free(seeds: np.ndarray, r: float, ids: Tensor, slack: np.ndarray) -> SeedNotFreeError:
    """The error for ellipsoids ids [J] that cut the seeds [S, 3] by slack [J] (< 0) and that no kept plane cuts off."""
    worst = float(slack.min())
    return SeedNotFreeError(
        f"seed {'segment' if seeds.shape[0] == 2 else 'point(s)'} is within the camera radius {r:g} of "
        f"{len(ids)} ellipsoid(s) (worst slack {worst:.3g}); no safe polytope contains it",
        ellipsoid_ids=ids, min_slack=worst,
    )


# ---------------------------------------------------------------------------------------- compiled path
def prepare_native(scene, index) -> bool:
    """Load the compiled polytope and build the arrays it reads for this scene and index (once; otherwise the first
    safe_polytope call does it). False when the compiled path does not apply or did not load."""
    from ..native import safe_polytope_c

    if not native_applies(scene, index) or safe_polytope_c() is None:
        return False
    native_arrays(scene, index)
    return True


def _native_polytope(fn, scene, index, seeds_t: Tensor, box: _Box, opts: PolytopeOptions) -> Polytope:
    """safe_polytope through native/polytope.c (one or two seeds [S, 3])."""
    dev = scene.means.device
    seeds, r = f64_numpy(seeds_t), float(scene.camera_radius)
    lo, hi = -box.b[3:], box.b[:3]  # b = (hi, -lo): the box in float64 numpy
    shrink = -1.0 if opts.stop_when_empty is None else float(opts.stop_when_empty)
    n, b, ids, bad_ids, bad_slack, stopped = native_safe_polytope(
        fn, scene, index, seeds, lo, hi, None if box.rot is None else f64_numpy(box.rot), r, opts.margin,
        opts.normal, opts.require_seed_inside, opts.near_fraction if opts.two_pass else 0.0, shrink)
    if bad_slack.size:
        raise _seed_not_free(seeds, r, torch.as_tensor(bad_ids, device=dev), bad_slack)
    return box.polytope([n], [b], torch.as_tensor(ids, device=dev), seeds_t, empty=stopped)


# ---------------------------------------------------------------------------------------- python path
def _distance_key(seeds: np.ndarray, mu: np.ndarray, amax: np.ndarray) -> np.ndarray:
    """[K] lower bound of the distance from the seed set [S, 3] to ellipsoids (means [K, 3], bounding radii [K]):
    the visiting order."""
    if seeds.shape[0] == 2:
        d = seeds[1] - seeds[0]
        u = np.clip((mu - seeds[0]) @ d / max(float(d @ d), 1e-300), 0, 1)
        dist = np.linalg.norm(seeds[0] + u[:, None] * d - mu, axis=1)
    else:
        dist = np.linalg.norm(mu[:, None, :] - seeds[None], axis=-1).min(1)
    return dist - amax


def _nearest_chunk(queue: np.ndarray, key: np.ndarray, step: int) -> tuple[np.ndarray, np.ndarray]:
    """(the ``step`` entries of queue [Q] with the smallest key, sorted by key; the others, unordered)."""
    if queue.size > step:
        part = np.argpartition(key[queue], step - 1)[:step]  # O(Q) partition instead of a full sort
        ch = queue[part]
        left = np.ones(queue.size, dtype=bool)
        left[part] = False
        rest = queue[left]
    else:
        ch, rest = queue, queue[:0]
    return ch[np.argsort(key[ch], kind="stable")], rest


def _nearest_plane_first(beyond: np.ndarray, slack: np.ndarray) -> np.ndarray:
    """bool [C]: the chunk's planes kept, nearest (smallest slack) first, skipping an ellipsoid that lies beyond a
    plane already kept (beyond [C, C]: ellipsoid i lies beyond plane j, exact support test)."""
    taken = np.zeros(len(slack), dtype=bool)
    for i in np.argsort(slack, kind="stable"):
        if beyond[i, taken].any():
            continue  # already cut off by a kept plane: needs no plane of its own
        taken[i] = True
    return taken


class _PlaneSet:
    """The planes of one safe polytope as the Python path decides them, candidate chunk by candidate chunk."""

    def __init__(self, seeds: np.ndarray, scene, opts: PolytopeOptions):
        self.seeds, self.scene, self.opts = seeds, scene, opts  # seeds [S, 3] float64
        self.r = float(scene.camera_radius)
        self.n: list = []  # kept planes, per chunk: normals [f, 3], offsets [f], scene ids [f] on the scene's device
        self.b: list = []
        self.ids: list = []
        # (scene ids [J] cpu, mu, rot, axes, slack) of ellipsoids whose own planes all cut the seeds
        self.bad: list = []
        self.stopped = False  # stop_when_empty: the planes kept so far hold no ball of that radius

    def add(self, ids: Tensor, mu_all: np.ndarray, amax: np.ndarray) -> None:
        """Decide candidates ids [K] (means [K, 3], bounding radii [K]): each is either cut off
        (exact support test) by a kept plane, gets its own plane, or goes to ``bad``."""
        K = int(ids.numel())
        if not K:
            return
        prune, r = self.opts.prune, self.r
        key = _distance_key(self.seeds, mu_all, amax)
        rot_all = f64_numpy(self.scene.rotations[ids])  # [K, 3, 3] one gather, not one per chunk
        axes_all = f64_numpy(self.scene.radii[ids])  # [K, 3]
        queue = np.arange(K)  # undecided candidates, unordered: only each chunk is sorted
        if prune and self.n:
            # already cut off by a kept plane (exact support test): decided, needs no plane of its own
            queue = queue[~cut_by(np.vstack(self.n), np.concatenate(self.b), mu_all, amax, rot_all, axes_all, r)]
        ids_cpu = ids.cpu()
        step = self.opts.chunk if prune else K
        while queue.size:
            ch, rest = _nearest_chunk(queue, key, step)
            # (every queued candidate is not cut off by the kept planes: filtered when they were added)
            new = self._decide_chunk(ids, ids_cpu, ch, mu_all[ch], rot_all[ch], axes_all[ch])
            if not prune:
                break
            if new is not None and rest.size:
                # drop the rest that lie beyond a new plane (exact support test, bounding sphere first)
                rest = rest[~cut_by(*new, mu_all[rest], amax[rest], rot_all[rest], axes_all[rest], r)]
            queue = rest

    def _decide_chunk(self, ids, ids_cpu, ch, mu, rot, axes):
        """Planes for the candidates ch [C] (ids positions, sorted nearest first) -> the planes kept (n [T, 3], b [T]),
        or None when none was."""
        o, r = self.opts, self.r
        n_c, b_c, slack_c = plane_candidates(self.seeds, mu, rot, axes, r, o.normal, o.margin)
        if o.require_seed_inside and (slack_c < 0).any():
            # no plane of this ellipsoid's family keeps all seeds; it is only fatal if no other
            # plane cuts it off either, which is decided once all planes are known
            neg = slack_c < 0
            self.bad.append((ids_cpu[torch.as_tensor(ch[neg])], mu[neg], rot[neg], axes[neg], slack_c[neg]))
            keep_c = ~neg
            ch, mu, rot, axes = ch[keep_c], mu[keep_c], rot[keep_c], axes[keep_c]
            n_c, b_c, slack_c = n_c[keep_c], b_c[keep_c], slack_c[keep_c]
        if not o.prune:
            self._keep(n_c, b_c, ids, ch)
            return None
        # redundancy inside the chunk: beyond[i, j] = ellipsoid i lies beyond plane j (exact support test)
        taken = _nearest_plane_first(support_gap(n_c, mu, rot, axes, r) >= b_c, slack_c)  # [C]
        if not taken.any():
            return None
        self._keep(n_c[taken], b_c[taken], ids, ch[taken])
        return self.n[-1], self.b[-1]

    def _keep(self, n: np.ndarray, b: np.ndarray, ids: Tensor, ch: np.ndarray) -> None:
        self.n.append(n)
        self.b.append(b)
        self.ids.append(ids[torch.as_tensor(ch).to(self.scene.means.device)])

    def check_seeds(self) -> None:
        """Raise SeedNotFreeError when a ``bad`` ellipsoid (its own planes all cut the seeds) lies beyond no kept
        plane either."""
        if not self.bad:
            return
        b_ids, b_mu, b_rot, b_axes, b_slack = (
            torch.cat([x[0] for x in self.bad]), *(np.concatenate([x[i] for x in self.bad]) for i in range(1, 5)))
        if self.n:
            kn, kb = np.vstack(self.n), np.concatenate(self.b)
            uncut = ~(support_gap(kn, b_mu, b_rot, b_axes, self.r) >= kb).any(1)
            b_ids, b_slack = b_ids[torch.as_tensor(uncut)], b_slack[uncut]
        if b_slack.size:
            raise _seed_not_free(self.seeds, self.r, b_ids, b_slack)

    def polytope(self, box: _Box, seeds_t: Tensor) -> Polytope:
        dev = self.scene.means.device
        kept = torch.cat(self.ids) if self.ids else torch.zeros(0, dtype=torch.long, device=dev)  # [F - 6]
        return box.polytope(self.n, self.b, kept, seeds_t, empty=self.stopped)


def _near_box(seeds: np.ndarray, seeds_t: Tensor, box: _Box, near_fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """(A [12, 3], b [12]): the box cut to a tube of half-width rho around the seed set, rho = near_fraction x the
    seeds' distance to the box (an oriented box around a seed segment, an axis-aligned one around other seeds)."""
    seeds_box = seeds_t if box.rot is None else seeds_t @ box.rot
    rho = near_fraction * float(torch.minimum(seeds_box - box.lo, box.hi - seeds_box).min().clamp_min(1e-9))
    if seeds.shape[0] == 2:  # oriented box around the segment: [-rho, L + rho] x [-rho, rho]^2
        frame = segment_frame_np(seeds[0], seeds[1])  # [3, 3] columns u, v, w
        proj = seeds @ frame  # [2, 3]
        t_lo, t_hi = proj.min(0) - rho, proj.max(0) + rho
    else:
        frame = np.eye(3)
        t_lo, t_hi = seeds.min(0) - rho, seeds.max(0) + rho
    return np.vstack([box.A, frame.T, -frame.T]), np.concatenate([box.b, t_hi, -t_lo])


def _proven_empty(planes: _PlaneSet, box: _Box, rho: float) -> bool:
    """The box and the kept planes hold no ball of radius rho (Chebyshev radius, HiGHS; float64 reference of
    native/polytope.c cn_planes_empty)."""
    if not planes.n:
        return False
    return not chebyshev_center(np.vstack([box.A] + planes.n), np.concatenate([box.b] + planes.b))[1] >= rho


def _add_two_pass(planes: _PlaneSet, scene, index, box: _Box, seeds_t: Tensor) -> None:
    """Pass 1: the ellipsoids near the seeds (``_near_box``) give the planes that bound the polytope in practice.
    Pass 2: only ellipsoids in index cells that are not entirely beyond one of those planes (or the box) can still
    meet the polytope; all others are excluded by planes that are kept, so the result is as safe as deciding every
    ellipsoid of the box (see query_box_in_planes). stop_when_empty: first a probe (pass 0) in a near box
    EMPTY_PROBE_FRACTION x smaller whose planes are kept only when they prove the polytope empty (as
    native/polytope.c)."""
    rho = planes.opts.stop_when_empty
    if rho is not None:
        probe = _PlaneSet(planes.seeds, scene, planes.opts)
        near0 = _near_box(planes.seeds, seeds_t, box, planes.opts.near_fraction * EMPTY_PROBE_FRACTION)
        probe.add(*candidates_near(scene, index, box.lo, box.hi, box.rot, planes=near0))
        if _proven_empty(probe, box, rho):
            planes.n, planes.b, planes.ids, planes.stopped = probe.n, probe.b, probe.ids, True
            return
    near = _near_box(planes.seeds, seeds_t, box, planes.opts.near_fraction)
    ids0, mu0, am0 = candidates_near(scene, index, box.lo, box.hi, box.rot, planes=near)
    planes.add(ids0, mu0, am0)
    kept = (np.vstack([box.A] + planes.n), np.concatenate([box.b] + planes.b))
    if rho is not None and _proven_empty(planes, box, rho):
        planes.stopped = True  # no ball of radius rho fits already: more planes keep it so
        return
    ids1, mu1, am1 = candidates_near(scene, index, box.lo, box.hi, box.rot, planes=kept)
    if ids0.numel() and ids1.numel():
        new1 = ~torch.isin(ids1, ids0)
        new1_np = new1.cpu().numpy()
        ids1, mu1, am1 = ids1[new1], mu1[new1_np], am1[new1_np]
    planes.add(ids1, mu1, am1)


AABB_FACES = np.vstack([np.eye(3), -np.eye(3)])  # [6, 3] an axis-aligned box's faces, the first planes


def _box_fits(seeds: np.ndarray, lo, hi, inside: bool) -> bool:
    """aabb_polytope's fast-path test for seeds [S, 3] and a box lo, hi [3] (numpy): all finite, hi > lo, and (inside)
    every seed in [lo, hi]; on Python floats (~2 us; eight numpy reductions took ~10). False for other shapes."""
    if not (isinstance(lo, np.ndarray) and isinstance(hi, np.ndarray) and lo.shape == hi.shape == (3,)):
        return False
    lo_l, hi_l, pts = lo.tolist(), hi.tolist(), seeds.tolist()
    isf = math.isfinite
    if not all(isf(a) and isf(b) and a < b for a, b in zip(lo_l, hi_l)):
        return False
    if not all(isf(v) for p in pts for v in p):
        return False
    return not inside or all(a <= v <= b for p in pts for v, a, b in zip(p, lo_l, hi_l))


def aabb_polytope(seeds: np.ndarray, scene, index, box_lo: np.ndarray, box_hi: np.ndarray, *,
                  options: Optional[PolytopeOptions] = None, **option_fields) -> Polytope:
    """safe_polytope(seeds, scene, index, box_lo, box_hi, ...) for float64 numpy seeds [S, 3] (a corridor segment,
    S = 2, or a goal, S = 1) in an axis-aligned box (float64 numpy [3] each): the same polytope, the same errors.
    Where the compiled path applies, a few numpy checks (finite seeds inside a finite box) are all the Python it runs:
    safe_polytope's general input handling took half as long as the compiled polytope itself on short segments."""
    opts = resolved_options(options, option_fields)
    from ..native import safe_polytope_c

    lo, hi = box_lo, box_hi
    fn = safe_polytope_c() if opts.backend == "auto" and opts.prune and native_applies(scene, index) else None
    if fn is None or seeds.shape not in ((1, 3), (2, 3)) or seeds.dtype != np.float64 or not _box_fits(
            seeds, lo, hi, opts.require_seed_inside):
        return safe_polytope(seeds, scene, index, lo, hi, options=opts)  # its checks and messages, or other paths
    r = float(scene.camera_radius)
    shrink = -1.0 if opts.stop_when_empty is None else float(opts.stop_when_empty)
    n, b, ids, bad_ids, bad_slack, stopped = native_safe_polytope(
        fn, scene, index, seeds, lo, hi, None, r, opts.margin, opts.normal, opts.require_seed_inside,
        opts.near_fraction if opts.two_pass else 0.0, shrink)
    if bad_slack.size:
        raise _seed_not_free(seeds, r, torch.from_numpy(bad_ids), bad_slack)
    A, off = [AABB_FACES, n], [hi, -lo, b]
    if stopped:  # _Box.polytope's explicit contradiction: first axis <= lo - (hi - lo)
        A.append(AABB_FACES[:1])
        off.append(np.array([lo[0] - (hi[0] - lo[0])]))
        ids = np.concatenate([ids, [-1]])
    return Polytope.from_numpy(np.concatenate(A), np.concatenate(off), torch.from_numpy(seeds), torch.from_numpy(ids))


# ---------------------------------------------------------------------------------------- main
def safe_polytope(
    seed_points: ArrayLike,
    scene,
    index=None,
    box_lo: Optional[ArrayLike] = None,
    box_hi: Optional[ArrayLike] = None,
    *,
    box_rotation: Optional[ArrayLike] = None,
    options: Optional[PolytopeOptions] = None,
    **option_fields,
) -> Polytope:
    """Safe polytope around seed points [S, 3] inside the box [box_lo, box_hi].

    Every point of the returned polytope, used as a camera centre, keeps the camera ball
    (scene.camera_radius) at distance >= ``margin`` outside every ellipsoid of the scene (exact, see
    module docstring) and lies in the box. All seed points are inside (else SeedNotFreeError when
    ``require_seed_inside``; with False the polytope is returned anyway and may exclude them or be
    empty, which ``closest_safe_point`` uses). Planes are float64 on the scene's device.

    box_rotation: optional orthonormal [3, 3] whose columns are the box axes; the box is then
    {x : box_lo <= box_rotation^T x <= box_hi} (an oriented box, e.g. aligned with a segment).
    options: PolytopeOptions (margin, normal rule, pruning, two passes, backend); ``option_fields`` set single
    fields by name on top of it (``margin=1e-3`` is short for ``options=PolytopeOptions(margin=1e-3)``).
    """
    opts = resolved_options(options, option_fields)
    dev = scene.means.device
    seeds_t = _checked_seeds(seed_points, dev)  # [S, 3]
    box = _checked_box(box_lo, box_hi, box_rotation, seeds_t, opts.require_seed_inside)
    from ..native import choose, safe_polytope_c

    fn = choose(opts.backend, safe_polytope_c, "polytope", "safe polytope",
                applies=opts.prune and seeds_t.shape[0] in (1, 2) and native_applies(scene, index),
                needs="a CPU scene, a GridIndex on the CPU, prune and one or two seeds")
    if fn is not None:
        return _native_polytope(fn, scene, index, seeds_t, box, opts)
    planes = _PlaneSet(f64_numpy(seeds_t), scene, opts)
    if index is not None and opts.prune and opts.two_pass and hasattr(index, "query_box_in_planes"):
        _add_two_pass(planes, scene, index, box, seeds_t)
    else:
        planes.add(*candidates_near(scene, index, box.lo, box.hi, box.rot))
    planes.check_seeds()
    return planes.polytope(box, seeds_t)
