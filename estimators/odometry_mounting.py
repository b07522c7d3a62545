r"""Joint calibration of the wheel scale factors and a sensor's mounting (Censi et al.).

:func:`fit_odometry_and_mounting` runs
:class:`~realitygap.estimators.mounting_calibration.MountingCalibrationEKF` with
``estimate_odometry=True`` over encoder tick increments and the sensor's own
ego-motion, in several passes: each pass relinearises at the previous
estimate, re-estimates the full sensor-noise covariance from the residuals and
leaves out outliers. It returns an :class:`OdometryMountingFit`.
:func:`fit_pooled_drives` runs the same fit over the samples of several drives.

The precision a calibration reaches is stated where it matters, on a drive:
:func:`dead_reckoning_covariance` propagates the covariance of the fitted
scale factors to the dead-reckoned poses of a reference drive (first order,
Jacobian by central differences), :func:`predicted_position_error` turns it
into an ``n``-σ position error, and :func:`calibrate_until_precise` is the
sequential design that keeps collecting drives until that predicted error
falls below a target (or a round limit is reached).

References
----------
A. Censi, A. Franchi, L. Marchionni, G. Oriolo, "Simultaneous calibration of
odometry and sensor parameters for mobile robots", IEEE T-RO 29(2), 2013.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
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

__all__ = [
    "DriveSamples",
    "OdometryMountingFit",
    "SequentialCalibration",
    "calibrate_until_precise",
    "dead_reckoning_covariance",
    "dead_reckoning_jacobian",
    "dispersion_ratio",
    "fit_odometry_and_mounting",
    "fit_pooled_drives",
    "predicted_position_error",
    "ticks_for_path",
]

DriveSamples = tuple[Any, ...]
"""Samples of one drive: tick increments (K, 2), K sensor motions (or None), K weights and,
optionally, its loop closures (tick sums (L, 2), sensor motions (L, 3))."""


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
    n_loops : int
        Loop closures used.
    loop_heading_std : float
        Heading standard deviation of a loop closure in the last pass, rad
        (``nan`` without loop closures).
    """

    scales: FloatArray
    mounting: FloatArray
    cov: FloatArray
    n_updates: int
    n_outliers: int
    observable: bool
    n_loops: int = 0
    loop_heading_std: float = float("nan")

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
    loop_closures: tuple[npt.ArrayLike, npt.ArrayLike] | None = None,
    loop_position_std: float = 0.05,
    loop_heading_std: float = 2e-3,
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
    loop_closures : (array_like (L, 2), array_like (L, 3)), optional
        Loop closures: the summed tick increments between two frames of one
        drive and the sensor motion between them registered directly (the
        robot back near an earlier pose, after turning about ``2πm``). The
        net heading ``Σ Δθ(k)`` is exact for any path, so its residual tells
        the wheelbase and wheel-ratio scales without the per-frame rotation
        errors of a visual-odometry chain; the position, modelled as one arc,
        is only loosely weighted (``loop_position_std``).
    loop_position_std : float
        Standard deviation given to a loop closure's position, m.
    loop_heading_std : float
        Heading standard deviation of a loop closure in the first pass, rad; from the
        second pass on it is the root-mean-square heading residual of the
        kept loop closures (not below 0.1 mrad), and loop closures beyond
        ``outlier_sigma`` of it are left out.

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
    if loop_closures is None:
        L_inc, L_z = np.zeros((0, 2)), np.zeros((0, 3))
    else:
        L_inc = np.asarray(loop_closures[0], dtype=float).reshape(-1, 2)
        L_z = np.asarray(loop_closures[1], dtype=float).reshape(-1, 3)
        if len(L_inc) != len(L_z) or not (np.all(np.isfinite(L_inc)) and np.all(np.isfinite(L_z))):
            raise ValueError(
                "loop_closures must be finite tick sums (L, 2) and sensor motions (L, 3), got "
                f"shapes {L_inc.shape} and {L_z.shape}"
            )
        if len(L_inc):
            n_passes = max(int(n_passes), 5)  # the loops' noise is estimated over the passes
    if not (loop_position_std > 0 and loop_heading_std > 0):
        raise ValueError("loop_position_std and loop_heading_std must be > 0")
    loop_use = np.ones(len(L_inc), dtype=bool)
    loop_var = float(loop_heading_std) ** 2
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
            # the residuals' covariance already holds the wheels' own noise (slip, tick
            # quantisation): adding the model's wheel noise on top would count it twice and
            # overstate the posterior covariance
            noise = MountingNoise(sensor_std=sensor_std, wheel_std_per_sqrt_m=0.0)
        if pass_ > 0 and len(L_inc):
            r_loop = np.asarray(
                wrap_angle(
                    L_z[:, 2] - _predicted_sensor_motions(L_inc, nominal, scales, mounting)[:, 2]
                )
            )
            for _ in range(2):
                loop_var = max(float(np.mean(r_loop[loop_use] ** 2)), 1e-8)
                if len(L_inc) >= 3:
                    loop_use = r_loop**2 <= outlier_sigma**2 * loop_var
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
        R_loop = np.diag([loop_position_std**2, loop_position_std**2, loop_var])
        for i in np.flatnonzero(loop_use):
            ekf.step(L_inc[i], L_z[i], R_loop)
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
        int(loop_use.sum()),
        math.sqrt(loop_var) if len(L_inc) else float("nan"),
    )


