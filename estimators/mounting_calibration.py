r"""Sensor-mounting calibration of a differential drive (Censi et al. 2013).

:class:`MountingCalibrationEKF` jointly estimates the sensor pose ``s`` in the
world and the sensor mounting ``l`` on the base (optionally also odometry scale
factors) from odometry increments and the sensor's own ego-motion.
:func:`calibrate_mounting` runs it over a batch; :func:`calibrate_mounting_lsq`
solves the same residuals by nonlinear least squares for comparison.

Conventions follow :mod:`realitygap.core.geometry`: poses ``[x, y, θ]`` (m, m, rad),
``a ⊕ b`` compounding and ``⊖a`` inversion (Smith–Self–Cheeseman). The base
frame has x forward, y left; the sensor frame is the planar frame in which the
sensor's ego-motion is reported (for a camera, its optical axis projected on
the floor plane).

References
----------
A. Censi, A. Franchi, L. Marchionni, G. Oriolo, "Simultaneous calibration of
odometry and sensor parameters for mobile robots", IEEE T-RO 29(2), 2013.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from realitygap.core.geometry import (
    SKEW_2D,
    check_finite,
    rotation_2d,
    se2_compose,
    se2_inverse,
    wrap_angle,
)
from realitygap.estimators.base import Estimate
from realitygap.estimators.diffdrive_model import (
    DiffDriveKinematics,
    arc_increment,
    arc_increment_jacobian,
    se2_compose_jacobians,
)
from realitygap.estimators.kalman import all_finite, joseph_update

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "LowObservabilityWarning",
    "MountingCalibrationEKF",
    "MountingNoise",
    "MountingObservability",
    "MountingStep",
    "calibrate_mounting",
    "calibrate_mounting_lsq",
    "mounting_observability",
    "sensor_motion",
    "sensor_motion_jacobians",
]

_MOUNT_NAMES = ("l_x", "l_y", "l_theta")
_SCALE_NAMES = ("k_left", "k_right", "k_wheelbase")

#: Default prior standard deviations of the mounting ``[l_x, l_y, l_θ]`` (m, m, rad)
#: and of the wheel scale factors ``[k_L, k_R, k_b]``.
DEFAULT_MOUNTING_STD = (0.1, 0.1, 0.2)
DEFAULT_SCALE_STD = (0.05, 0.05, 0.05)


def sensor_motion(mounting: npt.ArrayLike, delta: npt.ArrayLike) -> FloatArray:
    r"""Sensor ego-motion for a base motion: ``z = ⊖l ⊕ δ ⊕ l``.

    Parameters
    ----------
    mounting : array_like, shape (3,)
        ``l = [l_x, l_y, l_θ]``: sensor pose in the base frame (m, m, rad).
    delta : array_like, shape (..., 3)
        Base motion(s) ``δ`` in the base frame at the start of the step.

    Returns
    -------
    z : ndarray, shape (..., 3)
        Motion of the sensor in its own frame at the start of the step.

    Notes
    -----
    In the plane rotations commute, so with ``t_l = (l_x, l_y)``, ``φ = l_θ``:

    .. math::

        z_\theta = \delta_\theta, \qquad
        z_{xy} = R(-\varphi)\big[(R(\delta_\theta) - I)\, t_l + \delta_{xy}\big].
    """
    l = np.asarray(mounting, dtype=float)
    d = np.asarray(delta, dtype=float)
    c, s = np.cos(d[..., 2]), np.sin(d[..., 2])
    wx = (c - 1.0) * l[0] - s * l[1] + d[..., 0]
    wy = s * l[0] + (c - 1.0) * l[1] + d[..., 1]
    cp, sp = math.cos(l[2]), math.sin(l[2])
    return np.stack([cp * wx + sp * wy, -sp * wx + cp * wy, d[..., 2] + 0.0 * wx], axis=-1)


def sensor_motion_jacobians(
    mounting: npt.ArrayLike, delta: npt.ArrayLike
) -> tuple[FloatArray, FloatArray]:
    r"""Jacobians of :func:`sensor_motion` with respect to ``l`` and ``δ``.

    Returns
    -------
    H_l : ndarray, shape (3, 3)
    H_delta : ndarray, shape (3, 3)

    Notes
    -----
    With ``w = (R(δ_θ) − I) t_l + δ_xy``:

    .. math::

        \frac{\partial z_{xy}}{\partial t_l} = R(-\varphi)(R(\delta_\theta) - I), \quad
        \frac{\partial z_{xy}}{\partial \varphi} = -R(-\varphi) S w, \quad
        \frac{\partial z_{xy}}{\partial \delta_{xy}} = R(-\varphi), \quad
        \frac{\partial z_{xy}}{\partial \delta_\theta} = R(-\varphi) S R(\delta_\theta) t_l,

    and ``∂z_θ/∂δ_θ = 1``.
    """
    l = np.asarray(mounting, dtype=float)
    d = np.asarray(delta, dtype=float)
    Rm = rotation_2d(l[2]).T
    Rd = rotation_2d(d[2])
    t_l = l[:2]
    w = (Rd - np.eye(2)) @ t_l + d[:2]
    H_l = np.zeros((3, 3))
    H_l[:2, :2] = Rm @ (Rd - np.eye(2))
    H_l[:2, 2] = -Rm @ SKEW_2D @ w
    H_d = np.zeros((3, 3))
    H_d[:2, :2] = Rm
    H_d[:2, 2] = Rm @ SKEW_2D @ Rd @ t_l
    H_d[2, 2] = 1.0
    return H_l, H_d


@dataclass(frozen=True)
class MountingNoise:
    """Noise model of the mounting calibration.

    Attributes
    ----------
    odometry_std : tuple of 3 floats
        Standard deviation of a supplied base increment ``δ`` per step
        (m, m, rad), used when ``δ`` is given directly.
    wheel_std_per_sqrt_m : float
        Wheel-distance noise of the augmented filter: per step each wheel's
        travel ``s`` has variance ``wheel_std_per_sqrt_m² · |s| + wheel_std_floor²`` (m²).
    wheel_std_floor : float
        See above, m.
    sensor_std : tuple of 3 floats
        Standard deviation of the measured sensor ego-motion ``z`` (m, m, rad).
    """

    odometry_std: tuple[float, float, float] = (1e-3, 1e-3, 2e-3)
    wheel_std_per_sqrt_m: float = 2e-3
    wheel_std_floor: float = 1e-5
    sensor_std: tuple[float, float, float] = (2e-3, 2e-3, 2e-3)

    def __post_init__(self) -> None:
        values: tuple[float, ...] = (
            *self.odometry_std,
            self.wheel_std_per_sqrt_m,
            self.wheel_std_floor,
            *self.sensor_std,
        )
        if len(self.odometry_std) != 3 or len(self.sensor_std) != 3:
            raise ValueError("odometry_std and sensor_std need three entries (m, m, rad)")
        if not all(math.isfinite(v) and v >= 0 for v in values):
            raise ValueError(f"noise standard deviations must be finite and >= 0, got {values}")

    @property
    def odometry_cov(self) -> FloatArray:
        """3×3 covariance of ``δ``."""
        return np.diag(np.square(self.odometry_std))

    @property
    def sensor_cov(self) -> FloatArray:
        """3×3 covariance of ``z``."""
        return np.diag(np.square(self.sensor_std))


@dataclass(frozen=True)
class MountingStep:
    """One step of :class:`MountingCalibrationEKF`.

    Attributes
    ----------
    t : float
        Time, s.
    odometry : ndarray, shape (3,) or (2,)
        Base increment ``δ`` (m, m, rad), or, for the augmented filter, tick
        increments ``(n_left, n_right)`` of the step.
    sensor_motion : ndarray, shape (3,) or None
        Measured sensor ego-motion over the step (``None``: predict only).
    sensor_cov : ndarray, shape (3, 3) or None
        Its covariance (``None``: ``noise.sensor_cov``).
    """

    t: float
    odometry: FloatArray
    sensor_motion: FloatArray | None = None
    sensor_cov: FloatArray | None = None


@dataclass(frozen=True)
class MountingObservability:
    """How much the data constrained each calibrated parameter.

    Attributes
    ----------
    names : tuple of str
        Parameter names (``l_x, l_y, l_theta`` and, if estimated, the scales).
    std_reference : ndarray
        Reference standard deviations (prior, or what counts as "unknown").
    std_posterior : ndarray
        Posterior standard deviations.
    ratio : ndarray
        ``std_posterior / std_reference``.
    poorly_observable : tuple of str
        Names whose ratio exceeds the threshold.
    """

    names: tuple[str, ...]
    std_reference: FloatArray
    std_posterior: FloatArray
    ratio: FloatArray
    poorly_observable: tuple[str, ...]

    @property
    def ok(self) -> bool:
        """True when every parameter was well constrained."""
        return not self.poorly_observable

    @property
    def message(self) -> str:
        """Human-readable summary."""
        if self.ok:
            return "all calibration parameters observable"
        return (
            f"low observability of {', '.join(self.poorly_observable)}: the data reduced their "
            "uncertainty by less than half. Pure straight motion leaves l_x, l_y "
            "unobservable and pure rotation in place confounds l_theta with the direction of "
            "(l_x, l_y); drive curves (turning while translating)."
        )


class LowObservabilityWarning(UserWarning):
    """The calibration data did not constrain some parameters (see MountingObservability)."""


def mounting_observability(
    P: npt.ArrayLike,
    std_reference: npt.ArrayLike,
    *,
    names: tuple[str, ...] | None = None,
    threshold: float = 0.5,
) -> MountingObservability:
    """Flag parameters whose posterior standard deviation did not shrink enough.

    Parameters
    ----------
    P : array_like, shape (n, n)
        Posterior covariance of the parameters.
    std_reference : array_like, shape (n,)
        Standard deviation before the data (the prior of an EKF).
    names : tuple of str, optional
        Parameter names; defaults to ``l_x, l_y, l_theta[, k_left, k_right, k_wheelbase]``.
    threshold : float, default 0.5
        A parameter is poorly observable when ``std_post > threshold · std_ref``.
    """
    P_a = np.asarray(P, dtype=float)
    ref = np.asarray(std_reference, dtype=float)
    n = ref.shape[0]
    if P_a.shape != (n, n):
        raise ValueError(f"P must have shape ({n}, {n}) like std_reference, got {P_a.shape}")
    if names is None:
        names = (_MOUNT_NAMES + _SCALE_NAMES)[:n]
    diag = np.diag(P_a)
    std_post = np.sqrt(np.where(np.isnan(diag), np.inf, np.clip(diag, 0.0, None)))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(ref > 0, std_post / ref, np.inf)
    poor = tuple(nm for nm, r in zip(names, ratio) if not r <= threshold)
    return MountingObservability(
        names=tuple(names),
        std_reference=ref,
        std_posterior=std_post,
        ratio=ratio,
        poorly_observable=poor,
    )


class MountingCalibrationEKF:
    r"""Simultaneous estimation of the sensor pose and its mounting (Censi et al. 2013).

    State (SEEDS_DIGEST §1.6):

    .. math::

        x = [s_x, s_y, s_\theta, l_x, l_y, l_\theta]
        \ (\,[\ldots, k_L, k_R, k_b]\ \text{if odometry is estimated}),

    with ``s`` the sensor pose in the world, ``l`` the sensor pose in the base
    frame, and optional multiplicative corrections of the left/right wheel
    radius and the wheelbase. The robot pose is ``q = s ⊕ ⊖l``.

    Motion with the odometry increment ``δ_k`` (given, or from tick increments
    through the scaled kinematics):

    .. math::

        q_k = q_{k-1} \oplus \delta_k \;\Rightarrow\;
        s_k = s_{k-1} \oplus (\ominus l \oplus \delta_k \oplus l), \quad l_k = l_{k-1}.

    Observation: the sensor's own ego-motion (VO/ICP)

    .. math::

        z_k = \ominus s_{k-1} \oplus s_k = \ominus l \oplus \delta_k \oplus l + v_k .

    Jacobians are analytic (:func:`sensor_motion_jacobians`,
    :func:`arc_increment_jacobian`). The odometry noise enters ``z`` through
    ``δ``; it is added to the measurement noise,
    ``R_eff = R_z + H_δ Σ_δ H_δᵀ``, and to the process noise of ``s``.

    Observability: with straight motion only (``δ_θ = 0``) ``z_xy = R(−l_θ) δ_xy``
    does not depend on ``(l_x, l_y)``: they are unobservable (``l_θ`` is seen
    through the direction of travel). With rotation in place only, ``z`` depends
    on ``R(−l_θ)(l_x, l_y)`` alone, so ``l_θ`` and the direction of ``(l_x, l_y)``
    cannot be separated. Curved motion (turning while translating) is needed;
    :meth:`observability` reports parameters the data did not constrain.

    Parameters
    ----------
    l0 : array_like, shape (3,)
        Initial mounting guess ``[l_x, l_y, l_θ]`` (m, m, rad), e.g. from CAD.
    P0 : array_like, shape (3, 3), optional
        Prior covariance of ``l0``; default ``diag(0.1 m, 0.1 m, 0.2 rad)²``.
    noise : MountingNoise, optional
    estimate_odometry : bool, default False
        Augment the state with wheel-radius and wheelbase scale factors; the
        odometry input then is tick increments and ``kinematics`` is required.
    kinematics : DiffDriveKinematics, optional
        Nominal kinematics (augmented mode).
    scales0 : array_like, shape (3,), optional
        Initial ``[k_L, k_R, k_b]`` (default ones), e.g. ``(c_L, c_R, E_b)``
        from :func:`realitygap.estimators.umbmark.umbmark`.
    P0_scales : array_like, shape (3, 3), optional
        Prior covariance of the scales; default ``diag(0.05)²``.
    s0 : array_like, shape (3,), optional
        Initial sensor pose in the world; default ``l0`` (robot at the origin).
    """

    def __init__(
        self,
        l0: npt.ArrayLike,
        P0: npt.ArrayLike | None = None,
        *,
        noise: MountingNoise | None = None,
        estimate_odometry: bool = False,
        kinematics: DiffDriveKinematics | None = None,
        scales0: npt.ArrayLike | None = None,
        P0_scales: npt.ArrayLike | None = None,
        s0: npt.ArrayLike | None = None,
    ):
        self._l0 = check_finite("l0", l0, (3,)).copy()
        self._P0_l = (
            np.diag(DEFAULT_MOUNTING_STD) ** 2
            if P0 is None
            else check_finite("P0", P0, (3, 3)).copy()
        )
        self.noise = noise if noise is not None else MountingNoise()
        self.estimate_odometry = bool(estimate_odometry)
        if self.estimate_odometry and kinematics is None:
            raise ValueError(
                "estimate_odometry=True needs the nominal kinematics: pass "
                "kinematics=DiffDriveKinematics(...)"
            )
        self.kinematics = kinematics
        self._k0 = np.ones(3) if scales0 is None else check_finite("scales0", scales0, (3,)).copy()
        self._P0_k = (
            np.diag(DEFAULT_SCALE_STD) ** 2
            if P0_scales is None
            else check_finite("P0_scales", P0_scales, (3, 3)).copy()
        )
        self._s0 = None if s0 is None else check_finite("s0", s0, (3,)).copy()
        self.reset()

    # -- access -------------------------------------------------------------
    @property
    def n(self) -> int:
        """State dimension (6, or 9 with odometry scales)."""
        return 9 if self.estimate_odometry else 6

    @property
    def x(self) -> FloatArray:
        """Full state vector, a copy."""
        return self._x.copy()

    @property
    def P(self) -> FloatArray:
        """Full state covariance, a copy."""
        return self._P.copy()

    @property
    def mounting(self) -> FloatArray:
        """Current mounting estimate ``l = [l_x, l_y, l_θ]``."""
        return self._x[3:6].copy()

    @property
    def mounting_cov(self) -> FloatArray:
        """3×3 covariance of the mounting estimate."""
        return self._P[3:6, 3:6].copy()

    @property
    def odometry_scales(self) -> FloatArray:
        """Current ``[k_L, k_R, k_b]`` (ones when not estimated)."""
        return self._x[6:9].copy() if self.estimate_odometry else np.ones(3)

    @property
    def robot_pose(self) -> FloatArray:
        """Base pose ``q = s ⊕ ⊖l`` in the world."""
        return se2_compose(self._x[:3], se2_inverse(self._x[3:6]))

    def calibrated_kinematics(self) -> DiffDriveKinematics:
        """Nominal kinematics scaled by the estimated factors (augmented mode)."""
        if self.kinematics is None:
            raise ValueError("no kinematics given to this filter")
        k = self.odometry_scales
        return self.kinematics.scaled(left=k[0], right=k[1], wheelbase=k[2])

    def observability(self, threshold: float = 0.5) -> MountingObservability:
        """Compare the posterior with the prior (see :func:`mounting_observability`)."""
        P_prior = np.zeros((self.n - 3, self.n - 3))
        P_prior[:3, :3] = self._P0_l
        if self.estimate_odometry:
            P_prior[3:, 3:] = self._P0_k
        return mounting_observability(
            self._P[3:, 3:], np.sqrt(np.diag(P_prior)), threshold=threshold
        )

    # -- Estimator protocol ---------------------------------------------------
    def reset(self, initial: Any | None = None) -> Estimate:
        """Restart; ``initial`` is the robot pose (3,) in the world (``None``: origin)."""
        q0 = np.zeros(3) if initial is None else check_finite("initial", initial, (3,))
        s0 = se2_compose(q0, self._l0) if self._s0 is None or initial is not None else self._s0
        x = [np.asarray(s0, dtype=float), self._l0]
        P = np.zeros((self.n, self.n))
        P[3:6, 3:6] = self._P0_l
        # s = q ⊕ l: the prior on l propagates into s.
        _, J_l = se2_compose_jacobians(q0, self._l0)
        P[:3, :3] = J_l @ self._P0_l @ J_l.T
        P[:3, 3:6] = J_l @ self._P0_l
        P[3:6, :3] = P[:3, 3:6].T
        if self.estimate_odometry:
            x.append(self._k0)
            P[6:, 6:] = self._P0_k
        self._x = np.concatenate(x)
        self._P = P
        self._t = 0.0
        self._n_rejected = 0
        self._n_updates = 0
        return self._make_estimate("ok")

    def update(self, measurement: MountingStep | None) -> Estimate:
        """One :class:`MountingStep` (predict, then correct if a sensor motion is given)."""
        if measurement is None:
            return self._make_estimate("ok")
        if not isinstance(measurement, MountingStep):
            raise TypeError(
                f"MountingCalibrationEKF.update expects MountingStep or None, got "
                f"{type(measurement).__name__}"
            )
        status = "ok"
        if not self.step(measurement.odometry, measurement.sensor_motion, measurement.sensor_cov):
            status = "rejected: non-finite odometry or sensor motion"
        if all_finite(measurement.t):
            self._t = float(measurement.t)
        return self._make_estimate(status)

    # -- filter ---------------------------------------------------------------
    def _delta(self, odometry: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Base increment, its Jacobian w.r.t. the scales (3×3) and its covariance (3×3)."""
        if not self.estimate_odometry:
            return odometry.copy(), np.zeros((3, 3)), self.noise.odometry_cov
        assert self.kinematics is not None
        kin = self.kinematics
        k_l, k_r, k_b = self._x[6:9]
        s_l0 = kin.meters_per_tick_left * odometry[0]
        s_r0 = kin.meters_per_tick_right * odometry[1]
        s_l, s_r, b = k_l * s_l0, k_r * s_r0, k_b * kin.wheelbase
        ds, dth = 0.5 * (s_l + s_r), (s_r - s_l) / b
        J_arc = arc_increment_jacobian(ds, dth)
        # ∂(ds, dθ)/∂(k_L, k_R, k_b)
        J_u_k = np.array([[0.5 * s_l0, 0.5 * s_r0, 0.0], [-s_l0 / b, s_r0 / b, -dth / k_b]])
        # ∂(ds, dθ)/∂(s_L, s_R) for the wheel-distance noise
        J_u_s = np.array([[0.5, 0.5], [-1.0 / b, 1.0 / b]])
        n = self.noise
        var = n.wheel_std_per_sqrt_m**2 * np.abs([s_l, s_r]) + n.wheel_std_floor**2
        J_ds = J_arc @ J_u_s
        return arc_increment(ds, dth), J_arc @ J_u_k, J_ds @ np.diag(var) @ J_ds.T

    def step(
        self,
        odometry: npt.ArrayLike,
        sensor_motion_measured: npt.ArrayLike | None = None,
        sensor_cov: npt.ArrayLike | None = None,
    ) -> bool:
        """Predict with one odometry input and, if given, correct with the sensor motion.

        Parameters
        ----------
        odometry : array_like, shape (3,) or (2,)
            ``δ`` (m, m, rad), or tick increments ``(n_L, n_R)`` in augmented mode.
        sensor_motion_measured : array_like, shape (3,), optional
            Measured ``z = ⊖s_{k-1} ⊕ s_k``.
        sensor_cov : array_like, shape (3, 3), optional
            Covariance of ``z``; default ``noise.sensor_cov``.

        Returns
        -------
        bool
            False when the input was rejected (non-finite or wrong shape); the
            state is then unchanged.
        """
        expected = (2,) if self.estimate_odometry else (3,)
        u = np.asarray(odometry, dtype=float)
        if u.shape != expected:
            raise ValueError(
                f"odometry must have shape {expected} "
                f"({'tick increments (n_L, n_R)' if self.estimate_odometry else 'δ = [dx, dy, dθ]'}), "
                f"got {u.shape}"
            )
        z = None if sensor_motion_measured is None else np.asarray(sensor_motion_measured, float)
        R_z = self.noise.sensor_cov if sensor_cov is None else np.asarray(sensor_cov, float)
        if not all_finite(u) or (z is not None and (not all_finite(z, R_z) or z.shape != (3,))):
            self._n_rejected += 1
            return False

        delta, J_delta_k, Sigma_delta = self._delta(u)
        l = self._x[3:6]
        z_hat = sensor_motion(l, delta)
        H_l, H_d = sensor_motion_jacobians(l, delta)

        # Predict s_k = s ⊕ z_hat(l, δ(k)).
        s = self._x[:3]
        J_s, J_z = se2_compose_jacobians(s, z_hat)
        F = np.eye(self.n)
        F[:3, :3] = J_s
        F[:3, 3:6] = J_z @ H_l
        if self.estimate_odometry:
            F[:3, 6:9] = J_z @ H_d @ J_delta_k
        G = J_z @ H_d
        x_pred = self._x.copy()
        x_pred[:3] = se2_compose(s, z_hat)
        P_pred = F @ self._P @ F.T
        P_pred[:3, :3] += G @ Sigma_delta @ G.T
        P_pred = 0.5 * (P_pred + P_pred.T)

        if z is None:
            self._x, self._P = x_pred, P_pred
            return True

        # Correct with z = ⊖l ⊕ δ ⊕ l (independent of s).
        H = np.zeros((3, self.n))
        H[:, 3:6] = H_l
        if self.estimate_odometry:
            H[:, 6:9] = H_d @ J_delta_k
        R_eff = R_z + H_d @ Sigma_delta @ H_d.T
        innovation = z - z_hat
        innovation[2] = wrap_angle(innovation[2])
        try:
            x_new, P_new, _ = joseph_update(x_pred, P_pred, innovation, H, R_eff)
        except np.linalg.LinAlgError:
            self._n_rejected += 1
            return False
        if not (np.all(np.isfinite(x_new)) and np.all(np.isfinite(P_new))):
            self._n_rejected += 1
            return False
        x_new[2] = wrap_angle(x_new[2])
        x_new[5] = wrap_angle(x_new[5])
        self._x, self._P = x_new, P_new
        self._n_updates += 1
        return True

    def _make_estimate(self, status: str) -> Estimate:
        q = self.robot_pose
        # q = s ⊕ ⊖l: first-order covariance from s and l.
        l = self._x[3:6]
        J_s, J_il = se2_compose_jacobians(self._x[:3], se2_inverse(l))
        c, s_ = math.cos(l[2]), math.sin(l[2])
        J_inv = np.array(  # ∂(⊖l)/∂l
            [
                [-c, -s_, s_ * l[0] - c * l[1]],
                [s_, -c, c * l[0] + s_ * l[1]],
                [0.0, 0.0, -1.0],
            ]
        )
        J = np.hstack([J_s, J_il @ J_inv])
        cov = J @ self._P[:6, :6] @ J.T
        extras: dict[str, Any] = {
            "mounting": self.mounting,
            "mounting_cov": self.mounting_cov,
            "sensor_pose": self._x[:3].copy(),
            "n_updates": self._n_updates,
            "n_rejected": self._n_rejected,
        }
        if self.estimate_odometry:
            extras["odometry_scales"] = self.odometry_scales
        return Estimate(t=self._t, pose=q, cov=0.5 * (cov + cov.T), status=status, extras=extras)


