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
    _pooled_fit,
    end_pose_from_frames,
)
from realitygap.experiments.calib_camera import _loop_closures, _sensor_motions_of
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


@pytest.mark.slow
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


def test_loop_closures_of_a_figure_eight_match_the_true_heading(
    excitation_log: DriveLog,
) -> None:
    """The drive comes back to its start after each circle: every loop closure's net
    wheel heading is ±2π (true body) and its registered heading the true residual turn."""
    from realitygap.estimators.vo_params import VOParams
    from realitygap.robots.diffdrive import DiffDriveParams

    log = excitation_log
    incs, motions = _loop_closures(log, VOParams(seed=3))
    assert 1 <= len(incs) == len(motions) <= 2
    true_kin = nominal_kinematics(DiffDriveParams()).scaled(1.05, 0.98, 1.05)
    _, dtheta = true_kin.increment_from_ticks(incs[:, 0], incs[:, 1])
    turns = np.round(np.asarray(dtheta) / (2 * math.pi))
    assert np.all(np.abs(turns) == 1)
    np.testing.assert_allclose(np.asarray(dtheta) - 2 * math.pi * turns, motions[:, 2], atol=3e-3)
    np.testing.assert_allclose(motions[:, :2], 0.0, atol=0.05)


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
    assert quick.max_iterations == quick.iterations  # the quick run adds no iterations
    with pytest.raises(ValueError, match="iterations <= max_iterations"):
        CalibConfig(iterations=4, max_iterations=3)
    with pytest.raises(ValueError, match="target_error_m"):
        CalibConfig(target_error_m=0.0)


def test_reference_drives_have_the_test_drives_shapes() -> None:
    from realitygap.estimators.diffdrive_model import integrate_arcs

    cfg = CalibConfig()
    refs = cfg.reference_paths()
    ends = {name: integrate_arcs(np.zeros(3), *path, wrap=False)[-1] for name, path in refs.items()}
    np.testing.assert_allclose(ends["straight"], [cfg.straight_length, 0.0, 0.0], atol=1e-9)
    r = cfg.curve_radius
    np.testing.assert_allclose(ends["curve"], [0.0, 2.0 * r, math.pi], atol=1e-9)


def _synthetic_drive(
    rng: np.random.Generator, nominal: object, scales: np.ndarray, mount: np.ndarray, n: int
) -> tuple[np.ndarray, list[np.ndarray | None], np.ndarray]:
    """Tick increments of turns both ways, noisy sensor motions (some missing) and weights."""
    from realitygap.estimators.diffdrive_model import arc_increment
    from realitygap.estimators.mounting_calibration import sensor_motion

    base = rng.uniform(80.0, 200.0, n)
    turn = rng.uniform(-120.0, 120.0, n)
    inc = np.round(np.stack([base - turn, base + turn], 1))
    ds, dth = nominal.scaled(*scales).increment_from_ticks(inc[:, 0], inc[:, 1])  # type: ignore[attr-defined]
    z = np.asarray(sensor_motion(mount, arc_increment(ds, dth)))
    weights = rng.uniform(0.5, 2.0, n)
    z = z + 1e-3 * rng.standard_normal(z.shape) / np.sqrt(weights)[:, None]
    motions: list[np.ndarray | None] = [None if rng.random() < 0.05 else zk for zk in z]
    return inc, motions, weights


@pytest.mark.slow
def test_pooled_fit_over_drives_is_more_precise_than_each_drive() -> None:
    """Independent drives pooled in one fit: scatter of k_b below every single drive's."""
    from realitygap.estimators.diffdrive_model import DiffDriveKinematics

    nominal = DiffDriveKinematics(0.035, 0.035, 0.23, 2578.0)
    scales = np.array([1.05, 0.98, 1.05])
    mount = np.array([0.011, 0.008, -0.017])
    rng = np.random.default_rng(19)
    single: list[list[float]] = [[], [], []]
    pooled: list[float] = []
    for _ in range(24):
        drives = [_synthetic_drive(rng, nominal, scales, mount, 60) for _ in range(3)]
        for i, (inc, motions, w) in enumerate(drives):
            fit = fit_odometry_and_mounting(
                inc, motions, nominal, np.ones(3), np.zeros(3), sensor_weights=w
            )
            single[i].append(fit.scales[2])
        fit = _pooled_fit(drives, nominal, np.ones(3), np.zeros(3))
        pooled.append(fit.scales[2])
        assert fit.n_updates + fit.n_outliers == sum(m is not None for d in drives for m in d[1])
    err_single = [np.sqrt(np.mean((np.array(s) - scales[2]) ** 2)) for s in single]
    err_pooled = np.sqrt(np.mean((np.array(pooled) - scales[2]) ** 2))
    # three independent drives: the pooled error is about 1/sqrt(3) ≈ 0.58 of one drive's
    assert err_pooled < 0.8 * float(np.mean(err_single))
    assert abs(np.mean(pooled) - scales[2]) < 3.0 * err_pooled / np.sqrt(len(pooled)) + 1e-4
    with pytest.raises(ValueError, match="at least one drive"):
        _pooled_fit([], nominal, np.ones(3), np.zeros(3))
