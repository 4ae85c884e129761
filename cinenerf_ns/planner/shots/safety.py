"""Safety report of a shot: exact clearance along the densely sampled path (the paper's Fig. 5).

`clearance_fn(points [P,3]) -> [P]` is the distance from each camera centre to the closest obstacle
minus the camera radius (planner.distance.clearance gives it exactly for a splat scene); negative
means the camera body touches an obstacle.

Dense sampling: the path is cut into pieces no longer than `max_spacing` (scene units). For a Shot with
its trajectory the samples are exact curve points; for bare positions the path is the polyline through
them. Because an exact distance function is 1-Lipschitz, between two samples p_i, p_{i+1} joined by a
path piece of length l_i the clearance is at least (c_i + c_{i+1} - l_i) / 2; the minimum of that over
all pieces is reported as `lipschitz_lower_bound`, a certificate for the continuous path (valid only if
clearance_fn is an exact distance, not for conservative approximations).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Dict, Optional, Sequence, Union

import numpy as np

from ..atomic import atomic_open
from ..errors import InvalidInputError
from ..geometry import clearance_queries
from ..geometry.ranges import group_ranks
from ..trajectory.bezier import to_numpy
from ..trajectory.timing import native_bezier
from .shot import Shot

if TYPE_CHECKING:
    from ..space import PlanningSpace

DEFAULT_THRESHOLDS = (0.0, 0.01, 0.03, 0.05)
DEFAULT_CLEARANCE_CAP = 0.5
"""Reports search clearance only up to this (scene units); a sample at the cap is 'at least the cap'. Far from
everything (open background, a path outside a capture) an uncapped search is unbounded work and no more useful."""


def _speed_bounds(traj) -> np.ndarray:
    """[M] upper bound of |p'(t)| on each Bezier segment: the derivative curve lies in the convex hull of
    its control points D/d_k (P_{i+1} - P_i), so its norm is at most the largest of theirs."""
    hodo = traj.degree * np.diff(traj.control_points, axis=1) / traj.durations[:, None, None]  # [M, D, 3]
    return np.linalg.norm(hodo, axis=2).max(1)


def _piece_speed_bound(traj, vb: np.ndarray, tau0: np.ndarray, tau1: np.ndarray) -> np.ndarray:
    """Speed bound on each curve-time piece [tau0, tau1]: max of vb over the segments it touches."""
    lo, _ = traj.segment_of(np.minimum(tau0, tau1))
    hi, _ = traj.segment_of(np.maximum(tau0, tau1))
    out = np.maximum(vb[lo], vb[hi])
    for j in np.flatnonzero(hi - lo > 1):  # pieces spanning whole segments (rare)
        out[j] = vb[lo[j] : hi[j] + 1].max()
    return out


def _dense_curve_native(counts_fn, traj, f_times: np.ndarray, f_pos: np.ndarray, tau: np.ndarray,
                        max_spacing: float):
    """dense_samples' curve branch by native/timing.c: cn_dense_counts (the speed bounds and the pieces per frame
    interval, whose sum sizes the outputs), then cn_dense_fill (the samples, their curve points and piece lengths)."""
    from ..native import dense_fill_c

    curve, _keep = native_bezier(traj)  # curve[1]: the number of segments M
    f_pos, f_times, tau = (np.ascontiguousarray(a, dtype=np.float64) for a in (f_pos, f_times, tau))
    T = len(tau)
    vb, sub = np.empty(curve[1]), np.empty(T - 1, dtype=np.int64)
    S = counts_fn(*curve, f_pos.ctypes.data, tau.ctypes.data, T, float(max_spacing), vb.ctypes.data, sub.ctypes.data)
    if S < 0:
        raise MemoryError("dense_samples: more samples than int64 counts (max_spacing too small)")
    t, pos, lengths = np.empty(S + 1), np.empty((S + 1, 3)), np.empty(S)
    if dense_fill_c()(*curve, vb.ctypes.data, f_times.ctypes.data, tau.ctypes.data, T, sub.ctypes.data,
                      t.ctypes.data, pos.ctypes.data, lengths.ctypes.data) < 0:
        raise MemoryError("the compiled dense sampling ran out of memory")
    return t, pos, lengths


def dense_samples(shot_or_positions: Any, times: Optional[Any], max_spacing: float, backend: str = "auto"):
    """(times [S], positions [S,3], piece_lengths [S-1]) densely covering the path.

    backend, for a Shot with its trajectory and (finite) curve times: "auto" (native/timing.c's cn_dense_counts and
    cn_dense_fill, the same arithmetic, when they load), "native" or "python" (the numpy reference below); a
    polyline always takes the numpy path.
    """
    from ..native import choose, dense_counts_c

    if isinstance(shot_or_positions, Shot):
        shot = shot_or_positions
        f_times, f_pos = shot.times, shot.positions
        traj, tau = shot.trajectory, shot.curve_times
    else:
        f_pos = to_numpy(shot_or_positions)
        if f_pos.ndim != 2 or f_pos.shape[1] != 3 or len(f_pos) == 0:
            raise InvalidInputError(f"positions must have shape [T, 3], got {tuple(f_pos.shape)}.")
        f_times = np.arange(len(f_pos), dtype=np.float64) if times is None else to_numpy(times).reshape(-1)
        if f_times.shape != (len(f_pos),):
            raise InvalidInputError(f"times must have shape [{len(f_pos)}], got {f_times.shape}.")
        traj, tau = None, None
    if not (np.all(np.isfinite(f_pos)) and np.all(np.isfinite(f_times))):
        raise InvalidInputError("path positions/times contain NaN or inf.")
    curve = traj is not None and tau is not None
    fn = choose(backend, dense_counts_c, "timing", "dense sampling", applies=curve and bool(np.all(np.isfinite(tau))),
                needs="a Shot with its trajectory and finite curve times")
    if len(f_pos) == 1:
        return f_times.copy(), f_pos.copy(), np.zeros(0)
    if fn is not None:
        return _dense_curve_native(fn, traj, f_times, f_pos, tau, max_spacing)
    chord = np.linalg.norm(np.diff(f_pos, axis=0), axis=1)  # [T-1]
    if curve:
        vb = _speed_bounds(traj)  # [M] rigorous speed bound per segment
        approx_len = np.maximum(chord, _piece_speed_bound(traj, vb, tau[:-1], tau[1:]) * np.abs(np.diff(tau)))
    else:
        approx_len = chord
    sub = np.maximum(1, np.ceil(approx_len / max_spacing).astype(np.int64))  # pieces per interval
    idx, k = group_ranks(sub)  # [S-1] the interval of each piece and its rank there
    frac = k / sub[idx]  # [S-1] k / n within its interval
    t = np.concatenate([f_times[idx] + frac * np.diff(f_times)[idx], f_times[-1:]])
    if curve:
        ctau = np.concatenate([tau[idx] + frac * np.diff(tau)[idx], tau[-1:]])
        pos = traj.evaluate(ctau)
        # upper bound of each piece's arc length: speed bound x curve-time span
        lengths = _piece_speed_bound(traj, vb, ctau[:-1], ctau[1:]) * np.abs(np.diff(ctau))
        lengths = np.maximum(lengths, np.linalg.norm(np.diff(pos, axis=0), axis=1))
    else:
        pos = np.concatenate([f_pos[idx] + frac[:, None] * np.diff(f_pos, axis=0)[idx], f_pos[-1:]])
        lengths = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    return t, pos, lengths


def safety_report(
    shot_or_positions: Union[Shot, Any],
    clearance_fn: Callable[[np.ndarray], Any],
    times: Optional[Any] = None,
    max_spacing: float = 0.005,
    thresholds: Sequence[float] = DEFAULT_THRESHOLDS,
    label: str = "",
    clearance_cap: Optional[float] = None,
) -> Dict[str, Any]:
    """Clearance statistics along the densely sampled path; a JSON-serialisable dict.

    shot_or_positions: a Shot (its trajectory is sampled when present) or positions [T,3] (a polyline,
    with `times` [T], default 0..T-1). Keys: label, num_samples, max_sample_spacing, min/mean/max
    clearance, argmin_time_s, argmin_position, fraction_below {threshold: fraction of samples below},
    lipschitz_lower_bound, safe (min clearance > 0), times, clearance (the samples, for plotting).
    ``clearance_cap``: the cap clearance_fn applies (its values are min(clearance, cap), still 1-Lipschitz, so the
    bound above stays valid); the report states it and how many samples are at it ("at least the cap").
    """
    if not (max_spacing > 0 and math.isfinite(max_spacing)):
        raise InvalidInputError(f"max_spacing must be positive, got {max_spacing}.")
    t, pos, lengths = dense_samples(shot_or_positions, times, max_spacing)
    c = to_numpy(clearance_fn(pos)).reshape(-1)
    if c.shape != (len(pos),):
        raise InvalidInputError(f"clearance_fn returned shape {c.shape} for {len(pos)} points.")
    if not np.all(np.isfinite(c)):
        raise InvalidInputError("clearance_fn returned NaN or inf.")
    i = int(np.argmin(c))
    bound = float(np.min((c[:-1] + c[1:] - lengths) / 2)) if len(lengths) else float(c[0])
    capped = {} if clearance_cap is None else {
        "clearance_cap": float(clearance_cap),
        "samples_at_cap": int(np.sum(c >= float(clearance_cap) * (1 - 1e-12))),
        "cap_note": "a clearance equal to clearance_cap means 'at least the cap' (not searched further)",
    }
    return {**capped,
        "label": label,
        "num_samples": int(len(c)),
        "max_sample_spacing": float(lengths.max()) if len(lengths) else 0.0,
        "min_clearance": float(c[i]),
        "mean_clearance": float(c.mean()),
        "max_clearance": float(c.max()),
        "argmin_time_s": float(t[i]),
        "argmin_position": pos[i].tolist(),
        "fraction_below": {f"{th:g}": float(np.mean(c < th)) for th in thresholds},
        "lipschitz_lower_bound": min(bound, float(c[i])),
        "safe": bool(c[i] > 0),
        "times": t.tolist(),
        "clearance": c.tolist(),
    }


# ---------------------------------------------------------------------------------------------- plots
def _figure(figsize):
    # Figure + Agg canvas directly: no pyplot global state, no display needed, safe in threads
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=100)
    FigureCanvasAgg(fig)
    return fig


def _save_png(fig, png_path: Union[str, Path]) -> Path:
    """Atomic PNG write (atomic.atomic_open)."""
    with atomic_open(png_path, binary=True) as f:
        fig.savefig(f, format="png", bbox_inches="tight")
    return Path(png_path)


def plot_clearance(
    reports: Union[Dict[str, Any], Sequence[Dict[str, Any]]],
    png_path: Union[str, Path],
    title: str = "Distance to the closest obstacle",
) -> Path:
    """Clearance over time, one line per report (candidate), red line at 0 (paper Fig. 5)."""
    if isinstance(reports, dict):
        reports = [reports]
    if len(reports) == 0:
        raise InvalidInputError("plot_clearance needs at least one report.")
    fig = _figure((7, 3.5))
    ax = fig.add_subplot(1, 1, 1)
    for k, rep in enumerate(reports):
        label = rep.get("label") or f"candidate {k}"
        ax.plot(rep["times"], rep["clearance"], lw=1.5, label=f"{label} (min {rep['min_clearance']:.3f})")
    ax.axhline(0.0, color="red", lw=1.5, label="collision")
    cap = reports[0].get("clearance_cap")
    if cap is not None and any(r.get("samples_at_cap") for r in reports):
        ax.axhline(cap, color="grey", ls="--", lw=1, label=f"cap: at least {cap:g}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("clearance [scene units]")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    return _save_png(fig, png_path)


def _ellipses_xy(obstacles: Any, max_count: int):
    """(centres [N,2], widths [N], heights [N], angles_deg [N]) of the xy shadows of ellipsoids."""
    means = to_numpy(obstacles.means)
    rot = to_numpy(obstacles.rotations)
    radii = to_numpy(obstacles.radii)
    if len(means) > max_count:  # keep the largest ones: they dominate the picture
        keep = np.argsort(-radii.max(1))[:max_count]
        means, rot, radii = means[keep], rot[keep], radii[keep]
    cov = np.einsum("nij,nj,nkj->nik", rot, radii**2, rot)[:, :2, :2]  # projected covariance [N,2,2]
    evals, evecs = np.linalg.eigh(cov)
    widths = 2 * np.sqrt(np.clip(evals[:, 1], 0, None))
    heights = 2 * np.sqrt(np.clip(evals[:, 0], 0, None))
    angles = np.degrees(np.arctan2(evecs[:, 1, 1], evecs[:, 0, 1]))
    return means[:, :2], widths, heights, angles


def _point_density_rgba(xy: np.ndarray, bins: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Grey RGBA image of how many points fall in each square bin (the longer side cut in ``bins``, from the points'
    lower corner); empty bins are transparent, the others more opaque the more points they hold (log scale).
    xy [N, 2] -> (image [H, W, 4], lower corner [2], bin size)."""
    lo, hi = xy.min(0), xy.max(0)
    step = max(float((hi - lo).max()) / bins, 1e-9)
    nx, ny = (np.floor((hi - lo) / step).astype(int) + 1).tolist()
    ij = np.minimum(np.floor((xy - lo) / step).astype(int), [nx - 1, ny - 1])  # [N, 2] each point's bin (x, y)
    counts = np.bincount(ij[:, 1] * nx + ij[:, 0], minlength=ny * nx).reshape(ny, nx)  # [H, W]
    rgba = np.zeros((ny, nx, 4))
    rgba[..., :3] = 0.3
    rgba[..., 3] = np.where(counts > 0, 0.35 + 0.6 * np.log1p(counts) / np.log1p(counts.max()), 0.0)
    return rgba, lo, step


