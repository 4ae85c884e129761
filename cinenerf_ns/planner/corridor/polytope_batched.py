"""Safe polytopes for all segments of a path in one batched computation (paper Prop. 2).

``safe_polytope`` (polytope.py) builds one polytope at a time on the host, a few hundred small numpy
calls each. Here the polytopes of M seed segments are built together with torch (CPU or CUDA tensors,
float64 for all plane math), so a GPU does the per-(segment, ellipsoid) work in a few big kernels:

1. candidate pairs (segment m, ellipsoid j) for all boxes at once: the index's ``query_boxes`` (padded
   AABB meets the box grown by the camera radius) then the bounding-sphere filter of ``_candidates``;
2. every pair gets the distance lower-bound key of ``safe_polytope`` (segment-to-mean distance minus the
   largest semi-axis) and the pairs are sorted by (segment, key);
3. rounds: per segment, its ``chunk`` nearest undecided pairs get their best-slack plane (the three
   normal rules of ``_planes_at`` at the same reference point, ported to torch), planes are kept
   nearest-first unless the ellipsoid already lies beyond a kept plane of the chunk (exact support
   test, as in ``safe_polytope``), and every other undecided pair of that segment lying entirely beyond
   one of the new planes is decided (bounding sphere first, then the exact support test). Repeat until
   no segment has undecided pairs.

Safety does not depend on the normals nor on the order (polytope.py's docstring): every kept plane is
n.x <= n.mu - ||diag(a) R^T n|| - r - margin with |n| = 1, which no camera ball centred on its side can
cross into E_j; an ellipsoid gets no plane only when it lies entirely beyond a kept plane of the same
polytope (exact support test), and the box excludes every ellipsoid that is not a candidate. So every
point of a returned polytope keeps the camera ball >= margin outside every ellipsoid of the scene.

A pair whose own best plane does not keep the whole seed segment (negative slack: the segment passes
within the camera radius, or grazes a flat ellipsoid where none of the normal rules separates it) gets
no plane; at the end it must lie beyond some kept plane of its segment, else the segment is flagged
``failed`` (the same rule as ``safe_polytope``'s SeedNotFreeError; because the kept planes can differ
from the host path's, a flag is not guaranteed to coincide with it). The caller builds those segments
with the host path (which splits them). Negative-slack rows are retried with the host code's extra
reference points (``polytope_planes.plane_candidates``, numpy) before they are declared bad: that retry is rare and
is a long sequential loop that a GPU would run launch by launch.

Only axis-aligned boxes (build_corridor's default ``box="aabb"``) are supported.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional, Tuple

import numpy as np
import torch
from torch import Tensor

from ..errors import InvalidInputError
from ..scene.spatial_index import GridIndex
from .polytope import NORMAL_RULES, Polytope
from .polytope_planes import body_normals, plane_candidates


def _k_sphere(w2: Tensor, lam: Tensor, kappa: float, s: Tensor) -> Tensor:
    """Corollary 1's K(s) = sum_i w_i^2 s(1-s) / (kappa + s (lambda_i - kappa)). w2, lam [C, 3]; s [C, T] -> [C, T]."""
    s3 = s[..., None]  # [C, T, 1]
    return (w2[:, None, :] * s3 * (1 - s3) / (kappa + s3 * (lam[:, None, :] - kappa))).sum(-1)


def _argmax_k(w2: Tensor, lam: Tensor, kappa: float, n_coarse: int = 64, n_fine: int = 33) -> Tensor:
    """s* = argmax_{s in (0,1)} K(s) [C] (K is concave): a coarse grid, then a fine grid over the best
    bracket (two kernels' worth of work instead of a golden-section loop: on a GPU the number of launches,
    not the arithmetic, is the cost). Accuracy ~2 / (65 * 32) in s; only the normal uses it, never the offset."""
    c = w2.shape[0]
    grid = torch.linspace(0.0, 1.0, n_coarse + 2, dtype=w2.dtype, device=w2.device)[1:-1]  # [T]
    vals = _k_sphere(w2, lam, kappa, grid.expand(c, n_coarse))  # [C, T]
    best = grid[vals.argmax(-1)]  # [C]
    step = float(grid[1] - grid[0])
    lo = (best - step).clamp_min(1e-9)
    hi = (best + step).clamp_max(1 - 1e-9)
    t = torch.linspace(0.0, 1.0, n_fine, dtype=w2.dtype, device=w2.device)  # [T2]
    fine = lo[:, None] + (hi - lo)[:, None] * t  # [C, T2]
    vals = _k_sphere(w2, lam, kappa, fine)
    return fine.gather(1, vals.argmax(-1, keepdim=True)).squeeze(1)


