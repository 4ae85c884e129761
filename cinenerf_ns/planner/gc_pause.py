"""Python's cyclic garbage collector paused while a request runs (PlannerConfig.pause_gc).

Why: a prepared 1M-Gaussian scene leaves ~210k objects tracked by the collector, and a request allocates thousands of
small ones, so collections start inside requests, and each older-generation one walks every tracked object (on the
CPU box at 1M Gaussians the collector took ~6% of request time in a profile). Reference counting still frees every
acyclic object at once; reference cycles made during a request are freed after it, when the collector runs again.
Measured: docs/PLANNER_DEFAULTS.md.

Nested or concurrent requests (viewer callbacks run in threads): the request that turned the collector off turns it
back on; one that found it off leaves it off.
"""
from __future__ import annotations

import contextlib
import gc


@contextlib.contextmanager
def paused_gc(pause: bool = True):
    """The cyclic collector off inside the block when ``pause`` (and it was on), back on afterwards."""
    was_on = pause and gc.isenabled()
    if was_on:
        gc.disable()
    try:
        yield
    finally:
        if was_on:
            gc.enable()
