"""How a planner's requests build their corridors: PlannerConfig.corridor_backend and grid_polytopes resolved for
the prepared scene and this process, and the keyword arguments of corridor.build_corridor that follow from them.
Functions of a prepared Planner (planner.py), which exposes them as methods."""
from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from ..shots.workers import in_worker, usable_cpus

if TYPE_CHECKING:
    from ..shots.planner import Planner

GRID_POLYTOPE_MAX_VOXEL = 2.0
"""PlannerConfig.grid_polytopes 'auto': grid polytopes when voxel_size <= this x camera_radius (between a ratio where
they were a win and one where they were a loss: docs/PLANNER_DEFAULTS.md)."""

SPLIT_LONG_MARGINS = 2.0
"""With grid polytopes, build_corridor's ``split_long`` is this x the box margin: a longer segment that needs a Prop-2
polytope is split so that its free runs take grid polytopes and its Prop-2 boxes stay small (safe_corridor.py;
docs/PLANNER_DEFAULTS.md)."""


CORRIDOR_THREADS_MAX = 8
"""PlannerConfig.corridor_threads None: at most this many threads build a request's polytopes (a request has a few to
a dozen polytopes to build; docs/PLANNER_DEFAULTS.md)."""


def corridor_threads(planner: "Planner") -> int:
    """config.corridor_threads resolved for this process: 1 in a candidate worker, the value given, else one per
    usable CPU up to CORRIDOR_THREADS_MAX."""
    if in_worker():
        return 1
    t = planner.config.corridor_threads
    return int(t) if t is not None else max(1, min(CORRIDOR_THREADS_MAX, usable_cpus()))


def corridor_backend(planner: "Planner", many: bool = False) -> str:
    """config.corridor_backend resolved for this process: 'batched' or 'cpu'. 'auto': for one request's corridor
    (``many`` False) 'cpu', the compiled host polytopes on the request scene (the CPU mirror of a CUDA scene), unless
    requests themselves run on a CUDA scene (request_device 'scene'), then 'batched'; for a many-corridor batch
    (``many``: stages.legs_corridor, the candidates' two-phase rounds) 'batched' on a CUDA scene, else 'cpu'. One
    request's handful of segments is cheaper on the host than in GPU kernel launches and syncs, in median and tail
    (docs/PLANNER_DEFAULTS.md). Always 'cpu' inside a forked candidate worker, where CUDA cannot be used."""
    b = planner.config.corridor_backend
    scene = planner.batch_scene
    if in_worker() or (b == "batched" and scene.device.type == "cuda" and torch.cuda._is_in_bad_fork()):
        return "cpu"
    if b == "auto":
        on_cuda = (scene if many else planner.scene).device.type == "cuda"
        return "batched" if on_cuda else "cpu"
    return b


def use_grid_polytopes(planner: "Planner") -> bool:
    """config.grid_polytopes resolved for the prepared grid ('auto': voxel_size <= GRID_POLYTOPE_MAX_VOXEL x the
    camera radius)."""
    g = planner.config.grid_polytopes
    if g == "auto":
        return float(planner.ready().grid.voxel_size) <= GRID_POLYTOPE_MAX_VOXEL * float(planner.scene.camera_radius)
    return bool(g)


def corridor_kwargs(planner: "Planner", many: bool = False) -> dict:
    """Keyword arguments of build_corridor (after waypoints, scene, index) for the planner's requests: the box margin,
    the planning region, the polytope threads (corridor_threads), the grid's voxels when grid polytopes are on, and
    the resolved corridor backend (corridor_backend; ``many``: for build_corridors over many ways; the batched one
    runs on ``batch_scene`` / its index; the corridor's polytopes end up on the request device)."""
    prep = planner.ready()
    kw = dict(box_margin=planner.config.box_margin, region=planner.region(), threads=corridor_threads(planner))
    if use_grid_polytopes(planner):
        kw["grid"] = prep.voxels
        kw["split_long"] = SPLIT_LONG_MARGINS * float(planner.config.box_margin)
    if corridor_backend(planner, many) == "batched":
        bidx = prep.batch_index if prep.batch_index is not None else prep.index
        kw.update(backend="batched", batch_scene=planner.batch_scene, batch_index=bidx)
    return kw
