"""Optimiser schedules whose checkpointed state holds no numpy scalars (torch>=2.6 weights_only)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Type

from nerfstudio.engine.schedulers import (
    ExponentialDecayScheduler,
    ExponentialDecaySchedulerConfig,
)


@dataclass
class FloatExponentialDecaySchedulerConfig(ExponentialDecaySchedulerConfig):
    """nerfstudio's exponential decay with warm-up whose learning-rate factors are python floats
    (the stock one stores numpy scalars in the checkpoint, which torch>=2.6 refuses to load)."""

    _target: Type = field(default_factory=lambda: FloatExponentialDecayScheduler)
    """target class to instantiate"""


class FloatExponentialDecayScheduler(ExponentialDecayScheduler):
    """Same schedule as ``ExponentialDecayScheduler``; the lambda returns ``float``."""

    def get_scheduler(self, optimizer, lr_init: float):
        sched = super().get_scheduler(optimizer, lr_init)
        sched.lr_lambdas = [(lambda step, _f=f: float(_f(step))) for f in sched.lr_lambdas]
        # LambdaLR already evaluated the lambda once in its constructor: re-cast what it stored.
        sched.base_lrs = [float(x) for x in sched.base_lrs]
        sched._last_lr = [float(x) for x in sched.get_last_lr()]
        for group, lr in zip(optimizer.param_groups, sched._last_lr):
            group["lr"] = float(lr)
        return sched


