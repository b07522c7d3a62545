"""``realitygap/WallClimb-v0``: an adsorption climber drives to a goal point on an 8 m blade.

The robot (:mod:`realitygap.robots.climber`) climbs the suction side of a blade pitched
tip-up, held by an adsorption force; it carries an IMU, a down-looking camera and a
tether to a fixed anchor. The policy sees the estimator's output only; ``info`` carries
ground truth, reward terms and every detected anomaly.

Action space — ``Box(-1, 1, (2,), float32)``: ``v = a0 · v_max`` (m/s),
``ω = a1 · w_max`` (rad/s); the firmware limits acceleration and maps the twist to
wheel speeds with the nominal geometry.

Observation space — ``Box(float32, (18,))`` (world = CAD frame, z up, m)

=========  ==============================================================
idx        meaning
=========  ==============================================================
0–2        estimated body position
3–5        estimated body x-axis (heading, unit vector)
6–8        estimated body z-axis (surface normal, unit vector)
9–11       goal position
12, 13     goal in the estimated body frame, x and y
14         last tether reading, m
15, 16     last applied command v / v_max, ω / w_max
17         1 when the estimate is usable (estimator ``ok``), else 0
=========  ==============================================================

Observation pipelines (``estimator=``):

* ``"docked"`` (default, fast enough for RL): each episode starts from a docking pose
  known to the accuracy of the global initialisation (σ = 1 cm, 0.03 rad yaw); the VIO
  is initialised from one second of still IMU data, then :class:`.SlidingWindowVIO`
  (geometric camera mode) feeds :class:`.ConstrainedEstimator` (tether + adsorption
  constraints) — :class:`DockedClimbPipeline`;
* ``"localiser"``: the full :class:`.ClimbLocaliser` (static init → excitation path →
  Algorithm 1 → constrained tracking); until the global initialisation succeeds the
  estimate is in the VIO frame and ``ok`` is 0. ``info["anchor_observable"]`` is
  False when the excitation path did not suffice (status ``init_degraded``);
* any object with ``reset(initial=None)`` and ``update(measurement)`` returning a
  :class:`.ClimbEstimate`.

Bad input is detected and reported, never raised: tether slack / jumps / invalid
readings (``info["estimator_flags"]``), lost visual tracking (``info["visual_ok"]``),
the robot leaving the surface (``info["detached"]``, terminates the episode), a
non-finite estimate (replaced by the last finite one, ``info["estimate_ok"] = False``).

Reward — named sum (``info["reward_terms"]``): progress towards the goal (true
distance), a time cost, an effort cost, a detachment penalty and a success bonus
(within ``success_tol`` m), weighted by :class:`.WallClimbRewardWeights`. Start and goal
sampling, reward, success and termination live in :class:`.WallClimbTask`; the env
composes the robot, the task and the observation pipeline.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from realitygap.core.checks import check_choice, check_finite_float
from realitygap.core.geometry import quat_xyzw_from_matrix, so3_exp
from realitygap.envs.common import (
    ESTIMATOR_METHODS,
    ESTIMATOR_PROTOCOL,
    check_estimator,
    check_instance,
    check_open,
    check_rates,
    check_reality,
    check_render_mode,
    check_reset_options,
    check_seed,
    check_started,
    check_twist_action,
    release_freed_memory,
)
from realitygap.envs.tasks.wall_climb import WallClimbRewardWeights, WallClimbTask
from realitygap.estimators.climb import (
    ClimbEstimate,
    ClimbLocaliser,
    ConstrainedConfig,
    ConstrainedEstimator,
    LocaliserConfig,
    LocaliserPhase,
    SlidingWindowVIO,
    StaticInit,
    SurfaceModel,
    TetherReading,
    VioConfig,
    static_initialise,
)
from realitygap.robots.climber import (
    BodyState,
    ClimberParams,
    ClimberRobot,
    ClimbFaults,
    ClimbWorld,
    chart_pose,
)
from realitygap.robots.climber_sensors import (
    CameraModel,
    ImuModel,
    TetherModel,
    calibrated_measurement,
)
from realitygap.robots.diffdrive import FirmwareLimits
from realitygap.robots.effects import Reality
from realitygap.robots.sensors import SensorMode, check_sensor_mode

FloatArray = npt.NDArray[np.float64]

__all__ = ["DockedClimbPipeline", "DockedStart", "WallClimbEnv"]


@dataclass(frozen=True, eq=False)
class DockedStart:
    """Initial state of :class:`DockedClimbPipeline`.

    Attributes
    ----------
    static
        VIO static initialisation (from still IMU data).
    pose
        Body pose in the CAD frame at ``static.t`` (``frame="cad"``).
    cov : (6, 6)
        Its covariance (position m², attitude rad²).
    """

    static: StaticInit
    pose: ClimbEstimate
    cov: FloatArray


class DockedClimbPipeline:
    """VIO → adsorption-constrained tracking from a known docking pose.

    The tracking phase of :class:`.ClimbLocaliser` without the excitation path: the
    global pose is given by :class:`DockedStart`; VIO keyframes and tether readings
    update :class:`.ConstrainedEstimator`, and between keyframes the constrained pose is
    carried forward by the VIO's IMU-rate motion.

    Parameters
    ----------
    surface
        CAD surface model (world = CAD frame).
    anchor_cad : (3,)
        Nominal anchor, m.
    h
        Nominal height above the surface of the wheel centres (see
        :class:`.ConstrainedConfig` ``wheel_track``), m.
    vio_config, config
        :class:`.VioConfig`, :class:`.ConstrainedConfig`.
    """

    def __init__(
        self,
        surface: SurfaceModel,
        anchor_cad: npt.ArrayLike,
        h: float,
        *,
        vio_config: VioConfig | None = None,
        config: ConstrainedConfig | None = None,
    ) -> None:
        self.vio = SlidingWindowVIO(vio_config)
        self.backend = ConstrainedEstimator(surface, anchor_cad, h, config)
        self._last: ClimbEstimate | None = None
        self._kf_last: ClimbEstimate | None = None
        self._backend_last: ClimbEstimate | None = None
        self._kf_count = 0
        self._rotations_of: tuple[ClimbEstimate, ClimbEstimate] | None = None
        self._rotations = (np.eye(3), np.eye(3))

    def reset(self, initial: DockedStart | None = None) -> ClimbEstimate:
        """Start from ``initial`` (required)."""
        if not isinstance(initial, DockedStart):
            raise ValueError(
                "DockedClimbPipeline.reset needs a DockedStart (static IMU init + docking pose), "
                f"got {type(initial).__name__}"
            )
        self.vio.reset(initial.static)
        self._kf_count = self.vio.keyframe_count
        self._kf_last = self.vio.keyframe_estimate()
        self.backend.reset(initial.pose, initial.cov)
        self._backend_last = self.backend.update(self._kf_last)
        self._last = self._backend_last
        return self._last

    def update(self, measurement: Any) -> ClimbEstimate:
        """Consume one measurement (or ``None``); returns the CAD-frame estimate."""
        if self._last is None:
            raise RuntimeError("call reset(DockedStart(...)) before update()")
        if measurement is None:
            return self._last
        if isinstance(measurement, TetherReading):
            self._backend_last = self.backend.update(measurement)
            self._last = self._backend_last
            return self._last
        vio_now = self.vio.update(measurement)
        if self.vio.keyframe_count != self._kf_count:
            self._kf_count = self.vio.keyframe_count
            self._kf_last = self.vio.keyframe_estimate()
            self._backend_last = self.backend.update(self._kf_last)
            self._last = self._backend_last
            return self._last
        kf, c = self._kf_last, self._backend_last
        assert kf is not None and c is not None
        key = self._rotations_of
        if key is None or key[0] is not kf or key[1] is not c:
            # rotation matrices of the keyframe pair, converted once per keyframe
            self._rotations = (kf.rotation, c.rotation)
            self._rotations_of = (kf, c)
        R_kf, R_c = self._rotations
        dR = R_kf.T @ vio_now.rotation
        dp = R_kf.T @ (vio_now.position - kf.position)
        self._last = dataclasses.replace(
            c,
            t=vio_now.t,
            position=c.position + R_c @ dp,
            quat_xyzw=quat_xyzw_from_matrix(R_c @ dR),
            velocity=R_c @ R_kf.T @ vio_now.velocity,
        )
        return self._last


ESTIMATOR_NAMES = ("docked", "localiser")
"""The built-in observation pipelines ``estimator=`` may name."""


_ENV_ID = "realitygap/WallClimb-v0"
"""The id the env is registered under (named in its state errors)."""


class WallClimbEnv(gym.Env[npt.NDArray[np.float32], npt.NDArray[np.float32]]):
    """Reach a goal point on the blade; see the module docstring for the spaces.

    Parameters
    ----------
    render_mode
        ``None`` or ``"rgb_array"``.
    sensor_mode
        ``"fast"`` (geometric camera) or ``"image"`` (TinyRenderer frames).
    estimator
        ``"docked"``, ``"localiser"`` or an estimator object (see module docstring).
    params
        Nominal robot and blade (what the estimator believes).
    reality
        Effects that make the simulated robot differ from ``params``: a :class:`Reality`,
        its dict form (:meth:`Reality.from_dict`) or a reality file's path (a diagnosis's
        ``--export``).
    estimator_reality
        Effects the robot's sensor drivers and default estimator are calibrated to (same
        forms as ``reality``; e.g. a diagnosis's twin): tether readings are turned back into
        distances and the constant IMU biases removed under the sensor model of
        ``estimator_reality.apply_params(params)``
        (:func:`~realitygap.robots.climber_sensors.calibrated_measurement`), and the
        estimator uses its anchor.
    faults
        :class:`.ClimbFaults` (bad-input injection).
    start, goal
        Fixed chart points ``(x [m], ξ)`` on the suction side (start also takes a
        heading ``(x, ξ, heading [rad])``); random when ``None``.
    success_tol
        m.
    physics_hz, control_hz
        Hz; the ratio must be even (IMU at half the physics rate by default).
    detach_margin
        Height above the rolling height beyond which the robot counts as detached, m.
    reward_weights
        Weights of the reward terms (:class:`.WallClimbRewardWeights` defaults when ``None``).
    vio_config
        VIO settings; default: the robot's noise and camera mount with a 5-keyframe
        window and 3 solver iterations (the cost of RL rollouts is dominated by the
        window solve; on the ``climb003`` paths the accuracy is unchanged).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}  # noqa: RUF012 (gymnasium's name)
    sensor_modes: tuple[SensorMode, ...] = (SensorMode.FAST, SensorMode.IMAGE)
    """Accepted ``sensor_mode`` values, fastest first."""

    closed: bool = False
    """True once :meth:`close` ran (reset, step and render then refuse)."""

    def __init__(
        self,
        render_mode: str | None = None,
        sensor_mode: str | SensorMode = SensorMode.FAST,
        estimator: str | Any = "docked",
        params: ClimberParams | None = None,
        reality: Reality | Mapping[str, Any] | str | os.PathLike[str] | None = None,
        estimator_reality: Reality | Mapping[str, Any] | str | os.PathLike[str] | None = None,
        faults: ClimbFaults | None = None,
        start: npt.ArrayLike | None = None,
        goal: npt.ArrayLike | None = None,
        success_tol: float = 0.05,
        physics_hz: float = 240.0,
        control_hz: float = 20.0,
        detach_margin: float = 0.03,
        vio_config: VioConfig | None = None,
        reward_weights: WallClimbRewardWeights | None = None,
    ) -> None:
        render_mode = check_render_mode(render_mode, self.metadata["render_modes"])
        self.sensor_mode = check_sensor_mode(sensor_mode, self.sensor_modes)
        physics_hz, control_hz, ratio = check_rates(physics_hz, control_hz)
        success_tol = check_finite_float(
            success_tol, "success_tol", low=0.0, high=1.0, strict_low=True, unit="m"
        )
        detach_margin = check_finite_float(
            detach_margin, "detach_margin", low=0.0, high=0.5, strict_low=True, unit="m"
        )
        faults = check_instance(faults, "faults", ClimbFaults, default=ClimbFaults)
        reality = check_reality(reality, "climber")
        reward_weights = check_instance(
            reward_weights, "reward_weights", WallClimbRewardWeights, default=WallClimbRewardWeights
        )
        vio_config = check_instance(vio_config, "vio_config", VioConfig, optional=True)
        params = check_instance(params, "params", ClimberParams, default=ClimberParams)
        if isinstance(estimator, str):
            check_choice(estimator, "estimator", ESTIMATOR_NAMES)
        else:
            check_estimator(
                estimator,
                ESTIMATOR_METHODS,
                protocol=f"{ESTIMATOR_PROTOCOL}; or a name: {', '.join(ESTIMATOR_NAMES)}",
            )
        self.render_mode = render_mode
        self.params = params
        self.reality = reality
        self.true_params: ClimberParams = self.reality.apply_params(self.params)
        self.believed_params: ClimberParams | None = None
        if estimator_reality is not None:
            if not isinstance(estimator, str):
                raise ValueError(
                    "estimator_reality calibrates the default estimators, but estimator is a "
                    "plug-in. Fix: pass estimator='docked' or 'localiser', or drop "
                    "estimator_reality"
                )
            believed = check_reality(estimator_reality, "climber", name="estimator_reality")
            self.believed_params = believed.apply_params(self.params)
        self.faults = faults
        self.task = WallClimbTask(
            blade_length=self.params.blade.length,
            start=start,
            goal=goal,
            success_tol=success_tol,
            detach_margin=detach_margin,
            weights=reward_weights,
        )
        imu_every = physics_hz / self.params.imu_rate
        if abs(imu_every - round(imu_every)) > 1e-9:
            raise ValueError(
                f"physics_hz / imu_rate must be whole, got {physics_hz} / {self.params.imu_rate}"
            )
        self._imu_every = int(round(imu_every))
        cam_every = control_hz / self.params.camera_rate
        if abs(cam_every - round(cam_every)) > 1e-9 or cam_every < 1:
            raise ValueError(
                f"control_hz / camera_rate must be a whole number ≥ 1, got {control_hz} / "
                f"{self.params.camera_rate}"
            )
        self._cam_every = int(round(cam_every))

        textured = self.sensor_mode is SensorMode.IMAGE or render_mode == "rgb_array"
        self.scene = ClimbWorld(
            self.true_params,
            physics_hz=physics_hz,
            n_substeps=ratio,
            textured=textured,
        )
        self.robot = ClimberRobot(self.scene, self.true_params)
        pts, nrm = self.params.cad_cloud(0.02)
        self.cad_surface = SurfaceModel(pts, nrm)
        self.vio_config = (
            vio_config
            if vio_config is not None
            else self.params.vio_config(window_size=5, max_iterations=3)
        )
        self.estimator_kind = estimator if isinstance(estimator, str) else "custom"
        self.estimator: Any = self._make_estimator(estimator)

        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        big = 30.0
        low = np.full(18, -big, dtype=np.float32)
        high = np.full(18, big, dtype=np.float32)
        low[3:9], high[3:9] = -1.0, 1.0
        low[14], high[14] = 0.0, big
        low[15:17], high[15:17] = -1.0, 1.0
        low[17], high[17] = 0.0, 1.0
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self._obs_low, self._obs_high = low, high

        self._t = 0.0
        self._steps = 0
        self._cmd = np.zeros(2)
        self._firmware = FirmwareLimits(a_max=0.5, alpha_max=2.0)
        """The firmware's acceleration limits (m/s², rad/s²); the speeds are the action's."""
        self._goal = np.zeros(3)
        self._estimate: ClimbEstimate | None = None
        self._good_estimate: ClimbEstimate | None = None
        self._state: BodyState | None = None
        self._tether_len = 0.0
        self._visual_ok = True
        self._flags: dict[str, int] = {}

    # ------------------------------------------------------------------ helpers
    def _make_estimator(self, estimator: str | Any) -> Any:
        nominal = self.params
        anchor = (
            nominal.anchor_world
            if self.believed_params is None
            else self.believed_params.anchor_world_true
        )
        if estimator == "docked":
            return DockedClimbPipeline(
                self.cad_surface,
                anchor,
                nominal.h,
                vio_config=self.vio_config,
                config=nominal.constrained_config(),
            )
        if estimator == "localiser":
            return ClimbLocaliser(
                self.cad_surface,
                anchor,
                nominal.h,
                vio_config=self.vio_config,
                config=nominal.constrained_config(),
                localiser_config=LocaliserConfig(init_path_length=2.0, init_max_path_length=6.0),
            )
        return estimator  # a plug-in, checked by the constructor

    @property
    def dt(self) -> float:
        """Control period, s."""
        return self.scene.world.dt

    @property
    def v_max(self) -> float:
        return self.params.v_max

    @property
    def w_max(self) -> float:
        return self.params.w_max

    @property
    def goal(self) -> FloatArray:
        """Goal position (world), m."""
        return self._goal.copy()

    # ------------------------------------------------------------------ gym API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[npt.NDArray[np.float32], dict[str, Any]]:
        """Start an episode; ``options`` may hold ``start`` ``(x, ξ[, heading])`` and ``goal`` ``(x, ξ)``."""
        check_open(self, "reset", _ENV_ID)
        super().reset(seed=check_seed(seed))
        options = check_reset_options(options, ("start", "goal"), "WallClimb-v0")
        rng = self.np_random
        start, goal = self.task.sample_start_goal(rng, options)
        tp = self.true_params
        surf = self.scene.surface
        heading = float(start[2]) if len(start) == 3 else 0.0
        pos, R = chart_pose(surf, tp, float(start[0]), float(start[1]), heading, tp.h_true)
        self._goal = chart_pose(surf, tp, float(goal[0]), float(goal[1]), 0.0, 0.0)[0]
        # a fresh body each episode: no contact manifolds or solver warm starts carried
        # over from the previous episode, so a seeded episode is exactly repeatable
        self.robot.remove()
        self.robot = ClimberRobot(self.scene, tp)
        self.robot.reset(pos, R)
        self.robot.adsorption_scale = 1.0
        self._imu = ImuModel(tp, rng)
        self._tether = TetherModel(tp, rng, self.faults)
        self._camera = CameraModel(self.robot, tp, self.sensor_mode, rng, self.faults)
        self._flags = {}
        # one second standing still before the episode (VIO static initialisation)
        n_static = int(round(tp.imu_rate))
        still = self._calibrated(self._imu.at_rest(R, 0.0, n_static))
        self._t0 = n_static / tp.imu_rate
        self._t, self._steps = self._t0, 0
        self._cmd = np.zeros(2)
        self._state = self.robot.state(self._t)
        self._state_prev_imu = self._state
        self._tether_len = self._calibrated(
            [self._tether.read(self._t, pos, 1.0 / tp.camera_rate)]
        )[0].length
        self._visual_ok = True
        if self.estimator_kind == "docked":
            static = static_initialise(still, gravity=self.vio_config.gravity)
            static = dataclasses.replace(static, t=self._t)
            cfg = LocaliserConfig()
            p_err = rng.normal(0, cfg.init_position_sigma, 3)
            R_err = so3_exp(np.array([0.0, 0.0, rng.normal(0, cfg.init_yaw_sigma)]))
            start_est = ClimbEstimate(
                t=self._t,
                position=pos + p_err,
                quat_xyzw=quat_xyzw_from_matrix(R_err @ R),
                frame="cad",
            )
            cov = np.diag(
                [cfg.init_position_sigma**2] * 3
                + [cfg.init_tilt_sigma**2] * 2
                + [cfg.init_yaw_sigma**2]
            )
            est = self.estimator.reset(DockedStart(static, start_est, cov))
        else:
            est = self.estimator.reset()
            for m in still:
                est = self.estimator.update(m)
        self._camera.capture(self._state, tp.h_true)
        self._set_estimate(est)
        self.task.reset(self._true_distance())
        info = self._info({}, detached=False, success=False)
        return self._observation(), info

    def step(
        self, action: npt.ArrayLike
    ) -> tuple[npt.NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        if self._state is None:
            check_open(self, "step", _ENV_ID)
            check_started(self, False, _ENV_ID)
        a0, a1 = check_twist_action(action)
        prm = self.params
        v, w = self._firmware.limit(
            a0 * prm.v_max, a1 * prm.w_max, self._cmd[0], self._cmd[1], self.dt
        )
        self._cmd[:] = (v, w)
        self.robot.set_twist(v, w, prm)
        measurements = self._simulate()
        for m in measurements:
            self._set_estimate(self.estimator.update(m))
        self._steps += 1
        task = self.task
        detached = task.is_detached(self.robot.last_height, self.true_params.h_true)
        dist = self._true_distance()
        success = task.is_success(dist, detached)
        reward, terms = task.get_reward(dist, (a0, a1), detached, success)
        obs = self._observation()
        terminated = bool(task.is_terminated(detached, success))
        return obs, reward, terminated, False, self._info(terms, detached, success)

    def _simulate(self) -> list[Any]:
        """One control period of physics; returns the measurements in time order."""
        w = self.scene.world
        out: list[Any] = []
        dtp = w.physics_dt
        t0 = time_start = self._t
        apply_adsorption = self.robot.apply_adsorption
        done = 0
        for k in range(self._imu_every - 1, w.n_substeps, self._imu_every):
            w.step(k + 1 - done, before_each=apply_adsorption)
            done = k + 1
            t = time_start + (k + 1) * dtp
            s = self.robot.state(t)
            out.append(self._imu.sample(self._state_prev_imu, s))
            self._state_prev_imu = s
        w.step(w.n_substeps - done, before_each=apply_adsorption)
        self._t = t0 + w.n_substeps * dtp
        self._state = self._state_prev_imu
        if (self._steps + 1) % self._cam_every == 0:
            height = self.robot.height_above_surface()
            frame = self._camera.capture(self._state, height)
            if frame is not None:
                self._visual_ok = bool(getattr(frame, "ok", True))
                out.append(frame)
            reading = self._tether.read(
                self._t, self._state.position, 1.0 / self.params.camera_rate
            )
            out.append(reading)
        out = self._calibrated(out)
        if (self._steps + 1) % self._cam_every == 0:
            self._tether_len = out[-1].length
        return out

    def _calibrated(self, measurements: list[Any]) -> list[Any]:
        """``measurements`` as the drivers calibrated to ``estimator_reality`` report them
        (unchanged without one)."""
        if self.believed_params is None:
            return measurements
        return [calibrated_measurement(m, self.believed_params) for m in measurements]

    def render(self) -> npt.NDArray[np.uint8] | None:
        check_open(self, "render", _ENV_ID)
        if self.render_mode != "rgb_array" or self._state is None:
            return None
        pos = self._state.position
        n = self._state.R[:, 2]
        eye = pos + 1.2 * n + np.array([0.0, 0.0, 0.4])
        return self.scene.world.render_rgb(eye, pos, fov_deg=60.0, near=0.05, far=20.0)

    def close(self) -> None:
        self.scene.close()
        self._state = None
        self.closed = True
        release_freed_memory()

    # ------------------------------------------------------------------ internals
    def _set_estimate(self, est: ClimbEstimate) -> None:
        # a sum of finite numbers is finite (positions in m, unit quaternion)
        finite = math.isfinite(float(np.sum(est.position) + np.sum(est.quat_xyzw)))
        if finite:
            self._good_estimate = est
            self._estimate = est
        else:
            self._flags["non_finite_estimate"] = self._flags.get("non_finite_estimate", 0) + 1
            last = self._good_estimate
            if last is None:
                raise RuntimeError("the estimator returned a non-finite first estimate")
            self._estimate = dataclasses.replace(last, ok=False, status="non_finite_estimate")
        for f in self._estimate.status.split("|"):
            if f and f != "ok":
                self._flags[f] = self._flags.get(f, 0) + 1

    def _true_distance(self) -> float:
        assert self._state is not None
        return float(np.linalg.norm(self._state.position - self._goal))

    def _observation(self) -> npt.NDArray[np.float32]:
        est = self._estimate
        assert est is not None
        R = est.rotation
        rel = R.T @ (self._goal - est.position)
        obs = np.empty(18, dtype=np.float64)
        obs[0:3] = est.position
        obs[3:6] = R[:, 0]
        obs[6:9] = R[:, 2]
        obs[9:12] = self._goal
        obs[12:14] = rel[:2]
        obs[14] = self._tether_len
        obs[15] = self._cmd[0] / self.v_max
        obs[16] = self._cmd[1] / self.w_max
        obs[17] = 1.0 if est.ok else 0.0
        out = obs.astype(np.float32)
        np.clip(out, self._obs_low, self._obs_high, out=out)
        return out

    def _info(self, terms: dict[str, float], detached: bool, success: bool) -> dict[str, Any]:
        est, s = self._estimate, self._state
        assert est is not None and s is not None
        info: dict[str, Any] = {
            "true_pose": np.concatenate([s.position, quat_xyzw_from_matrix(s.R)]),
            "estimated_pose": np.concatenate([est.position, est.quat_xyzw]),
            "position_error": float(np.linalg.norm(est.position - s.position)),
            "estimate_ok": bool(est.ok),
            "estimate_status": est.status,
            "estimate_frame": est.frame,
            "estimator_flags": dict(self._flags),
            "goal": self._goal.copy(),
            "goal_distance": self._true_distance(),
            "height_above_surface": float(self.robot.last_height),
            "adsorption_force": float(self.robot.last_force),
            "tether_length": float(self._tether_len),
            "tether_true_distance": self._tether.true_distance(s.position),
            "visual_ok": self._visual_ok,
            "detached": bool(detached),
            "is_success": bool(success),
            "reward_terms": dict(terms),
            "t": self._t,
        }
        if isinstance(self.estimator, ClimbLocaliser):
            loc = self.estimator
            info["localiser_phase"] = loc.phase.value
            gi = loc.global_init
            info["global_init_status"] = None if gi is None else gi.status
            info["anchor_observable"] = (
                None
                if loc.phase is not LocaliserPhase.TRACKING
                else bool(gi is not None and gi.converged)
            )
        return info
