"""Vectorised torch ray caster for the analytic room: colour (Lambert + ambient), label id, depth.

No shadows, no reflections: shading depends on the surface point only (view-independent), which a
degree-0 splat can represent exactly. Textures are procedural functions of the hit point so the
images carry features for training.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from cinenerf_ns.synthetic import primitives as prim
from cinenerf_ns.synthetic.room import BACKGROUND, Room

PATTERNS = ("plain", "stripes", "checker", "noise", "wood", "planks")
BACKGROUND_COLOUR = (0.6, 0.7, 0.9)


@dataclass
class Intrinsics:
    """Pinhole intrinsics (pixels). Principal point at the image centre by default."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_fov(cls, width: int, height: int, fov_x_deg: float) -> "Intrinsics":
        f = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2)
        return cls(width, height, f, f, width / 2.0, height / 2.0)


def camera_rays(c2w: Tensor, intr: Intrinsics, supersample: int = 1) -> tuple[Tensor, Tensor, Tensor]:
    """Rays through pixel (sub-)centres. c2w [3,4] or [4,4], OpenGL camera (x right, y up, looks -z).

    Returns origins [H*s, W*s, 3], unit directions [H*s, W*s, 3] and the camera-frame z-component
    factor cos [H*s, W*s] (z-depth = t * cos)."""
    s = supersample
    dt = c2w.dtype
    u = (torch.arange(intr.width * s, dtype=dt) + 0.5) / s  # pixel coords of sub-sample centres
    v = (torch.arange(intr.height * s, dtype=dt) + 0.5) / s
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    d_cam = torch.stack([(uu - intr.cx) / intr.fx, -(vv - intr.cy) / intr.fy, -torch.ones_like(uu)], dim=-1)
    norm = d_cam.norm(dim=-1, keepdim=True)
    d_cam = d_cam / norm
    R = c2w[:3, :3]
    dirs = d_cam @ R.T
    origins = c2w[:3, 3].expand_as(dirs)
    return origins, dirs, 1.0 / norm[..., 0]


