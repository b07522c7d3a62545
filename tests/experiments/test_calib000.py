"""Building blocks of the ``calib000`` experiment and the odometry + mounting fit."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from realitygap.controllers.drives import PathFollower
from realitygap.estimators.odometry_mounting import fit_odometry_and_mounting
from realitygap.experiments import EXPERIMENTS, load_all
from realitygap.experiments.calib000 import (
    CalibConfig,
    _make_calib_env,
    _sensor_motions_of,
    end_pose_from_frames,
)
from realitygap.experiments.drive_harness import (
    DriveLog,
    RecordingOdometry,
    drive,
    figure_eight,
    nominal_kinematics,
    timed_reference,
)


def test_calibrated_reality_is_another_body() -> None:
    from realitygap.robots.diffdrive import DiffDriveParams

    cfg = CalibConfig()
    nominal = DiffDriveParams()
    true = cfg.reality().apply_params(nominal)
    assert true.wheel_radius_left == pytest.approx(1.05 * nominal.wheel_radius_left)
    assert true.wheel_radius_right == pytest.approx(0.98 * nominal.wheel_radius_right)
    assert true.wheelbase == pytest.approx(1.05 * nominal.wheelbase)
    np.testing.assert_allclose(
        np.array(true.camera.mount_xyz[:2]) - nominal.camera.mount_xyz[:2], [0.011, 0.008]
    )
    assert math.degrees(true.camera.mount_yaw - nominal.camera.mount_yaw) == pytest.approx(-1.0)


@pytest.fixture(scope="module")
def excitation_log() -> DriveLog:
    """A short figure-eight of the seed-000 robot, camera frames at 5 Hz (image mode)."""
    from realitygap.robots.diffdrive import DiffDriveParams

    cfg = CalibConfig()
    nominal = nominal_kinematics(DiffDriveParams())
    recorder = RecordingOdometry(nominal.scaled(1.05, 0.98, 1.05))
    env = _make_calib_env(cfg, recorder, 5.0)
    start = np.zeros(3)
    try:
        path = figure_eight(start, ((0.45, 1),))
        return drive(env, recorder, PathFollower(timed_reference(path, 0.35)), start, 3, 4000)
    finally:
        env.close()


def test_online_calibration_recovers_wheelbase_and_diameter_ratio(
    excitation_log: DriveLog,
) -> None:
    from realitygap.estimators.vo_params import VOParams
    from realitygap.robots.diffdrive import DiffDriveParams

    log = excitation_log
    assert not log.collided and len(log.frames) == len(log.frame_index) > 40
    nominal = nominal_kinematics(DiffDriveParams())
    inc, motions, weights, lost = _sensor_motions_of(log, VOParams(seed=3))
    assert lost == 0
    # a UMBmark-like seed: ratio roughly right, wheelbase and mean size unknown
    fit = fit_odometry_and_mounting(
        inc, motions, nominal, [1.03, 0.96, 1.0], np.zeros(3), sensor_weights=weights
    )
    E_d, E_b = fit.scales[1] / fit.scales[0], fit.scales[2]
    assert E_b == pytest.approx(1.05, rel=0.01)
    assert E_d == pytest.approx(0.98 / 1.05, rel=0.01)
    assert fit.observable and fit.n_updates + fit.n_outliers == len(motions)
    assert np.hypot(*(fit.mounting[:2] - [0.011, 0.008])) < 0.01
    # the dead-reckoned drive with the fitted scales stays within a few centimetres
    odo = log.dead_reckon(nominal.scaled(*fit.scales))
    assert np.max(np.hypot(*(odo[:, :2] - log.gt[:, :2]).T)) < 0.03


def test_camera_loop_closure_of_a_frame_on_itself(excitation_log: DriveLog) -> None:
    f0 = excitation_log.frames[0]
    end = end_pose_from_frames([f0, f0], np.array([0.011, 0.008, -0.02]))
    assert end.source == "loop closure" and end.n_inliers >= 40
    np.testing.assert_allclose(end.base_motion, 0.0, atol=1e-6)
    with pytest.raises(ValueError, match="at least two frames"):
        end_pose_from_frames([f0], np.zeros(3))


def test_experiments_are_registered() -> None:
    load_all()
    for name in ("calib000", "vo", "umbmark-real"):
        assert name in EXPERIMENTS
    assert EXPERIMENTS["umbmark-real"].data_subdir == "optiodom_diffdrive"
    quick = CalibConfig.quick()
    assert replace(quick, runs_per_direction=2).iterations == 3
