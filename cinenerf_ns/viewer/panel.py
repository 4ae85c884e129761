"""The cinematography panel's logic: state, plan / animate / export, over two small interfaces.

* :class:`PanelBackend` gives the Gaussians, a text query (``locate``) and the planner (``plan``).
* :class:`PanelView` is what the panel draws on and moves: the viser implementation is
  ``viser_ui.ViserPanelUI``; tests use a fake that records calls. No viser import here.

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
from dataclasses import replace
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np

from cinenerf_ns.planner.config import MAX_CANDIDATES
from cinenerf_ns.planner.errors import GoalUnreachableError, InvalidInputError, PlanningError
from cinenerf_ns.planner.shots.framing import FRAMINGS
from cinenerf_ns.point_text import parse_point

from .backend import to_numpy
from .conventions import interpolate_pose
from .export import Exporter, default_exporter
from .panel_output import OutputMixin, Previewer
from .panel_types import (  # noqa: F401 - re-exported: callers import the panel's types from here
    DisplayOptions,
    ExportResult,
    PanelBackend,
    PanelConfig,
    PanelView,
    PlanRequest,
    PlanResult,
    ServerLimits,
    Shot,
    Target,
)
from .region_box import RegionMixin
from .safe_text import check_text
from .shot_text import (  # noqa: F401 - re-exported: callers import the shot texts from here
    SCORE_RULE,
    candidate_label,
    check_shot,
    goal_note,
    min_clearance,
    plan_summary,
    shot_score,
    shot_summary,
    sort_by_score,
    timings_detail,
)

log = logging.getLogger(__name__)

MAX_PANEL_CANDIDATES = MAX_CANDIDATES
"""Most candidates one Plan asks for (the planner's cap)."""


# ----------------------------------------------------------------------------------------- panel
class CinePanel(OutputMixin, RegionMixin):
    """All state and logic of the cinematography panel. GUI layers call the public methods (export and preview:
    :class:`~.panel_output.OutputMixin`; the planning region:
    :class:`~.region_box.RegionMixin`)."""

    IDLE, PLANNING, READY, PLAYING, PAUSED = "idle", "planning", "ready", "playing", "paused"

    def __init__(
        self,
        backend: PanelBackend,
        view: PanelView,
        config: Optional[PanelConfig] = None,
        exporter: Optional[Exporter] = None,
        previewer: Optional[Previewer] = None,
        limits: Optional[ServerLimits] = None,
    ) -> None:
        """``previewer`` renders a camera-path dict to a video (None: no "Preview video"). ``limits``: the work shared
        with the other clients' panels of the same viewer (plan slots, the preview slot, files written)."""
        self.backend = backend
        self.view = view
        self.config = replace(config) if config is not None else PanelConfig()
        # absolute once, at start: exports never depend on a later working directory, and the path shown is the file's
        self.config.data_dir = Path(self.config.data_dir).expanduser().absolute()
        if self.config.output_dir is not None:
            self.config.output_dir = Path(self.config.output_dir).expanduser().absolute()
        self.exporter: Exporter = exporter or default_exporter()
        self.previewer = previewer
        self.limits = limits if limits is not None else ServerLimits()
        self.options = DisplayOptions()
        self.seed = 0
        self.last_timings: Dict[str, float] = {}
        self.status = ""
        self.status_level = "info"
        self._status_owner = ""  # what set the status ("speed": a speed error, cleared by the next good speed)
        self._status_before = ("", "info")  # the status a speed error replaced
        self._lock = threading.RLock()  # state; held while joining the animation thread
        self._t_lock = threading.Lock()  # playback time / end-of-shot state, shared with the animation thread
        self._state = self.IDLE
        self._shots: List[Shot] = []
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
        self._init_output()

    # ------------------------------------------------------------------ read-only state
    @property
    def state(self) -> str:
        return self._state

    @property
    def planned_before(self) -> bool:
        """Whether a Plan was ever requested (its status, even a fast failure's, then owns the status line)."""
        return self._generation > 0

    @property
    def shots(self) -> List[Shot]:
        return list(self._shots)

    @property
    def selected(self) -> int:
        return self._selected

    @property
    def shot(self) -> Optional[Shot]:
        with self._lock:
            return self._shots[self._selected] if self._shots else None

    @property
    def targets(self) -> List[Target]:
        return list(self._targets)

    @property
    def playback_time(self) -> float:
        return self._t

    # ------------------------------------------------------------------ status
    def _set_status(self, text: str, level: str = "info", owner: str = "") -> None:
        if owner and not self._status_owner:
            self._status_before = (self.status, self.status_level)
        self.status, self.status_level, self._status_owner = text, level, owner
        try:
            self.view.set_status(text, level)
        except Exception:  # a broken view must not take the panel down
            log.exception("view.set_status failed")

    def _call_view(self, method: str, *args) -> None:
        """A view call whose failure must not stop the panel (logged)."""
        try:
            getattr(self.view, method)(*args)
        except Exception:
            log.exception("view.%s failed", method)

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
        framing: Optional[str] = None,
    ) -> cf.Future:
        """Cancel any animation and plan on the worker thread. Returns a Future of
        :class:`PlanResult` (None when the request failed or was superseded; see ``status``). Texts longer than
        ``MAX_TEXT_CHARS``, or a client with ``limits.max_pending_plans`` requests queued, are refused at once."""
        done: cf.Future = cf.Future()
        done.set_result(None)
        try:
            goto, look_at = check_text(goto or "", "Go to"), check_text(look_at or "", "Look at")
            n = int(n_candidates if n_candidates is not None else self.config.n_candidates)
            if not 1 <= n <= MAX_PANEL_CANDIDATES:
                raise InvalidInputError(f"'Candidates' must be 1 to {MAX_PANEL_CANDIDATES} (got {n})")
            framing = "medium" if framing is None else framing
            if framing not in FRAMINGS:
                raise InvalidInputError(f"'Framing' must be one of {', '.join(FRAMINGS)} (got {str(framing)[:40]!r})")
        except (InvalidInputError, TypeError, ValueError, OverflowError) as err:
            self._fail("Plan", err)
            return done
        with self._lock:
            if self._closed:
                return done
            if self._pending >= self.limits.max_pending_plans:
                self._set_status(f"Still working on {self._pending} earlier Plan requests: wait for them before "
                                 "planning again", "error")
                return done
            self._stop_animation()
            if new_start:
                self.seed += 1
            self._generation += 1
            self._pending += 1
            self._last_texts = (goto, look_at)
            req = PlanRequest(
                goto=goto or "", look_at=look_at or "", seed=self.seed,
                n_candidates=n, start_from_camera=start_from_camera, generation=self._generation, framing=framing,
            )
            self._state = self.PLANNING
        # one source of truth: the boxes show exactly the texts this plan uses; the last plan's outputs go away
        self._call_view("show_inputs", req.goto, req.look_at)
        self._call_view("show_export", None, "")
        self._call_view("show_preview", None)
        self._call_view("show_details", "")
        self._set_status(f"Planning: go to '{req.goto}', look at '{req.look_at}'...", "busy")
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
            if not np.all(np.isfinite(point)):
                raise InvalidInputError(f"'{role}': the point '{text}' is not finite: give three finite numbers "
                                        "'x y z'")
            return Target(role, text, point, None)
        found = tuple(self.backend.locate(text))  # (centroid [3], mask [N][, what it matched])
        centroid, mask = to_numpy(found[0]).reshape(3), found[1]
        matched = str(found[2]) if len(found) > 2 and found[2] else ""
        mask = None if mask is None else to_numpy(mask, bool).reshape(-1)
        if mask is not None and not mask.any():
            raise InvalidInputError(f"'{role}': '{text}' matches nothing in this scene (no Gaussian selected)")
        if not np.all(np.isfinite(centroid)):
            raise InvalidInputError(f"the query '{text}' gave a non-finite centroid {centroid}")
        return Target(role, text, centroid, mask, matched)

    def _superseded(self, req: PlanRequest) -> bool:
        return req.generation != self._generation or self._closed

    def _plan_job(self, req: PlanRequest) -> Optional[PlanResult]:
        try:
            if self._superseded(req):
                return None  # a newer Plan was requested before this one started
            waited = []
            if not self.limits.acquire_plan_slot(lambda: self._superseded(req), lambda: waited.append(
                    self._set_status("Waiting for another user's Plan on this viewer to finish...", "busy"))):
                return None  # superseded (or closed) while waiting
            try:
                if waited and not self._superseded(req):
                    self._set_status(f"Planning: go to '{req.goto}', look at '{req.look_at}'...", "busy")
                return self._plan_now(req)
            finally:
                self.limits.release_plan_slot()
        except BaseException as err:  # never let the worker die silently
            if not self._superseded(req):
                self._fail("Plan", err)
                if req.warning:  # the likely cause, said with the error
                    end = "" if self.status.endswith((".", "!", "?")) else "."
                    self._set_status(f"{self.status}{end} Warning: {req.warning}", "error")
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
        warning = req.warning = same_place_warning(goal, look)
        if warning:  # said while planning too, not only when the shot is there
            self._set_status(f"Planning: {goal.describe()}; {look.describe()}... Warning: {warning}", "busy")
        start = None
        if req.start_from_camera:
            start = self.view.camera_position()
            if start is None:
                raise InvalidInputError("'start from my camera' needs a connected browser; none is connected")
        t1 = time.perf_counter()
        extra = {}
        if getattr(self.backend, "plans_end_poses", False):  # the real planner: end poses and visibility
            extra = {"targets": (goal, look), "framing": req.framing}
        shots = list(self.backend.plan(goal.point, look.point, start=start, seed=req.seed,
                                       n_candidates=req.n_candidates, **extra))
        t2 = time.perf_counter()
        if not shots:
            raise GoalUnreachableError(
                f"the planner found no collision-free shot to '{req.goto}' (try a new random start)"
            )
        # only Shots the panel can play; best (lowest score) first
        shots = sort_by_score([check_shot(s, f"candidate {i + 1}") for i, s in enumerate(shots)])
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
        result = PlanResult(shots, [goal, look], timings, warning)
        self._report_plan(req, result)
        if self.config.autoplay:
            with self._lock:  # atomic with request_plan's generation bump: no stale autoplay
                if not self._superseded(req):
                    self.play()
        return result

    def _report_plan(self, req: PlanRequest, result: PlanResult) -> None:
        """Status in the user's words (what was planned, what each query matched, the best shot, any warning);
        timings and the planner's internals go to the details fold."""
        shots, (goal, look), timings = result.shots, result.targets, result.timings
        scored = shot_score(shots[0]) is not None
        text = (f"{plan_summary(len(shots))}: {goal.describe()}; {look.describe()}. "
                f"Shot 1: {shot_summary(shots[0])}{goal_note(shots[0])}."
                f"{f' Candidates are sorted by score ({SCORE_RULE}).' if scored and len(shots) > 1 else ''}")
        if result.warning:
            text += f" Warning: {result.warning}"
        else:
            more = "pick another candidate, " if len(shots) > 1 else ""
            text += f" Next: Play it again, {more}or Export camera path."
        self._set_status(text, "warn" if result.warning else "ok")
        inner = timings_detail(shots[0].timings)
        by = getattr(self.backend, "planner_name", None)
        self._call_view("show_details", (
            f"Planner{f': {by}' if by else ''}, seed {req.seed}. Total {timings['total_s']:.2f} s: queries "
            f"{timings['query_s']:.2f} s, planning {timings['plan_s']:.2f} s{f' ({inner})' if inner else ''}, "
            f"drawing {timings['draw_s']:.2f} s."
            + (f" End pose: {shots[0].end_pose_note}." if shots[0].end_pose_note else "")))

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
        self._call_view("show_export", None, "")  # the export / preview shown were of another candidate
        self._call_view("show_preview", None)
        scored = shot_score(shot) is not None
        self._set_status(f"Candidate {index + 1}: {shot_summary(shot)}{f' ({SCORE_RULE})' if scored else ''}", "ok")

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
        """A speed <= 0 (e.g. "0" on the way to typing 0.25) keeps the current speed and says so until a good one
        arrives, which puts back the status it replaced."""
        if not (np.isfinite(speed) and speed > 0):
            self._set_status(f"Speed must be above 0 (got {speed:g}); still playing at {self.config.speed:g}x",
                             "error", owner="speed")
            return
        self.config.speed = float(speed)
        if self._status_owner == "speed":
            self._set_status(*self._status_before)

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

    def _animate(self, shot: Shot, stop: threading.Event) -> None:
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

    # ------------------------------------------------------------------ teardown
    def close(self) -> None:
        with self._lock:
            self._closed = True
            self._generation += 1
            self._stop_animation()
        self._executor.shutdown(wait=True, cancel_futures=True)
        self._close_output()


def same_place_warning(goal: Target, look: Target) -> str:
    """A warning when the go-to and look-at targets are the same place (the camera would end inside what it looks at),
    else ""."""
    same_mask = goal.mask is not None and look.mask is not None and goal.mask.shape == look.mask.shape \
        and bool(np.array_equal(goal.mask, look.mask))
    if not (same_mask or np.allclose(goal.point, look.point, atol=1e-6)):
        return ""
    return (f"'Go to' and 'Look at' are the same place ('{goal.text}' / '{look.text}'): the camera flies into what "
            f"it looks at. Look at something else, or go to a point beside it.")
