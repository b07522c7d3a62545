"""Pre-integration against closed forms, static init."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.core.geometry import (
    hat,
    so3_exp,
    so3_log,
)
from realitygap.estimators.climb.measurements import ImuSample
from realitygap.estimators.climb.preintegration import Preintegration, static_initialise

G = np.array([0.0, 0.0, -9.81])


# ------------------------------------------------------------------ pre-integration


def _closed_form(omega: np.ndarray, f: np.ndarray, T: float) -> tuple:
    """ΔR, Δv, Δp for constant body rate ω and specific force f (no gravity term)."""
    k = np.linalg.norm(omega)
    K = hat(omega / k)
    s, c = math.sin(k * T), math.cos(k * T)
    dR = np.eye(3) + s * K + (1 - c) * K @ K
    int1 = T * np.eye(3) + (1 - c) / k * K + (T - s / k) * K @ K
    int2 = T**2 / 2 * np.eye(3) + (T / k - s / k**2) * K + (T**2 / 2 - (1 - c) / k**2) * K @ K
    return dR, int1 @ f, int2 @ f


@pytest.mark.parametrize("seed", range(3))
def test_preintegration_matches_constant_rate_closed_form(seed: int) -> None:
    rng = np.random.default_rng(seed)
    omega, f = rng.normal(0, 0.8, 3), rng.normal(0, 3.0, 3)
    bg, ba = rng.normal(0, 0.01, 3), rng.normal(0, 0.1, 3)
    T, n = 1.3, 260
    pre = Preintegration(bg, ba)
    for _ in range(n):
        pre.integrate(omega + bg, f + ba, T / n)
    dR, dv, dp = _closed_form(omega, f, T)
    assert pre.dt == pytest.approx(T)
    np.testing.assert_allclose(pre.delta_R, dR, atol=1e-10)
    np.testing.assert_allclose(pre.delta_v, dv, atol=1e-9)
    np.testing.assert_allclose(pre.delta_p, dp, atol=1e-9)
    # prediction with gravity
    R_i, p_i, v_i = so3_exp(rng.normal(size=3)), rng.normal(size=3), rng.normal(size=3)
    R_j, p_j, v_j = pre.predict(R_i, p_i, v_i, G)
    np.testing.assert_allclose(R_j, R_i @ dR, atol=1e-10)
    np.testing.assert_allclose(v_j, v_i + G * T + R_i @ dv, atol=1e-9)
    np.testing.assert_allclose(p_j, p_i + v_i * T + 0.5 * G * T * T + R_i @ dp, atol=1e-9)


def test_bias_jacobians_first_order() -> None:
    rng = np.random.default_rng(5)
    n, dt = 400, 0.0025
    gyro = rng.normal(0, 0.5, (n, 3)) + 0.3
    acc = rng.normal(0, 2.0, (n, 3)) + np.array([0.0, 0.0, 9.81])
    nominal = Preintegration()
    for k in range(n):
        nominal.integrate(gyro[k], acc[k], dt)
    for dbg, dba in [
        (np.array([2e-3, -1e-3, 3e-3]), np.zeros(3)),
        (np.zeros(3), np.array([0.02, -0.03, 0.01])),
    ]:
        again = Preintegration(dbg, dba)
        for k in range(n):
            again.integrate(gyro[k], acc[k], dt)
        dR, dv, dp = nominal.corrected(dbg, dba)
        change = np.linalg.norm(again.delta_p - nominal.delta_p)
        assert np.linalg.norm(dp - again.delta_p) < 0.03 * change
        assert np.linalg.norm(dv - again.delta_v) < 0.03 * np.linalg.norm(
            again.delta_v - nominal.delta_v
        )
        assert np.linalg.norm(so3_log(dR.T @ again.delta_R)) < 1e-6


def test_preintegration_covariance_closed_form_at_rest() -> None:
    sg, sa = 0.005, 0.05
    pre = Preintegration(gyro_noise_density=sg, accel_noise_density=sa)
    T, n = 2.0, 2000
    for _ in range(n):
        pre.integrate(np.zeros(3), np.zeros(3), T / n)
    C = pre.cov
    np.testing.assert_allclose(C, C.T)
    assert np.all(np.linalg.eigvalsh(C) >= -1e-15)
    np.testing.assert_allclose(np.diag(C)[0:3], sg**2 * T, rtol=1e-9)
    np.testing.assert_allclose(np.diag(C)[3:6], sa**2 * T, rtol=1e-9)
    np.testing.assert_allclose(np.diag(C)[6:9], sa**2 * T**3 / 3, rtol=1e-3)


# ------------------------------------------------------------------ static init


def test_static_initialisation_recovers_bias_and_tilt() -> None:
    rng = np.random.default_rng(1)
    R = Rotation.from_euler("ZYX", [0.0, -0.2, 0.1]).as_matrix()
    bg, n, dt = np.array([0.01, -0.02, 0.005]), 400, 0.005
    f = R.T @ np.array([0, 0, 9.81])
    sg, sa = 0.005 / math.sqrt(dt), 0.05 / math.sqrt(dt)
    samples = [
        ImuSample(k * dt, bg + rng.normal(0, sg, 3), f + rng.normal(0, sa, 3)) for k in range(n)
    ]
    init = static_initialise(samples)
    assert np.all(np.abs(init.bias_gyro - bg) < 4 * sg / math.sqrt(n))
    tilt_err = np.linalg.norm(so3_log(init.R_world_body.T @ R))
    assert tilt_err < 4 * sa / math.sqrt(n) / 9.81 * 2
    assert abs(Rotation.from_matrix(init.R_world_body).as_euler("ZYX")[0]) < 1e-12
    assert init.still and init.t == samples[-1].t
    wobble = np.array([0.0, 0.0, 1.0])
    moving = [ImuSample(s.t, s.gyro + wobble * math.sin(20 * s.t), s.accel) for s in samples]
    assert not static_initialise(moving).still


def test_static_initialisation_errors() -> None:
    few = [ImuSample(0.0, np.zeros(3), [0, 0, 9.81])] * 5
    with pytest.raises(ValueError, match="at least 10"):
        static_initialise(few)
    wrong_units = [ImuSample(0.0, np.zeros(3), [0, 0, 1.0])] * 20
    with pytest.raises(ValueError, match="units"):
        static_initialise(wrong_units)
