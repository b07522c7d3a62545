"""The classical navigation baseline: improved APF → QP smoothing → Kanayama tracker → polar stabiliser.

:class:`ClassicalNavPolicy` has stable-baselines3's ``predict`` signature, so the
same harness scores it and a trained PPO model. It plans only from the
observation — the estimated pose, the goal and the scan — and keeps a memory of
the obstacle points it has seen (world frame, through the estimated pose).

Per episode it runs a small state machine:

``align``      turn in place towards the planned path's initial direction;
``track``      follow the time-parameterised smoothed path with the Kanayama law;
``stabilise``  polar-coordinate point stabilisation onto the goal pose;
``done``       stand still.

It re-plans when newly seen obstacles come close to the remaining path, when the
tracking error grows too large, or when a plan failed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from realitygap.baselines.common import PerEnvPolicy
from realitygap.controllers import (
    APFParams,
    ImprovedAPF,
    KanayamaTracker,
    PolarStabiliser,
    TimedReference,
    VelocityLimits,
    shortcut_waypoints,
    smooth_path,
)
from realitygap.core.geometry import wrap_angle

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class ClassicalNavConfig:
    """Settings of the classical pipeline (SI units)."""

    inflation_radius: float = 0.25
    """Obstacle inflation for planning: robot radius plus a margin (m)."""
    stabilise_radius: float = 0.20
    """Switch from path tracking to point stabilisation within this distance of the goal (m)."""
    align_tolerance: float = math.radians(10.0)
    """Heading error (rad) below which the initial turn-in-place ends."""
    replan_tracking_error: float = 0.20
    """Re-plan when the robot is this far from its reference (m)."""
    path_clearance: float = 0.22
    """Re-plan when a newly seen obstacle point is this close to the remaining path (m)."""
    memory_resolution: float = 0.05
    """Obstacle memory cell size (m); one point is kept per cell."""
    replan_interval: float = 1.0
    """Minimum time between re-plans triggered by new obstacles (s)."""
    speed_fraction: float = 0.8
    """Fraction of the velocity limits the reference may use."""
    acceleration_fraction: float = 0.5
    """Fraction of the base's acceleration limits the policy uses: gentle acceleration keeps
    the wheels from slipping, which wheel odometry cannot see."""
    done_pos_tol: float = 0.002
    done_ang_tol: float = math.radians(0.3)
    settle_timeout: float = 10.0
    """Time (s) the point stabiliser may take; if by then the robot is within
    ``settle_radius`` it finishes by turning in place onto the goal heading (a robot
    whose drive differs from its model can limit-cycle around a millimetre goal)."""
    settle_radius: float = 0.015
    ramp_commands: bool = True
    """Ramp each command from the last applied one within the acceleration limits above.
    ``False`` returns the command the pipeline asks for, only saturated to the velocity
    limits (the base's firmware still limits acceleration): the label a learned policy
    imitates (:mod:`realitygap.baselines.imitation`)."""
    reference_lead: float | None = None
    """``None``: the path reference runs on the clock (time since tracking began). A number
    (s): the reference is the path point nearest to the robot, advanced by this lead time,
    and the robot re-plans when it is ``replan_tracking_error`` away from the path — the
    command is then a function of where the robot is, not of how long it has driven, which
    is what an expert must be when another policy drives (DAgger)."""
    brake_before_replan: bool = True
    """Stop before planning from a new pose (a plan starts from standstill)."""
    sticky_final: bool = True
    """Once turning onto the goal heading (``align_final``) or ``done``, stay there. ``False``
    leaves these phases again when the robot is out of their region (another policy
    drives)."""
    apf: APFParams = field(default_factory=lambda: APFParams(inflation_radius=0.25, max_escapes=8))


@dataclass
class _EpisodeState:
    memory: dict[tuple[int, int], tuple[float, float]] = field(default_factory=dict)
    new_points: list[tuple[float, float]] = field(default_factory=list)
    goal: FloatArray | None = None
    phase: str = "plan"
    reference: TimedReference | None = None
    path_tree: cKDTree | None = None
    t_ref: float = 0.0
    t: float = 0.0
    last_replan: float = -1e9
    path_heading: float = 0.0
    plans: int = 0
    stuck_events: int = 0
    gave_up: int = 0
    failed_smoothing: int = 0
    t_stabilise: float = 0.0


class ClassicalNavPolicy(PerEnvPolicy):
    """SB3-compatible classical policy for ``realitygap/WheeledNav-v0``.

    Parameters
    ----------
    scan_angles : (n,) beam bearings in the base frame (rad), as in the observation.
    scan_range_max : range (m) of a scan value of 1.
    limits : velocity and acceleration limits of the base.
    dt : control period (s).
    config : pipeline settings.

    Use :meth:`from_env` to read all of these from an environment.
    """

    def __init__(
        self,
        scan_angles: npt.ArrayLike,
        scan_range_max: float,
        limits: VelocityLimits,
        dt: float,
        config: ClassicalNavConfig | None = None,
    ):
        self.scan_angles = np.asarray(scan_angles, dtype=float)
        self.scan_cos, self.scan_sin = np.cos(self.scan_angles), np.sin(self.scan_angles)
        self.scan_range_max = float(scan_range_max)
        self.limits = limits
        self.dt = float(dt)
        self.config = config or ClassicalNavConfig()
        self.apf = ImprovedAPF(self.config.apf)
        self.tracker = KanayamaTracker()
        self._stabilisers: dict[int, PolarStabiliser] = {}
        self._states: dict[int, _EpisodeState] = {}
        self.n_obs = 12 + len(self.scan_angles)
        self.obs_what = f"WheeledNav-v0 with a scan of {len(self.scan_angles)} beams"

    @classmethod
    def from_env(cls, env: Any, config: ClassicalNavConfig | None = None) -> ClassicalNavPolicy:
        """Build the policy for a (possibly wrapped) WheeledNav env, with its nominal limits."""
        base = env.unwrapped
        p = base.params
        cfg = config or ClassicalNavConfig()
        limits = VelocityLimits(
            v_max=p.v_max,
            w_max=p.w_max,
            a_max=p.a_max * cfg.acceleration_fraction,
            alpha_max=p.alpha_max * cfg.acceleration_fraction,
        )
        return cls(base.scan_angles, base.scan_range_max, limits, base.dt, cfg)

    # ------------------------------------------------------------------ SB3 interface
    def reset(self, env_index: int | None = None) -> None:
        """Forget the episode state of one env (or of all)."""
        if env_index is None:
            self._states.clear()
            self._stabilisers.clear()
        else:
            self._states.pop(env_index, None)
            self._stabilisers.pop(env_index, None)

    def episode_stats(self, env_index: int = 0) -> dict[str, Any]:
        """Planner statistics of the current episode (plans, APF dead-ends, give-ups, phase)."""
        st = self._states.get(env_index, _EpisodeState())
        return {
            "plans": st.plans,
            "apf_stuck_events": st.stuck_events,
            "apf_gave_up": st.gave_up,
            "smoothing_failures": st.failed_smoothing,
            "phase": st.phase,
        }

    def is_done(self, env_index: int = 0) -> bool:
        """Whether the policy has settled on the goal (by its own estimate)."""
        st = self._states.get(env_index)
        return st is not None and st.phase == "done"

    def carrot(
        self, pose: npt.ArrayLike, lookahead: float, env_index: int = 0
    ) -> FloatArray | None:
        """The point ``lookahead`` m along the current path beyond the path point nearest to
        ``pose``, as ``[x, y, heading]``; ``None`` when there is no path to follow (no plan
        yet, a failed one, or the final phases on the goal)."""
        st = self._states.get(env_index)
        if (
            st is None
            or st.reference is None
            or st.path_tree is None
            or st.phase in ("stabilise", "align_final", "done")
        ):
            return None
        p = np.asarray(pose, dtype=float)
        nearest = int(st.path_tree.query(p[:2])[1])
        s = float(st.reference.path.s[nearest]) + float(lookahead)
        return st.reference.sample_at_s(s).pose.copy()

    @staticmethod
    def expert_config(**overrides: Any) -> ClassicalNavConfig:
        """Settings that make the command a function of the state another policy drives the
        robot into — the expert of :mod:`realitygap.baselines.imitation`:

        - no acceleration ramp of its own: a ramped command is "the last command plus a small
          step", which a network cannot copy from standstill; the base's firmware limits
          acceleration anyway;
        - the path reference is the nearest path point plus a 0.3 s lead, not a point that runs
          on the clock (which would run away from a slower driver and make it re-plan);
        - no braking to a stop before a re-plan (an all-zero command means "stop here");
        - docking a smooth network can follow: within 2 cm of the goal it turns in place onto
          the goal heading at once, stops within 1.5 cm and 2.5° (inside the env's 3 cm and
          5°) and leaves these final phases when the robot leaves their region.
        """
        settings: dict[str, Any] = {
            "ramp_commands": False,
            "reference_lead": 0.3,
            "brake_before_replan": False,
            "sticky_final": False,
            "done_pos_tol": 0.015,
            "done_ang_tol": math.radians(2.5),
            "settle_timeout": 0.0,
            "settle_radius": 0.02,
            **overrides,
        }
        return ClassicalNavConfig(**settings)

    # ------------------------------------------------------------------ internals
    def act(self, i: int, obs: FloatArray) -> FloatArray:
        """The action of env ``i`` for its observation row (see :class:`PerEnvPolicy`)."""
        pose = np.array([obs[0], obs[1], math.atan2(obs[3], obs[2])])
        goal = np.array([obs[4], obs[5], math.atan2(obs[7], obs[6])])
        v_prev, w_prev = obs[10] * self.limits.v_max, obs[11] * self.limits.w_max
        st = self._states.get(i)
        if st is None or st.goal is None or np.any(np.abs(st.goal - goal) > 1e-6):
            self.reset(i)
            st = self._states[i] = _EpisodeState(goal=goal)
            self._stabilisers[i] = PolarStabiliser(limits=self.limits)
        st.t += self.dt
        self._remember(st, pose, obs[12:])
        v, w = self._control(i, st, pose, goal, v_prev)
        if self.config.ramp_commands:
            v, w = self.limits.clip(v, w, v_prev, w_prev, self.dt)
        else:
            v, w = self.limits.saturate(v, w)
        return np.array([v / self.limits.v_max, w / self.limits.w_max])

    def _remember(self, st: _EpisodeState, pose: FloatArray, scan: FloatArray) -> None:
        hit = scan < 0.999
        if not np.any(hit):
            return
        r = scan[hit] * self.scan_range_max
        c, s = math.cos(pose[2]), math.sin(pose[2])
        bx, by = r * self.scan_cos[hit], r * self.scan_sin[hit]
        xs, ys = pose[0] + c * bx - s * by, pose[1] + s * bx + c * by
        res = self.config.memory_resolution
        for x, y in zip(xs.tolist(), ys.tolist()):
            key = (int(math.floor(x / res)), int(math.floor(y / res)))
            if key not in st.memory:
                st.memory[key] = (x, y)
                st.new_points.append((x, y))

    def _obstacles(self, st: _EpisodeState) -> FloatArray:
        if not st.memory:
            return np.zeros((0, 2))
        return np.array(list(st.memory.values()), dtype=float)

    def _plan(self, st: _EpisodeState, pose: FloatArray, goal: FloatArray) -> bool:
        st.plans += 1
        st.last_replan = st.t
        st.new_points.clear()
        obstacles = self._obstacles(st)
        result = self.apf.plan(pose[:2], goal[:2], obstacles)
        st.stuck_events += result.stuck_events
        if not result.reached:
            st.gave_up += 1
            st.reference = None
            return False
        waypoints = shortcut_waypoints(
            result.waypoints, obstacles, self.config.apf.inflation_radius
        )
        if len(waypoints) < 2 or np.hypot(*(waypoints[-1] - waypoints[0])) < 1e-3:
            st.reference = None
            return False
        first = waypoints[min(1, len(waypoints) - 1)] - waypoints[0]
        st.path_heading = math.atan2(first[1], first[0])
        path = smooth_path(waypoints, st.path_heading, None)
        if not path.feasible:
            st.failed_smoothing += 1
        st.reference = TimedReference(path, self.limits, speed_fraction=self.config.speed_fraction)
        st.path_tree = cKDTree(path.xy)
        st.t_ref = 0.0
        st.phase = "align"
        return True

    def _needs_replan(self, st: _EpisodeState, pose: FloatArray) -> bool:
        if st.reference is None:
            return st.t - st.last_replan >= self.config.replan_interval or st.plans == 0
        sample = st.reference.sample(st.t_ref)
        if self.config.reference_lead is not None and st.path_tree is not None:
            off_path = float(st.path_tree.query(pose[:2])[0])
        else:
            off_path = math.hypot(*(sample.pose[:2] - pose[:2]))
        if off_path > self.config.replan_tracking_error:
            return True
        if st.new_points and st.t - st.last_replan >= 0.25 and st.path_tree is not None:
            d, idx = st.path_tree.query(np.asarray(st.new_points))
            s_now = sample.s
            ahead = st.reference.path.s[idx] >= s_now - 0.05
            st.new_points.clear()
            return bool(np.any(ahead & (d < self.config.path_clearance)))
        return False

    def _control(
        self, i: int, st: _EpisodeState, pose: FloatArray, goal: FloatArray, v_prev: float
    ) -> tuple[float, float]:
        stab = self._stabilisers[i]
        dist = math.hypot(goal[0] - pose[0], goal[1] - pose[1])
        if not self.config.sticky_final and st.phase in ("align_final", "done"):
            inside = dist <= 2.0 * self.config.settle_radius
            if st.phase == "done":
                inside = stab.done(pose, goal, self.config.done_pos_tol, self.config.done_ang_tol)
            if not inside:
                st.phase = "stabilise"
        if st.phase == "align_final":
            heading_err = abs(float(wrap_angle(goal[2] - pose[2])))
            if heading_err <= self.config.done_ang_tol:
                st.phase = "done"
                return 0.0, 0.0
            return stab.command(pose, np.array([pose[0], pose[1], goal[2]]))
        if st.phase in ("stabilise", "done") or dist < self.config.stabilise_radius:
            if st.phase not in ("stabilise", "done"):
                stab.reset()
                st.t_stabilise = st.t
            if st.phase == "done":
                return 0.0, 0.0
            st.phase = "stabilise"
            if stab.done(pose, goal, self.config.done_pos_tol, self.config.done_ang_tol):
                st.phase = "done"
                return 0.0, 0.0
            if (
                st.t - st.t_stabilise > self.config.settle_timeout
                and dist < self.config.settle_radius
            ):
                st.phase = "align_final"
                stab.reset()
            return stab.command(pose, goal)
        if self._needs_replan(st, pose):
            if self.config.brake_before_replan and abs(v_prev) > 0.05:
                # brake before planning from a new heading
                return 0.0, 0.0
            if not self._plan(st, pose, goal):
                return 0.0, 0.0
        if st.reference is None:  # the last plan failed: wait still until the next attempt
            return 0.0, 0.0
        if st.phase == "align":
            err = float(wrap_angle(st.path_heading - pose[2]))
            if abs(err) > self.config.align_tolerance:
                return stab.command(pose, np.array([pose[0], pose[1], st.path_heading]))
            st.phase = "track"
            st.t_ref = 0.0
        if self.config.reference_lead is not None and st.path_tree is not None:
            nearest = int(st.path_tree.query(pose[:2])[1])
            st.t_ref = float(st.reference.t[nearest]) + self.config.reference_lead
        else:
            st.t_ref += self.dt
        ref = st.reference.sample(st.t_ref)
        if st.t_ref >= st.reference.duration:
            st.phase = "stabilise"
            stab.reset()
            return stab.command(pose, goal)
        return self.tracker.command(pose, ref.pose, ref.v, ref.w)
