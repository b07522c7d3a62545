"""Classical baseline for ``realitygap/WallClimb-v0``: APF → QP smoothing → Kanayama tracker in a surface chart.

The blade's suction side is nearly a graph over the blade frame's ``(x, y)`` plane
(span, chord), so the chart is that plane: a point's chart coordinates are its blade
frame ``x, y``; the heading is the angle of the body x-axis projected into it. In the
chart the climber is a unicycle; the pipeline of :mod:`realitygap.baselines.classical`
runs there unchanged (no obstacles: the APF gives the straight route, the QP smooths
it under the start heading), and its ``(v, ω)`` goes to the robot as is (the chart is
close to isometric on the suction side's middle, so lengths and turn rates carry
over to first order).

States: ``align`` (turn towards the path), ``track`` (Kanayama on the timed
reference), ``stabilise`` (polar stabiliser on the goal point), ``done``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.baselines.common import PerEnvPolicy
from realitygap.controllers import (
    APFParams,
    ImprovedAPF,
    KanayamaTracker,
    PolarStabiliser,
    TimedReference,
    VelocityLimits,
    smooth_path,
)
from realitygap.core.geometry import wrap_angle
from realitygap.robots.climber import ClimberParams

FloatArray = npt.NDArray[np.float64]

__all__ = ["ClimbChartPolicy", "ClimbPolicyConfig", "chart_from_world"]

N_OBS = 18


def chart_from_world(
    params: ClimberParams, position: npt.ArrayLike, x_axis: npt.ArrayLike | None = None
) -> FloatArray:
    """Chart coordinates ``(x, y[, θ])`` (m, m, rad) of a world position (and heading axis)."""
    b = params.blade_from_world(position)
    if x_axis is None:
        return np.asarray(b[..., :2], dtype=float)
    d = np.asarray(x_axis, dtype=float) @ params.R_world_blade
    return np.array([b[0], b[1], math.atan2(d[1], d[0])])


@dataclass(frozen=True)
class ClimbPolicyConfig:
    """Settings (SI units)."""

    stabilise_radius: float = 0.08
    """Switch from tracking to point stabilisation within this distance (m)."""
    align_tolerance: float = math.radians(15.0)
    """Heading error (rad) that ends the initial turn in place."""
    replan_tracking_error: float = 0.15
    """Re-plan when this far from the reference (m)."""
    done_tol: float = 0.03
    """Stop within this distance of the goal (m)."""
    speed_fraction: float = 0.7
    apf: APFParams = field(default_factory=lambda: APFParams(inflation_radius=0.1))


@dataclass
class _State:
    goal: FloatArray | None = None
    phase: str = "plan"
    reference: TimedReference | None = None
    t_ref: float = 0.0
    heading: float = 0.0
    plans: int = 0


class ClimbChartPolicy(PerEnvPolicy):
    """SB3-compatible classical policy for ``WallClimb-v0`` (see module docstring).

    Parameters
    ----------
    params
        Nominal robot and mount (for the chart).
    dt
        Control period, s.
    config
        :class:`ClimbPolicyConfig`.
    """

    n_obs = N_OBS
    obs_what = "WallClimb-v0"

    def __init__(
        self, params: ClimberParams, dt: float, config: ClimbPolicyConfig | None = None
    ) -> None:
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive period in s, got {dt!r}")
        self.params = params
        self.dt = float(dt)
        self.config = config or ClimbPolicyConfig()
        self.limits = VelocityLimits(
            v_max=params.v_max, w_max=params.w_max, a_max=0.4, alpha_max=1.5
        )
        self.apf = ImprovedAPF(self.config.apf)
        self.tracker = KanayamaTracker()
        self._states: dict[int, _State] = {}
        self._stab: dict[int, PolarStabiliser] = {}

    @classmethod
    def from_env(cls, env: Any, config: ClimbPolicyConfig | None = None) -> ClimbChartPolicy:
        """Build from a (possibly wrapped) ``WallClimb-v0`` env."""
        base = env.unwrapped
        return cls(base.params, base.dt, config)

    def reset(self, env_index: int | None = None) -> None:
        """Forget the episode state of one env (or all)."""
        if env_index is None:
            self._states.clear()
            self._stab.clear()
        else:
            self._states.pop(env_index, None)
            self._stab.pop(env_index, None)

    def phase(self, env_index: int = 0) -> str:
        """Current phase of env ``env_index``."""
        st = self._states.get(env_index)
        return "plan" if st is None else st.phase

    # ------------------------------------------------------------------ internals
    def act(self, i: int, obs: FloatArray) -> FloatArray:
        """The action of env ``i`` for its observation row (see :class:`PerEnvPolicy`)."""
        pose = chart_from_world(self.params, obs[0:3], obs[3:6])
        goal = chart_from_world(self.params, obs[9:12])
        st = self._states.get(i)
        if st is None or st.goal is None or np.any(np.abs(st.goal - goal) > 1e-6):
            st = self._states[i] = _State(goal=goal)
            self._stab[i] = PolarStabiliser(limits=self.limits)
        if obs[17] < 0.5:  # estimate unusable: stand still
            return np.zeros(2)
        v, w = self._control(i, st, pose, goal)
        v_prev, w_prev = obs[15] * self.params.v_max, obs[16] * self.params.w_max
        v, w = self.limits.clip(v, w, v_prev, w_prev, self.dt)
        return np.array([v / self.params.v_max, w / self.params.w_max])

    def _plan(self, st: _State, pose: FloatArray, goal: FloatArray) -> bool:
        st.plans += 1
        result = self.apf.plan(pose[:2], goal, None)
        if not result.reached or len(result.waypoints) < 2:
            return False
        wps = np.asarray(result.waypoints, dtype=float)
        first = wps[min(1, len(wps) - 1)] - wps[0]
        st.heading = math.atan2(first[1], first[0])
        path = smooth_path(wps, st.heading, None)
        st.reference = TimedReference(path, self.limits, speed_fraction=self.config.speed_fraction)
        st.t_ref = 0.0
        st.phase = "align"
        return True

    def _control(
        self, i: int, st: _State, pose: FloatArray, goal: FloatArray
    ) -> tuple[float, float]:
        stab = self._stab[i]
        dist = math.hypot(*(goal - pose[:2]))
        if st.phase == "done" or dist < self.config.done_tol:
            st.phase = "done"
            return 0.0, 0.0
        if st.phase == "stabilise" or dist < self.config.stabilise_radius:
            st.phase = "stabilise"
            heading = math.atan2(goal[1] - pose[1], goal[0] - pose[0])
            err = float(wrap_angle(heading - pose[2]))
            return 0.1 * math.cos(err) * min(1.0, dist / 0.05), 2.0 * err
        if st.reference is None or st.phase == "plan":
            if not self._plan(st, pose, goal):
                return 0.0, 0.0
        assert st.reference is not None
        if st.phase == "align":
            err = float(wrap_angle(st.heading - pose[2]))
            if abs(err) > self.config.align_tolerance:
                return stab.command(pose, np.array([pose[0], pose[1], st.heading]))
            st.phase = "track"
        st.t_ref += self.dt
        ref = st.reference.sample(min(st.t_ref, st.reference.duration))
        if math.hypot(*(ref.pose[:2] - pose[:2])) > self.config.replan_tracking_error:
            st.phase = "plan"
            return 0.0, 0.0
        if st.t_ref >= st.reference.duration:
            st.phase = "stabilise"
        return self.tracker.command(pose, ref.pose, ref.v, ref.w)
