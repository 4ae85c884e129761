"""Store a run's training-camera centres in a compact export that lacks them (exports made before 2026-11-25).

    python scripts/add_camera_centres.py --scene ROOM.pt|ROOM.npz --transforms DATA/transforms.json \
        --dataparser-transforms RUN/dataparser_transforms.json

Writes info["camera_centres"] ([F, 3], the run's normalised coordinates), info["camera_poses"] ([F, 3, 4], where
cinesplat-viewer opens) and info["start_region"] (their box +0.1,
what random starts are drawn from) and nothing else: the arrays are copied as stored (no re-quantisation). With them
the volume centre of a text target also fills what no training camera saw (cinenerf_ns/method/object_centre.py).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Optional

import numpy as np
import torch

from cinenerf_ns.method.training_cameras import camera_info, camera_poses


def add_camera_centres(scene: Path, centres: np.ndarray, poses: Optional[np.ndarray] = None) -> dict:
    """Rewrite the compact export ``scene`` (.npz or .pt) with the camera centres [F, 3] (and poses [F, 3, 4] when
    given) in its info; returns the info."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    if len(c) == 0 or not np.isfinite(c).all():
        raise SystemExit(f"no finite camera centres to store ({len(c)} given)")
    tmp = scene.with_name(scene.name + ".tmp")
    if scene.suffix == ".npz":
        with np.load(scene, allow_pickle=False) as z:
            flat = {k: z[k] for k in z.files}
        info = json.loads(str(flat["info_json"]))
        info.update(camera_info(c, poses))
        flat["info_json"] = np.array(json.dumps(info))
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **flat)
    else:
        blob = torch.load(scene, map_location="cpu", weights_only=True)
        if not isinstance(blob, dict) or blob.get("format") != "cinesplat-compact":
            raise SystemExit(f"{scene} is not a cinesplat compact export")
        info = json.loads(blob["info_json"])
        info.update(camera_info(c, poses))
        blob["info_json"] = json.dumps(info)
        torch.save(blob, tmp)
    tmp.replace(scene)
    return info


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", type=Path, required=True, help="compact export (.pt or .npz)")
    ap.add_argument("--transforms", type=Path, required=True, help="the training data's transforms.json")
    ap.add_argument("--dataparser-transforms", type=Path, required=True, help="the run's dataparser_transforms.json")
    a = ap.parse_args(argv)
    for p in (a.scene, a.transforms, a.dataparser_transforms):
        if not p.is_file():
            raise SystemExit(f"not found: {p}")
    poses = camera_poses(a.transforms, a.dataparser_transforms, a.transforms.parent)
    add_camera_centres(a.scene, poses[:, :, 3], poses)
    print(f"{a.scene}: stored {len(poses)} camera centres and poses and their box")


if __name__ == "__main__":
    main()
