"""The cinematography panel's logic: state, plan / animate / export, over two small interfaces.

* :class:`PanelBackend` gives the Gaussians, a text query (``locate``) and the planner (``plan``).
* :class:`PanelView` is what the panel draws on and moves: the viser implementation is
  ``viser_view.ViserView``; tests use a fake that records calls. No viser import here.

Threads: GUI callbacks only *request* work. Planning runs on one worker thread (requests that were
superseded by a newer Plan before they started are skipped; a result that arrives after a newer Plan
was requested is dropped). Animation runs on its own thread at ``update_hz``; a new Plan, a
candidate switch, Pause or close stop it and join it before anything else touches the camera.
Every failure ends as a readable status line; nothing here lets an exception escape into the
viewer's callback thread.
"""
from __future__ import annotations

import concurrent.futures as cf
import logging
import threading
import time
import traceback
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Dict, List, Optional, Protocol, Sequence, Tuple, runtime_checkable

import numpy as np

from cinenerf_ns.planner.errors import GoalUnreachableError, InvalidInputError, PlanningError

from .backend import SceneGaussians, parse_point, to_numpy
from .conventions import interpolate_pose
from .export import Exporter, check_export_name, default_exporter, render_command, write_json_atomic

log = logging.getLogger(__name__)


# ----------------------------------------------------------------------------------------- interfaces
@runtime_checkable
class ShotLike(Protocol):
    """What the panel reads from a planned shot (``cinenerf_ns.planner.shot.Shot`` satisfies it).

    Required: ``times`` [T] seconds, increasing; ``positions`` [T, 3]; ``rotations`` [T, 3, 3]
    camera-to-world rotations, nerfstudio convention (camera looks along -z, y up).
    Optional, used when present: ``clearance`` [T] (or ``min_clearance`` float), ``corridor`` (with
    ``.polytopes``, each ``.A`` [F,3] / ``.b`` [F] or an ``(A, b)`` pair), ``look_at`` [3], ``goal`` [3],
    ``start`` [3], ``timings`` dict of seconds. Tensors may be torch (any device) or numpy."""

    times: Any
    positions: Any
    rotations: Any


@runtime_checkable
class PanelBackend(Protocol):
    """Scene access for the panel. Points are nerfstudio scene coordinates (numpy float64 [3])."""

    def gaussians(self) -> SceneGaussians:
        """Gaussians to draw / highlight (means [N,3], optional colors [N,3], opacities [N], covariances)."""
        ...

    def locate(self, text: str) -> Tuple[Any, Any]:
        """Text query -> (centroid [3], mask [N] bool over ``gaussians()``). Raises a
        ``PlanningError`` (e.g. ``InvalidInputError`` for empty text, ``NoMatchError`` when nothing
        matches) whose message is shown verbatim."""
        ...

    def plan(
        self, goal: np.ndarray, look_at: np.ndarray, start: Optional[np.ndarray] = None, seed: int = 0,
        n_candidates: int = 1,
    ) -> Sequence[ShotLike]:
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
    """Clearance numbers along the path."""


@dataclass
class Target:
    """A resolved go-to / look-at request."""

    role: str  # "go to" | "look at"
    text: str
    point: np.ndarray  # [3] scene units
    mask: Optional[np.ndarray] = None  # [N] bool, None for typed coordinates


class PanelView(Protocol):
    """Drawing / camera side of the panel. Called from worker threads: implementations must be
    thread-safe (viser's scene and GUI APIs are)."""

    def set_status(self, text: str, level: str) -> None:
        """level: "info" | "busy" | "ok" | "error"."""

    def show_candidates(self, labels: List[str], selected: int) -> None: ...

    def draw_shot(self, shot: Optional[ShotLike], options: DisplayOptions) -> None:
        """Draw (or with None, remove) path, frustums, corridor and clearance labels."""

    def draw_targets(self, targets: List[Target], options: DisplayOptions) -> None: ...

    def set_camera(self, c2w: np.ndarray) -> int:
        """Move every connected client's camera to nerfstudio c2w [3, 4]; returns clients moved."""

    def camera_position(self) -> Optional[np.ndarray]:
        """A connected client's camera position in scene units, None when no client."""

    def set_playing(self, playing: bool) -> None: ...

    def show_export(self, path: Path, command: str) -> None: ...


