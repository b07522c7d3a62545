"""``realitygap/ArmCalib-v0``: choose the measurement poses of a kinematic calibration.

An episode is one calibration campaign of a 6-DOF arm (UR-like, joints 2, 3, 4
parallel; :mod:`realitygap.robots.arm`) with a camera on its flange that looks
at an absolutely coded board on the table. The campaign has a budget of ``K``
attempts; at each step the policy names the next joint configuration. The env

1. moves the arm there and lets the servo settle (refused when out of reach,
   reported when the target collides);
2. captures an image of the board (PyBullet rendering in ``"image"`` mode, the
   board renderer from the true camera pose in ``"fast"`` mode) and reads the
   joint encoders;
3. measures the camera pose against the board (:func:`measure_board`: corners,
   code decoding, PnP; a frame that cannot be measured unambiguously is
   rejected, never mislabelled). The default ``"geometric"`` mode skips the
   image: the camera reports the corners a detector would find, with pixel
   noise, and only the PnP stage runs (:func:`observation_from_corners`) — fast
   enough for reinforcement learning;
4. forms pose pairs with every earlier pose, their hierarchical displacements
   :math:`\\delta' = t + t'` (:func:`hierarchical_displacement`), and identifies
   the MDH parameters and the camera point from the distance-accuracy residuals
   :math:`\\|p_j(u) - p_i(u)\\| - \\|\\delta'_{ij}\\|` (:func:`identify`), from the
   nominal model, once ``min_poses`` poses are in and then every
   ``identify_every`` poses (and always at the last attempt). An estimate that
   fails its sanity checks (not converged, implausible, poorly fitting) is not
   adopted; the previous one stays and ``info`` says why.

The reward is the drop of the positioning error of the current model on a
fixed set of validation poses, measured against the true arm (ground truth the
real cell would not have, reported in ``info``).

Action space — ``Box(-1, 1, (6,), float32)``

=====  =================================================================
idx    meaning
=====  =================================================================
0..5   joint command :math:`q_k = c_k + h_k a_k` (rad), ``c = joint_center``,
       ``h = joint_half_range`` (a box inside the joint limits)
=====  =================================================================

Observation space — ``Box(float32, (83,))``

======  ==================================================================
idx     meaning
======  ==================================================================
0..29   estimated minus nominal MDH parameters, joint by joint
        ``theta, d, a, alpha, beta`` (angles in mrad, lengths in mm; ±50)
30..32  estimated minus nominal camera point in the flange frame (mm; ±50)
33..65  log10 of the singular values of the unit-column-scaled identification
        Jacobian, descending, padded with -12
66      log10 of its condition number (0 before the first identification)
67      identified parameters / 33
68      poses used / K
69      attempts left / K
70      attempts wasted (invalid poses, failed measurements) / K
71      RMS distance residual of the fit (mm, ≤ 10)
72..77  current joint readings mapped to the action box (±2)
78..82  outcome of the last attempt, one-hot: ok, out of reach, collision,
        board not visible, measurement failed (all 0 after reset)
======  ==================================================================

Reward — a named sum (``info["reward_terms"]``): ``error_drop`` = drop of the
validation RMS positioning error (mm) since the last step; ``invalid_pose`` =
``-invalid_penalty`` when the attempt gave no usable measurement
(:class:`.ArmCalibRewardWeights`). Pose sampling, the budget, reward, success and
termination live in :class:`.ArmCalibTask`; the measurement and identification
pipeline in :mod:`realitygap.envs.arm_calib_pipeline`.

Positioning error: the camera point (the identified tool point) predicted by the
model at each validation pose's joint readings, compared with the true point
after the rigid registration that best aligns the two (the base-to-world pose
is not part of a distance calibration).
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from realitygap.core.checks import (
    check_finite_float,
    check_int,
    check_nonnegative_int,
    check_positive_int,
)
from realitygap.envs.arm_calib_pipeline import (
    ArmPoseMeasurement,
    CalibrationEstimate,
    MDHCalibrationEstimator,
    observation_from_corners,
)
from realitygap.envs.common import (
    check_action_array,
    check_bool,
    check_estimator,
    check_instance,
    check_open,
    check_randomize,
    check_reality,
    check_render_mode,
    check_reset_options,
    check_seed,
    check_started,
    check_vector,
    robot_effects,
)
from realitygap.envs.tasks.arm_calib import (
    ArmCalibRewardWeights,
    ArmCalibTask,
    AttemptOutcome,
    ViewConstraints,
)
from realitygap.estimators.arm.board_measurement import BoardMeasurementSettings, measure_board
from realitygap.estimators.arm.coded_board import CodedBoard
from realitygap.estimators.arm.identification import IdentificationSettings
from realitygap.estimators.arm.mdh import MDHTable, tool_positions
from realitygap.robots.arm import ArmParams, ArmRobot, MoveOutcome
from realitygap.robots.arm_cell import BoardPlacement, FlangeCamera, build_arm_scene
from realitygap.robots.effects import Reality, draw_reality
from realitygap.robots.sensors import SensorMode, check_sensor_mode
from realitygap.robots.world import World

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "DEFAULT_JOINT_CENTER",
    "DEFAULT_JOINT_HALF_RANGE",
    "N_OBS",
    "ArmCalibEnv",
    "default_arm_reality",
    "random_arm_reality",
]

MAX_BUDGET = 10_000
"""Most measurement attempts per campaign an env accepts."""

MAX_VALIDATION_POSES = 10_000
"""Most validation poses an env accepts (each costs a forward-kinematics evaluation per step)."""

MIN_POSES = 3
"""Fewest poses an identification can use (``min_poses``; the pairs need three)."""

DEFAULT_MIN_POSES = 8
"""``min_poses`` when none is given; it must not exceed ``budget``."""

ARM_ESTIMATOR_METHODS = {
    "reset": "reset()",
    "update": "update(measurement, force=False)",
}
"""The methods an ``estimator=`` plug-in of ArmCalib must have (as
:class:`~realitygap.envs.arm_calib_pipeline.MDHCalibrationEstimator`), besides an
``estimate`` property."""

DEFAULT_JOINT_CENTER: tuple[float, ...] = (0.0, -1.3, 1.6, -1.87, -1.57, 0.0)
"""Centre of the action box (rad): the camera looks down at the board from about 0.3 m."""
DEFAULT_JOINT_HALF_RANGE: tuple[float, ...] = (0.6, 0.5, 0.6, 0.5, 0.4, math.pi)
"""Half-widths of the action box (rad); about 28 % of it sees the board."""

N_PARAMS = 33  # 30 MDH + 3 tool
N_OBS = 83
_OUTCOMES = ("ok", "out_of_reach", "collision", "board_not_visible", "measurement_failed")
_SV_FLOOR = -12.0


# =========================================================================== realities
def default_arm_reality() -> Reality:
    """The default "real" arm: fixed, realistic geometric errors.

    Joint offsets of about 0.1°, length errors of about 0.5 mm, twists β of about
    0.05° on the parallel rows, twists α of about 0.05°, and a hand–eye error of
    about 1 mm / 0.2°.
    """
    from realitygap.robots.effects import make_effect

    return Reality(
        effects=(
            make_effect(
                "arm_joint_offset",
                dtheta1=1.1e-3,
                dtheta2=-1.9e-3,
                dtheta3=1.4e-3,
                dtheta4=-0.8e-3,
                dtheta5=2.0e-3,
                dtheta6=-1.2e-3,
            ),
            make_effect(
                "arm_link_length",
                dd1=0.4e-3,
                da2=-0.6e-3,
                da3=0.5e-3,
                dd4=-0.3e-3,
                dd5=0.7e-3,
                dd6=-0.4e-3,
            ),
            make_effect("arm_parallel_twist", beta2=0.9e-3, beta3=-0.8e-3),
            make_effect("arm_twist_error", dalpha1=0.7e-3, dalpha4=-0.9e-3, dalpha5=0.6e-3),
            make_effect("arm_handeye_error", dx=0.8e-3, dy=-1.1e-3, dz=0.6e-3, drz=3e-3),
        ),
        name="arm_default_errors",
    )


def random_arm_reality(
    rng: np.random.Generator,
    joint_offset_std: float = math.radians(0.1),
    length_std: float = 0.5e-3,
    beta_std: float = math.radians(0.05),
    alpha_std: float = math.radians(0.05),
    handeye_std: float = 1e-3,
) -> Reality:
    """A "real" arm with random geometric errors of the given standard deviations (rad, m)."""
    from realitygap.robots.effects import make_effect

    def n(std: float) -> float:
        return float(rng.normal(0.0, std))

    return Reality(
        effects=(
            make_effect(
                "arm_joint_offset", **{f"dtheta{k}": n(joint_offset_std) for k in range(1, 7)}
            ),
            make_effect(
                "arm_link_length",
                **{nm: n(length_std) for nm in ("dd1", "da2", "da3", "dd4", "dd5", "dd6")},
            ),
            make_effect("arm_parallel_twist", beta2=n(beta_std), beta3=n(beta_std)),
            make_effect(
                "arm_twist_error",
                **{f"dalpha{k}": n(alpha_std) for k in (1, 4, 5)},
            ),
            make_effect(
                "arm_handeye_error",
                dx=n(handeye_std),
                dy=n(handeye_std),
                dz=n(handeye_std),
                drz=n(3 * handeye_std),
            ),
        ),
        name="arm_random_errors",
    )


# =========================================================================== env
_ENV_ID = "realitygap/ArmCalib-v0"
"""The id the env is registered under (named in its state errors)."""


class ArmCalibEnv(gym.Env[npt.NDArray[np.float32], npt.NDArray[np.float32]]):
    """Kinematic calibration campaign; see the module docstring for spaces and reward.

    Parameters
    ----------
    render_mode : ``None`` or ``"rgb_array"`` (a view of the cell).
    sensor_mode : ``"geometric"`` (default: the corners a detector would report,
        projected from the true camera pose with pixel noise; then PnP), ``"fast"``
        (board renderer from the true camera pose, then :func:`measure_board`) or
        ``"image"`` (PyBullet TinyRenderer, then :func:`measure_board`). The pose
        pairs, displacements and identification downstream are the same.
    params : ArmParams, optional
        The nominal arm (what the controller believes).
    reality : Reality or its dict form (:meth:`Reality.from_dict`), optional
        Effects that make the simulated arm differ from ``params``;
        :func:`default_arm_reality` when omitted.
    randomize_reality : bool
        Draw a new "real" arm (:func:`random_arm_reality`) at every reset
        (the arm body is rebuilt); ``reality`` is then ignored.
    randomize : ``{"effect.param": (low, high)}`` or a
        :class:`~realitygap.robots.effects.Twin` (its boxes), optional
        Draw each campaign's arm as ``reality`` with these parameters drawn uniformly from
        their boxes (the arm body is rebuilt): a domain randomisation, e.g. centred on a
        diagnosis's twin. Not with ``randomize_reality``.
    estimator_reality : Reality, its dict form or a reality file's path, optional
        The transmission the controller is calibrated to (e.g. a diagnosis's twin): the
        estimator and the validation see the link angles inferred from the encoders under
        ``estimator_reality.apply_params(params)`` (its backlash, compliance and encoder
        scales; :meth:`~realitygap.robots.arm.ArmRobot.link_angles_from_encoders`).
    budget : int
        Attempts per campaign ``K``.
    joint_center, joint_half_range : array_like, shape (6,)
        The action box (rad).
    n_validation : int
        Validation poses (drawn once, with ``validation_seed``, where the nominal
        model expects a good view; collision-free).
    min_poses, identify_every : int
        When the pipeline identifies (:class:`MDHCalibrationEstimator`): ``min_poses`` in
        ``[3, budget]``.
    identification : IdentificationSettings, optional
    measurement : BoardMeasurementSettings, optional
    board : CodedBoard, optional
    placement : BoardPlacement, optional
    view : ViewConstraints, optional
    invalid_penalty : float
        Reward lost by an attempt that yields no measurement.
    estimator : MDHCalibrationEstimator, optional
        A configured pipeline instead of the default one: any object with
        ``reset()``, ``update(measurement, force=False)`` and an ``estimate`` property.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}  # noqa: RUF012 (gymnasium's name)
    sensor_modes: tuple[SensorMode, ...] = (SensorMode.GEOMETRIC, SensorMode.FAST, SensorMode.IMAGE)
    """Accepted ``sensor_mode`` values, fastest first."""

    closed: bool = False
    """True once :meth:`close` ran (reset, step and render then refuse)."""

    def __init__(
        self,
        render_mode: str | None = None,
        sensor_mode: str | SensorMode = SensorMode.GEOMETRIC,
        params: ArmParams | None = None,
        reality: Reality | Mapping[str, Any] | str | os.PathLike[str] | None = None,
        randomize_reality: bool = False,
        randomize: Mapping[str, Any] | None = None,
        estimator_reality: Reality | Mapping[str, Any] | str | os.PathLike[str] | None = None,
        budget: int = 20,
        joint_center: npt.ArrayLike = DEFAULT_JOINT_CENTER,
        joint_half_range: npt.ArrayLike = DEFAULT_JOINT_HALF_RANGE,
        n_validation: int = 40,
        validation_seed: int = 20240,
        min_poses: int = DEFAULT_MIN_POSES,
        identify_every: int = 1,
        identification: IdentificationSettings | None = None,
        measurement: BoardMeasurementSettings | None = None,
        board: CodedBoard | None = None,
        placement: BoardPlacement | None = None,
        view: ViewConstraints | None = None,
        invalid_penalty: float = 0.2,
        estimator: MDHCalibrationEstimator | None = None,
    ):
        render_mode = check_render_mode(render_mode, self.metadata["render_modes"])
        self.sensor_mode = check_sensor_mode(sensor_mode, self.sensor_modes)
        budget = check_positive_int(budget, "budget", high=MAX_BUDGET)
        n_validation = check_int(n_validation, "n_validation", low=4, high=MAX_VALIDATION_POSES)
        validation_seed = check_nonnegative_int(validation_seed, "validation_seed")
        too_many = isinstance(min_poses, (int, float)) and min_poses > budget >= MIN_POSES
        min_poses = check_int(
            min_poses,
            "min_poses",
            low=MIN_POSES,
            high=max(budget, MIN_POSES),
            what="a whole number of poses",
            fix=(
                f"min_poses (default {DEFAULT_MIN_POSES}) must not exceed budget={budget}, the "
                "attempts per campaign, or the campaign never identifies: lower min_poses or "
                "raise budget"
                if too_many
                else f"identification needs at least {MIN_POSES} poses, so budget >= {MIN_POSES}"
            ),
        )
        if min_poses > budget:
            raise ValueError(
                f"budget must be at least min_poses={min_poses} (identification needs "
                f"{MIN_POSES} poses or more), got {budget}. Fix: raise budget"
            )
        identify_every = check_positive_int(identify_every, "identify_every")
        invalid_penalty = check_finite_float(
            invalid_penalty, "invalid_penalty", low=0.0, high=100.0
        )
        check_bool(randomize_reality, "randomize_reality")
        params = check_instance(params, "params", ArmParams, default=ArmParams)
        reality = check_reality(reality, "arm", default=default_arm_reality)
        self.randomize = check_randomize(randomize, robot_effects("arm"), "arm's effects")
        if self.randomize and randomize_reality:
            raise ValueError(
                "randomize and randomize_reality are both given; randomize_reality draws "
                "arms of its own and ignores reality. Fix: pass one of them"
            )
        check_instance(identification, "identification", IdentificationSettings, optional=True)
        measurement = check_instance(
            measurement, "measurement", BoardMeasurementSettings, default=BoardMeasurementSettings
        )
        board = check_instance(board, "board", CodedBoard, default=CodedBoard)
        placement = check_instance(placement, "placement", BoardPlacement, default=BoardPlacement)
        view = check_instance(view, "view", ViewConstraints, default=ViewConstraints)
        if estimator is not None:
            check_estimator(
                estimator,
                ARM_ESTIMATOR_METHODS,
                attributes={"estimate": "an estimate property"},
                protocol="as MDHCalibrationEstimator",
            )
        self.render_mode = render_mode
        self.params = params
        self.randomize_reality = bool(randomize_reality)
        self.reality = self.nominal_reality = reality
        self.true_params: ArmParams = self.reality.apply_params(self.params)
        self.believed_params: ArmParams | None = None
        if estimator_reality is not None:
            believed = check_reality(estimator_reality, "arm", name="estimator_reality")
            self.believed_params = believed.apply_params(self.params)
        self.joint_center = _check_vec("joint_center", joint_center)
        self.joint_half_range = _check_vec("joint_half_range", joint_half_range, positive=True)
        self.board = board
        self.placement = placement
        self.measurement_settings = measurement
        self.task = ArmCalibTask(
            params=self.params,
            board=self.board,
            placement=self.placement,
            view=view,
            joint_center=self.joint_center,
            joint_half_range=self.joint_half_range,
            budget=budget,
            weights=ArmCalibRewardWeights(invalid_pose=float(invalid_penalty)),
        )
        self.tool0 = self.params.camera.T_flange_camera()[:3, 3].copy()
        self.estimator = estimator or MDHCalibrationEstimator(
            self.params.mdh,
            self.tool0,
            self.board.cell_size,
            identification,
            min_poses=min_poses,
            identify_every=identify_every,
        )

        self.world = World()
        textured = self.sensor_mode is SensorMode.IMAGE or render_mode == "rgb_array"
        self.robot: ArmRobot
        self.camera: FlangeCamera
        self.robot, self.camera = build_arm_scene(
            self.world, self.true_params, self.board, self.placement, textured=textured
        )
        self.home = self.joint_center.copy()

        self.action_space = spaces.Box(-1.0, 1.0, shape=(6,), dtype=np.float32)
        low = np.full(N_OBS, -50.0, dtype=np.float32)
        high = np.full(N_OBS, 50.0, dtype=np.float32)
        low[33:66], high[33:66] = _SV_FLOOR, 4.0
        low[66], high[66] = 0.0, 16.0
        low[67:71], high[67:71] = 0.0, 1.0
        low[71], high[71] = 0.0, 10.0
        low[72:78], high[72:78] = -2.0, 2.0
        low[78:83], high[78:83] = 0.0, 1.0
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self._obs_low, self._obs_high = low, high

        self.task.validation_q = self.candidate_pool(int(n_validation), int(validation_seed))
        self._truth_cache: FloatArray | None = None
        self._validation_q_cache: FloatArray | None = None
        self._nominal_param_vec = self.params.mdh.params()
        # episode state
        self._q_enc = self.home.copy()
        self._was_reset = False
        self._capture_seconds = 0.0
        self._measure_seconds = 0.0

    # ------------------------------------------------------------------ helpers
    @property
    def nominal_params(self) -> ArmParams:
        """The nominal arm (what the controller and the pipeline believe)."""
        return self.params

    @property
    def capture_seconds(self) -> float:
        """Wall time spent forming images (or corner lists) this episode (s)."""
        return self._capture_seconds

    @property
    def measure_seconds(self) -> float:
        """Wall time spent measuring camera poses this episode (s)."""
        return self._measure_seconds

    def q_from_action(self, action: npt.ArrayLike) -> FloatArray:
        """Joint command (6,) (rad) for a normalised action (clipped to ±1)."""
        a = np.clip(np.asarray(action, dtype=float).reshape(6), -1.0, 1.0)
        return self.joint_center + self.joint_half_range * a

    def action_from_q(self, q: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Normalised action(s) ``(..., 6)`` for joint command(s) (rad); not clipped."""
        return ((np.asarray(q, dtype=float) - self.joint_center) / self.joint_half_range).astype(
            np.float32
        )

    @property
    def budget(self) -> int:
        """Attempts per campaign ``K``."""
        return self.task.budget

    @property
    def validation_q(self) -> FloatArray:
        """Joint commands (n_val, 6) of the validation poses (rad)."""
        return self.task.validation_q

    def candidate_pool(self, n: int, seed: int, max_draws: int = 200_000) -> FloatArray:
        """``n`` joint commands (n, 6) inside the action box that the nominal model
        expects to see the board well (:class:`.ViewConstraints`) and that do not collide.

        Drawn uniformly with ``numpy.random.default_rng(seed)``
        (:meth:`.ArmCalibTask.candidate_pool`).
        """
        return self.task.candidate_pool(n, seed, self.robot.collides_at, max_draws)

    def _true_validation_points(self) -> FloatArray:
        """True camera points (n_val, 3) in the world at the validation readings (cached)."""
        if self._truth_cache is None:
            tp = self.true_params
            q_link = np.array([self.robot.link_target(q, np.ones(6)) for q in self.validation_q])
            self._truth_cache = tool_positions(
                tp.mdh, q_link, tp.camera.T_flange_camera()[:3, 3], tp.T_world_base
            )
        return self._truth_cache

    def validation_errors(self, table: MDHTable, tool: npt.ArrayLike) -> FloatArray:
        """Positioning errors (n_val,) (m) of a model on the validation poses (after the best
        rigid registration)."""
        return self.task.validation_errors(
            table, tool, self._true_validation_points(), self._validation_angles()
        )

    def _validation_angles(self) -> FloatArray | None:
        """The joint angles the model is given for the validation readings: ``None`` (the
        readings) without ``estimator_reality``, else the link angles inferred from them
        under it (cached with the truth, per arm body)."""
        if self.believed_params is None:
            return None
        if self._validation_q_cache is None:
            self._validation_q_cache = np.array(
                [
                    self.robot.link_angles_from_encoders(r, self.believed_params, np.ones(6))
                    for r in self.validation_q
                ]
            )
        return self._validation_q_cache

    # ------------------------------------------------------------------ gym API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[npt.NDArray[np.float32], dict[str, Any]]:
        """Start a campaign at the home configuration (the action box centre)."""
        check_open(self, "reset", _ENV_ID)
        super().reset(seed=check_seed(seed))
        check_reset_options(options, (), "ArmCalib-v0")
        self._was_reset = True
        rng = self.np_random
        if self.randomize_reality:
            self._rebuild(random_arm_reality(rng))
        elif self.randomize:
            self._rebuild(draw_reality(self.nominal_reality, self.randomize, rng))
        self.robot.reset(self.home)
        self._q_enc = self.robot.read_encoders(rng)
        self.estimator.reset()
        self._capture_seconds = 0.0
        self._measure_seconds = 0.0
        est = self.estimator.estimate
        errs = self.validation_errors(est.table, est.tool)
        self.task.reset(errs)
        info = self._info(est, errs, {}, "", None)
        return self._observation(est), info

    def step(
        self, action: npt.ArrayLike
    ) -> tuple[npt.NDArray[np.float32], float, bool, bool, dict[str, Any]]:
        if not self._was_reset or self.closed:
            check_open(self, "step", _ENV_ID)
            check_started(self, False, _ENV_ID)
        a = check_action_array(action, (6,))
        if np.shape(action) != (6,):
            raise ValueError(f"action must have shape (6,), got {np.shape(action)}")
        rng = self.np_random
        q_cmd = self.q_from_action(a)
        last = self.task.begin_attempt()
        outcome, message, board_status, measurement = self._attempt(q_cmd, rng)
        est = self.estimator.update(measurement, force=last)
        errs = self.validation_errors(est.table, est.tool)
        reward, terms = self.task.end_attempt(outcome, errs)
        info = self._info(est, errs, terms, message, board_status)
        info["outcome"] = outcome.value
        return self._observation(est), reward, self.task.is_terminated(), False, info

    def render(self) -> npt.NDArray[np.uint8] | None:
        check_open(self, "render", _ENV_ID)
        if self.render_mode != "rgb_array":
            return None
        return self.world.render_rgb(
            [0.6, 1.2, 1.1], [-0.45, 0.0, 0.1], fov_deg=55.0, near=0.05, far=6.0
        )

    def close(self) -> None:
        self.world.close()
        self.closed = True

    # ------------------------------------------------------------------ internals
    def _rebuild(self, reality: Reality) -> None:
        self.reality = reality
        self.true_params = reality.apply_params(self.params)
        self.robot.remove()
        self.robot = ArmRobot(self.world, self.true_params)
        self.camera = FlangeCamera(self.robot, self.board, self.placement)
        self._truth_cache = None
        self._validation_q_cache = None

    def _attempt(
        self, q_cmd: FloatArray, rng: np.random.Generator
    ) -> tuple[AttemptOutcome, str, str | None, ArmPoseMeasurement | None]:
        move = self.robot.move_to(q_cmd)
        self._q_enc = self.robot.read_encoders(rng)
        if move.outcome is MoveOutcome.OUT_OF_REACH:
            return AttemptOutcome.OUT_OF_REACH, move.message, None, None
        if move.outcome is MoveOutcome.COLLISION:
            return AttemptOutcome.COLLISION, move.message, None, None
        # the optical axis misses the board: no frame could be measured (skip the rendering)
        if not self.camera.axis_hits_board():
            return (
                AttemptOutcome.BOARD_NOT_VISIBLE,
                "the camera's optical axis does not meet the board",
                None,
                None,
            )
        t0 = time.perf_counter()
        cp = self.params.camera  # the pipeline measures with the nominal intrinsics
        if self.sensor_mode is SensorMode.GEOMETRIC:
            uv, ids = self.camera.visible_corners(rng)
            t1 = time.perf_counter()
            obs = observation_from_corners(
                uv, ids, cp.K, cp.dist_array, self.board, self.measurement_settings
            )
        else:
            img = self.camera.capture(self.sensor_mode, rng)
            t1 = time.perf_counter()
            obs = measure_board(img, cp.K, cp.dist_array, self.board, self.measurement_settings)
        self._capture_seconds += t1 - t0
        self._measure_seconds += time.perf_counter() - t1
        if not obs.ok:
            return (
                AttemptOutcome.MEASUREMENT_FAILED,
                f"board measurement failed: {obs.status.value}",
                obs.status.value,
                None,
            )
        return (
            AttemptOutcome.OK,
            "",
            obs.status.value,
            ArmPoseMeasurement(self._joint_angles(), obs),
        )

    def _joint_angles(self) -> FloatArray:
        """What the estimator is told the joints are: the encoder readings, or the link
        angles inferred from them under ``estimator_reality``."""
        if self.believed_params is None:
            return self._q_enc.copy()
        return self.robot.link_angles_from_encoders(self._q_enc, self.believed_params)

    def _observation(self, est: CalibrationEstimate) -> npt.NDArray[np.float32]:
        obs = np.zeros(N_OBS, dtype=np.float64)
        d = est.table.params() - self._nominal_param_vec
        obs[:30] = 1e3 * d  # rad -> mrad, m -> mm
        obs[30:33] = 1e3 * (est.tool - self.tool0)
        obs[33:66] = _SV_FLOOR
        if est.result is not None:
            sv = np.asarray(est.result.singular_values, dtype=float)[:33]
            with np.errstate(divide="ignore"):
                obs[33 : 33 + sv.size] = np.maximum(np.log10(np.maximum(sv, 1e-300)), _SV_FLOOR)
            obs[66] = math.log10(max(est.result.condition_number, 1.0))
            obs[67] = len(est.result.free_params) / N_PARAMS
            obs[71] = 1e3 * est.result.rms_after
        obs[68] = est.n_poses / self.budget
        obs[69] = (self.budget - self.task.attempts) / self.budget
        obs[70] = self.task.wasted / self.budget
        obs[72:78] = (self._q_enc - self.joint_center) / self.joint_half_range
        last = self.task.last_outcome
        if last is not None:
            obs[78 + _OUTCOMES.index(last.value)] = 1.0
        out = obs.astype(np.float32)
        np.clip(out, self._obs_low, self._obs_high, out=out)
        return out

    def _info(
        self,
        est: CalibrationEstimate,
        errs: FloatArray,
        terms: dict[str, float],
        message: str,
        board_status: str | None,
    ) -> dict[str, Any]:
        res = est.result
        return {
            "true_pose": self.robot.T_world_camera(),
            "q_command": self.robot.q_cmd.copy(),
            "q_encoder": self._q_enc.copy(),
            "outcome": None,
            "message": message,
            "measurement_status": board_status,
            "estimate_ok": est.ok,
            "estimate_status": est.status,
            "poses_used": est.n_poses,
            "attempts": self.task.attempts,
            "validation_rms_mm": 1e3 * float(np.sqrt(np.mean(errs**2))),
            "validation_max_mm": 1e3 * float(np.max(errs)),
            "nominal_validation_rms_mm": 1e3 * self.task.error_nominal,
            "free_params": res.free_params if res is not None else (),
            "condition_number": res.condition_number if res is not None else None,
            "fit_rms_mm": 1e3 * res.rms_after if res is not None else None,
            "reward_terms": dict(terms),
            "is_success": self.task.is_success(errs),
        }


def _check_vec(name: str, value: npt.ArrayLike, positive: bool = False) -> FloatArray:
    return check_vector(value, name, (6,), what="one joint angle per joint, rad", positive=positive)
