"""Censi mounting-calibration EKF and its batch and least-squares solvers."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from realitygap.core.geometry import se2_compose, se2_inverse, wrap_angle
from realitygap.estimators.base import Estimator
from realitygap.estimators.diffdrive_model import (
    DiffDriveKinematics,
    arc_increment,
)
from realitygap.estimators.mounting_calibration import (
    LowObservabilityWarning,
    MountingCalibrationEKF,
    MountingNoise,
    MountingStep,
    calibrate_mounting,
    calibrate_mounting_lsq,
    mounting_observability,
    sensor_motion,
    sensor_motion_jacobians,
)
from realitygap.estimators.umbmark import umbmark

MOUNT = np.array([0.11, -0.08, 0.3])
NOMINAL = DiffDriveKinematics.from_diameters(0.084, 0.084, 0.20, 2796.8)


def _fd(f, x: np.ndarray, eps: float = 1e-6) -> np.ndarray:  # type: ignore[no-untyped-def]
    cols = []
    for i in range(x.shape[0]):
        e = np.zeros_like(x)
        e[i] = eps
        d = f(x + e) - f(x - e)
        d[..., 2] = wrap_angle(d[..., 2]) if np.ndim(d) == 1 else d[..., 2]
        cols.append(d / (2 * eps))
    return np.stack(cols, axis=-1)


def _curvy_deltas(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    ds = 0.03 + 0.02 * rng.random(n)
    dth = 0.15 * np.sin(np.arange(n) / 15.0) + 0.05 * rng.standard_normal(n)
    return arc_increment(ds, dth)


# ---------------------------------------------------------------------------
# Jacobians
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(6))
def test_sensor_motion_is_conjugation_and_jacobians_match(seed: int) -> None:
    rng = np.random.default_rng(seed)
    l = np.array([*rng.uniform(-0.3, 0.3, 2), rng.uniform(-math.pi, math.pi)])
    d = np.array([*rng.uniform(-0.1, 0.1, 2), rng.uniform(-0.8, 0.8)])
    expected = se2_compose(se2_compose(se2_inverse(l), d), l)
    np.testing.assert_allclose(sensor_motion(l, d), expected, atol=1e-14)
    H_l, H_d = sensor_motion_jacobians(l, d)
    np.testing.assert_allclose(H_l, _fd(lambda v: sensor_motion(v, d), l), atol=1e-8)
    np.testing.assert_allclose(H_d, _fd(lambda v: sensor_motion(l, v), d), atol=1e-8)


# ---------------------------------------------------------------------------
# Mounting calibration
# ---------------------------------------------------------------------------


def test_mounting_calibration_converges_noise_free() -> None:
    deltas = _curvy_deltas(400, seed=1)
    z = sensor_motion(MOUNT, deltas)
    l0 = MOUNT + np.array([0.05, -0.05, math.radians(5.0)])
    l_ekf, P = calibrate_mounting(deltas, z, l0)
    assert np.all(np.abs(l_ekf[:2] - MOUNT[:2]) < 1e-3)
    assert abs(wrap_angle(l_ekf[2] - MOUNT[2])) < math.radians(0.05)
    assert P.shape == (3, 3) and np.all(np.linalg.eigvalsh(P) > 0)
    l_lsq, P_lsq = calibrate_mounting_lsq(deltas, z, l0)
    np.testing.assert_allclose(l_lsq, MOUNT, atol=1e-9)
    np.testing.assert_allclose(np.sqrt(np.diag(P)), np.sqrt(np.diag(P_lsq)), rtol=0.1)


def test_mounting_calibration_with_noise_is_consistent() -> None:
    rng = np.random.default_rng(7)
    deltas = _curvy_deltas(600, seed=2)
    noise = MountingNoise(sensor_std=(2e-3, 2e-3, 2e-3))
    z = sensor_motion(MOUNT, deltas) + rng.normal(0.0, 2e-3, deltas.shape)
    l0 = MOUNT + np.array([-0.04, 0.06, math.radians(-8.0)])
    l_hat, P = calibrate_mounting(deltas, z, l0, noise=noise)
    err = l_hat - MOUNT
    err[2] = wrap_angle(err[2])
    assert np.all(np.abs(err[:2]) < 5e-3) and abs(err[2]) < math.radians(0.5)
    assert np.all(np.abs(err) < 4.0 * np.sqrt(np.diag(P)))
    l_lsq, _ = calibrate_mounting_lsq(deltas, z, l0, noise=noise)
    np.testing.assert_allclose(l_lsq, l_hat, atol=1.5e-3)


def test_straight_motion_leaves_translation_unobservable() -> None:
    n = 300
    deltas = arc_increment(np.full(n, 0.04), np.zeros(n))
    z = sensor_motion(MOUNT, deltas)
    l0 = MOUNT + np.array([0.05, -0.05, math.radians(5.0)])
    with pytest.warns(LowObservabilityWarning, match="low observability of l_x, l_y"):
        l_hat, _ = calibrate_mounting(deltas, z, l0)
    # l_theta is seen through the direction of travel; l_x, l_y stay at the guess
    assert abs(wrap_angle(l_hat[2] - MOUNT[2])) < math.radians(0.05)
    np.testing.assert_allclose(l_hat[:2], l0[:2], atol=1e-6)
    ekf = MountingCalibrationEKF(l0)
    for d, zz in zip(deltas, z):
        ekf.step(d, zz)
    report = ekf.observability()
    assert report.poorly_observable == ("l_x", "l_y") and not report.ok
    with pytest.warns(LowObservabilityWarning, match="l_x, l_y"):
        calibrate_mounting_lsq(deltas, z, l0)


def test_rotation_in_place_confounds_heading_and_direction() -> None:
    n = 200
    deltas = arc_increment(np.zeros(n), np.full(n, 0.1))
    z = sensor_motion(MOUNT, deltas)
    with pytest.warns(LowObservabilityWarning):
        calibrate_mounting_lsq(deltas, z, MOUNT + np.array([0.02, 0.02, 0.1]))


def test_well_excited_data_is_reported_observable() -> None:
    deltas = _curvy_deltas(300, seed=3)
    z = sensor_motion(MOUNT, deltas)
    with warnings.catch_warnings():
        warnings.simplefilter("error", LowObservabilityWarning)
        calibrate_mounting(deltas, z, MOUNT + np.array([0.03, 0.0, 0.05]))


def test_augmented_filter_recovers_odometry_scales_seeded_by_umbmark() -> None:
    rng = np.random.default_rng(11)
    true_kin = NOMINAL.scaled(left=1.012, right=0.992, wheelbase=1.03)
    n = 900
    k = np.arange(n)
    n_l = 200 + 100 * np.sin(k / 20) + 20 * rng.standard_normal(n)
    n_r = 200 + 100 * np.cos(k / 31) + 20 * rng.standard_normal(n)
    ds, dth = true_kin.increment_from_ticks(n_l, n_r)
    z = sensor_motion(MOUNT, arc_increment(ds, dth))
    seed = umbmark([[0.0, 0.0, 0.0]], [[0.0, 0.0, 0.0]], 1.0, 0.2)  # a neutral UMBmark seed
    ekf = MountingCalibrationEKF(
        MOUNT + np.array([0.03, 0.03, 0.05]),
        estimate_odometry=True,
        kinematics=NOMINAL,
        scales0=[seed.c_L, seed.c_R, seed.E_b],
    )
    for i in range(n):
        est = ekf.update(
            MountingStep(t=0.05 * i, odometry=np.array([n_l[i], n_r[i]]), sensor_motion=z[i])
        )
    assert est.status == "ok" and "odometry_scales" in est.extras
    np.testing.assert_allclose(ekf.odometry_scales, [1.012, 0.992, 1.03], atol=5e-4)
    np.testing.assert_allclose(ekf.mounting[:2], MOUNT[:2], atol=1e-3)
    assert abs(wrap_angle(ekf.mounting[2] - MOUNT[2])) < math.radians(0.1)
    assert ekf.observability().ok
    cal = ekf.calibrated_kinematics()
    assert cal.wheelbase == pytest.approx(1.03 * NOMINAL.wheelbase, rel=5e-4)


def test_mounting_filter_tracks_robot_pose_and_is_an_estimator() -> None:
    deltas = _curvy_deltas(100, seed=4)
    ekf = MountingCalibrationEKF(MOUNT, np.diag([1e-6, 1e-6, 1e-6]))
    assert isinstance(ekf, Estimator)
    ekf.reset([1.0, 2.0, 0.5])
    q = np.array([1.0, 2.0, 0.5])
    for i, d in enumerate(deltas):
        est = ekf.update(MountingStep(t=0.1 * i, odometry=d, sensor_motion=sensor_motion(MOUNT, d)))
        q = se2_compose(q, d)
    np.testing.assert_allclose(est.pose, q, atol=1e-9)
    assert np.all(np.isfinite(est.cov))
    bad = ekf.update(MountingStep(t=20.0, odometry=np.array([np.nan, 0, 0])))
    assert bad.status.startswith("rejected") and bad.extras["n_rejected"] == 1
    np.testing.assert_allclose(bad.pose, q, atol=1e-9)


def test_mounting_error_paths() -> None:
    with pytest.raises(ValueError, match=r"deltas must have shape \(N, 3\)"):
        calibrate_mounting(np.zeros((4, 2)), np.zeros((4, 2)), MOUNT)
    with pytest.raises(ValueError, match="same shape as deltas"):
        calibrate_mounting(np.zeros((4, 3)), np.zeros((5, 3)), MOUNT)
    with pytest.raises(ValueError, match="must be finite"):
        calibrate_mounting_lsq([[np.nan, 0, 0]], [[0, 0, 0]], MOUNT)
    with pytest.raises(ValueError, match="needs the nominal kinematics"):
        MountingCalibrationEKF(MOUNT, estimate_odometry=True)
    ekf = MountingCalibrationEKF(MOUNT, estimate_odometry=True, kinematics=NOMINAL)
    with pytest.raises(ValueError, match=r"odometry must have shape \(2,\)"):
        ekf.step(np.zeros(3))
    with pytest.raises(ValueError, match="P must have shape"):
        mounting_observability(np.eye(2), [1.0, 1.0, 1.0])
