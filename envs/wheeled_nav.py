"""``realitygap/WheeledNav-v0``: a Kobuki-like robot drives to a goal pose among obstacles.

The env composes the robot (:mod:`realitygap.robots`), the task (goal, reward,
termination) and an observation pipeline: sensors → estimator → observation.
The policy never sees ground truth; ``info`` carries it.

Action space — ``Box(-1, 1, (2,), float32)``

====  ===============================  =======================
idx   meaning                          maps to
====  ===============================  =======================
0     forward speed command            ``v = a0 · v_max`` (m/s)
1     turn-rate command                ``ω = a1 · ω_max`` (rad/s)
====  ===============================  =======================

The base's firmware (:meth:`~realitygap.robots.diffdrive.DiffDriveRobot.command_twist`)
limits acceleration (``a_max``, ``alpha_max``) and converts the twist to wheel
speeds with the *nominal* geometry, as a real robot does.

Observation space — ``Box(float32, (12 + n_beams,))``

=========  ==============================================================
idx        meaning (estimated quantities come from the estimator)
=========  ==============================================================
0, 1       estimated position x, y (m, world frame)
2, 3       cos θ, sin θ of the estimated heading
4, 5       goal position x, y (m, world frame)
6, 7       cos θ_goal, sin θ_goal
8, 9       goal position in the estimated robot frame (m)
10, 11     last applied command v / v_max, ω / ω_max
12 …       scan ranges / range_max over the camera's field of view (1 = free)
=========  ==============================================================

Reward — a named sum (see ``info["reward_terms"]``): progress towards the goal
position, heading alignment near the goal, a time cost, an effort cost, a
collision penalty and a success bonus. Success: within ``success_pos_tol`` (m)
and ``success_ang_tol`` (rad) of the goal pose and at rest. The task
(:class:`~realitygap.envs.tasks.nav.NavTask`) holds goal sampling, reward,
success and termination.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from realitygap.core.checks import check_finite_float, check_positive_int
from realitygap.core.jit import KERNELS, compiled
from realitygap.envs.common import (
    ESTIMATOR_METHODS,
    ESTIMATOR_PROTOCOL,
    check_estimator,
    check_instance,
    check_open,
    check_randomize,
    check_rates,
    check_reality,
    check_render_mode,
    check_reset_options,
    check_seed,
    check_started,
    check_twist_action,
    odometry_belief,
    robot_effects,
)
from realitygap.envs.tasks.nav import (
    CONTROL_HZ,
    N_BEAMS,
    N_OBSTACLES,
    ROOM_HALF_SIZE,
    SCAN_HZ,
    SUCCESS_ANG_TOL,
    SUCCESS_POS_TOL,
    NavRewardWeights,
    NavTask,
)
from realitygap.estimators.base import DiffDriveMeasurement, Estimate, Estimator, Scan
from realitygap.estimators.scan import scan_angles
from realitygap.robots.diffdrive import (
    DiffDriveParams,
    DiffDriveRobot,
    FirmwareLimits,
    encoder_ticks,
)
from realitygap.robots.effects import Reality, draw_reality
from realitygap.robots.sensors import PlanarScanner, RGBDCamera, SensorMode, check_sensor_mode
from realitygap.robots.textures import SurfaceKind
from realitygap.robots.world import Primitive, World

_FLOAT64 = np.dtype(np.float64)

MAX_BEAMS = 4096
"""Most range beams per scan an env accepts."""

FloatArray = npt.NDArray[np.float64]

NAV8_STARTS: tuple[tuple[float, float, float], ...] = (
    (0.0, -2.4, 0.0),
    (-2.4, -2.4, 0.0),
    (-2.4, 0.0, 0.0),
    (-2.4, 2.4, 0.0),
    (0.0, 2.4, 0.0),
    (2.4, 2.4, 0.0),
    (2.4, 0.0, 0.0),
    (2.4, -2.4, 0.0),
)
"""The eight start poses of seed 001's test (goal ``(0, 0, π/2)``)."""


