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

import numpy as np
import numpy.typing as npt

from realitygap.estimators.base import DiffDriveMeasurement, Estimate
from realitygap.estimators.diffdrive_model import DiffDriveKinematics
from realitygap.estimators.fusion_ekf import FusionSettings, OdomVOFusionEKF
from realitygap.estimators.occupancy import OccupancyGrid
from realitygap.estimators.vo import RGBDVisualOdometry, planar_motion_from_camera
from realitygap.estimators.vo_params import VOParams

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class VONoise:
    """Covariance model of a VO key-frame-to-frame planar motion.

    ``σ_xy = xy_floor + xy_per_m · distance`` (m) and
    ``σ_θ = theta_floor + theta_per_rad · |Δθ| + theta_per_m · distance`` (rad).
    """

    xy_floor: float = 0.004
    xy_per_m: float = 0.02
    theta_floor: float = 0.003
    theta_per_rad: float = 0.02
    theta_per_m: float = 0.01

    def covariance(self, motion: FloatArray) -> FloatArray:
        dist = math.hypot(motion[0], motion[1])
        s_xy = self.xy_floor + self.xy_per_m * dist
        s_th = self.theta_floor + self.theta_per_rad * abs(motion[2]) + self.theta_per_m * dist
        return np.diag([s_xy**2, s_xy**2, s_th**2])


@dataclass(frozen=True)
class MapSettings:
    """Occupancy grid of the pipeline (m)."""

    resolution: float = 0.05
    size_m: tuple[float, float] = (10.0, 10.0)


@dataclass(frozen=True)
class FusedPipelineSettings:
    vo: VOParams = field(default_factory=VOParams)
    vo_noise: VONoise = field(default_factory=VONoise)
    fusion: FusionSettings = field(default_factory=lambda: FusionSettings(vo_timeout=math.inf))
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
            if res.ok and res.keyframe:
                motion = np.asarray(planar_motion_from_camera(res.T_prev_curr, self.T_base_camera))
                if self.ekf.update_relative(
                    motion, self.settings.vo_noise.covariance(motion), new_keyframe=True, t=t
                ):
                    self._n_vo_updates += 1
                self._failures = 0
            elif res.ok:
                self._failures = 0
            else:
                self._failures += 1
                self._n_vo_failures += 1
                if res.status in ("reinitialised", "reset", "initialised"):
                    self.ekf.set_keyframe(t)
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