def _draw_point_density(ax, xy: np.ndarray, bins: int = 300) -> None:
    """Obstacle points as a density image, not one marker each: a marker per point costs the PNG about 1 s per
    100k points (a splat's Gaussians near the paths' heights are 10^4-10^5), an image the same at any count."""
    if len(xy) == 0:
        return
    rgba, lo, step = _point_density_rgba(xy, bins)
    extent = (lo[0], lo[0] + rgba.shape[1] * step, lo[1], lo[1] + rgba.shape[0] * step)
    ax.imshow(rgba, extent=extent, origin="lower", interpolation="nearest", zorder=0)
    ax.plot([], [], "s", color="0.3", alpha=0.6, ms=5, label="obstacles (density of points)")


def plot_paths_topdown(
    paths: Sequence[Any],
    png_path: Union[str, Path],
    obstacles: Any = None,
    targets: Optional[Dict[str, Any]] = None,
    labels: Optional[Sequence[str]] = None,
    max_obstacles: int = 5000,
    title: str = "Camera paths (top view, x-y)",
) -> Path:
    """Top view (x-y) of camera paths.

    paths: Shots or positions [T,3]. obstacles: None, points [N,3] (drawn as a density image) or an object with
    means [N,3], rotations [N,3,3], radii [N,3] (e.g. EllipsoidScene; drawn as projected ellipses, the
    largest max_obstacles). targets: {"look at": [3], "go to": [3], ...} drawn as stars.
    """
    if len(paths) == 0:
        raise InvalidInputError("plot_paths_topdown needs at least one path.")
    from matplotlib.collections import EllipseCollection

    fig = _figure((6, 6))
    ax = fig.add_subplot(1, 1, 1)
    if obstacles is not None:
        if all(hasattr(obstacles, a) for a in ("means", "rotations", "radii")):
            xy, w, h, ang = _ellipses_xy(obstacles, max_obstacles)
            ax.add_collection(
                EllipseCollection(
                    w, h, ang, units="xy", offsets=xy, offset_transform=ax.transData,
                    facecolors=(0.3, 0.3, 0.3, 0.25), edgecolors=(0.2, 0.2, 0.2, 0.5), linewidths=0.3,
                )
            )
            ax.update_datalim(np.concatenate([xy - np.maximum(w, h)[:, None] / 2, xy + np.maximum(w, h)[:, None] / 2]))
        else:
            _draw_point_density(ax, to_numpy(obstacles).reshape(-1, 3)[:, :2])
    for k, p in enumerate(paths):
        pos = p.positions if isinstance(p, Shot) else to_numpy(p)
        label = labels[k] if labels is not None and k < len(labels) else f"path {k}"
        (line,) = ax.plot(pos[:, 0], pos[:, 1], lw=1.8, label=label)
        ax.plot(pos[0, 0], pos[0, 1], "o", color=line.get_color(), ms=6)
        ax.plot(pos[-1, 0], pos[-1, 1], "s", color=line.get_color(), ms=6)
    for name, pt in (targets or {}).items():
        pt = to_numpy(pt).reshape(-1)
        ax.plot(pt[0], pt[1], "*", ms=14, mec="k", label=name)
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(title)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    return _save_png(fig, png_path)


