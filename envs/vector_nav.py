r"""``realitygap/WheeledNavVec-v0``: ``N`` WheeledNav robots per call on the calibrated surrogate.

A :class:`gymnasium.vector.VectorEnv` for reinforcement learning at thousands
of env steps per second. It has WheeledNav's spaces, observation, reward,
success and termination (fast sensor mode; see
:mod:`realitygap.envs.wheeled_nav`), so a policy trained here runs unchanged
in the PyBullet env; what differs is the simulator:

* the drive is the kinematic surrogate that the diagnosis validates against
  PyBullet (:mod:`realitygap.robots.diffdrive_surrogate`), batched and stepped one
  control period at a time (:class:`~realitygap.envs.vector_drive.BatchDrive`),
  behind the same firmware limits and nominal inverse kinematics;
* the scan is the same analytic ray cast against the same footprints
  (walls and obstacles from :class:`~realitygap.envs.tasks.nav.NavTask`), with
  the same depth-noise model, at the same rate;
* the estimate is wheel odometry on the quantised encoder counts, as the fast
  env's default :class:`~realitygap.estimators.diffdrive_model.WheelOdometry`;
* episodes are drawn as :class:`~realitygap.envs.tasks.nav.NavTask` draws them,
  from a generator per robot, for all robots at once (batched rejection sampling,
  :func:`~realitygap.envs.vector_drive.random_layouts`): robot ``i`` reset with
  seed ``s + i`` starts the episode that ``WheeledNav-v0`` starts with
  ``reset(seed=s + i)`` (same start, goal and obstacles).

Cost is said before it is spent: the constructor estimates the memory and the
reset and step times of ``num_envs`` robots (:func:`estimate_vector_cost`),
refuses a size whose state does not fit in the available memory and warns
about a large one, before allocating anything.

Known limits (stated fidelity, measured by ``tests/envs/test_vector_nav.py``
and the ``bench-vec`` experiment):

* **contacts** — no rigid-body dynamics: the body does not pitch onto a
  caster, bounce, or get pushed; motors and traction are the surrogate's
  calibrated rate limits.
* **collisions** — detected analytically: the body disc (radius
  ``body_radius``) within :data:`CONTACT_MARGIN` of a footprint. The episode
  ends there, as in PyBullet; the robot never slides along a wall.
* **slip** — only as the surrogate models it (friction-limited acceleration,
  the ``longitudinal_slip`` and ``traction_slip`` terms); no lateral slip.
* **effects** — a ``reality`` (and domain randomisation, ``randomize``) may
  use every differential-drive effect with a surrogate term. Terms that are
  constant over an episode are exact; time-series terms (latency, limiters,
  lags, dead zones) act on a rolling window of ``history_steps`` applied
  twists: exact for delays shorter than the window, approximate for limiter
  transients or lags longer than it. ``timestamp_offset`` changes only
  recorded ground truth and has no effect here.
* the pose is planar; the estimator is wheel odometry only (no image mode).
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces
from gymnasium.vector import AutoresetMode

from realitygap.core.checks import (
    check_finite_float,
    check_int,
    check_positive_int,
)
from realitygap.core.geometry import check_finite
from realitygap.envs.common import (
    MAX_PHYSICS_HZ,
    available_memory_bytes,
    check_instance,
    check_open,
    check_randomize,
    check_reality,
    check_reset_options,
    check_seed,
    check_started,
    odometry_belief,
)
from realitygap.envs.layouts import clearance, free_route_exists, room_grid, room_walls
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
from realitygap.envs.vector_drive import (
    ROUTE_CHUNK,
    BatchDrive,
    BatchScenery,
    EpisodeLayouts,
    RobotStreams,
    effect_values,
    random_layouts,
    sample_start_goals,
    vector_effects,
)
from realitygap.estimators.scan import scan_angles
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import Reality
from realitygap.robots.world import Primitive

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "CONTACT_MARGIN",
    "WARN_BYTES",
    "WARN_RESET_S",
    "WARN_STEP_S",
    "VectorCost",
    "WheeledNavVecEnv",
    "check_num_envs",
    "check_vector_cost",
    "estimate_vector_cost",
]

MAX_BEAMS = 4096
"""Most range beams per scan (as WheeledNav-v0)."""

MAX_CONTROL_HZ = MAX_PHYSICS_HZ
"""Highest control rate (Hz): the PyBullet twin's highest physics rate."""

MAX_HISTORY_STEPS = 10_000
"""Longest window of applied twists (control steps) the time-series effect terms may read."""

CONTACT_MARGIN = 0.0
"""Distance (m) between the body disc and a footprint at which a collision is reported."""

