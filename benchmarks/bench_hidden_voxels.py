"""The unseen fill's sight-line test (object_centre.hidden_voxels): compiled kernel vs numpy, on real objects.

    python benchmarks/bench_hidden_voxels.py [--scene cinenerf_ns/assets/room0.npz] [--repeats 5]

For every labelled object of a trained scene with training cameras (the bundled room by default): the selection's
core is voxelised as volume_centroid does, then hidden_voxels runs on the box voxels the ray vote left empty, with
both backends (they must give the same voxels). Prints medians and the ratio; appends to benchmarks/RESULTS.md.
"""
from __future__ import annotations

import argparse
import datetime
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._results import append_results, device_name  # noqa: E402
from cinenerf_ns.method import object_centre as oc  # noqa: E402
from cinenerf_ns.planner.native import hidden_voxels_c  # noqa: E402
from cinenerf_ns.planner.scene.ellipsoids import quat_wxyz_to_rotmat  # noqa: E402
from cinenerf_ns.planner.scene.scene_config import SceneConfig  # noqa: E402
from cinenerf_ns.scenes import load_scene  # noqa: E402


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="cinenerf_ns/assets/room0.npz")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--no-record", action="store_true")
    a = ap.parse_args(argv)
    if hidden_voxels_c() is None:
        raise SystemExit("the compiled kernel did not load (see cinenerf_ns.planner.native.native_status())")
    ld = load_scene(a.scene, SceneConfig(), smooth_neighbors=32)
    sem = ld.semantics.semantic if ld.semantics else None
    if sem is None or sem.camera_centres is None:
        raise SystemExit(f"{a.scene} has no semantic latents or no training cameras")
    rows = []
    for name in ld.semantics.label_names:
        if name in ("floor", "wall", "ceiling", "background"):
            continue
        core = sem.locate_full(name).core
        m = sem.means[core].double().numpy()
        s = torch.exp(sem.log_scales[core].double()).numpy()
        q = sem.quats[core].double()
        F = oc.up_frame(sem.up)
        axes = np.einsum("ji,kjl->kil", F, quat_wxyz_to_rotmat(q).numpy() * s[:, None, :])
        pf = m @ F
        surf, lo, h, pad = oc.surface_voxels(pf, axes, 64, 1, 4.0, 2.0 * oc.neighbour_spacing(pf))
        solid = oc.enclosed_voxels(surf, 14)
        ii = np.argwhere(surf)
        lo_i, hi_i = ii.min(0), ii.max(0) + 1
        box = np.zeros_like(surf)
        box[lo_i[0]:hi_i[0], lo_i[1]:hi_i[1], lo_i[2]:hi_i[2]] = True
        cand, cams = box & ~solid, (sem.camera_centres @ F - lo) / h + pad - 0.5
        t, out = {}, {}
        for be in ("python", "native"):
            ts = []
            for _ in range(a.repeats):
                t0 = time.perf_counter()
                out[be] = oc.hidden_voxels(surf, cand, cams, backend=be)
                ts.append(1e3 * (time.perf_counter() - t0))
            t[be] = statistics.median(ts)
        if not np.array_equal(out["python"], out["native"]):
            raise SystemExit(f"{name}: the backends disagree")
        rows.append((name, int(cand.sum()), int(out["native"].sum()), t["python"], t["native"]))
        print(f"{name:>16}: {rows[-1][1]:6d} candidates, {rows[-1][2]:5d} hidden, numpy {t['python']:7.1f} ms, "
              f"compiled {t['native']:6.1f} ms, ratio {t['python'] / t['native']:.1f}")
    tot_p, tot_n = sum(r[3] for r in rows), sum(r[4] for r in rows)
    print(f"all {len(rows)} objects: numpy {tot_p:.0f} ms, compiled {tot_n:.0f} ms, ratio {tot_p / tot_n:.1f}")
    if not a.no_record:
        table = "\n".join(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]:.1f} | {r[4]:.1f} | {r[3] / r[4]:.1f} |" for r in rows)
        append_results(
            f"\n## bench_hidden_voxels ({datetime.date.today().isoformat()}, {device_name('cpu')})\n\n"
            f"scene `{a.scene}`, {len(sem.camera_centres)} training cameras, median of {a.repeats}; same voxels "
            "from both\n\n"
            "| object | candidates | hidden | numpy ms | compiled ms | ratio |\n|---|---|---|---|---|---|\n"
            f"{table}\n| all | | | {tot_p:.0f} | {tot_n:.0f} | {tot_p / tot_n:.1f} |\n")


if __name__ == "__main__":
    main()