def _check_batch(
    deltas: npt.ArrayLike, sensor_motions: npt.ArrayLike
) -> tuple[FloatArray, FloatArray]:
    d = np.asarray(deltas, dtype=float)
    z = np.asarray(sensor_motions, dtype=float)
    if d.ndim != 2 or d.shape[1] != 3:
        raise ValueError(
            f"deltas must have shape (N, 3) (base increments dx, dy, dθ), got {d.shape}"
        )
    if z.shape != d.shape:
        raise ValueError(
            f"sensor_motions must have the same shape as deltas {d.shape}, got {z.shape}"
        )
    if d.shape[0] == 0:
        raise ValueError("deltas and sensor_motions are empty; need at least one step")
    if not (np.all(np.isfinite(d)) and np.all(np.isfinite(z))):
        raise ValueError("deltas and sensor_motions must be finite; drop NaN/inf rows first")
    return d, z


def calibrate_mounting(
    deltas: npt.ArrayLike,
    sensor_motions: npt.ArrayLike,
    l0: npt.ArrayLike,
    *,
    P0: npt.ArrayLike | None = None,
    noise: MountingNoise | None = None,
    n_passes: int = 3,
    warn: bool = True,
) -> tuple[FloatArray, FloatArray]:
    """Batch mounting calibration with :class:`MountingCalibrationEKF`.

    Parameters
    ----------
    deltas : array_like, shape (N, 3)
        Base increments ``δ_k`` from odometry (m, m, rad), base frame.
    sensor_motions : array_like, shape (N, 3)
        Sensor ego-motions ``z_k`` over the same steps (m, m, rad), sensor frame.
    l0 : array_like, shape (3,)
        Initial mounting guess.
    P0 : array_like, shape (3, 3), optional
        Prior covariance of ``l0`` (default as in the filter).
    noise : MountingNoise, optional
    n_passes : int, default 3
        The filter is run ``n_passes`` times, each pass starting from the
        previous estimate with the prior covariance ``P0``; this relinearises
        around a better guess (the covariance returned is that of the last pass).
    warn : bool, default True
        Emit :class:`LowObservabilityWarning` if some parameter was not constrained.

    Returns
    -------
    l_hat : ndarray, shape (3,)
        Estimated mounting ``[l_x, l_y, l_θ]``.
    P : ndarray, shape (3, 3)
        Its posterior covariance.
    """
    d, z = _check_batch(deltas, sensor_motions)
    if int(n_passes) < 1:
        raise ValueError(f"n_passes must be >= 1, got {n_passes}")
    l_hat = check_finite("l0", l0, (3,)).copy()
    ekf = None
    for _ in range(int(n_passes)):
        ekf = MountingCalibrationEKF(l_hat, P0, noise=noise)
        for k in range(d.shape[0]):
            ekf.step(d[k], z[k])
        l_hat = ekf.mounting
    assert ekf is not None
    if warn:
        report = ekf.observability()
        if not report.ok:
            warnings.warn(report.message, LowObservabilityWarning, stacklevel=2)
    return l_hat, ekf.mounting_cov


