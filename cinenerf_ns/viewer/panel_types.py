"""The panel's interfaces and plain data: what a backend and a view must offer, its settings, targets. Shots are the
planner's ``Shot`` (planner/shots/shot.py), read as fields.

No viser import; tensors may be torch (any device) or numpy, converted with ``backend.to_numpy``.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Dict, List, Optional, Protocol, Sequence, Tuple, runtime_checkable

import numpy as np

from cinenerf_ns.planner.shots.camera_path import (
    DEFAULT_FOV_DEG,
    DEFAULT_PREVIEW_FPS,
    DEFAULT_PREVIEW_SIZE,
    DEFAULT_RENDER_SIZE,
)
from cinenerf_ns.planner.shots.shot import Shot
from cinenerf_ns.planner.trajectory.timing import TimingConfig

from .backend import SceneGaussians


@runtime_checkable
class PanelBackend(Protocol):
    """Scene access for the panel. Points are nerfstudio scene coordinates (numpy float64 [3])."""

    def gaussians(self) -> SceneGaussians:
        """Gaussians to draw / highlight (means [N,3], optional colors [N,3], opacities [N], covariances)."""
        ...

    def locate(self, text: str) -> Tuple[Any, ...]:
        """Text query -> (centroid [3], mask [N] bool over ``gaussians()``[, what it matched: a str such as
        "label 'sofa'" or "best relevancy 0.71"]). Raises a
        ``PlanningError`` (e.g. ``InvalidInputError`` for empty text, ``NoMatchError`` when nothing
        matches) whose message is shown verbatim."""
        ...

    def plan(
        self, goal: np.ndarray, look_at: np.ndarray, start: Optional[np.ndarray] = None, seed: int = 0,
        n_candidates: int = 1,
    ) -> Sequence[Shot]:
        """Collision-free shots from ``start`` (None: the planner picks a free start from ``seed``)
        to ``goal`` looking at ``look_at``. Raises ``PlanningError`` subclasses on failure."""
        ...


@dataclass
class DisplayOptions:
    """What the view draws besides the splat."""

    show_path: bool = True
    """Spline through the shot plus camera frustums along it."""
    show_targets: bool = True
    """Highlight the Gaussians / centroids the go-to and look-at queries matched."""
    show_corridor: bool = False
    """The shot's safe corridor (convex polytopes)."""
    show_clearance: bool = False
    """The shot's closest approach to the scene (one label, at the minimum clearance)."""


@dataclass
class Target:
    """A resolved go-to / look-at request."""

    role: str  # "go to" | "look at"
    text: str
    point: np.ndarray  # [3] scene units
    mask: Optional[np.ndarray] = None  # [N] bool, None for typed coordinates
    matched: str = ""  # what the query matched, in words ("label 'sofa'", "best relevancy 0.71"); "" for coordinates

    @property
    def count(self) -> Optional[int]:
        """Gaussians the query selected (None for typed coordinates)."""
        return None if self.mask is None else int(self.mask.sum())

    def describe(self) -> str:
        """"go to 'plant' matched label 'potted plant' (212 Gaussians)" / "look at the point (0, 1, 0.5)"."""
        if self.mask is None:
            return f"{self.role.lower()} the point ({', '.join(f'{v:.3g}' for v in self.point)})"
        if self.matched:
            return f"{self.role.lower()} '{self.text}' matched {self.matched} ({self.count} Gaussians)"
        return f"{self.role.lower()} '{self.text}': {self.count} Gaussians selected"


class PanelView(Protocol):
    """Drawing / camera side of the panel. Called from worker threads: implementations must be
    thread-safe (viser's scene and GUI APIs are)."""

    def set_status(self, text: str, level: str) -> None:
        """level: "info" | "busy" | "ok" | "warn" | "error"."""

    def show_inputs(self, goto: str, look_at: str) -> None:
        """Put the texts a Plan uses into the Go to / Look at boxes of every client (the server's values are the
        one source of truth: what is on screen is what was planned)."""

    def show_details(self, text: str) -> None:
        """Timings and other internals, in a collapsed details fold ("" clears it)."""

    def show_candidates(self, labels: List[str], selected: int) -> None: ...

    def draw_shot(self, shot: Optional[Shot], options: DisplayOptions) -> None:
        """Draw (or with None, remove) path, frustums, corridor and clearance labels."""

    def draw_targets(self, targets: List[Target], options: DisplayOptions) -> None: ...

    def set_camera(self, c2w: np.ndarray) -> int:
        """Move every connected client's camera to nerfstudio c2w [3, 4]; returns clients moved."""

    def camera_position(self) -> Optional[np.ndarray]:
        """A connected client's camera position in scene units, None when no client."""

    def set_playing(self, playing: bool) -> None: ...

    def show_export(self, path: Optional[Path], text: str, command: Optional[str] = None) -> None:
        """Show the exported file and how to render it (``text``: plain text, never markup; ``command``: a shell
        command shown verbatim); ``path`` None hides the box."""

    def show_preview(self, path: Optional[Path]) -> None:
        """Offer the preview video at ``path`` (a download); None hides the offer."""



