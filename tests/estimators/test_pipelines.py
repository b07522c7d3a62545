"""The fused odometry + VO observation pipeline."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.estimators.base import CameraIntrinsics, DiffDriveMeasurement, RGBDFrame, WheelTicks
from realitygap.estimators.diffdrive_model import DiffDriveKinematics, WheelOdometry
from realitygap.estimators.pipelines import FusedOdometryVO
from realitygap.estimators.vo import T_BASE_CAMERA_FORWARD

KIN = DiffDriveKinematics(0.035, 0.035, 0.23, 2578.33)
INTR = CameraIntrinsics(320, 240, 226.0, 208.0, 160.0, 120.0)


def _blank(t: float) -> RGBDFrame:
    rgb = np.full((240, 320, 3), 128, dtype=np.uint8)
    depth = np.full((240, 320), 2.0, dtype=np.float32)
    return RGBDFrame(t, rgb, depth, INTR)


def test_blank_frames_fall_back_to_odometry_and_say_so() -> None:
    fused = FusedOdometryVO(KIN, T_BASE_CAMERA_FORWARD)
    odo = WheelOdometry(KIN)
    fused.reset([1.0, 2.0, 0.3])
    odo.reset([1.0, 2.0, 0.3])
    est = None
    for k in range(10):
        ticks = WheelTicks(0.05 * k, 40 * k, 55 * k, KIN.ticks_per_rev)
        est = fused.update(DiffDriveMeasurement(0.05 * k, ticks, rgbd=_blank(0.05 * k)))
        ref = odo.update(ticks)
    assert est is not None
    assert not est.ok and "odometry only" in est.status
    assert est.extras["vo_status"] == "no_features"
    np.testing.assert_allclose(est.pose, ref.pose, atol=1e-9)
    assert np.all(np.isfinite(est.cov))


def test_update_none_and_wrong_type() -> None:
    fused = FusedOdometryVO(KIN, T_BASE_CAMERA_FORWARD)
    first = fused.reset()
    assert fused.update(None) is first
    with pytest.raises(TypeError, match="DiffDriveMeasurement"):
        fused.update(WheelTicks(0.0, 0, 0, 100.0))
    with pytest.raises(ValueError, match="4x4"):
        FusedOdometryVO(KIN, np.eye(3))
