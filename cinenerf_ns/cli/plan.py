"""``cinesplat-plan``: plan camera shots through a splat from the command line (no viewer, no GPU needed).

    cinesplat-plan --scene outputs/room/cinesplat/<run>/config.yml --go-to "armchair" --look-at "floor lamp"
    cinesplat-plan --scene scene.ply --go-to "0.1 0.2 0.3" --look-at "0 0 0.2" --candidates 4
    cinesplat-plan --scene procedural --go-to armchair --look-at "floor lamp"
    cinesplat-plan --scene procedural --go-to armchair --then-go-to sofa table --look-at "floor lamp" \\
        --max-angular-rate 45

With random starts the candidates are planned, scored (occlusion of the look-at object, framing, clearance,
smoothness, duration; planner/shots/scoring.py) and ranked: rank 1 is written as ``<name>_0.json``, rank 2 as
``<name>_1.json``, ...; the table and the report state every score term.

Targets are "x y z" points (scene units, nerfstudio's normalised coordinates for checkpoints) or text. Every option
is checked before torch and the scene load; errors go to stderr with exit status 2 and leave no file behind. The outputs
(camera paths, report, plots) appear together at the end or not at all.
"""
from __future__ import annotations

import sys
from typing import List, Optional

from rich.console import Console

from cinenerf_ns.console_text import error_line
from cinenerf_ns.option_surface import parse
from cinenerf_ns.planner.errors import PlanningError
from cinenerf_ns.signals import interrupted, signals_as_interrupts

from .plan_args import RENAMED_FLAGS, PlanArgs, check_args

ERRORS = Console(stderr=True, emoji=False)


def main(argv: Optional[List[str]] = None) -> int:
    """Parse ``argv`` (default: sys.argv), run; returns the exit status: 0, 2 for a user error (message on stderr),
    130 when interrupted (143 on SIGTERM, 129 on SIGHUP). Nothing partial is left behind in either case."""
    try:
        args = parse(PlanArgs, argv, "cinesplat-plan", RENAMED_FLAGS)
        check_args(args)  # --help and every option the scene is not needed for: answered before torch loads (~2 s)
        with signals_as_interrupts():  # SIGTERM / SIGHUP unwind like Ctrl-C: nothing is left behind
            from .plan_run import run_plan  # torch, the planner, the scene loader

            run_plan(args, checked=True)
    except KeyboardInterrupt as e:
        code, what = interrupted(e)
        ERRORS.print(f"cinesplat-plan: {what}; no output was written", markup=False, highlight=False)
        return code
    except MemoryError:
        ERRORS.print("cinesplat-plan: out of memory; lower --grid-resolution or --memory-budget-mb, or plan fewer "
                     "--candidates")
        return 2
    except (PlanningError, FileNotFoundError, ValueError, OSError) as e:  # user-facing: CheckpointError, QueryError...
        ERRORS.print(error_line("cinesplat-plan", e), soft_wrap=True)
        return 2
    return 0


def entrypoint() -> None:
    sys.exit(main())


if __name__ == "__main__":
    entrypoint()