def calibrate_mounting_lsq(
    deltas: npt.ArrayLike,
    sensor_motions: npt.ArrayLike,
    l0: npt.ArrayLike,
    *,
    noise: MountingNoise | None = None,
    std_reference: npt.ArrayLike = DEFAULT_MOUNTING_STD,
    warn: bool = True,
) -> tuple[FloatArray, FloatArray]:
    r"""Mounting by nonlinear least squares over the same residuals as the EKF.

    Minimises

    .. math::

        \sum_k \big\| W^{-1/2} \big( (\ominus l \oplus \delta_k \oplus l) \boxminus z_k
        \big) \big\|^2

    with :func:`scipy.optimize.least_squares` and analytic Jacobians; ``W`` is
    diagonal, sensor plus odometry variance per component (the odometry noise
    mapped at ``l = 0``, a first-order weighting). The covariance is
    ``(JᵀJ)⁻¹`` at the solution (whitened residuals), pseudo-inverted so that
    unobservable directions come out with a very large variance.

    Parameters
    ----------
    deltas, sensor_motions, l0, noise
        As in :func:`calibrate_mounting`.
    std_reference : array_like, shape (3,)
        Standard deviations regarded as "unknown" for the observability check.
    warn : bool, default True
        Emit :class:`LowObservabilityWarning` on poorly constrained parameters.

    Returns
    -------
    l_hat : ndarray, shape (3,)
    P : ndarray, shape (3, 3)
    """
    d, z = _check_batch(deltas, sensor_motions)
    x0 = check_finite("l0", l0, (3,)).copy()
    nz = noise if noise is not None else MountingNoise()
    w = 1.0 / np.sqrt(np.square(nz.sensor_std) + np.square(nz.odometry_std))

    def residuals(l: FloatArray) -> FloatArray:
        r = sensor_motion(l, d) - z
        r[:, 2] = wrap_angle(r[:, 2])
        return (r * w).ravel()

    def jacobian(l: FloatArray) -> FloatArray:
        Rm = rotation_2d(l[2]).T
        c, s = np.cos(d[:, 2]), np.sin(d[:, 2])
        J = np.zeros((d.shape[0], 3, 3))
        # ∂z_xy/∂t_l = R(-φ)(R(δθ) - I)
        A = np.stack([np.stack([c - 1.0, -s], -1), np.stack([s, c - 1.0], -1)], -2)
        J[:, :2, :2] = Rm @ A
        wv = A @ l[:2] + d[:, :2]
        J[:, :2, 2] = -(Rm @ SKEW_2D @ wv.T).T
        return (J * w[None, :, None]).reshape(-1, 3)

    sol = least_squares(residuals, x0, jac=jacobian, method="lm", xtol=1e-14, ftol=1e-14)
    l_hat = sol.x.copy()
    l_hat[2] = wrap_angle(l_hat[2])
    JtJ = sol.jac.T @ sol.jac
    P = np.linalg.pinv(JtJ, rcond=1e-12, hermitian=True)
    # Directions with (numerically) no information get an infinite variance.
    eigval, eigvec = np.linalg.eigh(JtJ)
    null = eigval <= 1e-10 * max(float(eigval.max()), 1e-300)
    if np.any(null):
        P = P + eigvec[:, null] @ np.diag(np.full(int(null.sum()), 1e12)) @ eigvec[:, null].T
    if warn:
        report = mounting_observability(P, std_reference)
        if not report.ok:
            warnings.warn(report.message, LowObservabilityWarning, stacklevel=2)
    return l_hat, P
