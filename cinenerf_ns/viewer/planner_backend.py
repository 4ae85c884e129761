"""The real planner (``cinenerf_ns.planner.shots.planner.Planner``) as the panel's ``plan`` callable.

One :class:`PreparedPlanner` per obstacle scene: ``prepare()`` (spatial index, occupancy grid, free
components) runs once, optionally on a background thread so the viewer's UI stays responsive; the
status callback reports progress and the time it took. ``plan`` waits for the preparation, then plans
and adds the exact clearance of every frame (``Shot.clearance``) so the panel can show each candidate's
minimum clearance (the planner's own dense verification is kept in ``Shot.safety``).

Planner errors (``GoalUnreachableError``, ``StartInCollisionError``, ``InvalidInputError`` ...) pass
through unchanged: their messages are written for the user and the panel shows them verbatim.
"""
from __future__ import annotations

import dataclasses
import threading
import time
from typing import Any, Callable, List, Optional, Sequence

import numpy as np

from cinenerf_ns.planner.errors import PlanningError
from cinenerf_ns.planner.scene import planning_region
from cinenerf_ns.planner.scene.ellipsoids import EllipsoidScene
from cinenerf_ns.planner.scene.user_box import user_box
from cinenerf_ns.planner.shots.planner import Planner, PlannerConfig

from .region_box import AUTOMATIC, RegionInfo, notify_all

StatusFn = Callable[[str, str], None]  # (text, level "busy" | "ok" | "error")


