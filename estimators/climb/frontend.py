"""Visual front-end of the climbing robot's VIO: relative motion from two down-looking images.

:func:`relative_motion_from_images` tracks OpenCV features (KLT) and fits the
homography of the locally planar surface; the known camera height gives the
metric scale.

Frames: ``world`` is the VIO frame, gravity along :math:`-z`, its origin and yaw
those of the body at initialisation; ``body`` = IMU frame (x forward, z away from
the surface); ``camera`` is OpenCV's optical frame (z along the optical axis).
Rotations are matrices :math:`R_{wb}` (body → world); quaternions are xyzw.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from realitygap.estimators.climb.measurements import RelativeMotion

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "relative_motion_from_images",
]


def relative_motion_from_images(
    image0: npt.NDArray[np.uint8],
    image1: npt.NDArray[np.uint8],
    K: npt.ArrayLike,
    camera_height: float,
    *,
    t0: float = 0.0,
    t1: float = 1.0,
    max_features: int = 400,
    min_inliers: int = 30,
    ransac_threshold_px: float = 1.0,
    plane_normal: npt.ArrayLike = (0.0, 0.0, 1.0),
    prior: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
) -> RelativeMotion:
    """Camera motion between two views of a locally planar, textured surface.

    Shi–Tomasi corners in ``image0`` are tracked into ``image1`` with pyramidal
    Lucas–Kanade (forward–backward checked); a RANSAC homography
    :math:`H \\simeq K (R + t n^\\top / d) K^{-1}` (with :math:`X_1 = R X_0 + t` and
    the plane :math:`n^\\top X_0 = d` in camera 0) is decomposed with OpenCV, the
    solution whose normal is closest to ``plane_normal`` is kept, and the known
    camera height :math:`d` makes the translation metric.

    Parameters
    ----------
    image0, image1
        (H, W) or (H, W, 3) uint8 frames.
    K : (3, 3)
        Intrinsics, pixels.
    camera_height
        Distance from the camera centre at ``t0`` to the surface plane, m.
    t0, t1
        Frame times, s (copied into the result).
    plane_normal : (3,)
        Expected surface normal in camera 0 (towards the camera: ``+z`` for a camera
        looking straight at it).
    prior
        Predicted motion ``(R_c0c1 (3, 3), p_c0c1 (3,) m)`` (e.g. from the IMU): the
        features are first moved by the homography it predicts, so that large
        inter-frame motions are still tracked.

    Returns
    -------
    RelativeMotion
        ``ok=False`` (identity motion) when too few features or inliers.
    """
    if not (math.isfinite(camera_height) and camera_height > 0):
        raise ValueError(f"camera_height must be a positive distance in m, got {camera_height!r}")
    Km = np.asarray(K, dtype=float)
    if Km.shape != (3, 3):
        raise ValueError(f"K must be (3, 3), got {Km.shape}")
    g0 = _grey(image0)
    g1 = _grey(image1)
    if g0.shape != g1.shape:
        raise ValueError(f"images must have the same size, got {g0.shape} and {g1.shape}")
    fail = RelativeMotion(t0, t1, np.eye(3), np.zeros(3), np.eye(6), ok=False)
    corners = cv2.goodFeaturesToTrack(g0, maxCorners=max_features, qualityLevel=0.01, minDistance=7)
    if corners is None or len(corners) < min_inliers:
        return fail
    pts0 = np.asarray(corners, dtype=np.float32)
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)

    def track(
        src: npt.NDArray[np.uint8],
        dst: npt.NDArray[np.uint8],
        p0: npt.NDArray[Any],
        guess: npt.NDArray[Any],
    ) -> tuple[npt.NDArray[np.float32], npt.NDArray[Any]]:
        p1, status, _ = cv2.calcOpticalFlowPyrLK(
            src,
            dst,
            p0,
            guess.copy(),
            winSize=(21, 21),
            maxLevel=3,
            criteria=criteria,
            flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
        )
        return np.asarray(p1, dtype=np.float32), np.asarray(status)

    if prior is not None:
        R_p = np.asarray(prior[0], dtype=float)
        p_p = np.asarray(prior[1], dtype=float)
        n0 = np.asarray(plane_normal, dtype=float)
        n0 = n0 / np.linalg.norm(n0)
        # X1 = R X0 + t with R = R_c0c1^T, t = -R_c0c1^T p_c0c1, plane n^T X0 = d
        H_pred = Km @ (R_p.T + np.outer(-R_p.T @ p_p, n0) / camera_height) @ np.linalg.inv(Km)
        guess = np.asarray(
            cv2.perspectiveTransform(pts0.astype(np.float64), H_pred), dtype=np.float32
        )
    else:
        guess = pts0
    pts1, st = track(g0, g1, pts0, guess)
    # backward check, started from where the features came from
    back, st_b = track(g1, g0, pts1, pts0)
    good = (st.ravel() == 1) & (st_b.ravel() == 1)
    good &= np.linalg.norm((back - pts0).reshape(-1, 2), axis=1) < 0.5
    if good.sum() < min_inliers:
        return fail
    a = pts0.reshape(-1, 2)[good]
    b = pts1.reshape(-1, 2)[good]
    H, mask = cv2.findHomography(a, b, cv2.RANSAC, ransac_threshold_px)
    if H is None or mask is None or int(mask.sum()) < min_inliers:
        return fail
    inl = mask.ravel().astype(bool)
    n_in = int(inl.sum())
    _, Rs, ts, ns = cv2.decomposeHomographyMat(H, Km)
    n_ref = np.asarray(plane_normal, dtype=float)
    n_ref = n_ref / np.linalg.norm(n_ref)
    rays = np.c_[a[inl], np.ones(n_in)] @ np.linalg.inv(Km).T
    best, best_score = -1, -np.inf
    for k in range(len(Rs)):
        n = np.asarray(ns[k], dtype=float).ravel()
        if np.any(rays @ n <= 0):  # points must lie in front of camera 0
            continue
        score = float(n @ n_ref)
        if score > best_score:
            best, best_score = k, score
    if best < 0:
        return fail
    R = np.asarray(Rs[best], dtype=float)
    t = np.asarray(ts[best], dtype=float).ravel() * camera_height
    proj = np.c_[a[inl], np.ones(n_in)] @ H.T
    err = np.linalg.norm(proj[:, :2] / proj[:, 2:3] - b[inl], axis=1)
    sigma_px = max(float(np.sqrt(np.mean(err**2))), 0.05)
    f = 0.5 * (Km[0, 0] + Km[1, 1])
    span = max(float(np.std(a[inl], axis=0).mean()), 1.0)
    # in-plane rotation from the feature spread; tilt is less well determined
    s_yaw = 2.0 * sigma_px / (span * math.sqrt(n_in))
    s_tilt = 10.0 * s_yaw
    s_t = camera_height * 3.0 * sigma_px / (f * math.sqrt(n_in)) + 0.01 * float(np.linalg.norm(t))
    cov = np.diag([s_tilt**2, s_tilt**2, s_yaw**2, s_t**2, s_t**2, (0.5 * s_t) ** 2])
    R_c0_c1 = R.T
    p_c0_c1 = -R.T @ t
    # orthonormalise
    u_, _, vt_ = np.linalg.svd(R_c0_c1)
    R_c0_c1 = u_ @ vt_
    return RelativeMotion(t0, t1, R_c0_c1, p_c0_c1, cov, ok=True, n_inliers=n_in)


def _grey(image: npt.ArrayLike) -> npt.NDArray[np.uint8]:
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise ValueError(f"images must be uint8, got {img.dtype}")
    if img.ndim == 3:
        return np.asarray(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), dtype=np.uint8)
    if img.ndim == 2:
        return img
    raise ValueError(f"images must be (H, W) or (H, W, 3), got {img.shape}")