# ----------------------------------------------------------------------------------------- config
@dataclass
class PanelConfig:
    """Panel settings (defaults match nerfstudio's Render tab)."""

    data_dir: Path = Path(".")
    """Dataset directory: exports go to ``<data_dir>/camera_paths/<name>.json`` like the Render tab."""
    config_path: Optional[Path] = None
    """The run's config.yml, for the ``ns-render`` command (None: a placeholder is shown)."""
    fov_deg: float = 50.0
    """Vertical field of view of the exported path."""
    render_width: int = 1920
    """Exported render width in pixels."""
    render_height: int = 1080
    """Exported render height in pixels."""
    fps: int = 30
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


@dataclass
class PlanResult:
    shots: List[ShotLike]
    targets: List[Target]
    timings: Dict[str, float]


@dataclass
class ExportResult:
    path: Path
    command: str


# ----------------------------------------------------------------------------------------- panel
class CinePanel:
    """All state and logic of the cinematography panel. GUI layers call the public methods."""

    IDLE, PLANNING, READY, PLAYING, PAUSED = "idle", "planning", "ready", "playing", "paused"

    def __init__(
        self,
        backend: PanelBackend,
        view: PanelView,
        config: Optional[PanelConfig] = None,
        exporter: Optional[Exporter] = None,
    ) -> None:
        self.backend = backend
        self.view = view
        self.config = replace(config) if config is not None else PanelConfig()
        self.exporter: Exporter = exporter or default_exporter()
        self.options = DisplayOptions()
        self.seed = 0
        self.last_timings: Dict[str, float] = {}
        self.status = ""
        self.status_level = "info"
        self._lock = threading.RLock()  # state; held while joining the animation thread
        self._t_lock = threading.Lock()  # playback time / end-of-shot state, shared with the animation thread
        self._state = self.IDLE
        self._shots: List[ShotLike] = []
        self._targets: List[Target] = []
        self._selected = 0
        self._t = 0.0  # playback time since the shot's first sample, seconds
        self._generation = 0
        self._pending = 0  # plan requests submitted and not finished
        self._last_texts: Tuple[str, str] = ("", "")
        self._executor = cf.ThreadPoolExecutor(max_workers=1, thread_name_prefix="cine-plan")
        self._anim_thread: Optional[threading.Thread] = None
        self._anim_stop = threading.Event()
        self.frames_sent = 0  # camera updates sent by the animation thread (all plays)
        self._closed = False

    # ------------------------------------------------------------------ read-only state
    @property
    def state(self) -> str:
        return self._state

    @property
    def shots(self) -> List[ShotLike]:
        return list(self._shots)

    @property
    def selected(self) -> int:
        return self._selected

    @property
    def shot(self) -> Optional[ShotLike]:
        with self._lock:
            return self._shots[self._selected] if self._shots else None

    @property
    def targets(self) -> List[Target]:
        return list(self._targets)

    @property
    def playback_time(self) -> float:
        return self._t

    # ------------------------------------------------------------------ status
    def _set_status(self, text: str, level: str = "info") -> None:
        self.status, self.status_level = text, level
        try:
            self.view.set_status(text, level)
        except Exception:  # a broken view must not take the panel down
            log.exception("view.set_status failed")

    def _fail(self, what: str, err: BaseException) -> None:
        if isinstance(err, PlanningError) or isinstance(err, ValueError):
            msg = f"{what} failed: {err}"
        else:  # unexpected: keep the type so a bug report is useful; the traceback goes to the log
            msg = f"{what} failed with an internal error ({type(err).__name__}: {err}); see the console log"
            log.error("%s failed:\n%s", what, "".join(traceback.format_exception(err)))
        self._set_status(msg, "error")

    # ------------------------------------------------------------------ planning
    def request_plan(
        self,
        goto: str,
        look_at: str,
        n_candidates: Optional[int] = None,
        new_start: bool = False,
        start_from_camera: bool = False,
    ) -> cf.Future:
        """Cancel any animation and plan on the worker thread. Returns a Future of
        :class:`PlanResult` (None when the request failed or was superseded; see ``status``)."""
        with self._lock:
            if self._closed:
                fut: cf.Future = cf.Future()
                fut.set_result(None)
                return fut
            self._stop_animation()
            if new_start:
                self.seed += 1
            self._generation += 1
            self._pending += 1
            self._last_texts = (goto, look_at)
            req = PlanRequest(
                goto=goto or "", look_at=look_at or "", seed=self.seed,
                n_candidates=int(n_candidates if n_candidates is not None else self.config.n_candidates),
                start_from_camera=start_from_camera, generation=self._generation,
            )
            self._state = self.PLANNING
        self._set_status(f"Planning: go to '{req.goto}', look at '{req.look_at}' (seed {req.seed})...", "busy")
        return self._executor.submit(self._plan_job, req)

    def new_random_start(self, n_candidates: Optional[int] = None) -> cf.Future:
        """Plan the last request again from a new random start (next seed)."""
        goto, look_at = self._last_texts
        return self.request_plan(goto, look_at, n_candidates=n_candidates, new_start=True)

    def _resolve(self, text: str, role: str) -> Target:
        text = (text or "").strip()
        if not text:
            raise InvalidInputError(f"'{role}' is empty: type an object (e.g. 'the chair') or coordinates 'x y z'")
        point = parse_point(text)
        if point is not None:
            return Target(role, text, point, None)
        centroid, mask = self.backend.locate(text)
        centroid = to_numpy(centroid).reshape(3)
        if not np.all(np.isfinite(centroid)):
            raise InvalidInputError(f"the query '{text}' gave a non-finite centroid {centroid}")
        return Target(role, text, centroid, None if mask is None else to_numpy(mask, bool).reshape(-1))

    def _superseded(self, req: PlanRequest) -> bool:
        return req.generation != self._generation or self._closed

    def _plan_job(self, req: PlanRequest) -> Optional[PlanResult]:
        try:
            if self._superseded(req):
                return None  # a newer Plan was requested before this one started
            return self._plan_now(req)
        except BaseException as err:  # never let the worker die silently
            if not self._superseded(req):
                self._fail("Plan", err)
                with self._lock:
                    self._state = self.READY if self._shots else self.IDLE
            return None
        finally:
            with self._lock:
                self._pending -= 1

    def _plan_now(self, req: PlanRequest) -> Optional[PlanResult]:
        t0 = time.perf_counter()
        goal = self._resolve(req.goto, "Go to")
        look = self._resolve(req.look_at, "Look at")
        start = None
        if req.start_from_camera:
            start = self.view.camera_position()
            if start is None:
                raise InvalidInputError("'start from my camera' needs a connected browser; none is connected")
        t1 = time.perf_counter()
        shots = list(self.backend.plan(goal.point, look.point, start=start, seed=req.seed,
                                       n_candidates=req.n_candidates))
        t2 = time.perf_counter()
        if not shots:
            raise GoalUnreachableError(
                f"the planner found no collision-free shot to '{req.goto}' (try a new random start)"
            )
        for i, s in enumerate(shots):
            check_shot(s, f"candidate {i + 1}")
        with self._lock:
            if self._superseded(req):
                return None  # a newer Plan arrived while planning: drop this result
            self._shots, self._targets, self._selected, self._t = shots, [goal, look], 0, 0.0
            self._state = self.READY
        self.view.draw_targets(self._targets, self.options)
        self.view.show_candidates([candidate_label(i, s) for i, s in enumerate(shots)], 0)
        self.view.draw_shot(shots[0], self.options)
        t3 = time.perf_counter()
        timings = {"query_s": t1 - t0, "plan_s": t2 - t1, "draw_s": t3 - t2, "total_s": t3 - t0}
        self.last_timings = timings
        inner = getattr(shots[0], "timings", None) or {}
        detail = timings_detail(inner)
        by = getattr(self.backend, "planner_name", None)
        self._set_status(
            f"Planned {len(shots)} candidate(s){f' with the {by}' if by else ''} in {timings['total_s']:.2f} s (query {timings['query_s']:.2f} s, "
            f"planner {timings['plan_s']:.2f} s{'; ' + detail if detail else ''}, drawing {timings['draw_s']:.2f} s). "
            f"{shot_summary(shots[0])}{goal_note(shots[0])}",
            "ok",
        )
        if self.config.autoplay:
            with self._lock:  # atomic with request_plan's generation bump: no stale autoplay
                if not self._superseded(req):
                    self.play()
        return PlanResult(shots, [goal, look], timings)

    def wait_idle(self, timeout: float = 30.0) -> bool:
        """Block until no plan request is pending (tests, benchmarks, CLI)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            with self._lock:
                if self._pending == 0:
                    return True
            time.sleep(0.005)
        return False

    # ------------------------------------------------------------------ candidates / display
    def select(self, index: int) -> None:
        """Show candidate ``index`` (stops playback, rewinds)."""
        with self._lock:
            if not self._shots:
                self._set_status("No shot to select: press Plan first", "error")
                return
            if not 0 <= index < len(self._shots):
                self._set_status(f"No candidate {index + 1} (have {len(self._shots)})", "error")
                return
            self._stop_animation()
            self._selected, self._t = index, 0.0
            self._state = self.READY
            shot = self._shots[index]
        self.view.draw_shot(shot, self.options)
        self._set_status(f"Candidate {index + 1}: {shot_summary(shot)}", "ok")

    def set_display(self, **flags: bool) -> None:
        """Toggle ``show_path`` / ``show_targets`` / ``show_corridor`` / ``show_clearance``."""
        for k, v in flags.items():
            if not hasattr(self.options, k):
                raise AttributeError(f"unknown display option {k}")
            setattr(self.options, k, bool(v))
        try:
            self.view.draw_shot(self.shot, self.options)
            self.view.draw_targets(self._targets, self.options)
        except Exception as err:
            self._fail("Drawing", err)

    # ------------------------------------------------------------------ animation
    def play(self) -> None:
        """Fly the selected shot at its real speed (times ``speed``); from the start when at the end."""
        with self._lock:
            shot = self.shot
            if shot is None:
                self._set_status("Nothing to play: press Plan first", "error")
                return
            self._stop_animation()
            times = to_numpy(shot.times)
            if self._t >= times[-1] - times[0]:
                self._t = 0.0
            self._anim_stop = threading.Event()
            self._state = self.PLAYING
            self._anim_thread = threading.Thread(
                target=self._animate, args=(shot, self._anim_stop), name="cine-animate", daemon=True
            )
            self.view.set_playing(True)  # before the thread starts: a very short shot may end at once
            self._anim_thread.start()

    def pause(self) -> None:
        with self._lock:
            if self._state != self.PLAYING:
                return
            self._stop_animation()
            self._state = self.PAUSED
        self.view.set_playing(False)

    def seek(self, t: float) -> None:
        """Jump to time ``t`` seconds into the shot (keeps playing if playing)."""
        with self._lock:
            shot = self.shot
            if shot is None:
                return
            times = to_numpy(shot.times)
            with self._t_lock:
                self._t = float(np.clip(t, 0.0, times[-1] - times[0]))
                t = self._t
            c2w = interpolate_pose(times, to_numpy(shot.positions), to_numpy(shot.rotations), times[0] + t)
        self.view.set_camera(c2w)

    def set_speed(self, speed: float) -> None:
        if not (np.isfinite(speed) and speed > 0):
            self._set_status(f"speed must be > 0, got {speed}", "error")
            return
        self.config.speed = float(speed)

    def set_loop(self, loop: bool) -> None:
        self.config.loop = bool(loop)

    def _stop_animation(self) -> None:
        """Stop and join the animation thread (no-op from the animation thread itself)."""
        th = self._anim_thread
        self._anim_stop.set()
        if th is not None and th is not threading.current_thread():
            th.join(timeout=5.0)
        self._anim_thread = None if th is not threading.current_thread() else th
        with self._t_lock:
            was_playing = self._state == self.PLAYING
            if was_playing:
                self._state = self.PAUSED
        if was_playing:
            self.view.set_playing(False)

    def _animate(self, shot: ShotLike, stop: threading.Event) -> None:
        # Never takes self._lock: callers hold it while joining this thread (see _stop_animation).
        times = to_numpy(shot.times)
        positions, rotations = to_numpy(shot.positions), to_numpy(shot.rotations)
        duration = float(times[-1] - times[0])
        period = 1.0 / max(self.config.update_hz, 1.0)
        last = time.perf_counter()
        next_tick = last
        try:
            while not stop.is_set():
                now = time.perf_counter()
                finished = False
                with self._t_lock:
                    self._t += (now - last) * self.config.speed
                    if self._t >= duration:
                        if self.config.loop and duration > 0:
                            self._t %= duration
                        else:
                            self._t, finished = duration, True
                    t = self._t
                last = now
                self.view.set_camera(interpolate_pose(times, positions, rotations, times[0] + t))
                self.frames_sent += 1
                if finished:
                    with self._t_lock:
                        if not stop.is_set():
                            self._state = self.READY
                    self.view.set_playing(False)
                    return
                next_tick += period
                delay = next_tick - time.perf_counter()
                if delay < -period:  # fell behind (slow client/CPU): do not catch up in a burst
                    next_tick = time.perf_counter()
                    delay = 0.0
                stop.wait(max(delay, 0.0))
        except Exception as err:
            self._fail("Animation", err)
            with self._t_lock:
                if not stop.is_set():
                    self._state = self.READY

    # ------------------------------------------------------------------ export
    def export(self, name: str) -> Optional[ExportResult]:
        """Write the selected shot to ``<data>/camera_paths/<name>.json`` (atomically) and show the
        ``ns-render`` command. Returns None (and sets an error status) on failure; an existing file
        of that name is only replaced once the new one is complete."""
        try:
            name = check_export_name(name)
            shot = self.shot
            if shot is None:
                raise InvalidInputError("nothing to export: press Plan first")
            cfg = self.config
            if hasattr(shot, "resampled"):  # ns-render plays frames at the file's own rate: re-time, never relabel
                shot = shot.resampled(cfg.fps)
            data = self.exporter(shot, cfg.fov_deg, cfg.render_width, cfg.render_height, cfg.fps)
            path = write_json_atomic(Path(cfg.data_dir) / "camera_paths" / f"{name}.json", data)
            command = render_command(cfg.config_path, path, Path(cfg.data_dir).absolute().name, name)
        except BaseException as err:
            self._fail("Export", err)
            return None
        self.view.show_export(path, command)
        note = "" if cfg.config_path is not None else " (replace the config placeholder with your run's config.yml)"
        self._set_status(f"Exported {path}. Render with: {command}{note}", "ok")
        return ExportResult(path, command)

    # ------------------------------------------------------------------ teardown
    def close(self) -> None:
        with self._lock:
            self._closed = True
            self._generation += 1
            self._stop_animation()
        self._executor.shutdown(wait=True, cancel_futures=True)


# ----------------------------------------------------------------------------------------- helpers
def check_shot(shot: Any, what: str = "shot") -> None:
    """Raise PlanningError when a shot lacks what the panel needs or holds NaN."""
    try:
        times = to_numpy(shot.times).reshape(-1)
        pos = to_numpy(shot.positions)
        rot = to_numpy(shot.rotations)
    except AttributeError as err:
        raise PlanningError(f"the planner returned a malformed {what}: {err}") from err
    t = len(times)
    if t < 2 or pos.shape != (t, 3) or rot.shape != (t, 3, 3):
        raise PlanningError(
            f"the planner returned a malformed {what}: times {times.shape}, positions {pos.shape}, "
            f"rotations {rot.shape} (want [T>=2], [T,3], [T,3,3])"
        )
    if not (np.all(np.isfinite(times)) and np.all(np.isfinite(pos)) and np.all(np.isfinite(rot))):
        raise PlanningError(f"the planner returned a {what} with NaN/inf samples")
    if not np.all(np.diff(times) > 0):
        raise PlanningError(f"the planner returned a {what} whose times do not increase")


def min_clearance(shot: Any) -> Optional[float]:
    """Smallest clearance the shot reports: per-frame ``clearance`` [T], else ``min_clearance``, else the
    planner's dense verification (``safety['min_exact_clearance']``, None when every sample was proven free)."""
    c = getattr(shot, "clearance", None)
    if c is not None:
        c = to_numpy(c).reshape(-1)
        return float(c.min()) if c.size else None
    m = getattr(shot, "min_clearance", None)
    if m is not None:
        return float(m)
    safety = getattr(shot, "safety", None)
    m = safety.get("min_exact_clearance") if isinstance(safety, dict) else None
    return None if m is None else float(m)


