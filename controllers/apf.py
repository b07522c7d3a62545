r"""Improved artificial potential field planner on obstacle point sets.

The classical potential field (Khatib) cannot reach a goal that lies close to an
obstacle: near the goal the attraction fades while the repulsion does not, so
the total force vanishes short of the goal.  The improved field multiplies the
repulsive potential by the distance to the goal raised to a power ``n`` (Ge and
Cui), which makes the goal the global minimum of the total potential:

.. math::

    U_\mathrm{att}(q) = \tfrac12 \varepsilon \rho_g^2, \qquad
    U_\mathrm{rep}(q) =
    \begin{cases}
      \tfrac12 \eta \left(\frac{1}{\rho} - \frac{1}{\rho_0}\right)^2 \rho_g^n
        & \rho \le \rho_0 \\
      0 & \rho > \rho_0
    \end{cases}

with :math:`\rho_g = \lVert q_\mathrm{goal} - q \rVert` and :math:`\rho` the
clearance between the robot centre and an inflated obstacle.  The forces are
the negative gradients

.. math::

    F_\mathrm{att} = \varepsilon \rho_g \, n_{RG}, \qquad
    F_\mathrm{rep} = F_\mathrm{rep1} \, n_{OR} + F_\mathrm{rep2} \, n_{RG},

    F_\mathrm{rep1} = \eta \left(\frac{1}{\rho} - \frac{1}{\rho_0}\right)
        \frac{\rho_g^n}{\rho^2}, \qquad
    F_\mathrm{rep2} = \frac{n}{2} \eta
        \left(\frac{1}{\rho} - \frac{1}{\rho_0}\right)^2 \rho_g^{n-1},

where :math:`n_{OR}` is the unit vector from the obstacle to the robot and
:math:`n_{RG}` the unit vector from the robot to the goal.  ``n = 0`` recovers
the classical field.

Obstacles are a point set in the world frame (points of a range scan or the
centres of occupied grid cells).  A point set has no notion of "one obstacle",
and summing the repulsion of every point would make the force grow with the
sampling density of the scan.  The planner therefore splits the plane around
the robot into equal angular sectors and lets, in each sector, only the nearest
point within the influence distance repel.  This is the "nearest point per
obstacle" rule of the classical field applied per viewing direction: it does
not depend on the point density, and the two walls of a corridor or of a trap
both push, which a single nearest point would not do.

The way-points follow the total force with a fixed step length.  Every step is
checked against the inflated obstacles along the whole segment, so way-points
and the straight segments between them stay outside the inflated obstacles.
Local minima are detected (no progress towards the goal over a window of
steps, stepping back and forth, a vanishing total force away from the goal, or
no admissible step); the dithering way-points are dropped, and the minimum is
escaped by following the boundary of the blocking obstacle at a fixed
clearance until the robot is clearly closer to the goal than where it met the
obstacle, or sees the goal (a "Bug"-style escape).  The first escape goes
round the side facing the goal; later ones alternate sides and demand twice
the progress of the one before, so a wide basin of attraction is left behind
eventually.  The number of escapes and of steps is bounded, so the planner
always terminates and reports when it gave up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np
import numpy.typing as npt

from .paths import ObstacleSet, check_xy, check_xy_points

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "APFOutcome",
    "APFParams",
    "APFResult",
    "ImprovedAPF",
]


class APFOutcome(str, Enum):
    """Why :meth:`ImprovedAPF.plan` stopped."""

    REACHED = "reached"
    """The last way-point is the goal."""
    GOAL_BLOCKED = "goal_blocked"
    """The goal lies inside an inflated obstacle; no way-points towards it."""
    ESCAPES_EXHAUSTED = "escapes_exhausted"
    """Stuck again after ``max_escapes`` escapes; the planner gave up."""
    ITERATION_LIMIT = "iteration_limit"
    """``max_iterations`` steps taken without reaching the goal."""


@dataclass(frozen=True)
class APFParams:
    """Settings of :class:`ImprovedAPF`.

    Attributes
    ----------
    attractive_gain : float
        :math:`\\varepsilon` of the attractive potential (> 0).
    repulsive_gain : float
        :math:`\\eta` of the repulsive potential (>= 0).
    influence_distance : float
        :math:`\\rho_0` in m: obstacles whose clearance exceeds it do not repel (> 0).
    goal_exponent : float
        :math:`n` of the goal-distance factor :math:`\\rho_g^n` (>= 0; 0 is the
        classical field).
    inflation_radius : float
        Robot radius plus safety margin in m.  Clearance is measured from the
        robot centre to a disc of this radius around each obstacle point, and
        no way-point or way-point segment enters these discs.
    step_length : float
        Distance in m between consecutive way-points (> 0).
    goal_tolerance : float
        Once the goal is within ``max(goal_tolerance, step_length)`` m and in
        plain sight, the goal itself is appended as the last way-point.
    max_iterations : int
        Bound on the number of way-points generated (field steps and escape steps).
    stuck_window : int
        Number of steps over which progress towards the goal is measured.
    stuck_progress : float
        Minimum decrease in m of the distance to the goal over ``stuck_window``
        steps; less is a local minimum.
    stuck_force_ratio : float
        A total force smaller than this fraction of the attractive force is a
        local minimum (the forces cancel).
    max_escapes : int
        Number of escapes tried before giving up.  Escape ``k`` (from 1) leaves
        the boundary once ``stuck_progress · 2**(k-1)`` closer to the goal than
        where it met the obstacle.
    escape_clearance : float
        Clearance in m kept from the obstacle while following its boundary.
    max_escape_steps : int
        Bound on the number of steps of one escape.
    sector_count : int
        Number of angular sectors around the robot; the nearest point of each
        sector within :math:`\\rho_0` repels.
    """

    attractive_gain: float = 1.0
    repulsive_gain: float = 0.02
    influence_distance: float = 0.5
    goal_exponent: float = 2.0
    inflation_radius: float = 0.22
    step_length: float = 0.05
    goal_tolerance: float = 0.05
    max_iterations: int = 3000
    stuck_window: int = 30
    stuck_progress: float = 0.05
    stuck_force_ratio: float = 0.02
    max_escapes: int = 8
    escape_clearance: float = 0.08
    max_escape_steps: int = 600
    sector_count: int = 16

    def __post_init__(self) -> None:
        positive = {
            "attractive_gain": self.attractive_gain,
            "influence_distance": self.influence_distance,
            "step_length": self.step_length,
            "goal_tolerance": self.goal_tolerance,
            "stuck_progress": self.stuck_progress,
            "escape_clearance": self.escape_clearance,
        }
        for name, value in positive.items():
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"APFParams.{name} must be finite and > 0, got {value!r}")
        non_negative = {
            "repulsive_gain": self.repulsive_gain,
            "goal_exponent": self.goal_exponent,
            "inflation_radius": self.inflation_radius,
            "stuck_force_ratio": self.stuck_force_ratio,
        }
        for name, value in non_negative.items():
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"APFParams.{name} must be finite and >= 0, got {value!r}")
        counts = {
            "max_iterations": self.max_iterations,
            "stuck_window": self.stuck_window,
            "max_escape_steps": self.max_escape_steps,
            "sector_count": self.sector_count,
        }
        for name, value in counts.items():
            if int(value) != value or value < 1:
                raise ValueError(f"APFParams.{name} must be an integer >= 1, got {value!r}")
        if int(self.max_escapes) != self.max_escapes or self.max_escapes < 0:
            raise ValueError(
                f"APFParams.max_escapes must be an integer >= 0, got {self.max_escapes!r}"
            )


@dataclass(frozen=True)
class APFResult:
    """Outcome of :meth:`ImprovedAPF.plan`.

    Attributes
    ----------
    waypoints : ndarray, shape (K, 2)
        Way-points in the world frame in m, starting at the start point; when
        ``reached`` the last one is exactly the goal.
    reached : bool
        Whether the goal was reached.
    stuck_events : int
        Number of local minima detected.
    gave_up : bool
        Whether the planner stopped without reaching the goal.
    reason : APFOutcome
        Why the planner stopped (a ``str``).
    escapes : int
        Number of boundary-following escapes carried out.
    """

    waypoints: FloatArray
    reached: bool
    stuck_events: int
    gave_up: bool
    reason: APFOutcome
    escapes: int = 0


class ImprovedAPF:
    """Improved artificial potential field planner (goal-non-reachable fix).

    Parameters
    ----------
    params : APFParams, optional
        Gains, geometry and budgets; the defaults suit a Kobuki-sized robot
        (radius 0.176 m) among obstacles seen by a range scan.

    Examples
    --------
    >>> planner = ImprovedAPF()
    >>> result = planner.plan([0.0, 0.0], [1.0, 0.0], np.zeros((0, 2)))
    >>> result.reached, result.waypoints.shape
    (True, (21, 2))
    """

    def __init__(self, params: APFParams | None = None) -> None:
        self.params = params if params is not None else APFParams()

    # -- forces -----------------------------------------------------------------------------

    def forces(
        self, q: npt.ArrayLike, goal_xy: npt.ArrayLike, obstacle_points: npt.ArrayLike | None
    ) -> tuple[FloatArray, FloatArray]:
        """Attractive and total repulsive force at ``q``.

        Parameters
        ----------
        q : array_like, shape (2,)
            Robot position in m (world frame).
        goal_xy : array_like, shape (2,)
            Goal position in m (world frame).
        obstacle_points : array_like, shape (M, 2) or None
            Obstacle points in m (world frame).

        Returns
        -------
        attractive, repulsive : ndarray, shape (2,)
            :math:`F_\\mathrm{att}` and :math:`F_\\mathrm{rep}` (summed over the
            nearest point of every sector), in the units of the gains.
        """
        q = check_xy("q", q)
        goal = check_xy("goal_xy", goal_xy)
        points = check_xy_points("obstacle_points", obstacle_points)
        obstacles = ObstacleSet(points, self.params.inflation_radius)
        return self._forces(q, goal, obstacles)

    def _forces(
        self, q: FloatArray, goal: FloatArray, obstacles: ObstacleSet
    ) -> tuple[FloatArray, FloatArray]:
        p = self.params
        to_goal = goal - q
        rho_goal = float(np.linalg.norm(to_goal))
        attractive = p.attractive_gain * to_goal
        repulsive = np.zeros(2)
        if rho_goal <= 0.0 or p.repulsive_gain == 0.0:
            return attractive, repulsive
        unit_to_goal = to_goal / rho_goal
        near = obstacles.within(q, p.inflation_radius + p.influence_distance)
        if len(near) == 0:
            return attractive, repulsive
        offsets = q - near
        distances = np.linalg.norm(offsets, axis=1)
        bearings = np.arctan2(-offsets[:, 1], -offsets[:, 0])
        sectors = np.floor((bearings + np.pi) / (2.0 * np.pi) * p.sector_count).astype(int)
        sectors %= p.sector_count
        order = np.lexsort((distances, sectors))
        _, first = np.unique(sectors[order], return_index=True)
        chosen = order[first]
        # A point inside the inflation (only possible when starting there) repels as
        # if it were at 1 mm clearance, which pushes straight out.
        clearance = np.maximum(distances[chosen] - p.inflation_radius, 1e-3)
        distances_chosen = np.maximum(distances[chosen], 1e-12)
        unit_from_obstacle = offsets[chosen] / distances_chosen[:, None]
        inverse_gap = 1.0 / clearance - 1.0 / p.influence_distance
        active = inverse_gap > 0.0
        if not np.any(active):
            return attractive, repulsive
        inverse_gap = inverse_gap[active]
        clearance = clearance[active]
        n = p.goal_exponent
        f_rep1 = p.repulsive_gain * inverse_gap * rho_goal**n / clearance**2
        f_rep2 = 0.5 * n * p.repulsive_gain * inverse_gap**2 * rho_goal ** (n - 1.0)
        repulsive = f_rep1 @ unit_from_obstacle[active] + float(np.sum(f_rep2)) * unit_to_goal
        return attractive, repulsive

    # -- planning ---------------------------------------------------------------------------

    def plan(
        self,
        start_xy: npt.ArrayLike,
        goal_xy: npt.ArrayLike,
        obstacle_points: npt.ArrayLike | None,
        rng: np.random.Generator | None = None,
    ) -> APFResult:
        """Follow the improved potential field from ``start_xy`` to ``goal_xy``.

        Parameters
        ----------
        start_xy, goal_xy : array_like, shape (2,)
            Start and goal positions in m (world frame).
        obstacle_points : array_like, shape (M, 2) or None
            Obstacle points in m (world frame), e.g. scan end points or centres
            of occupied cells; ``M`` may be 0.
        rng : numpy.random.Generator, optional
            Only used to choose the side of the first boundary-following escape
            when both sides are equally good (goal straight behind the
            obstacle); without it the obstacle is kept on the left, so the
            planner is deterministic.

        Returns
        -------
        APFResult
            Way-points (the first is the start), success flags and the number
            of local minima met.  If the start lies inside an inflated
            obstacle, the first way-points lead straight out of it.

        Raises
        ------
        ValueError
            If a position is not a finite 2-vector or ``obstacle_points`` is not
            a finite (M, 2) array.
        """
        p = self.params
        start = check_xy("start_xy", start_xy)
        goal = check_xy("goal_xy", goal_xy)
        points = check_xy_points("obstacle_points", obstacle_points)
        obstacles = ObstacleSet(points, p.inflation_radius)

        path: list[FloatArray] = [start.copy()]
        if obstacles.clearance(goal) <= 0.0:
            return APFResult(np.array(path), False, 0, True, APFOutcome.GOAL_BLOCKED)

        q = start.copy()
        budget = p.max_iterations
        q, budget = self._leave_inflation(q, obstacles, path, budget)

        stuck_events = 0
        escapes = 0
        side_hint = 0
        phase_start = len(path) - 1  # index of the first way-point of the current field phase
        reversal_steps: list[int] = []
        while budget > 0:
            rho_goal = float(np.linalg.norm(goal - q))
            if rho_goal <= max(p.goal_tolerance, p.step_length) and obstacles.segment_is_clear(
                q, goal
            ):
                if rho_goal > 0.0:
                    path.append(goal.copy())
                return APFResult(
                    np.array(path), True, stuck_events, False, APFOutcome.REACHED, escapes
                )

            attractive, repulsive = self._forces(q, goal, obstacles)
            total = attractive + repulsive
            force_norm = float(np.linalg.norm(total))
            step = self._field_step(q, total, force_norm, rho_goal, obstacles)
            if step is not None and len(path) - phase_start >= 2:
                previous_step = path[-1] - path[-2]
                if float((step - q) @ previous_step) < -0.7 * float(
                    np.linalg.norm(step - q)
                ) * float(np.linalg.norm(previous_step)):
                    reversal_steps.append(len(path))
            if self._is_stuck(
                path, phase_start, goal, reversal_steps, force_norm, attractive, step
            ):
                stuck_events += 1
                q = self._drop_dither(path, phase_start)
                if escapes >= p.max_escapes:
                    return APFResult(
                        np.array(path), False, stuck_events, True,
                        APFOutcome.ESCAPES_EXHAUSTED, escapes,
                    )  # fmt: skip
                escapes += 1
                side = self._escape_side(q, goal, obstacles, side_hint, rng)
                side_hint = -side
                q, budget = self._follow_boundary(
                    q, goal, side, obstacles, path, budget, p.stuck_progress * 2.0 ** (escapes - 1)
                )
                phase_start = len(path) - 1
                reversal_steps = []
                continue
            assert step is not None
            q = step
            path.append(q.copy())
            budget -= 1

        return APFResult(
            np.array(path), False, stuck_events, True, APFOutcome.ITERATION_LIMIT, escapes
        )

    def _is_stuck(
        self,
        path: list[FloatArray],
        phase_start: int,
        goal: FloatArray,
        reversal_steps: list[int],
        force_norm: float,
        attractive: FloatArray,
        step: FloatArray | None,
    ) -> bool:
        """Local-minimum test: no admissible step, cancelling forces, dithering or no progress."""
        p = self.params
        if step is None:
            return True
        if force_norm < p.stuck_force_ratio * float(np.linalg.norm(attractive)):
            return True
        recent = len(path) - min(p.stuck_window, 10)
        if sum(1 for k in reversal_steps if k >= recent) >= 3:
            return True
        if len(path) - 1 - phase_start >= p.stuck_window:
            before = float(np.linalg.norm(goal - path[-1 - p.stuck_window]))
            now = float(np.linalg.norm(goal - path[-1]))
            return before - now < p.stuck_progress
        return False

    def _drop_dither(self, path: list[FloatArray], phase_start: int) -> FloatArray:
        """Cut the way-points of the current phase that dithered around the local minimum.

        Keeps the path up to the earliest way-point of the phase within one
        step of the last one and returns that way-point.
        """
        q = path[-1]
        reach = self.params.step_length * (1.0 + 1e-9)
        for index in range(phase_start, len(path)):
            if float(np.linalg.norm(path[index] - q)) <= reach:
                del path[index + 1 :]
                return path[index].copy()
        return q.copy()

    def _field_step(
        self,
        q: FloatArray,
        force: FloatArray,
        force_norm: float,
        rho_goal: float,
        obstacles: ObstacleSet,
    ) -> FloatArray | None:
        """Next way-point along ``force``, shortened up to twice if blocked; None if blocked."""
        if force_norm <= 1e-12:
            return None
        direction = force / force_norm
        length = min(self.params.step_length, rho_goal)
        for _ in range(3):
            candidate = q + length * direction
            if obstacles.segment_is_clear(q, candidate):
                return candidate
            length *= 0.5
        return None

    def _leave_inflation(
        self, q: FloatArray, obstacles: ObstacleSet, path: list[FloatArray], budget: int
    ) -> tuple[FloatArray, int]:
        """Step straight away from the nearest point while the start is inside an inflation."""
        p = self.params
        while budget > 0 and obstacles.clearance(q) <= 0.0:
            distance, nearest = obstacles.nearest(q)
            assert nearest is not None
            away = q - nearest if distance > 1e-12 else np.array([1.0, 0.0])
            away /= np.linalg.norm(away)
            q = q + min(p.step_length, -obstacles.clearance(q) + 1e-3) * away
            path.append(q.copy())
            budget -= 1
        return q, budget

    def _escape_side(
        self,
        q: FloatArray,
        goal: FloatArray,
        obstacles: ObstacleSet,
        side_hint: int,
        rng: np.random.Generator | None,
    ) -> int:
        """+1 to go round with the obstacle on the left (counter-clockwise), -1 the other way."""
        if side_hint != 0:
            return side_hint
        distance, nearest = obstacles.nearest(q)
        if nearest is None or distance <= 1e-12:
            return 1
        normal = (q - nearest) / distance
        tangent_left = np.array([-normal[1], normal[0]])
        to_goal = goal - q
        score = float(tangent_left @ to_goal)
        if abs(score) <= 1e-6 * max(float(np.linalg.norm(to_goal)), 1e-12):
            return 1 if rng is None else int(rng.choice([-1, 1]))
        return 1 if score > 0.0 else -1

    def _follow_boundary(
        self,
        q: FloatArray,
        goal: FloatArray,
        side: int,
        obstacles: ObstacleSet,
        path: list[FloatArray],
        budget: int,
        leave_margin: float,
    ) -> tuple[FloatArray, int]:
        """Follow the nearest obstacle at ``escape_clearance`` until clearly closer to the goal.

        The robot first moves straight towards the nearest obstacle until it is
        at ``escape_clearance``; the distance to the goal there is the one to
        beat.  It leaves the boundary when the distance to the goal has dropped
        by ``stuck_progress`` below it, or when the goal is in plain sight and
        closer than it.
        """
        p = self.params
        steps = 0
        # Approach the blocking obstacle first, so that the distance that has to be beaten is the
        # one at its boundary (as in the Bug algorithms) and not the one at the local minimum.
        while steps < p.max_escape_steps and budget > 0:
            distance, nearest = obstacles.nearest(q)
            gap = distance - p.inflation_radius - p.escape_clearance
            if nearest is None or gap <= 0.5 * p.step_length:
                break
            candidate = q + min(p.step_length, gap) * (nearest - q) / distance
            if not obstacles.segment_is_clear(q, candidate):
                break
            q = candidate
            path.append(q.copy())
            budget -= 1
            steps += 1
        hit_distance = float(np.linalg.norm(goal - q))
        for _ in range(p.max_escape_steps - steps):
            if budget <= 0:
                break
            distance, nearest = obstacles.nearest(q)
            if nearest is None:
                break
            normal = (q - nearest) / max(distance, 1e-12)
            tangent = side * np.array([-normal[1], normal[0]])
            gap_error = (p.escape_clearance - (distance - p.inflation_radius)) / p.escape_clearance
            direction = tangent + np.clip(gap_error, -1.0, 1.0) * normal
            turned_step = self._admissible_turn(q, direction, normal, obstacles)
            if turned_step is None:
                break
            q = turned_step
            path.append(q.copy())
            budget -= 1
            goal_distance = float(np.linalg.norm(goal - q))
            if goal_distance < hit_distance - leave_margin:
                break
            if goal_distance < hit_distance and obstacles.segment_is_clear(q, goal):
                break
        return q, budget

    def _admissible_turn(
        self, q: FloatArray, direction: FloatArray, normal: FloatArray, obstacles: ObstacleSet
    ) -> FloatArray | None:
        """A clear step along ``direction``, turned towards ``normal`` in 15° increments if needed."""
        length = self.params.step_length
        direction = direction / max(float(np.linalg.norm(direction)), 1e-12)
        cross = direction[0] * normal[1] - direction[1] * normal[0]
        turn_sign = 1.0 if cross >= 0.0 else -1.0
        for k in range(13):
            angle = turn_sign * math.radians(15.0) * k
            c, s = math.cos(angle), math.sin(angle)
            turned = np.array(
                [c * direction[0] - s * direction[1], s * direction[0] + c * direction[1]]
            )
            candidate = q + length * turned
            if obstacles.segment_is_clear(q, candidate):
                return candidate
        return None


# -- post-processing and reference path lengths ---------------------------------------------
