"""Piecewise Bezier curves in time: Bernstein basis, evaluation, derivatives.

Storage is numpy float64 on the CPU: the curve's control points come out of a CPU QP solver and
are few (M segments x (D+1) points), so keeping them in numpy avoids device round trips. The
evaluation methods accept numpy arrays, Python scalars/lists or torch tensors; a torch input gives a
torch float64 output on the input's device, anything else a numpy float64 array.

Segment k covers global times [T_k, T_k + d_k] with T_k = d_0 + ... + d_{k-1}; inside it the curve is
    p(t) = sum_i P_{k,i} B_{i,D}(u),   u = (t - T_k) / d_k in [0, 1],
    B_{i,D}(u) = C(D, i) u^i (1 - u)^(D - i).
Derivatives are taken with respect to time t (not u), so
    d^r p / dt^r = D! / (D - r)! / d_k^r * sum_j (Delta^r P_k)_j B_{j,D-r}(u)
with the forward differences (Delta^r P)_j = sum_i (-1)^(r-i) C(r, i) P_{j+i}.
"""
from __future__ import annotations

import functools
import math
import sys
from dataclasses import dataclass
from typing import Any, Tuple

import numpy as np

from ..errors import InvalidInputError


def is_torch(x: Any) -> bool:
    """Whether x is a torch tensor. torch is not imported here (the curve does not need it; the planner's
    configuration imports this module, and a command that only checks its options should not load torch): a
    process that has not imported torch holds no tensor."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(x, torch.Tensor)


def to_numpy(x: Any) -> np.ndarray:
    if is_torch(x):
        import torch

        return x.detach().to("cpu", torch.float64).numpy()
    return np.asarray(x, dtype=np.float64)


def same_kind_as(out: np.ndarray, ref: Any):
    """Return `out` as the same kind of array as `ref` (torch float64 on ref's device, else numpy)."""
    if is_torch(ref):
        import torch

        return torch.from_numpy(np.ascontiguousarray(out)).to(ref.device)
    return out


def bernstein_basis(degree: int, u: np.ndarray) -> np.ndarray:
    """Bernstein polynomials B_{i,degree}(u) for i = 0..degree: u [T] -> [T, degree+1] (float64)."""
    u = np.asarray(u, dtype=np.float64).reshape(-1)  # [T]
    binom = np.array([math.comb(degree, k) for k in range(degree + 1)], dtype=np.float64)
    # powers by cumulative products (much faster than float **); column 0 is exactly 1, so the end
    # points u = 0 and u = 1 are exact
    up = np.ones((u.shape[0], degree + 1))
    vp = np.ones((u.shape[0], degree + 1))
    if degree > 0:
        up[:, 1:] = np.cumprod(np.broadcast_to(u[:, None], (u.shape[0], degree)), axis=1)
        vp[:, 1:] = np.cumprod(np.broadcast_to((1.0 - u)[:, None], (u.shape[0], degree)), axis=1)
    return binom * up * vp[:, ::-1]


def difference_matrix(degree: int, order: int) -> np.ndarray:
    """Forward-difference operator: [degree+1-order, degree+1], row j gives (Delta^order P)_j."""
    n = degree + 1 - order
    mat = np.zeros((n, degree + 1))
    for j in range(n):
        for i in range(order + 1):
            mat[j, j + i] = (-1.0) ** (order - i) * math.comb(order, i)
    return mat


@functools.lru_cache(maxsize=None)
def _bernstein_to_power(n: int) -> np.ndarray:
    """[n+1, n+1] matrix M with power coefficients c = M P of a degree-n Bernstein polynomial with coefficients P:
    M[j, i] = C(n, j) C(j, i) (-1)^(j - i) (cached, read-only)."""
    m = np.zeros((n + 1, n + 1))
    for j in range(n + 1):
        for i in range(j + 1):
            m[j, i] = math.comb(n, j) * math.comb(j, i) * (-1.0) ** (j - i)
    m.setflags(write=False)
    return m


def power_coefficients(points: np.ndarray) -> np.ndarray:
    """Bernstein control points [M, n+1, 3] -> power-basis coefficients [M, n+1, 3] (segment k is
    sum_j c[k, j] u^j on u in [0, 1])."""
    return np.einsum("ji,mic->mjc", _bernstein_to_power(points.shape[1] - 1), points)


def derivative_control_points(control_points: np.ndarray, durations: np.ndarray, order: int) -> np.ndarray:
    """Control points of the order-th time derivative of each segment.

    control_points [M, D+1, 3], durations [M] -> [M, D+1-order, 3] (zeros of shape [M, 1, 3] when
    order > D: the derivative vanishes identically).
    """
    degree = control_points.shape[1] - 1
    if order > degree:
        return np.zeros((control_points.shape[0], 1, control_points.shape[2]))
    scale = math.factorial(degree) / math.factorial(degree - order)  # D! / (D-r)!
    diff = difference_matrix(degree, order)  # [D+1-r, D+1]
    pts = np.einsum("jd,mdc->mjc", diff, control_points)  # [M, D+1-r, 3]
    return pts * (scale / durations**order)[:, None, None]


@dataclass
class BezierTrajectory:
    """Piecewise Bezier curve; segment k has control points control_points[k] and lasts durations[k]."""

    control_points: np.ndarray  # [M, D+1, 3] float64
    durations: np.ndarray  # [M] float64, > 0

    def __post_init__(self) -> None:
        cp = to_numpy(self.control_points)
        dur = to_numpy(self.durations).reshape(-1)
        if cp.ndim != 3 or cp.shape[1] < 2:
            raise InvalidInputError(
                f"Bezier control points must have shape [segments, degree+1 >= 2, dim], got {tuple(cp.shape)}."
            )
        if dur.shape[0] != cp.shape[0]:
            raise InvalidInputError(
                f"Bezier curve has {cp.shape[0]} segments but {dur.shape[0]} durations."
            )
        if not (np.all(np.isfinite(cp)) and np.all(np.isfinite(dur))):
            raise InvalidInputError("Bezier control points and durations must be finite (found NaN or inf).")
        if np.any(dur <= 0):
            raise InvalidInputError(f"Bezier segment durations must be positive, got {dur.tolist()}.")
        self.control_points = cp
        self.durations = dur
        self._starts = np.concatenate([[0.0], np.cumsum(dur)[:-1]])  # [M] start time of each segment
        self.info: dict = {}  # how the curve was made (solver status, timings); filled by the QP
        # derivative control points per order: the timing calls derivative() ~10x per shot. A curve is treated as
        # immutable; the cache is keyed on the arrays' identity so replacing them (not editing in place) is safe.
        self._dcp: dict = {}

    # ------------------------------------------------------------------ properties
    @property
    def num_segments(self) -> int:
        return self.control_points.shape[0]

    @property
    def degree(self) -> int:
        return self.control_points.shape[1] - 1

    @property
    def total_duration(self) -> float:
        return float(self.durations.sum())

    @property
    def segment_starts(self) -> np.ndarray:
        """Global start time of every segment, [M]."""
        return self._starts.copy()

    @property
    def start(self) -> np.ndarray:
        return self.control_points[0, 0].copy()

    @property
    def end(self) -> np.ndarray:
        return self.control_points[-1, -1].copy()

    # ------------------------------------------------------------------ evaluation
    def segment_of(self, t: Any) -> Tuple[np.ndarray, np.ndarray]:
        """Segment index and local parameter u in [0, 1] for global times t [T].

        Times outside [0, total_duration] are clamped to the ends (the curve is held there). At a join
        the later segment is chosen (u = 0), except at the very end (last segment, u = 1).
        """
        tt = np.clip(to_numpy(t).reshape(-1), 0.0, self.total_duration)  # [T]
        seg = np.searchsorted(self._starts, tt, side="right") - 1
        seg = np.clip(seg, 0, self.num_segments - 1)  # [T]
        u = np.clip((tt - self._starts[seg]) / self.durations[seg], 0.0, 1.0)  # [T]
        u[tt >= self.total_duration] = 1.0  # exact end point despite rounding of the cumulative sum
        return seg, u

    def evaluate(self, t: Any):
        """Positions at global times t [T] -> [T, 3]."""
        return self.derivative(t, 0)

    def derivative(self, t: Any, order: int = 1):
        """order-th time derivative at global times t [T] -> [T, 3] (order 0 is the position)."""
        if order < 0:
            raise InvalidInputError(f"derivative order must be >= 0, got {order}.")
        seg, u = self.segment_of(t)
        pts = self._derivative_points(order)  # [M, n+1, 3]
        basis = bernstein_basis(pts.shape[1] - 1, u)  # [T, n+1]
        out = np.einsum("tj,tjc->tc", basis, pts[seg])  # [T, 3]
        return same_kind_as(out, t)

    def speed(self, t: Any) -> np.ndarray:
        """|p'(t)| at global times t [T] -> [T] numpy, for the timing's arc-length integrals (many thousand times per
        shot). Horner's rule on the power-basis coefficients of p' (cached): about twice as fast as derivative(t, 1)
        and equal to its norm up to rounding (~1e-13 relative), but not exactly 0 where the curve rests."""
        seg, u = self.segment_of(t)
        c = self.speed_coefficients()[seg]  # [T, n+1, 3]: c_0 + c_1 u + ... + c_n u^n per point
        out = c[:, -1].copy()
        for j in range(c.shape[1] - 2, -1, -1):
            out *= u[:, None]
            out += c[:, j]
        return np.sqrt(np.einsum("tc,tc->t", out, out))

    def speed_coefficients(self) -> np.ndarray:
        """Power-basis coefficients [M, n+1, 3] of p' per segment (C-contiguous, cached like _derivative_points): what
        speed evaluates by Horner's rule, and native/timing.c with it."""
        hit = self._dcp.get("power1")
        if hit is None or hit[0] is not self.control_points or hit[1] is not self.durations:
            hit = (self.control_points, self.durations,
                   np.ascontiguousarray(power_coefficients(self._derivative_points(1))))
            self._dcp["power1"] = hit
        return hit[2]

    def _derivative_points(self, order: int) -> np.ndarray:
        """derivative_control_points(order) [M, D+1-order, 3], cached (see __post_init__)."""
        hit = self._dcp.get(order)
        if hit is None or hit[0] is not self.control_points or hit[1] is not self.durations:
            hit = (self.control_points, self.durations,
                   derivative_control_points(self.control_points, self.durations, order))
            self._dcp[order] = hit
        return hit[2]

    def sample(self, n: int, as_torch: bool = False):
        """n times evenly spaced over [0, total_duration] (ends included) and the positions there.

        Returns (times [n], positions [n, 3]); numpy unless as_torch.
        """
        if n < 2:
            raise InvalidInputError(f"sample needs n >= 2, got {n}.")
        times = np.linspace(0.0, self.total_duration, n)
        pos = self.derivative(times, 0)
        if as_torch:
            import torch

            return torch.from_numpy(times), torch.from_numpy(pos)
        return times, pos

    def to_dict(self) -> dict:
        return {
            "control_points": self.control_points.tolist(),
            "durations": self.durations.tolist(),
        }

    @classmethod
    def from_dict(cls, d: dict) -> "BezierTrajectory":
        return cls(np.asarray(d["control_points"], dtype=np.float64), np.asarray(d["durations"], dtype=np.float64))
