"""Resolved go-to / look-at targets -> what the planner plans to: the look-at subject (its Gaussians when the text
named an object) and, for an object go-to, the chosen end poses (planner/shots/end_pose.py). Shared by
``cinesplat-plan`` and both viewers, so they choose the same way."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Dict, Optional

import numpy as np

from cinenerf_ns.planner.geometry.visibility import SubjectSamples
from cinenerf_ns.planner.shots.end_pose import EndPoseChoice, EndPoseConfig, choose_end_poses, visibility_volume
from cinenerf_ns.planner.shots.framing import FramingConfig, subject_size
from cinenerf_ns.planner.shots.target_object import TargetObject, scene_members, subject_samples


@dataclass
class ShotTargets:
    """The look-at subject, its visibility samples, and the end poses (None: plan to the go-to point as given)."""

    subject: TargetObject
    samples: SubjectSamples
    choice: Optional[EndPoseChoice]
    good_view: bool  # go-to and look-at name the same object: "a good view of X"
    framing: FramingConfig
    why_no_end_pose: Optional[str] = None  # without a choice: why the shot ends at the go-to point (said to the user)

    @property
    def ends_at_poses(self) -> bool:
        """Shots were planned to end poses (each shot's goal_target is its pose), not to the go-to point."""
        return self.choice is not None and bool(self.choice.poses)

    def goals(self, goal: np.ndarray) -> np.ndarray:
        """The go-to points to plan to: the end poses [P, 3], or ``goal`` [3] itself as [1, 3]."""
        if self.choice is not None and self.choice.poses:
            return np.stack([p.point for p in self.choice.poses])
        return np.asarray(goal, np.float64).reshape(1, 3)

    def pose_of(self, candidate: int) -> Optional[Dict[str, Any]]:
        """The end pose (dict) a candidate (its start's index) planned to, with why it was chosen; None without."""
        if self.choice is None or not self.choice.poses:
            return None
        k = candidate % len(self.choice.poses)
        return {**self.choice.poses[k].to_dict(), "why": self.choice.why(k), "rank_among_end_poses": k + 1}

    def note(self) -> Optional[str]:
        """What the user should know about the end pose: chosen how, or why there is none."""
        if self.choice is None:
            return self.why_no_end_pose
        what = "a good view of the look-at object" if self.good_view else "the go-to object"
        if not self.choice.poses:
            return f"no end pose around {what} could be used ({self.choice.why()}); planned to the go-to point instead"
        return self.choice.why()

    def view_report(self, positions_last: np.ndarray, look_at: np.ndarray, up, score_terms: Optional[dict]) -> dict:
        """What the user sees at the end of a shot: the subject's visible fraction (last frame and the share of frames
        with at least half of it seen, from the score when there is one) and its size in the last frame."""
        size, whole = subject_size(np.asarray(positions_last, np.float64).reshape(1, 3), np.asarray(look_at),
                                   np.asarray(up, np.float64) / np.linalg.norm(up), self.subject.outline_points(),
                                   self.subject.pad, self.framing)
        t = score_terms or {}
        return {"visible_last": t.get("visible_last"), "frames_visible_half": t.get("frames_visible_half"),
                "size_last": float(size[0]), "whole_in_frame": bool(whole[0]), "framing": self.framing.framing,
                "framing_band": list(self.framing.band)}


def same_object(gm: Dict[str, Any], lm: Dict[str, Any]) -> bool:
    """The go-to and look-at texts name the same object (the same label, or the same selected Gaussians)."""
    if "mask" not in gm or "mask" not in lm:
        return False
    if gm.get("label") is not None and gm.get("label") == lm.get("label"):
        return True
    return bool(np.array_equal(gm["mask"], lm["mask"]))


def shot_targets(planner, gm: Dict[str, Any], lm: Dict[str, Any], framing: FramingConfig, component: int,
                 k: int = 1, object_radius: float = 0.1, end_pose: bool = True,
                 facing_from: Optional[np.ndarray] = None) -> ShotTargets:
    """The targets of a request from its resolved go-to ``gm`` and look-at ``lm`` (scenes.resolve_match): end poses
    when the go-to is an object (its mask) and ``end_pose``; ``component``: the free component the shot starts in;
    ``k``: end poses wanted (distinct ones for ranked candidates); ``facing_from`` [3]: where views of "a good view of
    X" are preferred from (the start region's centre)."""
    scene = planner.scene
    look = np.asarray(lm["point"], np.float64)
    members = scene_members(scene, lm.get("mask"))
    if members is not None and members.size:
        vol = visibility_volume(planner)
        subject = TargetObject.of_members(vol, members, look, lm.get("text", "look-at"))
        samples = subject_samples(vol, subject.members, EndPoseConfig.samples)  # end poses' and scores'
    else:
        subject = TargetObject.point(look, object_radius, lm.get("text", "look-at"))
        samples = SubjectSamples.of_point(look)
    good_view = same_object(gm, lm)
    choice = None
    g_members = scene_members(scene, gm.get("mask"))
    if end_pose and g_members is not None and g_members.size:
        goto = None if good_view else TargetObject.of_members(visibility_volume(planner), g_members, gm["point"],
                                                              gm.get("text", "go-to"))
        facing = None if facing_from is None else np.asarray(facing_from, np.float64) - subject.centre
        choice = choose_end_poses(planner, subject, goto, framing, component, k=k, facing=facing, samples=samples)
    why = None
    if choice is None:  # the framing is then reported, not aimed for: say so rather than ignore it silently
        why = (f"the go-to is a point, so the shot ends there; the {framing.framing} framing is reported, not aimed for"
               if end_pose else f"end poses are off, so the shot ends at the go-to point; the {framing.framing} "
               "framing is reported, not aimed for")
    return ShotTargets(subject, samples, choice, good_view, framing, why)


def start_region_centre(planner) -> np.ndarray:
    """The centre of the start region (or of the planning region without one)."""
    reg = planner.config.start_region
    lo, hi = (np.asarray(v, np.float64) for v in reg) if reg is not None else planner.region()
    return 0.5 * (lo + hi)


def end_pose_count(candidates: int) -> int:
    """Distinct end poses for a request of ``candidates`` (each candidate ends at one, round robin)."""
    return max(1, min(int(candidates), 8))

