"""How a planner's requests build their corridors: PlannerConfig.corridor_backend and grid_polytopes resolved for
the prepared scene and this process, and the keyword arguments of corridor.build_corridor that follow from them.
Functions of a PlanningSpace (space.py)."""
from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from ..host_pool import in_worker, usable_cpus

if TYPE_CHECKING:
    from ..space import PlanningSpace

GRID_POLYTOPE_MAX_VOXEL = 2.0
"""PlannerConfig.grid_polytopes 'auto': grid polytopes when voxel_size <= this x camera_radius (between a ratio where
they were a win and one where they were a loss: docs/PLANNER_DEFAULTS.md)."""

SPLIT_LONG_MARGINS = 2.0
"""With grid polytopes, build_corridor's ``split_long`` is this x the box margin: a longer segment that needs a Prop-2
polytope is split so that its free runs take grid polytopes and its Prop-2 boxes stay small (safe_corridor.py;
docs/PLANNER_DEFAULTS.md)."""


MERGE_SEGMENTS = True
"""A request's corridors merge consecutive segments that one of their polytopes holds (build_corridor's ``merge``,
corridor_trim.merged_pieces): the same safe polytopes, fewer QP segments (1M grove, grid 128: ~16% fewer;
docs/PLANNER_DEFAULTS.md, benchmarks/RESULTS.md issue 37 fourth pass)."""


CORRIDOR_THREADS_MAX = 8
"""PlannerConfig.corridor_threads None: at most this many threads build a request's polytopes (a request has a few to
a dozen polytopes to build; docs/PLANNER_DEFAULTS.md)."""


def corridor_threads(space: "PlanningSpace") -> int:
    """config.corridor_threads resolved for this process: 1 in a candidate worker, the value given, else one per
    usable CPU up to CORRIDOR_THREADS_MAX."""
    if in_worker():
        return 1
    t = space.config.corridor_threads
    return int(t) if t is not None else max(1, min(CORRIDOR_THREADS_MAX, usable_cpus()))


def corridor_backend(space: "PlanningSpace", many: bool = False) -> str:
    """config.corridor_backend resolved for this process: 'batched' or 'cpu'. 'auto': for one request's corridor
    (``many`` False) 'cpu', the compiled host polytopes on the request scene (the CPU mirror of a CUDA scene), unless
    requests themselves run on a CUDA scene (request_device 'scene'), then 'batched'; for a many-corridor batch
    (``many``: stages.legs_corridor, the candidates' two-phase rounds) 'batched' on a CUDA scene, else 'cpu'. One
    request's handful of segments is cheaper on the host than in GPU kernel launches and syncs, in median and tail
    (docs/PLANNER_DEFAULTS.md). Always 'cpu' inside a forked candidate worker, where CUDA cannot be used."""
    b = space.config.corridor_backend
    scene = space.batch_scene
    if in_worker() or (b == "batched" and scene.device.type == "cuda" and torch.cuda._is_in_bad_fork()):
        return "cpu"
    if b == "auto":
        on_cuda = (scene if many else space.scene).device.type == "cuda"
        return "batched" if on_cuda else "cpu"
    return b


def use_grid_polytopes(space: "PlanningSpace") -> bool:
    """config.grid_polytopes resolved for the prepared grid ('auto': voxel_size <= GRID_POLYTOPE_MAX_VOXEL x the
    camera radius)."""
    g = space.config.grid_polytopes
    if g == "auto":
        return float(space.prepared.grid.voxel_size) <= GRID_POLYTOPE_MAX_VOXEL * float(space.scene.camera_radius)
    return bool(g)


def corridor_kwargs(space: "PlanningSpace", many: bool = False) -> dict:
    """Keyword arguments of build_corridor (after waypoints, scene, index) for the planner's requests: the box margin,
    the planning region, the polytope threads (corridor_threads), segment merging (MERGE_SEGMENTS), the grid's voxels
    when grid polytopes are on, and the resolved corridor backend (corridor_backend; ``many``: for build_corridors over
    many ways; the batched one runs on ``batch_scene`` / its index; the corridor's polytopes end up on the request
    device)."""
    prep = space.prepared
    kw = dict(box_margin=space.config.box_margin, region=space.region(), threads=corridor_threads(space),
              merge=MERGE_SEGMENTS)
    if use_grid_polytopes(space):
        kw["grid"] = prep.voxels
        kw["split_long"] = SPLIT_LONG_MARGINS * float(space.config.box_margin)
    if corridor_backend(space, many) == "batched":
        bidx = prep.batch_index if prep.batch_index is not None else prep.index
        kw.update(backend="batched", batch_scene=space.batch_scene, batch_index=bidx)
    return kw
