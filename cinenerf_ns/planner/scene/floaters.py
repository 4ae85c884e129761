"""Floaters on purpose: small, faint, isolated Gaussians (a capture's noise in the air) may be treated as
non-obstacles. The rule, stated:

    a Gaussian is a floater when it is
      faint     opacity <= FLOATER_MAX_OPACITY,
      small     its largest obstacle semi-axis (beta x opacity x scale) <= FLOATER_MAX_AXIS_RADII x the camera radius,
      isolated  fewer than FLOATER_NEIGHBOURS other obstacle means lie within FLOATER_ISOLATION_RADII x the camera
                radius of its mean (a surface's Gaussians have many neighbours that close; noise in the air has none).

``--ignore-floaters``: 'off' keeps every Gaussian; 'on' drops the floaters from the obstacles; 'auto' drops them when
they are at least FLOATER_AUTO_FRACTION of the obstacles (a capture with visible noise), else keeps them. Every shot
is still verified by the exact check, against the obstacle set it was planned with: the report says which
(``obstacle_note``)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..errors import InvalidInputError

if TYPE_CHECKING:
    from .ellipsoids import EllipsoidScene

FLOATER_MAX_OPACITY = 0.4
FLOATER_MAX_AXIS_RADII = 0.5
FLOATER_ISOLATION_RADII = 3.0
FLOATER_NEIGHBOURS = 3
FLOATER_AUTO_FRACTION = 0.01
FLOATER_MODES = ("auto", "on", "off")
FLOATER_RULE = (f"opacity <= {FLOATER_MAX_OPACITY:g}, largest semi-axis <= {FLOATER_MAX_AXIS_RADII:g} camera radii, "
                f"fewer than {FLOATER_NEIGHBOURS} other means within {FLOATER_ISOLATION_RADII:g} camera radii; "
                f"auto: ignored when >= {100 * FLOATER_AUTO_FRACTION:g}% of the obstacles")


def floater_mask(scene: "EllipsoidScene") -> np.ndarray:
    """bool [N]: the scene's Gaussians that are floaters by the module's rule (faint, small, isolated)."""
    from scipy.spatial import cKDTree

    r = float(scene.camera_radius)
    op = scene.opacities.detach().cpu().double().numpy()
    axis = scene.radii.detach().max(dim=1).values.cpu().double().numpy()
    cand = np.flatnonzero((op <= FLOATER_MAX_OPACITY) & (axis <= FLOATER_MAX_AXIS_RADII * r))
    out = np.zeros(len(scene), dtype=bool)
    if cand.size == 0 or r <= 0:
        return out
    means = scene.means.detach().cpu().double().numpy()
    tree = cKDTree(means)
    near = tree.query_ball_point(means[cand], FLOATER_ISOLATION_RADII * r, return_length=True)  # self included
    out[cand[np.asarray(near) - 1 < FLOATER_NEIGHBOURS]] = True
    return out


@dataclass
class FloaterChoice:
    mode: str  # 'auto' | 'on' | 'off' as asked
    ignored: bool  # the floaters were dropped from the obstacles
    count: int  # floaters found by the rule
    total: int  # obstacles before
    rule: str = FLOATER_RULE

    def obstacle_note(self) -> str:
        """Which obstacle set shots are planned and verified against (for the report)."""
        kept = self.total - self.count if self.ignored else self.total
        if self.ignored:
            return (f"{kept} of {self.total} Gaussians: {self.count} floaters ignored (--ignore-floaters {self.mode}; "
                    f"{self.rule})")
        return f"all {self.total} Gaussians above the opacity floor (floaters kept: --ignore-floaters {self.mode})"

    def to_dict(self) -> dict:
        return {"mode": self.mode, "ignored": self.ignored, "floaters": self.count, "gaussians": self.total,
                "ignored_gaussians": self.count if self.ignored else 0, "rule": self.rule,
                "obstacles": self.obstacle_note()}


def apply_floater_rule(scene: "EllipsoidScene", mode: str) -> tuple["EllipsoidScene", FloaterChoice]:
    """(the obstacle scene, the choice): ``mode`` 'off' keeps every Gaussian (no search), 'on' drops the floaters,
    'auto' drops them when they are >= FLOATER_AUTO_FRACTION of the obstacles."""
    if mode not in FLOATER_MODES:
        raise InvalidInputError(f"--ignore-floaters must be one of {', '.join(FLOATER_MODES)}, got {mode!r}")
    n = len(scene)
    if mode == "off":
        return scene, FloaterChoice(mode, False, 0, n)
    mask = floater_mask(scene)
    count = int(mask.sum())
    ignore = count > 0 and (mode == "on" or count >= FLOATER_AUTO_FRACTION * n) and count < n
    if not ignore:
        return scene, FloaterChoice(mode, False, count, n)
    keep = torch.as_tensor(np.flatnonzero(~mask), device=scene.means.device)
    return scene.subset(keep), FloaterChoice(mode, True, count, n)
