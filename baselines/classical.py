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

It re-plans when an obstacle point seen since the plan was made lies close to the
path ahead (it brakes first, and the request stands until the new plan is made), when
the tracking error grows too large, or when a plan failed. Where the potential field
meets a local minimum, the complete grid planner
(:func:`~realitygap.controllers.grid_shortest_path`) plans too and the shorter plan is
taken, so a way that exists in the map is found (a narrow gap the field's escape does not
pass). The smoothed path must keep ``path_clearance`` from every remembered point, or the
planner's dense way-points are smoothed instead of the shortcut ones.

The obstacle memory takes each scan once (the env repeats its last scan between scans,
and a repeated scan projected from a newer pose smears over the robot's motion) and only
returns nearer than ``mark_range`` (a depth camera's noise grows with the square of the
range). The episode is done only at rest (:func:`~realitygap.envs.tasks.nav.at_rest`): a
robot still turning when it passes the tolerance overshoots.

``realitygap run nav-stress`` measures the pipeline over hundreds of unseen layouts in both
sensor modes and classifies every failure.
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
    APFOutcome,
    APFParams,
    ImprovedAPF,
    KanayamaTracker,
    PolarStabiliser,
    SmoothPath,
    TimedReference,
    VelocityLimits,
    grid_shortest_path,
    path_length,
    shortcut_waypoints,
    smooth_path,
)
from realitygap.core.geometry import wrap_angle
from realitygap.envs.tasks.nav import at_rest

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
    mark_range: float = 4.0
    """Only returns nearer than this (m) enter the obstacle memory. A depth camera's noise
    grows with the square of the range (σ ≈ 3 cm at 4 m, 13 cm at 8 m for a Kinect v2), and
    a remembered point is never taken back: farther returns would fill the free space with
    phantom obstacles. An obstacle beyond it is marked once the robot comes within it, and
    the plan is renewed then."""
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
    grid_resolution: float = 0.05
    """Cell size (m) of the grid planner that takes over when the potential field is
    trapped."""
    apf: APFParams = field(default_factory=lambda: APFParams(inflation_radius=0.25, max_escapes=8))