def _closest_t(w2: Tensor, lam: Tensor, iters: int = 8) -> Tensor:
    """t >= 0 with sum_i lambda_i w_i^2 / (lambda_i + t)^2 = 1 [C] (polytope_planes.closest_t in torch: Newton on the
    concave increasing phi(t) = (sum_i c_i / (lambda_i + t)^2)^(-1/2) from the left, monotone; ~8 steps reach
    ~1e-12). Only a normal rule uses it. Written with few ops per step: on a GPU each op is a kernel launch."""
    c = lam * w2  # [C, 3]
    t = ((lam.min(-1).values * w2.sum(-1)).sqrt() - lam.max(-1).values).clamp_min(0.0)  # [C] below the root
    for _ in range(iters):
        inv = 1.0 / (lam + t[:, None])  # [C, 3]
        q = c * inv * inv
        S = q.sum(-1).clamp_min(1e-300)  # [C]
        # Newton step (1 - phi) / phi' with phi = S^-1/2, phi' = S^-3/2 sum(q / den): (S^(3/2) - S) / sum(q / den);
        # phi >= 1 (S <= 1: at or past the root, or w = 0) takes no step
        step = (S * S.sqrt() - S) / (q * inv).sum(-1).clamp_min(1e-300)
        t = t + step.clamp_min(0.0)
    return t


def _exact_offsets(nw: Tensor, mu: Tensor, rot: Tensor, axes: Tensor, r: float, margin: float) -> Tuple[Tensor, Tensor]:
    """Unit world normals and exact offsets for normals nw [..., C, 3] of ellipsoids [C]:
    b = n.mu - ||diag(a) R^T n|| - r - margin (module docstring of polytope.py). Normalises n here (a float32
    rotation is not exactly orthonormal, so R nb is only nearly unit) and applies R^T to the unit n itself,
    so the offset is exact for the ellipsoid {mu + R diag(a) u : |u| <= 1} whatever R is."""
    nw = nw / nw.norm(dim=-1, keepdim=True).clamp_min(1e-300)
    nbody = torch.einsum("cji,...cj->...ci", rot, nw)  # R^T n  [..., C, 3]
    off = (nw * mu).sum(-1) - (axes * nbody).norm(dim=-1) - r - margin  # [..., C]
    return nw, off


def _planes_at(w: Tensor, p0: Tensor, p1: Tensor, mu: Tensor, rot: Tensor, axes: Tensor, r: float,
               normal: str, margin: float) -> Tuple[Tensor, Tensor, Tensor]:
    """Best-slack safe plane per row among the normal rules at body-frame reference points w [C, 3]
    (polytope_planes._planes_at in torch) -> (n [C, 3], b [C], slack [C]); slack = b - max(n.p0, n.p1)."""
    lam = axes * axes  # [C, 3]
    degenerate = (w * w).sum(-1) < 1e-24  # reference point at the centre: any direction is valid
    w = torch.where(degenerate[:, None], torch.tensor([0.0, 0.0, 1e-12], dtype=w.dtype, device=w.device), w)
    nb = torch.stack(body_normals(w, w * w, lam, r, normal, _argmax_k, _closest_t))  # [R, C, 3]
    nw = torch.einsum("cij,rcj->rci", rot, nb)  # world normals R nb  [R, C, 3]
    nw, off = _exact_offsets(nw, mu, rot, axes, r, margin)  # [R, C, 3], [R, C]
    slack = off - torch.maximum((nw * p0).sum(-1), (nw * p1).sum(-1))  # [R, C]
    best = slack.argmax(0, keepdim=True)  # [1, C]
    n = nw.gather(0, best[..., None].expand(1, -1, 3)).squeeze(0)
    return n, off.gather(0, best).squeeze(0), slack.gather(0, best).squeeze(0)


