"""How the planner's config dataclasses appear on cinesplat-plan's and cinesplat-viewer's command lines: nested the
nerfstudio way (``--planner.grid-resolution``, ``--trajectory.smoothness-weight``, ``--score.w-occlusion``), each
field declared once, in its config.

A tyro constructor rule (``REGISTRY``, passed to ``tyro.cli`` by ``parse``) adjusts how those dataclasses are shown,
without touching them: it hides the fields a command fills itself (COMMAND_SET), gives the few flags users type daily
their short spelling as an alias (SHORT_FLAGS), lifts the planner's trajectory and timing settings out of the
``--planner.`` prefix (UNPREFIXED) and makes every field's docstring one line of help. A flag that was renamed fails
with its new name (``renamed_flag``) instead of tyro's generic "unrecognized option"."""
from __future__ import annotations

import dataclasses
import functools
import re
import sys
import threading
from typing import Annotated, Any, Callable, Dict, List, Optional, Sequence, Type, TypeVar

import tyro
from tyro.constructors import ConstructorRegistry, StructConstructorSpec, StructFieldSpec, StructTypeInfo

from cinenerf_ns.planner.config import PlannerConfig
from cinenerf_ns.planner.errors import InvalidInputError
from cinenerf_ns.planner.scene.scene_config import SceneConfig
from cinenerf_ns.planner.shots.score_config import ScoreConfig
from cinenerf_ns.planner.trajectory.timing import TimingConfig

T = TypeVar("T")

COMMAND_SET: Dict[type, tuple] = {
    PlannerConfig: ("bounds", "bounds_rule", "start_region", "up", "obstacles_note", "candidate_workers"),
    ScoreConfig: ("fov_deg",),
}
"""Config fields a command sets itself (from --region or the scene, --up, the floater rule, --workers, --fov): not
flags of their own."""
SHORT_FLAGS: Dict[tuple, str] = {
    (PlannerConfig, "grid_resolution"): "--grid-resolution",
    (PlannerConfig, "memory_budget_mb"): "--memory-budget-mb",
    (TimingConfig, "max_speed"): "--max-speed",
    (TimingConfig, "fps"): "--fps",
    (SceneConfig, "camera_radius"): "--camera-radius",
    (SceneConfig, "opacity_floor"): "--opacity-floor",
}
"""(config, field) -> the short alias of its nested flag, for the settings users change daily (--opacity-floor:
the planner's empty-scene message names it)."""
UNPREFIXED = {(PlannerConfig, "trajectory"), (PlannerConfig, "timing")}
"""Nested configs shown as ``--trajectory.*`` / ``--timing.*`` rather than ``--planner.trajectory.*``."""

_busy = threading.local()


def one_line(text: Optional[str]) -> Optional[str]:
    """A field docstring as one line of help (tyro keeps a docstring's line breaks)."""
    return None if text is None else " ".join(str(text).split())


def _help(helptext: Any) -> Optional[str]:
    return one_line(helptext() if callable(helptext) else helptext)


def _field_type(owner: type, f: StructFieldSpec) -> Any:
    if f.name in COMMAND_SET.get(owner, ()):
        return Annotated[f.type, tyro.conf.Suppress]
    if (owner, f.name) in SHORT_FLAGS:
        return Annotated[f.type, tyro.conf.arg(aliases=(SHORT_FLAGS[(owner, f.name)],))]
    if (owner, f.name) in UNPREFIXED:
        return Annotated[f.type, tyro.conf.arg(prefix_name=False)]
    return f.type


def _rule(info: StructTypeInfo) -> Optional[StructConstructorSpec]:
    """tyro's own spec of a cinenerf_ns dataclass, with COMMAND_SET hidden, SHORT_FLAGS, UNPREFIXED, one-line help."""
    t = info.type
    busy = getattr(_busy, "types", None)
    if busy is None:
        busy = _busy.types = set()
    if not dataclasses.is_dataclass(t) or not t.__module__.startswith("cinenerf_ns") or t in busy:
        return None
    busy.add(t)
    try:
        base = ConstructorRegistry.get_struct_spec(info)  # the default dataclass rule (this rule declines: busy)
    finally:
        busy.discard(t)
    if not isinstance(base, StructConstructorSpec):
        return None
    fields = tuple(dataclasses.replace(f, type=_field_type(t, f), helptext=functools.partial(_help, f.helptext))
                   for f in base.fields)
    return StructConstructorSpec(instantiate=base.instantiate, fields=fields)


REGISTRY = ConstructorRegistry()
REGISTRY.struct_rule(_rule)


def renamed_flag(argv: Sequence[str], renamed: Dict[str, str]) -> Optional[str]:
    """The message for the first flag of ``argv`` that was renamed (``renamed``: old flag -> new), else None."""
    for a in argv:
        old = str(a).split("=", 1)[0]
        if old in renamed:
            return f"{old} was renamed: use {renamed[old]}"
    return None


def parse(cls: Type[T], argv: Optional[Sequence[str]], prog: str, renamed: Dict[str, str]) -> T:
    """``tyro.cli`` of a command's options with this module's rule (tyro's own parse errors exit with status 2); a
    renamed flag is an InvalidInputError naming its replacement."""
    args: List[str] = list(sys.argv[1:] if argv is None else argv)
    message = renamed_flag(args, renamed)
    if message is not None:
        raise InvalidInputError(message)
    return tyro.cli(cls, args=args, prog=prog, registry=REGISTRY)


def flag_name(owner: type, field: str, prefix: str) -> str:
    """The flag a user types for ``owner.field`` under ``prefix`` (e.g. '--planner'): its short alias if it has one."""
    return SHORT_FLAGS.get((owner, field), f"{prefix}.{field.replace('_', '-')}")


def with_flag_names(message: str, config: Any, prefix: str) -> str:
    """``message`` with each field name of ``config`` (a dataclass under ``prefix``) written as the user's flag:
    a config's validate() speaks of 'active_set_tolerance', the command line of '--trajectory.active-set-tolerance'."""
    owner = type(config)
    for f in dataclasses.fields(config):
        if "_" in f.name and not dataclasses.is_dataclass(getattr(config, f.name)):
            message = re.sub(rf"(?<![\w.-]){re.escape(f.name)}(?![\w-])", flag_name(owner, f.name, prefix), message)
    return message


def validated(what: str, check: Callable[[], None]) -> None:
    """Run a config's validate() (a bound method); its InvalidInputError is said with the flags it is about, or with
    the flag prefix it belongs to when it names no field."""
    try:
        check()
    except InvalidInputError as e:
        config = getattr(check, "__self__", None)
        message = str(e)
        if dataclasses.is_dataclass(config):
            named = with_flag_names(message, config, what)
            if named != message:
                raise InvalidInputError(named) from e
        raise InvalidInputError(f"{what}: {message}") from e
