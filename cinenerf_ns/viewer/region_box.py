"""The planning region in the viewer: what a page shows of it (a box, its corners, the rule that chose it) and the
panel's Apply / Reset to automatic / show-hide logic. No viser import: the widgets and the box are drawn by
``region_ui.RegionWidgets``; the region itself belongs to the planner (``planner_backend.PreparedPlanner``, a
:class:`RegionSource`), shared by every page of a viewer.

The checks are the planner's (``user_box.user_box``, ``planning_region.check_user_box`` / ``check_region``, the same as
``cinesplat-plan --region``): a bad box (empty, inverted, not finite, outside the scene, too thin for the camera, a
grid over the memory budget) is refused before any preparation, with the planner's message."""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Callable, Optional, Protocol, Sequence

import numpy as np

from cinenerf_ns.planner.errors import InvalidInputError, PlanningError
from cinenerf_ns.planner.scene.user_box import format_point

log = logging.getLogger(__name__)

AUTOMATIC = "automatic"
"""RegionInfo.rule while an automatic region is being prepared (its rule is known once prepared)."""


@dataclass
class RegionInfo:
    """The planner's planning region as a page shows it."""

    lo: Optional[np.ndarray]
    """[3] scene units: the prepared region (the occupancy grid's box, which paths never leave), or the box asked for
    while it is prepared; None while an automatic region is prepared."""
    hi: Optional[np.ndarray]
    """[3], as ``lo``."""
    rule: str
    """What chose it, in words: 'automatic: training cameras', 'automatic: dense content', 'user box', 'stored in the
    export' (planner.region_rule())."""
    state: str = "ready"
    """'preparing' | 'ready' | 'error' | 'later' (ns-viewer before the first Plan: prepared by the next Plan)."""
    error: str = ""
    """Why the planner could not prepare this region (state 'error')."""
    generation: int = 0
    """0: the region the viewer opened with; each Apply / Reset adds one."""
    automatic: bool = True
    """Whether the region is the planner's automatic choice (no box given), 'Reset to automatic' then does nothing."""
    asked: Optional[tuple] = None
    """(lo [3], hi [3]) the box given (user box, stored in the export), None for the automatic region: the fold's
    corners show it as given; ``lo`` / ``hi`` are the prepared box, rounded out to whole voxels."""

    def box_text(self) -> str:
        """'(x, y, z)..(x, y, z)' or '(not known yet)'."""
        if self.lo is None or self.hi is None:
            return "(not known yet)"
        return f"{format_point(self.lo)}..{format_point(self.hi)}"

    def describe(self) -> str:
        """'the planning region (x, y, z)..(x, y, z), chosen by: automatic: training cameras'."""
        return f"the planning region {self.box_text()}, chosen by: {self.rule}"

    def region_option(self) -> str:
        """The cinesplat-plan option that plans in this box (the one given, else the prepared one): --region "x0 y0 z0
        x1 y1 z1" ("" when not known)."""
        lo, hi = self.asked if self.asked is not None else (self.lo, self.hi)
        if lo is None or hi is None:
            return ""
        return "--region \"" + " ".join(f"{v:.6g}" for v in (*lo, *hi)) + "\""


class RegionSource(Protocol):
    """The planner side of the region (``PreparedPlanner``)."""

    def region_info(self) -> Optional[RegionInfo]:
        """The current region (None before the first preparation started)."""

    def set_region(self, bounds: Optional[Sequence[Any]]) -> RegionInfo:
        """Plan in ``bounds`` (lo [3], hi [3]) or, with None, the automatic region: checked at once (InvalidInputError
        with the planner's message), then prepared in the background."""

    def add_region_listener(self, fn: Callable[[], None]) -> None:
        """Call ``fn()`` whenever the region or its state changed (from any thread)."""


def notify_all(listeners: Sequence[Callable[[], None]]) -> None:
    """Call every region listener; one that fails (a page that left) does not stop the others or the caller."""
    for fn in list(listeners):
        try:
            fn()
        except Exception:
            log.debug("a planning-region listener failed", exc_info=True)


