"""Sliding-window VIO: synthetic runs, rendered images, errors, the batched window solver."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.core.geometry import rot_z
from realitygap.estimators.climb.factors import StateStack, WindowProblem
from realitygap.estimators.climb.measurements import (
    CameraFrame,
    ImuSample,
    RelativeMotion,
    TetherReading,
)
from realitygap.estimators.climb.vio import SlidingWindowVIO, VioConfig
from realitygap.robots.climb_synthetic import (
    ClimbRecording,
    ClimbScenario,
    render_planar_view,
    synthesise_recording,
)

G = np.array([0.0, 0.0, -9.81])


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


@pytest.mark.slow
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


@pytest.mark.slow
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


# ------------------------------------------------------------------ rendered images

K = np.array([[280.0, 0.0, 160.0], [0.0, 280.0, 120.0], [0.0, 0.0, 1.0]])
TEXEL = 0.25 / 1024


@pytest.mark.slow
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
    problem = WindowProblem(
        vio._imu_factors, vis, vio._prior, cfg.gravity_vector, cfg.loss_scale, True
    )
    cost1, D1, B1, b1 = problem.linearise(StateStack.of(states))
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