WARN_BYTES = 1 << 30
"""Estimated memory (bytes) above which the constructor warns (1 GiB)."""

WARN_RESET_S = 10.0
"""Estimated time (s) of one reset of every robot above which the constructor warns."""

WARN_STEP_S = 1.0
"""Estimated time (s) of one step of every robot above which the constructor warns."""

# Cost model: arrays counted from the shapes the env allocates, in float64 entries per
# robot, and times per robot measured on one core of a 2-core x86-64 VM (NumPy 2).
_PYTHON_BYTES_PER_ROBOT = 1_000
"""A robot's generator and stream (``np.random.Generator`` with its ``PCG64``), bytes."""
_STREAM_WIDTH = 64
"""Doubles buffered per robot by :class:`~realitygap.envs.vector_drive.RobotStreams`."""
_RESET_S_PER_ROBOT = (25e-6, 250e-6)
"""Reset time per robot (s): base, and extra with random obstacles (the route check's grid
labelling and footprint rasterising dominate); measured 0.21-0.27 s for 1000 robots."""
_STEP_S_PER_ROBOT_BEAM = 0.25e-6
"""Step time per robot and scan beam (s); the ray cast dominates a step (measured ~1.1 s
per step for 100 000 robots and 64 beams)."""


@dataclass(frozen=True)
class VectorCost:
    """Estimated cost of a vector env of ``num_envs`` robots.

    ``bytes_per_robot`` and ``bytes`` of state and working arrays (reset and
    step temporaries included); ``reset_s`` and ``step_s``, seconds for one
    reset / step of every robot; ``available_bytes``, memory the process may
    still allocate (``None``: unknown).
    """

    num_envs: int
    bytes_per_robot: int
    bytes: int
    reset_s: float
    step_s: float
    available_bytes: int | None

    def summary(self) -> str:
        return (
            f"~{self.bytes / 2**30:.2f} GiB ({self.bytes_per_robot / 1024:.1f} KiB per robot), "
            f"~{self.reset_s:.1f} s per reset and ~{self.step_s:.2f} s per step"
        )


def estimate_vector_cost(
    num_envs: int,
    *,
    n_beams: int = N_BEAMS,
    n_obstacles: int = N_OBSTACLES,
    history_steps: int = 40,
) -> VectorCost:
    """Memory and time of ``num_envs`` robots, from the per-robot arrays' shapes.

    Float64 entries per robot, with ``B`` beams, ``K`` obstacles and a window of
    ``H`` twists: state (pose, estimate, goal, ticks, previous errors, steps)
    14 + B; drive constants, state and effect values ~30 + 2 H; scenery
    9 K (boxes 6, cylinders 3); layouts 9 K; stream buffer 64; a step's
    temporaries (ray-cast directions and ranges, observation in float64 and
    float32, ``final_obs``, info copies) ~12 B + 60; a reset's sampling
    arrays ~40 K. Plus the robot's generator (~1 kB) and the route check's
    fixed chunk of grids.
    """
    n = int(num_envs)
    b, k, h = int(n_beams), max(int(n_obstacles), 0), int(history_steps)
    floats = (14 + b) + (30 + 2 * h) + 9 * k + 9 * k + _STREAM_WIDTH + (12 * b + 60) + 40 * k
    per_robot = 8 * floats + _PYTHON_BYTES_PER_ROBOT
    fixed = ROUTE_CHUNK * 25 * 141 * 141 if k else 0  # route grids, labels and patches
    reset_s = n * (_RESET_S_PER_ROBOT[0] + (_RESET_S_PER_ROBOT[1] if k else 0.0))
    step_s = n * b * _STEP_S_PER_ROBOT_BEAM
    return VectorCost(
        n, per_robot, n * per_robot + fixed, reset_s, step_s, available_memory_bytes()
    )


def check_num_envs(num_envs: Any) -> int:
    """``num_envs`` as a positive int, else a ``ValueError`` saying what came and the fix.

    ``bool``, ``float`` (even ``64.0``) and ``str`` are refused rather than converted.
    """
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)):
        raise ValueError(
            f"num_envs must be a whole number of robots (a positive int), got {num_envs!r} "
            f"({type(num_envs).__name__}). Fix: pass an int, e.g. "
            "gym.make_vec('realitygap/WheeledNavVec-v0', num_envs=64)"
        )
    if num_envs < 1:
        raise ValueError(
            f"num_envs must be a whole number of robots >= 1, got {int(num_envs)}. Fix: pass "
            "at least one robot, e.g. gym.make_vec('realitygap/WheeledNavVec-v0', num_envs=64)"
        )
    return int(num_envs)


