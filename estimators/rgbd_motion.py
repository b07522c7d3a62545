"""Rigid camera motion from RGB-D correspondences: PnP and maximum likelihood.

Both solvers take the key-frame's 3-D points ``P_kf`` (camera frame, m) and
the current frame's pixels or points, and return the pose of the current
camera in the key-frame, ``P_kf ≈ R P_cur + t``.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

from realitygap.estimators.base import CameraIntrinsics

FloatArray = npt.NDArray[np.float64]

__all__ = ["motion_covariance_ml", "point_covariance", "refine_motion_ml", "solve_pnp"]


def _camera_matrix(intr: CameraIntrinsics) -> FloatArray:
    return np.array([[intr.fx, 0.0, intr.cx], [0.0, intr.fy, intr.cy], [0.0, 0.0, 1.0]])


def solve_pnp(
    P_kf: FloatArray,
    px: FloatArray,
    intr: CameraIntrinsics,
    rng: np.random.Generator,
    max_iters: int,
    reprojection_px: float,
    min_inliers: int,
) -> tuple[FloatArray, FloatArray, npt.NDArray[np.bool_]] | None:
    """Pose ``(R, t)`` of the current camera in the key-frame from key-frame points (n, 3)
    and current pixels (n, 2): EPnP in RANSAC, Levenberg–Marquardt on the inliers, and
    the inlier mask; ``None`` if fewer than ``min_inliers`` agree within
    ``reprojection_px``. OpenCV's RANSAC sampler is seeded from ``rng``."""
    K = _camera_matrix(intr)
    obj = np.ascontiguousarray(P_kf, dtype=np.float64)
    img = np.ascontiguousarray(px, dtype=np.float64)
    cv2.setRNGSeed(int(rng.integers(2**31)))
    ok, rvec, tvec, idx = cv2.solvePnPRansac(
        obj,
        img,
        K,
        None,
        iterationsCount=max_iters,
        reprojectionError=reprojection_px,
        confidence=0.999,
        flags=cv2.SOLVEPNP_EPNP,
    )
    if not ok or idx is None or len(idx) < min_inliers:
        return None
    inl = np.zeros(len(obj), dtype=bool)
    inl[idx.ravel()] = True
    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], K, None, rvec, tvec)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, None)
    inl = np.linalg.norm(proj.reshape(-1, 2) - img, axis=1) <= reprojection_px
    if np.count_nonzero(inl) < min_inliers:
        return None
    R_ck, _ = cv2.Rodrigues(rvec)  # key-frame → current: X_cur = R_ck X_kf + t_ck
    return R_ck.T, -R_ck.T @ tvec.ravel(), inl


def point_covariance(
    P: FloatArray, intr: CameraIntrinsics, pixel_sigma_px: float, depth_a_m: float, depth_b: float
) -> FloatArray:
    """Covariances (n, 3, 3) of back-projected points ``P`` (n, 3): ``pixel_sigma_px`` across
    the viewing ray, ``σ_z = depth_a_m + depth_b·z²`` along it (first-order propagation
    through ``X = ((u − cx) z / fx, (v − cy) z / fy, z)``)."""
    z = P[:, 2]
    n = len(P)
    J = np.zeros((n, 3, 3))
    J[:, 0, 0] = z / intr.fx
    J[:, 1, 1] = z / intr.fy
    J[:, 0, 2] = P[:, 0] / z
    J[:, 1, 2] = P[:, 1] / z
    J[:, 2, 2] = 1.0
    s_z = depth_a_m + depth_b * z * z
    D = np.zeros((n, 3, 3))
    D[:, 0, 0] = D[:, 1, 1] = pixel_sigma_px**2
    D[:, 2, 2] = s_z * s_z
    return J @ D @ J.transpose(0, 2, 1)


def _residual_jacobian(q: FloatArray) -> FloatArray:
    """Jacobians (n, 3, 6) of ``e = P_kf − R P_cur − t`` with respect to ``(δθ, δt)`` for
    ``R ← exp([δθ]×) R``, ``t ← t + δt``, at the rotated points ``q = R P_cur`` (n, 3)."""
    J = np.zeros((len(q), 3, 6))
    J[:, 0, 1], J[:, 0, 2] = -q[:, 2], q[:, 1]
    J[:, 1, 0], J[:, 1, 2] = q[:, 2], -q[:, 0]
    J[:, 2, 0], J[:, 2, 1] = -q[:, 1], q[:, 0]
    J[:, :, 3:] = -np.eye(3)
    return J


