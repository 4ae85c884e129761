"""Corridor-stage micro-benchmark (polytopes along a shortcut A* path) on a synthetic 200k-Gaussian scene.

Self-contained: it brings its own bucket index and conservative AABB occupancy grid so it runs before
the real spatial_index / occupancy modules are wired in. Prints medians; the lead records results.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_corridor.py [--n 200000] [--queries 20]
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from cinenerf_ns.planner.astar import AStarGrid, astar, shortcut
from cinenerf_ns.planner.corridor import build_corridor
from cinenerf_ns.planner.goal import closest_safe_point, sample_free_starts
from cinenerf_ns.planner.scene import EllipsoidScene


def surface_scene(n: int, seed: int = 0) -> EllipsoidScene:
    """Gaussians on the surfaces of a room (walls/floor/ceiling of [-1,1]^3) and 25 spheres/boxes."""
    g = torch.Generator().manual_seed(seed)
    n_room = n // 3
    face = torch.randint(0, 6, (n_room,), generator=g)
    p = torch.rand(n_room, 3, generator=g) * 2 - 1
    ax = face // 2
    p[torch.arange(n_room), ax] = torch.where(face % 2 == 0, -1.0, 1.0)
    n_obj = n - n_room
    c = torch.rand(25, 3, generator=g) * 1.4 - 0.7
    rad = torch.rand(25, generator=g) * 0.12 + 0.05
    k = torch.randint(0, 25, (n_obj,), generator=g)
    d = torch.randn(n_obj, 3, generator=g)
    d = d / d.norm(dim=-1, keepdim=True)
    q = c[k] + rad[k, None] * d
    means = torch.cat([p, q])
    quats = torch.randn(n, 4, generator=g)
    log_scales = torch.log(torch.rand(n, 3, generator=g) * 0.008 + 0.002)
    return EllipsoidScene.from_splat(means, quats, log_scales, torch.full((n,), 3.0))


class BucketIndex:
    """Uniform-grid buckets over ellipsoid AABBs (query_box contract of spatial_index.GridIndex)."""

    def __init__(self, scene: EllipsoidScene, cell: float = 0.05):
        lo, hi = scene.aabb()
        self.origin = scene.bounds()[0] - 1e-6
        self.cell = cell
        clo = ((lo - self.origin) / cell).floor().long()
        chi = ((hi - self.origin) / cell).floor().long()
        self.dims = (chi.max(0).values + 1).tolist()
        span = (chi - clo).max().item() + 1
        ids, cells = [], []
        for di in range(span):
            for dj in range(span):
                for dk in range(span):
                    c = clo + torch.tensor([di, dj, dk])
                    ok = (c <= chi).all(-1)
                    ids.append(torch.nonzero(ok).squeeze(-1))
                    cc = c[ok]
                    cells.append((cc[:, 0] * self.dims[1] + cc[:, 1]) * self.dims[2] + cc[:, 2])
        ids, cells = torch.cat(ids), torch.cat(cells)
        order = torch.argsort(cells)
        self.ids, cells = ids[order], cells[order]
        ncell = self.dims[0] * self.dims[1] * self.dims[2]
        self.start = torch.searchsorted(cells, torch.arange(ncell + 1))
        self.lo, self.hi = lo, hi

    def query_box(self, lo, hi):
        lo_c = ((lo.float() - self.origin) / self.cell).floor().long().clamp_min(0)
        hi_c = ((hi.float() - self.origin) / self.cell).floor().long()
        hi_c = torch.minimum(hi_c, torch.tensor(self.dims) - 1)
        if (hi_c < lo_c).any():
            return torch.zeros(0, dtype=torch.long)
        ii, jj, kk = torch.meshgrid(*[torch.arange(a, b + 1) for a, b in zip(lo_c.tolist(), hi_c.tolist())], indexing="ij")
        cells = ((ii * self.dims[1] + jj) * self.dims[2] + kk).reshape(-1)
        s, e = self.start[cells], self.start[cells + 1]
        idx = torch.repeat_interleave(s, e - s) + (torch.arange(int((e - s).sum())) - torch.repeat_interleave(torch.cumsum(e - s, 0) - (e - s), e - s))
        return torch.unique(self.ids[idx])


class AabbGrid:
    """Conservative occupancy: voxel occupied if it meets some inflated ellipsoid AABB."""

    def __init__(self, scene: EllipsoidScene, res: int = 100):
        self.lo = scene.bounds()[0].double() - 0.05
        hi = scene.bounds()[1].double() + 0.05
        self.voxel_size = float((hi - self.lo).max() / res)
        lo, hi = scene.aabb(pad=scene.camera_radius)
        a = ((lo.double() - self.lo) / self.voxel_size).floor().long().clamp(0, res - 1)
        b = ((hi.double() - self.lo) / self.voxel_size).floor().long().clamp(0, res - 1)
        occ = torch.zeros(res, res, res, dtype=torch.bool)
        span = int((b - a).max()) + 1
        for di in range(span):
            for dj in range(span):
                for dk in range(span):
                    c = a + torch.tensor([di, dj, dk])
                    ok = (c <= b).all(-1)
                    occ[c[ok, 0], c[ok, 1], c[ok, 2]] = True
        self.occupied = occ.numpy()

    def voxel_to_world(self, ijk):
        return self.lo + (torch.as_tensor(ijk, dtype=torch.float64) + 0.5) * self.voxel_size

    def world_to_voxel(self, x):
        return ((torch.as_tensor(x, dtype=torch.float64) - self.lo) / self.voxel_size).floor().long()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=200_000)
    ap.add_argument("--queries", type=int, default=20)
    ap.add_argument("--res", type=int, default=100)
    ap.add_argument("--box-margin", type=float, default=0.1)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--box", default="aabb", choices=["aabb", "oriented"])
    ap.add_argument("--astar-weight", type=float, default=1.0, help="1: optimal A*; >1: weighted A*")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    t = time.perf_counter()
    scene = surface_scene(args.n)
    index = BucketIndex(scene)
    grid = AabbGrid(scene, args.res)
    ag = AStarGrid(grid.occupied)
    _ = ag.labels
    print(f"scene {len(scene)} ellipsoids; prep (index+grid+components) {time.perf_counter() - t:.2f} s; "
          f"grid {grid.occupied.shape} occupied {grid.occupied.mean():.3f}")

    starts = sample_free_starts(2 * args.queries, scene, index, grid, generator=0, region_lo=[-0.9] * 3, region_hi=[0.9] * 3)
    rows = []
    for q in range(args.queries):
        s, g = starts[2 * q], starts[2 * q + 1]
        t0 = time.perf_counter()
        try:
            path = astar(ag, grid.world_to_voxel(s).tolist(), grid.world_to_voxel(g).tolist(), heuristic_weight=args.astar_weight)
        except Exception as e:  # noqa: BLE001
            print("astar:", e)
            continue
        t1 = time.perf_counter()
        pts = grid.voxel_to_world(path)
        occ = torch.as_tensor(grid.occupied)

        def seg_free(p0, p1):  # voxel-sampled segment test (benchmark only, not conservative)
            ts = torch.linspace(0, 1, 64, dtype=torch.float64)[None, :, None]
            x = p0[:, None] + ts * (p1 - p0)[:, None]
            v = grid.world_to_voxel(x).clamp(0, occ.shape[0] - 1)
            return ~occ[v[..., 0], v[..., 1], v[..., 2]].any(-1)

        short = shortcut(pts, seg_free)
        short = torch.cat([s[None], short[1:-1], g[None]])
        t2 = time.perf_counter()
        c2 = time.process_time()
        try:
            cor = build_corridor(short, scene, index, args.box_margin, box=args.box)
        except Exception as e:  # noqa: BLE001
            print("corridor:", e)
            continue
        t3 = time.perf_counter()
        c3 = time.process_time()
        rows.append((t1 - t0, t2 - t1, t3 - t2, len(cor), float(np.mean(cor.num_faces)), cor.n_splits, c3 - c2))
    a = np.asarray(rows)
    print(f"{len(rows)}/{args.queries} queries ok")
    for name, col in (("astar ms", 0), ("shortcut ms", 1), ("corridor ms", 2), ("corridor cpu", 6)):
        print(f"{name:12s} median {np.median(a[:, col]) * 1e3:7.2f}  p95 {np.percentile(a[:, col], 95) * 1e3:7.2f}")
    print(f"segments median {np.median(a[:, 3]):.0f} (max {a[:, 3].max():.0f}); faces/polytope mean {a[:, 4].mean():.1f}; "
          f"splits total {int(a[:, 5].sum())}")
    per_seg = a[:, 2] / a[:, 3]
    print(f"corridor ms per segment median {np.median(per_seg) * 1e3:.2f} (cpu {np.median(a[:, 6] / a[:, 3]) * 1e3:.2f})")
    closest_safe_point(scene.means[0].double(), scene, index, grid)  # warm-up (scipy/clarabel imports)
    ts = []
    for q in range(20):
        t = time.perf_counter()
        closest_safe_point(scene.means[q * 1000 + 7].double(), scene, index, grid)
        ts.append(time.perf_counter() - t)
    print(f"closest_safe_point (targets = Gaussian means) ms median {np.median(ts) * 1e3:.2f} max {max(ts) * 1e3:.2f}")


if __name__ == "__main__":
    main()