def check_vector_cost(num_envs: int, **shape: int) -> VectorCost:
    """The estimated cost of ``num_envs`` robots (:func:`estimate_vector_cost` with ``shape``),
    said before anything is allocated.

    Raises
    ------
    ValueError
        If the estimated memory exceeds the memory available, naming both and the
        largest ``num_envs`` that fits.

    Warns
    -----
    UserWarning
        If the estimate exceeds
        :data:`WARN_BYTES`, :data:`WARN_RESET_S` or :data:`WARN_STEP_S`.
    """
    cost = estimate_vector_cost(num_envs, **shape)
    avail = cost.available_bytes
    if avail is not None and cost.bytes > avail:
        fits = max((avail - (cost.bytes - cost.num_envs * cost.bytes_per_robot)), 0)
        fits //= cost.bytes_per_robot
        raise ValueError(
            f"num_envs must be a whole number of robots whose state fits in memory: expected "
            f"num_envs <= {fits} ({avail / 2**30:.1f} GiB available, "
            f"~{cost.bytes_per_robot / 1024:.1f} KiB per robot), got {cost.num_envs} "
            f"(~{cost.bytes / 2**30:.1f} GiB). Fix: pass num_envs={max(fits // 2, 1)} or "
            "fewer, or run several vector envs in separate processes"
        )
    if cost.bytes > WARN_BYTES or cost.reset_s > WARN_RESET_S or cost.step_s > WARN_STEP_S:
        warnings.warn(
            f"WheeledNavVec with num_envs={cost.num_envs}: estimated {cost.summary()} "
            f"(warned above {WARN_BYTES / 2**30:g} GiB, {WARN_RESET_S:g} s per reset or "
            f"{WARN_STEP_S:g} s per step)",
            UserWarning,
            stacklevel=3,
        )
    return cost


_ENV_ID = "realitygap/WheeledNavVec-v0"
"""The id the env is registered under (named in its state errors)."""


