"""What the panel says about shots and queries, in the user's words (pure functions; no viewer state).

Shots are the planner's ``Shot`` (planner/shots/shot.py): ``times`` [T] s, ``positions`` [T, 3], ``rotations``
[T, 3, 3], and the fields a request fills (clearance, safety, score, subject_view, goal_moved); read as fields.
"""
from __future__ import annotations

from typing import Any, Dict, List, Optional, Sequence

import numpy as np

from cinenerf_ns.planner.errors import PlanningError
from cinenerf_ns.planner.shots.shot import Shot

from .backend import to_numpy

SCORE_RULE = "lower score is better"


def check_shot(shot: Any, what: str = "shot") -> Shot:
    """``shot`` itself when it is a ``Shot`` the panel can play; PlanningError when it is something else, has fewer
    than two frames or holds NaN."""
    if not isinstance(shot, Shot):
        raise PlanningError(f"the planner returned a malformed {what}: a {type(shot).__name__}, not a "
                            f"cinenerf_ns.planner Shot")
    times = to_numpy(shot.times).reshape(-1)
    pos = to_numpy(shot.positions)
    rot = to_numpy(shot.rotations)
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
    return shot


def min_clearance(shot: Shot) -> Optional[float]:
    """Smallest clearance the shot reports: per-frame ``clearance`` [T], else the planner's dense verification
    (``safety['min_exact_clearance']``, None when every sample was proven free)."""
    if shot.clearance is not None:
        c = to_numpy(shot.clearance).reshape(-1)
        return float(c.min()) if c.size else None
    m = None if shot.safety is None else shot.safety.get("min_exact_clearance")
    return None if m is None else float(m)


def shot_score(shot: Shot) -> Optional[float]:
    """The candidate's ranking score when the planner gives one (``shot.score``), else None."""
    return None if shot.score is None else float(shot.score)


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


def shot_summary(shot: Shot) -> str:
    times = to_numpy(shot.times)
    pos = to_numpy(shot.positions)
    length = float(np.linalg.norm(np.diff(pos, axis=0), axis=1).sum())
    c = min_clearance(shot)
    cl = "n/a" if c is None else f"{c:.3g}"
    score = shot_score(shot)
    return (f"{times[-1] - times[0]:.1f} s, {length:.2f} units long, min clearance {cl}"
            f"{'' if score is None else f', score {score:.3g}'}{subject_view_text(shot)}")


def subject_view_text(shot: Shot) -> str:
    """', the look-at object 96% visible at the end (seen in 100% of frames), size 0.45 (medium 0.35-0.6)' from the
    shot's subject_view (PreparedPlanner), else ''."""
    v = shot.subject_view
    if not v:
        return ""
    out = ""
    if v.get("visible_last") is not None:
        out += f", the look-at object {100 * v['visible_last']:.0f}% visible at the end"
        if v.get("frames_visible_half") is not None:
            out += f" (at least half visible in {100 * v['frames_visible_half']:.0f}% of frames)"
    lo, _, hi = v["framing_band"]
    out += f", its size {v['size_last']:.2f} ({v['framing']} {lo:g}-{hi:g})"
    return out


def goal_note(shot: Shot) -> str:
    """' Note: the go-to point moved ...' when the planner ended the shot away from the go-to target (planner
    explain_goal: from where to where and why), else ''."""
    mv = shot.goal_moved
    if not mv:
        return ""
    f = lambda p: "(" + ", ".join(f"{v:.3f}" for v in p) + ")"  # noqa: E731
    return (f" Note: the go-to point moved {mv['distance']:.3f} units, from {f(mv['from'])} to {f(mv['to'])}: "
            f"{mv['why']}.")


def candidate_label(i: int, shot: Shot) -> str:
    """Dropdown entry: ``'<n>: <duration> s, clearance <min>[, score <s>]'`` (the panel parses the number)."""
    times = to_numpy(shot.times)
    c = min_clearance(shot)
    score = shot_score(shot)
    return (f"{i + 1}: {times[-1] - times[0]:.1f} s, clearance {'n/a' if c is None else f'{c:.3g}'}"
            f"{'' if score is None else f', score {score:.3g}'}")


def sort_by_score(shots: Sequence[Shot]) -> List[Shot]:
    """Candidates best first: ascending ``score`` (lower is better); shots without a score keep their order after
    the scored ones (a stable sort)."""
    scored = [s for s in shots if shot_score(s) is not None]
    return sorted(scored, key=shot_score) + [s for s in shots if shot_score(s) is None]


def plan_summary(n_shots: int) -> str:
    """'Planned 3 shots' (the headline of a finished Plan; its time goes to the details fold)."""
    return f"Planned {n_shots} shot{'s' if n_shots != 1 else ''}"
