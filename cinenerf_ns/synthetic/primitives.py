"""Analytic primitives of the synthetic room: exact signed distance, ray intersection, volume, sampling.

Three primitives, all axis-aligned (the room is built from them, so ground truth stays exact):

* ``box``      centre c[3], half-extents h[3]
* ``sphere``   centre c[3], radius r
* ``cylinder`` centre c[3] (mid-height), radius r, half-height hh, axis = world +z (capped)

Every function is vectorised over points / rays and over primitives of one kind
(params stacked as tensors), and works in the dtype it is given (float64 for references/tests,
float32 for rendering).
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

KINDS = ("box", "sphere", "cylinder")


# ----------------------------------------------------------------------------------------------
# Signed distance (exact). Points [P,3], params [S,...] -> [P,S]
# ----------------------------------------------------------------------------------------------
def sdf_box(points: Tensor, centres: Tensor, half: Tensor) -> Tensor:
    """Exact signed distance from points [P,3] to axis-aligned boxes (centres [S,3], half [S,3]) -> [P,S]."""
    q = (points[:, None, :] - centres[None]).abs() - half[None]  # [P,S,3]
    outside = q.clamp(min=0).norm(dim=-1)  # [P,S]
    inside = q.max(dim=-1).values.clamp(max=0)  # [P,S]
    return outside + inside


def sdf_sphere(points: Tensor, centres: Tensor, radii: Tensor) -> Tensor:
    """Exact signed distance to spheres (centres [S,3], radii [S]) -> [P,S]."""
    return (points[:, None, :] - centres[None]).norm(dim=-1) - radii[None]


def sdf_cylinder(points: Tensor, centres: Tensor, radii: Tensor, half_heights: Tensor) -> Tensor:
    """Exact signed distance to capped z-axis cylinders (centres [S,3], radii [S], half_heights [S]) -> [P,S]."""
    rel = points[:, None, :] - centres[None]  # [P,S,3]
    d_rad = rel[..., :2].norm(dim=-1) - radii[None]  # [P,S]
    d_ax = rel[..., 2].abs() - half_heights[None]  # [P,S]
    d = torch.stack([d_rad, d_ax], dim=-1)  # [P,S,2]
    return d.max(dim=-1).values.clamp(max=0) + d.clamp(min=0).norm(dim=-1)


# ----------------------------------------------------------------------------------------------
# Ray intersection. Origins [R,3], unit directions [R,3] -> t [R,S] (inf = miss), normals via helper.
# Only hits with t > t_min count (rays start outside every solid in our use: cameras are in free space).
# ----------------------------------------------------------------------------------------------
def _safe_inv(d: Tensor) -> Tensor:
    # Avoid 0/0 in the slab test: a zero component becomes a tiny signed value (ray parallel to slab).
    tiny = torch.finfo(d.dtype).tiny ** 0.5
    d = torch.where(d.abs() < tiny, torch.where(d < 0, -tiny, tiny) * torch.ones_like(d), d)
    return 1.0 / d


def ray_box(origins: Tensor, dirs: Tensor, centres: Tensor, half: Tensor, t_min: float = 1e-6):
    """Slab test. Returns (t [R,S], axis [R,S] long of the entry face). t = inf on miss."""
    inv = _safe_inv(dirs)[:, None, :]  # [R,1,3]
    lo = centres - half  # [S,3]
    hi = centres + half
    t1 = (lo[None] - origins[:, None, :]) * inv  # [R,S,3]
    t2 = (hi[None] - origins[:, None, :]) * inv
    tnear_ax = torch.minimum(t1, t2)
    tfar = torch.maximum(t1, t2).min(dim=-1).values  # [R,S]
    tnear, axis = tnear_ax.max(dim=-1)  # [R,S]
    hit = (tfar >= tnear) & (tnear > t_min)
    inf = torch.full_like(tnear, math.inf)
    return torch.where(hit, tnear, inf), axis


def ray_sphere(origins: Tensor, dirs: Tensor, centres: Tensor, radii: Tensor, t_min: float = 1e-6) -> Tensor:
    """Nearest entry t [R,S] of unit-direction rays into spheres (inf on miss)."""
    oc = origins[:, None, :] - centres[None]  # [R,S,3]
    b = (oc * dirs[:, None, :]).sum(-1)  # [R,S]
    c = (oc * oc).sum(-1) - radii[None] ** 2
    disc = b * b - c
    sq = disc.clamp(min=0).sqrt()
    t0 = -b - sq
    t1 = -b + sq
    t = torch.where(t0 > t_min, t0, t1)
    ok = (disc >= 0) & (t > t_min)
    return torch.where(ok, t, torch.full_like(t, math.inf))


def ray_cylinder(
    origins: Tensor, dirs: Tensor, centres: Tensor, radii: Tensor, half_heights: Tensor, t_min: float = 1e-6
):
    """Nearest hit t [R,S] with capped z-axis cylinders, and whether it is on a cap (bool [R,S])."""
    oc = origins[:, None, :] - centres[None]  # [R,S,3]
    d = dirs[:, None, :].expand_as(oc)
    inf = torch.full(oc.shape[:2], math.inf, dtype=oc.dtype, device=oc.device)
    # side: |o_xy + t d_xy| = r
    a = (d[..., :2] ** 2).sum(-1)
    b = (oc[..., :2] * d[..., :2]).sum(-1)
    c = (oc[..., :2] ** 2).sum(-1) - radii[None] ** 2
    disc = b * b - a * c
    sq = disc.clamp(min=0).sqrt()
    a_safe = torch.where(a > 1e-12, a, torch.ones_like(a))
    best = inf
    for sgn in (-1.0, 1.0):
        ts = (-b + sgn * sq) / a_safe
        z = oc[..., 2] + ts * d[..., 2]
        ok = (disc >= 0) & (a > 1e-12) & (ts > t_min) & (z.abs() <= half_heights[None])
        best = torch.minimum(best, torch.where(ok, ts, inf))
    side_t = best
    # caps: z = +-hh
    dz = d[..., 2]
    dz_safe = torch.where(dz.abs() > 1e-12, dz, torch.ones_like(dz))
    cap_best = inf
    for sgn in (-1.0, 1.0):
        tc = (sgn * half_heights[None] - oc[..., 2]) / dz_safe
        xy = oc[..., :2] + tc[..., None] * d[..., :2]
        ok = (dz.abs() > 1e-12) & (tc > t_min) & ((xy**2).sum(-1) <= radii[None] ** 2)
        cap_best = torch.minimum(cap_best, torch.where(ok, tc, inf))
    on_cap = cap_best < side_t
    return torch.minimum(side_t, cap_best), on_cap


# ----------------------------------------------------------------------------------------------
# Volumes and uniform samples inside (for object centroids and IoU ground truth)
# ----------------------------------------------------------------------------------------------
def volume(kind: str, params: dict) -> float:
    if kind == "box":
        h = params["half"]
        return 8.0 * h[0] * h[1] * h[2]
    if kind == "sphere":
        return 4.0 / 3.0 * math.pi * params["radius"] ** 3
    if kind == "cylinder":
        return math.pi * params["radius"] ** 2 * 2.0 * params["half_height"]
    raise ValueError(f"unknown primitive kind {kind!r}; expected one of {KINDS}")


def sample_inside(kind: str, params: dict, n: int, generator: torch.Generator) -> Tensor:
    """n points [n,3] (float64) uniformly distributed inside one primitive."""
    c = torch.tensor(params["centre"], dtype=torch.float64)
    u = torch.rand(n, 3, generator=generator, dtype=torch.float64)
    if kind == "box":
        h = torch.tensor(params["half"], dtype=torch.float64)
        return c + (2 * u - 1) * h
    if kind == "sphere":
        v = torch.randn(n, 3, generator=generator, dtype=torch.float64)
        v = v / v.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        return c + v * params["radius"] * u[:, :1] ** (1.0 / 3.0)
    if kind == "cylinder":
        rad = params["radius"] * u[:, 0].sqrt()
        ang = 2 * math.pi * u[:, 1]
        z = (2 * u[:, 2] - 1) * params["half_height"]
        return c + torch.stack([rad * torch.cos(ang), rad * torch.sin(ang), z], dim=-1)
    raise ValueError(f"unknown primitive kind {kind!r}; expected one of {KINDS}")


def aabb(kind: str, params: dict) -> tuple[list[float], list[float]]:
    c = params["centre"]
    if kind == "box":
        h = params["half"]
    elif kind == "sphere":
        h = [params["radius"]] * 3
    elif kind == "cylinder":
        h = [params["radius"], params["radius"], params["half_height"]]
    else:
        raise ValueError(f"unknown primitive kind {kind!r}; expected one of {KINDS}")
    return [c[i] - h[i] for i in range(3)], [c[i] + h[i] for i in range(3)]