def default_estimator(
    params: DiffDriveParams, sensor_mode: SensorMode = SensorMode.FAST
) -> Estimator:
    """The default observation pipeline for ``params`` (the robot's nominal parameters).

    Image fidelity: wheel odometry fused with RGB-D visual odometry in an EKF, plus an
    occupancy grid (:class:`~realitygap.estimators.pipelines.FusedOdometryVO`). Fast
    fidelity renders no images, so the default is wheel odometry alone.
    """
    from realitygap.estimators.diffdrive_model import DiffDriveKinematics, WheelOdometry

    kin = DiffDriveKinematics(
        wheel_radius_left=params.wheel_radius_left,
        wheel_radius_right=params.wheel_radius_right,
        wheelbase=params.wheelbase,
        ticks_per_rev=params.ticks_per_rev,
    )
    if SensorMode(sensor_mode) is SensorMode.IMAGE:
        from realitygap.estimators.pipelines import FusedOdometryVO

        return FusedOdometryVO(kin, params.camera.T_base_camera())
    return WheelOdometry(kin)


_ENV_ID = "realitygap/WheeledNav-v0"
"""The id the env is registered under (named in its state errors)."""


class WheeledNavEnv(gym.Env[npt.NDArray[np.float32], npt.NDArray[np.float32]]):
    """Differential-drive navigation to a goal pose; see the module docstring for the spaces.

    Parameters
    ----------
    render_mode : ``None`` or ``"rgb_array"`` (a view from above).
    sensor_mode : ``"fast"`` (analytic scan, no rendering) or ``"image"`` (rendered RGB-D
        frames; the scan is derived from depth).
    estimator : the observation pipeline's estimator (any object with ``reset``/``update``,
        see :class:`~realitygap.estimators.base.Estimator`); default: see
        :func:`default_estimator` (odometry + RGB-D VO fusion in image mode, wheel odometry
        in fast mode), with the nominal geometry.
    params : nominal robot parameters (what the robot is believed to be).
    reality : effects that make the simulated robot differ from ``params`` ("the real robot"):
        a :class:`~realitygap.robots.effects.Reality`, its dict form
        (:meth:`~realitygap.robots.effects.Reality.from_dict`) or the path of a reality
        file (a diagnosis's ``--export``, :mod:`~realitygap.robots.effects.twin`).
    randomize : ``{"effect.param": (low, high)}`` or a
        :class:`~realitygap.robots.effects.Twin` (its boxes): each episode's robot is
        ``reality`` with these parameters drawn uniformly from their boxes, from the
        episode's generator (domain randomisation).
    estimator_reality : effects the default estimator's model includes (same forms as
        ``reality``): the pipeline believes ``estimator_reality.apply_params(params)`` — e.g.
        a diagnosis's twin, whose fitted wheel sizes calibrate the odometry. Not with
        ``estimator``.
    n_obstacles : random obstacles per episode (0: empty room).
    obstacles : a fixed layout instead of random ones.
    room_half_size : half the side of the square room (m).
    start, goal : fixed start / goal poses ``[x, y, θ]``; random when ``None``.
    success_pos_tol, success_ang_tol : success tolerances (m, rad).
    physics_hz, control_hz : physics rate and control rate (Hz); their ratio must be whole.
        The default 240 Hz is the rate the vector env's surrogate and the diagnosis replay
        are calibrated to; 120 Hz cuts a step's physics to about 0.6 of it (``realitygap run
        bench-speed`` measures both) but is other dynamics: opt in where that is acceptable.
    n_beams : scan beams over the camera's horizontal field of view.
    scan_hz : rate of the planar scan (Hz); steps in between re-use the last scan.
    camera_hz : rate of rendered RGB-D frames in image mode (Hz), default 5 Hz (a frame every
        fourth control step). Frames are rendered only at this rate; a scan due between
        frames renders the small depth picture it needs. At 5 Hz and 320 × 240 the
        image-mode pipeline (VO key-framing, odometry fusion) keeps the classical policy's
        success of a 20 Hz camera, and an image-mode step costs about a third of one at
        20 Hz (``realitygap run bench-speed`` measures both, in one core's CPU time).
    terminate_on_success : end the episode on success (otherwise ``info["is_success"]`` is
        reported and the episode runs on, e.g. to measure where a controller settles).
    reward_weights : weights of the reward terms.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}  # noqa: RUF012 (gymnasium's name)
    sensor_modes: tuple[SensorMode, ...] = (SensorMode.FAST, SensorMode.IMAGE)
    """The sensor fidelities this env accepts, fastest first."""

    closed: bool = False
    """True once :meth:`close` ran (reset, step and render then refuse)."""

    def __init__(
        self,
        render_mode: str | None = None,
        sensor_mode: str | SensorMode = SensorMode.FAST,
        estimator: Estimator | None = None,
        params: DiffDriveParams | None = None,
        reality: Reality | Mapping[str, Any] | str | os.PathLike[str] | None = None,
        randomize: Mapping[str, Any] | None = None,
        estimator_reality: Reality | Mapping[str, Any] | str | os.PathLike[str] | None = None,
        n_obstacles: int = N_OBSTACLES,
        obstacles: list[Primitive] | None = None,
        room_half_size: float = ROOM_HALF_SIZE,
        start: npt.ArrayLike | None = None,
        goal: npt.ArrayLike | None = None,
        success_pos_tol: float = SUCCESS_POS_TOL,
        success_ang_tol: float = SUCCESS_ANG_TOL,
        physics_hz: float = 240.0,
        control_hz: float = CONTROL_HZ,
        n_beams: int = N_BEAMS,
        scan_hz: float = SCAN_HZ,
        camera_hz: float = 5.0,
        terminate_on_success: bool = True,
        reward_weights: NavRewardWeights = NavRewardWeights(),  # noqa: B008 (frozen)
    ):
        render_mode = check_render_mode(render_mode, self.metadata["render_modes"])
        self.sensor_mode = check_sensor_mode(sensor_mode, self.sensor_modes)
        physics_hz, control_hz, ratio = check_rates(physics_hz, control_hz)
        # room_half_size, n_obstacles, obstacles, start, goal, success tolerances,
        # terminate_on_success and reward_weights: checked by the task (shared with the
        # vector env)
        self.task = NavTask(
            room_half_size=room_half_size,
            n_obstacles=n_obstacles,
            obstacles=obstacles,
            start=start,
            goal=goal,
            success_pos_tol=success_pos_tol,
            success_ang_tol=success_ang_tol,
            terminate_on_success=terminate_on_success,
            weights=reward_weights,
        )
        n_beams = check_positive_int(n_beams, "n_beams", high=MAX_BEAMS)
        for rate_name, rate in (("scan_hz", scan_hz), ("camera_hz", camera_hz)):
            check_finite_float(
                rate, rate_name, low=0.0, high=control_hz, strict_low=True, unit="Hz"
            )
        params = check_instance(params, "params", DiffDriveParams, default=DiffDriveParams)
        reality = check_reality(reality, "diffdrive")
        self.randomize = check_randomize(
            randomize, robot_effects("diffdrive"), "differential drive's effects"
        )
        if estimator is not None:
            check_estimator(estimator, ESTIMATOR_METHODS, protocol=ESTIMATOR_PROTOCOL)
            if estimator_reality is not None:
                raise ValueError(
                    "estimator and estimator_reality are both given; estimator_reality builds "
                    "the default estimator. Fix: pass one of them"
                )
        believed = params
        if estimator_reality is not None:
            believed = odometry_belief(estimator_reality, params)
        self.render_mode = render_mode
        self.params = params
        self.reality = self.nominal_reality = reality
        self.true_params = self.reality.apply_params(self.params)
        self.n_beams = int(n_beams)
        self._scan_every = self._divisor("scan_hz", scan_hz, control_hz)
        self._camera_every = self._divisor("camera_hz", camera_hz, control_hz)
        self.estimator: Estimator = (
            estimator if estimator is not None else default_estimator(believed, self.sensor_mode)
        )

        # the robot applies no external forces: a control period's physics steps run in one
        # call into the engine; the scenery is static rigid bodies. Both give the physics
        # steps of one call each with multibody scenery, bit for bit, at less cost (World)
        self.world = World(
            physics_hz=physics_hz, n_substeps=ratio, fused_substeps=True, rigid_scenery=True
        )
        self.robot: DiffDriveRobot | None = None
        self.scanner: PlanarScanner | None = None
        self.camera: RGBDCamera | None = None

        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        n_obs = 12 + self.n_beams
        low = np.full(n_obs, -1.0, dtype=np.float32)
        high = np.full(n_obs, 1.0, dtype=np.float32)
        big = 4.0 * self.room_half_size
        for idx in (0, 1, 4, 5, 8, 9):
            low[idx], high[idx] = -big, big
        low[12:] = 0.0
        self.observation_space = spaces.Box(low, high, dtype=np.float32)

        self._obs_low, self._obs_high = low, high
        # episode state
        self._t = 0.0
        self._steps = 0
        self._start_pose = np.zeros(3)
        self._scan: Scan | None = None
        self._estimate: Estimate | None = None
        self._obstacles: tuple[Primitive, ...] = ()
        self._obs_out = np.zeros(12 + self.n_beams, dtype=np.float32)
        self._obs_head, self._obs_tail = self._obs_out[:12], self._obs_out[12:]
        self._obs_low_head, self._obs_high_head = low[:12].copy(), high[:12].copy()
        self._obs_scan: Scan | None = None  # the scan whose values are in _obs_out[12:]
        self._episode_consts = (self.dt, self.v_max, self.w_max)  # control period, v_max, w_max

    # ------------------------------------------------------------------ properties
    @property
    def dt(self) -> float:
        """Control period in s."""
        return self.world.dt

    @property
    def room_half_size(self) -> float:
        """Half the side of the square room (m)."""
        return self.task.room_half_size

    @property
    def success_pos_tol(self) -> float:
        """Success tolerance on the distance to the goal position (m); settable."""
        return self.task.success_pos_tol

    @success_pos_tol.setter
    def success_pos_tol(self, value: float) -> None:
        self.task.success_pos_tol = float(value)

    @property
    def success_ang_tol(self) -> float:
        """Success tolerance on the heading error (rad); settable."""
        return self.task.success_ang_tol

    @success_ang_tol.setter
    def success_ang_tol(self, value: float) -> None:
        self.task.success_ang_tol = float(value)

    @property
    def obstacles(self) -> tuple[Primitive, ...]:
        """Ground truth: the footprints of this episode's walls and obstacles (a new tuple
        per episode). A policy must not read it; privileged experts and analysis may."""
        return self._obstacles

    @property
    def scan_angles(self) -> FloatArray:
        """Bearings (rad, base frame) of the scan beams in the observation, as the robot
        believes its camera is mounted (nominal parameters)."""
        cam = self.params.camera
        return cam.mount_yaw + scan_angles(self.n_beams, math.radians(cam.hfov_deg))

    @property
    def scan_range_max(self) -> float:
        """Range (m) that a scan value of 1 in the observation stands for."""
        return self.params.camera.range_max

    @property
    def v_max(self) -> float:
        return self.params.v_max

    @property
    def w_max(self) -> float:
        return self.params.w_max

    # ------------------------------------------------------------------ gym API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[npt.NDArray[np.float32], dict[str, Any]]:
        """Start an episode. ``options`` may hold ``start`` and ``goal`` poses ``[x, y, θ]``."""
        check_open(self, "reset", _ENV_ID)
        super().reset(seed=check_seed(seed))
        options = check_reset_options(options, ("start", "goal"), "WheeledNav-v0")
        rng = self.np_random
        if self.randomize:  # this episode's robot, drawn first from the episode's generator
            self.reality = draw_reality(self.nominal_reality, self.randomize, rng)
            self.true_params = self.reality.apply_params(self.params)
        radius = self.true_params.body_radius
        start, goal = self.task.sample_start_goal(rng, options, radius)
        self._start_pose = start.copy()
        self._obstacles = self.task.sample_arena(rng, start, goal, radius)
        robot = self._build_world(rng, start)
        robot.attach_firmware(
            self.dt,
            nominal=self.params,
            limits=FirmwareLimits.from_params(self.params),
            reality=self.reality,
        )

        self._t, self._steps = 0.0, 0
        # the episode's constants, read once (the step's hot path uses them as plain floats)
        self._episode_consts = (self.dt, self.v_max, self.w_max)
        self._estimate = self.estimator.reset(start.copy())
        self._estimate = self.estimator.update(self._measure())
        pose = robot.pose2d()
        dist, ang = self.task.reset(goal, pose)
        info = self._info(pose, dist, ang, {}, collision=False, success=False)
        return self._observation(), info

    def step(
        self, action: npt.ArrayLike
    ) -> tuple[npt.NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        robot, task = self.robot, self.task  # read once: the step's hot path
        if robot is None:
            check_open(self, "step", _ENV_ID)
            check_started(self, False, _ENV_ID)
        a0, a1 = check_twist_action(action)
        dt, v_max, w_max = self._episode_consts
        robot.command_twist(a0 * v_max, a1 * w_max)
        self.world.step()
        self._steps = steps = self._steps + 1
        self._t = steps * dt

        pose = robot.pose2d()  # the true pose, read once for the scan, task and info
        self._estimate = self.estimator.update(self._measure(pose))

        dist, ang = task.pose_error(pose)
        collision = robot.in_contact_with_scenery(pose)
        success = task.is_success(dist, ang, robot)
        reward, terms = task.get_reward(dist, ang, (a0, a1), collision, success)
        return (
            self._observation(),
            reward,
            task.is_terminated(collision, success),
            False,
            self._info(pose, dist, ang, terms, collision, success),
        )

    def render(self) -> npt.NDArray[np.uint8] | None:
        check_open(self, "render", _ENV_ID)
        if self.render_mode != "rgb_array" or self.robot is None:
            return None
        x, y, _ = self.robot.pose2d()
        return self.world.render_rgb(
            [x - 2.5, y - 2.5, 4.0], [x, y, 0.0], fov_deg=60, near=0.1, far=30
        )

    def close(self) -> None:
        self.world.close()
        self.robot = None
        self.closed = True

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _divisor(name: str, rate_hz: float, control_hz: float) -> int:
        """Control steps per sensor sample; the rate must divide the control rate."""
        if not (rate_hz > 0 and math.isfinite(rate_hz)) or rate_hz > control_hz:
            raise ValueError(f"{name} must be in (0, control_hz={control_hz}], got {rate_hz!r}")
        k = control_hz / rate_hz
        if abs(k - round(k)) > 1e-9:
            raise ValueError(
                f"control_hz / {name} must be a whole number, got {control_hz} / {rate_hz}"
            )
        return int(round(k))

    def _build_world(self, rng: np.random.Generator, start: FloatArray) -> DiffDriveRobot:
        """A fresh world: floor, the episode's walls and obstacles, the robot at ``start``."""
        w = self.world
        w.reset_simulation()
        textured = self.sensor_mode is SensorMode.IMAGE or self.render_mode == "rgb_array"
        # one draw from the episode's generator whatever the mode, so that fast and image
        # episodes of one seed share their layouts and noise
        tex_rng = np.random.default_rng(int(rng.integers(2**31)))
        if textured:
            w.add_floor(textured_half_size=self.room_half_size + 0.1, rng=tex_rng)
            for prim in self._obstacles:
                kind = SurfaceKind.WALL if prim.name.startswith("wall") else SurfaceKind.OBJECT
                w.add_primitive(prim, surface=kind, rng=tex_rng)
        else:
            w.add_floor()
            for prim in self._obstacles:
                w.add_primitive(prim)
        robot = DiffDriveRobot(w, self.true_params)
        robot.reset(start)
        self.robot = robot
        self.scanner = PlanarScanner(robot, self.true_params.camera, n_beams=self.n_beams)
        self.camera = (
            RGBDCamera(robot, self.true_params.camera)
            if self.sensor_mode is SensorMode.IMAGE
            else None
        )
        return robot

    def _measure(self, pose: FloatArray | None = None) -> DiffDriveMeasurement:
        """The sensors' measurement at this step, their noise drawn from the episode's
        generator; ``pose`` is the robot's true pose when the caller has read it since the
        last physics step (the fast scan needs it)."""
        robot, scanner, camera = self.robot, self.scanner, self.camera
        assert robot is not None and scanner is not None
        t, steps = self._t, self._steps
        ticks = encoder_ticks(t, robot.encoder_angles(), self.params.ticks_per_rev)
        if camera is None:  # fast fidelity: the analytic scan when due, no frame
            if steps % self._scan_every:
                return DiffDriveMeasurement(t, ticks, None, None)  # (positional: cheaper)
            rng = self._np_random  # the episode's generator (np_random, without its property)
            self._scan = scan = scanner.scan_fast(
                t, self.np_random if rng is None else rng, None if pose is None else pose.tolist()
            )
            return DiffDriveMeasurement(t, ticks, scan, None)
        frame = None
        scan = None
        # the camera renders only when its own frame is due; a scan due between frames
        # renders the small depth picture it needs (PlanarScanner.render_size)
        if steps % self._camera_every == 0:
            frame = camera.render(t, self.np_random)
        if steps % self._scan_every == 0:
            if frame is not None:
                scan = scanner.scan_from_frame(frame)
            else:
                scan = scanner.scan_rendered(camera, t, self.np_random)
            self._scan = scan
        return DiffDriveMeasurement(t, ticks, scan, frame)

    def _observation(self) -> npt.NDArray[np.float32]:
        assert self._estimate is not None and self._scan is not None
        assert self.robot is not None
        pose = self._estimate.pose
        x, y, th = pose.tolist() if type(pose) is np.ndarray else (float(v) for v in pose)
        gx, gy, gth = self.task.goal.tolist()
        cmd_v, cmd_w = self.robot.command.tolist()
        _, v_max, w_max = self._episode_consts
        out = self._obs_out
        new_scan = self._obs_scan is not self._scan  # the scan part changes only with a new scan
        if _fill_observation_compiled is not None and KERNELS.on:
            _fill_observation_compiled(
                x,
                y,
                th,
                gx,
                gy,
                gth,
                cmd_v / v_max,
                cmd_w / w_max,
                self._scan.ranges,
                self._scan.range_max,
                new_scan,
                self._obs_low,
                self._obs_high,
                out,
            )
            self._obs_scan = self._scan
            return out.copy()
        # = np.clip to the observation space, without its Python wrapper: the scan part when
        # the scan is new, the 12 entries before it at every step
        if new_scan:
            scaled = np.divide(self._scan.ranges, self._scan.range_max)
            np.minimum(scaled, 1.0, out=scaled)  # inf (nothing seen) -> 1
            tail = self._obs_tail
            tail[:] = scaled  # float64 -> float32, as astype
            np.minimum(tail, self._obs_high[12:], out=tail)
            np.maximum(tail, self._obs_low[12:], out=tail)
            self._obs_scan = self._scan
        head = self._obs_head
        # Python floats -> float32, as astype
        head[:] = observation_head(x, y, th, gx, gy, gth, cmd_v / v_max, cmd_w / w_max)
        np.minimum(head, self._obs_high_head, out=head)
        np.maximum(head, self._obs_low_head, out=head)
        return out.copy()

    def _info(
        self,
        pose: FloatArray,
        dist: float,
        ang: float,
        terms: dict[str, float],
        collision: bool,
        success: bool,
    ) -> dict[str, Any]:
        """The step's ``info``. ``pose`` and ``terms`` are the caller's fresh objects, kept by
        nothing else: they go in as they are."""
        assert self._estimate is not None
        est_pose = self._estimate.pose
        return {
            "true_pose": pose,
            "estimated_pose": (
                est_pose.copy()
                if type(est_pose) is np.ndarray and est_pose.dtype is _FLOAT64
                else np.array(est_pose, dtype=float)
            ),
            "estimate_ok": bool(self._estimate.ok),
            "estimate_status": self._estimate.status,
            "goal": self.task.goal.copy(),
            "pos_error": dist,
            "heading_error": ang,
            "collision": collision,
            "is_success": success,
            "reward_terms": terms,
            "t": self._t,
        }


