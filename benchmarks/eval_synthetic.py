"""Ground-truth side of the end-to-end evaluation on synthetic rooms (issue 5, item 2).

Everything here compares *outputs* of the method/planner with the room's analytic ground truth
(geometry.json written by ``cinesplat-synth``); nothing here feeds the method or the planner.
All metrics work in whichever frame the ground-truth object ``gt`` lives in:

* ``Room`` (cinenerf_ns.synthetic.room): original room coordinates, metres;
* ``GroundTruthNS(room, NerfstudioTransform)``: nerfstudio's normalised coordinates, the frame of
  the trained splat, camera paths and the planner's ``camera_radius``.

Library use (the lead wires the planner/method around it)::

    from benchmarks.eval_synthetic import *
    gt = load_ground_truth("data/room0", "outputs/room0/cinesplat/<run>/dataparser_transforms.json")
    selection_metrics(means, mask, gt, "floor lamp")           # IoU / centroid error of a selection
    clearance_along(positions, gt, camera_radius=0.03)          # true clearance per sample
    look_at_errors_deg(c2w, gt.object_centres()["floor lamp"])  # per frame
    plot_topdown(gt, {"shot 0": positions}, "topdown.png"); plot_clearance({...}, "clearance.png")

CLI on exported camera paths (nerfstudio camera-path JSON, coordinates = nerfstudio's)::

    PYTHONPATH=. .venv/bin/python benchmarks/eval_synthetic.py --dataset data/room0 \\
        --dataparser-transforms outputs/.../dataparser_transforms.json \\
        --camera-paths shot0.json shot1.json --look-at "floor lamp" --go-to "red armchair" \\
        --camera-radius 0.03 --out benchmarks/synth_eval
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import torch
from torch import Tensor

from cinenerf_ns.synthetic.ns_transform import GroundTruthNS, NerfstudioTransform
from cinenerf_ns.synthetic.room import FIRST_OBJECT_LABEL, Room

GroundTruth = Room | GroundTruthNS


# ----------------------------------------------------------------------------------------------
# loading
# ----------------------------------------------------------------------------------------------

def _save_figure(fig, png) -> Path:
    """Write ``fig`` to ``png`` (its folder made), close it and return the path."""
    import matplotlib.pyplot as plt

    png = Path(png)
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(png, dpi=130)
    plt.close(fig)
    return png

def load_ground_truth(dataset: str | Path, dataparser_transforms: str | Path | None = None) -> GroundTruthNS:
    """Ground truth in nerfstudio coordinates. With ``dataparser_transforms`` (written by ns-train) the
    transform of the trained run is used; without it it is recomputed from transforms.json the way
    NerfstudioDataParser (default settings) does."""
    room = Room.load(dataset)
    tf = (
        NerfstudioTransform.from_dataparser_json(dataparser_transforms)
        if dataparser_transforms is not None
        else NerfstudioTransform.from_dataset(dataset)
    )
    return GroundTruthNS(room, tf)


def object_names(gt: GroundTruth) -> list[str]:
    return [n for k, n in sorted(gt.labels.items()) if k >= FIRST_OBJECT_LABEL]


# ----------------------------------------------------------------------------------------------
# object selection
# ----------------------------------------------------------------------------------------------
def gaussians_in_object(means: Tensor, gt: GroundTruth, name: str, surface_tol: float) -> Tensor:
    """bool [N]: Gaussian centres inside the object or within ``surface_tol`` of its surface
    (splat centres sit on, not inside, surfaces, so a small tolerance is needed; same units as gt)."""
    return gt.object_sdf(name, torch.as_tensor(means, dtype=torch.float64)) <= surface_tol


def selection_metrics(
    means: Tensor, selected: Tensor, gt: GroundTruth, name: str, surface_tol: float | None = None
) -> dict:
    """IoU / precision / recall of a per-Gaussian selection [N] against the Gaussians of the true
    object volume, and the centroid error of the selection to the object's true volume centroid.

    ``surface_tol`` defaults to 1% of the room size. ``centroid_error_frac`` = error / room size
    (largest interior side). Empty selection: IoU 0, centroid error inf. ``truth_centroid_error_frac``: the same
    error for the object's TRUE Gaussians (the best any selection can score: Gaussians lie on surfaces, so their
    mean is not the volume centroid; the rest of ``centroid_error_frac`` is the selection's own error)."""
    means = torch.as_tensor(means, dtype=torch.float64).reshape(-1, 3)
    sel = torch.as_tensor(selected).reshape(-1).bool()
    if sel.shape[0] != means.shape[0]:
        raise ValueError(f"selection has {sel.shape[0]} entries but there are {means.shape[0]} Gaussians")
    tol = 0.01 * gt.room_size() if surface_tol is None else surface_tol
    truth = gaussians_in_object(means, gt, name, tol)
    inter = int((sel & truth).sum())
    union = int((sel | truth).sum())
    centre = gt.object_centres()[name]
    err = float((means[sel].mean(0) - centre).norm()) if bool(sel.any()) else math.inf
    err_truth = float((means[truth].mean(0) - centre).norm()) if bool(truth.any()) else math.inf
    return {
        "object": name,
        "iou": inter / union if union else 0.0,
        "precision": inter / int(sel.sum()) if bool(sel.any()) else 0.0,
        "recall": inter / int(truth.sum()) if bool(truth.any()) else 0.0,
        "n_selected": int(sel.sum()),
        "n_true": int(truth.sum()),
        "centroid_error": err,
        "centroid_error_frac": err / gt.room_size(),
        "truth_centroid_error_frac": err_truth / gt.room_size(),
        "surface_tol": tol,
    }


