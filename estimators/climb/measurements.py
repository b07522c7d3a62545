"""Measurements of a climbing robot fed to its localisers, and their output.

:class:`ImuSample`, :class:`CameraFrame`, :class:`RelativeMotion` (already
computed visual motion, the fast geometric sensor mode) and :class:`TetherReading`
are produced by the robot layer; :class:`ClimbEstimate` is what the estimators
return. :func:`check_vec3` and :func:`check_time` validate their fields.

Frames: ``world`` is the VIO frame, gravity along :math:`-z`, its origin and yaw
those of the body at initialisation; ``body`` = IMU frame (x forward, z away from
the surface); ``camera`` is OpenCV's optical frame (z along the optical axis).
Rotations are matrices :math:`R_{wb}` (body → world); quaternions are xyzw.
The IMU measures angular rate :math:`\\omega` (rad/s) and specific force
:math:`f = R_{wb}^\\top (a - g)` (m/s²), :math:`g = (0, 0, -9.81)`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import matrix_from_quat_xyzw

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "CameraFrame",
    "ClimbEstimate",
    "ImuSample",
    "RelativeMotion",
    "TetherReading",
    "check_time",
    "check_vec3",
]

_EMPTY: Mapping[str, Any] = MappingProxyType({})


def check_vec3(name: str, value: npt.ArrayLike) -> FloatArray:
    """``value`` as a float array of shape (3,); ``ValueError`` unless finite and of that shape."""
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,) or not math.isfinite(arr[0] + arr[1] + arr[2]):
        raise ValueError(f"{name} must be a finite (3,) array, got {value!r}")
    return arr


def check_time(name: str, value: float) -> float:
    """``value`` as a float time in s; ``ValueError`` unless finite."""
    t = float(value)
    if not math.isfinite(t):
        raise ValueError(f"{name} must be a finite time in s, got {value!r}")
    return t


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
        object.__setattr__(self, "t", check_time("ImuSample.t", self.t))
        object.__setattr__(self, "gyro", check_vec3("ImuSample.gyro", self.gyro))
        object.__setattr__(self, "accel", check_vec3("ImuSample.accel", self.accel))


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
        object.__setattr__(self, "t", check_time("CameraFrame.t", self.t))
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
        t0 = check_time("RelativeMotion.t0", self.t0)
        t1 = check_time("RelativeMotion.t1", self.t1)
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
            self, "translation", check_vec3("RelativeMotion.translation", self.translation)
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
        object.__setattr__(self, "t", check_time("TetherReading.t", self.t))
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
