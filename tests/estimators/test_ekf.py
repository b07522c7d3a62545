"""Odometry/VO fusion EKF and the Censi mounting-calibration EKF."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from realitygap.core.geometry import se2_between, se2_compose, se2_inverse, wrap_angle
from realitygap.estimators.base import Estimator, WheelTicks
from realitygap.estimators.diffdrive_model import (
    DiffDriveKinematics,
    OdometryNoise,
    arc_increment,
    integrate_arcs,
)
from realitygap.estimators.ekf import (
    AbsolutePoseMeasurement,
    FusionSettings,
    FusionStep,
    LowObservabilityWarning,
    MountingCalibrationEKF,
    MountingNoise,
    MountingStep,
    OdometryIncrement,
    OdomVOFusionEKF,
    RelativePoseMeasurement,
    calibrate_mounting,
    calibrate_mounting_lsq,
    motion_jacobians,
    mounting_observability,
    relative_pose_jacobians,
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


@pytest.mark.parametrize("seed", range(6))
def test_motion_and_relative_pose_jacobians_match(seed: int) -> None:
    rng = np.random.default_rng(10 + seed)
    q = np.array([*rng.uniform(-2, 2, 2), rng.uniform(-3, 3)])
    u = np.array([rng.uniform(-0.1, 0.2), rng.uniform(-0.5, 0.5) * (seed % 3 != 0)])
    F, G = motion_jacobians(q, u[0], u[1])
    np.testing.assert_allclose(
        F, _fd(lambda v: se2_compose(v, arc_increment(u[0], u[1])), q), atol=1e-8
    )
    np.testing.assert_allclose(
        G, _fd(lambda v: se2_compose(q, arc_increment(v[0], v[1])), u), atol=1e-8
    )
    qk = np.array([*rng.uniform(-2, 2, 2), rng.uniform(-3, 3)])
    H_now, H_key = relative_pose_jacobians(q, qk)
    np.testing.assert_allclose(H_now, _fd(lambda v: se2_between(qk, v), q), atol=1e-8)
    np.testing.assert_allclose(H_key, _fd(lambda v: se2_between(v, q), qk), atol=1e-8)


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


# ---------------------------------------------------------------------------
# Odometry + VO fusion
# ---------------------------------------------------------------------------


def _trajectory(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    ds = 0.02 + 0.01 * rng.random(n)
    dth = 0.05 * np.sin(np.arange(n) / 25.0)
    return ds, dth


def test_odometry_only_matches_dead_reckoning() -> None:
    ds, dth = _trajectory(200, 0)
    ekf = OdomVOFusionEKF(settings=FusionSettings(vo_timeout=math.inf))
    assert isinstance(ekf, Estimator)
    ekf.reset([0.2, 0.1, -0.3])
    for k in range(200):
        est = ekf.update(OdometryIncrement(t=0.05 * (k + 1), ds=ds[k], dtheta=dth[k]))
    np.testing.assert_allclose(est.pose, integrate_arcs([0.2, 0.1, -0.3], ds, dth)[-1], atol=1e-12)
    assert est.ok and est.status == "ok"
    assert np.trace(est.cov) > 0
    assert ekf.update(None) is est


def test_wheel_ticks_need_kinematics_and_are_integrated() -> None:
    with pytest.raises(ValueError, match="has no kinematics"):
        OdomVOFusionEKF().update(WheelTicks(0.0, 0, 0, 2796.8))
    ekf = OdomVOFusionEKF(NOMINAL, FusionSettings(vo_timeout=math.inf))
    ekf.reset()
    for k, (l, r) in enumerate([(0, 0), (100, 120), (250, 260)]):
        est = ekf.update(WheelTicks(0.05 * k, l, r, NOMINAL.ticks_per_rev))
    np.testing.assert_allclose(
        est.pose, NOMINAL.integrate(np.zeros(3), [100, 150], [120, 140])[-1], atol=1e-12
    )


def test_relative_vo_updates_correct_biased_odometry() -> None:
    rng = np.random.default_rng(1)
    n, every = 400, 10
    ds, dth = _trajectory(n, 1)
    truth = integrate_arcs(np.zeros(3), ds, dth)
    odo_ds, odo_dth = ds * 1.03, dth + 0.004  # biased odometry
    R = np.diag([1e-3, 1e-3, 2e-3]) ** 2
    ekf = OdomVOFusionEKF()
    ekf.reset()
    key = 0
    for k in range(n):
        t = 0.05 * (k + 1)
        vo = None
        if (k + 1) % every == 0:
            z = se2_between(truth[key], truth[k + 1]) + rng.multivariate_normal(np.zeros(3), R)
            vo = RelativePoseMeasurement(t=t, motion=z, cov=R, keyframe_t=0.05 * key)
            key = k + 1
        est = ekf.update(
            FusionStep(t=t, odometry=OdometryIncrement(t, odo_ds[k], odo_dth[k]), vo=vo)
        )
        assert est.ok
    odo_only = integrate_arcs(np.zeros(3), odo_ds, odo_dth)[-1]
    err_odo = np.hypot(*(odo_only[:2] - truth[-1, :2]))
    err_fused = np.hypot(*(est.pose[:2] - truth[-1, :2]))
    assert err_fused < 0.25 * err_odo
    assert est.extras["n_vo_updates"] == n // every
    # the filter's uncertainty grows more slowly than with odometry alone
    assert np.all(np.isfinite(est.cov))


def test_stochastic_clone_keeps_the_relative_constraint() -> None:
    ekf = OdomVOFusionEKF()
    ekf.reset([1.0, 1.0, 0.3])
    for _ in range(20):
        ekf.predict(0.05, 0.02)
    z = np.array([0.9, 0.15, 0.35])
    ekf.update_relative(z, np.eye(3) * 1e-12, new_keyframe=False)
    np.testing.assert_allclose(se2_between(ekf.keyframe_pose, ekf.x), z, atol=1e-6)
    # the clone was the initial pose, known exactly, so it must not move
    np.testing.assert_allclose(ekf.keyframe_pose, [1.0, 1.0, 0.3], atol=1e-9)


def test_absolute_update_pulls_towards_measurement() -> None:
    ekf = OdomVOFusionEKF()
    ekf.reset()
    for _ in range(50):
        ekf.predict(0.02, 0.0)
    before = ekf.x
    est = ekf.update(
        AbsolutePoseMeasurement(t=1.0, pose=np.array([0.9, 0.1, 0.05]), cov=np.eye(3) * 1e-6)
    )
    assert np.hypot(*(est.pose[:2] - [0.9, 0.1])) < np.hypot(*(before[:2] - [0.9, 0.1]))
    assert est.pose[0] == pytest.approx(0.9, abs=1e-3)


@pytest.mark.parametrize(
    "bad",
    [
        OdometryIncrement(t=0.1, ds=float("nan"), dtheta=0.0),
        OdometryIncrement(t=0.1, ds=0.01, dtheta=float("inf")),
        RelativePoseMeasurement(t=0.1, motion=np.array([np.nan, 0, 0]), cov=np.eye(3)),
        RelativePoseMeasurement(t=0.1, motion=np.zeros(3), cov=np.full((3, 3), np.inf)),
        AbsolutePoseMeasurement(t=0.1, pose=np.array([0, np.inf, 0]), cov=np.eye(3)),
        FusionStep(t=0.1, odometry=OdometryIncrement(t=0.1, ds=float("-inf"), dtheta=0.0)),
    ],
)
def test_non_finite_input_is_rejected_never_nan(bad: object) -> None:
    ekf = OdomVOFusionEKF(settings=FusionSettings(vo_timeout=math.inf))
    ekf.reset([0.5, 0.5, 0.5])
    for k in range(5):
        ekf.update(OdometryIncrement(t=0.01 * k, ds=0.01, dtheta=0.01))
    before_x, before_P = ekf.x, ekf.P
    est = ekf.update(bad)
    assert np.all(np.isfinite(est.pose)) and np.all(np.isfinite(est.cov))
    np.testing.assert_array_equal(est.pose, before_x)
    np.testing.assert_array_equal(est.cov, before_P)
    assert est.extras["n_rejected"] == 1
    assert "rejected: non-finite" in est.status
    est = ekf.update(OdometryIncrement(t=1.0, ds=0.01, dtheta=0.0))
    assert est.status == "ok" and est.extras["n_rejected"] == 1


def test_vo_failure_falls_back_to_odometry_and_recovers() -> None:
    ds, dth = _trajectory(60, 2)
    ekf = OdomVOFusionEKF()
    ekf.reset()
    for k in range(60):
        t = 0.05 * (k + 1)
        lost = RelativePoseMeasurement(t=t, motion=np.full(3, np.nan), cov=np.eye(3), ok=False)
        est = ekf.update(FusionStep(t=t, odometry=OdometryIncrement(t, ds[k], dth[k]), vo=lost))
        assert not est.ok
        assert est.status == "vo_lost: odometry only"
        assert est.extras["n_rejected"] == 0
    np.testing.assert_allclose(est.pose, integrate_arcs(np.zeros(3), ds, dth)[-1], atol=1e-12)
    good = RelativePoseMeasurement(t=3.05, motion=np.zeros(3), cov=np.eye(3) * 1e-4, keyframe_t=3.0)
    est = ekf.update(FusionStep(t=3.05, odometry=OdometryIncrement(3.05, 0.0, 0.0), vo=good))
    assert est.ok and est.status == "ok"


def test_vo_timeout_flags_odometry_only() -> None:
    ekf = OdomVOFusionEKF(settings=FusionSettings(vo_timeout=0.5))
    ekf.reset()
    statuses = [
        ekf.update(FusionStep(t=0.1 * k, odometry=OdometryIncrement(0.1 * k, 0.01, 0.0))).ok
        for k in range(10)
    ]
    assert statuses[:6] == [True] * 6 and statuses[-1] is False
    assert ekf.vo_lost


def test_keyframe_mismatch_and_outlier_gating() -> None:
    ekf = OdomVOFusionEKF(settings=FusionSettings(gate_chi2=16.27, vo_timeout=math.inf))
    ekf.reset()
    for k in range(5):
        ekf.update(OdometryIncrement(t=0.1 * (k + 1), ds=0.02, dtheta=0.0))
    first = RelativePoseMeasurement(t=0.5, motion=np.array([0.1, 0, 0]), cov=np.eye(3) * 1e-4)
    assert ekf.update(first).extras["keyframe_t"] == pytest.approx(0.5)
    for k in range(5, 10):
        ekf.update(OdometryIncrement(t=0.1 * (k + 1), ds=0.02, dtheta=0.0))
    wrong_key = RelativePoseMeasurement(
        t=1.0, motion=np.array([0.2, 0, 0]), cov=np.eye(3) * 1e-4, keyframe_t=0.3
    )
    est = ekf.update(wrong_key)
    assert "does not match the cloned key-frame" in est.status
    assert est.extras["keyframe_t"] == pytest.approx(1.0)
    for k in range(10, 20):
        ekf.update(OdometryIncrement(t=0.1 * (k + 1), ds=0.02, dtheta=0.0))
    outlier = RelativePoseMeasurement(t=2.0, motion=np.array([5.0, 0, 0]), cov=np.eye(3) * 1e-4)
    before = ekf.x
    est = ekf.update(outlier)
    assert est.extras["n_outliers"] == 1 and "VO outlier" in est.status
    np.testing.assert_array_equal(est.pose, before)


def test_fusion_type_errors_and_settings_validation() -> None:
    with pytest.raises(TypeError, match=r"OdomVOFusionEKF\.update expects"):
        OdomVOFusionEKF().update(np.zeros(3))
    with pytest.raises(ValueError, match="vo_timeout must be >= 0"):
        FusionSettings(vo_timeout=-1.0)
    with pytest.raises(ValueError, match="must be finite and >= 0"):
        OdometryNoise(distance_var_per_m=-1.0)
