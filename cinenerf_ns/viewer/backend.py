"""Concrete pieces a panel backend is made of: the Gaussians to draw, target parsing, and a
backend assembled from injectable callables (the integrator passes the real planner / semantics).

Coordinates are nerfstudio scene units throughout; the viser scale is applied only when drawing.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any, Callable, List, Optional, Sequence, Tuple

import numpy as np

from cinenerf_ns.planner.errors import InvalidInputError, PlanningError


class NoMatchError(PlanningError):
    """A text query matched no Gaussian (relevancy below threshold everywhere)."""


def to_numpy(x: Any, dtype=np.float64) -> np.ndarray:
    """torch tensor (any device) / list / array -> numpy array (detached, on CPU)."""
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x, dtype=dtype)


@dataclass
class SceneGaussians:
    """What the viewer needs to draw a splat (and to highlight query matches)."""

    means: np.ndarray  # [N, 3] scene units
    colors: Optional[np.ndarray] = None  # [N, 3] RGB in [0, 1]
    opacities: Optional[np.ndarray] = None  # [N] in [0, 1]
    covariances: Optional[np.ndarray] = None  # [N, 3, 3] display covariances (scene units^2)

    def __post_init__(self) -> None:
        self.means = to_numpy(self.means, np.float32)
        n = self.means.shape[0]
        if self.means.ndim != 2 or self.means.shape[1] != 3:
            raise InvalidInputError(f"Gaussian means must be [N, 3], got {self.means.shape}")
        if self.colors is not None:
            self.colors = to_numpy(self.colors, np.float32).reshape(n, 3)
        if self.opacities is not None:
            self.opacities = to_numpy(self.opacities, np.float32).reshape(n)
        if self.covariances is not None:
            self.covariances = to_numpy(self.covariances, np.float32).reshape(n, 3, 3)

    def __len__(self) -> int:
        return int(self.means.shape[0])


LocateFn = Callable[[str], Tuple[Any, ...]]  # text -> (centroid [3], mask [N][, what it matched, in words])
PlanFn = Callable[..., List[Any]]  # (goal [3], look_at [3], start=None|[3], seed=int, n_candidates=int) -> shots


class FunctionBackend:
    """A :class:`~cinenerf_ns.viewer.panel.PanelBackend` made of callables.

    ``locate`` may be None (no semantics yet): then only typed "x y z" targets work and an object
    query gets a message saying so. ``plan_lock`` serialises planner calls (a planner object is not
    assumed to be thread-safe)."""

    def __init__(
        self,
        gaussians: SceneGaussians,
        plan_fn: PlanFn,
        locate_fn: Optional[LocateFn] = None,
        name: str = "scene",
        planner_name: str = "planner",
        region_source: Any = None,
    ) -> None:
        """``region_source``: the planner's planning region (region_box.RegionSource: ``PreparedPlanner``), which the
        panel shows and lets a page set; None: the panel has no region to show."""
        self.region_source = region_source
        self._gaussians = gaussians
        self._plan_fn = plan_fn
        self._locate_fn = locate_fn
        self.name = name
        self.planner_name = planner_name
        self._plan_lock = threading.Lock()

    def gaussians(self) -> SceneGaussians:
        return self._gaussians

    def locate(self, text: str) -> Tuple[Any, ...]:
        """(centroid [3], mask [N][, what it matched]) of ``text``."""
        if not text or not text.strip():
            raise InvalidInputError("empty query: type an object name or 'x y z' coordinates")
        if self._locate_fn is None:
            raise InvalidInputError(
                f"text queries need a trained cinesplat scene (semantic latents + codec); this scene has none. "
                f"Type coordinates 'x y z' instead of '{text}'"
            )
        found = tuple(self._locate_fn(text))  # (centroid [3], mask [N][, what it matched])
        centroid, mask = to_numpy(found[0]).reshape(3), to_numpy(found[1], bool).reshape(-1)
        return (centroid, mask) + found[2:3]

    def plan(self, goal, look_at, start=None, seed: int = 0, n_candidates: int = 1) -> List[Any]:
        with self._plan_lock:
            return list(self._plan_fn(goal, look_at, start=start, seed=seed, n_candidates=n_candidates))


def label_locate(means: np.ndarray, labels: Sequence[str], label_of: np.ndarray) -> LocateFn:
    """Stand-in text query for scenes with known per-Gaussian labels (the demo scene, synthetic rooms): a query
    matches every label that holds each of its words, whole words (scenes.word_matches: 'box' and 'red box' ->
    'red box', 'ox' nothing); their Gaussians together.

    Not CLIP semantics: this is exact label matching, used where labels are ground truth."""
    from cinenerf_ns.scenes import word_matches

    means = np.asarray(means, dtype=np.float64)
    label_of = np.asarray(label_of)

    def locate(text: str) -> Tuple[np.ndarray, np.ndarray]:
        if not text.strip():
            raise InvalidInputError("empty query: type an object name or 'x y z' coordinates")
        hit = word_matches(text, list(labels))
        if not hit:
            raise NoMatchError(f"'{text}' matches no object in this scene (whole words; known: {', '.join(labels)})")
        mask = np.isin(label_of, hit)
        if not mask.any():
            raise NoMatchError(f"'{text}' names an object with no Gaussians left")
        return means[mask].mean(0), mask, "the label" + ("s " if len(hit) > 1 else " ") + ", ".join(
            f"'{labels[i]}'" for i in hit)

    return locate