def _segment_planes(p0: Tensor, p1: Tensor, mu: Tensor, rot: Tensor, axes: Tensor, r: float, normal: str,
                    margin: float) -> Tuple[Tensor, Tensor, Tensor]:
    """Per row (seed segment p0, p1 [C, 3]; ellipsoid mu [C, 3], rot [C, 3, 3], axes [C, 3]) the best-slack
    plane at the segment point closest to mu in the ellipsoid metric (polytope_planes.plane_candidates' first
    step) -> (n [C, 3], b [C], slack [C])."""
    lam = axes * axes
    w0 = torch.einsum("cji,cj->ci", rot, p0 - mu)  # R^T (p0 - mu)  [C, 3]
    d = torch.einsum("cji,cj->ci", rot, p1 - p0)  # [C, 3]
    den = (d * d / lam).sum(-1)  # [C]
    u = (-(w0 * d / lam).sum(-1) / den.clamp_min(1e-300)).clamp(0.0, 1.0)
    u = torch.where(den > 0, u, torch.zeros_like(u))
    return _planes_at(w0 + u[:, None] * d, p0, p1, mu, rot, axes, r, normal, margin)


def _retry_on_host(rows: Tensor, p0: Tensor, p1: Tensor, mu: Tensor, rot: Tensor, axes: Tensor, seg: Tensor,
                   r: float, normal: str, margin: float) -> Tuple[Tensor, Tensor, Tensor]:
    """Negative-slack rows [B] (indices into the row tensors): the host path's full plane search
    (``polytope_planes.plane_candidates`` with its extra reference points), one call per segment; the returned
    normal's offset is recomputed exactly here. -> (n [B, 3], b [B], slack [B]) on the rows' device."""
    dev = mu.device
    seg_h = seg[rows].cpu().numpy()
    p0_h, p1_h = p0[rows].cpu().numpy(), p1[rows].cpu().numpy()
    mu_h, rot_h, axes_h = mu[rows].cpu().numpy(), rot[rows].cpu().numpy(), axes[rows].cpu().numpy()
    n_h = np.zeros((len(seg_h), 3))
    for m in np.unique(seg_h):
        j = np.flatnonzero(seg_h == m)
        seeds = np.stack([p0_h[j[0]], p1_h[j[0]]])  # [2, 3]
        n_h[j] = plane_candidates(seeds, mu_h[j], rot_h[j], axes_h[j], r, normal, margin)[0]
    n, b = _exact_offsets(torch.as_tensor(n_h, device=dev), mu[rows], rot[rows], axes[rows], r, margin)
    slack = b - torch.maximum((n * p0[rows]).sum(-1), (n * p1[rows]).sum(-1))
    return n, b, slack


def _support_gap(n: Tensor, mu: Tensor, rot: Tensor, axes: Tensor, r: float) -> Tensor:
    """min over E (+) B_r of n_f.x for ellipsoids [..., 3] and planes n [..., F, 3] -> [..., F]
    (mu [..., 3], rot [..., 3, 3], axes [..., 3]; leading dims broadcast)."""
    nbody = torch.einsum("...ji,...fj->...fi", rot, n)  # R^T n_f  [..., F, 3]
    return torch.einsum("...i,...fi->...f", mu, n) - (axes[..., None, :] * nbody).norm(dim=-1) - r


def candidate_pairs(scene, index, box_lo: Tensor, box_hi: Tensor) -> Tuple[Tensor, Tensor]:
    """(box_idx [P], g_idx [P]) sorted by box: a superset of the ellipsoids whose camera-inflated body
    meets each box (the index's AABB query, then the bounding-sphere test of polytope._candidates).
    index: a GridIndex (``query_boxes``), anything with ``query_box(lo, hi)``, or None (all ellipsoids)."""
    r = float(scene.camera_radius)
    dev = scene.means.device
    M, N = box_lo.shape[0], len(scene)
    if index is None:
        q = torch.arange(M, device=dev).repeat_interleave(N)
        g = torch.arange(N, device=dev).repeat(M)
    elif hasattr(index, "query_boxes"):
        # padded AABB (pad p) grown by r - p contains the inflated body when r > p (as in _candidates)
        e = max(r - float(getattr(index, "pad", 0.0)), 0.0) * (1 + 1e-9)
        kw = dict(method="auto") if isinstance(index, GridIndex) else {}  # "auto": a scan for big boxes
        q, g = index.query_boxes(box_lo - e, box_hi + e, **kw)
        q, g = q.to(dev), g.to(dev)
    else:
        ids = [torch.as_tensor(index.query_box(box_lo[m] - r, box_hi[m] + r), device=dev).long() for m in range(M)]
        q = torch.cat([torch.full_like(i, m) for m, i in enumerate(ids)])
        g = torch.cat(ids)
    mu = scene.means.index_select(0, g).to(torch.float64)  # [P, 3]
    amax = scene.radii.index_select(0, g).to(torch.float64).max(-1).values  # [P]
    lo, hi = box_lo.index_select(0, q), box_hi.index_select(0, q)
    gap = (mu - torch.minimum(torch.maximum(mu, lo), hi)).norm(dim=-1)  # mean-to-box distance
    near = gap <= amax * (1 + 1e-6) + r + 1e-6 * (1 + mu.abs().max(-1).values)
    return q[near], g[near]


