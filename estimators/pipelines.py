"""Observation pipelines of the wheeled robot: sensors → estimators → estimate.

:class:`FusedOdometryVO` is the full pipeline of seeds 000/001: wheel
odometry predicts, RGB-D visual odometry corrects at its key-frames through a
stochastic-cloning EKF, and the planar scan builds an occupancy grid from the
fused pose. When VO fails (blank wall, depth holes, lost track) the filter runs
on odometry alone and says so in the estimate's ``ok``/``status``.

Both pipelines here follow the :class:`~realitygap.estimators.base.Estimator`
protocol and accept :class:`~realitygap.estimators.base.DiffDriveMeasurement`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import wrap_angle
from realitygap.estimators.base import DiffDriveMeasurement, Estimate
from realitygap.estimators.diffdrive_model import DiffDriveKinematics, OdometryNoise
from realitygap.estimators.fusion_ekf import FusionSettings, OdomVOFusionEKF
from realitygap.estimators.occupancy import OccupancyGrid
from realitygap.estimators.vo import RGBDVisualOdometry, VOResult, planar_motion_from_camera
from realitygap.estimators.vo_params import VOParams

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class VONoise:
    r"""Covariance model of a VO key-frame-to-frame planar motion of the base.

    With ``from_inliers`` (default) the covariance is the one the VO solver derived from
    its own inliers (:attr:`~realitygap.estimators.vo.VOResult.motion_cov`, the
    6-DoF camera motion), carried to the planar base motion ``z = (dx, dy, dθ)`` through
    the mounting by the Jacobian ``J`` of
    :func:`~realitygap.estimators.vo.planar_motion_from_camera`, plus a floor for what the
    point-noise model does not see (rendering, keypoint localisation biases):

    .. math::

        \Sigma_z = J\, \Sigma_{6}\, J^\top
        + \operatorname{diag}(\sigma_{xy,0}^2, \sigma_{xy,0}^2, \sigma_{\theta,0}^2).

    A motion few or badly spread inliers support gets a large covariance and moves the
    estimate little; a well-supported one is trusted. Without a solver covariance (the
    PnP solver, a motion chained through the previous frame) or with
    ``from_inliers=False``, the fixed model ``σ_xy = xy_floor + xy_per_m · distance`` (m)
    and ``σ_θ = theta_floor + theta_per_rad · |Δθ| + theta_per_m · distance`` (rad) is used.
    """

    xy_floor: float = 0.004
    xy_per_m: float = 0.02
    theta_floor: float = 0.003
    theta_per_rad: float = 0.02
    theta_per_m: float = 0.01
    from_inliers: bool = True

    def covariance(
        self,
        motion: FloatArray,
        result: VOResult | None = None,
        T_base_camera: FloatArray | None = None,
    ) -> FloatArray:
        """Covariance (3, 3) of the planar base motion ``motion`` (m², m², rad²).

        Parameters
        ----------
        motion : (3,) planar base motion ``[dx, dy, dθ]`` (m, m, rad).
        result : the VO result the motion came from; its ``motion_cov`` is used when
            ``from_inliers`` and the motion was registered against the key-frame.
        T_base_camera : (4, 4) camera mounting the motion was converted with.
        """
        if (
            self.from_inliers
            and result is not None
            and result.motion_cov is not None
            and result.reference == "keyframe"
            and np.all(np.isfinite(result.motion_cov))
        ):
            J = planar_motion_jacobian(result.T_prev_curr, T_base_camera)
            floor = np.diag([self.xy_floor**2, self.xy_floor**2, self.theta_floor**2])
            cov = J @ result.motion_cov @ J.T + floor
            return 0.5 * (cov + cov.T)
        dist = math.hypot(motion[0], motion[1])
        s_xy = self.xy_floor + self.xy_per_m * dist
        s_th = self.theta_floor + self.theta_per_rad * abs(motion[2]) + self.theta_per_m * dist
        return np.diag([s_xy**2, s_xy**2, s_th**2])


def planar_motion_jacobian(
    T_prev_curr: npt.ArrayLike, T_base_camera: npt.ArrayLike | None = None, step: float = 1e-6
) -> FloatArray:
    """Jacobian (3, 6) of :func:`~realitygap.estimators.vo.planar_motion_from_camera` with
    respect to the camera-motion increments ``(δθ, δt)`` of ``R ← exp([δθ]×) R``,
    ``t ← t + δt`` (rad, m), by central differences of ``step``."""
    T = np.asarray(T_prev_curr, dtype=float)
    J = np.empty((3, 6))
    for k in range(6):
        cols = []
        for sign in (1.0, -1.0):
            d = np.zeros(6)
            d[k] = sign * step
            Tk = T.copy()
            Tk[:3, :3] = cv2.Rodrigues(d[:3])[0] @ T[:3, :3]
            Tk[:3, 3] = T[:3, 3] + d[3:]
            cols.append(np.array(planar_motion_from_camera(Tk, T_base_camera)))
        diff = cols[0] - cols[1]
        diff[2] = wrap_angle(diff[2])
        J[:, k] = diff / (2.0 * step)
    return J


@dataclass(frozen=True)
class MapSettings:
    """Occupancy grid of the pipeline (m)."""

    resolution: float = 0.05
    size_m: tuple[float, float] = (10.0, 10.0)


CALIBRATED_ODOMETRY_NOISE = OdometryNoise(
    distance_var_per_m=1e-6, heading_var_per_rad=1e-5, heading_var_per_m=1e-6
)
"""Dead-reckoning noise of wheel odometry whose geometry is the robot's own (calibrated, or the
nominal geometry of the nominal robot): σ ≈ 1 mm per √m and 0.2° per √rad (``calib000``
calibrates to millimetres over metres; the ``nav8`` pipeline uses the same). With it the fusion keeps the odometry's smooth, accurate short-range
motion and VO corrects what odometry cannot see (slip, a drifting heading) over distance;
with the generic :class:`OdometryNoise` (1 cm per √m, 1.8° per √rad) every VO key-frame's
error — a few millimetres and tenths of a degree in feature-poor views — pulls the pose."""


_NEW_CHAIN = frozenset({"initialised", "reinitialised", "reset"})
"""VO statuses of a frame that starts a new key-frame chain (:class:`~realitygap.estimators.
vo_params.VOStatus` values): its ``T_prev_curr`` is no measurement of motion."""


@dataclass(frozen=True)
class FusedPipelineSettings:
    """Settings of :class:`FusedOdometryVO`: VO, its noise model, the fusion (odometry noise
    :data:`CALIBRATED_ODOMETRY_NOISE` by default), the map and the lost-track count."""

    vo: VOParams = field(default_factory=VOParams)
    vo_noise: VONoise = field(default_factory=VONoise)
    fusion: FusionSettings = field(
        default_factory=lambda: FusionSettings(
            odometry_noise=CALIBRATED_ODOMETRY_NOISE, vo_timeout=math.inf
        )
    )
    map: MapSettings | None = field(default_factory=MapSettings)
    lost_after: int = 3
    """Consecutive failed VO frames after which the estimate is flagged as odometry-only."""


class FusedOdometryVO:
    """Wheel odometry ⊕ RGB-D visual odometry (EKF) with an occupancy grid.

    Parameters
    ----------
    kinematics : the odometry model (nominal or calibrated wheel radii, wheelbase).
    T_base_camera : (4, 4) camera mounting believed by the estimator (nominal or calibrated).
    settings : VO, noise, fusion and map settings.

    ``Estimate.extras`` carries ``vo_status``, ``vo_inliers``, ``n_vo_updates``,
    ``n_vo_failures`` and, when a map is kept, ``occupancy`` (the live
    :class:`~realitygap.estimators.occupancy.OccupancyGrid`).
    """

    def __init__(
        self,
        kinematics: DiffDriveKinematics,
        T_base_camera: npt.ArrayLike,
        settings: FusedPipelineSettings | None = None,
    ):
        self.kinematics = kinematics
        self.T_base_camera = np.asarray(T_base_camera, dtype=float)
        if self.T_base_camera.shape != (4, 4):
            raise ValueError(
                f"T_base_camera must be a 4x4 transform, got shape {self.T_base_camera.shape}"
            )
        self.settings = settings or FusedPipelineSettings()
        self.vo = RGBDVisualOdometry(self.settings.vo, T_base_camera=self.T_base_camera)
        self.ekf = OdomVOFusionEKF(kinematics=None, settings=self.settings.fusion)
        self.grid: OccupancyGrid | None = None
        self._last_ticks: tuple[int, int] | None = None
        self._failures = 0
        self._n_vo_updates = 0
        self._n_vo_failures = 0
        self._vo_status = "no_frame"
        self._vo_inliers = 0
        self._estimate: Estimate | None = None

    def reset(self, initial: Any | None = None) -> Estimate:
        pose = np.zeros(3) if initial is None else np.asarray(initial, dtype=float).reshape(3)
        self.ekf.reset(pose)
        T_world_base = np.eye(4)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        T_world_base[:2, :2] = [[c, -s], [s, c]]
        T_world_base[:2, 3] = pose[:2]
        self.vo.reset(T_world_base @ self.T_base_camera)
        if self.settings.map is not None:
            m = self.settings.map
            self.grid = OccupancyGrid(resolution=m.resolution, size_m=m.size_m, origin_xy=None)
            self.grid.reset()
        self._last_ticks = None
        self._failures = self._n_vo_updates = self._n_vo_failures = 0
        self._vo_status, self._vo_inliers = "no_frame", 0
        self._estimate = self._make_estimate(0.0, "ok")
        return self._estimate

    def update(self, measurement: DiffDriveMeasurement | None) -> Estimate:
        if self._estimate is None:
            self.reset()
        if measurement is None:
            assert self._estimate is not None
            return self._estimate
        if not isinstance(measurement, DiffDriveMeasurement):
            raise TypeError(
                f"FusedOdometryVO.update expects a DiffDriveMeasurement or None, got {type(measurement).__name__}"
            )
        t = float(measurement.t)
        ticks = measurement.ticks
        if self._last_ticks is not None:
            scale = self.kinematics.ticks_per_rev / float(ticks.ticks_per_rev)
            d_left = (ticks.left - self._last_ticks[0]) * scale
            d_right = (ticks.right - self._last_ticks[1]) * scale
            ds, dth = self.kinematics.increment_from_ticks(d_left, d_right)
            self.ekf.predict(ds, dth, t)
        self._last_ticks = (ticks.left, ticks.right)

        if measurement.rgbd is not None:
            res = self.vo.update(measurement.rgbd)
            self._vo_status, self._vo_inliers = str(res.status), int(res.n_inliers)
            if res.status in _NEW_CHAIN:
                # VO started a new key-frame chain at this frame: it measured no motion, the
                # filter anchors its key-frame here (its first relative motion comes next)
                self.ekf.set_keyframe(t)
            elif res.ok and res.keyframe:
                motion = np.asarray(planar_motion_from_camera(res.T_prev_curr, self.T_base_camera))
                if self.ekf.update_relative(
                    motion,
                    self.settings.vo_noise.covariance(motion, res, self.T_base_camera),
                    new_keyframe=True,
                    t=t,
                ):
                    self._n_vo_updates += 1
            if res.ok:
                self._failures = 0
            else:
                self._failures += 1
                self._n_vo_failures += 1
        if measurement.scan is not None and self.grid is not None:
            self.grid.update(self.ekf.x[:3].copy(), measurement.scan)
        lost = self._failures >= self.settings.lost_after
        status = f"vo_lost ({self._vo_status}): odometry only" if lost else "ok"
        self._estimate = self._make_estimate(t, status)
        return self._estimate

    def _make_estimate(self, t: float, status: str) -> Estimate:
        extras: dict[str, Any] = {
            "vo_status": self._vo_status,
            "vo_inliers": self._vo_inliers,
            "n_vo_updates": self._n_vo_updates,
            "n_vo_failures": self._n_vo_failures,
        }
        if self.grid is not None:
            extras["occupancy"] = self.grid
        return Estimate(
            t=t,
            pose=np.array(self.ekf.x[:3], dtype=float),
            cov=np.array(self.ekf.P[:3, :3], dtype=float),
            ok=status == "ok",
            status=status,
            extras=extras,
        )
