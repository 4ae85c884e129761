"""The corridor QP's settings (TrajectoryConfig: the curve's shape, its cost and the solver) and their checks."""
from __future__ import annotations

from dataclasses import dataclass

from ..errors import InvalidInputError

SOLVERS = ("active_set", "clarabel", "osqp")


@dataclass
class TrajectoryConfig:
    """Shape, cost and solver of the corridor QP."""

    degree: int = 5
    """Bezier degree D of every segment (D+1 control points each)."""
    continuity: int = 2
    """Continuity order at joins: position and its first `continuity` time derivatives match (2 = C2)."""
    smoothness_order: int = 3
    """Which time derivative's squared integral is minimised: 2 = acceleration, 3 = jerk."""
    smoothness_weight: float = 1.0
    """Weight of the smoothness integral in the objective."""
    length_weight: float = 1e-2
    """Weight of the squared control-polygon length ("minimum length") in the objective."""
    nominal_speed: float = 0.5
    """Scene units per second used to turn waypoint distances into segment durations."""
    min_segment_duration: float = 0.05
    """Lower bound of a segment's duration in seconds (keeps very short segments well conditioned)."""
    rest_at_ends: int = 1
    """Number of time derivatives forced to zero at start and goal (0: none, 1: velocity, 2: + acceleration)."""
    solver: str = "active_set"
    """QP solver: "active_set" (the exact optimum: equalities eliminated, then a dual active-set method; Clarabel
    where it does not apply or fails numerically, said in the trajectory's info), "clarabel" (interior point) or "osqp"
    (ADMM with polishing)."""
    margin: float = 1e-5
    """Polytope offsets are shrunk by this distance (scene units) so solver tolerance cannot leave a point outside."""
    osqp_margin: float = 1e-4
    """The margin used with OSQP instead of `margin`: ADMM meets constraints only to ~eps * |b|, and its
    polishing step often fails on this cost, so it needs more room."""

    def effective_margin(self) -> float:
        return self.osqp_margin if self.solver == "osqp" else self.margin
    max_iter: int = 200
    """Clarabel iteration limit (OSQP gets 100x this many ADMM iterations)."""
    tolerance: float = 1e-8
    """Clarabel feasibility/optimality tolerance (tol_feas, tol_gap_abs, tol_gap_rel)."""
    active_set_tolerance: float = 1e-10
    """active_set: how far (scene units, times 1 + the waypoints' largest coordinate) a control point may stay outside
    a face shrunk by `margin` when the solve ends; it must stay below `margin`."""
    iterative_refinement: bool = False
    """Clarabel's iterative refinement of each KKT solve; off: about half the solve time, same optimum (control points
    are still checked against their polytopes). The retry after a stalled solve turns it on."""
    osqp_tolerance: float = 1e-6
    """OSQP eps_abs/eps_rel. ADMM converges slowly on this ill-conditioned cost (1/d^5 terms), so it gets
    a looser tolerance than Clarabel; polishing usually sharpens it and the margin covers the rest."""
    working_set: bool = True
    """Clarabel: solve with the faces near the path first, adding violated ones until none is (working_set.py): the
    same optimum with fewer constraints. OSQP always gets all faces (ADMM's answer moved ~1e-3 with the face set)."""

    def validate(self) -> None:
        if self.degree < 1:
            raise InvalidInputError(f"degree (of the Bezier segments) must be >= 1, got {self.degree}.")
        if not 0 <= self.continuity < self.degree:
            raise InvalidInputError(
                f"continuity order must be in [0, degree-1] = [0, {self.degree - 1}], got {self.continuity}."
            )
        if not 1 <= self.smoothness_order <= self.degree:
            raise InvalidInputError(
                f"smoothness_order must be in [1, degree] = [1, {self.degree}], got {self.smoothness_order}."
            )
        if self.rest_at_ends < 0 or 2 * (self.rest_at_ends + 1) > self.degree + 1:
            raise InvalidInputError(
                f"rest_at_ends={self.rest_at_ends} pins {self.rest_at_ends + 1} control points at each end, "
                f"more than a degree-{self.degree} segment has; use a higher degree or fewer rest derivatives."
            )
        if self.smoothness_weight < 0 or self.length_weight < 0 or self.smoothness_weight + self.length_weight == 0:
            raise InvalidInputError(f"smoothness_weight and length_weight must be >= 0 and not both zero, got "
                                    f"{self.smoothness_weight:g} and {self.length_weight:g}.")
        if self.nominal_speed <= 0 or self.min_segment_duration <= 0:
            raise InvalidInputError("nominal_speed and min_segment_duration must be positive.")
        if self.solver not in SOLVERS:
            raise InvalidInputError(f'solver must be one of {", ".join(SOLVERS)}, got "{self.solver}".')
        if self.margin < 0 or self.osqp_margin < 0:
            raise InvalidInputError(f"margins must be >= 0, got {self.margin}, {self.osqp_margin}.")
        if self.solver == "active_set" and not 0 <= self.active_set_tolerance < max(self.margin, 1e-300):
            raise InvalidInputError(f"active_set_tolerance must be below the polytope margin ({self.margin:g}; "
                                    f"0 when the margin is 0), got {self.active_set_tolerance:g}.")