# ----------------------------------------------------------------------------------------------
# trajectories
# ----------------------------------------------------------------------------------------------
def clearance_along(positions: Tensor, gt: GroundTruth, camera_radius: float) -> Tensor:
    """True clearance [T] of a camera sphere of ``camera_radius`` at each sample: SDF - radius
    (exact for positive SDF; same units as gt)."""
    p = torch.as_tensor(positions, dtype=torch.float64).reshape(-1, 3)
    return gt.sdf(p) - camera_radius


def clearance_lower_bound(positions: Tensor, clearance: Tensor) -> Tensor:
    """Certified lower bound [T-1] of the clearance on each *straight* segment between consecutive
    samples: the SDF is 1-Lipschitz, so on a segment of length L with end clearances c0, c1 the
    clearance is >= (c0 + c1 - L) / 2. For a curved trajectory this bounds the chord; dense sampling
    keeps chord and curve close (the evaluation reports both the samples and this bound)."""
    p = torch.as_tensor(positions, dtype=torch.float64).reshape(-1, 3)
    c = torch.as_tensor(clearance, dtype=torch.float64).reshape(-1)
    L = (p[1:] - p[:-1]).norm(dim=-1)
    return (c[1:] + c[:-1] - L) / 2


def look_at_errors_deg(c2w: Tensor, target: Tensor) -> Tensor:
    """Angle [T] (degrees) between each camera's viewing direction (-z column of the camera-to-world,
    nerfstudio/OpenGL convention) and the direction from the camera to ``target`` ([3] or [T,3])."""
    m = torch.as_tensor(c2w, dtype=torch.float64)
    fwd = -m[..., :3, 2]
    v = torch.as_tensor(target, dtype=torch.float64) - m[..., :3, 3]
    cos = (fwd * v).sum(-1) / (fwd.norm(dim=-1) * v.norm(dim=-1)).clamp(min=1e-300)
    # atan2 of (|cross|, dot) is accurate near 0 degrees where acos is not
    sin = torch.linalg.cross(fwd, v).norm(dim=-1) / (fwd.norm(dim=-1) * v.norm(dim=-1)).clamp(min=1e-300)
    return torch.rad2deg(torch.atan2(sin, cos))


