"""IMU pre-integration between keyframes and the static initialisation of a climbing robot.

:class:`Preintegration` integrates IMU readings between two keyframes with bias
Jacobians and covariance (Forster et al., "On-manifold preintegration");
:func:`static_initialise` estimates the gyro bias and roll/pitch from a still robot.

Frames: ``world`` is the VIO frame, gravity along :math:`-z`, its origin and yaw
those of the body at initialisation; ``body`` = IMU frame (x forward, z away from
the surface); ``camera`` is OpenCV's optical frame (z along the optical axis).
Rotations are matrices :math:`R_{wb}` (body → world); quaternions are xyzw.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from realitygap.core.geometry import (
    hat,
    so3_exp,
)
from realitygap.estimators.climb.measurements import (
    ImuSample,
    check_vec3,
)

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "Preintegration",
    "StaticInit",
    "static_initialise",
]


class Preintegration:
    """IMU pre-integration between two keyframes (Forster et al.).

    With bias-corrected readings :math:`\\tilde\\omega_k = \\omega_k - b_g`,
    :math:`\\tilde f_k = f_k - b_a`, each held constant over :math:`\\Delta t_k`:

    .. math::

        \\Delta R_{k+1} &= \\Delta R_k \\mathrm{Exp}(\\tilde\\omega_k \\Delta t_k) \\\\
        \\Delta v_{k+1} &= \\Delta v_k + \\Delta R_k \\Gamma_1 \\tilde f_k \\Delta t_k \\\\
        \\Delta p_{k+1} &= \\Delta p_k + \\Delta v_k \\Delta t_k
                          + \\Delta R_k \\Gamma_2 \\tilde f_k \\Delta t_k^2

    with :math:`\\Gamma_1 = \\int_0^1 \\mathrm{Exp}(\\sigma\\theta)d\\sigma`,
    :math:`\\Gamma_2 = \\int_0^1 (1-\\sigma)\\mathrm{Exp}(\\sigma\\theta)d\\sigma`,
    :math:`\\theta = \\tilde\\omega_k\\Delta t_k` (exact for piecewise-constant
    readings). The bias Jacobians and the covariance of :math:`[\\delta\\theta,
    \\delta v, \\delta p]` follow Forster's first-order recursions. Between states
    :math:`i, j`:

    .. math::

        R_j = R_i \\Delta R, \\quad
        v_j = v_i + g\\Delta t + R_i \\Delta v, \\quad
        p_j = p_i + v_i \\Delta t + \\tfrac12 g \\Delta t^2 + R_i \\Delta p.

    Parameters
    ----------
    bias_gyro, bias_accel : (3,)
        Biases used for integration (linearisation point), rad/s and m/s².
    gyro_noise_density, accel_noise_density
        White-noise densities, rad/s/√Hz and m/s²/√Hz.
    """

    def __init__(
        self,
        bias_gyro: npt.ArrayLike = (0.0, 0.0, 0.0),
        bias_accel: npt.ArrayLike = (0.0, 0.0, 0.0),
        *,
        gyro_noise_density: float = 0.005,
        accel_noise_density: float = 0.05,
    ) -> None:
        self.bias_gyro = check_vec3("bias_gyro", bias_gyro).copy()
        self.bias_accel = check_vec3("bias_accel", bias_accel).copy()
        if gyro_noise_density < 0 or accel_noise_density < 0:
            raise ValueError("noise densities must be non-negative")
        self._sg2 = float(gyro_noise_density) ** 2
        self._sa2 = float(accel_noise_density) ** 2
        self.dt = 0.0
        self.delta_R = np.eye(3)
        self.delta_v = np.zeros(3)
        self.delta_p = np.zeros(3)
        self.J_R_bg = np.zeros((3, 3))
        self.J_v_bg = np.zeros((3, 3))
        self.J_v_ba = np.zeros((3, 3))
        self.J_p_bg = np.zeros((3, 3))
        self.J_p_ba = np.zeros((3, 3))
        self.cov = np.zeros((9, 9))

    def integrate(self, gyro: npt.ArrayLike, accel: npt.ArrayLike, dt: float) -> None:
        """Add one reading held for ``dt`` s (``dt = 0`` is a no-op).

        :math:`\\mathrm{Exp}(\\theta)`, :math:`J_r(\\theta)`, :math:`\\Gamma_1` and
        :math:`\\Gamma_2` share :math:`[\\theta]_\\times` and its square; the
        accelerometer noise enters the covariance through :math:`\\Delta R` only as
        :math:`\\Delta R \\Delta R^\\top = I`, so its term is a constant pattern.
        """
        if not (math.isfinite(dt) and dt >= 0.0):
            raise ValueError(f"dt must be a non-negative time in s, got {dt!r}")
        if dt == 0.0:
            return
        w = np.asarray(gyro, dtype=float) - self.bias_gyro
        a = np.asarray(accel, dtype=float) - self.bias_accel
        theta = w * dt
        ang = math.sqrt(float(theta @ theta))
        K = hat(theta)
        K2 = K @ K
        eye = np.eye(3)
        if ang < 1e-8:
            E = eye + K + 0.5 * K2
        else:
            E = eye + (math.sin(ang) / ang) * K + ((1.0 - math.cos(ang)) / ang**2) * K2
        if ang < 1e-6:
            Jr = eye - 0.5 * K + K2 / 6.0
        else:
            c1 = (1 - math.cos(ang)) / ang**2
            c2 = (ang - math.sin(ang)) / ang**3
            Jr = eye - c1 * K + c2 * K2
        if ang < 1e-4:
            g1 = eye + K / 2.0 + K2 / 6.0
            g2 = 0.5 * eye + K / 6.0 + K2 / 24.0
        else:
            sn, cs = math.sin(ang), math.cos(ang)
            g1 = eye + ((1 - cs) / ang**2) * K + ((ang - sn) / ang**3) * K2
            g2 = 0.5 * eye + ((ang - sn) / ang**3) * K + ((ang * ang / 2 - 1 + cs) / ang**4) * K2
        dR = self.delta_R
        dR_a = dR @ hat(a)
        dR_a_J = dR_a @ self.J_R_bg
        dt2 = dt * dt
        # Jacobians (old ΔR), p before v before R
        self.J_p_ba = self.J_p_ba + self.J_v_ba * dt - 0.5 * dR * dt2
        self.J_p_bg = self.J_p_bg + self.J_v_bg * dt - 0.5 * dR_a_J * dt2
        self.J_v_ba = self.J_v_ba - dR * dt
        self.J_v_bg = self.J_v_bg - dR_a_J * dt
        self.J_R_bg = E.T @ self.J_R_bg - Jr * dt
        # covariance of [dtheta, dv, dp]
        A = np.eye(9)
        A[0:3, 0:3] = E.T
        A[3:6, 0:3] = -dR_a * dt
        A[6:9, 0:3] = -0.5 * dR_a * dt2
        A[6:9, 3:6] = eye * dt
        cov = A @ self.cov @ A.T
        cov[0:3, 0:3] += (self._sg2 * dt) * (Jr @ Jr.T)
        qa = self._sa2 * dt
        cov[3:6, 3:6] += qa * eye
        cov[3:6, 6:9] += (0.5 * qa * dt) * eye
        cov[6:9, 3:6] += (0.5 * qa * dt) * eye
        cov[6:9, 6:9] += (0.25 * qa * dt2) * eye
        self.cov = cov
        # mean
        self.delta_p = self.delta_p + self.delta_v * dt + dR @ (g2 @ a) * dt2
        self.delta_v = self.delta_v + dR @ (g1 @ a) * dt
        self.delta_R = dR @ E
        self.dt += dt

    def corrected(
        self, bias_gyro: npt.ArrayLike, bias_accel: npt.ArrayLike
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(ΔR, Δv, Δp)`` for other biases, to first order (no re-integration)."""
        dbg = np.asarray(bias_gyro, dtype=float) - self.bias_gyro
        dba = np.asarray(bias_accel, dtype=float) - self.bias_accel
        if not (dbg.any() or dba.any()):  # at the linearisation point (the usual case)
            return self.delta_R.copy(), self.delta_v.copy(), self.delta_p.copy()
        dR = self.delta_R @ so3_exp(self.J_R_bg @ dbg)
        dv = self.delta_v + self.J_v_bg @ dbg + self.J_v_ba @ dba
        dp = self.delta_p + self.J_p_bg @ dbg + self.J_p_ba @ dba
        return dR, dv, dp

    def predict(
        self,
        R_i: FloatArray,
        p_i: FloatArray,
        v_i: FloatArray,
        gravity: FloatArray,
        bias_gyro: npt.ArrayLike | None = None,
        bias_accel: npt.ArrayLike | None = None,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """State ``(R_j, p_j, v_j)`` at the end of the interval (world frame)."""
        bg = self.bias_gyro if bias_gyro is None else bias_gyro
        ba = self.bias_accel if bias_accel is None else bias_accel
        dR, dv, dp = self.corrected(bg, ba)
        T = self.dt
        R_j = R_i @ dR
        v_j = v_i + gravity * T + R_i @ dv
        p_j = p_i + v_i * T + 0.5 * gravity * T * T + R_i @ dp
        return R_j, p_j, v_j


@dataclass(frozen=True, eq=False)
class StaticInit:
    """Result of :func:`static_initialise`.

    Attributes
    ----------
    t
        Time of the last sample used, s.
    bias_gyro : (3,)
        Mean angular rate, rad/s.
    bias_accel : (3,)
        Accelerometer bias along the measured gravity direction, m/s² (the other
        components are unobservable at rest and set to 0).
    R_world_body : (3, 3)
        Roll and pitch from the mean specific force, yaw 0 (ZYX convention).
    gyro_std
        RMS deviation of the angular rate from its mean, rad/s (motion check).
    still
        True when ``gyro_std`` and the specific-force spread look like a still robot.
    """

    t: float
    bias_gyro: FloatArray
    bias_accel: FloatArray
    R_world_body: FloatArray
    gyro_std: float
    still: bool


def static_initialise(
    samples: Sequence[ImuSample],
    *,
    gravity: float = 9.81,
    max_gyro_std: float = 0.3,
    max_accel_std: float = 2.0,
) -> StaticInit:
    """Initialise the VIO from IMU readings of a still robot.

    At rest :math:`\\omega = b_g + n_g` and :math:`f = R_{wb}^\\top (0,0,g) + b_a + n_a`,
    so the mean rate is the gyro bias and the mean specific force points along body
    "up": roll :math:`\\phi = \\mathrm{atan2}(f_y, f_z)`, pitch
    :math:`\\theta = \\mathrm{atan2}(-f_x, \\sqrt{f_y^2+f_z^2})`, yaw 0.

    Parameters
    ----------
    samples
        At least 10 readings of the still robot.
    gravity
        Magnitude of gravity, m/s².
    max_gyro_std, max_accel_std
        Spreads (rad/s, m/s²) above which ``still`` is False.
    """
    if len(samples) < 10:
        raise ValueError(f"static initialisation needs at least 10 IMU samples, got {len(samples)}")
    if not all(isinstance(s, ImuSample) for s in samples):
        raise TypeError("samples must be ImuSample instances")
    gyro = np.array([s.gyro for s in samples])
    acc = np.array([s.accel for s in samples])
    bg = gyro.mean(axis=0)
    f = acc.mean(axis=0)
    norm_f = float(np.linalg.norm(f))
    if norm_f < 0.5 * gravity:
        raise ValueError(
            f"mean specific force {norm_f:.3g} m/s² is far below gravity {gravity} m/s²; "
            "check the accelerometer units (m/s²) and that the robot is still"
        )
    roll = math.atan2(f[1], f[2])
    pitch = math.atan2(-f[0], math.hypot(f[1], f[2]))
    R = Rotation.from_euler("ZYX", [0.0, pitch, roll]).as_matrix()
    ba = (norm_f - gravity) * f / norm_f
    gyro_std = float(np.sqrt(np.mean(np.sum((gyro - bg) ** 2, axis=1))))
    acc_std = float(np.sqrt(np.mean(np.sum((acc - f) ** 2, axis=1))))
    return StaticInit(
        t=samples[-1].t,
        bias_gyro=bg,
        bias_accel=ba,
        R_world_body=R,
        gyro_std=gyro_std,
        still=gyro_std <= max_gyro_std and acc_std <= max_accel_std,
    )