def fit_pooled_drives(
    drives: Sequence[DriveSamples],
    nominal: Any,
    scales0: npt.ArrayLike,
    mounting0: npt.ArrayLike,
) -> OdometryMountingFit:
    """One joint odometry/mounting fit over the samples of several drives.

    Parameters
    ----------
    drives : sequence of (tick increments (K, 2), K sensor motions or None, K weights[, loops])
        Samples of each drive (independent measurements of the same body);
        ``loops`` (optional) are its loop closures as ``(tick sums (L, 2), motions (L, 3))``.
    nominal : DiffDriveKinematics
        Nominal kinematics the scales refer to.
    scales0, mounting0 : array_like, shape (3,)
        Linearisation point (e.g. the last estimate).

    Returns
    -------
    OdometryMountingFit
        Under the filter's wide default prior, so that the result rests on the
        data of all drives rather than on any earlier posterior.
    """
    if not drives:
        raise ValueError("drives must hold at least one drive's samples, got none")
    inc = np.concatenate([np.asarray(d[0], dtype=float).reshape(-1, 2) for d in drives])
    motions = [m for d in drives for m in d[1]]
    weights = np.concatenate([np.asarray(d[2], dtype=float) for d in drives])
    loops = [d[3] for d in drives if len(d) > 3 and len(d[3][0])]
    return fit_odometry_and_mounting(
        inc,
        motions,
        nominal,
        scales0,
        mounting0,
        sensor_weights=weights,
        loop_closures=(
            (
                np.concatenate([np.asarray(lc[0], dtype=float).reshape(-1, 2) for lc in loops]),
                np.concatenate([np.asarray(lc[1], dtype=float).reshape(-1, 3) for lc in loops]),
            )
            if loops
            else None
        ),
    )


def _check_path(path: tuple[npt.ArrayLike, npt.ArrayLike]) -> tuple[FloatArray, FloatArray]:
    ds = np.asarray(path[0], dtype=float)
    dtheta = np.asarray(path[1], dtype=float)
    if ds.ndim != 1 or ds.shape != dtheta.shape or ds.size == 0:
        raise ValueError(
            "a reference path must be two equally long 1-D arrays (Δs in m, Δθ in rad) "
            f"with at least one step, got shapes {ds.shape} and {dtheta.shape}"
        )
    if not (np.all(np.isfinite(ds)) and np.all(np.isfinite(dtheta))):
        raise ValueError("a reference path must be finite; found NaN or inf")
    return ds, dtheta


def ticks_for_path(kinematics: Any, ds: npt.ArrayLike, dtheta: npt.ArrayLike) -> FloatArray:
    r"""Tick increments (K, 2) with which ``kinematics`` dead-reckons the arcs ``(Δs, Δθ)``.

    The exact inverse of ``increment_from_ticks``:
    ``n_L = (Δs − bΔθ/2)/m_L``, ``n_R = (Δs + bΔθ/2)/m_R`` (fractional ticks).
    """
    d_s, d_th = _check_path((ds, dtheta))
    half = 0.5 * kinematics.wheelbase * d_th
    return np.stack(
        [
            (d_s - half) / kinematics.meters_per_tick_left,
            (d_s + half) / kinematics.meters_per_tick_right,
        ],
        axis=1,
    )


