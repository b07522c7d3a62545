"""The ArmCalib task: spend a budget of measurement poses to calibrate the arm best.

The task draws candidate and validation poses (inside the action box, where the
nominal model expects a good view of the board and the arm does not collide),
counts attempts against the budget, scores each attempt with a named sum of
reward terms and decides success and termination. It reads only what the env
hands it (positioning errors against the true arm, the outcome of an attempt,
a collision test); it never touches the simulation.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

import numpy as np
import numpy.typing as npt

from realitygap.envs.common import check_finite_fields
from realitygap.estimators.arm.calibration import registered_position_errors
from realitygap.estimators.arm.coded_board import CodedBoard
from realitygap.estimators.arm.mdh import MDHTable, joint_frames, tool_positions
from realitygap.robots.arm import ArmParams
from realitygap.robots.arm_cell import BoardPlacement

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "ArmCalibRewardWeights",
    "ArmCalibTask",
    "AttemptOutcome",
    "ViewConstraints",
    "nominal_view_ok",
]


class AttemptOutcome(str, Enum):
    """What became of one attempted measurement pose."""

    OK = "ok"
    OUT_OF_REACH = "out_of_reach"
    COLLISION = "collision"
    BOARD_NOT_VISIBLE = "board_not_visible"
    MEASUREMENT_FAILED = "measurement_failed"


@dataclass(frozen=True)
class ViewConstraints:
    """When the nominal model expects the camera to see the board well.

    Attributes
    ----------
    max_tilt_deg : float
        Largest angle between the optical axis and the board normal (deg).
    min_distance, max_distance : float
        Range along the optical axis to the board plane (m).
    board_margin : float
        The optical axis must meet the board at least this far inside its edge (m).
    """

    max_tilt_deg: float = 35.0
    min_distance: float = 0.22
    max_distance: float = 0.42
    board_margin: float = 0.12

    def __post_init__(self) -> None:
        check_finite_fields(self)
        if not 0.0 < self.max_tilt_deg < 90.0:
            raise ValueError(f"max_tilt_deg must be in (0, 90), got {self.max_tilt_deg}")
        if not 0.0 < self.min_distance < self.max_distance:
            raise ValueError("need 0 < min_distance < max_distance (m)")
        if self.board_margin < 0:
            raise ValueError("board_margin must be >= 0 (m)")


def nominal_view_ok(
    params: ArmParams,
    board: CodedBoard,
    placement: BoardPlacement,
    q: npt.ArrayLike,
    view: ViewConstraints | None = None,
) -> npt.NDArray[np.bool_]:
    """Whether the board is expected in good view at joint readings ``q`` (N, 6) (nominal model).

    Returns
    -------
    ndarray of bool, shape (N,)
    """
    v = view or ViewConstraints()
    qa = np.atleast_2d(np.asarray(q, dtype=float))
    F = joint_frames(params.mdh, qa, params.T_world_base)[:, -1] @ params.camera.T_flange_camera()
    C = np.linalg.inv(placement.T_world_board()) @ F  # camera in board
    z = C[:, :3, 2]
    c = C[:, :3, 3]
    facing = z[:, 2] > math.cos(math.radians(v.max_tilt_deg))
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.where(facing, -c[:, 2] / z[:, 2], np.nan)
    hit = c + lam[:, None] * z
    m, s = v.board_margin, board.side
    inside = (hit[:, 0] > m) & (hit[:, 0] < s - m) & (hit[:, 1] > m) & (hit[:, 1] < s - m)
    return facing & inside & (lam > v.min_distance) & (lam < v.max_distance)


@dataclass(frozen=True)
class ArmCalibRewardWeights:
    r"""Weights of the ArmCalib reward terms.

    With the validation RMS positioning error ``e`` (m) before (``e⁻``) and after
    an attempt:

    .. math::

        r = w_e (e^- - e) - w_i [\text{attempt gave no usable measurement}]

    Parameters
    ----------
    error_drop : float
        ``w_e``, per metre of error drop (1000: the term is in mm).
    invalid_pose : float
        ``w_i``, penalty on an attempt that yields no measurement.
    """

    error_drop: float = 1e3
    invalid_pose: float = 0.2

    def __post_init__(self) -> None:
        check_finite_fields(self)


class ArmCalibTask:
    """A calibration campaign of ``budget`` attempted measurement poses.

    Parameters
    ----------
    params : ArmParams
        The nominal arm (for the expected view of the board).
    board : CodedBoard
    placement : BoardPlacement
    view : ViewConstraints
    joint_center, joint_half_range : ndarray, shape (6,)
        The action box (rad).
    budget : int
        Attempts per campaign ``K``.
    weights : ArmCalibRewardWeights
    success_rms_mm : float
        Validation RMS positioning error (mm) at or below which the campaign succeeds.
    """

    def __init__(
        self,
        *,
        params: ArmParams,
        board: CodedBoard,
        placement: BoardPlacement,
        view: ViewConstraints,
        joint_center: FloatArray,
        joint_half_range: FloatArray,
        budget: int,
        weights: ArmCalibRewardWeights = ArmCalibRewardWeights(),
        success_rms_mm: float = 0.1,
    ) -> None:
        if int(budget) != budget or budget < 1:
            raise ValueError(f"budget must be a positive whole number of poses, got {budget!r}")
        self.params = params
        self.board = board
        self.placement = placement
        self.view = view
        self.joint_center = joint_center
        self.joint_half_range = joint_half_range
        self.budget = int(budget)
        self.weights = weights
        self.success_rms_mm = float(success_rms_mm)
        self.validation_q = np.zeros((0, 6))
        self.attempts = 0
        self.wasted = 0
        self.last_outcome: AttemptOutcome | None = None
        self.error = 0.0
        self.error_nominal = 0.0

    # ------------------------------------------------------------------ poses
    def candidate_pool(
        self,
        n: int,
        seed: int,
        collides: Callable[[FloatArray], bool],
        max_draws: int = 200_000,
    ) -> FloatArray:
        """``n`` joint commands (n, 6) inside the action box that the nominal model
        expects to see the board well (:class:`ViewConstraints`) and for which
        ``collides(q)`` is False.

        Drawn uniformly with ``numpy.random.default_rng(seed)``.
        """
        rng = np.random.default_rng(seed)
        out: list[FloatArray] = []
        drawn = 0
        while len(out) < n and drawn < max_draws:
            k = max(64, 4 * (n - len(out)))
            q = self.joint_center + self.joint_half_range * rng.uniform(-1.0, 1.0, (k, 6))
            drawn += k
            ok = nominal_view_ok(self.params, self.board, self.placement, q, self.view)
            ok &= np.all(q >= self.params.joint_lower, axis=1) & np.all(
                q <= self.params.joint_upper, axis=1
            )
            for qq in q[ok]:
                if not collides(qq):
                    out.append(qq)
                    if len(out) == n:
                        break
        if len(out) < n:
            raise ValueError(
                f"found only {len(out)} of {n} feasible poses in {drawn} draws; widen the action "
                "box or relax the view constraints"
            )
        return np.array(out)

    def validation_errors(
        self,
        table: MDHTable,
        tool: npt.ArrayLike,
        true_points: FloatArray,
        q: FloatArray | None = None,
    ) -> FloatArray:
        """Positioning errors (n_val,) (m) of a model on :attr:`validation_q` against the
        ``true_points`` (n_val, 3), after the best rigid registration. ``q``: the joint
        angles the model is given for the validation readings (default: the readings)."""
        q = self.validation_q if q is None else q
        p_model = tool_positions(table, q, np.asarray(tool, dtype=float))
        return registered_position_errors(p_model, true_points)

    # ------------------------------------------------------------------ episode
    def reset(self, errors: FloatArray) -> None:
        """Start a campaign; ``errors`` (m) are those of the starting (nominal) model."""
        self.attempts = 0
        self.wasted = 0
        self.last_outcome = None
        self.error = float(np.sqrt(np.mean(errors**2)))
        self.error_nominal = self.error

    def begin_attempt(self) -> bool:
        """Count one attempt; returns whether it is the campaign's last.

        Raises
        ------
        RuntimeError
            If the budget is spent.
        """
        if self.attempts >= self.budget:
            raise RuntimeError("the campaign's budget is spent; call reset()")
        self.attempts += 1
        return self.is_terminated()

    def end_attempt(
        self, outcome: AttemptOutcome, errors: FloatArray
    ) -> tuple[float, dict[str, float]]:
        """Record the ``outcome`` of the attempt and the model's validation ``errors`` (m)
        after it; returns the reward and its named terms."""
        self.last_outcome = outcome
        if outcome is not AttemptOutcome.OK:
            self.wasted += 1
        err = float(np.sqrt(np.mean(errors**2)))
        wt = self.weights
        terms = {
            "error_drop": wt.error_drop * (self.error - err),
            "invalid_pose": -wt.invalid_pose if outcome is not AttemptOutcome.OK else 0.0,
        }
        self.error = err
        return float(sum(terms.values())), terms

    def is_success(self, errors: FloatArray) -> bool:
        """Whether the validation RMS error is at or below ``success_rms_mm``."""
        return bool(errors.size and 1e3 * np.sqrt(np.mean(errors**2)) <= self.success_rms_mm)

    def is_terminated(self) -> bool:
        """The campaign ends when its budget is spent."""
        return self.attempts >= self.budget
