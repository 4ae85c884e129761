"""Micro-benchmark of the planner geometry core (index, collision, clearance, occupancy).

    PYTHONPATH=. .venv/bin/python benchmarks/bench_geometry.py --n 200000 [--device cuda] [--threads 1]

Scene: a synthetic "room" of flat Gaussians on a floor, four walls and a few boxes (splats lie on
surfaces), plus a fraction of free-floating small ones. Prints medians (wall ms) and process CPU
time for the one-time builds. Timings only; correctness lives in tests/planner/.
"""
from __future__ import annotations

import argparse
import json
import math
import statistics
import time

import torch

from cinenerf_ns.planner.geometry.collision import max_k_sphere, points_collide, segments_collide
from cinenerf_ns.planner.geometry.distance import clearance
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.occupancy import build_occupancy
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.scene.spatial_index import GridIndex


def room_splat(n: int, seed: int = 0):
    """Splat parameters of a room [-1,1]^2 x [0,1] with boxes: means on surfaces, flat scales."""
    g = torch.Generator().manual_seed(seed)
    pts, normals = [], []
    n_float = n // 20
    n_surf = n - n_float
    # surfaces: (origin, u, v, normal) rectangles
    rects = [((-1, -1, 0), (2, 0, 0), (0, 2, 0), (0, 0, 1)), ((-1, -1, 0), (2, 0, 0), (0, 0, 1), (0, 1, 0)),
             ((-1, 1, 0), (2, 0, 0), (0, 0, 1), (0, -1, 0)), ((-1, -1, 0), (0, 2, 0), (0, 0, 1), (1, 0, 0)),
             ((1, -1, 0), (0, 2, 0), (0, 0, 1), (-1, 0, 0))]
    for cx, cy, s in ((-0.4, -0.3, 0.3), (0.5, 0.4, 0.25), (0.2, -0.5, 0.15)):
        for o, u, v, nn in (((cx - s, cy - s, 2 * s), (2 * s, 0, 0), (0, 2 * s, 0), (0, 0, 1)),
                            ((cx - s, cy - s, 0), (2 * s, 0, 0), (0, 0, 2 * s), (0, -1, 0)),
                            ((cx - s, cy + s, 0), (2 * s, 0, 0), (0, 0, 2 * s), (0, 1, 0)),
                            ((cx - s, cy - s, 0), (0, 2 * s, 0), (0, 0, 2 * s), (-1, 0, 0)),
                            ((cx + s, cy - s, 0), (0, 2 * s, 0), (0, 0, 2 * s), (1, 0, 0))):
            rects.append((o, u, v, nn))
    areas = torch.tensor([torch.tensor(u, dtype=torch.float).norm() * torch.tensor(v, dtype=torch.float).norm()
                          for _, u, v, _ in rects])
    counts = torch.distributions.Multinomial(n_surf, areas / areas.sum()).sample().long()
    for (o, u, v, nn), c in zip(rects, counts.tolist()):
        ab = torch.rand(c, 2, generator=g)
        pts.append(torch.tensor(o) + ab[:, :1] * torch.tensor(u, dtype=torch.float) + ab[:, 1:]
                   * torch.tensor(v, dtype=torch.float))
        normals.append(torch.tensor(nn, dtype=torch.float).expand(c, 3))
    means = torch.cat(pts + [torch.rand(n_float, 3, generator=g) * torch.tensor([2.0, 2.0, 1.0])
                             - torch.tensor([1.0, 1.0, 0.0])])
    nrm = torch.cat(normals + [torch.randn(n_float, 3, generator=g)])
    nrm = nrm / nrm.norm(dim=-1, keepdim=True)
    # quaternion rotating z to the normal, plus a random spin about it
    z = torch.tensor([0.0, 0.0, 1.0])
    axis = torch.cross(z.expand_as(nrm), nrm, dim=-1)
    w = 1 + (nrm * z).sum(-1)
    q = torch.cat([w[:, None], axis], -1)
    q[w < 1e-6] = torch.tensor([0.0, 1.0, 0.0, 0.0])
    q = q / q.norm(dim=-1, keepdim=True)
    ls = torch.log(torch.rand(means.shape[0], 3, generator=g) * 0.012 + 0.003)
    ls[: n_surf, 2] = math.log(5e-4)  # flat on the surface
    op = torch.randn(means.shape[0], generator=g) + 2.0
    return means, q, ls, op