def motion_covariance_ml(
    P_cur: FloatArray,
    P_kf: FloatArray,
    R: FloatArray,
    t: FloatArray,
    S_cur: FloatArray,
    S_kf: FloatArray,
) -> FloatArray:
    r"""Covariance (6, 6) of the motion ``P_kf ≈ R P_cur + t`` from its own inliers.

        The inverse of the Gauss–Newton information of :func:`refine_motion_ml` at the
        solution, scaled by the a-posteriori variance factor when the inliers scatter more
        than their point covariances say:

        .. math::

            \Sigma = \max\!\left(1, rac{\chi^2}{3n - 6}
    ight)
            \Big(\sum_i J_i^	op C_i^{-1} J_i\Big)^{-1}, \qquad
            \chi^2 = \sum_i e_i^	op C_i^{-1} e_i,

        with ``Cᵢ = S_kf,i + R S_cur,i Rᵀ``. The parameters are the rotation and translation
        increments ``(δθ, δt)`` (rad, m) of ``R ← exp([δθ]×) R``, ``t ← t + δt``.

        Parameters
        ----------
        P_cur, P_kf : (n, 3) inlier points in the current and key-frame camera frames, m;
            ``n ≥ 3``.
        R, t : the motion (3, 3) and (3,) m.
        S_cur, S_kf : (n, 3, 3) point covariances (:func:`point_covariance`), m².

        Returns
        -------
        ndarray, shape (6, 6)
            Covariance of ``(δθ, δt)`` in rad² and m²; ``inf`` on the diagonal when the
            points do not constrain the motion.
    """
    n = len(P_cur)
    if n < 3:
        raise ValueError(f"motion_covariance_ml needs at least 3 point pairs, got {n}")
    W = np.linalg.inv(S_kf + R @ S_cur @ R.T)
    q = P_cur @ R.T
    e = P_kf - q - t
    J = _residual_jacobian(q)
    H = np.einsum("nji,njk,nkl->il", J, W, J)
    chi2 = float(np.einsum("ni,nij,nj->", e, W, e))
    factor = max(1.0, chi2 / max(3 * n - 6, 1))
    try:
        cov = np.linalg.inv(H) * factor
    except np.linalg.LinAlgError:
        return np.diag(np.full(6, np.inf))
    if not np.all(np.isfinite(cov)):
        return np.diag(np.full(6, np.inf))
    return 0.5 * (cov + cov.T)


def refine_motion_ml(
    P_cur: FloatArray,
    P_kf: FloatArray,
    R: FloatArray,
    t: FloatArray,
    S_cur: FloatArray,
    S_kf: FloatArray,
    iterations: int = 6,
) -> tuple[FloatArray, FloatArray]:
    """Gauss–Newton on SE(3) for ``P_kf ≈ R P_cur + t`` under anisotropic point noise.

    Minimises ``Σ eᵢᵀ Cᵢ⁻¹ eᵢ`` with ``eᵢ = P_kf,i − R P_cur,i − t`` and
    ``Cᵢ = S_kf,i + R S_cur,i Rᵀ`` (see :func:`point_covariance`), starting from
    ``(R, t)``; the start is returned if the iterations do not lower that cost.
    """

    def info(R: FloatArray) -> FloatArray:
        return np.linalg.inv(S_kf + R @ S_cur @ R.T)

    def cost(R: FloatArray, t: FloatArray) -> float:
        e = P_kf - P_cur @ R.T - t
        return float(np.einsum("ni,nij,nj->", e, info(R), e))

    R0, t0 = R, t
    W = info(R)
    for _ in range(iterations):
        q = P_cur @ R.T
        e = P_kf - q - t
        # e(δθ, δt) ≈ e + [q]× δθ − δt  for R ← exp([δθ]×) R, t ← t + δt
        Jr = _residual_jacobian(q)
        JW = Jr.transpose(0, 2, 1) @ W
        H = np.einsum("nij,njk->ik", JW, Jr)
        g = np.einsum("nij,nj->i", JW, e)
        try:
            delta = -np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            break
        R = cv2.Rodrigues(delta[:3])[0] @ R
        t = t + delta[3:]
        W = info(R)
        if float(np.linalg.norm(delta)) < 1e-10:
            break
    return (R, t) if cost(R, t) <= cost(R0, t0) else (R0, t0)