def distance_to_object(position: Tensor, gt: GroundTruth, name: str) -> dict:
    """Distance of a (final) camera position [3] to an object's surface and to its centre."""
    p = torch.as_tensor(position, dtype=torch.float64).reshape(1, 3)
    return {
        "surface": float(gt.object_sdf(name, p)[0]),
        "centre": float((p[0] - gt.object_centres()[name]).norm()),
    }


def shot_metrics(
    times: Tensor,
    c2w: Tensor,
    gt: GroundTruth,
    camera_radius: float,
    look_at: str | None = None,
    go_to: str | None = None,
) -> dict:
    """All per-shot numbers for one sampled trajectory: times [T], c2w [T,3|4,4]."""
    c2w = torch.as_tensor(c2w, dtype=torch.float64)
    pos = c2w[:, :3, 3]
    clr = clearance_along(pos, gt, camera_radius)
    out = {
        "n_samples": int(pos.shape[0]),
        "duration": float(torch.as_tensor(times)[-1] - torch.as_tensor(times)[0]) if len(times) else 0.0,
        "min_clearance": float(clr.min()),
        "min_clearance_segment_bound": float(clearance_lower_bound(pos, clr).min()) if len(pos) > 1
        else float(clr.min()),
        "safe": bool((clr > 0).all()),
        "clearance": clr,
    }
    if look_at is not None:
        err = look_at_errors_deg(c2w, gt.object_centres()[look_at])
        out.update(look_at=look_at, look_at_error_max_deg=float(err.max()), look_at_error_mean_deg=float(err.mean()),
                   look_at_errors_deg=err)
    if go_to is not None:
        d = distance_to_object(pos[-1], gt, go_to)
        out.update(go_to=go_to, final_surface_distance=d["surface"], final_centre_distance=d["centre"])
    return out


def read_camera_path(path: str | Path) -> tuple[Tensor, Tensor]:
    """times [T], c2w [T,4,4] from a nerfstudio camera-path JSON (``camera_path[i].camera_to_world``
    flattened row-major 4x4; times from ``fps`` or evenly over ``seconds``)."""
    d = json.loads(Path(path).read_text())
    frames = d["camera_path"]
    c2w = torch.tensor([f["camera_to_world"] for f in frames], dtype=torch.float64).reshape(-1, 4, 4)
    if "fps" in d and d["fps"]:
        times = torch.arange(len(frames), dtype=torch.float64) / float(d["fps"])
    else:
        times = torch.linspace(0, float(d.get("seconds", len(frames))), len(frames), dtype=torch.float64)
    return times, c2w


