"""A small visual-inertial odometry for a climbing robot with a down-looking camera.

Pieces, usable on their own:

* measurement dataclasses produced by the robot layer: :class:`ImuSample`,
  :class:`CameraFrame`, :class:`RelativeMotion` (already computed visual motion, the
  fast geometric sensor mode), :class:`TetherReading`; the output :class:`ClimbEstimate`;
* SO(3) helpers re-exported from :mod:`realitygap.core.geometry`;
* :class:`Preintegration` — IMU pre-integration between keyframes with bias
  Jacobians and covariance (Forster et al., "On-manifold preintegration");
* :func:`static_initialise` — gyro bias and roll/pitch from a still robot;
* :func:`relative_motion_from_images` — OpenCV features (KLT) + homography of the
  locally planar surface; the known camera height gives the metric scale;
* :class:`SlidingWindowVIO` — a sliding-window least-squares estimator
  (:func:`scipy.optimize.least_squares`, robust loss) over poses, velocities and
  biases with pre-integrated IMU factors, bias random walks, visual relative-motion
  factors, and a prior on the oldest state obtained by marginalisation.

Frames: ``world`` is the VIO frame, gravity along :math:`-z`, its origin and yaw
those of the body at initialisation; ``body`` = IMU frame (x forward, z away from
the surface); ``camera`` is OpenCV's optical frame (z along the optical axis).
Rotations are matrices :math:`R_{wb}` (body → world); quaternions are xyzw.
The IMU measures angular rate :math:`\\omega` (rad/s) and specific force
:math:`f = R_{wb}^\\top (a - g)` (m/s²), :math:`g = (0, 0, -9.81)`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
from scipy.linalg import solve_triangular
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from realitygap.core.geometry import (
    hat,
    hat_batch,
    matrix_from_quat_xyzw,
    quat_xyzw_from_matrix,
    right_jacobian,
    right_jacobian_batch,
    right_jacobian_inv,
    right_jacobian_inv_batch,
    so3_exp,
    so3_exp_batch,
    so3_log,
    so3_log_batch,
)

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "CameraFrame",
    "ClimbEstimate",
    "ImuSample",
    "Preintegration",
    "RelativeMotion",
    "SlidingWindowVIO",
    "StaticInit",
    "TetherReading",
    "VioConfig",
    "relative_motion_from_images",
    "static_initialise",
]

_EMPTY: Mapping[str, Any] = MappingProxyType({})


def _vec3(name: str, value: npt.ArrayLike) -> FloatArray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,) or not math.isfinite(arr[0] + arr[1] + arr[2]):
        raise ValueError(f"{name} must be a finite (3,) array, got {value!r}")
    return arr


def _time(name: str, value: float) -> float:
    t = float(value)
    if not math.isfinite(t):
        raise ValueError(f"{name} must be a finite time in s, got {value!r}")
    return t


# --------------------------------------------------------------------------- measurements


@dataclass(frozen=True, eq=False)
class ImuSample:
    """One IMU reading, held constant over ``[t, t_next)``.

    Attributes
    ----------
    t
        Time, s.
    gyro : (3,)
        Angular rate of the body in the body frame, rad/s.
    accel : (3,)
        Specific force in the body frame, m/s² (≈ +9.81 along body up at rest).
    """

    t: float
    gyro: FloatArray
    accel: FloatArray

    def __post_init__(self) -> None:
        object.__setattr__(self, "t", _time("ImuSample.t", self.t))
        object.__setattr__(self, "gyro", _vec3("ImuSample.gyro", self.gyro))
        object.__setattr__(self, "accel", _vec3("ImuSample.accel", self.accel))


@dataclass(frozen=True, eq=False)
class CameraFrame:
    """A frame of the down-looking camera.

    Attributes
    ----------
    t
        Exposure time, s.
    image
        (H, W) grey or (H, W, 3) RGB uint8.
    K : (3, 3)
        Pinhole intrinsics, pixels.
    """

    t: float
    image: npt.NDArray[np.uint8]
    K: FloatArray

    def __post_init__(self) -> None:
        object.__setattr__(self, "t", _time("CameraFrame.t", self.t))
        img = np.asarray(self.image)
        if img.dtype != np.uint8 or img.ndim not in (2, 3) or (img.ndim == 3 and img.shape[2] != 3):
            raise ValueError(
                f"CameraFrame.image must be (H, W) or (H, W, 3) uint8, got {img.dtype} {img.shape}"
            )
        K = np.asarray(self.K, dtype=float)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError(f"CameraFrame.K must be a (3, 3) camera matrix, got {self.K!r}")
        object.__setattr__(self, "K", K)


@dataclass(frozen=True, eq=False)
class RelativeMotion:
    """Motion of the camera between frames at ``t0`` and ``t1``, in the camera frame at ``t0``.

    Attributes
    ----------
    t0, t1
        Times of the two frames, s.
    rotation : (3, 3)
        :math:`R_{c_0 c_1}`.
    translation : (3,)
        Position of camera 1 in camera 0, m.
    cov : (6, 6)
        Covariance of [rotation (right perturbation, rad), translation (m)].
    ok
        False when the visual front-end lost track (the other fields are then unused).
    n_inliers
        Feature inliers supporting the estimate (0 in the geometric mode).
    """

    t0: float
    t1: float
    rotation: FloatArray
    translation: FloatArray
    cov: FloatArray
    ok: bool = True
    n_inliers: int = 0

    def __post_init__(self) -> None:
        t0 = _time("RelativeMotion.t0", self.t0)
        t1 = _time("RelativeMotion.t1", self.t1)
        if t1 <= t0:
            raise ValueError(f"RelativeMotion needs t1 > t0, got t0={t0!r}, t1={t1!r}")
        object.__setattr__(self, "t0", t0)
        object.__setattr__(self, "t1", t1)
        R = np.asarray(self.rotation, dtype=float)
        if R.shape != (3, 3) or not np.all(np.isfinite(R)):
            raise ValueError(
                f"RelativeMotion.rotation must be a finite (3, 3) matrix, got {R.shape}"
            )
        if self.ok and not np.allclose(R @ R.T, np.eye(3), atol=1e-6):
            raise ValueError("RelativeMotion.rotation must be orthonormal")
        object.__setattr__(self, "rotation", R)
        object.__setattr__(
            self, "translation", _vec3("RelativeMotion.translation", self.translation)
        )
        C = np.asarray(self.cov, dtype=float)
        if C.shape != (6, 6) or not np.all(np.isfinite(C)):
            raise ValueError(f"RelativeMotion.cov must be a finite (6, 6) matrix, got {C.shape}")
        object.__setattr__(self, "cov", C)


@dataclass(frozen=True)
class TetherReading:
    """Tether length between the robot's attachment point and the anchor.

    Attributes
    ----------
    t
        Time, s.
    length
        Measured length, m.
    ok
        False when the sensor flags the reading invalid.
    """

    t: float
    length: float
    ok: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "t", _time("TetherReading.t", self.t))
        length = float(self.length)
        if not math.isfinite(length) or length < 0:
            raise ValueError(
                f"TetherReading.length must be a non-negative length in m, got {self.length!r}"
            )
        object.__setattr__(self, "length", length)


@dataclass(frozen=True, eq=False)
class ClimbEstimate:
    """A 6-DOF pose estimate of the climbing robot.

    Attributes
    ----------
    t
        Time, s.
    position : (3,)
        Body origin, m, in ``frame``.
    quat_xyzw : (4,)
        Body orientation :math:`R_{\\mathrm{frame},b}` (xyzw).
    velocity : (3,)
        Body velocity in ``frame``, m/s (zeros when unknown).
    cov : (6, 6)
        Covariance of [position (m), orientation (small angles about the ``frame``
        axes, rad)].
    ok
        False while initialising or when the estimator had to fall back.
    status
        ``"ok"`` or the reasons, ``|``-separated (e.g. ``"imu_only"``).
    frame
        ``"world"`` (VIO frame) or ``"cad"`` (blade/CAD frame).
    extras
        Estimator-specific values (biases, residuals, weights …).
    """

    t: float
    position: FloatArray
    quat_xyzw: FloatArray
    velocity: FloatArray = field(default_factory=lambda: np.zeros(3))
    cov: FloatArray = field(default_factory=lambda: np.zeros((6, 6)))
    ok: bool = True
    status: str = "ok"
    frame: str = "world"
    extras: Mapping[str, Any] = field(default_factory=lambda: _EMPTY)

    @property
    def pose(self) -> FloatArray:
        """``[x, y, z, qx, qy, qz, qw]`` (m, quaternion xyzw)."""
        return np.concatenate([self.position, self.quat_xyzw])

    @property
    def rotation(self) -> FloatArray:
        """Rotation matrix :math:`R_{\\mathrm{frame},b}`."""
        return matrix_from_quat_xyzw(self.quat_xyzw)


# --------------------------------------------------------------------------- pre-integration


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
        self.bias_gyro = _vec3("bias_gyro", bias_gyro).copy()
        self.bias_accel = _vec3("bias_accel", bias_accel).copy()
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


# --------------------------------------------------------------------------- static init


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


# --------------------------------------------------------------------------- visual front-end


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


# --------------------------------------------------------------------------- sliding window


@dataclass(frozen=True)
class VioConfig:
    """Settings of :class:`SlidingWindowVIO` (SI units).

    Attributes
    ----------
    gravity
        m/s².
    gyro_noise_density, accel_noise_density
        rad/s/√Hz, m/s²/√Hz.
    gyro_bias_walk, accel_bias_walk
        Bias random-walk densities, rad/s²/√Hz and m/s³/√Hz.
    window_size
        Keyframes in the window (≥ 2).
    static_init_duration
        Seconds of still IMU data used by :func:`static_initialise`.
    R_body_camera
        Rows of :math:`R_{bc}` (camera → body); default looks along body :math:`-z`.
    p_body_camera
        Camera centre in the body frame, m.
    camera_height
        Nominal distance of the camera centre from the surface, m.
    visual_rotation_sigma, visual_translation_sigma
        Per-frame noise assumed for image-based relative motion (rad, m) when the
        front-end's own covariance is smaller.
    solver
        ``"gauss_newton"``: Levenberg–Marquardt on the block-sparse normal equations
        with Huber re-weighting of the visual factors (fast); ``"scipy"``:
        :func:`scipy.optimize.least_squares` (``trf``) with ``loss`` applied to every
        whitened residual (dense SVD per step: slower, especially when BLAS threads
        compete for cores).
    loss, loss_scale
        Robust loss and its scale on whitened residuals (``"linear"``: none).
    max_iterations
        Iterations per window solve.
    cost_tolerance
        The window solve stops once a step lowers the whitened cost (a χ² with
        ≈ 15 residuals per keyframe, so a standard deviation of several units) by
        less than this fraction of it, or the linear model predicts less for the
        next step (–).
    prior_position_sigma, prior_yaw_sigma, prior_tilt_sigma, prior_velocity_sigma,
    prior_gyro_bias_sigma, prior_accel_bias_sigma
        Prior on the first state (m, rad, rad, m/s, rad/s, m/s²).
    """

    gravity: float = 9.81
    gyro_noise_density: float = 0.005
    accel_noise_density: float = 0.05
    gyro_bias_walk: float = 1e-4
    accel_bias_walk: float = 1e-3
    window_size: int = 8
    static_init_duration: float = 1.0
    R_body_camera: tuple[tuple[float, float, float], ...] = (
        (1.0, 0.0, 0.0),
        (0.0, -1.0, 0.0),
        (0.0, 0.0, -1.0),
    )
    p_body_camera: tuple[float, float, float] = (0.1, 0.0, -0.02)
    camera_height: float = 0.06
    visual_rotation_sigma: float = 2e-3
    visual_translation_sigma: float = 3e-4
    solver: str = "gauss_newton"
    loss: str = "huber"
    loss_scale: float = 3.0
    max_iterations: int = 6
    cost_tolerance: float = 1e-4
    prior_position_sigma: float = 1e-3
    prior_yaw_sigma: float = 1e-3
    prior_tilt_sigma: float = 0.01
    prior_velocity_sigma: float = 0.01
    prior_gyro_bias_sigma: float = 0.003
    prior_accel_bias_sigma: float = 0.1

    def __post_init__(self) -> None:
        positive = (
            "gravity",
            "gyro_noise_density",
            "accel_noise_density",
            "gyro_bias_walk",
            "accel_bias_walk",
            "static_init_duration",
            "camera_height",
            "visual_rotation_sigma",
            "visual_translation_sigma",
            "loss_scale",
            "cost_tolerance",
            "prior_position_sigma",
            "prior_yaw_sigma",
            "prior_tilt_sigma",
            "prior_velocity_sigma",
            "prior_gyro_bias_sigma",
            "prior_accel_bias_sigma",
        )
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"VioConfig.{name} must be positive, got {value!r}")
        if int(self.window_size) != self.window_size or self.window_size < 2:
            raise ValueError(
                f"VioConfig.window_size must be an integer ≥ 2, got {self.window_size!r}"
            )
        if int(self.max_iterations) != self.max_iterations or self.max_iterations < 1:
            raise ValueError(
                f"VioConfig.max_iterations must be an integer ≥ 1, got {self.max_iterations!r}"
            )
        if self.solver not in ("gauss_newton", "scipy"):
            raise ValueError(
                f"VioConfig.solver must be 'gauss_newton' or 'scipy', got {self.solver!r}"
            )
        losses = ("linear", "huber", "soft_l1", "cauchy", "arctan")
        if self.loss not in losses:
            raise ValueError(f"VioConfig.loss must be one of {losses}, got {self.loss!r}")
        R = np.asarray(self.R_body_camera, dtype=float)
        if (
            R.shape != (3, 3)
            or not np.allclose(R @ R.T, np.eye(3), atol=1e-6)
            or np.linalg.det(R) < 0
        ):
            raise ValueError("VioConfig.R_body_camera must be a proper rotation (3 rows of 3)")

    @property
    def R_bc(self) -> FloatArray:
        """:math:`R_{bc}` (3, 3)."""
        return np.asarray(self.R_body_camera, dtype=float)

    @property
    def p_bc(self) -> FloatArray:
        """Camera centre in the body frame (3,), m."""
        return np.asarray(self.p_body_camera, dtype=float)

    @property
    def gravity_vector(self) -> FloatArray:
        """:math:`g = (0, 0, -g)` in the world frame, m/s²."""
        return np.array([0.0, 0.0, -self.gravity])


@dataclass
class _State:
    t: float
    R: FloatArray
    p: FloatArray
    v: FloatArray
    bg: FloatArray
    ba: FloatArray

    def copy(self) -> _State:
        return _State(
            self.t, self.R.copy(), self.p.copy(), self.v.copy(), self.bg.copy(), self.ba.copy()
        )

    def retract(self, d: FloatArray) -> _State:
        return _State(
            self.t,
            self.R @ so3_exp(d[0:3]),
            self.p + d[3:6],
            self.v + d[6:9],
            self.bg + d[9:12],
            self.ba + d[12:15],
        )


@dataclass
class _Prior:
    mean: _State
    W: FloatArray  # (15, 15) whitening: r = W [Log(R_m^T R), p - p_m, ...]


@dataclass
class _ImuFactor:
    pre: Preintegration
    W: FloatArray  # (9, 9)
    W_bias: FloatArray  # (6, 6)


@dataclass
class _VisualFactor:
    dR: FloatArray
    dp: FloatArray
    W: FloatArray  # (6, 6)


def _whitener(cov: FloatArray) -> FloatArray:
    """:math:`W` with :math:`W^\\top W = \\Sigma^{-1}` (inverse Cholesky factor)."""
    cov = 0.5 * (cov + cov.T) + 1e-15 * np.eye(len(cov))
    return np.linalg.inv(np.linalg.cholesky(cov))


def _imu_residual(
    si: _State, sj: _State, f: _ImuFactor, g: FloatArray, want_jac: bool
) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """15 whitened rows [rR, rv, rp, rbg, rba]; Jacobians wrt state i and j (15 × 15 each)."""
    pre = f.pre
    T = pre.dt
    dbg = si.bg - pre.bias_gyro
    dba = si.ba - pre.bias_accel
    corr = pre.J_R_bg @ dbg
    dRc = pre.delta_R @ so3_exp(corr)
    RiT = si.R.T
    E = dRc.T @ RiT @ sj.R
    rR = so3_log(E)
    dv_w = sj.v - si.v - g * T
    dp_w = sj.p - si.p - si.v * T - 0.5 * g * T * T
    rv = RiT @ dv_w - (pre.delta_v + pre.J_v_bg @ dbg + pre.J_v_ba @ dba)
    rp = RiT @ dp_w - (pre.delta_p + pre.J_p_bg @ dbg + pre.J_p_ba @ dba)
    r9 = np.concatenate([rR, rv, rp])
    rb = np.concatenate([sj.bg - si.bg, sj.ba - si.ba])
    r = np.concatenate([f.W @ r9, f.W_bias @ rb])
    if not want_jac:
        return r, None, None
    Ji = np.zeros((9, 15))
    Jj = np.zeros((9, 15))
    Jrinv = right_jacobian_inv(rR)
    Ji[0:3, 0:3] = -Jrinv @ sj.R.T @ si.R
    Jj[0:3, 0:3] = Jrinv
    Ji[0:3, 9:12] = -Jrinv @ E.T @ right_jacobian(corr) @ pre.J_R_bg
    Ji[3:6, 0:3] = hat(RiT @ dv_w)
    Ji[3:6, 6:9] = -RiT
    Jj[3:6, 6:9] = RiT
    Ji[3:6, 9:12] = -pre.J_v_bg
    Ji[3:6, 12:15] = -pre.J_v_ba
    Ji[6:9, 0:3] = hat(RiT @ dp_w)
    Ji[6:9, 3:6] = -RiT
    Jj[6:9, 3:6] = RiT
    Ji[6:9, 6:9] = -RiT * T
    Ji[6:9, 9:12] = -pre.J_p_bg
    Ji[6:9, 12:15] = -pre.J_p_ba
    Ji_full = np.zeros((15, 15))
    Jj_full = np.zeros((15, 15))
    Ji_full[:9] = f.W @ Ji
    Jj_full[:9] = f.W @ Jj
    Ji_full[9:, 9:] = -f.W_bias
    Jj_full[9:, 9:] = f.W_bias
    return r, Ji_full, Jj_full


def _visual_residual(
    si: _State, sj: _State, f: _VisualFactor, want_jac: bool
) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """6 whitened rows [rR, rp]; Jacobians wrt state i and j (6 × 15 each)."""
    RiT = si.R.T
    E = f.dR.T @ RiT @ sj.R
    rR = so3_log(E)
    d = sj.p - si.p
    rp = RiT @ d - f.dp
    r = f.W @ np.concatenate([rR, rp])
    if not want_jac:
        return r, None, None
    Ji = np.zeros((6, 15))
    Jj = np.zeros((6, 15))
    Jrinv = right_jacobian_inv(rR)
    Ji[0:3, 0:3] = -Jrinv @ sj.R.T @ si.R
    Jj[0:3, 0:3] = Jrinv
    Ji[3:6, 0:3] = hat(RiT @ d)
    Ji[3:6, 3:6] = -RiT
    Jj[3:6, 3:6] = RiT
    return r, f.W @ Ji, f.W @ Jj


def _prior_residual(
    s: _State, prior: _Prior, want_jac: bool
) -> tuple[FloatArray, FloatArray | None]:
    m = prior.mean
    rR = so3_log(m.R.T @ s.R)
    e = np.concatenate([rR, s.p - m.p, s.v - m.v, s.bg - m.bg, s.ba - m.ba])
    r = prior.W @ e
    if not want_jac:
        return r, None
    J = np.eye(15)
    J[0:3, 0:3] = right_jacobian_inv(rR)
    return r, prior.W @ J


@dataclass
class _Stack:
    """Window states as arrays: ``R`` (n, 3, 3), ``p, v, bg, ba`` (n, 3)."""

    R: FloatArray
    p: FloatArray
    v: FloatArray
    bg: FloatArray
    ba: FloatArray

    @classmethod
    def of(cls, states: Sequence[_State]) -> _Stack:
        return cls(
            np.array([s.R for s in states]),
            np.array([s.p for s in states]),
            np.array([s.v for s in states]),
            np.array([s.bg for s in states]),
            np.array([s.ba for s in states]),
        )

    def retract(self, dx: FloatArray) -> _Stack:
        """Right perturbation by ``dx`` (n, 15) = [δθ, δp, δv, δb_g, δb_a] per state."""
        return _Stack(
            self.R @ so3_exp_batch(dx[:, 0:3]),
            self.p + dx[:, 3:6],
            self.v + dx[:, 6:9],
            self.bg + dx[:, 9:12],
            self.ba + dx[:, 12:15],
        )

    def states(self, times: Sequence[float]) -> list[_State]:
        return [
            _State(t, self.R[k], self.p[k], self.v[k], self.bg[k], self.ba[k])
            for k, t in enumerate(times)
        ]


class _WindowProblem:
    """The window's least-squares problem with every factor evaluated at once.

    Same residuals and analytic Jacobians as :func:`_prior_residual`,
    :func:`_imu_residual` and :func:`_visual_residual` (which stay the reference and
    serve the marginalisation), stacked over the window's ``K = n - 1`` IMU factors
    and its visual factors, and accumulated straight into the blocks of the
    block-tridiagonal normal equations.
    """

    def __init__(
        self,
        imu: Sequence[_ImuFactor],
        vis: Sequence[_VisualFactor | None],
        prior: _Prior,
        gravity: FloatArray,
        loss_scale: float,
        robust: bool,
    ) -> None:
        pres = [f.pre for f in imu]
        self.T = np.array([q.dt for q in pres])
        self.dR = np.array([q.delta_R for q in pres])
        self.dv = np.array([q.delta_v for q in pres])
        self.dp = np.array([q.delta_p for q in pres])
        self.bg0 = np.array([q.bias_gyro for q in pres])
        self.ba0 = np.array([q.bias_accel for q in pres])
        self.J_R_bg = np.array([q.J_R_bg for q in pres])
        self.J_v_bg = np.array([q.J_v_bg for q in pres])
        self.J_v_ba = np.array([q.J_v_ba for q in pres])
        self.J_p_bg = np.array([q.J_p_bg for q in pres])
        self.J_p_ba = np.array([q.J_p_ba for q in pres])
        self.W = np.array([f.W for f in imu])
        self.W_bias = np.array([f.W_bias for f in imu])
        self.vis_idx = np.array([k for k, f in enumerate(vis) if f is not None], dtype=int)
        present = [f for f in vis if f is not None]
        self.vis_dR = np.array([f.dR for f in present]).reshape(-1, 3, 3)
        self.vis_dp = np.array([f.dp for f in present]).reshape(-1, 3)
        self.vis_W = np.array([f.W for f in present]).reshape(-1, 6, 6)
        self.prior = prior
        self.g = gravity
        self.k_h = loss_scale
        self.robust = robust

    def linearise(self, X: _Stack) -> tuple[float, FloatArray, FloatArray, FloatArray]:
        """Robust cost and ``D (n, 15, 15), B (n-1, 15, 15), b (n, 15)`` as in
        :meth:`SlidingWindowVIO._normal_equations`."""
        n = len(X.p)
        D = np.zeros((n, 15, 15))
        B = np.zeros((n - 1, 15, 15))
        b = np.zeros((n, 15))
        # prior on state 0
        s0 = _State(0.0, X.R[0], X.p[0], X.v[0], X.bg[0], X.ba[0])
        r0, J0 = _prior_residual(s0, self.prior, True)
        assert J0 is not None
        cost = float(r0 @ r0)
        D[0] += J0.T @ J0
        b[0] += J0.T @ r0
        if n < 2:
            return cost, D, B, b
        # IMU factors k: states k → k + 1
        T, g = self.T, self.g
        Ri, Rj = X.R[:-1], X.R[1:]
        RiT = np.swapaxes(Ri, 1, 2)
        dbg = X.bg[:-1] - self.bg0
        dba = X.ba[:-1] - self.ba0
        corr = np.einsum("kij,kj->ki", self.J_R_bg, dbg)
        dRc = self.dR @ so3_exp_batch(corr)
        RiT_Rj = RiT @ Rj
        E = np.swapaxes(dRc, 1, 2) @ RiT_Rj
        rR = so3_log_batch(E)
        dv_w = X.v[1:] - X.v[:-1] - g * T[:, None]
        dp_w = X.p[1:] - X.p[:-1] - X.v[:-1] * T[:, None] - 0.5 * g * (T * T)[:, None]
        bv = np.einsum("kij,kj->ki", RiT, dv_w)
        bp = np.einsum("kij,kj->ki", RiT, dp_w)
        mv = lambda J, x: np.einsum("kij,kj->ki", J, x)  # noqa: E731
        rv = bv - (self.dv + mv(self.J_v_bg, dbg) + mv(self.J_v_ba, dba))
        rp = bp - (self.dp + mv(self.J_p_bg, dbg) + mv(self.J_p_ba, dba))
        r9 = np.concatenate([rR, rv, rp], axis=1)
        rb = np.concatenate([X.bg[1:] - X.bg[:-1], X.ba[1:] - X.ba[:-1]], axis=1)
        r = np.concatenate([mv(self.W, r9), mv(self.W_bias, rb)], axis=1)  # (K, 15)
        cost += float(np.sum(r * r))
        K = len(T)
        Ji = np.zeros((K, 9, 15))
        Jj = np.zeros((K, 9, 15))
        Jrinv = right_jacobian_inv_batch(rR)
        Ji[:, 0:3, 0:3] = -Jrinv @ np.swapaxes(RiT_Rj, 1, 2)
        Jj[:, 0:3, 0:3] = Jrinv
        Ji[:, 0:3, 9:12] = -Jrinv @ np.swapaxes(E, 1, 2) @ right_jacobian_batch(corr) @ self.J_R_bg
        Ji[:, 3:6, 0:3] = hat_batch(bv)
        Ji[:, 3:6, 6:9] = -RiT
        Jj[:, 3:6, 6:9] = RiT
        Ji[:, 3:6, 9:12] = -self.J_v_bg
        Ji[:, 3:6, 12:15] = -self.J_v_ba
        Ji[:, 6:9, 0:3] = hat_batch(bp)
        Ji[:, 6:9, 3:6] = -RiT
        Jj[:, 6:9, 3:6] = RiT
        Ji[:, 6:9, 6:9] = -RiT * T[:, None, None]
        Ji[:, 6:9, 9:12] = -self.J_p_bg
        Ji[:, 6:9, 12:15] = -self.J_p_ba
        Ji_f = np.zeros((K, 15, 15))
        Jj_f = np.zeros((K, 15, 15))
        Ji_f[:, :9] = self.W @ Ji
        Jj_f[:, :9] = self.W @ Jj
        Ji_f[:, 9:, 9:] = -self.W_bias
        Jj_f[:, 9:, 9:] = self.W_bias
        JiT, JjT = np.swapaxes(Ji_f, 1, 2), np.swapaxes(Jj_f, 1, 2)
        D[:-1] += JiT @ Ji_f
        D[1:] += JjT @ Jj_f
        B += JjT @ Ji_f
        b[:-1] += mv(JiT, r)
        b[1:] += mv(JjT, r)
        # visual factors (Huber-weighted blocks)
        idx = self.vis_idx
        if len(idx):
            Ri_v, Rj_v = X.R[idx], X.R[idx + 1]
            RiT_v = np.swapaxes(Ri_v, 1, 2)
            RiT_Rj_v = RiT_v @ Rj_v
            Ev = np.swapaxes(self.vis_dR, 1, 2) @ RiT_Rj_v
            rRv = so3_log_batch(Ev)
            bd = np.einsum("kij,kj->ki", RiT_v, X.p[idx + 1] - X.p[idx])
            rv6 = mv(self.vis_W, np.concatenate([rRv, bd - self.vis_dp], axis=1))
            nr = np.linalg.norm(rv6, axis=1)
            w = np.ones(len(idx))
            if self.robust:
                big = nr > self.k_h
                w = np.where(big, self.k_h / np.where(big, nr, 1.0), 1.0)
                cost += float(np.sum(np.where(big, 2.0 * self.k_h * nr - self.k_h**2, nr * nr)))
            else:
                cost += float(np.sum(nr * nr))
            M = len(idx)
            Jvi = np.zeros((M, 6, 15))
            Jvj = np.zeros((M, 6, 15))
            Jr_v = right_jacobian_inv_batch(rRv)
            Jvi[:, 0:3, 0:3] = -Jr_v @ np.swapaxes(RiT_Rj_v, 1, 2)
            Jvj[:, 0:3, 0:3] = Jr_v
            Jvi[:, 3:6, 0:3] = hat_batch(bd)
            Jvi[:, 3:6, 3:6] = -RiT_v
            Jvj[:, 3:6, 3:6] = RiT_v
            Jvi = self.vis_W @ Jvi
            Jvj = self.vis_W @ Jvj
            JviT = np.swapaxes(Jvi, 1, 2) * w[:, None, None]
            JvjT = np.swapaxes(Jvj, 1, 2) * w[:, None, None]
            D[idx] += JviT @ Jvi  # idx is unique: one visual factor per interval
            D[idx + 1] += JvjT @ Jvj
            B[idx] += JvjT @ Jvi
            b[idx] += mv(JviT, rv6)
            b[idx + 1] += mv(JvjT, rv6)
        return cost, D, B, b


class SlidingWindowVIO:
    """Sliding-window visual-inertial odometry (world = gravity-aligned VIO frame).

    Each keyframe state is :math:`x_k = (R_k, p_k, v_k, b_{g,k}, b_{a,k})`. A window of
    ``window_size`` keyframes minimises

    .. math::

        \\lVert r_0 \\rVert^2 + \\sum_k \\rho\\left(\\lVert r^{\\mathrm{imu}}_{k,k+1}
        \\rVert^2_{\\Sigma} + \\lVert b_{k+1} - b_k \\rVert^2_{\\Sigma_b}
        + \\lVert r^{\\mathrm{vis}}_{k,k+1} \\rVert^2_{\\Sigma_v}\\right)

    over right perturbations of all states, with analytic Jacobians and a robust
    loss :math:`\\rho` on the visual factors, by Levenberg–Marquardt on the
    block-sparse normal equations or by :func:`scipy.optimize.least_squares`
    (``VioConfig.solver``). The visual residual of a
    body-frame relative motion :math:`(\\Delta R_m, \\Delta p_m)` is
    :math:`[\\mathrm{Log}(\\Delta R_m^\\top R_k^\\top R_{k+1}),\\; R_k^\\top (p_{k+1} -
    p_k) - \\Delta p_m]`. When the window is full the oldest state is marginalised
    (Schur complement of its factors) into a Gaussian prior :math:`r_0` on the next.

    Feed measurements in time order through :meth:`update`: :class:`ImuSample`
    (≥ 100 Hz), and either :class:`CameraFrame` (images, processed by
    :func:`relative_motion_from_images`) or :class:`RelativeMotion` (geometric
    mode). The first ``static_init_duration`` seconds of IMU data must come from a
    still robot. A failed or missing visual motion adds an IMU-only keyframe
    (status ``"imu_only"``); the estimate never becomes NaN.

    Parameters
    ----------
    config
        :class:`VioConfig`.
    """

    def __init__(self, config: VioConfig | None = None) -> None:
        self.config = VioConfig() if config is None else config
        if not isinstance(self.config, VioConfig):
            raise TypeError(f"config must be VioConfig, got {type(self.config).__name__}")
        self.reset()

    # ---------------------------------------------------------------- public API

    def reset(self, initial: StaticInit | None = None) -> ClimbEstimate:
        """Start over; with ``initial`` the static phase is skipped (first keyframe at ``initial.t``)."""
        self._states: list[_State] = []
        self._imu_factors: list[_ImuFactor] = []
        self._vis_factors: list[_VisualFactor | None] = []
        self._prior: _Prior | None = None
        self._static: list[ImuSample] = []
        self._last_imu: ImuSample | None = None
        self._cursor: float | None = None
        self._pending: Preintegration | None = None
        self._prev_image: CameraFrame | None = None
        self._status = "initialising"
        self._lost = 0
        self._cov6 = np.zeros((6, 6))
        self._n_keyframes = 0
        self._last_t = -math.inf
        self.static_init: StaticInit | None = None
        if initial is not None:
            self._start(initial)
        return self.estimate()

    @property
    def initialised(self) -> bool:
        """True once the first keyframe exists."""
        return bool(self._states)

    @property
    def keyframe_count(self) -> int:
        """Keyframes created since :meth:`reset`."""
        return self._n_keyframes

    def update(self, measurement: ImuSample | CameraFrame | RelativeMotion | None) -> ClimbEstimate:
        """Consume one measurement (or ``None``) and return the current estimate."""
        if measurement is None:
            return self.estimate()
        if isinstance(measurement, ImuSample):
            self._on_imu(measurement)
        elif isinstance(measurement, RelativeMotion):
            self._on_motion(measurement)
        elif isinstance(measurement, CameraFrame):
            self._on_frame(measurement)
        else:
            raise TypeError(
                "measurement must be ImuSample, CameraFrame, RelativeMotion or None, "
                f"got {type(measurement).__name__}"
            )
        return self.estimate()

    def estimate(self) -> ClimbEstimate:
        """Latest state, IMU-propagated past the newest keyframe."""
        if not self._states:
            return ClimbEstimate(
                t=self._last_imu.t if self._last_imu is not None else 0.0,
                position=np.zeros(3),
                quat_xyzw=np.array([0.0, 0.0, 0.0, 1.0]),
                ok=False,
                status="initialising",
            )
        s = self._states[-1]
        R, p, v, t = s.R, s.p, s.v, s.t
        if self._pending is not None and self._pending.dt > 0:
            R, p, v = self._pending.predict(R, p, v, self.config.gravity_vector)
            t = t + self._pending.dt
        return ClimbEstimate(
            t=t,
            position=p.copy(),
            quat_xyzw=quat_xyzw_from_matrix(R),
            velocity=v.copy(),
            cov=self._cov6.copy(),
            ok=self._status == "ok",
            status=self._status,
            frame="world",
            extras=MappingProxyType(
                {
                    "bias_gyro": s.bg.copy(),
                    "bias_accel": s.ba.copy(),
                    "keyframes": self._n_keyframes,
                    "lost_frames": self._lost,
                }
            ),
        )

    def keyframe_estimate(self) -> ClimbEstimate:
        """The newest keyframe's state (no IMU propagation).

        ``extras["previous_keyframe"]`` is ``(t, position, R)`` of the keyframe before
        it *in the same window solution* (absent for the first keyframe): the
        relative motion between the two is the VIO's current best estimate, whereas
        the previous keyframe's own estimate at its creation has since been refined.
        """
        if not self._states:
            return self.estimate()
        s = self._states[-1]
        extras: dict[str, Any] = {"bias_gyro": s.bg.copy(), "bias_accel": s.ba.copy()}
        if len(self._states) > 1:
            q = self._states[-2]
            extras["previous_keyframe"] = (q.t, q.p.copy(), q.R.copy())
        return ClimbEstimate(
            t=s.t,
            position=s.p.copy(),
            quat_xyzw=quat_xyzw_from_matrix(s.R),
            velocity=s.v.copy(),
            cov=self._cov6.copy(),
            ok=self._status == "ok",
            status=self._status,
            frame="world",
            extras=MappingProxyType(extras),
        )

    # ---------------------------------------------------------------- measurements

    def _check_time(self, t: float) -> None:
        if t < self._last_t - 1e-9:
            raise ValueError(
                f"measurements must arrive in time order: got t={t!r} after t={self._last_t!r}"
            )
        self._last_t = max(self._last_t, t)

    def _on_imu(self, m: ImuSample) -> None:
        self._check_time(m.t)
        if not self._states:
            self._static.append(m)
            self._last_imu = m
            if (
                m.t - self._static[0].t >= self.config.static_init_duration
                and len(self._static) >= 10
            ):
                self._start(static_initialise(self._static, gravity=self.config.gravity))
            return
        self._advance_to(m.t)
        self._last_imu = m

    def _advance_to(self, t: float) -> None:
        """Integrate the held IMU reading up to time ``t``."""
        if self._last_imu is None or self._pending is None or self._cursor is None:
            return
        dt = t - self._cursor
        if dt > 0:
            self._pending.integrate(self._last_imu.gyro, self._last_imu.accel, dt)
            self._cursor = t

    def _start(self, init: StaticInit) -> None:
        cfg = self.config
        self.static_init = init
        s0 = _State(
            init.t,
            init.R_world_body.copy(),
            np.zeros(3),
            np.zeros(3),
            init.bias_gyro.copy(),
            init.bias_accel.copy(),
        )
        # prior: tilt in world axes → body perturbation
        cov_world_rot = np.diag(
            [cfg.prior_tilt_sigma**2, cfg.prior_tilt_sigma**2, cfg.prior_yaw_sigma**2]
        )
        cov = np.zeros((15, 15))
        cov[0:3, 0:3] = s0.R.T @ cov_world_rot @ s0.R
        cov[3:6, 3:6] = np.eye(3) * cfg.prior_position_sigma**2
        cov[6:9, 6:9] = np.eye(3) * cfg.prior_velocity_sigma**2
        cov[9:12, 9:12] = np.eye(3) * cfg.prior_gyro_bias_sigma**2
        cov[12:15, 12:15] = np.eye(3) * cfg.prior_accel_bias_sigma**2
        self._prior = _Prior(s0.copy(), _whitener(cov))
        self._states = [s0]
        self._n_keyframes = 1
        self._cursor = init.t
        self._pending = self._new_preintegration(s0)
        if self._last_imu is None and self._static:
            self._last_imu = self._static[-1]
        self._static = []
        self._status = "ok" if init.still else "ok|init_motion_detected"
        self._cov6 = np.zeros((6, 6))
        self._cov6[0:3, 0:3] = np.eye(3) * cfg.prior_position_sigma**2
        self._cov6[3:6, 3:6] = cov_world_rot

    def _new_preintegration(self, s: _State) -> Preintegration:
        return Preintegration(
            s.bg,
            s.ba,
            gyro_noise_density=self.config.gyro_noise_density,
            accel_noise_density=self.config.accel_noise_density,
        )

    def _on_frame(self, frame: CameraFrame) -> None:
        self._check_time(frame.t)
        prev = self._prev_image
        self._prev_image = frame
        if not self._states or prev is None:
            if self._states:
                self._add_keyframe(frame.t, None)
            return
        motion = relative_motion_from_images(
            prev.image,
            frame.image,
            frame.K,
            self.config.camera_height,
            t0=prev.t,
            t1=frame.t,
            prior=self._predicted_camera_motion(prev.t, frame.t),
        )
        cfg = self.config
        if motion.ok:
            floor = np.diag(
                [cfg.visual_rotation_sigma**2] * 3 + [cfg.visual_translation_sigma**2] * 3
            )
            motion = RelativeMotion(
                motion.t0,
                motion.t1,
                motion.rotation,
                motion.translation,
                np.maximum(motion.cov, floor),
                ok=True,
                n_inliers=motion.n_inliers,
            )
        self._on_motion(motion)

    def _on_motion(self, m: RelativeMotion) -> None:
        self._check_time(m.t1)
        if not self._states:
            return
        last = self._states[-1]
        linked = m.ok and abs(m.t0 - last.t) < 1e-6
        self._add_keyframe(m.t1, m if linked else None, lost=not m.ok)

    def _predicted_camera_motion(
        self, t0: float, t1: float
    ) -> tuple[FloatArray, FloatArray] | None:
        """IMU-predicted camera motion from the newest keyframe (at ``t0``) to ``t1``."""
        if not self._states or self._pending is None or abs(self._states[-1].t - t0) > 1e-6:
            return None
        self._advance_to(t1)
        s = self._states[-1]
        R_j, p_j, _ = self._pending.predict(s.R, s.p, s.v, self.config.gravity_vector)
        dR = s.R.T @ R_j
        dp = s.R.T @ (p_j - s.p)
        R_bc, p_bc = self.config.R_bc, self.config.p_bc
        return R_bc.T @ dR @ R_bc, R_bc.T @ (dR @ p_bc + dp - p_bc)

    # ---------------------------------------------------------------- keyframes

    def _body_motion(self, m: RelativeMotion) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Camera-frame relative motion → body-frame ``(ΔR, Δp, cov)``."""
        R_bc, p_bc = self.config.R_bc, self.config.p_bc
        dR = R_bc @ m.rotation @ R_bc.T
        dp = R_bc @ m.translation + p_bc - dR @ p_bc
        J = np.zeros((6, 6))
        J[0:3, 0:3] = R_bc
        J[3:6, 3:6] = R_bc
        J[3:6, 0:3] = dR @ hat(p_bc) @ R_bc
        return dR, dp, J @ m.cov @ J.T

    def _add_keyframe(self, t: float, motion: RelativeMotion | None, lost: bool = False) -> None:
        assert self._pending is not None
        self._advance_to(t)
        pre = self._pending
        last = self._states[-1]
        if pre.dt <= 1e-9:
            return  # duplicate time
        cfg = self.config
        g = cfg.gravity_vector
        R_j, p_j, v_j = pre.predict(last.R, last.p, last.v, g)
        vis: _VisualFactor | None = None
        if motion is not None:
            dR, dp, cov = self._body_motion(motion)
            vis = _VisualFactor(dR, dp, _whitener(cov))
            R_j = last.R @ dR
            p_j = last.p + last.R @ dp
        cov_b = np.zeros((6, 6))
        cov_b[0:3, 0:3] = np.eye(3) * cfg.gyro_bias_walk**2 * pre.dt
        cov_b[3:6, 3:6] = np.eye(3) * cfg.accel_bias_walk**2 * pre.dt
        factor = _ImuFactor(pre, _whitener(pre.cov + 1e-12 * np.eye(9)), _whitener(cov_b))
        self._states.append(_State(t, R_j, p_j, v_j, last.bg.copy(), last.ba.copy()))
        self._imu_factors.append(factor)
        self._vis_factors.append(vis)
        self._n_keyframes += 1
        if lost:
            self._lost += 1
        self._optimise()
        if len(self._states) > cfg.window_size:
            self._marginalise()
        newest = self._states[-1]
        self._pending = self._new_preintegration(newest)
        self._cursor = t
        if vis is None and self._n_keyframes > 2:
            self._status = "imu_only"
        elif vis is not None:
            self._status = "ok"

    # ---------------------------------------------------------------- optimisation

    def _factors(
        self, states: list[_State], want_jac: bool
    ) -> list[tuple[FloatArray, list[tuple[int, FloatArray]], bool]]:
        """Whitened residual blocks ``(r, [(state index, ∂r/∂δx_k)], robust)``."""
        g = self.config.gravity_vector
        assert self._prior is not None
        out: list[tuple[FloatArray, list[tuple[int, FloatArray]], bool]] = []
        r, J = _prior_residual(states[0], self._prior, want_jac)
        out.append((r, [(0, J)] if J is not None else [], False))
        for k in range(len(states) - 1):
            r, Ji, Jj = _imu_residual(states[k], states[k + 1], self._imu_factors[k], g, want_jac)
            out.append(
                (r, [(k, Ji), (k + 1, Jj)] if Ji is not None and Jj is not None else [], False)
            )
            vf = self._vis_factors[k]
            if vf is not None:
                r, Ji, Jj = _visual_residual(states[k], states[k + 1], vf, want_jac)
                jacs = [(k, Ji), (k + 1, Jj)] if Ji is not None and Jj is not None else []
                out.append((r, jacs, True))
        return out

    def _normal_equations(
        self, blocks: list[tuple[FloatArray, list[tuple[int, FloatArray]], bool]], n: int
    ) -> tuple[float, FloatArray, FloatArray, FloatArray]:
        """Robust cost and the block-tridiagonal :math:`H = J^\\top W J`, :math:`b = J^\\top W r`.

        Returns ``cost, D (n, 15, 15), B (n-1, 15, 15), b (n, 15)`` with ``D[k] = H_kk``
        and ``B[k] = H_{k+1,k}`` (every factor links at most two consecutive states).
        """
        k_h = self.config.loss_scale
        robust = self.config.loss != "linear"
        D = np.zeros((n, 15, 15))
        B = np.zeros((max(n - 1, 0), 15, 15))
        b = np.zeros((n, 15))
        cost = 0.0
        for r, jacs, is_robust in blocks:
            nr = float(np.linalg.norm(r))
            w = 1.0
            if robust and is_robust and nr > k_h:
                w = k_h / nr
                cost += 2.0 * k_h * nr - k_h * k_h
            else:
                cost += nr * nr
            for i, Ji in jacs:
                b[i] += w * (Ji.T @ r)
                D[i] += w * (Ji.T @ Ji)
            if len(jacs) == 2:
                (i, Ji), (j, Jj) = jacs
                if j == i + 1:
                    B[i] += w * (Jj.T @ Ji)
                else:
                    B[j] += w * (Ji.T @ Jj)
        return cost, D, B, b

    @staticmethod
    def _solve_block_tridiagonal(
        D: FloatArray, B: FloatArray, rhs: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Solve :math:`H x = rhs` for the block-tridiagonal ``H`` (diagonal blocks ``D``,
        sub-diagonal blocks ``B``) by one dense Cholesky factorisation (for a window of
        ~8 states one LAPACK call beats a Python loop over the blocks); also return the
        last diagonal block of the factor (the newest state's information).

        Raises :class:`numpy.linalg.LinAlgError` if ``H`` is not positive definite.
        """
        n = len(D)
        H = np.zeros((n, 15, n, 15))
        k = np.arange(n)
        H[k, :, k, :] = D
        H[k[1:], :, k[:-1], :] = B
        H[k[:-1], :, k[1:], :] = np.swapaxes(B, 1, 2)
        L = np.linalg.cholesky(H.reshape(15 * n, 15 * n))
        y = solve_triangular(L, rhs.reshape(-1), lower=True, check_finite=False)
        x = solve_triangular(L.T, y, lower=False, check_finite=False)
        if not np.all(np.isfinite(x)):
            raise np.linalg.LinAlgError("non-finite solution of the window's normal equations")
        step: FloatArray = np.asarray(x, dtype=np.float64).reshape(n, 15)
        l_last: FloatArray = np.asarray(L[-15:, -15:], dtype=np.float64)
        return step, l_last

    def _optimise(self) -> None:
        n = len(self._states)
        if self.config.solver == "scipy":
            self._optimise_scipy()
            _, D, B, _ = self._normal_equations(self._factors(self._states, True), n)
        else:
            D, B = self._optimise_lm()
        try:
            D = D + 1e-12 * np.eye(15)
            _, L_last = self._solve_block_tridiagonal(D, B, np.zeros((n, 15)))
            L_inv = np.linalg.inv(L_last)
            cov = L_inv.T @ L_inv  # last diagonal block of H^{-1}
            R = self._states[-1].R
            c6 = np.zeros((6, 6))
            c6[0:3, 0:3] = cov[3:6, 3:6]
            c6[3:6, 3:6] = R @ cov[0:3, 0:3] @ R.T
            c6[0:3, 3:6] = cov[3:6, 0:3] @ R.T
            c6[3:6, 0:3] = c6[0:3, 3:6].T
            if np.all(np.isfinite(c6)):
                self._cov6 = 0.5 * (c6 + c6.T)
        except np.linalg.LinAlgError:
            pass

    def _optimise_lm(self) -> tuple[FloatArray, FloatArray]:
        """Levenberg–Marquardt with Huber IRLS weights on the visual factors; returns the
        blocks of :math:`H` at the solution. All factors are evaluated at once
        (:class:`_WindowProblem`); the previous solution warm-starts every state but
        the newest."""
        assert self._prior is not None
        times = [s.t for s in self._states]
        n = len(times)
        cfg = self.config
        problem = _WindowProblem(
            self._imu_factors,
            self._vis_factors,
            self._prior,
            cfg.gravity_vector,
            cfg.loss_scale,
            cfg.loss != "linear",
        )
        X = _Stack.of(self._states)
        cost, D, B, b = problem.linearise(X)
        lam = 1e-6
        eye = np.eye(15)
        tol = cfg.cost_tolerance
        for it in range(cfg.max_iterations):
            diag = np.einsum("kii->ki", D)
            A = D + (lam * diag)[:, :, None] * eye + 1e-12 * eye
            try:
                dx, _ = self._solve_block_tridiagonal(A, B, -b)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            if it > 0:
                # decrease of ‖r‖² predicted by the linear model at X:
                # -2 bᵀdx - dxᵀ H dx with (H + λ diag) dx = -b
                predicted = float(-np.sum(b * dx) + lam * np.sum(diag * dx * dx))
                if predicted < tol * max(cost, 1.0):
                    break
            trial = X.retract(dx)
            new_cost, D_new, B_new, b_new = problem.linearise(trial)
            if np.isfinite(new_cost) and new_cost <= cost:
                decrease = cost - new_cost
                X, cost, D, B, b = trial, new_cost, D_new, B_new, b_new
                lam = max(lam / 10.0, 1e-9)
                if float(np.max(np.abs(dx))) < 1e-7 or decrease < tol * max(cost, 1.0):
                    break
            else:
                lam *= 10.0
                if lam > 1e6:
                    break
        self._states = X.states(times)
        assert len(self._states) == n
        return D, B

    def _optimise_scipy(self) -> None:
        """:func:`scipy.optimize.least_squares` (trust-region reflective, robust loss)."""
        base = [s.copy() for s in self._states]
        n = len(base)
        cache: dict[bytes, tuple[FloatArray, FloatArray]] = {}

        def states_at(x: FloatArray) -> list[_State]:
            return [s.retract(x[15 * k : 15 * k + 15]) for k, s in enumerate(base)]

        def evaluate(x: FloatArray) -> tuple[FloatArray, FloatArray]:
            key = x.tobytes()
            if key not in cache:
                blocks = self._factors(states_at(x), True)
                res = np.concatenate([r for r, _, _ in blocks])
                J = np.zeros((len(res), 15 * n))
                row = 0
                for r, jacs, _ in blocks:
                    for k, Jk in jacs:
                        J[row : row + len(r), 15 * k : 15 * k + 15] += Jk
                    row += len(r)
                cache.clear()
                cache[key] = (res, J)
            return cache[key]

        x0 = np.zeros(15 * n)
        try:
            sol = least_squares(
                lambda x: evaluate(x)[0],
                x0,
                jac=lambda x: evaluate(x)[1],
                method="trf",
                loss=self.config.loss,
                f_scale=self.config.loss_scale,
                max_nfev=self.config.max_iterations + 2,
                x_scale="jac",
                xtol=1e-8,
                ftol=1e-8,
                gtol=1e-8,
            )
            x = sol.x if np.all(np.isfinite(sol.x)) else x0
        except (np.linalg.LinAlgError, ValueError):
            x = x0
        self._states = states_at(x)

    def _marginalise(self) -> None:
        """Fold state 0 and its factors into a prior on state 1."""
        assert self._prior is not None
        s0, s1 = self._states[0], self._states[1]
        g = self.config.gravity_vector
        rs: list[FloatArray] = []
        Js: list[FloatArray] = []
        r, J = _prior_residual(s0, self._prior, True)
        assert J is not None
        rs.append(r)
        Js.append(np.hstack([J, np.zeros((15, 15))]))
        r, Ji, Jj = _imu_residual(s0, s1, self._imu_factors[0], g, True)
        assert Ji is not None and Jj is not None
        rs.append(r)
        Js.append(np.hstack([Ji, Jj]))
        vf = self._vis_factors[0]
        if vf is not None:
            r, Ji, Jj = _visual_residual(s0, s1, vf, True)
            assert Ji is not None and Jj is not None
            rs.append(r)
            Js.append(np.hstack([Ji, Jj]))
        rr = np.concatenate(rs)
        JJ = np.vstack(Js)
        H = JJ.T @ JJ
        b = JJ.T @ rr
        Hmm, Hmr, Hrr = H[:15, :15], H[:15, 15:], H[15:, 15:]
        Hmm_inv = np.linalg.inv(Hmm + 1e-12 * np.eye(15))
        Lam = Hrr - Hmr.T @ Hmm_inv @ Hmr
        gvec = b[15:] - Hmr.T @ Hmm_inv @ b[:15]
        Lam = 0.5 * (Lam + Lam.T) + 1e-10 * np.eye(15)
        try:
            delta = -np.linalg.solve(Lam, gvec)
            L = np.linalg.cholesky(Lam)
        except np.linalg.LinAlgError:
            w, V = np.linalg.eigh(Lam)
            w = np.maximum(w, 1e-8)
            Lam = (V * w) @ V.T
            delta = -np.linalg.solve(Lam, gvec)
            L = np.linalg.cholesky(Lam)
        self._prior = _Prior(s1.retract(delta), L.T)
        self._states.pop(0)
        self._imu_factors.pop(0)
        self._vis_factors.pop(0)