def shot_score(shot: Any) -> Optional[float]:
    """The candidate's ranking score when the planner gives one (``shot.score``), else None."""
    s = getattr(shot, "score", None)
    try:
        return None if s is None else float(s)
    except (TypeError, ValueError):
        return None


def timings_detail(timings: Dict[str, Any]) -> str:
    """``{'astar_ms': 12.3, 'fit_s': 0.5}`` -> ``'astar 12 ms, fit 0.50 s'`` (the planner reports ms)."""
    out = []
    for k, v in timings.items():
        if not isinstance(v, (int, float)):
            continue
        if k.endswith("_ms"):
            out.append(f"{k[:-3]} {v:.0f} ms")
        elif k.endswith("_s"):
            out.append(f"{k[:-2]} {v:.2f} s")
        else:
            out.append(f"{k} {v:.3g}")
    return ", ".join(out)


def shot_summary(shot: Any) -> str:
    times = to_numpy(shot.times)
    pos = to_numpy(shot.positions)
    length = float(np.linalg.norm(np.diff(pos, axis=0), axis=1).sum())
    c = min_clearance(shot)
    cl = "n/a" if c is None else f"{c:.3g}"
    score = shot_score(shot)
    return (f"{times[-1] - times[0]:.1f} s, {length:.2f} units long, min clearance {cl}"
            f"{'' if score is None else f', score {score:.3g}'}")


def goal_note(shot: Any) -> str:
    """' Note: the go-to point moved ...' when the planner ended the shot away from the go-to target (planner
    explain_goal: from where to where and why), else ''."""
    mv = getattr(shot, "goal_moved", None)
    if not mv:
        return ""
    f = lambda p: "(" + ", ".join(f"{v:.3f}" for v in p) + ")"  # noqa: E731
    return f" Note: the go-to point moved {mv['distance']:.3f} units, from {f(mv['from'])} to {f(mv['to'])}: {mv['why']}."


def candidate_label(i: int, shot: Any) -> str:
    """Dropdown entry: ``'<n>: <duration> s, clearance <min>[, score <s>]'`` (the panel parses the number)."""
    times = to_numpy(shot.times)
    c = min_clearance(shot)
    score = shot_score(shot)
    return (f"{i + 1}: {times[-1] - times[0]:.1f} s, clearance {'n/a' if c is None else f'{c:.3g}'}"
            f"{'' if score is None else f', score {score:.3g}'}")