# ----------------------------------------------------------------------------------------------
# plots and tables
# ----------------------------------------------------------------------------------------------
def plot_topdown(
    gt: GroundTruth,
    paths: Mapping[str, Tensor],
    png: str | Path,
    look_targets: Mapping[str, Tensor] | None = None,
    title: str = "camera paths (top-down)",
) -> Path:
    """Top-down view: room outline, object footprints with names, each path [T,3] with start/end marks."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 6))
    room_xy = gt.interior_outline_xy().numpy()
    ax.plot(room_xy[:, 0], room_xy[:, 1], "k-", lw=2)
    names = object_names(gt)
    room = gt.room if isinstance(gt, GroundTruthNS) else gt
    # draw each object in its own albedo (first part), so the plot reads like the renders
    colour = {o.name: tuple(room.parts[o.part_ids[0]].colour) for o in room.objects}
    centres = gt.object_centres()
    for name, poly in gt.part_outlines_xy():
        xy = poly.numpy()
        ax.fill(xy[:, 0], xy[:, 1], color=colour[name], alpha=0.35, lw=0.8, ec=colour[name])
    for n in names:
        c = centres[n].numpy()
        ax.annotate(n, c[:2], fontsize=7, ha="center", va="center")
    for k, (label, p) in enumerate(paths.items()):
        p = torch.as_tensor(p, dtype=torch.float64).reshape(-1, 3).numpy()
        line = ax.plot(p[:, 0], p[:, 1], "-", lw=1.5, label=label)[0]
        ax.plot(p[0, 0], p[0, 1], "o", color=line.get_color(), ms=5)
        ax.plot(p[-1, 0], p[-1, 1], "s", color=line.get_color(), ms=5)
        if look_targets and label in look_targets:
            t = torch.as_tensor(look_targets[label]).numpy()
            ax.plot([p[-1, 0], t[0]], [p[-1, 1], t[1]], ":", color=line.get_color(), lw=1)
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(title + "  (o start, \u25a1 end)")
    if paths:
        ax.legend(fontsize=7, loc="best")
    return _save_figure(fig, png)


def plot_clearance(
    series: Mapping[str, tuple[Tensor, Tensor]], png: str | Path, title: str = "true clearance over time"
) -> Path:
    """Clearance over time (like the paper's Fig. 5): series = {label: (times [T], clearance [T])};
    the zero line is the collision boundary (camera radius already subtracted)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    for label, (t, c) in series.items():
        ax.plot(torch.as_tensor(t).numpy(), torch.as_tensor(c).numpy(), lw=1.2, label=label)
    ax.axhline(0.0, color="r", lw=1, ls="--", label="collision")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("clearance (scene units)")
    ax.set_title(title)
    ax.legend(fontsize=7, loc="best")
    return _save_figure(fig, png)


def markdown_table(rows: Sequence[Mapping], columns: Sequence[str] | None = None, floatfmt: str = ".4g") -> str:
    """A GitHub markdown table of scalar columns (tensors / lists are skipped)."""
    if not rows:
        return "(no rows)\n"
    if columns is None:
        columns = [k for k, v in rows[0].items() if isinstance(v, (int, float, str, bool)) or v is None]

    def fmt(v):
        if isinstance(v, bool) or v is None or isinstance(v, str):
            return str(v)
        if isinstance(v, (int, np.integer)):
            return str(int(v))
        return format(float(v), floatfmt)

    lines = ["| " + " | ".join(columns) + " |", "|" + "|".join("---" for _ in columns) + "|"]
    lines += ["| " + " | ".join(fmt(r.get(c)) for c in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------------
# CLI: evaluate exported camera paths against the ground truth
# ----------------------------------------------------------------------------------------------
def main(argv: Sequence[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dataset", required=True, type=Path, help="dataset folder written by cinesplat-synth")
    ap.add_argument("--dataparser-transforms", type=Path, default=None,
                    help="dataparser_transforms.json of the trained run (default: recomputed from transforms.json)")
    ap.add_argument("--camera-paths", nargs="*", type=Path, default=[], help="nerfstudio camera-path JSON files")
    ap.add_argument("--look-at", default=None, help="object name every shot should look at")
    ap.add_argument("--go-to", default=None, help="object name every shot should end near")
    ap.add_argument("--camera-radius", type=float, default=0.03, help="camera body radius (nerfstudio units)")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/synth_eval"))
    a = ap.parse_args(argv)
    gt = load_ground_truth(a.dataset, a.dataparser_transforms)
    for n in (a.look_at, a.go_to):
        if n is not None and n not in object_names(gt):
            raise SystemExit(f"unknown object {n!r}; this room has {object_names(gt)}")
    rows, paths, series, looks = [], {}, {}, {}
    for cp in a.camera_paths:
        times, c2w = read_camera_path(cp)
        m = shot_metrics(times, c2w, gt, a.camera_radius, a.look_at, a.go_to)
        rows.append({"shot": cp.stem, **m})
        paths[cp.stem] = c2w[:, :3, 3]
        series[cp.stem] = (times, m["clearance"])
        if a.look_at:
            looks[cp.stem] = gt.object_centres()[a.look_at]
    a.out.mkdir(parents=True, exist_ok=True)
    plot_topdown(gt, paths, a.out / "topdown.png", looks)
    if series:
        plot_clearance(series, a.out / "clearance.png")
    table = markdown_table(rows)
    (a.out / "shots.md").write_text(table)
    print(table)
    return {"rows": rows, "out": str(a.out)}


if __name__ == "__main__":
    main()
