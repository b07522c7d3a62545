"""Validation of the climbing robot's measurements."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.core.geometry import matrix_from_quat_xyzw
from realitygap.estimators.climb.measurements import (
    CameraFrame,
    ImuSample,
    RelativeMotion,
    TetherReading,
)
from realitygap.estimators.climb.preintegration import Preintegration

K = np.array([[280.0, 0.0, 160.0], [0.0, 280.0, 120.0], [0.0, 0.0, 1.0]])


def test_measurement_errors() -> None:
    with pytest.raises(ValueError, match=r"ImuSample\.gyro"):
        ImuSample(0.0, np.zeros(2), np.zeros(3))
    with pytest.raises(ValueError, match="uint8"):
        CameraFrame(0.0, np.zeros((4, 4)), K)
    with pytest.raises(ValueError, match="camera matrix"):
        CameraFrame(0.0, np.zeros((4, 4), np.uint8), np.eye(2))
    with pytest.raises(ValueError, match="t1 > t0"):
        RelativeMotion(1.0, 1.0, np.eye(3), np.zeros(3), np.eye(6))
    with pytest.raises(ValueError, match="orthonormal"):
        RelativeMotion(0.0, 1.0, 2 * np.eye(3), np.zeros(3), np.eye(6))
    with pytest.raises(ValueError, match="non-negative length"):
        TetherReading(0.0, -1.0)
    with pytest.raises(ValueError, match="dt must be"):
        Preintegration().integrate(np.zeros(3), np.zeros(3), -0.1)
    with pytest.raises(ValueError, match="quat_xyzw"):
        matrix_from_quat_xyzw(np.zeros(4))