@dataclass
class PanelConfig:
    """Panel settings (defaults match nerfstudio's Render tab)."""

    data_dir: Path = Path(".")
    """Dataset directory: its name goes into the ``ns-render`` command's output path; exports go to
    ``<data_dir>/camera_paths/<name>.json`` like the Render tab unless ``output_dir`` is set."""
    output_dir: Optional[Path] = None
    """Where exports (``camera_paths/``) and previews (``previews/``) go (the standalone viewer's ``--output-dir``);
    None: ``data_dir`` (inside ns-viewer, where the Render tab lists them)."""
    config_path: Optional[Path] = None
    """The run's config.yml, for the ``ns-render`` command (None: the panel says why there is no command)."""
    scene_note: str = ""
    """What the scene is when there is no run (e.g. "a compact export (scene.pt) with no training run"), said where
    the ``ns-render`` command would be."""
    preview_width: int = DEFAULT_PREVIEW_SIZE[0]
    """Width of the "Preview video" render (CPU)."""
    preview_height: int = DEFAULT_PREVIEW_SIZE[1]
    """Height of the "Preview video" render."""
    preview_fps: float = DEFAULT_PREVIEW_FPS
    """Frame rate of the "Preview video" render."""
    fov_deg: float = DEFAULT_FOV_DEG
    """Vertical field of view of the exported path."""
    render_width: int = DEFAULT_RENDER_SIZE[0]
    """Exported render width in pixels."""
    render_height: int = DEFAULT_RENDER_SIZE[1]
    """Exported render height in pixels."""
    fps: float = TimingConfig.fps
    """Exported frame rate."""
    n_candidates: int = 3
    """Shots requested per Plan (random starts)."""
    update_hz: float = 60.0
    """Camera updates per second sent to each client while playing."""
    autoplay: bool = True
    """Start playing the first candidate as soon as it is planned."""
    loop: bool = False
    """Restart at the end."""
    speed: float = 1.0
    """Playback speed multiple of the shot's real speed."""


@dataclass
class PlanRequest:
    goto: str
    look_at: str
    seed: int
    n_candidates: int
    start_from_camera: bool
    generation: int
    warning: str = ""  # set once the targets are resolved (go-to and look-at the same place)
    framing: str = "medium"  # the look-at object's size in the last frame (planner/shots/framing.py)


@dataclass
class PlanResult:
    shots: List[Shot]
    targets: List[Target]
    timings: Dict[str, float]
    warning: str = ""


@dataclass
class ExportResult:
    path: Path
    command: Optional[str]  # None when the scene has no run to render with ns-render
    renamed_from: Optional[str] = None  # the name asked for when a file of that name existed


@dataclass
class ServerLimits:
    """The work one viewer does for all its browsers together (shared by every client's panel): plans run one at a
    time (``plan_slots``), one preview renders at a time, and the files written are capped in number and bytes."""

    plan_slots: int = 1
    """Plans running at once over all clients (the others wait, saying so)."""
    max_pending_plans: int = 3
    """Plan requests one client may have queued; more are refused until one finishes."""
    max_clients: int = 8
    """Browser pages served at once; a page beyond it is told to come back later."""
    max_preview_s: float = 60.0
    """Longest shot rendered by "Preview video" (seconds of video)."""
    max_files: int = 500
    """Files (exports and previews) this viewer writes in one run."""
    max_bytes: int = 2 * 1024 ** 3
    """Bytes of exports and previews this viewer writes in one run."""
    files_written: int = 0
    bytes_written: int = 0
    _plan_sem: Any = field(default=None, repr=False)
    _preview_lock: Any = field(default=None, repr=False)
    _files_lock: Any = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self._plan_sem = threading.BoundedSemaphore(max(int(self.plan_slots), 1))
        self._preview_lock = threading.Lock()
        self._files_lock = threading.Lock()

    def acquire_plan_slot(self, cancelled: Callable[[], bool], on_wait: Callable[[], None]) -> bool:
        """Wait for a planning slot; ``on_wait`` is called once if the wait is not immediate. False (no slot taken)
        when ``cancelled()`` became true meanwhile."""
        if self._plan_sem.acquire(blocking=False):
            return True
        on_wait()
        while not cancelled():
            if self._plan_sem.acquire(timeout=0.05):
                return True
        return False

    def release_plan_slot(self) -> None:
        self._plan_sem.release()

    def try_start_preview(self) -> bool:
        """Take the one preview slot (False: a preview of some client is rendering)."""
        return self._preview_lock.acquire(blocking=False)

    def end_preview(self) -> None:
        self._preview_lock.release()

    def reserve_file(self) -> None:
        """Count one more file written; raises ``InvalidInputError`` when the run's file or byte budget is spent."""
        from cinenerf_ns.planner.errors import InvalidInputError

        with self._files_lock:
            if self.files_written >= self.max_files or self.bytes_written >= self.max_bytes:
                raise InvalidInputError(
                    f"this viewer has written {self.files_written} files ({self.bytes_written / 2**20:.1f} MiB), its "
                    f"limit for one run ({self.max_files} files, {self.max_bytes / 2**20:.0f} MiB); restart it to "
                    "write more")
            self.files_written += 1

    def add_bytes(self, n: int) -> None:
        with self._files_lock:
            self.bytes_written += int(n)
