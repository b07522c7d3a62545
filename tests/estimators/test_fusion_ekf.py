"""Odometry/VO fusion EKF."""

from __future__ import annotations

import math

import numpy as np
import pytest

from realitygap.core.geometry import se2_between, se2_compose, wrap_angle
from realitygap.estimators.base import Estimator, WheelTicks
from realitygap.estimators.diffdrive_model import (
    DiffDriveKinematics,
    OdometryNoise,
    arc_increment,
    integrate_arcs,
)
from realitygap.estimators.fusion_ekf import (
    AbsolutePoseMeasurement,
    FusionSettings,
    FusionStep,
    OdometryIncrement,
    OdomVOFusionEKF,
    RelativePoseMeasurement,
    motion_jacobians,
    relative_pose_jacobians,
)

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


# ---------------------------------------------------------------------------
# Jacobians
# ---------------------------------------------------------------------------


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
