"""Build the bundled demo scene (cinenerf_ns/assets/) from a trained synthetic room.

    python scripts/make_demo_scene.py --scene ROOM.pt|config.yml --dataset GT_DIR --out cinenerf_ns/assets

GT_DIR holds what `scripts/gpu_check.sh room` copies out of the run: transforms.json (training cameras),
dataparser_transforms.json, geometry.json and labels.json. The scene is written as a compressed compact
export (SH degree 0, float16 per-Gaussian arrays, float32 means). When it exceeds --max-mb the Gaussians
of lowest opacity are dropped (they are the least visible; the demo then plans around exactly the scene it
ships, nothing else). The training cameras' centres are stored as info["camera_centres"] and their bounding box as
info["start_region"]: random starts are drawn where the capture was, and an object's volume centre fills what no
camera saw (what cinesplat-plan does with a run's config.yml).
"""
from __future__ import annotations

import argparse
import shutil
from dataclasses import replace
from pathlib import Path

import torch

from cinenerf_ns.method.checkpoint import export_compact, load_splat
from cinenerf_ns.method.training_cameras import camera_centres, camera_info


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, required=True)
    ap.add_argument("--dataset", type=Path, required=True)
    ap.add_argument("--out", type=Path, default=Path("cinenerf_ns/assets"))
    ap.add_argument("--name", default="room0")
    ap.add_argument("--max-mb", type=float, default=14.5, help="size budget of the scene file (MB = 1e6 bytes)")
    args = ap.parse_args()

    st = load_splat(args.scene)
    # start region and the cameras the volume centre fills what they did not see with
    st.info.update(camera_info(camera_centres(args.dataset / "transforms.json",
                                              args.dataset / "dataparser_transforms.json")))
    n0 = len(st)
    out = args.out / f"{args.name}.npz"
    keep_frac = 1.0
    while True:
        order = torch.argsort(torch.as_tensor(st.params.opacity_logits).float().reshape(-1), descending=True)
        k = int(round(n0 * keep_frac))
        sub = replace(st, params=st.params.subset(torch.sort(order[:k]).values)) if k < n0 else st
        sub.info["demo_pruned"] = {"kept": k, "of": n0, "rule": "highest opacity"}
        export_compact(sub, out, half=True)
        mb = out.stat().st_size / 1e6
        print(f"{k} of {n0} Gaussians -> {out} {mb:.2f} MB")
        if mb <= args.max_mb:
            break
        keep_frac *= 0.97 * args.max_mb / mb
    gt = args.out / f"{args.name}_gt"
    gt.mkdir(parents=True, exist_ok=True)
    for f in ("geometry.json", "labels.json", "dataparser_transforms.json"):
        shutil.copy(args.dataset / f, gt / f)
    print("ground truth files ->", gt)


if __name__ == "__main__":
    main()
