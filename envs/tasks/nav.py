"""The WheeledNav task: drive to a goal pose in a square room among obstacles.

The task draws the start and goal poses and the obstacle layout, scores each
step with a named sum of reward terms and decides success and termination. It
reads only ground truth handed to it by the env (poses, the collision flag,
the robot's twist); it never touches the simulation.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from realitygap.core.checks import check_finite_float, check_nonnegative_int
from realitygap.core.geometry import check_finite
from realitygap.envs.common import (
    check_bool,
    check_finite_fields,
    check_instance,
    check_obstacles,
    check_vector,
)
from realitygap.envs.layouts import (
    MAX_ROOM_HALF_SIZE,
    MIN_ROOM_HALF_SIZE,
    clearance,
    free_route_exists,
    obstacle_capacity,
    random_layout,
    room_walls,
)
from realitygap.robots.world import Primitive

FloatArray = npt.NDArray[np.float64]


# Defaults of a WheeledNav episode, shared by the PyBullet env and its vector twin so
# that the two build the same episodes from the same arguments.
ROOM_HALF_SIZE = 3.5  # m, half the side of the square room
N_OBSTACLES = 6
SUCCESS_POS_TOL = 0.03  # m
SUCCESS_ANG_TOL = math.radians(5.0)  # rad
CONTROL_HZ = 20.0  # Hz, one action per control period
N_BEAMS = 64  # beams of the planar scan
SCAN_HZ = 10.0  # Hz


REST_SPEED = 0.01
"""Speed (m/s) below which the robot is at rest."""
REST_YAW_RATE = 0.05
"""Yaw rate (rad/s) below which the robot is at rest."""


def at_rest(v: float, w: float) -> bool:
    """Whether a twist (m/s, rad/s) is at rest: ``|v| <`` :data:`REST_SPEED` and
    ``|ω| <`` :data:`REST_YAW_RATE`."""
    return abs(v) < REST_SPEED and abs(w) < REST_YAW_RATE


class _HasTwist(Protocol):
    def twist(self) -> FloatArray: ...


@dataclass(frozen=True)
class NavRewardWeights:
    r"""Weights of the WheeledNav reward terms.

    With the true distance ``d`` (m) and absolute heading error ``a`` (rad) to
    the goal pose before (``d⁻``, ``a⁻``) and after a step, and the normalised
    action ``(a₀, a₁)``:

    .. math::

        r = w_p (d^- - d) + w_h e^{-d / s_h} (a^- - a) - w_t
            - w_e (a_0^2 + a_1^2) - w_c [\text{collision}] + w_s [\text{success}]

    Parameters
    ----------
    progress : float
        ``w_p``, per metre of progress towards the goal position.
    heading : float
        ``w_h``, per radian of heading alignment.
    heading_scale : float
        ``s_h``, m: distance over which the heading term fades away from the goal.
    time : float
        ``w_t``, cost per step.
    effort : float
        ``w_e``, cost per unit squared normalised action.
    collision : float
        ``w_c``, penalty on touching a wall or an obstacle.
    success : float
        ``w_s``, bonus on success.
    """

    progress: float = 2.0
    heading: float = 0.5
    heading_scale: float = 0.3
    time: float = 0.01
    effort: float = 0.002
    collision: float = 5.0
    success: float = 5.0

    def __post_init__(self) -> None:
        check_finite_fields(self)


class NavTask:
    """Reach a goal pose ``[x, y, θ]`` in a square room, at rest.

    Parameters
    ----------
    room_half_size : half the side of the square room (m).
    n_obstacles : random obstacles per episode (0: empty room).
    obstacles : a fixed layout instead of random ones.
    start, goal : fixed start / goal poses ``[x, y, θ]``; random when ``None``.
    success_pos_tol, success_ang_tol : success tolerances (m, rad).
    terminate_on_success : end the episode on success.
    weights : the reward weights.
    """

    def __init__(
        self,
        *,
        room_half_size: float = ROOM_HALF_SIZE,
        n_obstacles: int = N_OBSTACLES,
        obstacles: Sequence[Primitive] | None = None,
        start: npt.ArrayLike | None = None,
        goal: npt.ArrayLike | None = None,
        success_pos_tol: float = SUCCESS_POS_TOL,
        success_ang_tol: float = SUCCESS_ANG_TOL,
        terminate_on_success: bool = True,
        weights: NavRewardWeights = NavRewardWeights(),
    ):
        self.room_half_size = check_finite_float(
            room_half_size,
            "room_half_size",
            low=MIN_ROOM_HALF_SIZE,
            high=MAX_ROOM_HALF_SIZE,
            unit="m",
            fix="a room whose side is 2 to 100 m (the route check's grid grows with its area)",
        )
        self.n_obstacles = check_nonnegative_int(
            n_obstacles,
            "n_obstacles",
            high=obstacle_capacity(self.room_half_size),
            fix=(
                f"a room of half-size {self.room_half_size:g} m holds at most that many obstacles"
                if isinstance(n_obstacles, (int, float)) and n_obstacles > 0
                else ""
            ),
        )
        self.fixed_obstacles = check_obstacles(obstacles)
        self.fixed_start = self._check_pose("start", start)
        self.fixed_goal = self._check_pose("goal", goal)
        self.success_pos_tol = check_finite_float(
            success_pos_tol,
            "success_pos_tol",
            low=0.0,
            high=self.room_half_size,
            strict_low=True,
            unit="m",
        )
        self.success_ang_tol = check_finite_float(
            success_ang_tol, "success_ang_tol", low=0.0, high=math.pi, strict_low=True, unit="rad"
        )
        self.terminate_on_success = check_bool(terminate_on_success, "terminate_on_success")
        self.weights = check_instance(weights, "reward_weights", NavRewardWeights)
        self.goal = np.zeros(3)
        self._prev_dist = 0.0
        self._prev_ang = 0.0

    def _check_pose(self, name: str, pose: Any) -> FloatArray | None:
        """A fixed pose ``[x, y, θ]`` (m, m, rad) inside the room, or ``None``."""
        if pose is None:
            return None
        arr = check_vector(pose, name, (3,), what="x [m], y [m], θ [rad]")
        h = self.room_half_size
        if np.any(np.abs(arr[:2]) >= h):
            raise ValueError(
                f"{name} {arr[:2].tolist()} lies outside the room: |x|, |y| must be < "
                f"room_half_size = {h:g} m (less the robot's radius). Fix: pass a pose inside "
                "the room, or None for a random one"
            )
        return arr

    # ------------------------------------------------------------------ episode set-up
    def sample_start_goal(
        self, rng: np.random.Generator, options: Mapping[str, Any], robot_radius: float
    ) -> tuple[FloatArray, FloatArray]:
        """Start and goal poses ``[x, y, θ]``: ``options``, else the fixed ones, else drawn.

        A drawn goal lies more than 1 m from the start (up to 100 draws).

        Raises
        ------
        ValueError
            If a pose is not finite or lies outside the room for a robot of
            radius ``robot_radius`` (m).
        """
        lim = self.room_half_size - 0.6
        start: Any = options.get("start", self.fixed_start)
        goal: Any = options.get("goal", self.fixed_goal)
        if start is None:
            start = np.array([*rng.uniform(-lim, lim, 2), rng.uniform(-math.pi, math.pi)])
        if goal is None:
            for _ in range(100):
                goal = np.array([*rng.uniform(-lim, lim, 2), rng.uniform(-math.pi, math.pi)])
                if np.hypot(*(goal[:2] - np.asarray(start)[:2])) > 1.0:
                    break
        start = check_finite("start", start, (3,))
        goal = check_finite("goal", goal, (3,))
        for name, pose in (("start", start), ("goal", goal)):
            if np.any(np.abs(pose[:2]) > self.room_half_size - robot_radius):
                raise ValueError(
                    f"{name} {pose[:2].tolist()} lies outside the room (|x|, |y| must be < "
                    f"{self.room_half_size - robot_radius:.3f} m)"
                )
        return start, goal

    def sample_arena(
        self,
        rng: np.random.Generator,
        start: FloatArray,
        goal: FloatArray,
        robot_radius: float,
    ) -> tuple[Primitive, ...]:
        """Footprints of the room's walls and this episode's obstacles.

        Random obstacles keep the start and goal clear and leave a route for a
        robot of radius ``robot_radius`` (m); a fixed layout is checked for both.

        Raises
        ------
        ValueError
            If the fixed layout overlaps the start or leaves no collision-free route.
        """
        if self.fixed_obstacles is not None:
            layout = list(self.fixed_obstacles)
            if np.min(clearance(layout, start[:2]), initial=np.inf) <= robot_radius:
                raise ValueError(
                    f"the start pose {start.tolist()} overlaps an obstacle of the given layout"
                )
            if not free_route_exists(
                layout + room_walls(self.room_half_size),
                start[:2],
                goal[:2],
                robot_radius,
                self.room_half_size,
            ):
                raise ValueError(
                    f"the given obstacle layout leaves no collision-free route from start {start[:2].tolist()} "
                    f"to goal {goal[:2].tolist()} for a robot of radius {robot_radius:.3f} m"
                )
        elif self.n_obstacles > 0:
            layout = random_layout(
                rng,
                self.n_obstacles,
                self.room_half_size,
                keep_clear=[tuple(start[:2]), tuple(goal[:2])],
                clear_radius=robot_radius + 0.25,
                robot_radius=robot_radius,
            )
        else:
            layout = []
        return tuple(room_walls(self.room_half_size) + layout)

    def reset(self, goal: FloatArray, pose: FloatArray) -> tuple[float, float]:
        """Start scoring towards ``goal`` from the true ``pose``; returns its pose error."""
        self.goal = goal
        self._prev_dist, self._prev_ang = self.pose_error(pose)
        return self._prev_dist, self._prev_ang

    # ------------------------------------------------------------------ scoring
    def pose_error(self, pose: FloatArray) -> tuple[float, float]:
        """True distance (m) and absolute heading error (rad) of ``pose`` to the goal pose."""
        # plain floats: cheaper scalar arithmetic, the same values
        goal = self.goal
        gx, gy, gth = goal.tolist() if type(goal) is np.ndarray else (float(v) for v in goal)
        x, y, th = pose.tolist()[:3] if type(pose) is np.ndarray else (float(v) for v in pose[:3])
        d_th = (th - gth + math.pi) % (2.0 * math.pi) - math.pi
        return math.hypot(x - gx, y - gy), abs(d_th)

    def is_success(self, dist: float, ang: float, robot: _HasTwist) -> bool:
        """Within the tolerances of the goal pose and at rest (:func:`at_rest`, read from
        ``robot.twist()`` only when within tolerance)."""
        if dist > self.success_pos_tol or ang > self.success_ang_tol:
            return False
        v, w = robot.twist()
        return at_rest(v, w)

    def get_reward(
        self, dist: float, ang: float, action: tuple[float, float], collision: bool, success: bool
    ) -> tuple[float, dict[str, float]]:
        """Reward of a step and its named terms (see :class:`NavRewardWeights`)."""
        wt = self.weights
        near = math.exp(-dist / wt.heading_scale)
        terms = {
            "progress": wt.progress * (self._prev_dist - dist),
            "heading": wt.heading * near * (self._prev_ang - ang),
            "time": -wt.time,
            "effort": -wt.effort * (action[0] ** 2 + action[1] ** 2),
            "collision": -wt.collision if collision else 0.0,
            "success": wt.success if success else 0.0,
        }
        self._prev_dist, self._prev_ang = dist, ang
        return float(sum(terms.values())), terms

    def is_terminated(self, collision: bool, success: bool) -> bool:
        """A collision ends the episode; so does success with ``terminate_on_success``."""
        return collision or (success and self.terminate_on_success)
