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

The base's firmware limits acceleration (``a_max``, ``alpha_max``) and converts
the twist to wheel speeds with the *nominal* geometry, as a real robot does.

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
and ``success_ang_tol`` (rad) of the goal pose and at rest.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from realitygap.core.geometry import check_finite
from realitygap.envs.common import check_twist_action
from realitygap.envs.layouts import clearance, free_route_exists, random_layout, room_walls
from realitygap.estimators.base import DiffDriveMeasurement, Estimate, Estimator, Scan
from realitygap.robots.diffdrive import DiffDriveParams, DiffDriveRobot, encoder_ticks
from realitygap.robots.effects import Reality
from realitygap.robots.sensors import PlanarScanner, RGBDCamera, SensorMode
from realitygap.robots.world import Primitive, World

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
    reality : effects that make the simulated robot differ from ``params`` ("the real robot").
    n_obstacles : random obstacles per episode (0: empty room).
    obstacles : a fixed layout instead of random ones.
    room_half_size : half the side of the square room (m).
    start, goal : fixed start / goal poses ``[x, y, θ]``; random when ``None``.
    success_pos_tol, success_ang_tol : success tolerances (m, rad).
    physics_hz, control_hz : physics rate and control rate (Hz); their ratio must be whole.
    n_beams : scan beams over the camera's horizontal field of view.
    scan_hz : rate of the planar scan (Hz); steps in between re-use the last scan.
    camera_hz : rate of rendered RGB-D frames in image mode (Hz).
    terminate_on_success : end the episode on success (otherwise ``info["is_success"]`` is
        reported and the episode runs on, e.g. to measure where a controller settles).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}  # noqa: RUF012 (gymnasium's name)

    def __init__(
        self,
        render_mode: str | None = None,
        sensor_mode: str | SensorMode = SensorMode.FAST,
        estimator: Estimator | None = None,
        params: DiffDriveParams | None = None,
        reality: Reality | None = None,
        n_obstacles: int = 6,
        obstacles: list[Primitive] | None = None,
        room_half_size: float = 3.5,
        start: npt.ArrayLike | None = None,
        goal: npt.ArrayLike | None = None,
        success_pos_tol: float = 0.03,
        success_ang_tol: float = math.radians(5.0),
        physics_hz: float = 240.0,
        control_hz: float = 20.0,
        n_beams: int = 64,
        scan_hz: float = 10.0,
        camera_hz: float = 20.0,
        terminate_on_success: bool = True,
    ):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        try:
            self.sensor_mode = SensorMode(sensor_mode)
        except ValueError:
            raise ValueError(
                f"sensor_mode must be 'fast' or 'image', got {sensor_mode!r}"
            ) from None
        ratio = physics_hz / control_hz
        if control_hz <= 0 or abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ValueError(
                f"physics_hz / control_hz must be a positive whole number, got {physics_hz} / {control_hz}"
            )
        if n_obstacles < 0:
            raise ValueError(f"n_obstacles must be >= 0, got {n_obstacles}")
        if estimator is not None and not isinstance(estimator, Estimator):
            raise TypeError(
                "estimator must have reset(initial=None) and update(measurement) methods, "
                f"got {type(estimator).__name__}"
            )
        self.render_mode = render_mode
        self.params = params if params is not None else DiffDriveParams()
        self.reality = reality if reality is not None else Reality()
        self.true_params = self.reality.apply_params(self.params)
        self.n_obstacles = int(n_obstacles)
        self.fixed_obstacles = list(obstacles) if obstacles is not None else None
        self.room_half_size = float(room_half_size)
        self.fixed_start = None if start is None else check_finite("start", start, (3,))
        self.fixed_goal = None if goal is None else check_finite("goal", goal, (3,))
        self.success_pos_tol = float(success_pos_tol)
        self.success_ang_tol = float(success_ang_tol)
        self.n_beams = int(n_beams)
        self.terminate_on_success = bool(terminate_on_success)
        self._scan_every = self._divisor("scan_hz", scan_hz, control_hz)
        self._camera_every = self._divisor("camera_hz", camera_hz, control_hz)
        self.estimator: Estimator = (
            estimator if estimator is not None else default_estimator(self.params, self.sensor_mode)
        )

        self.world = World(physics_hz=physics_hz, n_substeps=int(round(ratio)))
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
        self._cmd = np.zeros(2)
        self._goal = np.zeros(3)
        self._start_pose = np.zeros(3)
        self._scan: Scan | None = None
        self._estimate: Estimate | None = None
        self._obstacles: tuple[Primitive, ...] = ()
        self._command_hooks: list[Any] = []
        self._ticks_hooks: list[Any] = []
        self._prev_dist = 0.0
        self._prev_ang = 0.0
        self._obs_buf = np.zeros(12 + self.n_beams, dtype=np.float64)

    # ------------------------------------------------------------------ properties
    @property
    def dt(self) -> float:
        """Control period in s."""
        return self.world.dt

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
        half = math.radians(cam.hfov_deg) / 2.0
        return cam.mount_yaw + np.linspace(-half, half, self.n_beams)

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
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"start", "goal"}
        if unknown:
            raise ValueError(
                f"unknown reset option(s) {sorted(unknown)}; expected 'start' and/or 'goal'"
            )
        rng = self.np_random
        start, goal = self._draw_start_goal(rng, options)
        self._goal = goal
        self._start_pose = start.copy()
        self._build_world(rng, start, goal)

        self._t, self._steps = 0.0, 0
        self._cmd = np.zeros(2)
        self._command_hooks = self.reality.command_hooks(self.dt, self.params)
        self._ticks_hooks = self.reality.ticks_hooks()
        self._estimate = self.estimator.reset(start.copy())
        measurement = self._measure(rng)
        self._estimate = self.estimator.update(measurement)
        pose = self.robot.pose2d()  # type: ignore[union-attr]
        self._prev_dist, self._prev_ang = self._pose_error(pose)
        info = self._info(pose, self._prev_dist, self._prev_ang, {}, collision=False, success=False)
        return self._observation(), info

    def step(
        self, action: npt.ArrayLike
    ) -> tuple[npt.NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        if self.robot is None:
            raise RuntimeError("call reset() before step()")
        a0, a1 = check_twist_action(action)
        v, w = self._limit_acceleration(a0 * self.v_max, a1 * self.w_max)
        self._cmd[0], self._cmd[1] = v, w
        for hook in self._command_hooks:
            v, w = hook(v, w, self.dt)
        # firmware inverse kinematics with the nominal geometry
        half_b = self.params.wheelbase / 2.0
        self.robot.set_wheel_speeds(
            (v - w * half_b) / self.params.wheel_radius_left,
            (v + w * half_b) / self.params.wheel_radius_right,
        )
        self.world.step()
        self._steps += 1
        self._t = self._steps * self.dt

        rng = self.np_random
        measurement = self._measure(rng)
        self._estimate = self.estimator.update(measurement)

        pose = self.robot.pose2d()
        dist, ang = self._pose_error(pose)
        collision = self.robot.in_contact_with_scenery()
        success = self._is_success(dist, ang)
        reward, terms = self._get_rew(dist, ang, (a0, a1), collision, success)
        terminated = collision or (success and self.terminate_on_success)
        return (
            self._observation(),
            reward,
            terminated,
            False,
            self._info(pose, dist, ang, terms, collision, success),
        )

    def render(self) -> npt.NDArray[np.uint8] | None:
        if self.render_mode != "rgb_array" or self.robot is None:
            return None
        import pybullet as p

        c = self.world.bullet
        x, y, _ = self.robot.pose2d()
        view = c.computeViewMatrix([x - 2.5, y - 2.5, 4.0], [x, y, 0.0], [0, 0, 1])
        proj = c.computeProjectionMatrixFOV(60, 4 / 3, 0.1, 30)
        _, _, rgba, _, _ = c.getCameraImage(320, 240, view, proj, renderer=p.ER_TINY_RENDERER)
        return np.asarray(rgba, dtype=np.uint8).reshape(240, 320, 4)[..., :3].copy()

    def close(self) -> None:
        self.world.close()
        self.robot = None

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

    def _draw_start_goal(
        self, rng: np.random.Generator, options: dict[str, Any]
    ) -> tuple[FloatArray, FloatArray]:
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
            if np.any(np.abs(pose[:2]) > self.room_half_size - self.true_params.body_radius):
                raise ValueError(
                    f"{name} {pose[:2].tolist()} lies outside the room (|x|, |y| must be < "
                    f"{self.room_half_size - self.true_params.body_radius:.3f} m)"
                )
        return start, goal

    def _build_world(self, rng: np.random.Generator, start: FloatArray, goal: FloatArray) -> None:
        radius = self.true_params.body_radius
        if self.fixed_obstacles is not None:
            layout = list(self.fixed_obstacles)
            if np.min(clearance(layout, start[:2]), initial=np.inf) <= radius:
                raise ValueError(
                    f"the start pose {start.tolist()} overlaps an obstacle of the given layout"
                )
            if not free_route_exists(
                layout + room_walls(self.room_half_size),
                start[:2],
                goal[:2],
                radius,
                self.room_half_size,
            ):
                raise ValueError(
                    f"the given obstacle layout leaves no collision-free route from start {start[:2].tolist()} "
                    f"to goal {goal[:2].tolist()} for a robot of radius {radius:.3f} m"
                )
        elif self.n_obstacles > 0:
            layout = random_layout(
                rng,
                self.n_obstacles,
                self.room_half_size,
                keep_clear=[tuple(start[:2]), tuple(goal[:2])],
                clear_radius=radius + 0.25,
                robot_radius=radius,
            )
        else:
            layout = []
        self._obstacles = tuple(room_walls(self.room_half_size) + layout)
        w = self.world
        w.reset_simulation()
        w.add_floor()
        textured = self.sensor_mode is SensorMode.IMAGE or self.render_mode == "rgb_array"
        tex_rng = np.random.default_rng(int(rng.integers(2**31)))
        for prim in self._obstacles:
            tex = w.texture(prim.name, tex_rng) if textured else None
            w.add_primitive(prim, texture_id=tex)
        self.robot = DiffDriveRobot(w, self.true_params)
        self.robot.reset(start)
        self.scanner = PlanarScanner(self.robot, self.true_params.camera, n_beams=self.n_beams)
        self.camera = (
            RGBDCamera(self.robot, self.true_params.camera)
            if self.sensor_mode is SensorMode.IMAGE
            else None
        )

    def _limit_acceleration(self, v: float, w: float) -> tuple[float, float]:
        dv_max = self.params.a_max * self.dt
        dw_max = self.params.alpha_max * self.dt
        v = self._cmd[0] + min(dv_max, max(-dv_max, v - self._cmd[0]))
        w = self._cmd[1] + min(dw_max, max(-dw_max, w - self._cmd[1]))
        return float(v), float(w)

    def _measure(self, rng: np.random.Generator) -> DiffDriveMeasurement:
        assert self.robot is not None and self.scanner is not None
        angles = self.robot.wheel_angles()
        for hook in self._ticks_hooks:
            angles = hook(*angles)
        ticks = encoder_ticks(self._t, angles, self.params.ticks_per_rev)
        frame = None
        scan = None
        scan_due = self._steps % self._scan_every == 0
        if self.camera is not None and (scan_due or self._steps % self._camera_every == 0):
            frame = self.camera.render(self._t, rng)
        if scan_due:
            scan = (
                self.scanner.scan_from_frame(frame)
                if frame is not None
                else self.scanner.scan_fast(self._t, rng)
            )
            self._scan = scan
        return DiffDriveMeasurement(t=self._t, ticks=ticks, scan=scan, rgbd=frame)

    def _observation(self) -> npt.NDArray[np.float32]:
        assert self._estimate is not None and self._scan is not None
        x, y, th = (float(v) for v in self._estimate.pose)
        gx, gy, gth = (float(v) for v in self._goal)
        c, s = math.cos(th), math.sin(th)
        dx, dy = gx - x, gy - y
        obs = self._obs_buf
        obs[:12] = (
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
            self._cmd[0] / self.v_max,
            self._cmd[1] / self.w_max,
        )
        np.divide(self._scan.ranges, self._scan.range_max, out=obs[12:])
        np.minimum(obs[12:], 1.0, out=obs[12:])  # inf (nothing seen) -> 1
        out = obs.astype(np.float32)
        np.clip(out, self._obs_low, self._obs_high, out=out)
        return out

    def _pose_error(self, pose: FloatArray) -> tuple[float, float]:
        """True distance (m) and absolute heading error (rad) to the goal pose."""
        gx, gy, gth = self._goal
        d_th = (float(pose[2]) - gth + math.pi) % (2.0 * math.pi) - math.pi
        return math.hypot(float(pose[0]) - gx, float(pose[1]) - gy), abs(d_th)

    def _is_success(self, d: float, a: float) -> bool:
        assert self.robot is not None
        if d > self.success_pos_tol or a > self.success_ang_tol:
            return False
        v, w = self.robot.twist()
        return abs(v) < 0.01 and abs(w) < 0.05

    def _get_rew(
        self, dist: float, ang: float, action: tuple[float, float], collision: bool, success: bool
    ) -> tuple[float, dict[str, float]]:
        near = math.exp(-dist / 0.3)
        terms = {
            "progress": 2.0 * (self._prev_dist - dist),
            "heading": 0.5 * near * (self._prev_ang - ang),
            "time": -0.01,
            "effort": -0.002 * (action[0] ** 2 + action[1] ** 2),
            "collision": -5.0 if collision else 0.0,
            "success": 5.0 if success else 0.0,
        }
        self._prev_dist, self._prev_ang = dist, ang
        return float(sum(terms.values())), terms

    def _info(
        self,
        pose: FloatArray,
        dist: float,
        ang: float,
        terms: dict[str, float],
        collision: bool,
        success: bool,
    ) -> dict[str, Any]:
        assert self._estimate is not None
        return {
            "true_pose": pose.copy(),
            "estimated_pose": np.array(self._estimate.pose, dtype=float),
            "estimate_ok": bool(self._estimate.ok),
            "estimate_status": self._estimate.status,
            "goal": self._goal.copy(),
            "pos_error": dist,
            "heading_error": ang,
            "collision": collision,
            "is_success": success,
            "reward_terms": dict(terms),
            "t": self._t,
        }
