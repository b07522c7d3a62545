"""Graph Transformation Matching and rigid registration (Kabsch, RANSAC, ICP)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import pdist, squareform
from scipy.spatial.transform import Rotation

from realitygap.estimators.vo import (
    RegistrationError,
    check_transform,
    gtm_filter,
    icp_point_to_point,
    kabsch_umeyama,
    ransac_rigid,
)

# ---------------------------------------------------------------------------
# GTM
# ---------------------------------------------------------------------------


def gtm_reference(
    p: np.ndarray, q: np.ndarray, k: int | None = None, tol: float = 0.0
) -> np.ndarray:
    """GTM exactly as written: rebuild both graphs from scratch after every deletion."""
    active = np.ones(len(p), dtype=bool)
    DP, DQ = squareform(pdist(p)), squareform(pdist(q))
    while True:
        idx = np.flatnonzero(active)
        m = len(idx)
        if m < 3:
            return active
        dp, dq = DP[np.ix_(idx, idx)], DQ[np.ix_(idx, idx)]
        if k is None:
            eta_p, eta_q = dp.sum() / (m * (m - 1)), dq.sum() / (m * (m - 1))
            on_p, off_p = dp <= eta_p * (1 - tol), dp > eta_p * (1 + tol)
            on_q, off_q = dq <= eta_q * (1 - tol), dq > eta_q * (1 + tol)
            R = (on_p & off_q) | (off_p & on_q)
        else:
            kk = min(k, m - 1)

            def knn_graph(d: np.ndarray, kk: int = kk) -> np.ndarray:
                d = d.copy()
                np.fill_diagonal(d, np.inf)
                nearest = np.argsort(d, axis=1, kind="stable")[:, :kk]
                K = np.zeros(d.shape, dtype=bool)
                K[np.arange(len(d))[:, None], nearest] = True
                return K | K.T

            R = knn_graph(dp) != knn_graph(dq)
        np.fill_diagonal(R, False)
        col = R.sum(axis=0)
        if col.max() == 0:
            return active
        active[idx[np.argmax(col)]] = False


def similarity_matches(
    rng: np.random.Generator, n_in: int, n_out: int, noise_px: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Matches in a 320 × 240 image: inliers related by a random similarity plus
    Gaussian noise, outliers uniformly random in both images; shuffled."""
    size = np.array([320.0, 240.0])
    p_in = rng.uniform(0, size, (n_in, 2))
    angle, scale = rng.uniform(-0.4, 0.4), rng.uniform(0.8, 1.25)
    R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    q_in = scale * (p_in - size / 2) @ R.T + size / 2 + rng.uniform(-20, 20, 2)
    q_in += rng.normal(0.0, noise_px, q_in.shape)
    p = np.vstack([p_in, rng.uniform(0, size, (n_out, 2))])
    q = np.vstack([q_in, rng.uniform(0, size, (n_out, 2))])
    inlier = np.r_[np.ones(n_in, bool), np.zeros(n_out, bool)]
    perm = rng.permutation(n_in + n_out)
    return p[perm], q[perm], inlier[perm]


def precision_recall(kept: np.ndarray, inlier: np.ndarray) -> tuple[float, float]:
    true_pos = np.count_nonzero(kept & inlier)
    return true_pos / max(np.count_nonzero(kept), 1), true_pos / np.count_nonzero(inlier)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize(("k", "tol"), [(None, 0.0), (None, 0.05), (1, 0.0), (4, 0.0)])
def test_gtm_matches_reference(seed: int, k: int | None, tol: float) -> None:
    rng = np.random.default_rng(seed)
    p, q, _ = similarity_matches(rng, int(rng.integers(5, 80)), int(rng.integers(0, 30)), 1.0)
    np.testing.assert_array_equal(gtm_filter(p, q, k, tolerance=tol), gtm_reference(p, q, k, tol))