def _checked_inputs(segments, box_lo, box_hi, normal: str, chunk: int, dev) -> Tuple[Tensor, Tensor, Tensor]:
    """(segments [M, 2, 3], box_lo [M, 3], box_hi [M, 3]) float64 on dev, checked (one host sync)."""
    seg = torch.as_tensor(segments, device=dev).to(torch.float64)
    if seg.ndim != 3 or seg.shape[1:] != (2, 3) or seg.shape[0] == 0:
        raise InvalidInputError(f"safe_polytopes_batched needs segments [M>=1, 2, 3], got {tuple(seg.shape)}")
    if box_lo is None or box_hi is None:
        raise InvalidInputError("safe_polytopes_batched needs boxes box_lo, box_hi [M, 3]")
    M = seg.shape[0]
    lo = torch.as_tensor(box_lo, device=dev).to(torch.float64).reshape(-1, 3)
    hi = torch.as_tensor(box_hi, device=dev).to(torch.float64).reshape(-1, 3)
    if lo.shape != (M, 3) or hi.shape != (M, 3):
        raise InvalidInputError(f"boxes must be [M={M}, 3], got {tuple(lo.shape)}, {tuple(hi.shape)}")
    ok = torch.isfinite(seg).all() & torch.isfinite(lo).all() & torch.isfinite(hi).all() & (hi > lo).all()
    inside = ((seg >= lo[:, None] - 1e-12) & (seg <= hi[:, None] + 1e-12)).all()
    ok, inside = torch.stack([ok, inside]).tolist()  # one host sync
    if not ok:
        raise InvalidInputError("safe_polytopes_batched needs finite segments and boxes with lo < hi")
    if not inside:
        raise InvalidInputError("seed segments must lie inside their polytope boxes")
    if normal not in NORMAL_RULES:
        raise InvalidInputError(f"unknown normal rule {normal!r}")
    if chunk < 1:
        raise InvalidInputError(f"chunk must be >= 1, got {chunk}")
    return seg, lo, hi


@dataclass
class _Pairs:
    """Candidate (segment, ellipsoid) pairs sorted by (segment, distance lower bound), float64 geometry."""

    q: Tensor  # [P] segment
    g: Tensor  # [P] scene id
    mu: Tensor  # [P, 3]
    ax: Tensor  # [P, 3] semi-axes
    amax_s: Tensor  # [P] bounding-sphere radius (covers a float32 R's ~1e-7 stretch)
    amin: Tensor  # [P] lower bound of ||diag(a) R^T n|| (used only to skip exact tests)


def _sorted_pairs(scene, index, seg: Tensor, lo: Tensor, hi: Tensor) -> _Pairs:
    """Steps 1-2 of the module docstring: candidate pairs, sorted by (segment, distance lower bound)."""
    q, g = candidate_pairs(scene, index, lo, hi)  # [P], [P]
    mu = scene.means.index_select(0, g).to(torch.float64)  # [P, 3]
    ax = scene.radii.index_select(0, g).to(torch.float64)  # [P, 3]
    amax_s = ax.max(-1).values * (1 + 1e-6)  # [P]
    amin = ax.min(-1).values  # [P]
    p0, p1 = seg[:, 0].index_select(0, q), seg[:, 1].index_select(0, q)  # [P, 3]
    d = p1 - p0
    u = (((mu - p0) * d).sum(-1) / (d * d).sum(-1).clamp_min(1e-300)).clamp(0.0, 1.0)
    key = (p0 + u[:, None] * d - mu).norm(dim=-1) - ax.max(-1).values  # [P] as in safe_polytope
    order = torch.argsort(key, stable=True)
    order = order[torch.argsort(q[order], stable=True)]  # by segment, then by key
    return _Pairs(q[order], g[order], mu[order], ax[order], amax_s[order], amin[order])