def dead_reckoning_jacobian(
    tick_increments: npt.ArrayLike, nominal: Any, scales: npt.ArrayLike, rel_step: float = 1e-6
) -> FloatArray:
    """``∂p_j/∂k`` (K + 1, 3, 3) of the dead-reckoned poses ``[x, y, θ]`` from the origin
    with respect to ``k = [k_L, k_R, k_b]``, by central differences of relative step
    ``rel_step`` (see :func:`dead_reckoning_covariance`)."""
    inc = np.asarray(tick_increments, dtype=float)
    if inc.ndim != 2 or inc.shape[1] != 2 or not np.all(np.isfinite(inc)):
        raise ValueError(f"tick_increments must be finite with shape (K, 2), got {inc.shape}")
    k = np.asarray(scales, dtype=float)
    if k.shape != (3,) or not np.all(np.isfinite(k) & (k > 0)):
        raise ValueError(f"scales must be 3 positive finite factors [k_L, k_R, k_b], got {k}")
    if not rel_step > 0:
        raise ValueError(f"rel_step must be > 0, got {rel_step}")
    J = np.empty((inc.shape[0] + 1, 3, 3))
    for i in range(3):
        h = rel_step * k[i]
        poses = []
        for sign in (1.0, -1.0):
            kk = k.copy()
            kk[i] += sign * h
            poses.append(
                nominal.scaled(*kk).integrate(np.zeros(3), inc[:, 0], inc[:, 1], wrap=False)
            )
        J[:, :, i] = (poses[0] - poses[1]) / (2.0 * h)
    return J


def dead_reckoning_covariance(
    tick_increments: npt.ArrayLike,
    nominal: Any,
    scales: npt.ArrayLike,
    scales_cov: npt.ArrayLike,
    *,
    rel_step: float = 1e-6,
) -> FloatArray:
    r"""Covariance of dead-reckoned poses due to the uncertainty of the scale factors.

    The poses ``p_j(k)`` of the drive (from the origin) are differentiated
    with respect to ``k = [k_L, k_R, k_b]`` by central differences,
    ``J_j = ∂p_j/∂k``, and the covariance is propagated to first order,

    .. math::

        \Sigma_j = J_j\, \Sigma_k\, J_j^\top .

    It is the covariance of the difference between where a robot that trusts
    the estimate ``k̂`` believes it is and where it is, when the true scales
    scatter about ``k̂`` with covariance ``Σ_k``.

    Parameters
    ----------
    tick_increments : array_like, shape (K, 2)
        ``(n_L, n_R)`` per step (e.g. from :func:`ticks_for_path`).
    nominal : DiffDriveKinematics
        Nominal kinematics the scales refer to.
    scales : array_like, shape (3,)
        Estimate ``[k_L, k_R, k_b]``.
    scales_cov : array_like, shape (3, 3)
        Its covariance (e.g. ``fit.cov[3:, 3:]``).
    rel_step : float
        Relative finite-difference step.

    Returns
    -------
    ndarray, shape (K + 1, 3, 3)
        Covariance of ``[x, y, θ]`` (m², m², rad²) at the start and after each step.
    """
    C = np.asarray(scales_cov, dtype=float)
    if C.shape != (3, 3) or not np.all(np.isfinite(C)):
        raise ValueError(f"scales_cov must be a finite (3, 3) covariance, got shape {C.shape}")
    J = dead_reckoning_jacobian(tick_increments, nominal, scales, rel_step)
    return np.einsum("nij,jk,nlk->nil", J, C, J)


