"""Fakes for the panel tests: a view that records what it was told and a scripted backend."""
from __future__ import annotations

import threading
import time
from typing import Any, List, Optional

import numpy as np

from cinenerf_ns.planner.shots.shot import Shot
from cinenerf_ns.viewer.backend import NoMatchError, SceneGaussians
from cinenerf_ns.viewer.demo import look_at_rotation


class FakeView:
    def __init__(self, camera: Optional[np.ndarray] = None) -> None:
        self.lock = threading.Lock()
        self.calls: List[tuple] = []
        self.cameras: List[tuple] = []  # (perf_counter, c2w [3,4])
        self.statuses: List[tuple] = []
        self.playing: List[bool] = []
        self.exports: List[tuple] = []  # (path or None, text) of every show_export
        self.commands: List[Any] = []  # the command shown with each show_export (None: none)
        self.inputs: List[tuple] = []  # (goto, look_at) put on screen by each Plan
        self.details: List[str] = []
        self.previews: List[Any] = []  # paths offered (None: offer hidden)
        self.drawn_shot: Any = "never"
        self.candidates: List[str] = []
        self.targets: list = []
        self.camera = camera

    def _rec(self, *a):
        with self.lock:
            self.calls.append(a)

    def set_status(self, text, level):
        self._rec("status", text, level)
        with self.lock:
            self.statuses.append((text, level))

    def show_candidates(self, labels, selected):
        self._rec("candidates", list(labels), selected)
        self.candidates = list(labels)

    def draw_shot(self, shot, options):
        self._rec("draw_shot", shot, options)
        self.drawn_shot = shot

    def draw_targets(self, targets, options):
        self._rec("draw_targets", targets, options)
        self.targets = list(targets)

    def set_camera(self, c2w):
        with self.lock:
            self.cameras.append((time.perf_counter(), np.array(c2w)))
        return 1

    def camera_position(self):
        return self.camera

    def set_playing(self, playing):
        with self.lock:
            self.playing.append(playing)

    def show_export(self, path, text, command=None):
        self.exports.append((path, text))
        self.commands.append(command)

    def show_inputs(self, goto, look_at):
        self._rec("inputs", goto, look_at)
        self.inputs.append((goto, look_at))

    def show_details(self, text):
        self.details.append(text)

    def show_preview(self, path):
        self.previews.append(path)

    @property
    def last_status(self):
        return self.statuses[-1] if self.statuses else ("", "")


def line_shot(a, b, look_at, duration=1.0, n=31, clearance=0.05) -> Shot:
    a, b, look_at = (np.asarray(v, float) for v in (a, b, look_at))
    t = np.linspace(0.0, duration, n)
    pos = a[None] + (t / duration)[:, None] * (b - a)[None]
    rot = np.stack([look_at_rotation(p, look_at) for p in pos])
    return Shot(times=t, positions=pos, rotations=rot, look_at=look_at, goal=b, start=a,
                clearance=np.full(n, clearance))


class FakeBackend:
    """Objects 'chair' (Gaussians 0-9) and 'lamp' (10-19); ``fail`` makes plan raise it."""

    def __init__(self, plan_delay: float = 0.0, n_shots: Optional[int] = None, duration: float = 1.0):
        rng = np.random.default_rng(0)
        self.means = rng.uniform(-1, 1, (30, 3))
        self.plan_delay = plan_delay
        self.n_shots = n_shots
        self.duration = duration
        self.fail: Optional[BaseException] = None
        self.plan_calls: List[dict] = []
        self.started = threading.Event()

    def gaussians(self):
        return SceneGaussians(self.means)

    def locate(self, text):
        """(centroid, mask, what matched); 'ghost' names an object with no Gaussians left (an empty mask)."""
        mask = np.zeros(30, bool)
        if "chair" in text:
            mask[:10] = True
            label = "chair"
        elif "lamp" in text:
            mask[10:20] = True
            label = "lamp"
        elif "ghost" in text:
            return np.zeros(3), mask, "label 'ghost'"
        else:
            raise NoMatchError(f"'{text}' matches nothing")
        return self.means[mask].mean(0), mask, f"label '{label}'"

    def plan(self, goal, look_at, start=None, seed=0, n_candidates=1):
        self.plan_calls.append(dict(goal=goal, look_at=look_at, start=start, seed=seed, n=n_candidates))
        self.started.set()
        if self.plan_delay:
            time.sleep(self.plan_delay)
        if self.fail is not None:
            raise self.fail
        n = n_candidates if self.n_shots is None else self.n_shots
        a0 = np.array([2.0, 0.0, 0.5]) if start is None else np.asarray(start, float)
        return [
            line_shot(a0 + [0, 0.1 * i + 0.01 * seed, 0], goal, look_at, duration=self.duration, clearance=0.05 + i)
            for i in range(n)
        ]


def camera_looking(position, forward, roll_deg=0.0) -> np.ndarray:
    """[3, 4] a nerfstudio camera-to-world (OpenGL: x right, y up, looking along -z) at ``position`` looking along
    ``forward``, z up, turned ``roll_deg`` about its view direction."""
    f = np.asarray(forward, float) / np.linalg.norm(forward)
    x = np.cross(f, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(x, f)
    r = np.deg2rad(roll_deg)
    x, y = np.cos(r) * x + np.sin(r) * y, -np.sin(r) * x + np.cos(r) * y
    return np.c_[x, y, -f, position]


def wait_for(pred, timeout: float = 15.0) -> bool:
    """Poll ``pred`` until true (True) or ``timeout`` seconds (False)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.02)
    return False
