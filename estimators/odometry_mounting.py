r"""Joint calibration of the wheel scale factors and a sensor's mounting (Censi et al.).

:func:`fit_odometry_and_mounting` runs
:class:`~realitygap.estimators.mounting_calibration.MountingCalibrationEKF` with
``estimate_odometry=True`` over encoder tick increments and the sensor's own
ego-motion, in several passes: each pass relinearises at the previous
estimate, re-estimates the full sensor-noise covariance from the residuals and
leaves out outliers. It returns an :class:`OdometryMountingFit`.

References
----------
A. Censi, A. Franchi, L. Marchionni, G. Oriolo, "Simultaneous calibration of
odometry and sensor parameters for mobile robots", IEEE T-RO 29(2), 2013.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import wrap_angle
from realitygap.estimators.diffdrive_model import arc_increment
from realitygap.estimators.mounting_calibration import (
    DEFAULT_MOUNTING_STD,
    DEFAULT_SCALE_STD,
    MountingCalibrationEKF,
    MountingNoise,
    mounting_observability,
    sensor_motion,
)

FloatArray = npt.NDArray[np.float64]

__all__ = ["OdometryMountingFit", "fit_odometry_and_mounting"]


@dataclass(frozen=True)
class OdometryMountingFit:
    """Result of :func:`fit_odometry_and_mounting`.

    Attributes
    ----------
    scales : ndarray, shape (3,)
        ``[k_L, k_R, k_b]`` relative to the nominal kinematics.
    mounting : ndarray, shape (3,)
        ``[l_x, l_y, l_θ]`` (m, m, rad).
    cov : ndarray, shape (6, 6)
        Posterior covariance of ``[l_x, l_y, l_θ, k_L, k_R, k_b]``.
    n_updates : int
        Sensor-motion updates used in the last pass.
    n_outliers : int
        Sensor motions left out as outliers.
    observable : bool
        Whether every parameter is constrained: posterior standard deviation
        below half of the default prior's (0.1 m, 0.1 m, 0.2 rad, 0.05 ×3).
    """

    scales: FloatArray
    mounting: FloatArray
    cov: FloatArray
    n_updates: int
    n_outliers: int
    observable: bool

    @property
    def std(self) -> FloatArray:
        """Posterior standard deviations of ``[l_x, l_y, l_θ, k_L, k_R, k_b]``."""
        return np.sqrt(np.clip(np.diag(self.cov), 0.0, None))


_DEFAULT_PRIOR = np.diag([*DEFAULT_MOUNTING_STD, *DEFAULT_SCALE_STD]) ** 2
"""Prior covariance of ``[l_x, l_y, l_θ, k_L, k_R, k_b]`` (the filter's defaults)."""


def _predicted_sensor_motions(
    inc: FloatArray, nominal: Any, scales: FloatArray, mounting: FloatArray
) -> FloatArray:
    """``⊖l ⊕ δ(n_L, n_R; k) ⊕ l`` for every interval, shape (K, 3)."""
    ds, dtheta = nominal.scaled(*scales).increment_from_ticks(inc[:, 0], inc[:, 1])
    return np.asarray(sensor_motion(mounting, arc_increment(ds, dtheta)))


def fit_odometry_and_mounting(
    tick_increments: npt.ArrayLike,
    sensor_motions: Sequence[FloatArray | None],
    nominal: Any,
    scales0: npt.ArrayLike,
    mounting0: npt.ArrayLike,
    *,
    prior_cov: npt.ArrayLike | None = None,
    sensor_std: tuple[float, float, float] = (2e-3, 2e-3, 2e-3),
    sensor_weights: npt.ArrayLike | None = None,
    n_passes: int = 3,
    outlier_sigma: float = 4.0,
) -> OdometryMountingFit:
    r"""Online calibration of the wheel scale factors and the sensor mounting (Censi et al.).

    Runs :class:`~realitygap.estimators.mounting_calibration.MountingCalibrationEKF` with
    ``estimate_odometry=True`` over the samples: state ``[s, l, k_L, k_R,
    k_b]``, prediction ``s_k = s_{k-1} ⊕ (⊖l ⊕ δ(n_L, n_R; k) ⊕ l)`` and the
    sensor ego-motion ``z_k = ⊖l ⊕ δ_k ⊕ l`` as observation, with covariance
    ``C / w_k``.

    The first pass uses ``C = diag(sensor_std)²``. Each further pass restarts
    from the previous estimate with the same prior (relinearisation), with
    ``C`` re-estimated from the weighted residuals ``√w_k (z_k − ẑ_k)`` at the
    previous estimate, and leaves out samples whose Mahalanobis distance
    ``√(w_k rᵀ C⁻¹ r)`` exceeds ``outlier_sigma``. The full covariance matters:
    RGB-D odometry confuses a small turn with a sideways shift (distant points
    move alike), so its lateral and heading errors are strongly correlated
    (≈ −0.97 here); with a diagonal ``C`` those errors bias all three scale
    factors by per cent.

    Parameters
    ----------
    tick_increments : array_like, shape (K, 2)
        ``(n_L, n_R)`` encoder counts between consecutive sensor frames.
    sensor_motions : sequence of K ndarray (3,) or None
        Sensor ego-motion ``⊖s_{k-1} ⊕ s_k`` over the same intervals (m, m,
        rad, sensor frame); ``None`` where the sensor gave none (predict only).
    nominal : DiffDriveKinematics
        Nominal kinematics the scales refer to.
    scales0 : array_like, shape (3,)
        Prior mean of ``[k_L, k_R, k_b]`` (e.g. from UMBmark).
    mounting0 : array_like, shape (3,)
        Prior mean of the mounting ``[l_x, l_y, l_θ]`` (m, m, rad).
    prior_cov : array_like, shape (6, 6), optional
        Prior covariance of ``[l, k]``; default ``diag(0.1 m, 0.1 m, 0.2 rad,
        0.05, 0.05, 0.05)²`` (the filter's defaults). Cross terms are dropped.
    sensor_std : tuple of 3 floats
        Standard deviation of a sensor ego-motion of weight 1 (m, m, rad) in
        the first pass.
    sensor_weights : array_like, shape (K,), optional
        Relative information ``w_k > 0`` of each sensor motion (e.g. its
        visual-odometry inlier count over a reference count); ones by default.
    n_passes : int
        Filter passes (≥ 1); the noise covariance is estimated and outliers are
        removed from the second pass on.
    outlier_sigma : float
        Outlier threshold in robust standard deviations.

    Returns
    -------
    OdometryMountingFit
    """
    inc = np.asarray(tick_increments, dtype=float)
    n = len(sensor_motions)
    if inc.ndim != 2 or inc.shape[1] != 2 or inc.shape[0] != n:
        raise ValueError(
            f"tick_increments must have shape (K, 2) with K = len(sensor_motions) = {n}, "
            f"got {inc.shape}"
        )
    if int(n_passes) < 1:
        raise ValueError(f"n_passes must be >= 1, got {n_passes}")
    w = np.ones(n) if sensor_weights is None else np.asarray(sensor_weights, dtype=float)
    if w.shape != (n,) or not np.all(np.isfinite(w) & (w > 0)):
        raise ValueError(f"sensor_weights must be {n} positive finite numbers")
    P0 = _DEFAULT_PRIOR if prior_cov is None else np.asarray(prior_cov, dtype=float)
    if P0.shape != (6, 6):
        raise ValueError(f"prior_cov must have shape (6, 6), got {P0.shape}")
    noise = MountingNoise(sensor_std=sensor_std)
    cov = np.diag(np.square(sensor_std))
    has_z = np.array([z is not None for z in sensor_motions])
    Z = np.array([z if z is not None else np.zeros(3) for z in sensor_motions]).reshape(n, 3)
    use = has_z.copy()
    scales = np.asarray(scales0, dtype=float).copy()
    mounting = np.asarray(mounting0, dtype=float).copy()
    ekf = None
    for pass_ in range(int(n_passes)):
        if pass_ > 0 and np.count_nonzero(has_z) > 3:
            r = Z - _predicted_sensor_motions(inc, nominal, scales, mounting)
            r[:, 2] = np.asarray(wrap_angle(r[:, 2]))
            for _ in range(2):  # covariance of the kept residuals, then the outliers under it
                kept = r[use] * np.sqrt(w[use])[:, None]
                cov = kept.T @ kept / max(len(kept), 1) + 1e-12 * np.eye(3)
                d2 = w * np.einsum("ki,ij,kj->k", r, np.linalg.inv(cov), r)
                use = has_z & (d2 <= outlier_sigma**2)
        ekf = MountingCalibrationEKF(
            mounting,
            P0[:3, :3],
            noise=noise,
            estimate_odometry=True,
            kinematics=nominal,
            scales0=scales,
            P0_scales=P0[3:, 3:],
        )
        for k in range(n):
            if use[k]:
                ekf.step(inc[k], Z[k], cov / w[k])
            else:
                ekf.step(inc[k])
        scales, mounting = ekf.odometry_scales, ekf.mounting
    assert ekf is not None
    # judged against the filter's default prior, so that a carried-over (already small)
    # prior does not make well-constrained parameters look unobservable
    report = mounting_observability(ekf.P[3:, 3:], np.sqrt(np.diag(_DEFAULT_PRIOR)))
    return OdometryMountingFit(
        scales,
        mounting,
        ekf.P[3:, 3:],
        int(use.sum()),
        int(np.count_nonzero(has_z & ~use)),
        report.ok,
    )
