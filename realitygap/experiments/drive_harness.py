"""Driving a WheeledNav robot through a scripted drive and recording it.

The perception and calibration experiments share this harness: a room lined
with textured panels (:func:`calibration_room`), an estimator that records
every measurement the env hands it (:class:`RecordingOdometry`), the drive loop
itself (:func:`drive`, which returns a :class:`DriveLog`), and the exact arc
paths the drives follow (:func:`arc_path`, :func:`figure_eight`,
:func:`timed_reference`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from realitygap.controllers.drives import DriveController

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

__all__ = [
    "DriveLog",
    "RecordingOdometry",
    "arc_path",
    "calibration_room",
    "drive",
    "figure_eight",
    "load_average",
    "nominal_kinematics",
    "timed_reference",
]


def calibration_room(
    room_half_size: float = 2.5,
    panel_width: float = 0.5,
    panel_gap: float = 0.1,
    panel_height: float = 0.75,
) -> list[Any]:
    """A room lined with textured panels plus four pieces of furniture.

    The env textures every primitive with its own procedural image, so narrow
    panels along the walls give the camera dense, metric-scale texture (a wall
    carries one texture stretched over its whole length, which leaves few
    features). The furniture stands in the corners; the middle ``±1.5 m``
    stays free for driving.

    Parameters
    ----------
    room_half_size : float
        Half the side of the square room, m.
    panel_width, panel_gap, panel_height : float
        Width, spacing and height of the wall panels, m.

    Returns
    -------
    list of :class:`~realitygap.robots.world.Primitive`
        Obstacles for ``WheeledNavEnv(obstacles=...)``.
    """
    from realitygap.robots.world import Primitive, Shape

    if not room_half_size > 2.3:
        raise ValueError(
            f"room_half_size must exceed 2.3 m (the furniture stands at ±1.85 m), got "
            f"{room_half_size}"
        )
    thick = 0.06
    n = int((2.0 * room_half_size - 0.2) // (panel_width + panel_gap))
    span = n * (panel_width + panel_gap) - panel_gap
    out = []
    d = room_half_size - thick / 2.0 - 0.005
    for side, (nx, ny) in enumerate(((0, 1), (0, -1), (1, 0), (-1, 0))):
        for i in range(n):
            c = -span / 2.0 + panel_width / 2.0 + i * (panel_width + panel_gap)
            if nx == 0:
                center, half = (c, ny * d), (panel_width / 2.0, thick / 2.0)
            else:
                center, half = (nx * d, c), (thick / 2.0, panel_width / 2.0)
            out.append(
                Primitive(f"panel_{side}_{i}", Shape.BOX, center, panel_height, half_extents=half)
            )
    out += [
        Primitive("shelf_ne", Shape.BOX, (1.85, 1.75), 0.6, yaw=0.3, half_extents=(0.25, 0.2)),
        Primitive("bin_nw", Shape.CYLINDER, (-1.8, 1.85), 0.7, radius=0.2),
        Primitive("crate_sw", Shape.BOX, (-1.85, -1.8), 0.5, yaw=-0.4, half_extents=(0.3, 0.15)),
        Primitive("bin_se", Shape.CYLINDER, (1.8, -1.85), 0.6, radius=0.18),
    ]
    return out


class RecordingOdometry:
    """Wheel odometry that also keeps every measurement the env hands it (an Estimator).

    Used as the env's observation pipeline: the controller sees the odometry
    estimate (``info["estimated_pose"]``) computed with :attr:`kinematics`, and
    the experiment reads the recorded encoder counts and RGB-D frames
    afterwards. Set :attr:`kinematics` before ``env.reset`` to change the
    odometry in the loop.

    Parameters
    ----------
    kinematics : DiffDriveKinematics
        Geometry of the odometry in the loop.
    """

    def __init__(self, kinematics: Any):
        from realitygap.estimators.diffdrive_model import WheelOdometry

        self.kinematics = kinematics
        self._odometry = WheelOdometry(kinematics)
        self.ticks: list[Any] = []
        self.frames: list[tuple[int, Any]] = []

    def reset(self, initial: Any | None = None) -> Any:
        """Forget the recording and restart the odometry at ``initial``."""
        from realitygap.estimators.diffdrive_model import WheelOdometry

        self._odometry = WheelOdometry(self.kinematics)
        self.ticks = []
        self.frames = []
        return self._odometry.reset(initial)

    def update(self, measurement: Any | None) -> Any:
        """Record a :class:`DiffDriveMeasurement` and integrate its ticks."""
        if measurement is None:
            return self._odometry.update(None)
        self.ticks.append(measurement.ticks)
        if measurement.rgbd is not None:
            self.frames.append((len(self.ticks) - 1, measurement.rgbd))
        return self._odometry.update(measurement.ticks)


@dataclass(frozen=True)
class DriveLog:
    """One recorded drive.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Time of every control step from the reset, s.
    ticks : ndarray, shape (N, 2)
        Cumulative encoder counts ``[left, right]`` at each step.
    gt : ndarray, shape (N, 3)
        True base pose ``[x, y, θ]`` (m, m, rad), world frame.
    estimate : ndarray, shape (N, 3)
        The pose estimate the controller used.
    frames : tuple of RGBDFrame
        Rendered camera frames.
    frame_index : ndarray of int, shape (M,)
        Step index of each frame.
    T_world_camera : ndarray, shape (M, 4, 4)
        True camera pose at each frame (sim-only ground truth).
    collided : bool
        Whether the body touched scenery.
    ticks_per_rev : float
        Encoder counts per wheel revolution.
    """

    t: FloatArray
    ticks: FloatArray
    gt: FloatArray
    estimate: FloatArray
    frames: tuple[Any, ...]
    frame_index: IntArray
    T_world_camera: FloatArray
    collided: bool
    ticks_per_rev: float

    def tick_increments(self) -> tuple[FloatArray, FloatArray]:
        """Per-step increments ``(left, right)``, shape (N - 1,) each."""
        d = np.diff(self.ticks, axis=0)
        return d[:, 0], d[:, 1]

    def dead_reckon(self, kinematics: Any) -> FloatArray:
        """Odometry poses (N, 3) from the true start pose with ``kinematics``."""
        d_left, d_right = self.tick_increments()
        scale = kinematics.ticks_per_rev / self.ticks_per_rev
        return np.asarray(
            kinematics.integrate(self.gt[0], d_left * scale, d_right * scale, wrap=False)
        )


def drive(
    env: Any,
    recorder: RecordingOdometry,
    controller: DriveController,
    start: npt.ArrayLike,
    seed: int,
    max_steps: int,
) -> DriveLog:
    """Reset ``env`` at ``start`` and steer it with ``controller`` until it is done.

    Parameters
    ----------
    env : WheeledNav env (or a wrapper) whose estimator is ``recorder``.
    recorder : the env's :class:`RecordingOdometry`.
    controller : :class:`~realitygap.controllers.drives.DriveController`; sees ``info["estimated_pose"]``.
    start : array_like, shape (3,)
        Start pose ``[x, y, θ]`` (m, m, rad).
    seed : int
        Reset seed (room textures and sensor noise).
    max_steps : int
        Safety limit on control steps.

    Returns
    -------
    DriveLog
    """
    base = env.unwrapped
    _, info = env.reset(seed=seed, options={"start": np.asarray(start, dtype=float)})
    gts = [np.asarray(info["true_pose"], dtype=float)]
    est = [np.asarray(info["estimated_pose"], dtype=float)]
    times = [0.0]
    cams = [base.robot.T_world_camera()] if recorder.frames else []
    collided = False
    dt = base.dt
    for _ in range(int(max_steps)):
        v, w, done = controller.command(est[-1], times[-1])
        if done:
            break
        action = np.clip([v / base.v_max, w / base.w_max], -1.0, 1.0)
        n_frames = len(recorder.frames)
        _, _, terminated, truncated, info = env.step(action.astype(np.float32))
        times.append(times[-1] + dt)
        gts.append(np.asarray(info["true_pose"], dtype=float))
        est.append(np.asarray(info["estimated_pose"], dtype=float))
        if len(recorder.frames) > n_frames:
            cams.append(base.robot.T_world_camera())
        if info["collision"]:
            collided = True
        if terminated or truncated:
            break
    ticks = np.array([[m.left, m.right] for m in recorder.ticks], dtype=float)
    gt = np.array(gts)
    gt[:, 2] = np.unwrap(gt[:, 2])
    return DriveLog(
        t=np.array(times),
        ticks=ticks[: len(times)],
        gt=gt,
        estimate=np.array(est),
        frames=tuple(f for _, f in recorder.frames),
        frame_index=np.array([i for i, _ in recorder.frames], dtype=np.intp),
        T_world_camera=np.array(cams).reshape(-1, 4, 4),
        collided=collided,
        ticks_per_rev=float(recorder.ticks[0].ticks_per_rev),
    )


# --------------------------------------------------------------------------- controllers


def arc_path(
    start: npt.ArrayLike, segments: Sequence[tuple[float, float]], spacing: float = 0.01
) -> Any:
    """An exact path of circular arcs and straight pieces as a :class:`SmoothPath`.

    Parameters
    ----------
    start : array_like, shape (3,)
        Start pose ``[x, y, θ]`` (m, m, rad).
    segments : sequence of (length, curvature)
        Arc length (m, > 0) and signed curvature (1/m, positive turning left)
        of each piece, driven in order.
    spacing : float
        Sample spacing along the path, m.

    Returns
    -------
    SmoothPath
    """
    from realitygap.controllers import SmoothPath
    from realitygap.core.geometry import check_finite
    from realitygap.estimators.diffdrive_model import integrate_arcs

    p0 = check_finite("start", start, (3,))
    ds_list, kappa_list = [], []
    for length, piece_curvature in segments:
        if not length > 0:
            raise ValueError(f"segment lengths must be > 0 m, got {length!r}")
        n = max(2, int(math.ceil(length / spacing)))
        ds_list.append(np.full(n, length / n))
        kappa_list.append(np.full(n, float(piece_curvature)))
    ds = np.concatenate(ds_list)
    kappa = np.concatenate(kappa_list)
    poses = integrate_arcs(p0, ds, kappa * ds, wrap=False)
    curvature = np.concatenate([kappa[:1], kappa])
    return SmoothPath(
        xy=poses[:, :2].copy(),
        heading=poses[:, 2].copy(),
        curvature=curvature,
        s=np.concatenate([[0.0], np.cumsum(ds)]),
        feasible=True,
        message="ok",
    )


def figure_eight(start: FloatArray, laps: Sequence[tuple[float, int]]) -> Any:
    """Figure-eights from ``start``: per ``(radius, laps)`` pair, ``laps`` times a left then a right circle of ``radius`` m."""
    segs: list[tuple[float, float]] = []
    for radius, n in laps:
        for _ in range(int(n)):
            segs += [
                (2.0 * math.pi * radius, 1.0 / radius),
                (2.0 * math.pi * radius, -1.0 / radius),
            ]
    return arc_path(start, segs)


def timed_reference(path: Any, v_max: float = 0.3, w_max: float = 1.0) -> Any:
    """``path`` timed under ``v_max`` (m/s), ``w_max`` (rad/s), 0.5 m/s² and 2 rad/s², at 90 % speed."""
    from realitygap.controllers import TimedReference, VelocityLimits

    limits = VelocityLimits(v_max=v_max, w_max=w_max, a_max=0.5, alpha_max=2.0)
    return TimedReference(path, limits, speed_fraction=0.9)


def nominal_kinematics(params: Any) -> Any:
    """The :class:`DiffDriveKinematics` of a :class:`DiffDriveParams` body."""
    from realitygap.estimators.diffdrive_model import DiffDriveKinematics

    return DiffDriveKinematics(
        params.wheel_radius_left, params.wheel_radius_right, params.wheelbase, params.ticks_per_rev
    )


def load_average() -> float | None:
    """1-minute load average of the machine (timings are wall-clock), if known."""
    import os

    try:
        return float(os.getloadavg()[0])
    except (AttributeError, OSError):
        return None