class WheeledNavVecEnv(gym.vector.VectorEnv[Any, Any, Any]):
    """WheeledNav for ``num_envs`` robots on the batched surrogate (see the module docstring).

    Spaces: ``single_action_space`` and ``single_observation_space`` are
    WheeledNav's (fast mode); ``action_space`` / ``observation_space`` batch them.
    Autoreset is same-step: a finished robot's last observation and info are in
    ``info["final_obs"]`` / ``info["final_info"]`` (masks ``"_final_obs"``) and its
    row of the returned observation already starts the next episode.

    Parameters
    ----------
    num_envs : number of robots ``N`` (a positive int). Its estimated cost
        (:func:`estimate_vector_cost`, kept as :attr:`cost`) is checked before anything
        is allocated: a ``ValueError`` if it does not fit in the available memory, a
        ``UserWarning`` above :data:`WARN_BYTES`, :data:`WARN_RESET_S` or :data:`WARN_STEP_S`.
    params : nominal robot parameters.
    reality : effects applied to every robot (each must have a surrogate term); a
        :class:`Reality` or its :meth:`~Reality.to_dict` form.
    randomize : ``{"effect.param": (low, high)}`` or a
        :class:`~realitygap.robots.effects.Twin` (its boxes): drawn uniformly per robot
        and episode from the robot's generator, on top of ``reality``.
    estimator_reality : effects the odometry's model includes, as
        :class:`~realitygap.envs.wheeled_nav.WheeledNavEnv`'s.
    calibration : the surrogate's calibration; default: measured once on the
        PyBullet body (:func:`realitygap.robots.diffdrive_surrogate.calibrate`, cached).
    n_obstacles, obstacles, room_half_size, start, goal, success_pos_tol,
    success_ang_tol, terminate_on_success, reward_weights :
        as :class:`~realitygap.envs.wheeled_nav.WheeledNavEnv`.
    control_hz, n_beams, scan_hz : control rate (Hz), scan beams, scan rate (Hz).
    max_episode_steps : per-robot time limit (truncation), steps.
    history_steps : window of applied twists for time-series effect terms.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}  # noqa: RUF012 (gymnasium's name)

    def __init__(
        self,
        num_envs: int = 64,
        *,
        params: DiffDriveParams | None = None,
        reality: Reality | Mapping[str, Any] | None = None,
        randomize: Mapping[str, Any] | None = None,
        estimator_reality: Reality | Mapping[str, Any] | str | os.PathLike[str] | None = None,
        calibration: Any = None,
        n_obstacles: int = N_OBSTACLES,
        obstacles: list[Primitive] | None = None,
        room_half_size: float = ROOM_HALF_SIZE,
        start: npt.ArrayLike | None = None,
        goal: npt.ArrayLike | None = None,
        success_pos_tol: float = SUCCESS_POS_TOL,
        success_ang_tol: float = SUCCESS_ANG_TOL,
        control_hz: float = CONTROL_HZ,
        n_beams: int = N_BEAMS,
        scan_hz: float = SCAN_HZ,
        terminate_on_success: bool = True,
        reward_weights: NavRewardWeights = NavRewardWeights(),  # noqa: B008 (frozen)
        max_episode_steps: int = 1200,
        history_steps: int = 40,
        render_mode: str | None = None,
    ):
        n = check_num_envs(num_envs)
        if render_mode is not None:
            raise ValueError(
                f"the vector env does not render; render_mode must be None, got {render_mode!r}"
            )
        # every argument is checked before the cost is estimated and anything is allocated;
        # the episode settings by the task (as WheeledNav-v0 checks them)
        task = NavTask(
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
        n_beams = check_int(
            n_beams, "n_beams", low=2, high=MAX_BEAMS, what="a whole number of beams"
        )
        control_hz = check_finite_float(
            control_hz, "control_hz", low=0.0, high=MAX_CONTROL_HZ, strict_low=True, unit="Hz"
        )
        scan_hz = check_finite_float(
            scan_hz,
            "scan_hz",
            low=0.0,
            high=control_hz,
            strict_low=True,
            unit="Hz",
            fix="the scan rate cannot exceed control_hz",
        )
        k = control_hz / scan_hz
        if abs(k - round(k)) > 1e-9:
            raise ValueError(
                f"scan_hz must divide control_hz={control_hz:g} Hz (a whole ratio >= 1), got "
                f"{scan_hz:g} Hz. Fix: choose a scan rate such as {control_hz / 2:g} Hz"
            )
        max_episode_steps = check_positive_int(max_episode_steps, "max_episode_steps")
        history_steps = check_int(
            history_steps,
            "history_steps",
            low=1,
            high=MAX_HISTORY_STEPS,
            what="a whole number of control steps",
            fix="the window of applied twists the time-series effect terms read; 40 is default",
        )
        params = check_instance(params, "params", DiffDriveParams, default=DiffDriveParams)
        reality = check_reality(reality, "diffdrive")
        believed = params
        if estimator_reality is not None:
            believed = odometry_belief(estimator_reality, params)
        n_layout = (
            len(task.fixed_obstacles) if task.fixed_obstacles is not None else task.n_obstacles
        )
        self.cost = check_vector_cost(
            n, n_beams=n_beams, n_obstacles=n_layout, history_steps=history_steps
        )
        self.num_envs = n
        self.params = params
        self.reality = reality
        self.fixed_values = effect_values(self.reality)
        self.randomize = check_randomize(
            randomize, vector_effects(), "effects with a surrogate term"
        )
        self.true_params = self.reality.apply_params(self.params)
        self.dt = 1.0 / float(control_hz)
        self.n_beams = int(n_beams)
        self.max_episode_steps = int(max_episode_steps)
        self._scan_every = int(round(k))
        # one task holds the episode settings of every robot (its draws are batched here)
        self.task = task
        self.weights = task.weights
        self.room_half_size = task.room_half_size
        self.success_pos_tol, self.success_ang_tol = task.success_pos_tol, task.success_ang_tol
        self.terminate_on_success = task.terminate_on_success
        if calibration is None:
            from realitygap.robots.diffdrive_surrogate import calibrate

            calibration = calibrate(self.params)
        self.calibration = calibration
        effects = sorted(
            {k.split(".")[0] for k in (*self.fixed_values, *self.randomize)},
            key=vector_effects().index,
        )
        self.drive = BatchDrive(
            self.params, calibration, n, self.dt, effects, history_steps=history_steps
        )
        self.scenery = BatchScenery(n, task.n_obstacles, task.n_obstacles, self.room_half_size)

        # spaces: WheeledNav's, fast mode
        self.single_action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        n_obs = 12 + self.n_beams
        low = np.full(n_obs, -1.0, dtype=np.float32)
        high = np.full(n_obs, 1.0, dtype=np.float32)
        big = 4.0 * self.room_half_size
        for i in (0, 1, 4, 5, 8, 9):
            low[i], high[i] = -big, big
        low[12:] = 0.0
        self.single_observation_space = spaces.Box(low, high, dtype=np.float32)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, n)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, n)
        self._obs_low, self._obs_high = low, high

        cam = self.params.camera
        self._beam_offsets = scan_angles(self.n_beams, math.radians(cam.hfov_deg))
        self._beam_cos, self._beam_sin = np.cos(self._beam_offsets), np.sin(self._beam_offsets)
        self.scan_range_max = float(cam.range_max)
        self._odo_m_per_tick = (
            2.0
            * math.pi
            * np.array([believed.wheel_radius_left, believed.wheel_radius_right])
            / believed.ticks_per_rev
        )
        self._odo_wheelbase = float(believed.wheelbase)
        self._ticks_per_rad = self.params.ticks_per_rev / (2.0 * math.pi)

        # state
        self.streams: RobotStreams | None = None  # robot i's draws; seeds 0..N-1 by default
        self.noise_rng = np.random.default_rng(0)
        self.pose = np.zeros((n, 3))
        self.estimate = np.zeros((n, 3))
        self.ticks = np.zeros((n, 2))
        self.goal = np.zeros((n, 3))
        self.prev = np.zeros((n, 2))  # previous (distance, heading error)
        self.steps = np.zeros(n, dtype=np.int64)
        self.scan = np.full((n, self.n_beams), np.inf)
        self.obstacles = EpisodeLayouts(n, task.n_obstacles, room_walls(self.room_half_size))
        self._fixed_routes: tuple[npt.NDArray[np.bool_], npt.NDArray[np.int32]] | None = None
        self._started = False

    @property
    def scan_angles(self) -> FloatArray:
        """Bearings (rad, base frame) of the scan beams, nominal mount."""
        return self.params.camera.mount_yaw + self._beam_offsets

    # ------------------------------------------------------------------ gym API
    def reset(
        self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[npt.NDArray[np.float32], dict[str, Any]]:
        """Start an episode for every robot; robot ``i`` is seeded ``seed + i`` (or
        ``seed[i]``). ``options`` may hold ``start`` / ``goal`` poses, (3,) or (N, 3)."""
        check_open(self, "reset", _ENV_ID)
        options = check_reset_options(options, ("start", "goal"), "WheeledNavVec-v0")
        n = self.num_envs
        if seed is not None:
            if isinstance(seed, (list, tuple, np.ndarray)):
                seeds = np.array(
                    [check_seed(s, f"seed[{i}]") for i, s in enumerate(seed)], dtype=object
                )
            else:
                first = check_seed(seed)
                assert first is not None
                seeds = np.array([first + i for i in range(n)], dtype=object)
            if len(seeds) != n:
                raise ValueError(f"reset(seed=...) needs {n} seeds, got {len(seeds)}")
            self.streams = RobotStreams(seeds, _STREAM_WIDTH)
            self.noise_rng = np.random.default_rng(
                np.random.SeedSequence([int(seeds[0]), n]).generate_state(2)
            )
        elif self.streams is None:
            self.streams = RobotStreams(np.arange(n), _STREAM_WIDTH)
        poses: dict[str, FloatArray] = {}
        for key, value in options.items():
            arr = np.asarray(value, dtype=float)
            if arr.shape == (3,):
                arr = np.broadcast_to(arr, (n, 3))
            if arr.shape != (n, 3):
                raise ValueError(
                    f"reset option {key!r} must have shape (3,) or ({n}, 3), got {arr.shape}"
                )
            poses[key] = arr
        self._reset_robots(np.arange(n), poses)
        self._started = True
        return self._observation(), self._info(np.zeros(n, bool), np.zeros(n, bool))

    def step(
        self, actions: npt.ArrayLike
    ) -> tuple[
        npt.NDArray[np.float32],
        FloatArray,
        npt.NDArray[np.bool_],
        npt.NDArray[np.bool_],
        dict[str, Any],
    ]:
        if not self._started:
            check_open(self, "step", _ENV_ID)
            check_started(self, False, _ENV_ID)
        a = np.asarray(actions, dtype=np.float64)
        if a.shape != (self.num_envs, 2):
            raise ValueError(f"actions must have shape ({self.num_envs}, 2), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError("actions must be finite; got NaN or inf")
        a = np.clip(a, -1.0, 1.0)
        self.drive.step(a, self.pose)
        self.steps += 1
        self._update_estimate()
        due = np.flatnonzero(self.steps % self._scan_every == 0)
        if due.size:
            self._measure_scan(due)

        dist, ang = self._pose_error()
        collision = self._collisions()
        twist = self.drive.twist()
        success = (
            (dist <= self.success_pos_tol)
            & (ang <= self.success_ang_tol)
            & (np.abs(twist[:, 0]) < 0.01)
            & (np.abs(twist[:, 1]) < 0.05)
        )
        w = self.weights
        terms = {
            "progress": w.progress * (self.prev[:, 0] - dist),
            "heading": w.heading * np.exp(-dist / w.heading_scale) * (self.prev[:, 1] - ang),
            "time": np.full(self.num_envs, -w.time),
            "effort": -w.effort * (a[:, 0] ** 2 + a[:, 1] ** 2),
            "collision": np.where(collision, -w.collision, 0.0),
            "success": np.where(success, w.success, 0.0),
        }
        reward = sum(terms.values())
        self.prev[:, 0], self.prev[:, 1] = dist, ang
        terminated = collision | (success & self.terminate_on_success)
        truncated = (self.steps >= self.max_episode_steps) & ~terminated
        obs = self._observation()
        info = self._info(collision, success, dist, ang, terms)
        done = np.flatnonzero(terminated | truncated)
        if done.size:
            info["final_obs"] = obs.copy()
            info["_final_obs"] = terminated | truncated
            info["final_info"] = {
                k: (v.copy() if isinstance(v, np.ndarray) else v)
                for k, v in info.items()
                if k not in ("final_obs", "_final_obs")
            }
            info["_final_info"] = terminated | truncated
            self._reset_robots(done, {})
            fresh = self._observation()
            obs[done] = fresh[done]
            start_info = self._info(np.zeros(self.num_envs, bool), np.zeros(self.num_envs, bool))
            for key, value in start_info.items():
                if isinstance(value, np.ndarray):
                    info[key] = info[key].copy()
                    info[key][done] = value[done]
        return obs, np.asarray(reward, dtype=np.float64), terminated, truncated, info

    def restart_from(
        self, idx: npt.ArrayLike, starts: npt.ArrayLike
    ) -> tuple[npt.NDArray[np.float32], dict[str, Any]]:
        """Start robots ``idx`` again from poses ``starts`` (K, 3), at rest, in the same
        episode (goal and obstacles kept; odometry, scan and step count restarted).

        Returns the observation and info of every robot, as :meth:`reset` does.

        Raises
        ------
        ValueError
            If a pose is not finite or overlaps the room's walls or an obstacle.
        """
        rows = np.asarray(idx, dtype=np.intp).reshape(-1)
        poses = np.asarray(starts, dtype=float).reshape(-1, 3)
        if poses.shape[0] != rows.size or not np.all(np.isfinite(poses)):
            raise ValueError(
                f"starts must be {rows.size} finite poses [x, y, θ], got shape {poses.shape}"
            )
        if rows.size and np.any(
            self.scenery.clearance_of(rows, poses[:, :2]) <= self.true_params.body_radius
        ):
            raise ValueError("a start pose overlaps a wall or an obstacle of its episode")
        self.pose[rows] = poses
        self.estimate[rows] = poses
        self.drive.reset(rows)
        self.ticks[rows] = 0.0
        self.steps[rows] = 0
        self._measure_scan(rows)
        dist, ang = self._pose_error()
        self.prev[rows, 0], self.prev[rows, 1] = dist[rows], ang[rows]
        zeros = np.zeros(self.num_envs, bool)
        return self._observation(), self._info(zeros, zeros)

    def render(self) -> Any:
        check_open(self, "render", _ENV_ID)
        return super().render()

    def close_extras(self, **kwargs: Any) -> None:
        self._started = False

    # ------------------------------------------------------------------ internals
    def _reset_robots(self, idx: npt.NDArray[np.intp], poses: Mapping[str, FloatArray]) -> None:
        """New episodes for robots ``idx``, all drawn at once: start and goal (``poses`` (M, 3)
        rows aligned with ``idx``, else the task's fixed ones, else drawn), obstacles, and
        domain-randomised values, each robot from its own stream in
        :class:`~realitygap.envs.tasks.nav.NavTask`'s order of draws."""
        assert self.streams is not None
        task, streams = self.task, self.streams
        radius = self.true_params.body_radius
        given = {
            key: poses.get(key, None if fixed is None else np.broadcast_to(fixed, (idx.size, 3)))
            for key, fixed in (("start", task.fixed_start), ("goal", task.fixed_goal))
        }
        start, goal = sample_start_goals(
            streams, idx, self.room_half_size, given["start"], given["goal"]
        )
        self._check_poses(start, goal, radius)
        if task.fixed_obstacles is not None:
            self._check_fixed_layout(start, goal, radius)
            layout = (*room_walls(self.room_half_size), *task.fixed_obstacles)
            self.obstacles.set_shared(idx, layout)
            self.scenery.set_shared(idx, layout)
        elif task.n_obstacles > 0:
            layouts = random_layouts(
                streams,
                idx,
                task.n_obstacles,
                self.room_half_size,
                keep_clear=np.stack([start[:, :2], goal[:, :2]], axis=1),
                clear_radius=radius + 0.25,
                robot_radius=radius,
            )
            self.obstacles.set_arrays(idx, layouts)
            self.scenery.set_layouts(idx, layouts)
        else:
            walls = tuple(room_walls(self.room_half_size))
            self.obstacles.set_shared(idx, walls)
            self.scenery.set_shared(idx, walls)
        self.pose[idx] = start
        self.estimate[idx] = start
        self.goal[idx] = goal
        values: dict[str, FloatArray] = {
            k: np.full(idx.size, v) for k, v in self.fixed_values.items()
        }
        for key, (lo, hi) in self.randomize.items():
            values[key] = streams.uniform(idx, lo, hi)[:, 0]
        if self.randomize or self.fixed_values:
            self.drive.set_values(idx, values)
        self.drive.reset(idx)
        self.ticks[idx] = 0.0
        self.steps[idx] = 0
        self._measure_scan(idx)
        dist, ang = self._pose_error()
        self.prev[idx, 0], self.prev[idx, 1] = dist[idx], ang[idx]

    def _check_poses(self, start: FloatArray, goal: FloatArray, radius: float) -> None:
        """The errors of :meth:`NavTask.sample_start_goal` for given poses that are not
        finite or lie outside the room (raised for the first such robot)."""
        limit = self.room_half_size - radius
        for name, pose in (("start", start), ("goal", goal)):
            bad = ~np.all(np.isfinite(pose), axis=1)
            if bad.any():
                check_finite(name, pose[np.flatnonzero(bad)[0]], (3,))
            out = np.any(np.abs(pose[:, :2]) > limit, axis=1)
            if out.any():
                xy = pose[np.flatnonzero(out)[0], :2]
                raise ValueError(
                    f"{name} {xy.tolist()} lies outside the room (|x|, |y| must be < {limit:.3f} m)"
                )

    def _check_fixed_layout(self, start: FloatArray, goal: FloatArray, radius: float) -> None:
        """The checks of :meth:`NavTask.sample_arena` on a fixed layout, for every robot: the
        start clear of the obstacles, and a route to the goal (the layout's grid labelled
        once; a robot whose start or goal cell is blocked there is checked on its own)."""
        layout = list(self.task.fixed_obstacles or [])
        h = self.room_half_size
        if layout:
            clear = np.min(np.stack([p.footprint_distance(start[:, :2]) for p in layout]), 0)
            bad = np.flatnonzero(clear <= radius)
            if bad.size:
                raise ValueError(
                    f"the start pose {start[bad[0]].tolist()} overlaps an obstacle of the "
                    "given layout"
                )
        prims = layout + room_walls(h)
        resolution = 0.05
        if self._fixed_routes is None:
            from scipy import ndimage

            xy = room_grid(h, resolution)
            free = clearance(prims, xy) > radius
            free &= (np.abs(xy[..., 0]) < h - radius) & (np.abs(xy[..., 1]) < h - radius)
            self._fixed_routes = (free, ndimage.label(free)[0])
        free, labels = self._fixed_routes
        n = free.shape[0]
        cells = [np.rint((p[:, :2] + h) / resolution).astype(np.intp) for p in (start, goal)]
        inside = np.all((cells[0] >= 0) & (cells[0] < n) & (cells[1] >= 0) & (cells[1] < n), 1)
        s = np.where(inside[:, None], cells[0], 0)
        g = np.where(inside[:, None], cells[1], 0)
        plain = inside & free[s[:, 0], s[:, 1]] & free[g[:, 0], g[:, 1]]
        ok = plain & (labels[s[:, 0], s[:, 1]] == labels[g[:, 0], g[:, 1]])
        for j in np.flatnonzero(inside & ~plain):
            ok[j] = free_route_exists(prims, start[j, :2], goal[j, :2], radius, h, resolution)
        bad = np.flatnonzero(~ok)
        if bad.size:
            j = bad[0]
            raise ValueError(
                f"the given obstacle layout leaves no collision-free route from start "
                f"{start[j, :2].tolist()} to goal {goal[j, :2].tolist()} for a robot of radius "
                f"{radius:.3f} m"
            )

    def _pose_error(self) -> tuple[FloatArray, FloatArray]:
        d = self.pose - self.goal
        dist = np.hypot(d[:, 0], d[:, 1])
        ang = np.abs((d[:, 2] + math.pi) % (2.0 * math.pi) - math.pi)
        return dist, ang

    def _collisions(self) -> npt.NDArray[np.bool_]:
        return (
            self.scenery.clearance(self.pose[:, :2]) < self.true_params.body_radius + CONTACT_MARGIN
        )

    def _update_estimate(self) -> None:
        """Wheel odometry on quantised counts (the increments of
        :class:`~realitygap.estimators.diffdrive_model.WheelOdometry`)."""
        ticks = np.floor(self.drive.encoder_angles() * self._ticks_per_rad)
        s = (ticks - self.ticks) * self._odo_m_per_tick
        self.ticks = ticks
        ds = 0.5 * (s[:, 0] + s[:, 1])
        dth = (s[:, 1] - s[:, 0]) / self._odo_wheelbase
        est = self.estimate
        with np.errstate(divide="ignore", invalid="ignore"):
            small = np.abs(dth) < 1e-9
            f1 = np.where(small, 1.0 - dth**2 / 6.0, np.sin(dth) / np.where(small, 1.0, dth))
            f2 = np.where(small, dth / 2.0, (1.0 - np.cos(dth)) / np.where(small, 1.0, dth))
        dx, dy = ds * f1, ds * f2
        c, sn = np.cos(est[:, 2]), np.sin(est[:, 2])
        est[:, 0] += c * dx - sn * dy
        est[:, 1] += sn * dx + c * dy
        est[:, 2] = (est[:, 2] + dth + math.pi) % (2.0 * math.pi) - math.pi

    def _measure_scan(self, idx: npt.NDArray[np.intp]) -> None:
        """Analytic scan with depth noise for robots ``idx`` (as ``PlanarScanner.scan_fast``)."""
        cam = self.true_params.camera
        mount = self.drive.mount[idx]
        pose = self.pose[idx]
        c, s = np.cos(pose[:, 2]), np.sin(pose[:, 2])
        origin = np.column_stack(
            [
                pose[:, 0] + c * mount[:, 0] - s * mount[:, 1],
                pose[:, 1] + s * mount[:, 0] + c * mount[:, 1],
            ]
        )
        # beam directions by the angle-sum identities (no trigonometry per beam)
        co, so = self._beam_cos[None, :], self._beam_sin[None, :]
        ya = mount[:, 2]
        cy, sy = np.cos(ya)[:, None], np.sin(ya)[:, None]
        cb, sb = cy * co - sy * so, sy * co + cy * so  # bearing in the base frame
        ch, sh = c[:, None] * cb - s[:, None] * sb, s[:, None] * cb + c[:, None] * sb
        dirs = np.stack([ch, sh], axis=-1)
        ranges = self.scenery.ray_cast(
            idx, origin, dirs, cam.range_max, half_fov=float(np.ptp(self._beam_offsets)) / 2.0
        )
        ranges += mount[:, 0, None] * cb + mount[:, 1, None] * sb
        sigma = cam.depth_noise_a + cam.depth_noise_b * ranges * ranges
        ranges += self.noise_rng.standard_normal(ranges.shape) * np.where(
            np.isfinite(sigma), sigma, 0.0
        )
        np.maximum(ranges, cam.range_min, out=ranges)
        self.scan[idx] = ranges

    def _observation(self) -> npt.NDArray[np.float32]:
        n = self.num_envs
        est, goal = self.estimate, self.goal
        c, s = np.cos(est[:, 2]), np.sin(est[:, 2])
        dx, dy = goal[:, 0] - est[:, 0], goal[:, 1] - est[:, 1]
        obs = np.empty((n, 12 + self.n_beams), dtype=np.float64)
        obs[:, 0], obs[:, 1], obs[:, 2], obs[:, 3] = est[:, 0], est[:, 1], c, s
        obs[:, 4], obs[:, 5] = goal[:, 0], goal[:, 1]
        obs[:, 6], obs[:, 7] = np.cos(goal[:, 2]), np.sin(goal[:, 2])
        obs[:, 8], obs[:, 9] = c * dx + s * dy, -s * dx + c * dy
        obs[:, 10] = self.drive.cmd[:, 0] / self.params.v_max
        obs[:, 11] = self.drive.cmd[:, 1] / self.params.w_max
        np.divide(self.scan, self.scan_range_max, out=obs[:, 12:])
        np.minimum(obs[:, 12:], 1.0, out=obs[:, 12:])
        out = obs.astype(np.float32)
        np.clip(out, self._obs_low, self._obs_high, out=out)
        return out

    def _info(
        self,
        collision: npt.NDArray[np.bool_],
        success: npt.NDArray[np.bool_],
        dist: FloatArray | None = None,
        ang: FloatArray | None = None,
        terms: Mapping[str, FloatArray] | None = None,
    ) -> dict[str, Any]:
        if dist is None or ang is None:
            dist, ang = self._pose_error()
        return {
            "true_pose": self.pose.copy(),
            "estimated_pose": self.estimate.copy(),
            "goal": self.goal.copy(),
            "pos_error": dist,
            "heading_error": ang,
            "collision": collision,
            "is_success": success,
            "t": self.steps * self.dt,
            "reward_terms": {k: np.asarray(v, dtype=float) for k, v in (terms or {}).items()},
        }
