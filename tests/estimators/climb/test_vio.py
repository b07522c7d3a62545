"""VIO: SO(3) helpers, pre-integration against closed forms, static init, front-end, window."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.core.geometry import (
    hat,
    matrix_from_quat_xyzw,
    quat_xyzw_from_matrix,
    right_jacobian,
    right_jacobian_inv,
    rot_z,
    so3_exp,
    so3_log,
)
from realitygap.estimators.climb.vio import (
    CameraFrame,
    ImuSample,
    Preintegration,
    RelativeMotion,
    SlidingWindowVIO,
    TetherReading,
    VioConfig,
    relative_motion_from_images,
    static_initialise,
)
from realitygap.robots.blade_geometry import blade_texture
from realitygap.robots.climb_synthetic import (
    ClimbRecording,
    ClimbScenario,
    render_planar_view,
    synthesise_recording,
)

G = np.array([0.0, 0.0, -9.81])


# ------------------------------------------------------------------ SO(3)


@pytest.mark.parametrize("seed", range(3))
def test_so3_exp_log_and_jacobians(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for phi in [
        rng.normal(size=3),
        1e-9 * rng.normal(size=3),
        (np.pi - 1e-4) * np.array([0.6, 0.0, 0.8]),
    ]:
        R = so3_exp(phi)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(R, Rotation.from_rotvec(phi).as_matrix(), atol=1e-12)
        np.testing.assert_allclose(so3_log(R), phi, atol=1e-8)
        np.testing.assert_allclose(
            right_jacobian_inv(phi) @ right_jacobian(phi), np.eye(3), atol=1e-9
        )
    phi = rng.normal(size=3)
    delta = 1e-6 * rng.normal(size=3)
    lhs = so3_exp(phi + delta)
    rhs = so3_exp(phi) @ so3_exp(right_jacobian(phi) @ delta)
    np.testing.assert_allclose(lhs, rhs, atol=1e-11)
    a, b = rng.normal(size=3), rng.normal(size=3)
    np.testing.assert_allclose(hat(a) @ b, np.cross(a, b))
    q = quat_xyzw_from_matrix(so3_exp(phi))
    assert q[3] >= 0
    np.testing.assert_allclose(matrix_from_quat_xyzw(q), so3_exp(phi), atol=1e-12)


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


# ------------------------------------------------------------------ window on synthetic data


def _world_truth(rec: ClimbRecording, vio: SlidingWindowVIO, t: np.ndarray) -> np.ndarray:
    """Ground truth in the VIO world frame (body frame at the static init, yaw only)."""
    assert vio.static_init is not None
    p0, R0 = rec.truth_at(vio.static_init.t)
    psi = Rotation.from_matrix(R0[0]).as_euler("ZYX")[0]
    p, _ = rec.truth_at(t)
    return (p - p0[0]) @ rot_z(psi)


@pytest.fixture(scope="module")
def loop_recording() -> ClimbRecording:
    return synthesise_recording(ClimbScenario(), np.random.default_rng(0), sweep=False)


def _run(vio: SlidingWindowVIO, measurements: list) -> list:
    out, n = [], 0
    for m in measurements:
        if isinstance(m, TetherReading):
            continue
        est = vio.update(m)
        assert np.all(np.isfinite(est.position)) and np.all(np.isfinite(est.quat_xyzw))
        if vio.keyframe_count != n:
            n = vio.keyframe_count
            out.append(vio.keyframe_estimate())
    return out


def test_vio_synthetic_run_has_bounded_drift(loop_recording: ClimbRecording) -> None:
    vio = SlidingWindowVIO()
    kfs = _run(vio, list(loop_recording.measurements))
    t = np.array([k.t for k in kfs])
    p = np.array([k.position for k in kfs])
    truth = _world_truth(loop_recording, vio, t)
    err = np.linalg.norm(p - truth, axis=1)
    distance = np.sum(np.linalg.norm(np.diff(truth, axis=0), axis=1))
    assert distance > 2.0
    assert err.max() < 0.02 * distance  # < 2 % of the distance travelled
    assert all(k.status == "ok" for k in kfs[2:])
    assert np.all(np.linalg.eigvalsh(kfs[-1].cov) > 0)
    assert kfs[-1].frame == "world" and kfs[-1].ok


def test_tracking_loss_falls_back_to_imu(loop_recording: ClimbRecording) -> None:
    ms = [
        m
        for m in loop_recording.measurements
        if not isinstance(m, TetherReading)
        and (m.t1 if isinstance(m, RelativeMotion) else m.t) < 9.0
    ]
    lost = [
        dataclasses.replace(m, ok=False)
        if isinstance(m, RelativeMotion) and 6.0 < m.t1 < 7.0
        else m
        for m in ms
    ]
    vio = SlidingWindowVIO()
    kfs = _run(vio, lost)
    during = [k for k in kfs if 6.0 < k.t < 7.0]
    after = [k for k in kfs if k.t > 7.05]
    assert during and all(k.status == "imu_only" and not k.ok for k in during)
    assert after and after[-1].status == "ok"
    t = np.array([k.t for k in kfs])
    err = np.linalg.norm(
        np.array([k.position for k in kfs]) - _world_truth(loop_recording, vio, t), axis=1
    )
    assert err.max() < 0.1


def test_scipy_solver_agrees(loop_recording: ClimbRecording) -> None:
    ms = [
        m
        for m in loop_recording.measurements
        if not isinstance(m, TetherReading)
        and (m.t1 if isinstance(m, RelativeMotion) else m.t) < 2.2
    ]
    a = _run(SlidingWindowVIO(VioConfig(window_size=3)), ms)
    b = _run(
        SlidingWindowVIO(VioConfig(window_size=3, solver="scipy", loss="linear", max_iterations=6)),
        ms,
    )
    assert len(a) == len(b)
    np.testing.assert_allclose(a[-1].position, b[-1].position, atol=2e-4)


# ------------------------------------------------------------------ visual front-end

K = np.array([[280.0, 0.0, 160.0], [0.0, 280.0, 120.0], [0.0, 0.0, 1.0]])
DOWN = np.diag([1.0, -1.0, -1.0])  # camera looking along -z of the plane frame
TEXEL = 0.25 / 1024


@pytest.fixture(scope="module")
def texture() -> np.ndarray:
    return blade_texture(np.random.default_rng(0), 1024)


def test_homography_front_end_recovers_metric_motion(texture: np.ndarray) -> None:
    c0 = np.array([0.11, 0.07, 0.06])
    R0 = DOWN
    R1 = rot_z(np.deg2rad(3.0)) @ Rotation.from_euler("x", 1.0, degrees=True).as_matrix() @ DOWN
    c1 = c0 + np.array([0.008, -0.005, 0.0])
    img0 = render_planar_view(texture, TEXEL, K, (320, 240), R0, c0)
    img1 = render_planar_view(texture, TEXEL, K, (320, 240), R1, c1)
    m = relative_motion_from_images(img0, img1, K, 0.06, t0=0.0, t1=0.1)
    assert m.ok and m.n_inliers > 50
    R_true = R0.T @ R1
    t_true = R0.T @ (c1 - c0)
    assert np.degrees(np.linalg.norm(so3_log(R_true.T @ m.rotation))) < 0.2
    assert np.linalg.norm(m.translation - t_true) < 0.03 * np.linalg.norm(t_true) + 2e-4
    assert np.all(np.linalg.eigvalsh(m.cov) > 0)
    blank = np.full((240, 320), 128, np.uint8)
    assert not relative_motion_from_images(blank, blank, K, 0.06).ok


def test_vio_on_rendered_images(texture: np.ndarray) -> None:
    """Robot on a level textured floor: still, then accelerating along body x."""
    cfg = VioConfig()
    h = 0.08

    def x_of(t: float) -> float:  # smooth start at 1.2 s, 0.1 m/s after 2.2 s
        tau = t - 1.2
        if tau <= 0:
            return 0.0
        if tau <= 1.0:
            return 0.05 * (tau - math.sin(math.pi * tau) / math.pi)
        return 0.05 + 0.1 * (tau - 1.0)

    def a_of(t: float) -> float:
        tau = t - 1.2
        return 0.05 * math.pi * math.sin(math.pi * tau) if 0 < tau <= 1.0 else 0.0

    vio = SlidingWindowVIO(cfg)
    dt, t_end = 0.005, 3.5
    frames = [k * 0.1 for k in range(int(t_end / 0.1) + 1)]
    for k in range(int(t_end / dt) + 1):
        t = k * dt
        vio.update(ImuSample(t, np.zeros(3), [a_of(t + dt / 2), 0.0, 9.81]))
        if any(abs(t - tf) < 1e-9 for tf in frames):
            body = np.array([0.2 + x_of(t), 0.1, h])
            cam = body + cfg.p_bc
            img = render_planar_view(texture, TEXEL, K, (320, 240), cfg.R_bc, cam)
            vio.update(CameraFrame(t, img, K))
    est = vio.estimate()
    assert est.status == "ok"
    np.testing.assert_allclose(est.position, [x_of(est.t), 0.0, 0.0], atol=0.01)


# ------------------------------------------------------------------ errors


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


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"window_size": 1}, "window_size"),
        ({"solver": "ceres"}, "solver"),
        ({"loss": "l1"}, "loss"),
        ({"camera_height": 0.0}, "camera_height"),
        ({"R_body_camera": ((1, 0, 0), (0, 1, 0), (0, 0, -1))}, "proper rotation"),
    ],
)
def test_config_errors(kwargs: dict[str, object], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        VioConfig(**kwargs)  # type: ignore[arg-type]


def test_update_errors() -> None:
    vio = SlidingWindowVIO()
    assert not vio.update(None).ok
    vio.update(ImuSample(1.0, np.zeros(3), [0, 0, 9.81]))
    with pytest.raises(ValueError, match="time order"):
        vio.update(ImuSample(0.5, np.zeros(3), [0, 0, 9.81]))
    with pytest.raises(TypeError, match="ImuSample, CameraFrame"):
        vio.update("frame")  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="VioConfig"):
        SlidingWindowVIO("fast")  # type: ignore[arg-type]


# ------------------------------------------------------------------ window solver


def test_batched_window_linearisation_matches_the_per_factor_reference(
    loop_recording: ClimbRecording,
) -> None:
    """All factors evaluated at once give the per-factor residuals, Jacobians and normal
    equations, also away from the optimum (perturbed states)."""
    from realitygap.estimators.climb import vio as vio_module

    ms = [
        m
        for m in loop_recording.measurements
        if not isinstance(m, TetherReading)
        and (m.t1 if isinstance(m, RelativeMotion) else m.t) < 4.0
    ]
    vio = SlidingWindowVIO()
    _run(vio, ms)
    assert len(vio._states) == vio.config.window_size
    rng = np.random.default_rng(3)
    states = [s.retract(rng.normal(0, 0.02, 15)) for s in vio._states]
    cfg = vio.config
    # one visual factor far off so that its Huber weight is active
    vis = list(vio._vis_factors)
    k = next(i for i, f in enumerate(vis) if f is not None)
    vis[k] = dataclasses.replace(vis[k], dp=vis[k].dp + 0.05)
    vio._vis_factors = vis
    cost0, D0, B0, b0 = vio._normal_equations(vio._factors(states, True), len(states))
    problem = vio_module._WindowProblem(
        vio._imu_factors, vis, vio._prior, cfg.gravity_vector, cfg.loss_scale, True
    )
    cost1, D1, B1, b1 = problem.linearise(vio_module._Stack.of(states))
    assert cost1 == pytest.approx(cost0, rel=1e-12)
    np.testing.assert_allclose(D1, D0, rtol=1e-10, atol=1e-9 * np.abs(D0).max())
    np.testing.assert_allclose(B1, B0, rtol=1e-10, atol=1e-9 * np.abs(B0).max())
    np.testing.assert_allclose(b1, b0, rtol=1e-10, atol=1e-9 * np.abs(b0).max())
    # the dense factorisation solves the block-tridiagonal system
    n = len(states)
    A = D0 + 1e-3 * np.eye(15)
    x, L_last = SlidingWindowVIO._solve_block_tridiagonal(A, B0, b0)
    H = np.zeros((15 * n, 15 * n))
    for i in range(n):
        H[15 * i : 15 * i + 15, 15 * i : 15 * i + 15] = A[i]
        if i < n - 1:
            H[15 * i + 15 : 15 * i + 30, 15 * i : 15 * i + 15] = B0[i]
            H[15 * i : 15 * i + 15, 15 * i + 15 : 15 * i + 30] = B0[i].T
    np.testing.assert_allclose(H @ x.reshape(-1), b0.reshape(-1), atol=1e-8 * np.abs(b0).max())
    cov_last = np.linalg.inv(H)[-15:, -15:]
    L_inv = np.linalg.inv(L_last)
    np.testing.assert_allclose(L_inv.T @ L_inv, cov_last, rtol=1e-6, atol=1e-12)


def test_batched_so3_maps_match_the_scalar_ones() -> None:
    from realitygap.core import geometry

    rng = np.random.default_rng(5)
    phi = np.vstack([rng.normal(0, s, (4, 3)) for s in (1e-9, 1e-5, 1e-2, 1.0)])
    phi = np.vstack([phi, [[0.0, 0.0, 3.1]]])  # near π: the scalar log's branch
    R = geometry.so3_exp_batch(phi)
    for k, v in enumerate(phi):
        np.testing.assert_allclose(R[k], so3_exp(v), atol=1e-14)
        np.testing.assert_allclose(geometry.so3_log_batch(R)[k], so3_log(so3_exp(v)), atol=1e-10)
        np.testing.assert_allclose(
            geometry.right_jacobian_batch(phi)[k], right_jacobian(v), atol=1e-12
        )
        np.testing.assert_allclose(
            geometry.right_jacobian_inv_batch(phi)[k], right_jacobian_inv(v), atol=1e-9
        )


def test_keyframe_estimate_carries_the_refined_previous_keyframe(
    loop_recording: ClimbRecording,
) -> None:
    ms = [
        m
        for m in loop_recording.measurements
        if not isinstance(m, TetherReading)
        and (m.t1 if isinstance(m, RelativeMotion) else m.t) < 3.0
    ]
    vio = SlidingWindowVIO()
    kfs = _run(vio, ms)
    t_prev, p_prev, R_prev = vio.keyframe_estimate().extras["previous_keyframe"]
    assert t_prev == kfs[-2].t
    np.testing.assert_array_equal(p_prev, vio._states[-2].p)
    np.testing.assert_array_equal(R_prev, vio._states[-2].R)