class RoomRenderer:
    """Holds the room's parts as stacked tensors (one group per primitive kind) for fast casting."""

    def __init__(self, room: Room, dtype: torch.dtype = torch.float32, light: tuple[float, float, float] | None = None):
        self.room = room
        self.dtype = dtype
        self.groups = {}
        for kind in prim.KINDS:
            ids = [i for i, p in enumerate(room.parts) if p.kind == kind]
            if not ids:
                continue
            ps = [room.parts[i].params for i in ids]
            t = lambda key: torch.tensor([p[key] for p in ps], dtype=dtype)  # noqa: E731
            g = {"ids": torch.tensor(ids), "centre": t("centre")}
            if kind == "box":
                g["half"] = t("half")
            else:
                g["radius"] = t("radius")
            if kind == "cylinder":
                g["half_height"] = t("half_height")
            self.groups[kind] = g
        P = len(room.parts)
        self.labels = torch.tensor([p.label for p in room.parts] + [BACKGROUND], dtype=torch.long)
        self.colours = torch.tensor([p.colour for p in room.parts] + [BACKGROUND_COLOUR], dtype=dtype)
        self.pattern = torch.tensor([PATTERNS.index(p.pattern) for p in room.parts] + [0], dtype=torch.long)
        self.pscale = torch.tensor([p.pattern_scale for p in room.parts] + [1.0], dtype=dtype)
        self.paxis = torch.tensor([p.pattern_axis for p in room.parts] + [2], dtype=torch.long)
        self.centres = torch.tensor([p.params["centre"] for p in room.parts] + [[0.0, 0.0, 0.0]], dtype=dtype)
        gen = torch.Generator().manual_seed(1234)
        # per-part random noise directions/phases (3 octaves), seeded by the part's pattern_seed
        dirs, phases = [], []
        for p in room.parts + [None]:
            g = torch.Generator().manual_seed(p.pattern_seed if p is not None else 0)
            d = torch.randn(3, 3, generator=g, dtype=torch.float64)
            dirs.append(d / d.norm(dim=-1, keepdim=True))
            phases.append(torch.rand(3, generator=g, dtype=torch.float64) * 2 * math.pi)
        del gen
        self.noise_dirs = torch.stack(dirs).to(dtype)  # [P+1,3,3]
        self.noise_phase = torch.stack(phases).to(dtype)  # [P+1,3]
        self.background_index = P
        # bounding sphere of every part, for the conservative per-tile cone culling in `cast`
        bc, br = [], []
        for p in room.parts:
            lo_, hi_ = prim.aabb(p.kind, p.params)
            lo_, hi_ = torch.tensor(lo_, dtype=torch.float64), torch.tensor(hi_, dtype=torch.float64)
            bc.append((lo_ + hi_) / 2)
            br.append(float((hi_ - lo_).norm() / 2) * (1 + 1e-4) + 1e-6)
        self.bound_centre = torch.stack(bc).to(dtype)  # [P,3]
        self.bound_radius = torch.tensor(br, dtype=dtype)  # [P]
        lo, hi = room.interior_lo, room.interior_hi
        default_light = [(lo[0] + hi[0]) / 2 * 0.5, (lo[1] + hi[1]) / 2 * 0.5, hi[2] * 0.92]
        self.light = torch.tensor(light if light is not None else [float(x) for x in default_light], dtype=dtype)

    # ------------------------------------------------------------------ casting
    def cast_reference(self, origins: Tensor, dirs: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Brute force (every ray against every part). Nearest hit of rays [R,3] (unit dirs):
        t [R] (inf on miss), part index [R] (P on miss), normal [R,3]. Reference for `cast`."""
        R = origins.shape[0]
        best_t = torch.full((R,), math.inf, dtype=self.dtype)
        best_part = torch.full((R,), self.background_index, dtype=torch.long)
        normal = torch.zeros(R, 3, dtype=self.dtype)
        for kind, g in self.groups.items():
            if kind == "box":
                t, axis = prim.ray_box(origins, dirs, g["centre"], g["half"])
            elif kind == "sphere":
                t = prim.ray_sphere(origins, dirs, g["centre"], g["radius"])
            else:
                t, on_cap = prim.ray_cylinder(origins, dirs, g["centre"], g["radius"], g["half_height"])
            tk, k = t.min(dim=1)  # [R]
            better = tk < best_t
            if not bool(better.any()):
                continue
            idx = better.nonzero(as_tuple=True)[0]
            kk = k[idx]
            best_t[idx] = tk[idx]
            best_part[idx] = g["ids"][kk]
            hit = origins[idx] + tk[idx, None] * dirs[idx]
            c = g["centre"][kk]
            if kind == "box":
                ax = axis[idx, kk]
                n = torch.zeros(len(idx), 3, dtype=self.dtype)
                n[torch.arange(len(idx)), ax] = -torch.sign(dirs[idx, ax])
            elif kind == "sphere":
                n = hit - c
            else:
                cap = on_cap[idx, kk]
                side = torch.cat([(hit - c)[:, :2], torch.zeros(len(idx), 1, dtype=self.dtype)], dim=-1)
                capn = torch.zeros(len(idx), 3, dtype=self.dtype)
                capn[:, 2] = torch.sign(hit[:, 2] - c[:, 2])
                n = torch.where(cap[:, None], capn, side)
            normal[idx] = n / n.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        return best_t, best_part, normal


    def _part_t(self, i: int, origins: Tensor, dirs: Tensor) -> Tensor:
        """Hit distance [K] of rays with part i (inf on miss)."""
        p = self.room.parts[i]
        dt = self.dtype
        c = torch.tensor([p.params["centre"]], dtype=dt)
        if p.kind == "box":
            return prim.ray_box(origins, dirs, c, torch.tensor([p.params["half"]], dtype=dt))[0][:, 0]
        if p.kind == "sphere":
            return prim.ray_sphere(origins, dirs, c, torch.tensor([p.params["radius"]], dtype=dt))[:, 0]
        r = torch.tensor([p.params["radius"]], dtype=dt)
        hh = torch.tensor([p.params["half_height"]], dtype=dt)
        return prim.ray_cylinder(origins, dirs, c, r, hh)[0][:, 0]

    def normals_at(self, points: Tensor, part: Tensor) -> Tensor:
        """Outward unit normals [R,3] of parts [R] at surface points [R,3] (background rows: 0)."""
        n = torch.zeros_like(points)
        for kind in prim.KINDS:
            g = self.groups.get(kind)
            if g is None:
                continue
            lut = torch.full((self.background_index + 1,), -1, dtype=torch.long)
            lut[g["ids"]] = torch.arange(len(g["ids"]))
            k = lut[part]
            m = k >= 0
            if not bool(m.any()):
                continue
            kk = k[m]
            rel = points[m] - g["centre"][kk]
            if kind == "box":
                # the hit face is the one the point lies on: largest (|rel| - half) is ~0 there, < 0 elsewhere
                ax = ((rel.abs() - g["half"][kk])).argmax(dim=-1)
                nn = torch.zeros_like(rel)
                nn[torch.arange(len(kk)), ax] = torch.sign(rel[torch.arange(len(kk)), ax])
            elif kind == "sphere":
                nn = rel
            else:
                side = rel[:, :2].norm(dim=-1) - g["radius"][kk]
                cap = rel[:, 2].abs() - g["half_height"][kk]
                nn = torch.where(
                    (cap > side)[:, None],
                    torch.stack([torch.zeros_like(cap), torch.zeros_like(cap), torch.sign(rel[:, 2])], -1),
                    torch.cat([rel[:, :2], torch.zeros_like(cap)[:, None]], -1),
                )
            n[m] = nn / nn.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        return n

    def cast(self, origins: Tensor, dirs: Tensor, tile_id: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """Nearest hit of rays [R,3] (unit dirs): t [R] (inf on miss), part index [R] (P on miss), normal [R,3].

        Rays are grouped into tiles (tile_id [R]; one tile if None). A part is only tested against the
        rays of tiles whose bounding cone (apex at the tile's common origin) meets the part's bounding
        sphere: a conservative cull, so the result equals `cast_reference` (tested)."""
        R = origins.shape[0]
        dt = self.dtype
        if tile_id is None:
            tile_id = torch.zeros(R, dtype=torch.long)
        T = int(tile_id.max()) + 1 if R else 0
        best_t = torch.full((R,), math.inf, dtype=dt)
        best_part = torch.full((R,), self.background_index, dtype=torch.long)
        if R == 0:
            return best_t, best_part, torch.zeros(0, 3, dtype=dt)
        # tile cones: axis = normalised mean direction, half-angle from the widest ray. Done in float64
        # whatever the render dtype: acos near 1 loses ~sqrt(eps) rad in float32, more than the margin.
        d64, o64 = dirs.double(), origins.double()
        axis = torch.zeros(T, 3, dtype=torch.float64).index_add_(0, tile_id, d64)
        axis = axis / axis.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        cos_ray = (d64 * axis[tile_id]).sum(-1).clamp(-1, 1)
        min_cos = torch.full((T,), 1.0, dtype=torch.float64).scatter_reduce(0, tile_id, cos_ray, reduce="amin")
        half = torch.acos(min_cos)  # [T]
        apex = torch.zeros(T, 3, dtype=torch.float64).index_copy_(0, tile_id, o64)  # tiles share one origin
        spread = torch.zeros(T, dtype=torch.float64).scatter_reduce(
            0, tile_id, (o64 - apex[tile_id]).norm(dim=-1), reduce="amax")  # 0 for pinhole tiles
        v = self.bound_centre.double()[None] - apex[:, None]  # [T,P,3]
        dist = v.norm(dim=-1)  # [T,P]
        rad = self.bound_radius.double()[None] + spread[:, None]
        inside = dist <= rad
        ang = torch.acos(((v * axis[:, None]).sum(-1) / dist.clamp(min=1e-12)).clamp(-1, 1))
        alpha = torch.asin((rad / dist.clamp(min=1e-12)).clamp(max=1.0))
        cand = inside | (ang <= half[:, None] + alpha + 1e-6)  # [T,P]
        for i in range(self.background_index):
            rays = cand[:, i][tile_id].nonzero(as_tuple=True)[0]
            if rays.numel() == 0:
                continue
            t = self._part_t(i, origins[rays], dirs[rays])
            better = t < best_t[rays]
            sel = rays[better]
            best_t[sel] = t[better]
            best_part[sel] = i
        hit = torch.isfinite(best_t)
        pts = origins + torch.where(hit, best_t, torch.zeros_like(best_t))[:, None] * dirs
        normal = self.normals_at(pts, torch.where(hit, best_part, torch.full_like(best_part, self.background_index)))
        return best_t, best_part, normal

    # ------------------------------------------------------------------ shading
    def texture(self, part: Tensor, points: Tensor) -> Tensor:
        """Brightness modulation in [0.55, 1] [R] of each part's procedural pattern at points [R,3]."""
        local = points - self.centres[part]  # [R,3]
        s = self.pscale[part]
        pat = self.pattern[part]
        ax = self.paxis[part]
        coord = local.gather(1, ax[:, None])[:, 0]
        # noise: a sum of three oriented sine waves (smooth, seeded per part)
        proj = torch.einsum("rc,rkc->rk", local, self.noise_dirs[part]) / s[:, None]  # [R,3]
        freqs = torch.tensor([1.0, 2.3, 5.1], dtype=self.dtype)
        noise = (torch.sin(proj * freqs + self.noise_phase[part]) / freqs).sum(-1) / 1.6  # ~[-1,1]
        m = torch.ones_like(coord)
        m = torch.where(pat == 1, 0.5 + 0.5 * torch.tanh(3 * torch.sin(2 * math.pi * coord / s)), m)  # stripes
        chk = (torch.floor(local / s[:, None] + 1e-4).sum(-1).remainder(2))
        m = torch.where(pat == 2, 0.35 + 0.65 * chk, m)  # checker
        m = torch.where(pat == 3, 0.5 + 0.5 * noise, m)  # noise
        rings = local[:, :2].norm(dim=-1)
        m = torch.where(pat == 4, 0.5 + 0.5 * torch.sin(2 * math.pi * rings / s + 2.0 * noise), m)  # wood rings
        # planks: boards along `axis` with seams and grain noise
        board = torch.floor(coord / s)
        seam = ((coord / s - board) < 0.04).to(self.dtype)
        grain = 0.5 + 0.5 * torch.sin(board * 2.7 + 13 * noise)
        m = torch.where(pat == 5, (0.3 + 0.7 * grain) * (1 - 0.8 * seam), m)
        # a faint noise layer on every pattern: no perfectly flat patch, so every surface carries
        # photometric gradients in every direction (helps splat training)
        m = m.clamp(0, 1) * (0.85 + 0.15 * (0.5 + 0.5 * noise))
        return 0.55 + 0.45 * m

    def shade(self, t: Tensor, part: Tensor, normal: Tensor, origins: Tensor, dirs: Tensor) -> Tensor:
        """Linear RGB [R,3]: albedo * texture * (ambient + Lambert from a point light + fill light)."""
        hit_ok = torch.isfinite(t)
        tt = torch.where(hit_ok, t, torch.zeros_like(t))
        points = origins + tt[:, None] * dirs
        n = torch.where((normal * dirs).sum(-1, keepdim=True) > 0, -normal, normal)  # face the viewer
        to_light = self.light - points
        to_light = to_light / to_light.norm(dim=-1, keepdim=True).clamp(min=1e-9)
        fill = torch.tensor([0.3, 0.5, -0.81], dtype=self.dtype)
        fill = fill / fill.norm()
        lum = 0.35 + 0.55 * (n * to_light).sum(-1).clamp(min=0) + 0.2 * (n * -fill).sum(-1).clamp(min=0)
        albedo = self.colours[part] * self.texture(part, points)[:, None]
        rgb = albedo * lum[:, None]
        return torch.where(hit_ok[:, None], rgb, self.colours[part])

    # ------------------------------------------------------------------ full image
    @torch.no_grad()
    def render(self, c2w: Tensor, intr: Intrinsics, supersample: int = 1, chunk: int = 1 << 15) -> dict[str, Tensor]:
        """Render one view. c2w [3,4]/[4,4] OpenGL camera-to-world in room coordinates.

        Returns rgb [H,W,3] float in [0,1] (sRGB-encoded), label [H,W] long (centre sample),
        distance [H,W] (Euclidean ray length to the hit, inf on miss), depth [H,W] (camera z-depth)."""
        c2w = torch.as_tensor(c2w, dtype=self.dtype)
        o, d, cos = camera_rays(c2w, intr, supersample)
        Hs, Ws = d.shape[:2]
        o = o.reshape(-1, 3)
        d = d.reshape(-1, 3)
        tile = 16
        vv, uu = torch.meshgrid(torch.arange(Hs), torch.arange(Ws), indexing="ij")
        tile_id = ((vv // tile) * ((Ws + tile - 1) // tile) + uu // tile).reshape(-1)
        ts, parts, n = self.cast(o, d, tile_id)
        rgb = torch.empty(o.shape[0], 3, dtype=self.dtype)
        for a in range(0, o.shape[0], chunk):
            b = min(a + chunk, o.shape[0])
            rgb[a:b] = self.shade(ts[a:b], parts[a:b], n[a:b], o[a:b], d[a:b])
        s = supersample
        H, W = intr.height, intr.width
        rgb = rgb.reshape(H, s, W, s, 3).mean(dim=(1, 3))
        rgb = rgb.clamp(0, 1) ** (1 / 2.2)  # linear -> display gamma
        centre = s // 2  # sub-sample nearest the pixel centre carries label and depth
        ts = ts.reshape(H, s, W, s)[:, centre, :, centre]
        parts = parts.reshape(H, s, W, s)[:, centre, :, centre]
        cos = cos.reshape(H, s, W, s)[:, centre, :, centre]
        return {"rgb": rgb, "label": self.labels[parts], "distance": ts, "depth": ts * cos}


def render_view(room: Room, c2w: Tensor, intr: Intrinsics, supersample: int = 1) -> dict[str, Tensor]:
    """One-shot convenience wrapper around RoomRenderer.render."""
    return RoomRenderer(room).render(c2w, intr, supersample)
