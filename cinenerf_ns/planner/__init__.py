"""The camera planner (paper Sec. IV): a splat's Gaussians as ellipsoid obstacles in, verified collision-free shots out.
Imports nothing of nerfstudio, gsplat or viser (tests/test_layering.py).

The public names below load their module on first use (PEP 562), so ``import cinenerf_ns.planner.errors`` stays light.
The flow, by module (docs/ARCHITECTURE.md draws it):
  scene/ellipsoids.py (EllipsoidScene) -> shots/planner.py (Planner: the user-facing API over space.py's PlanningSpace,
  which prepare() builds once and every module below shots/ takes: scene/planning_region.py, search/starts.py,
  geometry/clearance_queries.py, corridor/corridor_options.py; shots/plan_request.py) -> shots/stages.py (one leg,
  the only place a leg is planned: search/reach.py goal, search/coarse_path.py + search/astar.py voxel path,
  search/shortcut.py, corridor/safe_corridor.py, trajectory/qp.py QP, shots/shot.py timing + orientation,
  shots/safety.py verification)
  -> shots/candidates.py (ranked shots, shots/candidate_scores.py) / shots/multistop.py (the stages chained over
  stops) -> shots/camera_path.py (nerfstudio camera path).
"""
from __future__ import annotations

from .lazy_exports import lazy_exports

_WHERE = {
    "EllipsoidScene": "scene.ellipsoids", "SceneConfig": "scene.scene_config",
    "Planner": "shots.planner", "PlannerConfig": "config", "PreparedScene": "space", "PlanningSpace": "space",
    "MAX_CANDIDATES": "config",
    "plan_leg": "shots.stages", "ReachableGoal": "search.reach", "reachable_goal": "search.reach",
    "plan_candidates": "shots.candidates", "RankedShot": "shots.candidates", "score_shots": "shots.candidate_scores",
    "plan_multistop": "shots.multistop", "MultiStopShot": "shots.multistop",
    "Shot": "shots.shot", "TimingConfig": "trajectory.timing", "TrajectoryConfig": "trajectory.qp_config",
    "DynamicLimits": "trajectory.dynamics",
    "retime_shot": "shots.shot", "ScoreConfig": "shots.score_config",
    "safety_report": "shots.safety", "verify_shot": "shots.safety", "plot_clearance": "shots.safety",
    "plot_paths_topdown": "shots.safety",
    "shot_to_camera_path": "shots.camera_path", "write_camera_path": "shots.camera_path",
    "read_camera_path": "shots.camera_path",
    "clearance": "geometry.distance", "build_corridor": "corridor.safe_corridor", "Corridor": "corridor.safe_corridor",
    "atomic_write": "atomic", "SplatParams": "scene.splat_params",
    "PlanningError": "errors", "InvalidInputError": "errors", "GoalUnreachableError": "errors",
    "StartInCollisionError": "errors", "UnsafeTrajectoryError": "errors", "EmptySceneError": "errors",
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _WHERE)
