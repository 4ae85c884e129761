"""Seeded set-up work that leaves the training's random streams alone.

``torch.manual_seed`` seeds the CPU generator AND every CUDA generator. Set-up code that seeds its own modules
with it (random-weight CLIP, the codec's MLPs) would restart the CUDA stream that training then draws from
(splatfacto's random backgrounds and split samples), so ``--machine.seed`` would no longer decide it. Here only the
CPU generator is seeded, inside a fork that restores it afterwards."""

from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

import torch


@contextmanager
def cpu_seeded(seed: int) -> Iterator[None]:
    """Run the block with the CPU generator seeded to ``seed``; every generator is as before afterwards and no CUDA
    generator is touched (modules built in the block are made on the CPU)."""
    with torch.random.fork_rng(devices=[]):
        torch.random.default_generator.manual_seed(int(seed))
        yield