@pytest.mark.parametrize(
    ("k", "tol", "noise_px", "n_in", "n_out"),
    [
        (None, 0.0, 0.0, 200, 100),  # exact GTM, exact similarity
        (None, 0.05, 1.0, 200, 100),  # radius graph with a dead band, 1 px noise
        (None, 0.05, 0.5, 150, 150),  # half of the matches wrong
        (4, 0.0, 0.3, 200, 100),  # k-NN graph, 0.3 px noise
    ],
)
@pytest.mark.parametrize("seed", range(3))
def test_gtm_precision_recall(
    seed: int, k: int | None, tol: float, noise_px: float, n_in: int, n_out: int
) -> None:
    p, q, inlier = similarity_matches(np.random.default_rng(seed), n_in, n_out, noise_px)
    precision, recall = precision_recall(gtm_filter(p, q, k, tolerance=tol), inlier)
    assert precision >= 0.95
    assert recall >= 0.9


@pytest.mark.parametrize("k", [None, 3, 6])
@pytest.mark.parametrize("seed", range(3))
def test_gtm_keeps_all_inliers(seed: int, k: int | None) -> None:
    p, q, _ = similarity_matches(np.random.default_rng(seed), 120, 0, 0.0)
    assert gtm_filter(p, q, k).all()


@pytest.mark.parametrize("k", [None, 4])
def test_gtm_is_symmetric_and_similarity_invariant(k: int | None) -> None:
    rng = np.random.default_rng(11)
    p, q, _ = similarity_matches(rng, 80, 30, 0.5)
    kept = gtm_filter(p, q, k)
    np.testing.assert_array_equal(gtm_filter(q, p, k), kept)
    R = Rotation.from_euler("z", 0.7).as_matrix()[:2, :2]
    np.testing.assert_array_equal(gtm_filter(2.5 * p @ R.T + [7.0, -3.0], q, k), kept)


def test_gtm_exact_radius_graph_is_fragile_under_noise() -> None:
    """Documented behaviour: without a dead band, keypoint noise flips edges near
    the threshold and exact GTM sheds many inliers; the dead band fixes it."""
    p, q, inlier = similarity_matches(np.random.default_rng(0), 200, 100, 0.5)
    _, recall_exact = precision_recall(gtm_filter(p, q), inlier)
    _, recall_band = precision_recall(gtm_filter(p, q, tolerance=0.05), inlier)
    assert recall_exact < 0.8 < 0.95 < recall_band


def test_gtm_small_inputs() -> None:
    assert gtm_filter(np.zeros((0, 2)), np.zeros((0, 2))).shape == (0,)
    assert gtm_filter([[0.0, 0.0], [1.0, 1.0]], [[5.0, 5.0], [0.0, 9.0]]).all()
    p = np.random.default_rng(0).random((6, 2))
    assert gtm_filter(p, p[::-1], k=5).all()  # k ≥ N − 1: complete graphs agree


@pytest.mark.parametrize("k", [None, 2])
def test_gtm_degenerate_point_sets(k: int | None) -> None:
    """Coincident keypoints (SIFT reports several orientations at one spot)."""
    same = np.zeros((6, 2))
    assert gtm_filter(same, same, k).all()
    p = np.repeat(np.random.default_rng(1).uniform(0, 300, (8, 2)), 2, axis=0)
    kept = gtm_filter(p, 0.5 * p + 3.0, k)
    assert kept.all()
    q = 0.5 * p + 3.0
    q[0] = [290.0, 10.0]  # one wrong match among duplicates
    kept = gtm_filter(p, q, k)
    assert not kept[0]
    if k is None:  # (k-NN ties between duplicates may cost a few more)
        assert kept[1:].all()


def test_gtm_errors() -> None:
    p = np.zeros((5, 2))
    with pytest.raises(
        ValueError, match=r"pts_p and pts_q must have the same shape, got \(5, 2\) and \(4, 2\)"
    ):
        gtm_filter(p, np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"pts_q must have shape \(N, 2\), got \(5, 3\)"):
        gtm_filter(p, np.zeros((5, 3)))
    with pytest.raises(ValueError, match="k must be a positive integer or None, got 0"):
        gtm_filter(p, p, k=0)
    with pytest.raises(ValueError, match="tolerance applies to the radius graph"):
        gtm_filter(p, p, k=3, tolerance=0.1)
    with pytest.raises(ValueError, match=r"tolerance must lie in \[0, 1\), got 1.5"):
        gtm_filter(p, p, tolerance=1.5)
    with pytest.raises(ValueError, match="pts_p must be finite"):
        gtm_filter(np.full((5, 2), np.nan), p)


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