def _chunk_planes(pairs: _Pairs, ch: Tensor, seg: Tensor, scene, r: float, normal: str, margin: float, st: dict):
    """Best-slack plane of every chunk pair ch [C] (step 3a), negative-slack rows retried on the host
    -> (means [C, 3], semi-axes [C, 3], rotations [C, 3, 3], n [C, 3], b [C], slack [C])."""
    cq = pairs.q[ch]
    rot = scene.rotations.index_select(0, pairs.g[ch]).to(torch.float64)  # [C, 3, 3]
    c_mu, c_ax = pairs.mu[ch], pairs.ax[ch]
    s0, s1 = seg[cq, 0], seg[cq, 1]  # [C, 3]
    n, b, slack = _segment_planes(s0, s1, c_mu, rot, c_ax, r, normal, margin)  # [C, 3], [C], [C]
    neg = torch.nonzero(slack < 0).squeeze(-1)
    st["retried"] += int(neg.numel())
    if neg.numel():  # rare: the host path's extra reference points for grazing segments
        n2, b2, sl2 = _retry_on_host(neg, s0, s1, c_mu, rot, c_ax, cq, r, normal, margin)
        better = sl2 > slack[neg]
        n[neg] = torch.where(better[:, None], n2, n[neg])
        b[neg] = torch.where(better, b2, b[neg])
        slack[neg] = torch.where(better, sl2, slack[neg])
    return c_mu, c_ax, rot, n, b, slack


def _dense(x: Tensor, slot: Tensor, M: int, k: int, fill) -> Tensor:
    """Rows x [C, ...] scattered to their slots of a dense [M, k, ...] layout, other slots ``fill``."""
    out = torch.full((M * k, *x.shape[1:]), fill, dtype=x.dtype, device=x.device)
    return out.index_copy_(0, slot, x).view(M, k, *x.shape[1:])


def _greedy_in_chunks(slot: Tensor, n, b, slack, good, mu, ax, rot, M: int, k: int, r: float) -> Tuple[Tensor, ...]:
    """Step 3b: nearest-plane-first greedy inside each segment's chunk, on a dense [M, k] layout (chunk rows at
    ``slot`` = segment * k + rank) -> (taken bool [M, k], normals [M, k, 3], offsets [M, k]; inf: no plane)."""
    dn = _dense(n, slot, M, k, 0.0)
    db = _dense(torch.where(good, b, torch.full_like(b, float("inf"))), slot, M, k, float("inf"))
    dmu, dax, drot = _dense(mu, slot, M, k, 0.0), _dense(ax, slot, M, k, 1.0), _dense(rot, slot, M, k, 0.0)
    # beyond[m, i, j]: ellipsoid i of segment m lies beyond plane j of segment m (exact support test;
    # planes that are not candidates have b = inf and never count)
    beyond = _support_gap(dn[:, None, :, :], dmu, drot, dax, r) >= db[:, None, :]  # [M, k, k]
    dsl, dgood = _dense(slack, slot, M, k, float("inf")), _dense(good, slot, M, k, False)
    beyond_h, dsl_h, dgood_h = beyond.cpu().numpy(), dsl.cpu().numpy(), dgood.cpu().numpy()
    taken_h = np.zeros((M, k), dtype=bool)
    order_h = np.argsort(dsl_h, axis=1, kind="stable")  # nearest plane first
    rows = np.arange(M)
    for t in range(k):
        i = order_h[:, t]
        hit = (beyond_h[rows, i, :] & taken_h).any(-1)
        taken_h[rows, i] = dgood_h[rows, i] & ~hit
    return torch.as_tensor(taken_h, device=n.device), dn, db


