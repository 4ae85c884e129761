"""The allowed range of every number a user can set in the planner's nested configs (``--planner.*``,
``--trajectory.*``, ``--timing.*``, ``--obstacles.*``, ``--score.*``), checked before any scene is loaded.

One table, ``RANGES``: (config class, field) -> Range. ``check_config_ranges`` walks the configs a command parsed and
raises InvalidInputError naming the flag as the user typed it (``--trajectory.nominal-speed``, or its short alias
``--max-speed``) and its range. The configs' own ``validate()`` still checks the relations between fields (continuity
below the degree, ...); this table keeps NaN, infinities and absurd sizes away from them. A test holds every numeric
field of those configs to an entry here, so a new field cannot arrive unchecked."""
from __future__ import annotations

import dataclasses
from typing import Any, Dict, NamedTuple, Sequence, Tuple

from cinenerf_ns.option_surface import COMMAND_SET, UNPREFIXED, flag_name
from cinenerf_ns.options import check_number
from cinenerf_ns.planner.config import GRID_RESOLUTION_RANGE, PlannerConfig
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.shots.score_config import ScoreConfig
from cinenerf_ns.planner.trajectory.qp_config import TrajectoryConfig
from cinenerf_ns.planner.trajectory.timing import MAX_FPS, MIN_FPS, TimingConfig


class Range(NamedTuple):
    lo: float
    hi: float
    integer: bool = False
    lo_open: bool = False  # (lo, hi] instead of [lo, hi]
    none_ok: bool = False  # None is allowed (the field's "automatic" / "off")


WEIGHT = Range(0.0, 1e6)
POSITIVE_SCALE = Range(0.0, 1e6, lo_open=True)
TOLERANCE = Range(0.0, 1e-2, lo_open=True)
THREADS = Range(1, 256, integer=True, none_ok=True)

RANGES: Dict[Tuple[type, str], Range] = {
    (PlannerConfig, "grid_resolution"): Range(*GRID_RESOLUTION_RANGE, integer=True),
    (PlannerConfig, "max_voxel_radii"): Range(0.0, 100.0, lo_open=True, none_ok=True),
    (PlannerConfig, "start_look_distance"): Range(0.0, 0.99),
    (PlannerConfig, "astar_weight"): Range(1.0, 100.0),
    (PlannerConfig, "box_margin"): Range(0.0, 100.0, lo_open=True),
    # below 1e-4 a long shot would need millions of samples; above 0.05 the sampled check would skip thin obstacles
    (PlannerConfig, "verify_spacing"): Range(1e-4, 0.05),
    (PlannerConfig, "robust_bounds_quantile"): Range(0.0, 0.49),
    (PlannerConfig, "region_padding"): Range(0.0, 10.0),
    (PlannerConfig, "memory_budget_mb"): Range(64, 2**20),
    (PlannerConfig, "far_limit"): Range(0.0, 1000.0, lo_open=True),
    (PlannerConfig, "max_attempts_per_candidate"): Range(1, 1000, integer=True),
    (PlannerConfig, "plan_cpu_threads"): THREADS,
    (PlannerConfig, "corridor_threads"): THREADS,
    (TrajectoryConfig, "degree"): Range(1, 12, integer=True),
    (TrajectoryConfig, "continuity"): Range(0, 11, integer=True),
    (TrajectoryConfig, "smoothness_order"): Range(1, 12, integer=True),
    (TrajectoryConfig, "smoothness_weight"): WEIGHT,
    (TrajectoryConfig, "length_weight"): WEIGHT,
    (TrajectoryConfig, "nominal_speed"): Range(0.0, 100.0, lo_open=True),
    (TrajectoryConfig, "min_segment_duration"): Range(0.0, 60.0, lo_open=True),
    (TrajectoryConfig, "rest_at_ends"): Range(0, 5, integer=True),
    (TrajectoryConfig, "margin"): Range(0.0, 0.1),
    (TrajectoryConfig, "osqp_margin"): Range(0.0, 0.1),
    (TrajectoryConfig, "max_iter"): Range(1, 100_000, integer=True),
    (TrajectoryConfig, "tolerance"): TOLERANCE,
    (TrajectoryConfig, "active_set_tolerance"): Range(0.0, 1e-2),
    (TrajectoryConfig, "osqp_tolerance"): TOLERANCE,
    (TimingConfig, "max_speed"): Range(0.0, 100.0, lo_open=True),
    (TimingConfig, "max_acceleration"): Range(0.0, 1000.0, lo_open=True, none_ok=True),
    (TimingConfig, "fps"): Range(MIN_FPS, MAX_FPS),
    (TimingConfig, "table_samples_per_segment"): Range(2, 4096, integer=True),
    (TimingConfig, "max_frames"): Range(2, 1_000_000, integer=True),
    (SceneConfig, "beta"): Range(0.0, 10.0, lo_open=True),
    (SceneConfig, "camera_radius"): Range(0.0, 10.0),
    (SceneConfig, "opacity_floor"): Range(0.0, 0.999),
    (SceneConfig, "min_axis"): Range(0.0, 10.0),
    (SceneConfig, "max_axis"): Range(0.0, 1e6, lo_open=True, none_ok=True),
    **{(ScoreConfig, f.name): WEIGHT for f in dataclasses.fields(ScoreConfig) if f.name.startswith("w_")},
    (ScoreConfig, "target_fill"): Range(0.0, 1.0, lo_open=True),
    (ScoreConfig, "clearance_ref"): POSITIVE_SCALE,
    (ScoreConfig, "jerk_ref"): POSITIVE_SCALE,
    (ScoreConfig, "angular_rate_ref"): POSITIVE_SCALE,
    (ScoreConfig, "duration_ref"): POSITIVE_SCALE,
    (ScoreConfig, "occlusion_frames"): Range(1, 4096, integer=True),
    (ScoreConfig, "visibility_frames"): Range(1, 1024, integer=True),
    (ScoreConfig, "clearance_cap"): Range(0.0, 1e6, lo_open=True, none_ok=True),
}
"""(config, field) -> allowed values of every number a command line can set."""


def _nested_prefix(owner: type, field: str, prefix: str) -> str:
    return f"--{field}" if (owner, field) in UNPREFIXED else f"{prefix}.{field.replace('_', '-')}"


def check_config_ranges(configs: Sequence[Tuple[str, Any]]) -> None:
    """InvalidInputError naming the flag and its range for the first number out of RANGES, in the (prefix, config)
    pairs a command parsed (e.g. ('--planner', args.planner)); nested configs are followed with their own prefix."""
    for prefix, cfg in configs:
        owner = type(cfg)
        for f in dataclasses.fields(cfg):
            value = getattr(cfg, f.name)
            if dataclasses.is_dataclass(value):
                check_config_ranges([(_nested_prefix(owner, f.name, prefix), value)])
                continue
            rng = RANGES.get((owner, f.name))
            if rng is None or f.name in COMMAND_SET.get(owner, ()) or (value is None and rng.none_ok):
                continue
            check_number(value, flag_name(owner, f.name, prefix), rng.lo, rng.hi, rng.lo_open, rng.integer)