def predicted_position_error(
    path: tuple[npt.ArrayLike, npt.ArrayLike],
    nominal: Any,
    scales: npt.ArrayLike,
    scales_cov: npt.ArrayLike,
    n_sigma: float = 2.0,
) -> float:
    r"""Predicted ``n``-σ position error (m) of a reference drive dead-reckoned with the estimate.

    The drive is the path ``(Δs, Δθ)`` driven on the estimated kinematics
    (:func:`ticks_for_path`); the figure is
    ``n_sigma · max_j √tr Σ_xy,j`` over its poses
    (:func:`dead_reckoning_covariance`): ``n_sigma`` times the largest
    root-mean-square position error along the drive.
    """
    if not n_sigma > 0:
        raise ValueError(f"n_sigma must be > 0, got {n_sigma}")
    k = np.asarray(scales, dtype=float)
    inc = ticks_for_path(nominal.scaled(*k), *path)
    cov = dead_reckoning_covariance(inc, nominal, k, scales_cov)
    rms = np.sqrt(np.clip(cov[:, 0, 0] + cov[:, 1, 1], 0.0, None))
    return float(n_sigma * rms.max())


def dispersion_ratio(
    scales: Sequence[npt.ArrayLike],
    covs: Sequence[npt.ArrayLike],
    pooled: npt.ArrayLike,
    jacobian: npt.ArrayLike | None = None,
) -> float:
    r"""Birge ratio ``χ²/ν`` of independent scale estimates about their pooled value.

    With ``d_r = J (k_r − k̄)`` and ``S_r = J Σ_r Jᵀ`` (``J`` = identity by default),

    .. math::

        \chi^2 = \sum_r d_r^\top S_r^{-1} d_r, \qquad \nu = m (R - 1),

    for ``R`` estimates and ``m`` rows of ``J``. About 1 when the estimates
    scatter as their covariances say; above 1 when errors shared within a
    group of drives (and differing between groups) make each group's
    covariance too small. ``J`` projects onto what matters, e.g. the end
    position of a reference drive (:func:`dead_reckoning_jacobian`).
    ``nan`` for fewer than two estimates.
    """
    if len(scales) != len(covs):
        raise ValueError(f"need one covariance per estimate, got {len(scales)} and {len(covs)}")
    J = np.eye(3) if jacobian is None else np.asarray(jacobian, dtype=float)
    if J.ndim != 2 or J.shape[1] != 3:
        raise ValueError(f"jacobian must have shape (m, 3), got {J.shape}")
    if len(scales) < 2:
        return float("nan")
    k_bar = np.asarray(pooled, dtype=float)
    chi2 = 0.0
    for k, c in zip(scales, covs):
        d = J @ (np.asarray(k, dtype=float) - k_bar)
        chi2 += float(d @ np.linalg.solve(J @ np.asarray(c, dtype=float) @ J.T, d))
    return chi2 / (J.shape[0] * (len(scales) - 1))


@dataclass(frozen=True)
class SequentialCalibration:
    """Result of :func:`calibrate_until_precise`.

    Attributes
    ----------
    fit : OdometryMountingFit
        Pooled fit over the drives of every round.
    rounds : int
        Rounds of drives collected.
    predicted_error_m : tuple of float
        Predicted ``n_sigma`` position error of the worst reference drive after each round, m.
    reached : bool
        Whether the last prediction is within the target (``False``: stopped at ``max_rounds``).
    target_error_m : float
        The target, m.
    n_drives : int
        Drives pooled in ``fit``.
    scales_cov : ndarray, shape (3, 3)
        Covariance of the scales behind the last prediction (worst reference
        drive): the fit's, widened by the dispersion ratio when that exceeds 1.
    dispersion : tuple of float
        Dispersion ratio of the rounds' own estimates on the worst reference
        drive's end position after each round (:func:`dispersion_ratio`;
        ``nan`` after the first).
    """

    fit: OdometryMountingFit
    rounds: int
    predicted_error_m: tuple[float, ...]
    reached: bool
    target_error_m: float
    n_drives: int
    scales_cov: FloatArray
    dispersion: tuple[float, ...]


