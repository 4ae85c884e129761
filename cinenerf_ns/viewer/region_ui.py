"""The planning region on a viser page: a "Planning region" fold (show the box, its low / high corners as numbers,
Apply, Reset to automatic, the rule that chose it) and the box drawn as a wireframe with a label. The logic is the
panel's (``region_box.RegionMixin``); ``ViserPanelUI`` builds one of these and passes its PanelView calls on."""
from __future__ import annotations

import logging
import threading
from typing import Any, Callable, List, Optional

import numpy as np
import viser

from .region_box import RegionInfo
from .safe_text import md_escape

log = logging.getLogger(__name__)

REGION_COLOR = (255, 200, 0)
"""The box's colour (yellow: none of the shot's pink / white, the go-to's green or the look-at's orange)."""
_STATE_ICON = {"preparing": "⏳ ", "ready": "", "error": "❌ ", "later": ""}


def box_edges(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """[12, 2, 3] the edges of the axis-aligned box [lo, hi]: pairs of corners that differ along one axis."""
    corners = np.array([[hi[i] if (k >> i) & 1 else lo[i] for i in range(3)] for k in range(8)])
    return np.array([[corners[k], corners[k | (1 << i)]] for k in range(8) for i in range(3) if not (k >> i) & 1])


class RegionWidgets:
    """The fold and the box on one page (``gui`` / ``scene``: the page's ``client.gui`` / ``client.scene``, or the
    server's). Corners are scene units; the box is drawn at ``scale`` x scene units."""

    def __init__(self, gui: Any, scene: Any, scale: float, root: str) -> None:
        self.scene, self.scale, self.root = scene, float(scale), root
        self._lock = threading.Lock()
        self._nodes: List[Any] = []
        self.rule_text = ""  # what the fold says of the region, before escaping
        self.folder = gui.add_folder("Planning region", expand_by_default=False)
        with self.folder:
            self.show = gui.add_checkbox("Show region box", True,
                                         hint="The box the planner works in: paths never leave it")
            self.rule_md = gui.add_markdown("(the planner is preparing)")
            self.lo = gui.add_vector3("Low corner", (0.0, 0.0, 0.0), step=0.01,
                                      hint="x0 y0 z0 of the box, scene units")
            self.hi = gui.add_vector3("High corner", (1.0, 1.0, 1.0), step=0.01,
                                      hint="x1 y1 z1 of the box, scene units (each above the low corner's)")
            self.apply = gui.add_button("Apply region", icon=viser.Icon.CHECK,
                                        hint="Plan in this box from now on (every page; the planner prepares again)")
            self.reset = gui.add_button("Reset to automatic", icon=viser.Icon.RESTORE,
                                        hint="The planner's own region: the training cameras' box, else the dense "
                                             "content")

    def attach(self, panel: Any, guarded: Callable[[Callable], Callable]) -> None:
        """Wire the widgets to ``panel`` (a CinePanel; ``guarded`` keeps errors out of viser's callback thread). A
        panel without a region source (an injected backend with no planner region) shows no fold."""
        self.folder.visible = panel.region_source is not None
        self.apply.on_click(guarded(lambda e: panel.apply_region(self.lo.value, self.hi.value)))
        self.reset.on_click(guarded(lambda e: panel.reset_region()))
        self.show.on_update(guarded(lambda e: panel.set_region_box(bool(self.show.value))))
        panel.show_region_box = bool(self.show.value)

    def show_region(self, info: RegionInfo) -> None:
        """The rule and state in words; the corners when known (the prepared box: what paths stay in)."""
        state = {"preparing": " (preparing the planner for it...)", "error": f" (refused: {info.error})",
                 "later": " (prepared at the next Plan)"}
        self.rule_text = f"{info.box_text()}, chosen by: {info.rule}{state.get(info.state, '')}"
        self.rule_md.content = _STATE_ICON.get(info.state, "") + md_escape(self.rule_text)
        lo, hi = (info.lo, info.hi) if info.asked is None else info.asked  # a box asked for: as typed
        if lo is not None and hi is not None:
            self.lo.value = tuple(round(float(v), 4) for v in lo)
            self.hi.value = tuple(round(float(v), 4) for v in hi)
        self.reset.disabled = info.automatic

    def draw_region(self, info: Optional[RegionInfo]) -> None:
        """The region as a wireframe box with a label at its top corner; None (or a region not known yet) removes
        it."""
        with self._lock:
            for h in self._nodes:
                try:
                    h.remove()
                except Exception:  # a page that left
                    log.debug("removing %s failed", getattr(h, "name", "?"), exc_info=True)
            self._nodes = []
            if info is None or info.lo is None or info.hi is None:
                return
            lo, hi = np.asarray(info.lo, np.float64), np.asarray(info.hi, np.float64)
            base = f"{self.root}/region"
            self._nodes.append(self.scene.add_line_segments(  # its 12 edges (a wireframe box shows face diagonals)
                f"{base}/box", points=(box_edges(lo, hi) * self.scale).astype(np.float32), colors=REGION_COLOR,
                thickness=2.0, thickness_units="screen"))
            label = f"planning region ({info.rule})" + (" - preparing" if info.state == "preparing" else "")
            self._nodes.append(self.scene.add_label(f"{base}/label", label, position=tuple(hi * self.scale),
                                                    anchor="bottom-right"))
