"""`make demo`: plan a shot from text on the bundled demo scene, on the CPU, in under a minute.

The bundled scene (cinenerf_ns/assets/room0.npz, see assets/README.md) is a synthetic room trained with
`ns-train cinesplat` on label masks. The demo asks "go to the red armchair, look at the floor lamp" and
writes into demo_output/: the nerfstudio camera path (demo_0.json), the planner report
(demo_report.json with the exact clearance along the whole curve), the clearance-over-time plot and a
top view of the path through the room, and a preview of the shot rendered on the CPU (demo.mp4, 480x270 at 15 fps,
and its contact sheet demo_sheet.png). Without the bundled scene (e.g. a trimmed checkout) it falls back
to a procedural room with known object names.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Optional

from rich.console import Console

from cinenerf_ns.cli.plan_args import PlanArgs
from cinenerf_ns.cli.plan_run import run_plan
from cinenerf_ns.console_text import error_line, lit
from cinenerf_ns.planner.errors import PlanningError
from cinenerf_ns.scenes import ASSETS, DEMO_SCENE  # noqa: F401 (ASSETS: the bundled files)


def demo_args(output_dir: Path, scene: Path = DEMO_SCENE, candidates: int = 1) -> PlanArgs:
    """The demo's plan: the bundled room, or the procedural room when a trimmed checkout lacks it (the header names
    the scene). A --scene the user gives is planned as given: a missing file is refused, never replaced."""
    if scene.exists() or Path(scene) != DEMO_SCENE:
        return PlanArgs(scene=str(scene), go_to="the red armchair", look_at="the floor lamp", output_dir=output_dir,
                        name="demo", candidates=candidates, seed=0)
    return PlanArgs(scene="procedural:20000:0", go_to="armchair", look_at="lamp", output_dir=output_dir, name="demo",
                    candidates=candidates, seed=0)


def demo_preview(loaded, camera_path: str, output_dir: Path, console: Console,
                 subject_points=None) -> Optional[dict]:
    """demo.mp4 + demo_sheet.png of the planned shot (the preview's default size and frame rate, 480x270 at 15 fps,
    CPU; the look-at object outlined on the sheet) through ``loaded``, the LoadedScene the plan used (any scene
    scenes.load_scene reads; the procedural fallback's objects in their display colours)."""
    from cinenerf_ns.preview import preview_camera_path
    from cinenerf_ns.scenes import preview_scene

    return preview_camera_path(preview_scene(loaded), camera_path, output_dir, "demo",
                               console=console, subject_points=subject_points)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--output-dir", type=Path, default=Path("demo_output"))
    ap.add_argument("--scene", type=Path, default=DEMO_SCENE,
                    help="compact scene / config.yml (default: the bundled room)")
    ap.add_argument("--candidates", type=int, default=1)
    ap.add_argument("--no-preview", action="store_true", help="skip the mp4 preview of the planned shot")
    a = ap.parse_args(argv)
    # the candidates table has many columns; user text (paths) printed as typed (console_text)
    console = Console(width=max(Console().width, 150), emoji=False)
    args = demo_args(a.output_dir, a.scene, a.candidates)
    console.print(f"[bold]cinenerf_ns demo[/bold]: scene {lit(args.scene)}\n  go to: {lit(repr(args.go_to))}   "
                  f"look at: {lit(repr(args.look_at))}")
    t0 = time.perf_counter()
    kept: dict = {}
    summary = run_plan(args, console=console, keep=kept)  # the scene it loaded is rendered below, not loaded again
    cam = summary["candidates"][0]["camera_path"]
    preview = None if a.no_preview else demo_preview(kept["loaded"], cam, a.output_dir, console,
                                                     summary["look_at"].get("extent_points"))
    if preview is not None:
        summary["preview"] = preview
    console.print(f"\n[green]done in {time.perf_counter() - t0:.1f} s[/green]. Outputs in {lit(a.output_dir)}/:")
    console.print(f"  camera path  {cam}\n  report       {summary['report']}\n"
                  f"  clearance    {summary['plots']['clearance']}\n  top view     {summary['plots']['topdown']}",
                  markup=False)
    if preview is not None:
        console.print(f"  preview      {preview['paths']['mp4']} ({preview['frames']} frames, {preview['width']}x"
                      f"{preview['height']} @ {preview['fps']:g} fps, "
                      f"rendered in {preview['timings']['total_s']:.1f} s)\n"
                      f"  contact      {preview['paths']['contact_sheet']}", markup=False)
    console.print("\nGo further (after `source .venv/bin/activate` when you used make):")
    console.print(f"  watch and re-plan in the browser:  cinesplat-viewer --load-config {args.scene}", markup=False)
    console.print(f"  the same from the command line:    cinesplat-plan --scene {args.scene} --go-to 'green sofa' "
                  f"--look-at 'bookshelf' --candidates 4", markup=False)
    console.print("  render video with nerfstudio (needs a trained run; the compact demo scene holds no "
                  "optimiser state):\n"
                  "    cinesplat-synth --seed 0 --output data/room0 --ply-in-transforms\n"
                  "    ns-train cinesplat --data data/room0 --pipeline.datamanager.feature-source labels "
                  "--pipeline.datamanager.clip.random-weights True --pipeline.datamanager.clip.feature-long-side 240 "
                  "--max-num-iterations 5000\n"
                  f"    ns-render camera-path --load-config outputs/room0/cinesplat/<run>/config.yml "
                  f"--camera-path-filename {cam} --output-path renders/demo.mp4", markup=False)
    return summary


def entrypoint(argv=None) -> None:
    """`python -m cinenerf_ns.cli.demo`: a user error (a --scene that does not load, an output folder that cannot be
    written) ends with one line on stderr and exit status 2, as cinesplat-plan's do."""
    try:
        main(argv)
    except (PlanningError, FileNotFoundError, ValueError, OSError) as e:
        Console(stderr=True, emoji=False).print(error_line("cinenerf_ns demo", e), soft_wrap=True)
        sys.exit(2)


if __name__ == "__main__":
    entrypoint()
