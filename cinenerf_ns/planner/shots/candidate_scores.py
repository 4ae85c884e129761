"""Scores of many candidate shots at once on a prepared planner (scoring.py's terms): one occlusion call and one
exact-clearance call for all shots instead of one each. The expensive per-frame inputs (score_parts) can be computed
where the shots are planned (a candidate worker process, on the CPU copy) and combined here (score_from_parts)."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, List, Optional

import numpy as np
import torch

from ..errors import InvalidInputError
from ..geometry import clearance_queries
from ..geometry.occlusion import sight_lines_blocked
from ..geometry.visibility import SubjectSamples, subject_visibility
from ..scene.planning_region import as_point
from .scoring import ScoreConfig, ShotScore, score_terms, scored_frames
from .shot import Shot

if TYPE_CHECKING:
    from .planner import Planner


def score_shots(
    planner: "Planner",
    shots: List[Shot],
    look_at: Any,
    config: Optional[ScoreConfig] = None,
    object_radius: float = 0.1,
    object_center: Optional[Any] = None,
    object_samples: Optional[Any] = None,
    exclude: Optional[torch.Tensor] = None,
    subject: Optional[SubjectSamples] = None,
) -> List[ShotScore]:
    """scoring.score_shot for several shots: one occlusion call and one exact-clearance call for all.

    Clearance terms use the scored frames (the same <= config.occlusion_frames frames per shot as the
    occlusion term); the shots' safety is established separately by the dense verification. ``subject``: samples
    of the look-at object's Gaussians; occlusion is then its visible fraction (scoring.py)."""
    cfg = config or ScoreConfig()
    cfg.validate()
    look = as_point(look_at, "look-at point")
    parts = score_parts(planner, shots, look, cfg, object_radius, object_samples, exclude, batch=True, subject=subject)
    return [score_from_parts(sh, part, look, cfg, object_radius, object_center) for sh, part in zip(shots, parts)]


def score_parts(planner: "Planner", shots: List[Shot], look: np.ndarray, cfg: ScoreConfig, object_radius: float,
                object_samples: Optional[Any], exclude: Optional[torch.Tensor], batch: bool,
                subject: Optional[SubjectSamples] = None, visibility_later: bool = False) -> List[tuple]:
    """The expensive per-frame inputs of each shot's score, one occlusion call and one exact-clearance call for all
    shots: [(tested frame indices [T'], occluded [T', S] bool, clearance [T'] exact up to the cap, visibility [T_v]
    or None, visibility frame indices [T_v] or None)]. With a ``subject`` the occlusion is its visible fraction on
    <= cfg.visibility_frames of the tested frames (one subject_visibility call for all shots; CPU, compiled) instead
    of sight lines.

    batch: on the scene's own device (a GPU when there is one: many frames x many Gaussians); False: on the request
    device (the CPU copy of a GPU scene), where the compiled sight-line and capped-distance searches apply
    (native/polytope.c): what the candidate worker processes use, since they cannot use CUDA. Both are exact: the
    clearances agree to ~1e-13, the occlusion flags except for sight lines that graze an ellipsoid within rounding.

    visibility_later: without a ``subject``, the occlusion is left out ((i, None, clr, None, None)): the caller adds
    the subject's visibility with with_visibility (a candidate worker leaves it to the parent, which holds the
    subject's classes and walks all candidates' frames in one threaded call instead of pickling the subject to every
    worker)."""
    if not (math.isfinite(object_radius) and object_radius >= 0):
        raise InvalidInputError(f"object_radius must be finite and >= 0, got {object_radius}.")
    prep = planner.ready()
    targets = look[None] if object_samples is None else np.asarray(object_samples, np.float64).reshape(-1, 3)
    idx = [scored_frames(sh.num_frames, cfg.occlusion_frames) for sh in shots]
    pos = np.concatenate([sh.positions[i] for sh, i in zip(shots, idx)])  # [sum T', 3]
    scene, index = planner.scene, prep.index
    if batch:
        scene = planner.batch_scene
        index = prep.batch_index if prep.batch_index is not None else prep.index
    if exclude is not None:
        exclude = torch.as_tensor(exclude, device=scene.device)
    clr = planner.clearance(pos, cap=cfg.clearance_cap, batch=batch)  # [sum T'] exact up to the cap
    if subject is not None or visibility_later:
        out, o = [], 0
        for i in idx:
            out.append((i, None, clr[o : o + len(i)], None, None))
            o += len(i)
        return out if subject is None else with_visibility(planner, shots, out, subject, cfg)
    free_grid = None if batch else clearance_queries.free_voxel_grid(planner.space)  # the CPU copy's compiled test
    occ = sight_lines_blocked(pos, targets, scene, index, exclude=exclude, stop_distance=object_radius,
                              free_grid=free_grid).cpu().numpy()  # [sum T', S]
    out, o = [], 0
    for i in idx:
        n = len(i)
        out.append((i, occ[o : o + n], clr[o : o + n], None, None))
        o += n
    return out


def with_visibility(planner: "Planner", shots: List[Shot], parts: List[tuple], subject: SubjectSamples,
                    cfg: ScoreConfig) -> List[tuple]:
    """score_parts entries made with visibility_later, completed with the subject's visible fraction on <=
    cfg.visibility_frames of each shot's tested frames (one subject_visibility call for all shots; each frame's
    fraction is independent of the others, so the numbers do not depend on how shots are grouped)."""
    idx = [p[0] for p in parts]
    vsub = [scored_frames(len(i), cfg.visibility_frames) for i in idx]  # positions among each shot's frames
    vpos = np.concatenate([sh.positions[i[v]] for sh, i, v in zip(shots, idx, vsub)])
    from .end_pose import visibility_volume

    vis = subject_visibility(visibility_volume(planner), vpos, subject)  # [sum T_v]
    out, ov = [], 0
    for (i, _, clr, _, _), v in zip(parts, vsub):
        nv = len(v)
        out.append((i, (vis[ov : ov + nv] < 0.5)[:, None], clr, vis[ov : ov + nv], i[v]))
        ov += nv
    return out


def score_from_parts(shot: Shot, part: tuple, look: np.ndarray, cfg: ScoreConfig, object_radius: float,
                     object_center: Optional[Any]) -> ShotScore:
    """A shot's ShotScore from its score_parts entry (scoring.score_terms; cheap)."""
    i, occ, clr, vis, vidx = part
    sc = score_terms(shot, look, occ, clr, object_radius, object_center, cfg, visibility=vis)
    sc.tested_frame_index = i
    sc.visibility, sc.visibility_frame_index = vis, vidx
    return sc
