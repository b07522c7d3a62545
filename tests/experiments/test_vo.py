"""Building blocks of the ``vo`` experiment: match precision and relative pose errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from realitygap.core.geometry import se2_compose, transform_from_rt
from realitygap.estimators.base import CameraIntrinsics
from realitygap.experiments.vo import match_precision, relative_pose_errors

K = CameraIntrinsics(320, 240, 228.0, 208.0, 160.0, 120.0)


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _synthetic_matches(seed: int, n: int = 80) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points in the previous camera, their exact pixels in the current one, and the motion."""
    rng = np.random.default_rng(seed)
    T = transform_from_rt(_rot_y(rng.uniform(-0.2, 0.2)), rng.uniform(-0.1, 0.1, 3))
    z = rng.uniform(1.0, 5.0, n)
    uv = rng.uniform([10, 10], [310, 230], (n, 2))
    Q = np.stack([(uv[:, 0] - K.cx) * z / K.fx, (uv[:, 1] - K.cy) * z / K.fy, z], 1)
    P_prev = Q @ T[:3, :3].T + T[:3, 3]  # the same points seen from the previous camera
    return P_prev, uv, T


@pytest.mark.parametrize("seed", range(4))
def test_match_precision_is_one_for_exact_correspondences(seed: int) -> None:
    P_prev, uv, T = _synthetic_matches(seed)
    good = match_precision(P_prev, uv, T, K)
    assert good.dtype == bool and good.shape == (len(uv),)
    assert good.mean() == 1.0


@pytest.mark.parametrize("seed", range(4))
def test_match_precision_counts_injected_outliers(seed: int) -> None:
    P_prev, uv, T = _synthetic_matches(seed)
    rng = np.random.default_rng(100 + seed)
    bad = rng.choice(len(uv), 12, replace=False)
    wrong = uv.copy()
    wrong[bad] = uv[np.roll(bad, 1)] + 20.0  # swapped partners, clearly displaced
    wrong[bad[:3]] += 0.5  # sub-pixel jitter on three of them stays wrong
    good = match_precision(P_prev, wrong, T, K)
    assert not good[bad].any() and good.sum() == len(uv) - 12
    assert good.mean() < 1.0
    # within tolerance is correct, beyond is not
    near = uv.copy()
    near[0] += [2.0, 0.0]
    assert match_precision(P_prev, near, T, K, tol_px=3.0)[0]
    assert not match_precision(P_prev, near, T, K, tol_px=1.0)[0]


def test_match_precision_validates_input() -> None:
    P_prev, uv, T = _synthetic_matches(0)
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        match_precision(P_prev[:, :2], uv, T, K)
    with pytest.raises(ValueError, match="tol_px"):
        match_precision(P_prev, uv, T, K, tol_px=0.0)
    with pytest.raises(ValueError, match="T_prev_curr"):
        match_precision(P_prev, uv, np.eye(3), K)
    behind = P_prev.copy()
    behind[:, 2] = -behind[:, 2]
    assert not match_precision(behind, uv, np.eye(4), K).any()


def test_relative_pose_errors_closed_forms() -> None:
    s = np.linspace(0.0, 5.0, 501)
    gt = np.stack([s, np.zeros_like(s), np.zeros_like(s)], 1)
    t, r = relative_pose_errors(gt, gt, 1.0)
    assert len(t) == 401 and np.all(t == 0.0) and np.all(r == 0.0)
    # a rigidly moved estimate has no relative error
    moved = se2_compose(np.array([1.0, -2.0, 0.7]), gt)
    t, r = relative_pose_errors(gt, moved, 1.0)
    assert np.max(t) < 1e-12 and np.max(r) < 1e-12
    # a 1 % scale error is 1 cm per metre
    t, r = relative_pose_errors(gt, gt * [1.01, 1.0, 1.0], 1.0)
    np.testing.assert_allclose(t, 0.01, rtol=0.011)  # segments of 1.00-1.01 m
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        relative_pose_errors(gt, gt[:, :2])
