"""Estimators of the arm-calibration set-up: kinematics, coded board, hand–eye, identification.

Pure numpy / scipy / OpenCV. The pieces, in the order a calibration uses them:

* :mod:`.mdh` — 5-parameter MDH tables, forward kinematics, parameter Jacobian;
* :mod:`.coded_board` — absolutely coded checkerboard (unique 8×8 code windows);
* :mod:`.board_detection` — X-corners and their lattice coordinates in an image;
* :mod:`.board_measurement` — camera pose from a partial view of the board;
* :mod:`.board_displacement` — hierarchical displacements between two measurements;
* :mod:`.handeye` — single-axis, two-axis and AX = XB hand–eye calibration;
* :mod:`.residuals` — observations and distance, displacement or position
  residuals with their analytic Jacobian;
* :mod:`.identifiability` — which parameters the observations can identify;
* :mod:`.least_squares` — Kabsch / Wahba alignment and the QR least squares;
* :mod:`.identification` — Gauss–Newton / Levenberg–Marquardt identification;
* :mod:`.calibration` — the end-to-end checks on laser-tracker and eye-in-hand data.
"""

from __future__ import annotations

from .board_displacement import (
    HierarchicalDisplacement,
    cell_under_optical_axis,
    hierarchical_displacement,
    transition_pose,
)
from .board_measurement import (
    BoardMeasurementSettings,
    BoardObservation,
    MeasurementStatus,
    measure_board,
)
from .calibration import (
    ArmCalibrationReport,
    ErrorStats,
    calibrate_fr3,
    calibrate_ur10,
    pair_distance_errors,
    registered_position_errors,
)
from .coded_board import CodedBoard, lfsr_m_sequence, render_board_image, window_statistics
from .handeye import (
    AXXBMethod,
    CircleFit,
    HandEyeResult,
    average_transforms,
    fit_circle_3d,
    fit_plane,
    handeye_single_axis,
    handeye_two_axis,
    solve_ax_xb,
)
from .identifiability import Identifiability, analyse_identifiability
from .identification import IdentificationResult, IdentificationSettings, Solver, identify
from .least_squares import kabsch
from .mdh import (
    MDHTable,
    ParamSet,
    forward_kinematics,
    jacobian_params,
    joint_frames,
    tool_positions,
)
from .residuals import PairObservations, PositionObservations, ResidualMode

__all__ = [
    "AXXBMethod",
    "ArmCalibrationReport",
    "BoardMeasurementSettings",
    "BoardObservation",
    "CircleFit",
    "CodedBoard",
    "ErrorStats",
    "HandEyeResult",
    "HierarchicalDisplacement",
    "Identifiability",
    "IdentificationResult",
    "IdentificationSettings",
    "MDHTable",
    "MeasurementStatus",
    "PairObservations",
    "ParamSet",
    "PositionObservations",
    "ResidualMode",
    "Solver",
    "analyse_identifiability",
    "average_transforms",
    "calibrate_fr3",
    "calibrate_ur10",
    "cell_under_optical_axis",
    "fit_circle_3d",
    "fit_plane",
    "forward_kinematics",
    "handeye_single_axis",
    "handeye_two_axis",
    "hierarchical_displacement",
    "identify",
    "jacobian_params",
    "joint_frames",
    "kabsch",
    "lfsr_m_sequence",
    "measure_board",
    "pair_distance_errors",
    "registered_position_errors",
    "render_board_image",
    "solve_ax_xb",
    "tool_positions",
    "transition_pose",
    "window_statistics",
]