def _undecided(pairs: _Pairs, rest: Tensor, dn: Tensor, new_b: Tensor, scene, r: float, block: int,
               st: dict) -> Tensor:
    """Step 3c: the pairs of rest [R] NOT lying entirely beyond one of their segment's new planes (dn [M, k, 3],
    new_b [M, k], inf where none): bounding sphere first, the exact support test where it cannot decide."""
    keep_rest = []
    for s in range(0, rest.numel(), block):
        j = rest[s:s + block]  # [B]
        qj = pairs.q[j]
        nn, bb = dn[qj], new_b[qj]  # [B, k, 3], [B, k]
        proj = torch.einsum("bi,bki->bk", pairs.mu[j], nn)  # [B, k]
        cut = (proj - pairs.amax_s[j, None] - r >= bb).any(-1)  # sound: bounding sphere beyond => body beyond
        maybe = torch.nonzero(~cut & (proj - pairs.amin[j, None] - r >= bb).any(-1)).squeeze(-1)
        if maybe.numel():  # the exact support test only where the sphere test cannot decide
            jm = j[maybe]
            st["exact_tests"] += int(jm.numel())
            rm = scene.rotations.index_select(0, pairs.g[jm]).to(torch.float64)
            cut[maybe] = (_support_gap(nn[maybe], pairs.mu[jm], rm, pairs.ax[jm], r) >= bb[maybe]).any(-1)
        keep_rest.append(j[~cut])
    return torch.cat(keep_rest) if keep_rest else rest


def _decide_pairs(pairs: _Pairs, seg: Tensor, scene, r: float, normal: str, margin: float, k: int, block: int,
                  st: dict):
    """Step 3's rounds until no pair is undecided -> (kept planes: segment [T], normal [T, 3], offset [T], scene
    id [T]; bad pairs [Bp]: their own planes all cut their segment)."""
    q, g, mu = pairs.q, pairs.g, pairs.mu
    M, dev = seg.shape[0], seg.device
    # planes kept, per round (seeded with empty tensors: a path may need no plane at all)
    kept_seg, kept_g = [q[:0]], [g[:0]]
    kept_n, kept_b = [mu[:0]], [mu[:0, 0]]
    bad_pair = [q[:0]]  # pair indices whose own planes all cut their segment (decided at the end)
    ar_m = torch.arange(M, device=dev)
    alive = torch.arange(q.numel(), device=dev)  # [A] undecided pairs, still sorted by (segment, key)
    while alive.numel():
        st["alive"].append(int(alive.numel()))
        # ---- 3a. the k nearest undecided pairs of every segment: rank inside its segment's run
        qa = q[alive]
        starts = torch.searchsorted(qa, ar_m)  # [M] first undecided pair of each segment
        rank = torch.arange(alive.numel(), device=dev) - starts[qa]  # [A]
        in_chunk = rank < k
        ch, ch_rank = alive[in_chunk], rank[in_chunk]  # [C]
        rest = alive[~in_chunk]
        cq, cg = q[ch], g[ch]
        c_mu, c_ax, rot, n, b, slack = _chunk_planes(pairs, ch, seg, scene, r, normal, margin, st)
        good = slack >= 0  # [C] planes that keep the whole segment
        bad_pair.append(ch[~good])
        slot = cq * k + ch_rank  # [C]
        taken, dn, db = _greedy_in_chunks(slot, n, b, slack, good, c_mu, c_ax, rot, M, k, r)
        took = taken.view(-1)[slot]  # [C]
        kept_seg.append(cq[took]), kept_n.append(n[took]), kept_b.append(b[took]), kept_g.append(cg[took])
        new_b = torch.where(taken, db, torch.full_like(db, float("inf")))  # [M, k]
        alive = _undecided(pairs, rest, dn, new_b, scene, r, block, st)
    kept = torch.cat(kept_seg), torch.cat(kept_n), torch.cat(kept_b), torch.cat(kept_g)  # [T]...
    return kept, torch.cat(bad_pair)