def corners(lo: Sequence[float], hi: Sequence[float]) -> tuple:
    """(lo, hi) as float64 [3] arrays; InvalidInputError naming the corner unless each is 3 numbers (the box's own
    rules are the planner's: RegionSource.set_region)."""
    out = []
    for v, what in ((lo, "low corner"), (hi, "high corner")):
        try:
            a = np.asarray(v, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError) as e:
            raise InvalidInputError(f"the planning region's {what} must be 3 numbers x y z, got {v!r}") from e
        if a.shape != (3,):
            raise InvalidInputError(f"the planning region's {what} must be 3 numbers x y z, got {a.size}")
        out.append(a)
    return tuple(out)


class RegionMixin:
    """The panel's part for the planning region (``CinePanel`` inherits it). ``region_source``: the viewer's planner
    (None: a backend without a planning region; the buttons then say so). The view may implement
    ``show_region(info)`` (the fold's corners and rule) and ``draw_region(info)`` (the box; None removes it)."""

    region_source: Optional[RegionSource] = None
    show_region_box: bool = True

    def region_info(self) -> Optional[RegionInfo]:
        src = self.region_source
        return None if src is None else src.region_info()

    def _region_call(self, method: str, *args) -> None:
        fn = getattr(self.view, method, None)
        if fn is None:
            return
        try:
            fn(*args)
        except Exception:  # a broken view must not take the panel down
            log.exception("view.%s failed", method)

    def _set_region(self, bounds: Optional[tuple], what: str) -> Optional[RegionInfo]:
        src = self.region_source
        if src is None:
            self._fail(what, InvalidInputError("this viewer's planner has no planning region to set"))
            return None
        try:
            info = src.set_region(bounds)
        except (PlanningError, ValueError, TypeError) as err:
            self._fail(what, err)
            self._show_region(self.region_info())  # the fold shows the region in use again, not the refused numbers
            return None
        return info

    def apply_region(self, lo: Sequence[float], hi: Sequence[float]) -> bool:
        """Plan in the box [lo, hi] from now on (every page: the planner is shared). A bad box is refused at once with
        the planner's message and the region in use stays; a good one is prepared in the background (said in the
        status; a Plan pressed meanwhile waits for it)."""
        try:
            bounds = corners(lo, hi)
        except InvalidInputError as err:
            self._fail("Planning region", err)
            return False
        info = self._set_region(bounds, "Planning region")
        if info is None:
            return False
        self._set_status(f"Planning region set to {info.box_text()} (user box): {_when(info)}", _level(info))
        return True

    def reset_region(self) -> bool:
        """Back to the planner's automatic region (training cameras, else the dense content), prepared in the
        background."""
        info = self._set_region(None, "Reset to automatic")
        if info is None:
            return False
        self._set_status(f"Planning region back to automatic: {_when(info)}", _level(info))
        return True

    def set_region_box(self, on: bool) -> None:
        """Show or hide the region's box on this page."""
        self.show_region_box = bool(on)
        self._region_call("draw_region", self.region_info() if self.show_region_box else None)

    def _show_region(self, info: Optional[RegionInfo]) -> None:
        """The fold and the box (not the status)."""
        if info is not None:
            self._region_call("show_region", info)
            self._region_call("draw_region", info if self.show_region_box else None)

    def region_changed(self) -> None:
        """The planner's region or its state changed (a listener of the region source): the fold, the box and, once a
        region applied on any page is prepared (or failed), the status."""
        info = self.region_info()
        if info is None:
            return
        self._show_region(info)
        if info.generation == 0:  # the opening preparation: the viewer says it (status, details)
            return
        if info.state == "ready":
            how = "" if info.automatic else f"; cinesplat-plan {info.region_option()} plans in the same box"
            self._set_status(f"Planner ready in {info.describe()}{how}.", "ok")
        elif info.state == "error":
            self._set_status(f"The planner could not prepare {info.describe()}: {info.error}", "error")


def _when(info: RegionInfo) -> str:
    """When the planner works in a region just asked for, in words."""
    if info.state == "later":
        return "the next Plan prepares the planner for it."
    return "preparing the planner for it in the background; a Plan waits for it..."


def _level(info: RegionInfo) -> str:
    return "info" if info.state == "later" else "busy"


STORED_RULE = "stored in the export"
"""PlannerConfig.bounds_rule of a region a compact export stores (as cinesplat-plan says it)."""


def stored_region_config(region: Optional[tuple]) -> dict:
    """PlannerConfig's bounds / bounds_rule for the region a scene file stores (None: {}, the automatic region)."""
    return {} if region is None else {"bounds": region, "bounds_rule": STORED_RULE}
