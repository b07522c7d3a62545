"""Measurements, estimates and the :class:`Estimator` protocol.

Sensors in :mod:`realitygap.robots` produce the measurement dataclasses below;
estimators turn them into an :class:`Estimate`. Nothing here imports PyBullet,
so estimators run unchanged on recorded real data.

Frames: ``world`` is the fixed frame of the scene, ``base`` the robot's body
frame (x forward, y left, z up), ``camera`` the optical frame (x right, y down,
z forward, OpenCV convention).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, init=False)
class WheelTicks:
    """Cumulative encoder counts of a differential drive at time ``t`` (s).

    ``ticks_per_rev`` counts per wheel revolution; counts are signed integers,
    increasing when the wheel drives the robot forward.
    """

    t: float
    left: int
    right: int
    ticks_per_rev: float

    def __init__(self, t: float, left: int, right: int, ticks_per_rev: float) -> None:
        # frozen: the fields go into the instance's dict directly (what the generated
        # __init__ does with one object.__setattr__ per field, at twice the cost)
        d = self.__dict__
        d["t"], d["left"], d["right"], d["ticks_per_rev"] = t, left, right, ticks_per_rev


@dataclass(frozen=True, init=False)
class Scan:
    """Planar range scan in the base frame.

    ``angles`` (n,) rad, counter-clockwise from the base x axis; ``ranges`` (n,) m,
    ``inf`` where nothing was seen within ``range_max``.
    """

    t: float
    angles: FloatArray
    ranges: FloatArray
    range_min: float
    range_max: float

    def __init__(
        self, t: float, angles: FloatArray, ranges: FloatArray, range_min: float, range_max: float
    ) -> None:
        d = self.__dict__  # frozen: as WheelTicks
        d["t"], d["angles"], d["ranges"] = t, angles, ranges
        d["range_min"], d["range_max"] = range_min, range_max


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics: ``u = fx X/Z + cx``, ``v = fy Y/Z + cy`` (pixels)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    @property
    def K(self) -> FloatArray:
        """3×3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class RGBDFrame:
    """A colour + depth frame.

    ``rgb`` (H, W, 3) uint8; ``depth`` (H, W) float32 in m along the optical axis,
    ``nan`` where the sensor returned nothing (out of range, holes).
    """

    t: float
    rgb: npt.NDArray[np.uint8]
    depth: npt.NDArray[np.float32]
    intrinsics: CameraIntrinsics


@dataclass(frozen=True, init=False)
class DiffDriveMeasurement:
    """Everything a differential-drive robot's sensors report at one control step.

    Channels that did not report at this step are ``None``.
    """

    t: float
    ticks: WheelTicks
    scan: Scan | None = None
    rgbd: RGBDFrame | None = None

    def __init__(
        self,
        t: float,
        ticks: WheelTicks,
        scan: Scan | None = None,
        rgbd: RGBDFrame | None = None,
    ) -> None:
        d = self.__dict__  # frozen: as WheelTicks
        d["t"], d["ticks"], d["scan"], d["rgbd"] = t, ticks, scan, rgbd


@dataclass
class Estimate:
    """An estimator's output.

    ``pose`` is ``[x, y, theta]`` (m, m, rad) of the base in the world frame and
    ``cov`` its 3×3 covariance. ``ok`` is False when the estimator had to fall
    back (e.g. visual odometry lost), and ``status`` says why. ``extras`` holds
    estimator-specific results (calibrated parameters, map, …).
    """

    t: float
    pose: FloatArray
    cov: FloatArray = field(default_factory=lambda: np.zeros((3, 3)))
    ok: bool = True
    status: str = "ok"
    extras: dict[str, Any] = field(default_factory=dict)


@runtime_checkable
class Estimator(Protocol):
    """What an environment's observation pipeline needs from an estimator.

    ``reset`` starts a new episode from a known initial state (``None``: the
    origin); ``update`` consumes one measurement, or ``None`` when nothing was
    measured this step, and returns the current estimate.
    """

    def reset(self, initial: Any | None = None) -> Estimate: ...

    def update(self, measurement: Any | None) -> Estimate: ...