@dataclass
class _EpisodeState:
    memory: dict[tuple[int, int], tuple[float, float]] = field(default_factory=dict)
    since_plan: list[tuple[float, float]] = field(default_factory=list)
    """Obstacle points first seen since the current plan was made: the plan holds only
    while none of them lies on the path ahead (each check sees them all, so a re-plan it
    asks for is not forgotten while the robot brakes for it)."""
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
    grid_plans: int = 0
    failed_smoothing: int = 0
    t_stabilise: float = 0.0
    last_outcome: str = ""
    """Why the last plan ended (:class:`~realitygap.controllers.APFOutcome` value, or
    ``"grid"`` when the grid planner's path was taken)."""
    last_scan: FloatArray | None = None
    """The scan last remembered (the env repeats a scan between scans)."""


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
            "grid_plans": st.grid_plans,
            "smoothing_failures": st.failed_smoothing,
            "phase": st.phase,
            "last_plan": st.last_outcome,
        }

    def planned_path(self, env_index: int = 0) -> FloatArray | None:
        """The smoothed path (K, 2) the policy is following (world frame, m); ``None``
        without one (no plan yet, or the last plan failed)."""
        st = self._states.get(env_index)
        if st is None or st.reference is None:
            return None
        return np.asarray(st.reference.path.xy, dtype=float).copy()

    def obstacle_memory(self, env_index: int = 0) -> FloatArray:
        """The obstacle points (M, 2) the policy remembers (world frame, m), through its
        estimated poses."""
        st = self._states.get(env_index)
        return self._obstacles(st) if st is not None else np.zeros((0, 2))

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
        v, w = self._control(i, st, pose, goal, v_prev, w_prev)
        if self.config.ramp_commands:
            v, w = self.limits.clip(v, w, v_prev, w_prev, self.dt)
        else:
            v, w = self.limits.saturate(v, w)
        return np.array([v / self.limits.v_max, w / self.limits.w_max])

    def _remember(self, st: _EpisodeState, pose: FloatArray, scan: FloatArray) -> None:
        # the env repeats its last scan between scans (scan_hz < control rate): a repeated
        # scan was taken where the robot was then, and projecting it from the pose of now
        # smears it over the robot's motion since (15 cm at 6 m after 50 ms of turning)
        if st.last_scan is not None and np.array_equal(scan, st.last_scan):
            return
        st.last_scan = scan.copy()
        hit = scan < min(0.999, self.config.mark_range / self.scan_range_max)
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
                st.since_plan.append((x, y))

    def _obstacles(self, st: _EpisodeState) -> FloatArray:
        if not st.memory:
            return np.zeros((0, 2))
        return np.array(list(st.memory.values()), dtype=float)

    def _plan(self, st: _EpisodeState, pose: FloatArray, goal: FloatArray) -> bool:
        st.plans += 1
        st.last_replan = st.t
        st.since_plan.clear()
        obstacles = self._obstacles(st)
        result = self.apf.plan(pose[:2], goal[:2], obstacles)
        st.stuck_events += result.stuck_events
        st.last_outcome = str(result.reason.value)
        raw: FloatArray | None = result.waypoints if result.reached else None
        if (result.stuck_events or not result.reached) and (
            result.reason is not APFOutcome.GOAL_BLOCKED
        ):
            # the field met a local minimum: it gave up, or escaped along an obstacle's
            # boundary, maybe the long way round. The grid planner is complete (it finds a
            # way whenever the map has one) and gives the shortest: the shorter plan is taken
            grid = grid_shortest_path(
                pose[:2],
                goal[:2],
                obstacles,
                resolution=self.config.grid_resolution,
                inflation_radius=self.config.apf.inflation_radius,
            )
            if grid is not None and (raw is None or path_length(grid) < path_length(raw)):
                raw = grid
                st.grid_plans += 1
                st.last_outcome = "grid"
        if raw is None:
            st.gave_up += 1
            st.reference = None
            return False
        chosen = self._smooth_clear_path(raw, obstacles, pose)
        if chosen is None:
            st.reference = None
            return False
        path, st.path_heading = chosen
        if not path.feasible:
            st.failed_smoothing += 1
        st.reference = TimedReference(path, self.limits, speed_fraction=self.config.speed_fraction)
        st.path_tree = cKDTree(path.xy)
        st.t_ref = 0.0
        st.phase = "align"
        return True

    def _smooth_clear_path(
        self, raw: FloatArray, obstacles: FloatArray, pose: FloatArray
    ) -> tuple[SmoothPath, float] | None:
        """The smoothed path through the planner's way-points, and its initial heading.

        The smoothing fits the way-points without seeing the obstacles, and a fit through
        a few shortcut corners cuts them. The path must keep ``path_clearance`` from every
        remembered point (or, where the robot starts nearer, its start clearance): the
        shortcut way-points are smoothed first, and where that path cuts a corner, the
        planner's dense way-points, which the fit follows closely. Of paths that both cut,
        the one with more clearance is taken. ``None`` when the way-points go nowhere.
        """
        tree = cKDTree(obstacles) if len(obstacles) else None
        start_clear = float(tree.query(pose[:2])[0]) if tree is not None else math.inf
        need = min(self.config.path_clearance, start_clear - 0.01)
        best: tuple[float, SmoothPath, float] | None = None
        for waypoints in (
            shortcut_waypoints(raw, obstacles, self.config.apf.inflation_radius),
            raw,
        ):
            if len(waypoints) < 2 or np.hypot(*(waypoints[-1] - waypoints[0])) < 1e-3:
                continue
            first = waypoints[1] - waypoints[0]
            heading = math.atan2(first[1], first[0])
            path = smooth_path(waypoints, heading, None)
            clear = float(tree.query(path.xy)[0].min()) if tree is not None else math.inf
            if best is None or clear > best[0]:
                best = (clear, path, heading)
            if clear >= need:
                break
        return None if best is None else (best[1], best[2])

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
        if st.since_plan and st.t - st.last_replan >= 0.25 and st.path_tree is not None:
            # the path from the robot's projection on, against every point seen since the plan
            d, idx = st.path_tree.query(np.asarray(st.since_plan))
            s_robot = st.reference.path.s[int(st.path_tree.query(pose[:2])[1])]
            ahead = st.reference.path.s[idx] >= min(sample.s, s_robot) - 0.05
            return bool(np.any(ahead & (d < self.config.path_clearance)))
        return False

    def _control(
        self,
        i: int,
        st: _EpisodeState,
        pose: FloatArray,
        goal: FloatArray,
        v_prev: float,
        w_prev: float,
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
            # done only at rest: a robot still turning when it passes the tolerance overshoots
            if heading_err <= self.config.done_ang_tol and at_rest(v_prev, w_prev):
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
            if stab.done(
                pose, goal, self.config.done_pos_tol, self.config.done_ang_tol
            ) and at_rest(v_prev, w_prev):
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
