"""The command lines' option surface (issue 35): the planner's configs nested the nerfstudio way, the daily flags'
short aliases, renamed flags failing with their new name, the viewer speaking the CLI's names, and a docstring under
every config field (tyro's help text)."""
from __future__ import annotations

import ast
import dataclasses
import inspect
import re
import textwrap
import typing

import pytest

from cinenerf_ns.cli.plan_args import RENAMED_FLAGS, PlanArgs
from cinenerf_ns.option_surface import COMMAND_SET, SHORT_FLAGS, parse
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.shots.end_pose import EndPoseConfig
from cinenerf_ns.planner.shots.framing import FramingConfig
from cinenerf_ns.planner.trajectory.dynamics import DynamicLimits
from cinenerf_ns.viewer.standalone import RENAMED_FLAGS as VIEWER_RENAMED, StandaloneConfig

TARGETS = ["--scene", "procedural", "--go-to", "sofa", "--look-at", "lamp"]


def _help(cls, prog: str, capsys) -> str:
    with pytest.raises(SystemExit) as e:
        parse(cls, ["--help"], prog, {})
    assert e.value.code == 0
    return capsys.readouterr().out


def _flags(text: str) -> set:
    return set(re.findall(r"(?<![\w-])--[a-z][a-z0-9.-]*", text))


def test_help_shows_the_nested_configs(capsys):
    flags = _flags(_help(PlanArgs, "cinesplat-plan", capsys))
    for f in ("--planner.grid-resolution", "--planner.region-padding", "--planner.corridor-backend",
              "--trajectory.smoothness-weight", "--trajectory.smoothness-order", "--trajectory.solver",
              "--timing.fps", "--timing.max-speed", "--timing.ease", "--obstacles.beta", "--obstacles.camera-radius",
              "--score.w-occlusion", "--score.clearance-cap", "--unseen-fill", "--no-unseen-fill",
              # the short aliases, and the request's own flags
              "--grid-resolution", "--memory-budget-mb", "--fps", "--max-speed", "--camera-radius", "--scene",
              "--go-to", "--look-at", "--then-go-to", "--candidates", "--output-dir", "--name", "--framing",
              "--region", "--start", "--seed", "--preview", "--safety-margin", "--ignore-floaters", "--no-end-pose"):
        assert f in flags, f
    # what the command sets itself is no flag; nothing is said twice negatively; no trajectory under --planner.
    for f in ("--planner.bounds", "--planner.start-region", "--planner.up", "--planner.obstacles-note",
              "--planner.candidate-workers", "--score.fov-deg", "--planner.trajectory.degree", "--planner.timing.fps"):
        assert f not in flags, f
    assert not [f for f in flags if "no-no-" in f]
    assert not set(RENAMED_FLAGS) & flags


def _broken_lines(text: str) -> list:
    """Help lines that end although the next line's first word would fit: a docstring's own line break."""
    rows = [ln.replace("│", " ") for ln in text.splitlines()]  # boxed on a terminal, plain when captured
    bad = []
    for row, nxt in zip(rows, rows[1:]):
        words, indent = nxt.split(), len(row) - len(row.lstrip())
        if not (words and row.strip() and indent >= 7 and len(nxt) - len(nxt.lstrip()) == indent
                and len(row) == len(nxt)):
            continue
        if len(words[0]) + 1 <= len(row) - len(row.rstrip()) - 1:
            bad.append(row.strip())
    return bad


def test_help_lines_are_whole_sentences(capsys):
    """Each field's docstring is one line of help (tyro would keep its line breaks, mid-sentence)."""
    assert not _broken_lines(_help(PlanArgs, "cinesplat-plan", capsys))
    assert not _broken_lines(_help(StandaloneConfig, "cinesplat-viewer", capsys))
    import tyro

    from cinenerf_ns.planner.shots.planner import PlannerConfig

    with pytest.raises(SystemExit):
        tyro.cli(PlannerConfig, args=["--help"])  # without the rule: the docstrings' own breaks
    assert _broken_lines(capsys.readouterr().out)


def test_old_flags_parse_into_the_nested_configs():
    old = parse(PlanArgs, TARGETS + ["--grid-resolution", "40", "--fps", "24", "--max-speed", "0.3",
                                     "--camera-radius", "0.02", "--memory-budget-mb", "512", "--no-unseen-fill",
                                     "--no-end-pose", "--candidates", "3", "--framing", "close"], "p", RENAMED_FLAGS)
    new = parse(PlanArgs, TARGETS + ["--planner.grid-resolution", "40", "--timing.fps", "24", "--timing.max-speed",
                                     "0.3", "--obstacles.camera-radius", "0.02", "--planner.memory-budget-mb", "512",
                                     "--no-unseen-fill", "--no-end-pose", "--candidates", "3", "--framing", "close"],
                "p", RENAMED_FLAGS)
    assert old == new
    p = old.planner
    assert (p.grid_resolution, p.timing.fps, p.timing.max_speed, p.memory_budget_mb) == (40, 24.0, 0.3, 512.0)
    assert old.obstacles.camera_radius == 0.02 and not old.unseen_fill and not old.end_pose
    assert parse(PlanArgs, TARGETS, "p", RENAMED_FLAGS) == PlanArgs(scene="procedural", go_to="sofa", look_at="lamp")


