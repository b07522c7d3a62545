"""Graph Transformation Matching."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import pdist, squareform
from scipy.spatial.transform import Rotation

from realitygap.estimators.gtm import gtm_filter

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