def observation_head(
    x: float, y: float, th: float, gx: float, gy: float, gth: float, cmd_v: float, cmd_w: float
) -> tuple[float, float, float, float, float, float, float, float, float, float, float, float]:
    """The 12 entries before the scan: estimated pose ``(x, y, cos th, sin th)``, goal
    ``(gx, gy, cos gth, sin gth)``, the goal in the robot's frame, and the normalised
    command ``(cmd_v, cmd_w)`` (m, rad, 1)."""
    c, s = math.cos(th), math.sin(th)
    dx, dy = gx - x, gy - y
    return (
        x,
        y,
        c,
        s,
        gx,
        gy,
        math.cos(gth),
        math.sin(gth),
        c * dx + s * dy,
        -s * dx + c * dy,
        cmd_v,
        cmd_w,
    )


_observation_head = compiled(observation_head) or observation_head
"""The compiled twin that :func:`fill_observation` calls (a compiled kernel calls only
compiled functions); :func:`observation_head` itself without Numba."""


def fill_observation(
    x: float,
    y: float,
    th: float,
    gx: float,
    gy: float,
    gth: float,
    cmd_v: float,
    cmd_w: float,
    ranges: FloatArray,
    range_max: float,
    new_scan: bool,
    low: npt.NDArray[np.float32],
    high: npt.NDArray[np.float32],
    out: npt.NDArray[np.float32],
) -> None:
    """Loop form of :meth:`WheeledNavEnv._observation`'s arithmetic into ``out``
    (``12 + n_beams``,): estimated pose ``(x, y, th)``, goal pose ``(gx, gy, gth)``
    (m, m, rad), normalised command ``(cmd_v, cmd_w)``, and with ``new_scan`` the scan
    ``ranges`` (m) over ``range_max`` (m); each entry cast to float32 and clipped to
    ``[low, high]`` (``np.minimum`` then ``np.maximum``: NaN stays NaN). The same
    operations as the NumPy form: compiled, the same bits."""
    x, y, th, gx, gy, gth = float(x), float(y), float(th), float(gx), float(gy), float(gth)
    cmd_v, cmd_w = float(cmd_v), float(cmd_w)
    head = _observation_head(x, y, th, gx, gy, gth, cmd_v, cmd_w)
    for i in range(12):
        v = np.float32(head[i])
        v = v if (v <= high[i] or v != v) else high[i]
        out[i] = v if (v >= low[i] or v != v) else low[i]
    if new_scan:
        for j in range(ranges.shape[0]):
            r = ranges[j] / range_max
            r = r if (r <= 1.0 or r != r) else 1.0  # inf (nothing seen) -> 1
            v = np.float32(r)
            k = 12 + j
            v = v if (v <= high[k] or v != v) else high[k]
            out[k] = v if (v >= low[k] or v != v) else low[k]


_fill_observation_compiled = compiled(fill_observation)
""":func:`fill_observation` compiled by Numba; ``None`` without Numba."""