class PreparedPlanner:
    """A :class:`Planner` over one scene, prepared once; ``plan`` matches ``backend.PlanFn``."""

    name = "cinenerf_ns planner"

    def __init__(
        self,
        scene: EllipsoidScene,
        config: Optional[PlannerConfig] = None,
        on_status: Optional[StatusFn] = None,
        clearance_cap: Optional[float] = 0.05,
    ) -> None:
        """clearance_cap: per-frame clearances shown in the panel are exact up to this (scene units) and
        reported as the cap above it (None: always exact, slow on large scenes)."""
        self.scene = scene
        self.clearance_cap = clearance_cap
        # candidate_workers=0: the viewer runs in a multi-threaded process (viser's server, and during ns-train the
        # trainer's CUDA threads); forking it for worker processes could deadlock a child on a lock another
        # thread held at the fork. The CLI (one thread) uses the workers. Pass a config to choose otherwise.
        self.config = config or PlannerConfig(candidate_workers=0)
        self.on_status = on_status
        self.planner: Optional[Planner] = None
        self.prepare_s: Optional[float] = None  # wall time of prepare(), once done
        self.prepare_detail = ""  # its timings, for the details fold
        self.error: Optional[BaseException] = None  # what prepare() raised, re-raised by plan()
        self._done = threading.Event()  # the latest preparation's (set_region makes a new one)
        self._started = False
        self._start_lock = threading.Lock()
        self._plan_lock = threading.Lock()  # Planner objects are not assumed thread-safe
        self._prep_lock = threading.Lock()  # one preparation at a time (set_region while one runs: the next waits)
        self._thread: Optional[threading.Thread] = None  # the latest preparation's
        self._generation = 0  # 0: the opening preparation; each set_region adds one
        self._request: tuple = (0, self.config, self._done)  # (generation, config, done): the latest asked for
        self._queued = False  # a preparation thread is waiting for _prep_lock: it takes the latest request
        self._prepared_gen = -1  # the newest generation a preparation took up
        self._region: Optional[RegionInfo] = None
        self._listeners: List[Callable[[], None]] = []

    # ------------------------------------------------------------------ preparation
    def start(self, background: bool = True) -> "PreparedPlanner":
        """Begin ``prepare()`` (once); on a daemon thread when ``background``."""
        with self._start_lock:
            if self._started:
                return self
            self._started = True
            self._region = self._pending_region(self.config, 0)
        self._launch(background)
        return self

    def _launch(self, background: bool) -> None:
        """Prepare the latest request: on a new thread unless one already waits to (at most one runs and one waits,
        however often a page clicks Apply)."""
        with self._start_lock:
            if self._queued:
                return
            self._queued = True
        if background:
            self._thread = threading.Thread(target=self._prepare, name="cine-prepare", daemon=True)
            self._thread.start()
        else:
            self._prepare()

    def _status(self, text: str, level: str) -> None:
        if self.on_status is not None:
            try:
                self.on_status(text, level)
            except Exception:  # a broken view must not stop the preparation
                pass

    def _prepare(self) -> None:
        with self._prep_lock:
            with self._start_lock:
                self._queued = False
                gen, config, done = self._request
            try:
                if gen > self._prepared_gen:  # else prepared (or being replaced) already
                    self._prepared_gen = gen
                    self._prepare_now(gen, config)
            finally:
                done.set()

    def _prepare_now(self, gen: int, config: PlannerConfig) -> None:
        t0 = time.perf_counter()
        self._status(f"Preparing the planner for {len(self.scene)} obstacles (spatial index, occupancy grid)...",
                     "busy")
        try:
            planner = Planner(self.scene, config)
            prep = planner.prepare()
            from cinenerf_ns.planner.shots.end_pose import visibility_volume

            t_vol = time.perf_counter()
            visibility_volume(planner)  # the end poses' splat volume, off the first Plan's path
            prep.timings_ms["visibility_ms"] = 1e3 * (time.perf_counter() - t_vol)
            lo, hi = planner.region()
            rule = planner.region_rule()  # computed here, off the UI's threads (a histogram of the means)
            region = RegionInfo(lo, hi, rule if config.bounds is not None else f"{AUTOMATIC}: {rule}", "ready",
                                generation=gen, automatic=config.bounds is None, asked=self._asked(config))
            if gen != self._generation:  # superseded while preparing: a newer region follows
                planner.close()
                return
            with self._plan_lock:  # never under a running plan
                old, self.planner, self.config, self.error = self.planner, planner, config, None
                self._region = region
            if old is not None:
                old.close()
            self.prepare_s = time.perf_counter() - t0
            detail = ", ".join(f"{k[:-3]} {v:.0f} ms" for k, v in prep.timings_ms.items())
            self.prepare_detail = (f"Planner prepared in {self.prepare_s:.2f} s ({detail}) for "
                                   f"{region.describe()}.")  # the details fold
            note = f" ({planner.grid_note})" if planner.grid_note else ""  # a finer grid than asked for is said
            self._status(f"Planner ready. It plans in {region.describe()}{note}.", "ok")
        except BaseException as err:  # kept and re-raised by plan(): the panel shows it
            if gen != self._generation:
                return
            with self._plan_lock:
                self.error, self.config = err, config
                asked = self._asked(config)
                self._region = RegionInfo(*(asked or (None, None)), self._region.rule if self._region else AUTOMATIC,
                                          "error", str(err), gen, asked is None, asked)
            self.prepare_s = time.perf_counter() - t0
            self._status(f"The planner could not prepare this scene: {err}", "error")
        self._notify()

    def wait_ready(self, timeout: Optional[float] = None) -> bool:
        """Start (in this thread if not started) and wait until prepare() finished; True when usable."""
        if not self._started:
            self.start(background=False)
        end = None if timeout is None else time.monotonic() + timeout
        while True:
            done = self._done
            if not done.wait(None if end is None else max(end - time.monotonic(), 0.0)):
                return False
            if done is self._done:  # else a newer region was asked for meanwhile: wait for it
                return self.planner is not None and self.error is None

    @property
    def ready(self) -> bool:
        return self._done.is_set() and self.planner is not None and self.error is None

    # ------------------------------------------------------------------ the planning region (region_box.RegionSource)
    def region_info(self) -> Optional[RegionInfo]:
        """The planning region in use, or the one being prepared (state 'preparing') or refused by prepare()."""
        return self._region

    def set_region(self, bounds: Optional[Sequence[Any]]) -> RegionInfo:
        """Plan in ``bounds`` (lo [3], hi [3]; bounds_rule 'user box') or, with None, the automatic region (training
        cameras, else the dense content). The box is checked at once, as cinesplat-plan --region is
        (user_box, planning_region's check_user_box and check_region: InvalidInputError, nothing changes); then the
        planner is prepared again in the background (a Plan waits for it; one asked for while another prepares
        replaces it)."""
        if bounds is not None:
            lo, hi = user_box(bounds, "the planning region")
            planning_region.check_user_box(self.scene, lo, hi, "the planning region")
            planning_region.check_region(self.config, float(self.scene.camera_radius), lo, hi)
            bounds = (lo, hi)
        config = dataclasses.replace(self.config, bounds=bounds, bounds_rule="user box")
        with self._start_lock:
            self._started = True
            self._generation += 1
            gen, old, self._done = self._generation, self._done, threading.Event()
            self._request = (gen, config, self._done)
            self._region = info = self._pending_region(config, gen)
        old.set()  # a preparation it replaces may still run: its waiters move on to this one
        self._notify()
        self._launch(background=True)
        return info

    @staticmethod
    def _asked(config: PlannerConfig) -> tuple:
        """(lo, hi) of the box a config asks for, None for the automatic region."""
        if config.bounds is None:
            return None
        return tuple(np.asarray(v, dtype=np.float64).reshape(3) for v in config.bounds)

    def _pending_region(self, config: PlannerConfig, gen: int) -> RegionInfo:
        rule = config.bounds_rule if config.bounds is not None else AUTOMATIC
        asked = self._asked(config)
        return RegionInfo(*(asked or (None, None)), rule, "preparing", generation=gen, automatic=asked is None,
                          asked=asked)

    def add_region_listener(self, fn: Callable[[], None]) -> None:
        """``fn()`` after every change of the region or its state (on the thread that changed it)."""
        self._listeners.append(fn)

    def _notify(self) -> None:
        notify_all(self._listeners)

    # ------------------------------------------------------------------ planning
    plans_end_poses = True  # the panel passes its resolved targets and framing (panel._plan_now)

    def plan(self, goal: Any, look_at: Any, start: Any = None, seed: int = 0, n_candidates: int = 1,
             targets: Optional[tuple] = None, framing: str = "medium") -> List[Any]:
        """Shots from the real planner (waits for ``prepare``); every shot gets ``clearance`` [T]:
        the exact clearance (camera radius included) of its frames. ``targets``: the panel's resolved (go-to,
        look-at) Targets (their masks): an object go-to then ends at a chosen end pose (shot_targets.py, as
        cinesplat-plan does), scores use the look-at object's visibility, and each shot gets ``end_pose`` and
        ``subject_view`` (what the status reports)."""
        self.wait_ready()
        if self.error is not None:
            if isinstance(self.error, PlanningError):
                raise type(self.error)(str(self.error))
            raise PlanningError(f"the planner could not prepare this scene: {type(self.error).__name__}: {self.error}")
        assert self.planner is not None
        pt = lambda x: None if x is None else np.asarray(_numpy(x), dtype=np.float64).reshape(-1)  # noqa: E731
        with self._plan_lock:
            tg = None
            if targets is not None:
                tg = self._targets(targets, framing, pt(look_at), pt(start), int(n_candidates))
            from cinenerf_ns.shot_request import ShotRequest, plan_request

            # the same request rule as cinesplat-plan (shot_request.py): one scored shot from a given start, else
            # ranked candidates from random starts (one included), best first by the documented shot score
            ranked = plan_request(self.planner, ShotRequest(
                goals=pt(goal)[None] if tg is None else tg.goals(pt(goal)), look_at=pt(look_at), start=pt(start),
                candidates=int(n_candidates), seed=int(seed), subject=None if tg is None else tg.samples))
            shots = []
            for r in ranked:
                r.shot.score, r.shot.rank = float(r.score.total), int(r.rank)
                r.shot.score_terms = r.score.to_dict()
                r.shot.end_pose = None if tg is None else tg.pose_of(r.candidate)
                shots.append(r.shot)
            for shot in shots:
                aimed = shot.goal_target if tg is not None and tg.ends_at_poses else pt(goal)
                shot.goal_moved = self.planner.explain_goal(aimed, shot.goal)  # said on screen, never silent
                if tg is not None:
                    terms = (shot.score_terms or {}).get("terms")
                    shot.subject_view = tg.view_report(shot.positions[-1], pt(look_at), self.planner.config.up, terms)
                    shot.end_pose_note = tg.note()
                if shot.clearance is None:
                    t0 = time.perf_counter()
                    # exact where it matters (near obstacles); capped far away: the uncapped search
                    # would dominate a Plan on large scenes
                    shot.clearance = np.asarray(self.planner.clearance(shot.positions, cap=self.clearance_cap,
                                                                       batch=True),
                                                dtype=np.float64).reshape(-1)
                    shot.timings["frame_clearance_ms"] = 1e3 * (time.perf_counter() - t0)
        return list(shots)


    def _targets(self, targets: tuple, framing: str, look: np.ndarray, start: Optional[np.ndarray], k: int):
        """shot_targets of the panel's (go-to, look-at) Targets: the same choice as cinesplat-plan."""
        from cinenerf_ns.planner.shots import stages
        from cinenerf_ns.planner.shots.framing import FramingConfig
        from cinenerf_ns.shot_targets import end_pose_count, shot_targets, start_region_centre

        goal_t, look_t = targets
        as_match = lambda t: {"point": np.asarray(t.point, np.float64), "text": t.text,  # noqa: E731
                              **({} if t.mask is None else {"mask": np.asarray(t.mask, bool)})}
        if start is not None:
            comp, facing = stages.start_voxel(self.planner.space, self.planner.checked_start(start))[1], start
        else:
            comp, facing = self.planner.main_component(), start_region_centre(self.planner)
        return shot_targets(self.planner, as_match(goal_t), as_match(look_t), FramingConfig(framing), comp,
                            k=1 if start is not None else end_pose_count(k), facing_from=facing)


def _numpy(x: Any) -> Any:
    return x.detach().cpu().numpy() if hasattr(x, "detach") else x
