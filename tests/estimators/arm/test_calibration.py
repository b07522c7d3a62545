"""End-to-end calibration checks on synthetic laser-tracker and eye-in-hand data."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.estimators.arm.calibration import calibrate_fr3, calibrate_ur10
from realitygap.estimators.arm.mdh import MDHTable, forward_kinematics, tool_positions

R_MB = Rotation.from_rotvec([0.01, -0.02, 0.5]).as_matrix()
T_MB = np.array([0.3, -0.2, 0.1])


@dataclass(frozen=True)
class TrackerSeries:
    joint_angles: np.ndarray
    probe_positions: np.ndarray
    probe_in_flange: np.ndarray


@dataclass(frozen=True)
class EyeInHand:
    joint_positions: np.ndarray
    T_board_camera: np.ndarray


def test_calibrate_ur10_on_synthetic_tracker_data() -> None:
    rng = np.random.default_rng(6)
    nominal = MDHTable.ur10()
    true = nominal.with_params(nominal.params() + rng.normal(0, 5e-4, 30))
    probe = np.array([0.0, 0.0, 0.109])
    q = rng.uniform(-np.pi, np.pi, (200, 6))
    m = tool_positions(true, q, probe + np.array([1e-3, 0, 0])) @ R_MB.T + T_MB
    m += rng.normal(0, 2e-5, m.shape)
    rep = calibrate_ur10(TrackerSeries(q, m, probe), np.arange(0, 200, 2), np.arange(1, 200, 2))
    assert rep.calibrated.rms < 0.1 * rep.nominal.rms
    assert rep.improvement == rep.nominal.rms / rep.calibrated.rms > 10
    assert rep.calibrated.rms < 1e-4
    assert rep.n_train == rep.n_test == 100
    assert "calibrated_train_registration" in rep.secondary


def test_calibrate_fr3_on_synthetic_eye_in_hand_data() -> None:
    rng = np.random.default_rng(7)
    nominal = MDHTable.franka_fr3()
    true = nominal.with_params(nominal.params() + rng.normal(0, 5e-4, 35))
    X = np.eye(4)
    X[:3, :3] = Rotation.from_euler("z", np.pi / 2).as_matrix()
    X[:3, 3] = [0.0945, -0.009, 0.04055]
    T_base_board = np.eye(4)
    T_base_board[:3, 3] = [0.66, -0.59, -0.01]
    q = rng.uniform(-1.5, 1.5, (60, 7))
    C = np.linalg.inv(T_base_board) @ forward_kinematics(true, q) @ X
    C[:, :3, 3] += rng.normal(0, 2e-5, (60, 3))
    rep = calibrate_fr3(EyeInHand(q, C), np.arange(0, 60, 2), np.arange(1, 60, 2))
    assert rep.calibrated.rms < 0.2 * rep.nominal.rms
    assert rep.identification.T_meas_base is not None


def test_overlapping_split_is_rejected() -> None:
    q = np.zeros((5, 6))
    m = np.zeros((5, 3))
    with pytest.raises(ValueError, match="overlap"):
        calibrate_ur10(
            TrackerSeries(q, m, np.array([0.0, 0.05, 0.1])), np.arange(3), np.arange(2, 5)
        )