def test_trajectory_and_score_settings_reach_the_planner(monkeypatch, tmp_path):
    """--trajectory.* (reachable from no command before) and --planner.* arrive in the Planner's config unchanged."""
    import cinenerf_ns.cli.plan_run as plan_mod

    class Stop(Exception):
        pass

    seen = []

    def fake_planner(scene, cfg):
        seen.append(cfg)
        raise Stop

    monkeypatch.setattr(plan_mod, "Planner", fake_planner)
    args = parse(PlanArgs, ["--scene", "procedural:3000:1", "--go-to", "armchair", "--look-at", "floor lamp",
                            "--output-dir", str(tmp_path), "--trajectory.smoothness-weight", "2.5",
                            "--trajectory.smoothness-order", "2", "--timing.no-ease", "--planner.box-margin", "0.2",
                            "--planner.grid-polytopes", "off", "--grid-resolution", "40", "--workers", "0"],
                 "p", RENAMED_FLAGS)
    with pytest.raises(Stop):
        plan_mod.run_plan(args)
    cfg = seen[0]
    assert (cfg.trajectory.smoothness_weight, cfg.trajectory.smoothness_order) == (2.5, 2)
    assert (cfg.timing.ease, cfg.box_margin, cfg.grid_polytopes, cfg.grid_resolution) == (False, 0.2, False, 40)
    assert cfg.start_region is not None and cfg.candidate_workers == 0  # set by the command, not by a flag


@pytest.mark.parametrize("old", sorted(RENAMED_FLAGS))
def test_a_renamed_flag_names_its_replacement(old):
    with pytest.raises(InvalidInputError, match=f"{re.escape(old)} was renamed: use {re.escape(RENAMED_FLAGS[old])}"):
        parse(PlanArgs, TARGETS + [old, "1"], "p", RENAMED_FLAGS)


def test_renamed_flags_are_no_flags_any_more(capsys):
    """Every replacement exists, every old spelling is gone (else the error would hide a working flag)."""
    plan = _flags(_help(PlanArgs, "cinesplat-plan", capsys))
    viewer = _flags(_help(StandaloneConfig, "cinesplat-viewer", capsys))
    for renamed, flags in ((RENAMED_FLAGS, plan), (VIEWER_RENAMED, viewer)):
        for old, new in renamed.items():
            assert old not in flags and new in flags, (old, new)


def test_the_viewer_speaks_the_cli_names(capsys):
    viewer = _flags(_help(StandaloneConfig, "cinesplat-viewer", capsys))
    plan = _flags(_help(PlanArgs, "cinesplat-plan", capsys))
    assert "--load-config" in viewer  # nerfstudio's name for a run, kept
    shared = {"--scene", "--candidates", "--output-dir", "--device", "--safety-margin", "--grid-resolution",
              "--max-speed", "--camera-radius", "--trajectory.smoothness-weight", "--planner.region-padding",
              "--obstacles.beta", "--timing.fps"}
    assert shared <= viewer & plan, shared - (viewer & plan)
    cfg = parse(StandaloneConfig, ["--scene", "procedural:2000", "--candidates", "5", "--grid-resolution", "48",
                                   "--trajectory.smoothness-weight", "3"], "v", VIEWER_RENAMED)
    assert (cfg.load_config, cfg.candidates, cfg.planner.grid_resolution) == ("procedural:2000", 5, 48)
    assert cfg.planner.trajectory.smoothness_weight == 3.0
    assert parse(StandaloneConfig, ["--load-config", "x.ply"], "v", VIEWER_RENAMED).load_config == "x.ply"


def _configs(root) -> list:
    """The dataclasses a command's options are made of (root and every nested config), once each."""
    out, todo = [], [root]
    while todo:
        c = todo.pop()
        if c in out:
            continue
        out.append(c)
        todo.extend(t for t in typing.get_type_hints(c).values() if isinstance(t, type) and dataclasses.is_dataclass(t))
    return out


def _undocumented(cls) -> list:
    """Fields of ``cls`` with no string statement right under them (the docstring tyro shows as help)."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    body = tree.body[0].body
    return [s.target.id for i, s in enumerate(body) if isinstance(s, ast.AnnAssign)
            and not (i + 1 < len(body) and isinstance(body[i + 1], ast.Expr)
                     and isinstance(body[i + 1].value, ast.Constant) and isinstance(body[i + 1].value.value, str))]


CONFIGS = sorted({c for root in (PlanArgs, StandaloneConfig) for c in _configs(root)}
                 | {EndPoseConfig, FramingConfig, DynamicLimits}, key=lambda c: c.__name__)


@pytest.mark.parametrize("cls", CONFIGS, ids=lambda c: c.__name__)
def test_every_config_field_has_a_docstring(cls):
    assert not _undocumented(cls), f"{cls.__name__}: fields without a docstring: {_undocumented(cls)}"


def test_the_surface_tables_name_real_fields():
    for cls, names in COMMAND_SET.items():
        assert set(names) <= {f.name for f in dataclasses.fields(cls)}, cls
    for (cls, name), flag in SHORT_FLAGS.items():
        assert name in {f.name for f in dataclasses.fields(cls)} and flag.startswith("--"), (cls, name)
    assert len({c.__name__ for c in CONFIGS}) >= 8


def test_the_readme_names_only_flags_that_exist(capsys):
    """The README's cinesplat-plan section and limits, and its cinesplat-viewer bullet, name flags the commands have."""
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    plan = _flags(_help(PlanArgs, "cinesplat-plan", capsys))
    viewer = _flags(_help(StandaloneConfig, "cinesplat-viewer", capsys))
    headless = text[text.index("### Headless"):text.index("### Evaluate")] + text[text.index("## Known limits"):]
    bullet = next(p for p in text.split("\n* ") if p.startswith("No GPU: `cinesplat-viewer")).split("\n\n")[0]
    for section, flags in ((headless, plan), (bullet, viewer)):
        named = _flags(section)
        assert named, section[:80]
        for f in named:
            assert f in flags or (f.endswith(".") and any(g.startswith(f) for g in flags)), f