def _failed_segments(pairs: _Pairs, bp: Tensor, kq: Tensor, kn: Tensor, kb: Tensor, scene, r: float, M: int) -> Tensor:
    """bool [M]: a bad pair of bp [Bp] that no kept plane (kq [T], kn [T, 3], kb [T]) of its segment cuts off."""
    failed = torch.zeros(M, dtype=torch.bool, device=pairs.q.device)
    if bp.numel():
        q = pairs.q
        same = q[bp][:, None] == kq[None, :]  # [Bp, T]
        rb = scene.rotations.index_select(0, pairs.g[bp]).to(torch.float64)
        gap = _support_gap(kn[None].expand(bp.numel(), -1, -1), pairs.mu[bp], rb, pairs.ax[bp], r)  # [Bp, T]
        uncut = ~((gap >= kb[None, :]) & same).any(-1)  # [Bp]
        failed[q[bp][uncut]] = True
    return failed


def _split_polytopes(kept, failed: Tensor, seg: Tensor, lo: Tensor, hi: Tensor,
                     out_device) -> List[Optional[Polytope]]:
    """Box planes then kept planes, split per segment (one transfer to out_device); None where failed [M] (CPU)."""
    kq, kn, kb, kg = kept
    M = seg.shape[0]
    srt = torch.argsort(kq, stable=True)
    counts = torch.bincount(kq, minlength=M).cpu().tolist()
    kn, kb, kg = kn[srt].to(out_device), kb[srt].to(out_device), kg[srt].to(out_device)
    seg_o, lo_o, hi_o = seg.to(out_device), lo.to(out_device), hi.to(out_device)
    eye = torch.eye(3, dtype=torch.float64, device=out_device)
    A_box = torch.cat([eye, -eye])  # [6, 3]
    polys: List[Optional[Polytope]] = []
    start = 0
    for m in range(M):
        c = counts[m]
        if failed[m]:
            polys.append(None)
        else:
            polys.append(Polytope(torch.cat([A_box, kn[start:start + c]]),
                                  torch.cat([hi_o[m], -lo_o[m], kb[start:start + c]]), seg_o[m], kg[start:start + c]))
        start += c
    return polys


def safe_polytopes_batched(
    segments,  # [M, 2, 3]
    scene,
    index=None,
    box_lo=None,  # [M, 3]
    box_hi=None,  # [M, 3]
    *,
    margin: float = 1e-6,
    normal: str = "auto",
    chunk: int = 32,
    block: int = 1 << 19,
    out_device: Optional[torch.device] = None,
    stats: Optional[dict] = None,
) -> Tuple[List[Optional[Polytope]], Tensor]:
    """Safe polytopes around M seed segments at once -> (polytopes [M], failed bool [M] on the CPU).

    Polytope m = box m ∩ one halfspace per ellipsoid that needs one; every point of it, as a camera
    centre, keeps the camera ball >= ``margin`` outside every ellipsoid of the scene, and it contains the
    whole segment m (module docstring). ``failed[m]``: no such polytope was found (some ellipsoid's own
    planes all cut the segment and no other kept plane cuts that ellipsoid off); then ``polytopes[m]`` is
    None and the caller must use the host path (``safe_polytope``, which raises SeedNotFreeError there,
    and the corridor's splitting). Planes are float64 on ``out_device`` (default: the scene's device).

    chunk: pairs per segment whose planes are computed per round (more: fewer rounds, i.e. fewer kernel
    launches and host syncs, but more planes computed that pruning would have made unnecessary).
    block: pairs per pruning block (bounds the memory of a [block, chunk, 3] float64 intermediate).
    stats: optional dict, filled with ``pairs`` (candidate pairs), ``alive`` (undecided pairs at the start of
    each round), ``exact_tests`` (pairs that needed the exact support test) and ``retried`` (negative-slack rows).
    """
    dev = scene.means.device
    out_device = dev if out_device is None else torch.device(out_device)
    seg, lo, hi = _checked_inputs(segments, box_lo, box_hi, normal, chunk, dev)
    r = float(scene.camera_radius)
    pairs = _sorted_pairs(scene, index, seg, lo, hi)
    st = stats if stats is not None else {}
    st.update(pairs=int(pairs.q.numel()), alive=[], exact_tests=0, retried=0)
    kept, bad_pairs = _decide_pairs(pairs, seg, scene, r, normal, margin, int(chunk), block, st)
    # bad pairs: fatal unless some kept plane of the same segment cuts them off
    failed = _failed_segments(pairs, bad_pairs, *kept[:3], scene, r, seg.shape[0]).cpu()
    return _split_polytopes(kept, failed, seg, lo, hi, out_device), failed
