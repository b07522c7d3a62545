"""Rigid registration: Kabsch–Umeyama, RANSAC, point-to-point ICP and the transform check."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.estimators.registration import (
    RegistrationError,
    check_transform,
    icp_point_to_point,
    kabsch_umeyama,
    ransac_rigid,
)

# ---------------------------------------------------------------------------
# Kabsch–Umeyama
# ---------------------------------------------------------------------------


def random_rigid(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    return Rotation.random(random_state=rng).as_matrix(), rng.uniform(-2.0, 2.0, 3)


@pytest.mark.parametrize("seed", range(10))
def test_kabsch_recovers_rigid_transform(seed: int) -> None:
    rng = np.random.default_rng(seed)
    R, t = random_rigid(rng)
    P = rng.normal(size=(int(rng.integers(3, 50)), 3))
    R_est, t_est = kabsch_umeyama(P, P @ R.T + t)
    np.testing.assert_allclose(R_est, R, atol=1e-9)
    np.testing.assert_allclose(t_est, t, atol=1e-9)


@pytest.mark.parametrize("seed", range(5))
def test_umeyama_recovers_scale(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    R, t = random_rigid(rng)
    s = rng.uniform(0.2, 5.0)
    P = rng.normal(size=(20, 3))
    R_est, t_est, s_est = kabsch_umeyama(P, s * P @ R.T + t, with_scale=True)
    np.testing.assert_allclose(R_est, R, atol=1e-9)
    np.testing.assert_allclose(t_est, t, atol=1e-9)
    assert s_est == pytest.approx(s, rel=1e-12)


def test_kabsch_zero_weights_ignore_points() -> None:
    rng = np.random.default_rng(3)
    R, t = random_rigid(rng)
    P = rng.normal(size=(30, 3))
    Q = P @ R.T + t
    Q[:10] = rng.normal(size=(10, 3)) * 5.0  # corrupted, weight 0
    w = np.r_[np.zeros(10), rng.uniform(0.5, 2.0, 20)]
    R_est, t_est = kabsch_umeyama(P, Q, weights=w)
    np.testing.assert_allclose(R_est, R, atol=1e-9)
    np.testing.assert_allclose(t_est, t, atol=1e-9)


def test_kabsch_never_returns_a_reflection() -> None:
    rng = np.random.default_rng(4)
    P = rng.normal(size=(20, 3))
    Q = P * [1.0, 1.0, -1.0]  # mirror image: best proper rotation, not the reflection
    R_est, _ = kabsch_umeyama(P, Q)
    assert np.linalg.det(R_est) == pytest.approx(1.0)
    np.testing.assert_allclose(R_est.T @ R_est, np.eye(3), atol=1e-12)


def test_kabsch_errors() -> None:
    P = np.zeros((4, 3))
    with pytest.raises(ValueError, match="P needs at least 3 points, got 2"):
        kabsch_umeyama(P[:2], P[:2])
    with pytest.raises(
        ValueError, match=r"P and Q must have the same shape, got \(4, 3\) and \(5, 3\)"
    ):
        kabsch_umeyama(P, np.zeros((5, 3)))
    with pytest.raises(ValueError, match="weights must be non-negative with a positive sum"):
        kabsch_umeyama(P, P, weights=[1.0, -1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match=r"weights must have shape \(4,\)"):
        kabsch_umeyama(P, P, weights=[1.0, 1.0])
    with pytest.raises(ValueError, match="P has no spread"):
        kabsch_umeyama(P, P, with_scale=True)


# ---------------------------------------------------------------------------
# RANSAC
# ---------------------------------------------------------------------------


def corrupted_cloud(
    seed: int, n: int = 200, outlier_ratio: float = 0.4, noise: float = 0.002
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    R, t = random_rigid(rng)
    P = rng.uniform(-2.0, 2.0, (n, 3))
    Q = P @ R.T + t + rng.normal(0.0, noise, (n, 3))
    outlier = rng.random(n) < outlier_ratio
    Q[outlier] = rng.uniform(-3.0, 3.0, (int(outlier.sum()), 3))
    return P, Q, R, t, ~outlier


@pytest.mark.parametrize("seed", range(5))
def test_ransac_recovers_transform_with_40_percent_outliers(seed: int) -> None:
    P, Q, R, t, inlier = corrupted_cloud(seed)
    R_est, t_est, mask = ransac_rigid(P, Q, 0.01, np.random.default_rng(seed), max_iters=500)
    angle = Rotation.from_matrix(R_est @ R.T).magnitude()
    assert angle < np.deg2rad(0.1)
    assert np.linalg.norm(t_est - t) < 0.005
    assert np.count_nonzero(mask & ~inlier) == 0
    assert np.count_nonzero(mask & inlier) >= 0.98 * np.count_nonzero(inlier)


def test_ransac_is_reproducible_with_the_same_generator() -> None:
    P, Q, *_ = corrupted_cloud(1)
    a = ransac_rigid(P, Q, 0.01, np.random.default_rng(5))
    b = ransac_rigid(P, Q, 0.01, np.random.default_rng(5))
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)


def test_ransac_weighted_refit() -> None:
    """The inlier refit is the weighted Kabsch fit of the inliers."""
    P, Q, *_ = corrupted_cloud(2, noise=0.004)
    w = np.random.default_rng(0).uniform(0.1, 1.0, len(P))
    R, t, mask = ransac_rigid(P, Q, 0.02, np.random.default_rng(1), weights=w)
    R_ref, t_ref = kabsch_umeyama(P[mask], Q[mask], weights=w[mask])
    np.testing.assert_allclose(R, R_ref, atol=1e-12)
    np.testing.assert_allclose(t, t_ref, atol=1e-12)
    with pytest.raises(ValueError, match="weights must be non-negative with a positive sum"):
        ransac_rigid(P, Q, 0.02, np.random.default_rng(1), weights=-w)


def test_ransac_fails_on_unrelated_points() -> None:
    rng = np.random.default_rng(2)
    P, Q = rng.uniform(-2, 2, (60, 3)), rng.uniform(-2, 2, (60, 3))
    with pytest.raises(RegistrationError, match="fewer than min_inliers=20"):
        ransac_rigid(P, Q, 0.01, rng, max_iters=200, min_inliers=20)
    with pytest.raises(RegistrationError, match="5 correspondences, fewer than min_inliers=6"):
        ransac_rigid(P[:5], Q[:5], 0.01, rng)


def test_ransac_errors() -> None:
    P = np.zeros((10, 3))
    rng = np.random.default_rng(0)
    with pytest.raises(
        ValueError, match="threshold_m must be a positive finite distance in m, got 0"
    ):
        ransac_rigid(P, P, 0, rng)
    with pytest.raises(TypeError, match=r"rng must be a numpy\.random\.Generator, got int"):
        ransac_rigid(P, P, 0.01, 42)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="min_inliers must be ≥ 3, got 2"):
        ransac_rigid(P, P, 0.01, rng, min_inliers=2)
    with pytest.raises(ValueError, match=r"confidence must lie in \(0, 1\)"):
        ransac_rigid(P, P, 0.01, rng, confidence=1.0)


# ---------------------------------------------------------------------------
# ICP
# ---------------------------------------------------------------------------


def box_surface_cloud(rng: np.random.Generator, n: int = 1500) -> np.ndarray:
    """Points on the surface of a 2 × 1.5 × 1 m box (well-constrained for ICP)."""
    size = np.array([2.0, 1.5, 1.0])
    pts = rng.uniform(0, 1, (n, 3)) * size
    face = rng.integers(0, 3, n)
    side = rng.integers(0, 2, n)
    pts[np.arange(n), face] = side * size[face]
    return pts - size / 2


@pytest.mark.parametrize("seed", range(4))
def test_icp_converges_from_perturbed_start(seed: int) -> None:
    rng = np.random.default_rng(seed)
    dst = box_surface_cloud(rng)
    R_true = Rotation.from_rotvec(rng.normal(size=3) * 0.05).as_matrix()
    t_true = rng.uniform(-0.05, 0.05, 3)
    src = (dst[rng.permutation(len(dst))[:800]] - t_true) @ R_true  # subset, moved away
    # start from a perturbed guess (≈ 3° and 3 cm off)
    R0 = Rotation.from_rotvec(rng.normal(size=3) * 0.03).as_matrix() @ R_true
    t0 = t_true + rng.uniform(-0.03, 0.03, 3)
    R, t, rms, iterations = icp_point_to_point(src, dst, R0, t0, max_iters=100, tol=1e-10)
    np.testing.assert_allclose(R, R_true, atol=1e-6)
    np.testing.assert_allclose(t, t_true, atol=1e-6)
    assert rms < 1e-6
    assert 1 <= iterations <= 100


def test_icp_with_noise_and_partial_overlap() -> None:
    rng = np.random.default_rng(9)
    dst = box_surface_cloud(rng, 2000)
    R_true = Rotation.from_euler("z", 4.0, degrees=True).as_matrix()
    t_true = np.array([0.04, -0.02, 0.01])
    src = (dst - t_true) @ R_true + rng.normal(0, 0.002, dst.shape)
    src = np.vstack([src[dst[:, 0] > -0.5], rng.uniform(-3, 3, (50, 3))])  # part + clutter
    R, t, rms, _ = icp_point_to_point(src, dst, max_iters=80, tol=1e-9, max_correspondence_m=0.1)
    assert Rotation.from_matrix(R @ R_true.T).magnitude() < np.deg2rad(0.1)
    assert np.linalg.norm(t - t_true) < 0.003
    assert rms < 0.01


def test_icp_zero_weights_ignore_points() -> None:
    rng = np.random.default_rng(4)
    dst = box_surface_cloud(rng)
    R_true = Rotation.from_euler("xyz", [1.0, -2.0, 3.0], degrees=True).as_matrix()
    t_true = np.array([0.02, 0.01, -0.03])
    src = (dst - t_true) @ R_true
    src[:100] += rng.normal(0.0, 0.05, (100, 3))  # corrupted, weight 0
    w = np.r_[np.zeros(100), np.ones(len(src) - 100)]
    R, t, _, _ = icp_point_to_point(src, dst, max_iters=100, tol=1e-12, weights=w)
    np.testing.assert_allclose(R, R_true, atol=1e-6)
    np.testing.assert_allclose(t, t_true, atol=1e-6)


def test_icp_stops_on_rms_change() -> None:
    rng = np.random.default_rng(1)
    dst = box_surface_cloud(rng)
    _, _, _, iterations = icp_point_to_point(dst, dst, max_iters=50, tol=1e-3)
    assert iterations == 1  # already aligned: the first step changes nothing


def test_icp_errors() -> None:
    cloud = np.random.default_rng(0).random((10, 3))
    with pytest.raises(ValueError, match="R0 must be a proper rotation"):
        icp_point_to_point(cloud, cloud, R0=2 * np.eye(3))
    with pytest.raises(ValueError, match="max_iters must be ≥ 1, got 0"):
        icp_point_to_point(cloud, cloud, max_iters=0)
    with pytest.raises(ValueError, match=r"ICP kept 0 correspondences within 0\.01 m"):
        icp_point_to_point(cloud + 10.0, cloud, max_correspondence_m=0.01)
    with pytest.raises(ValueError, match="dst needs at least 3 points, got 2"):
        icp_point_to_point(cloud, cloud[:2])


def test_check_transform() -> None:
    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 3.0]
    np.testing.assert_array_equal(check_transform("T", T), T)
    bad = T.copy()
    bad[3, 0] = 1.0
    with pytest.raises(ValueError, match=r"T must have last row \[0, 0, 0, 1\]"):
        check_transform("T", bad)
    with pytest.raises(ValueError, match="T must be finite"):
        check_transform("T", np.full((4, 4), np.nan))
