"""The WallClimb task: drive to a goal point on the suction side of the blade.

The task draws the start and goal chart points, scores each step with a named
sum of reward terms and decides detachment, success and termination. It reads
only ground truth handed to it by the env (true distance to the goal, height
above the surface); it never touches the simulation.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.checks import check_finite_float
from realitygap.envs.common import check_finite_fields, check_instance, check_vector

FloatArray = npt.NDArray[np.float64]

__all__ = ["WallClimbRewardWeights", "WallClimbTask"]


@dataclass(frozen=True)
class WallClimbRewardWeights:
    r"""Weights of the WallClimb reward terms.

    With the true distance ``d`` (m) to the goal point before (``d⁻``) and after a
    step, and the normalised action ``(a₀, a₁)``:

    .. math::

        r = w_p (d^- - d) - w_t - w_e (a_0^2 + a_1^2)
            - w_d [\text{detached}] + w_s [\text{success}]

    Parameters
    ----------
    progress : float
        ``w_p``, per metre of progress towards the goal.
    time : float
        ``w_t``, cost per step.
    effort : float
        ``w_e``, cost per unit squared normalised action.
    detach : float
        ``w_d``, penalty on leaving the surface.
    success : float
        ``w_s``, bonus on success.
    """

    progress: float = 5.0
    time: float = 0.01
    effort: float = 0.002
    detach: float = 5.0
    success: float = 5.0

    def __post_init__(self) -> None:
        check_finite_fields(self)


class WallClimbTask:
    """Reach a goal point on the suction side, on the surface.

    Parameters
    ----------
    blade_length : length of the blade (m); chart points keep 0.3 m from its ends.
    start, goal : fixed chart points ``(x [m], ξ)`` (start also ``(x, ξ, heading [rad])``);
        random when ``None``.
    success_tol : distance to the goal that counts as reached (m).
    detach_margin : height above the rolling height beyond which the robot counts as
        detached (m).
    weights : the reward weights.
    """

    def __init__(
        self,
        *,
        blade_length: float,
        start: npt.ArrayLike | None = None,
        goal: npt.ArrayLike | None = None,
        success_tol: float = 0.05,
        detach_margin: float = 0.03,
        weights: WallClimbRewardWeights = WallClimbRewardWeights(),
    ) -> None:
        self.blade_length = check_finite_float(
            blade_length, "blade_length", low=0.6, strict_low=True, unit="m"
        )
        self.fixed_start = (
            None if start is None else self.check_chart("start", start, allow_heading=True)
        )
        self.fixed_goal = (
            None if goal is None else self.check_chart("goal", goal, allow_heading=False)
        )
        self.success_tol = check_finite_float(
            success_tol, "success_tol", low=0.0, strict_low=True, unit="m"
        )
        self.detach_margin = check_finite_float(
            detach_margin, "detach_margin", low=0.0, strict_low=True, unit="m"
        )
        self.weights = check_instance(weights, "reward_weights", WallClimbRewardWeights)
        self._prev_dist = 0.0

    # ------------------------------------------------------------------ episode set-up
    def sample_start_goal(
        self, rng: np.random.Generator, options: Mapping[str, Any]
    ) -> tuple[FloatArray, FloatArray]:
        """Start ``(x, ξ[, heading])`` and goal ``(x, ξ)`` chart points: ``options``, else the
        fixed ones, else drawn.

        A drawn start lies in ``1.5 < x < 6`` m, ``0.2 < ξ < 0.55`` with a uniform
        heading; a drawn goal in ``1 < x < 7`` m, ``0.15 < ξ < 0.6`` with an L1 chart
        distance between 0.5 and 2.5 from the start (up to 50 draws).

        Raises
        ------
        ValueError
            If a point is not finite or lies off the suction side.
        """
        start = options.get("start", self.fixed_start)
        goal = options.get("goal", self.fixed_goal)
        if start is None:
            start = np.array(
                [rng.uniform(1.5, 6.0), rng.uniform(0.2, 0.55), rng.uniform(-np.pi, np.pi)]
            )
        start = self.check_chart("start", start, allow_heading=True)
        if goal is None:
            for _ in range(50):
                goal = np.array([rng.uniform(1.0, 7.0), rng.uniform(0.15, 0.6)])
                if 0.5 < abs(goal[0] - start[0]) + abs(goal[1] - start[1]) < 2.5:
                    break
        goal = self.check_chart("goal", goal, allow_heading=False)
        return start, goal

    def check_chart(self, name: str, value: Any, *, allow_heading: bool) -> FloatArray:
        """``value`` as a chart point on the suction side, or a ``ValueError`` saying why not."""
        sizes = (2, 3) if allow_heading else (2,)
        what = f"x [m], ξ{', heading [rad]' if allow_heading else ''}"
        arr = check_vector(value, name, sizes, what=what)
        L = self.blade_length
        if not (0.3 < arr[0] < L - 0.3 and 0.05 <= arr[1] <= 0.9):
            raise ValueError(
                f"{name} ({arr[0]:.3g}, {arr[1]:.3g}) must lie on the suction side: "
                f"0.3 < x < {L - 0.3} m, 0.05 ≤ ξ ≤ 0.9"
            )
        return arr

    def reset(self, dist: float) -> None:
        """Start scoring from the true distance ``dist`` (m) to the goal."""
        self._prev_dist = dist

    # ------------------------------------------------------------------ scoring
    def is_detached(self, height: float, rolling_height: float) -> bool:
        """Whether the body's ``height`` above the surface (m) is off the surface: below
        -2 cm or above ``rolling_height + detach_margin``."""
        return not (-0.02 < height < rolling_height + self.detach_margin)

    def is_success(self, dist: float, detached: bool) -> bool:
        """Within ``success_tol`` of the goal and on the surface."""
        return dist < self.success_tol and not detached

    def get_reward(
        self, dist: float, action: tuple[float, float], detached: bool, success: bool
    ) -> tuple[float, dict[str, float]]:
        """Reward of a step and its named terms (see :class:`WallClimbRewardWeights`)."""
        wt = self.weights
        terms = {
            "progress": wt.progress * (self._prev_dist - dist),
            "time": -wt.time,
            "effort": -wt.effort * (action[0] ** 2 + action[1] ** 2),
            "detach": -wt.detach if detached else 0.0,
            "success": wt.success if success else 0.0,
        }
        self._prev_dist = dist
        return float(sum(terms.values())), terms

    def is_terminated(self, detached: bool, success: bool) -> bool:
        """Leaving the surface or reaching the goal ends the episode."""
        return detached or success
