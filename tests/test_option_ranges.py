"""Every number of the planner's nested configs has a range (option_ranges.RANGES), is checked before any work, and
the message names the flag a user types (issue 38, second round: NaN weights, zero threads and a quantile of 1e12 had
reached the solver or torch)."""
from __future__ import annotations

import dataclasses
import math
import typing

import pytest

from cinenerf_ns.cli.plan_args import RENAMED_FLAGS, PlanArgs, check_args
from cinenerf_ns.option_ranges import RANGES, check_config_ranges, flag_name
from cinenerf_ns.option_surface import COMMAND_SET, UNPREFIXED, parse
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.shots.planner import PlannerConfig
from cinenerf_ns.planner.shots.score_config import ScoreConfig
from cinenerf_ns.planner.trajectory.qp_config import TrajectoryConfig
from cinenerf_ns.planner.trajectory.timing import TimingConfig
from cinenerf_ns.viewer.standalone import RENAMED_FLAGS as VIEWER_RENAMED, StandaloneConfig, check_config

TARGETS = ["--scene", "procedural", "--go-to", "sofa", "--look-at", "lamp"]
PREFIX = {PlannerConfig: "--planner", TrajectoryConfig: "--trajectory", TimingConfig: "--timing",
          SceneConfig: "--obstacles", ScoreConfig: "--score"}


def _numeric(tp) -> bool:
    args = [a for a in typing.get_args(tp) if a is not type(None)] if typing.get_origin(tp) is typing.Union else [tp]
    return bool(args) and all(a in (int, float) for a in args)


@pytest.mark.parametrize("cls", list(PREFIX))
def test_every_number_a_command_line_sets_has_a_range(cls):
    hints = typing.get_type_hints(cls)
    numbers = {f.name for f in dataclasses.fields(cls) if _numeric(hints[f.name])} - set(COMMAND_SET.get(cls, ()))
    missing = sorted(n for n in numbers if (cls, n) not in RANGES)
    assert not missing, f"{cls.__name__}: numeric fields without a range in option_ranges.RANGES: {missing}"
    assert numbers, cls  # the scan sees the fields at all


def test_the_defaults_are_inside_their_ranges():
    check_config_ranges([("--planner", PlannerConfig()), ("--obstacles", SceneConfig()), ("--score", ScoreConfig())])


def _bad_values(rng):
    bad = [math.nan, math.inf, rng.hi * 2 + 1]
    bad.append(rng.lo if rng.lo_open else rng.lo - 1)
    if rng.integer:
        bad.append(rng.lo + 0.5)
    if not rng.none_ok:
        bad.append(None)
    return bad


def _with(owner, field, value):
    """Root configs (PlannerConfig, SceneConfig, ScoreConfig) with ``owner.field = value``."""
    planner, obstacles, score = PlannerConfig(), SceneConfig(), ScoreConfig()
    if owner is TrajectoryConfig:
        planner = dataclasses.replace(planner, trajectory=dataclasses.replace(planner.trajectory, **{field: value}))
    elif owner is TimingConfig:
        planner = dataclasses.replace(planner, timing=dataclasses.replace(planner.timing, **{field: value}))
    elif owner is PlannerConfig:
        planner = dataclasses.replace(planner, **{field: value})
    elif owner is SceneConfig:
        obstacles = dataclasses.replace(obstacles, **{field: value})
    else:
        score = dataclasses.replace(score, **{field: value})
    return [("--planner", planner), ("--obstacles", obstacles), ("--score", score)]


def _flag(owner, field):
    prefix = PREFIX[owner]
    if owner in (TrajectoryConfig, TimingConfig):
        assert (PlannerConfig, owner.__name__.replace("Config", "").lower()) in UNPREFIXED
    return flag_name(owner, field, prefix)


@pytest.mark.parametrize("key", sorted(RANGES, key=lambda k: (k[0].__name__, k[1])), ids=lambda k: k[1])
def test_each_number_out_of_range_is_refused_naming_its_flag(key):
    owner, field = key
    rng = RANGES[key]
    flag = _flag(owner, field)
    for value in _bad_values(rng):
        with pytest.raises(InvalidInputError) as e:
            check_config_ranges(_with(owner, field, value))
        msg = str(e.value)
        assert msg.startswith(f"{flag} must be"), msg
        assert f"{rng.hi:g}" in msg and f"{rng.lo:g}" in msg, msg  # the allowed range is said
    check_config_ranges(_with(owner, field, rng.hi))  # the bounds themselves are allowed
    if not rng.lo_open:
        check_config_ranges(_with(owner, field, rng.lo))


@pytest.mark.parametrize("key", sorted(RANGES, key=lambda k: (k[0].__name__, k[1])), ids=lambda k: k[1])
def test_the_named_flag_is_a_real_flag_of_cinesplat_plan(key):
    owner, field = key
    rng = RANGES[key]
    flag = _flag(owner, field)
    value = rng.hi if not rng.integer else int(rng.hi)
    args = parse(PlanArgs, TARGETS + [flag, str(value)], "cinesplat-plan", RENAMED_FLAGS)
    configs = dict(_with(owner, field, value))
    assert (args.planner, args.obstacles, args.score) == (configs["--planner"], configs["--obstacles"],
                                                          configs["--score"])


@pytest.mark.parametrize("argv, flag", [
    (["--trajectory.nominal-speed", "nan"], "--trajectory.nominal-speed"),
    (["--planner.plan-cpu-threads", "0"], "--planner.plan-cpu-threads"),
    (["--planner.robust-bounds-quantile", "1e12"], "--planner.robust-bounds-quantile"),
    (["--planner.box-margin", "0"], "--planner.box-margin"),
    (["--score.w-jerk", "inf"], "--score.w-jerk"),
    (["--max-speed", "nan"], "--max-speed"),
])
def test_cinesplat_plan_refuses_before_loading(argv, flag, tmp_path):
    args = parse(PlanArgs, TARGETS + ["--output-dir", str(tmp_path / "out")] + argv, "cinesplat-plan",
                 RENAMED_FLAGS)
    with pytest.raises(InvalidInputError, match=f"^{flag} must be"):
        check_args(args)
    assert not (tmp_path / "out").exists()


def test_the_viewer_checks_the_same_ranges():
    cfg = parse(StandaloneConfig, ["--scene", "procedural", "--trajectory.smoothness-weight", "nan"],
                "cinesplat-viewer", VIEWER_RENAMED)
    with pytest.raises(InvalidInputError, match="^--trajectory.smoothness-weight must be"):
        check_config(cfg)


@pytest.mark.parametrize("argv, expect", [
    (["--trajectory.margin", "0"], "--trajectory.active-set-tolerance must be below the polytope margin"),
    (["--trajectory.rest-at-ends", "3"], "--trajectory.rest-at-ends=3 pins 4 control points"),
    (["--trajectory.smoothness-weight", "0", "--trajectory.length-weight", "0"],
     "--trajectory.smoothness-weight and --trajectory.length-weight must be >= 0 and not both zero"),
    (["--planner.region-rule", "nope"], "--planner.region-rule must be one of"),
])
def test_relations_between_fields_are_said_with_the_flags(argv, expect, tmp_path):
    args = parse(PlanArgs, TARGETS + ["--output-dir", str(tmp_path / "out")] + argv, "cinesplat-plan",
                 RENAMED_FLAGS)
    with pytest.raises(InvalidInputError) as e:
        check_args(args)
    assert str(e.value).startswith(expect), str(e.value)
