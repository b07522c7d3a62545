"""The fused odometry + VO observation pipeline."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.estimators.base import CameraIntrinsics, DiffDriveMeasurement, RGBDFrame, WheelTicks
from realitygap.estimators.diffdrive_model import DiffDriveKinematics, WheelOdometry
from realitygap.estimators.pipelines import FusedOdometryVO, VONoise, planar_motion_jacobian
from realitygap.estimators.vo import T_BASE_CAMERA_FORWARD, VOResult

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


def _result(motion_cov: np.ndarray | None, reference: str = "keyframe") -> VOResult:
    T = np.eye(4)
    return VOResult(
        t=0.0,
        T_world_camera=T,
        T_prev_curr=T,
        T_world_keyframe=T,
        pose=np.zeros(3),
        ok=True,
        status="ok",
        keyframe=True,
        reference=reference,
        motion_cov=motion_cov,
    )


def test_planar_jacobian_of_the_forward_mounting_at_rest() -> None:
    """Optical z is base x, optical −x is base y, a turn about optical −y is a base yaw."""
    J = planar_motion_jacobian(np.eye(4), T_BASE_CAMERA_FORWARD)
    expected = np.zeros((3, 6))
    expected[0, 5], expected[1, 3], expected[2, 1] = 1.0, -1.0, -1.0
    np.testing.assert_allclose(J, expected, atol=1e-8)


def test_vo_noise_uses_the_solver_covariance_of_keyframe_motions() -> None:
    noise = VONoise()
    C6 = np.diag([1e-6, 4e-6, 9e-6, 1e-4, 4e-4, 9e-4])
    cov = noise.covariance(np.zeros(3), _result(C6), T_BASE_CAMERA_FORWARD)
    floor = np.diag([noise.xy_floor**2, noise.xy_floor**2, noise.theta_floor**2])
    np.testing.assert_allclose(cov, np.diag([9e-4, 1e-4, 4e-6]) + floor, atol=1e-12)
    # a motion chained through the previous frame, or no solver covariance: the fixed model
    fixed = noise.covariance(np.array([0.1, 0.0, 0.0]))
    for res in (_result(C6, reference="previous_frame"), _result(None)):
        np.testing.assert_allclose(
            noise.covariance(np.array([0.1, 0.0, 0.0]), res, T_BASE_CAMERA_FORWARD), fixed
        )
    off = VONoise(from_inliers=False)
    np.testing.assert_allclose(
        off.covariance(np.array([0.1, 0.0, 0.0]), _result(C6), T_BASE_CAMERA_FORWARD), fixed
    )


class _ScriptedVO:
    """Stands in for the pipeline's VO: returns the results it is given, in turn."""

    def __init__(self, results: list[VOResult]):
        self.results = list(results)

    def reset(self, *_: object) -> None:
        pass

    def update(self, frame: object) -> VOResult:
        return self.results.pop(0)


@pytest.mark.parametrize("status", ["initialised", "reinitialised", "reset"])
def test_a_new_key_frame_chain_measures_no_motion(status: str) -> None:
    """The frame that starts a VO chain carries the identity as its ``T_prev_curr``; it is
    no measurement that the robot stood still since the filter's last key-frame. With the
    robot turning in place, the fused heading must stay the odometry's (it was pulled back
    1.6° by such a frame, which put the goal 4 cm off at the end of a 2 m drive)."""
    fused = FusedOdometryVO(KIN, T_BASE_CAMERA_FORWARD)
    odo = WheelOdometry(KIN)
    fused.reset([0.0, 0.0, 0.0])
    odo.reset([0.0, 0.0, 0.0])
    start = _result(None)
    start = VOResult(**{**start.__dict__, "status": status, "ok": status == "initialised"})
    est = ref = None
    for k in range(1, 9):
        ticks = WheelTicks(0.05 * k, -60 * k, 60 * k, KIN.ticks_per_rev)  # turning left
        if k == 8:
            fused.vo = _ScriptedVO([start])  # type: ignore[assignment]
            est = fused.update(DiffDriveMeasurement(0.05 * k, ticks, rgbd=_blank(0.05 * k)))
        else:
            est = fused.update(DiffDriveMeasurement(0.05 * k, ticks))
        ref = odo.update(ticks)
    assert est is not None and ref is not None
    assert ref.pose[2] > 0.1  # it did turn
    np.testing.assert_allclose(est.pose, ref.pose, atol=1e-9)
