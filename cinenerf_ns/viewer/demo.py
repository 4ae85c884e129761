"""A small labelled demo scene and a straight-line stand-in planner for the standalone viewer.

The stand-in exists so the viewer can be used and tested before the real planner
(``cinenerf_ns.planner.planner.Planner``) is wired in; ``standalone.py`` prefers the real one when it
imports. It is deliberately simple and honest: it only returns a straight segment whose every point
provably keeps the camera sphere outside every obstacle's *bounding sphere* (a conservative test:
distance to a Gaussian's bounding sphere <= distance to its ellipsoid), and raises
``GoalUnreachableError`` otherwise. No corridor, no smoothing beyond an ease-in/ease-out timing.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Tuple

import numpy as np

from cinenerf_ns.planner.errors import GoalUnreachableError, InvalidInputError, StartInCollisionError
from cinenerf_ns.planner.shot import Shot

from .backend import to_numpy

UP = np.array([0.0, 0.0, 1.0])


@dataclass
class DemoSplat:
    """Raw splat parameters (3DGS / splatfacto layout) plus ground-truth object labels."""

    means: np.ndarray  # [N, 3]
    quats_wxyz: np.ndarray  # [N, 4]
    log_scales: np.ndarray  # [N, 3]
    opacity_logits: np.ndarray  # [N]
    colors: np.ndarray  # [N, 3] RGB in [0, 1]
    labels: List[str]  # object names; label_of indexes this list, -1 = background
    label_of: np.ndarray  # [N] int


def demo_scene(seed: int = 0, floor_res: int = 30) -> DemoSplat:
    """A floor with three named objects ('red box', 'green ball', 'blue pillar'), ~2.5k Gaussians."""
    rng = np.random.default_rng(seed)
    parts: List[Tuple[np.ndarray, np.ndarray, float, int]] = []  # (means, color, sigma, label)
    g = np.linspace(-1.2, 1.2, floor_res)
    fx, fy = np.meshgrid(g, g)
    floor = np.stack([fx.ravel(), fy.ravel(), np.zeros(fx.size)], -1)
    parts.append((floor, np.array([0.55, 0.55, 0.5]), 0.045, -1))
    box = rng.uniform(-0.12, 0.12, (400, 3)) + np.array([0.5, 0.45, 0.14])
    parts.append((box, np.array([0.85, 0.15, 0.1]), 0.02, 0))
    d = rng.normal(size=(400, 3))
    ball = 0.15 * d / np.linalg.norm(d, axis=1, keepdims=True) + np.array([-0.5, 0.35, 0.2])
    parts.append((ball, np.array([0.15, 0.75, 0.2]), 0.02, 1))
    ang, hz = rng.uniform(0, 2 * np.pi, 500), rng.uniform(0.0, 0.7, 500)
    pillar = np.stack([0.08 * np.cos(ang), 0.08 * np.sin(ang) - 0.6, hz], -1)
    parts.append((pillar, np.array([0.15, 0.25, 0.85]), 0.02, 2))
    means = np.concatenate([p[0] for p in parts]).astype(np.float32)
    n = len(means)
    colors = np.concatenate([np.tile(p[1], (len(p[0]), 1)) for p in parts]).astype(np.float32)
    colors = np.clip(colors + rng.normal(scale=0.03, size=colors.shape), 0, 1).astype(np.float32)
    sig = np.concatenate([np.full(len(p[0]), p[2]) for p in parts])
    log_scales = np.log(np.stack([sig, sig, sig], -1)).astype(np.float32)
    log_scales[: len(floor), 2] = math.log(0.004)  # flat floor tiles
    q = rng.normal(size=(n, 4))
    q[: len(floor)] = [1, 0, 0, 0]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return DemoSplat(
        means=means, quats_wxyz=q.astype(np.float32), log_scales=log_scales,
        opacity_logits=np.full(n, 3.0, np.float32), colors=colors,
        labels=["red box", "green ball", "blue pillar"],
        label_of=np.concatenate([np.full(len(p[0]), p[3]) for p in parts]),
    )


def look_at_rotation(position: np.ndarray, target: np.ndarray, up: np.ndarray = UP) -> np.ndarray:
    """nerfstudio camera-to-world rotation [3, 3] at ``position`` looking at ``target`` (-z forward,
    +y up, no roll). Straight up/down falls back to +y as the up hint."""
    f = np.asarray(target, np.float64) - np.asarray(position, np.float64)
    nf = np.linalg.norm(f)
    if nf < 1e-12:
        raise InvalidInputError("the camera cannot look at its own position")
    f = f / nf
    hint = up if abs(float(f @ up)) < 0.999 else np.array([0.0, 1.0, 0.0])
    x = np.cross(f, hint)
    x /= np.linalg.norm(x)
    y = np.cross(x, f)
    return np.stack([x, y, -f], axis=1)


# the stand-in returns the planner's own Shot type so export/playback code paths are the real ones
StraightShot = Shot


class StraightLinePlanner:
    """Stand-in planner over obstacle bounding spheres (see module docstring)."""

    def __init__(
        self,
        centers: np.ndarray,  # [N, 3]
        bound_radii: np.ndarray,  # [N] radius of a sphere containing each obstacle ellipsoid
        camera_radius: float = 0.03,
        speed: float = 0.4,
        fps: int = 30,
        region: Optional[Tuple[np.ndarray, np.ndarray]] = None,
    ) -> None:
        self.centers = to_numpy(centers).reshape(-1, 3)
        self.bound_radii = to_numpy(bound_radii).reshape(-1)
        self.camera_radius = float(camera_radius)
        self.speed, self.fps = float(speed), int(fps)
        if region is None:
            lo, hi = self.centers.min(0), self.centers.max(0)
            pad = 0.15 * (hi - lo)
            region = (lo - pad, hi + pad)
        self.region = (np.asarray(region[0], np.float64), np.asarray(region[1], np.float64))

    @classmethod
    def from_scene(cls, scene: Any, **kw) -> "StraightLinePlanner":
        """From an ``EllipsoidScene`` (bounding radius = largest semi-axis)."""
        return cls(to_numpy(scene.means), to_numpy(scene.radii).max(-1), float(scene.camera_radius), **kw)

    def clearance_lower_bound(self, points: np.ndarray) -> np.ndarray:
        """[P, 3] -> [P]: min_j |p - c_j| - R_j - camera_radius (<= the true clearance).

        Exact value of that minimum through a KD-tree: with d1 the nearest-centre distance, any j
        with |p - c_j| > d1 + max(R) has |p - c_j| - R_j > d1 >= the nearest centre's term, so only
        centres within d1 + max(R) can attain the minimum."""
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        tree = self._tree()
        d1, _ = tree.query(pts)
        r_max = float(self.bound_radii.max()) if len(self.bound_radii) else 0.0
        out = np.empty(len(pts))
        for i, (p, near) in enumerate(zip(pts, tree.query_ball_point(pts, d1 + r_max + 1e-12))):
            near = np.asarray(near, dtype=np.int64)
            out[i] = (np.linalg.norm(self.centers[near] - p, axis=1) - self.bound_radii[near]).min()
        return out - self.camera_radius

    def clearance_lower_bound_reference(self, points: np.ndarray) -> np.ndarray:
        """Brute force over all obstacles (float64), the reference the KD-tree version is tested against."""
        pts = np.asarray(points, np.float64).reshape(-1, 3)
        d = np.linalg.norm(pts[:, None, :] - self.centers[None], axis=-1) - self.bound_radii[None]
        return d.min(1) - self.camera_radius

    def _tree(self):
        if getattr(self, "_kdtree", None) is None:
            from scipy.spatial import cKDTree

            self._kdtree = cKDTree(self.centers)
        return self._kdtree

    def _segment_clear(self, a: np.ndarray, b: np.ndarray) -> Tuple[bool, np.ndarray, np.ndarray]:
        # Samples spaced h apart with clearance > h/2 cover the whole segment (distance is 1-Lipschitz).
        length = float(np.linalg.norm(b - a))
        h = max(self.camera_radius / 2, 1e-3)
        n = max(int(math.ceil(length / h)), 1) + 1
        s = np.linspace(0.0, 1.0, n)
        pts = a[None] + s[:, None] * (b - a)[None]
        c = self.clearance_lower_bound(pts)
        return bool(np.all(c > 0.5 * length / (n - 1))), pts, c

    def _approach(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """Fly from the start towards the goal (often an object's centre, inside it) and stop at the
        last sample before the camera would come within 2 camera radii of any obstacle."""
        length = float(np.linalg.norm(goal - start))
        h = max(self.camera_radius / 2, 1e-3)
        n = max(int(math.ceil(length / h)), 1) + 1
        pts = start[None] + np.linspace(0.0, 1.0, n)[:, None] * (goal - start)[None]
        blocked = np.nonzero(self.clearance_lower_bound(pts) <= 2 * self.camera_radius)[0]
        if len(blocked) == 0:
            return goal
        return pts[max(int(blocked[0]) - 1, 0)]

    def plan(self, goal, look_at, start=None, seed: int = 0, n_candidates: int = 1) -> List[StraightShot]:
        goal, look_at = to_numpy(goal).reshape(3), to_numpy(look_at).reshape(3)
        rng = np.random.default_rng(seed)
        if start is not None:
            start = to_numpy(start).reshape(3)
            if self.clearance_lower_bound(start[None])[0] <= 0:
                raise StartInCollisionError(f"the start {np.round(start, 3).tolist()} is inside (or too near) the scene")
            shot = self._try(start, goal, look_at)
            if shot is None:
                raise GoalUnreachableError(
                    "no straight collision-free path from this start to the goal (the stand-in planner only "
                    "flies straight lines; try a random start)"
                )
            return [shot]
        shots, free_starts = [], 0
        for _ in range(200 * max(n_candidates, 1)):  # random free starts until enough straight shots
            p = rng.uniform(*self.region)
            if self.clearance_lower_bound(p[None])[0] <= 3 * self.camera_radius:
                continue
            free_starts += 1
            shot = self._try(p, goal, look_at)
            if shot is not None:
                shots.append(shot)
                if len(shots) == n_candidates:
                    break
            if free_starts >= 60 * max(n_candidates, 1):
                break
        if not shots:
            if free_starts == 0:
                raise StartInCollisionError("found no free random start in the scene bounds")
            raise GoalUnreachableError(
                f"no straight collision-free path to the goal from {free_starts} random starts (the stand-in "
                "planner only flies straight lines; the real planner goes around obstacles)"
            )
        return shots

    def _try(self, s: np.ndarray, goal: np.ndarray, look_at: np.ndarray) -> Optional[StraightShot]:
        end = self._approach(s, goal)
        # it must get at least half-way: stopping in front of another object is not "going to" the goal
        if np.linalg.norm(end - goal) > 0.5 * np.linalg.norm(s - goal) or np.linalg.norm(end - look_at) < 1e-6:
            return None
        ok, _, _ = self._segment_clear(s, end)
        return self._make_shot(s, end, goal, look_at) if ok else None

    def _make_shot(self, a: np.ndarray, b: np.ndarray, goal: np.ndarray, look_at: np.ndarray) -> StraightShot:
        length = float(np.linalg.norm(b - a))
        duration = max(1.5 * length / self.speed, 0.5)  # smoothstep peaks at 1.5x the mean speed
        n = max(int(math.ceil(duration * self.fps)), 1) + 1
        times = np.linspace(0.0, duration, n)
        u = times / duration
        s = u * u * (3 - 2 * u)  # ease in / ease out
        pos = a[None] + s[:, None] * (b - a)[None]
        target = look_at if np.linalg.norm(look_at - b) > 1e-6 else b + (b - a)
        rot = np.stack([look_at_rotation(p, target) for p in pos])
        return Shot(times=times, positions=pos, rotations=rot, look_at=look_at, goal=goal, start=a,
                    clearance=self.clearance_lower_bound(pos), fps=float(self.fps))