def calibrate_until_precise(
    collect_round: Callable[[int], tuple[Sequence[DriveSamples], npt.ArrayLike, npt.ArrayLike]],
    nominal: Any,
    reference_paths: Sequence[tuple[npt.ArrayLike, npt.ArrayLike]],
    target_error_m: float,
    *,
    min_rounds: int = 1,
    max_rounds: int = 8,
    n_sigma: float = 2.0,
    on_round: Callable[[int, OdometryMountingFit, float], None] | None = None,
) -> SequentialCalibration:
    """Collect calibration drives until the predicted error of reference drives meets a target.

    After each round the samples of all drives so far are fitted jointly
    (:func:`fit_pooled_drives`), the scale covariance is propagated to every
    reference drive (:func:`predicted_position_error`) and the calibration
    stops once the worst prediction is at most ``target_error_m`` (and at
    least ``min_rounds`` rounds ran) or after ``max_rounds``.

    The pooled covariance assumes independent samples. Each round is also
    fitted on its own, and when the rounds' estimates, projected on a
    reference drive's end position, scatter more than their covariances allow
    (dispersion ratio ``χ²/ν > 1``, :func:`dispersion_ratio`; e.g. a
    visual-odometry error shared by the frames of one drive), the pooled
    covariance is widened by that ratio before it is propagated to that
    drive (the Birge correction), so that such errors stop the calibration
    later rather than earlier.

    Parameters
    ----------
    collect_round : callable ``(round) -> (drives, scales0, mounting0)``
        Drives one round (numbered from 1) and returns its drives' samples and
        the linearisation point of the pooled fit (e.g. the round's own estimate).
    nominal : DiffDriveKinematics
        Nominal kinematics the scales refer to.
    reference_paths : sequence of (Δs, Δθ) arrays
        Drives whose precision is required (m, rad per step).
    target_error_m : float
        Required ``n_sigma`` position error, m (> 0).
    min_rounds, max_rounds : int
        Bounds on the rounds, ``1 ≤ min_rounds ≤ max_rounds``.
    n_sigma : float
        Multiple of the predicted RMS error held against the target.
    on_round : callable ``(round, fit, predicted_error_m) -> None``, optional
        Called after each round's pooled fit (e.g. to report progress).

    Returns
    -------
    SequentialCalibration
    """
    if not (np.isfinite(target_error_m) and target_error_m > 0):
        raise ValueError(f"target_error_m must be a positive length in m, got {target_error_m}")
    if not 1 <= int(min_rounds) <= int(max_rounds):
        raise ValueError(
            f"need 1 <= min_rounds <= max_rounds, got min_rounds={min_rounds}, "
            f"max_rounds={max_rounds}"
        )
    if not reference_paths:
        raise ValueError("reference_paths must hold at least one (Δs, Δθ) path, got none")
    paths = [_check_path(p) for p in reference_paths]
    drives: list[DriveSamples] = []
    history: list[float] = []
    dispersion: list[float] = []
    own: list[OdometryMountingFit] = []
    fit: OdometryMountingFit | None = None
    cov = np.zeros((3, 3))
    ratio = float("nan")
    for r in range(1, int(max_rounds) + 1):
        new, scales0, mounting0 = collect_round(r)
        if not new:
            raise ValueError(f"collect_round({r}) returned no drives")
        drives.extend(new)
        fit = fit_pooled_drives(drives, nominal, scales0, mounting0)
        own.append(fit_pooled_drives(list(new), nominal, scales0, mounting0))
        worst = -1.0
        for p in paths:
            inc = ticks_for_path(nominal.scaled(*fit.scales), *p)
            J_end = dead_reckoning_jacobian(inc, nominal, fit.scales)[-1, :2]
            r_p = dispersion_ratio(
                [f.scales for f in own], [f.cov[3:, 3:] for f in own], fit.scales, J_end
            )
            cov_p = fit.cov[3:, 3:] * (max(1.0, r_p) if np.isfinite(r_p) else 1.0)
            e_p = predicted_position_error(p, nominal, fit.scales, cov_p, n_sigma)
            if e_p > worst:
                worst, ratio, cov = e_p, r_p, cov_p
        dispersion.append(ratio)
        history.append(worst)
        if on_round is not None:
            on_round(r, fit, history[-1])
        if r >= int(min_rounds) and history[-1] <= target_error_m:
            break
    assert fit is not None
    return SequentialCalibration(
        fit,
        len(history),
        tuple(history),
        history[-1] <= target_error_m,
        float(target_error_m),
        len(drives),
        cov,
        tuple(dispersion),
    )
