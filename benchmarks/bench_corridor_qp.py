"""Corridor QP latency: hand-built sparse QP + Clarabel / OSQP vs the same problem through cvxpy.

Usage: .venv/bin/python benchmarks/bench_corridor_qp.py [--segments 10] [--faces 30] [--runs 30]
Prints medians (ms) of build, solve and total; single process, whatever threads the solvers use.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "planner" / "trajectory"))

from test_qp import cvxpy_reference, random_corridor  # noqa: E402

from cinenerf_ns.planner.trajectory.qp import TrajectoryConfig, solve_corridor_qp  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--segments", type=int, default=10)
    ap.add_argument("--faces", type=int, default=30)
    ap.add_argument("--runs", type=int, default=30)
    args = ap.parse_args()
    rows = {}
    for solver in ("clarabel", "osqp"):
        cfg = TrajectoryConfig(solver=solver)
        build, solve, total = [], [], []
        for seed in range(args.runs):
            polys, wp = random_corridor(seed, m=args.segments, faces=args.faces)
            t0 = time.perf_counter()
            traj = solve_corridor_qp(polys, wp, wp[0], wp[-1], cfg)
            total.append(1e3 * (time.perf_counter() - t0))
            build.append(traj.info["build_ms"])
            solve.append(traj.info["solve_ms"])
        rows[solver] = (statistics.median(build), statistics.median(solve), statistics.median(total))
    cv = []
    for seed in range(min(args.runs, 10)):
        polys, wp = random_corridor(seed, m=args.segments, faces=args.faces)
        t0 = time.perf_counter()
        cvxpy_reference(polys, wp, wp[0], wp[-1], TrajectoryConfig())
        cv.append(1e3 * (time.perf_counter() - t0))
    print(f"corridor QP, {args.segments} segments x {args.faces} faces, degree 5, C2, {args.runs} seeds")
    print("| solver | build ms | solve ms | total ms (median) |")
    print("|---|---|---|---|")
    for k, (b, s, t) in rows.items():
        print(f"| {k} direct | {b:.2f} | {s:.2f} | {t:.2f} |")
    print(f"| cvxpy (CLARABEL), incl. canonicalisation | - | - | {statistics.median(cv):.2f} |")


if __name__ == "__main__":
    main()
