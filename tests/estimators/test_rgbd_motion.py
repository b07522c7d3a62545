"""Maximum-likelihood and PnP camera motion from RGB-D correspondences."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.estimators.base import CameraIntrinsics
from realitygap.estimators.registration import kabsch_umeyama
from realitygap.estimators.rgbd_motion import (
    motion_covariance_ml,
    point_covariance,
    refine_motion_ml,
    solve_pnp,
)

K = CameraIntrinsics(320, 240, 226.0, 226.0, 160.0, 120.0)
A, B = 0.001, 0.002  # depth noise σ = A + B z² (m)


def _scene(rng: np.random.Generator, n: int = 150):
    """Points seen by both cameras, the true motion, and the points' projections."""
    u, v = rng.uniform(10, 310, n), rng.uniform(10, 230, n)
    z = rng.uniform(0.8, 5.0, n)
    P_cur = np.stack([(u - K.cx) * z / K.fx, (v - K.cy) * z / K.fy, z], 1)
    R = Rotation.from_euler("y", rng.uniform(-0.1, 0.1)).as_matrix()
    t = np.array([rng.uniform(-0.05, 0.05), 0.0, rng.uniform(0.05, 0.2)])
    return P_cur, P_cur @ R.T + t, R, t


def _observe(P: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Back-projection of noisy pixels (0.5 px) and noisy depth (σ = A + B z²)."""
    z = P[:, 2]
    u = K.fx * P[:, 0] / z + K.cx + rng.normal(0, 0.5, len(z))
    v = K.fy * P[:, 1] / z + K.cy + rng.normal(0, 0.5, len(z))
    zn = z + rng.normal(0, 1, len(z)) * (A + B * z * z)
    return np.stack([(u - K.cx) * zn / K.fx, (v - K.cy) * zn / K.fy, zn], 1)


def test_ml_recovers_an_exact_motion_from_a_perturbed_start() -> None:
    P_cur, P_kf, R, t = _scene(np.random.default_rng(0))
    R0 = Rotation.from_rotvec([0.02, -0.03, 0.01]).as_matrix() @ R
    S = point_covariance(P_cur, K, 0.5, A, B)
    R_ml, t_ml = refine_motion_ml(
        P_cur, P_kf, R0, t + 0.03, S, point_covariance(P_kf, K, 0.5, A, B)
    )
    assert np.allclose(R_ml, R, atol=1e-9) and np.allclose(t_ml, t, atol=1e-9)


def test_ml_beats_the_isotropic_fit_under_rgbd_noise() -> None:
    err_ml, err_ls = [], []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        P_cur, P_kf, _R, t = _scene(rng)
        Q_cur, Q_kf = _observe(P_cur, rng), _observe(P_kf, rng)
        R_ls, t_ls = kabsch_umeyama(Q_cur, Q_kf)
        _R_ml, t_ml = refine_motion_ml(
            Q_cur,
            Q_kf,
            R_ls,
            t_ls,
            point_covariance(Q_cur, K, 0.5, A, B),
            point_covariance(Q_kf, K, 0.5, A, B),
        )
        err_ml.append(np.linalg.norm(t_ml - t))
        err_ls.append(np.linalg.norm(t_ls - t))
    assert np.mean(err_ml) < 0.5 * np.mean(err_ls)
    assert np.mean(err_ml) < 0.005


def test_pnp_recovers_a_planted_motion_and_is_seeded() -> None:
    rng = np.random.default_rng(3)
    P_cur, P_kf, R, t = _scene(rng)
    px = np.stack(
        [K.fx * P_cur[:, 0] / P_cur[:, 2] + K.cx, K.fy * P_cur[:, 1] / P_cur[:, 2] + K.cy], 1
    )
    px[:20] += 40.0  # outliers
    out = [solve_pnp(P_kf, px, K, np.random.default_rng(1), 200, 2.0, 8) for _ in range(2)]
    assert out[0] is not None and out[1] is not None
    R_e, t_e, inl = out[0]
    assert np.allclose(R_e, R, atol=1e-6) and np.allclose(t_e, t, atol=1e-6)
    assert not inl[:20].any() and inl[20:].all()
    assert np.array_equal(out[0][0], out[1][0])
    assert solve_pnp(P_kf[:5], px[:5], K, rng, 50, 2.0, 8) is None


@pytest.mark.parametrize("z", [1.0, 4.0])
def test_point_covariance_is_depth_noise_along_the_ray(z: float) -> None:
    P = np.array([[0.0, 0.0, z]])
    C = point_covariance(P, K, 0.5, A, B)[0]
    assert C[2, 2] == pytest.approx((A + B * z * z) ** 2)
    assert C[0, 0] == pytest.approx((0.5 * z / K.fx) ** 2)


def test_ml_motion_covariance_matches_the_scatter_of_the_ml_motion() -> None:
    """Monte Carlo: the predicted covariance of (δθ, δt) is the scatter of the ML motions."""
    rng = np.random.default_rng(3)
    P_cur, P_kf, R, t = _scene(rng, n=80)
    deltas, covs = [], []
    for _ in range(150):
        Pc, Pk = _observe(P_cur, rng), _observe(P_kf, rng)
        S_c, S_k = point_covariance(Pc, K, 0.5, A, B), point_covariance(Pk, K, 0.5, A, B)
        R_ml, t_ml = refine_motion_ml(Pc, Pk, R, t, S_c, S_k)
        d_rot = Rotation.from_matrix(R_ml @ R.T).as_rotvec()
        deltas.append(np.concatenate([d_rot, t_ml - t]))
        covs.append(motion_covariance_ml(Pc, Pk, R_ml, t_ml, S_c, S_k))
    empirical = np.cov(np.array(deltas).T)
    predicted = np.mean(covs, axis=0)
    ratio = np.diag(empirical) / np.diag(predicted)
    assert np.all((ratio > 0.6) & (ratio < 1.6)), ratio


def test_ml_motion_covariance_grows_with_the_residual_scatter() -> None:
    """Inliers whose noise variance is 3× what their covariances say inflate the covariance ~3×;
    fewer inliers give a larger one."""
    rng = np.random.default_rng(4)
    P_cur, P_kf, R, t = _scene(rng, n=120)
    S_c, S_k = point_covariance(P_cur, K, 0.5, A, B), point_covariance(P_kf, K, 0.5, A, B)
    exact = motion_covariance_ml(P_cur, P_kf, R, t, S_c, S_k)
    Pc, Pk = P_cur.copy(), P_kf.copy()
    for _ in range(3):  # three independent draws: three times the modelled variance
        Pc, Pk = Pc + (_observe(P_cur, rng) - P_cur), Pk + (_observe(P_kf, rng) - P_kf)
    noisy = motion_covariance_ml(Pc, Pk, R, t, S_c, S_k)
    ratio = np.diag(noisy) / np.diag(exact)
    assert np.all((ratio > 1.5) & (ratio < 6.0)), ratio
    fewer = motion_covariance_ml(P_cur[:30], P_kf[:30], R, t, S_c[:30], S_k[:30])
    assert np.all(np.diag(fewer) > np.diag(exact))
    with pytest.raises(ValueError, match="at least 3 point pairs"):
        motion_covariance_ml(P_cur[:2], P_kf[:2], R, t, S_c[:2], S_k[:2])