def timed(fn, reps: int, device: str):
    out = []
    for _ in range(reps):
        if device == "cuda":
            torch.cuda.synchronize()
        t = time.perf_counter()
        fn()
        if device == "cuda":
            torch.cuda.synchronize()
        out.append((time.perf_counter() - t) * 1e3)
    return statistics.median(out)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=200_000)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: leave default)")
    ap.add_argument("--reps", type=int, default=10)
    ap.add_argument("--resolution", type=int, default=100)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    if a.threads:
        torch.set_num_threads(a.threads)
    dev = a.device
    res = {"n": a.n, "device": dev, "threads": torch.get_num_threads(),
           "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    means, q, ls, op = room_splat(a.n)
    scene = EllipsoidScene.from_splat(means.to(dev), q.to(dev), ls.to(dev), op.to(dev), SceneConfig())
    res["n_obstacles"] = len(scene)

    def build_once(fn):
        if dev == "cuda":
            torch.cuda.synchronize()
        t, c = time.perf_counter(), time.process_time()
        r = fn()
        if dev == "cuda":
            torch.cuda.synchronize()
        return r, (time.perf_counter() - t) * 1e3, (time.process_time() - c) * 1e3

    build_once(lambda: GridIndex.build(scene))  # warm-up
    index, res["index_build_ms"], res["index_build_cpu_ms"] = build_once(lambda: GridIndex.build(scene))
    res["index_stats"] = index.stats()
    build_occupancy(scene, index, resolution=20)  # warm-up
    grid, res["occupancy_build_ms"], res["occupancy_build_cpu_ms"] = build_once(
        lambda: build_occupancy(scene, index, resolution=a.resolution))
    res["occupancy_shape"] = list(grid.shape)
    res["occupancy_free_fraction"] = grid.free_fraction()

    g = torch.Generator().manual_seed(1)
    free = torch.nonzero(~grid.occupied.cpu())
    def free_points(k):
        pick = free[torch.randint(free.shape[0], (k,), generator=g)]
        return (grid.lo.cpu() + (pick.double() + torch.rand(k, 3, generator=g, dtype=torch.float64))
                * grid.voxel_size).to(dev)
    any_points = lambda k: (torch.rand(k, 3, generator=g) * torch.tensor([2.0, 2.0, 1.0])
                            - torch.tensor([1.0, 1.0, 0.0])).to(dev)
    for k in (1, 100, 1000):
        p = any_points(k)
        res[f"points_collide_{k}_ms"] = timed(lambda: points_collide(p, scene, index), a.reps, dev)
    p0 = free_points(50)
    p1 = p0 + (torch.randn(50, 3, generator=g, dtype=torch.float64) * 0.1).to(dev)
    res["segments_collide_50x0.17_ms"] = timed(lambda: segments_collide(p0, p1, scene, index), a.reps, dev)
    for k in (100, 1000):
        p = free_points(k)
        res[f"clearance_{k}_ms"] = timed(lambda: clearance(p, scene, index), max(3, a.reps // 3), dev)
    w = (torch.randn(10_000, 3, generator=g, dtype=torch.float64) * 0.1).to(dev)
    rr = (torch.rand(10_000, 3, generator=g, dtype=torch.float64) * 0.05 + 1e-3).to(dev)
    res["max_k_sphere_10k_pairs_ms"] = timed(lambda: max_k_sphere(w, rr, 0.03), a.reps, dev)
    pb = any_points(1000)
    res["query_points_1000_r0_ms"] = timed(lambda: index.query_points(pb, 0.0), a.reps, dev)
    print(json.dumps(res, indent=1))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
