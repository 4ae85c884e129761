"""`cinesplat-synth`: generate a seeded synthetic room and write a nerfstudio dataset.

    cinesplat-synth --seed 0 --num-views 150 --width 480 --height 360 --output data/room0
    ns-train cinesplat --data data/room0        # or splatfacto
"""
from __future__ import annotations

import tyro
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from cinenerf_ns.console_text import lit
from cinenerf_ns.synthetic.dataset import DatasetConfig, write_dataset

CONSOLE = Console(emoji=False)  # the output path printed as typed (console_text)


def main(config: DatasetConfig) -> dict:
    with Progress(
        TextColumn("[bold blue]rendering"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=CONSOLE,
    ) as progress:
        task = progress.add_task("render", total=config.num_views)
        info = write_dataset(config, progress=lambda i, n: progress.update(task, completed=i))
    CONSOLE.print(
        f"[green]wrote {config.num_views} views of room seed {config.seed} to {lit(config.output)}[/green] "
        f"(render {info['render_seconds']:.1f} s wall / {info['render_cpu_seconds']:.1f} s CPU, "
        f"total {info['total_seconds']:.1f} s, {config.threads} thread(s))"
    )
    CONSOLE.print(f"train with: ns-train cinesplat --data {config.output}", markup=False, soft_wrap=True)
    return info


def entrypoint() -> None:
    tyro.extras.set_accent_color("bright_yellow")
    main(tyro.cli(DatasetConfig))


if __name__ == "__main__":
    entrypoint()