def verify_shot(
    shot: Shot,
    points_free: Callable[[np.ndarray], Any],
    exact_clearance: Callable[[np.ndarray], Any],
    max_spacing: float = 0.005,
) -> Dict[str, Any]:
    """Safety verification of a shot's curve, sampled densely (spacing <= max_spacing).

    Every sample is first checked with the conservative test ``points_free`` (never "free" when the
    camera ball touches the scene). Samples it cannot prove free are measured with the exact
    clearance; the shot is safe iff none of those is negative. Cheap in the common case (corridor
    curves are safe by construction) and still exact where it matters. Returns a JSON-able dict
    (num_samples, num_inconclusive, min_exact_clearance (None when every sample was proven free), safe).
    """
    t, pos, _ = dense_samples(shot, None, max_spacing)
    ok = np.asarray(to_numpy(points_free(pos)), dtype=bool).reshape(-1)
    bad = np.flatnonzero(~ok)
    min_exact = None
    if len(bad):
        c = to_numpy(exact_clearance(pos[bad])).reshape(-1)
        min_exact = float(c.min())
    return {
        "num_samples": int(len(pos)),
        "max_sample_spacing": float(max_spacing),
        "num_inconclusive": int(len(bad)),
        "min_exact_clearance": min_exact,
        "safe": bool(min_exact is None or min_exact >= 0.0),
        "method": "conservative test on every sample (the points_free given: the planner's is the occupancy grid, then "
                  "Cor.1), exact distance where inconclusive",
    }


def clearance_report(space: "PlanningSpace", shot: Shot, max_spacing: float = 0.02, label: str = "",
                     cap: float = DEFAULT_CLEARANCE_CAP) -> dict:
    """safety_report of a shot with the planning space's exact clearance (clearance_queries.clearance on the scene's
    own device) capped at ``cap`` (bounded work on any scene: far from everything a sample is 'at least the cap')."""
    return safety_report(shot, lambda p: clearance_queries.clearance(space, p, cap=cap, batch=True),
                         max_spacing=max_spacing, label=label, clearance_cap=cap)
