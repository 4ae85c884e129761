"""`make demo`: plan a shot from text on the bundled demo scene, on the CPU, in under a minute.

The bundled scene (cinenerf_ns/assets/room0.npz, see assets/README.md) is a synthetic room trained with
`ns-train cinesplat` on label masks. The demo asks "go to the red armchair, look at the floor lamp" and
writes into demo_output/: the nerfstudio camera path (demo_0.json), the planner report
(demo_report.json with the exact clearance along the whole curve), the clearance-over-time plot and a
top view of the path through the room. Without the bundled scene (e.g. a trimmed checkout) it falls back
to a procedural room with known object names.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from rich.console import Console

from cinenerf_ns.cli.plan import PlanArgs, run_plan

ASSETS = Path(__file__).parent / "assets"
DEMO_SCENE = ASSETS / "room0.npz"


def demo_args(output_dir: Path, scene: Path = DEMO_SCENE, candidates: int = 1) -> PlanArgs:
    if scene.exists():
        return PlanArgs(scene=str(scene), go_to="the red armchair", look_at="the floor lamp", output_dir=output_dir,
                        name="demo", candidates=candidates, seed=0)
    return PlanArgs(scene="procedural:20000:0", go_to="armchair", look_at="lamp", output_dir=output_dir, name="demo",
                    candidates=candidates, seed=0)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--output-dir", type=Path, default=Path("demo_output"))
    ap.add_argument("--scene", type=Path, default=DEMO_SCENE, help="compact scene / config.yml (default: the bundled room)")
    ap.add_argument("--candidates", type=int, default=1)
    a = ap.parse_args(argv)
    console = Console(width=max(Console().width, 150))  # the candidates table has many columns
    args = demo_args(a.output_dir, a.scene, a.candidates)
    console.print(f"[bold]cinenerf_ns demo[/bold]: scene {args.scene}\n  go to: {args.go_to!r}   look at: {args.look_at!r}")
    t0 = time.perf_counter()
    summary = run_plan(args, console=console)
    cam = summary["candidates"][0]["camera_path"]
    console.print(f"\n[green]done in {time.perf_counter() - t0:.1f} s[/green]. Outputs in {a.output_dir}/:")
    console.print(f"  camera path  {cam}\n  report       {summary['report']}\n"
                  f"  clearance    {summary['plots']['clearance']}\n  top view     {summary['plots']['topdown']}")
    console.print("\nGo further (after `source .venv/bin/activate` when you used make):")
    console.print(f"  watch and re-plan in the browser:  cinesplat-viewer --load-config {args.scene}")
    console.print(f"  the same from the command line:    cinesplat-plan --scene {args.scene} --go-to 'green sofa' "
                  f"--look-at 'bookshelf' --candidates 4")
    console.print("  render video with nerfstudio (needs a trained run; the compact demo scene holds no "
                  "optimiser state):\n"
                  "    cinesplat-synth --seed 0 --output data/room0 --ply-in-transforms\n"
                  "    ns-train cinesplat --data data/room0 --pipeline.datamanager.feature-source labels "
                  "--pipeline.datamanager.clip.random-weights True --pipeline.datamanager.clip.feature-long-side 240 "
                  "--max-num-iterations 5000\n"
                  f"    ns-render camera-path --load-config outputs/room0/cinesplat/<run>/config.yml "
                  f"--camera-path-filename {cam} --output-path renders/demo.mp4")
    return summary


if __name__ == "__main__":
    main()
