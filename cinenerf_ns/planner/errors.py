"""Errors the planner raises. Each message is written for the user and shown verbatim
(CLI, viewer status line), so it says what was wrong and what to try."""


class PlanningError(Exception):
    """Base class of every planner error."""


class InvalidInputError(PlanningError, ValueError):
    """Input that cannot be planned with: NaN, wrong shape, empty text, unknown file."""


class EmptySceneError(PlanningError):
    """No obstacle is left after filtering (opacity floor, degenerate Gaussians)."""


class StartInCollisionError(PlanningError):
    """The requested start puts the camera body inside the scene."""


class GoalUnreachableError(PlanningError):
    """No collision-free path joins the start to the goal."""


class UnsafeTrajectoryError(PlanningError):
    """Verification found a trajectory sample with negative exact clearance."""


class CorridorInfeasibleError(GoalUnreachableError):
    """No trajectory of the requested smoothness fits inside the corridor."""


class TrajectorySolverError(PlanningError):
    """The QP solver failed for numerical reasons or returned a point outside the corridor."""
