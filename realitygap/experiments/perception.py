r"""Perception and odometry-calibration experiments: ``calib000``, ``vo``, ``umbmark-real``.

``calib000``
    Seed 000's calibration in simulation. The "real" robot is another body: its
    left/right wheel diameters are 1.05 / 0.98 × nominal, its wheelbase
    1.05 × nominal and its RGB-D camera is mounted off by (1.1 cm, 0.8 cm, −1°);
    the firmware still converts ``(v, ω)`` with the nominal geometry. Each of
    three calibration iterations runs

    1. **UMBmark** (Borenstein): squares driven clockwise and counter-clockwise
       by a closed-loop controller (:class:`SquareDriver`) whose pose estimate
       is the *current* calibrated odometry. The absolute end pose comes from
       the camera, not from ground truth: the last frame registered directly
       against the first one (a loop closure, millimetre-accurate when the
       robot is back near its start) or, when the two views do not overlap,
       the chained visual-odometry trajectory; it is carried to the base with
       the current mounting estimate (:func:`end_pose_from_frames`).
    2. **Online calibration** (Censi et al.): the
       :class:`~realitygap.estimators.mounting_calibration.MountingCalibrationEKF` over the
       sensor pose, the camera mounting and the left/right wheel-radius and
       wheelbase scale factors, seeded by the UMBmark result and by the
       previous iteration's posterior, fed with tick increments and the
       camera's ego-motion from
       :class:`~realitygap.estimators.vo.RGBDVisualOdometry` on rendered frames
       (5 Hz) along figure-eights — turns in both directions while
       translating (:func:`fit_odometry_and_mounting`).

    Then a straight and a semicircular trajectory are driven on the calibrated
    odometry, and its estimate (and the estimate fused with VO) is compared
    with ground truth at 20 positions each; the same drives dead-reckoned with
    the nominal geometry, and with UMBmark alone, are the contrast.

``vo``
    RGB-D visual odometry on a figure-eight drive through a textured
    ``realitygap/WheeledNav-v0`` room (image mode): trajectory error, relative
    error per metre, processing rate, SIFT against ORB, and the precision of
    the matches the ratio test, GTM and RANSAC keep, judged against
    ground-truth correspondences (:func:`match_precision`).

``umbmark-real``
    UMBmark on the real OptiOdom square sessions
    (:mod:`realitygap.calibrate`), checked by dead-reckoning the held-out
    circular, Ivanjko and free-path sessions from their wheel ticks.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from realitygap.experiments import RunContext, experiment

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

__all__ = [
    "CalibConfig",
    "DriveLog",
    "PathFollower",
    "RecordingOdometry",
    "SquareDriver",
    "arc_path",
    "calibration_room",
    "end_pose_from_frames",
    "fit_odometry_and_mounting",
    "match_precision",
    "relative_pose_errors",
    "umbmark_real_calibration",
]


# =============================================================================
# shared building blocks
# =============================================================================


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


class Controller(Protocol):
    """What :func:`drive` steers with."""

    def command(self, pose: FloatArray, t: float) -> tuple[float, float, bool]:
        """``(v, ω, done)`` in m/s, rad/s for the estimated pose ``[x, y, θ]`` at time ``t`` s."""
        ...


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
    controller: Controller,
    start: npt.ArrayLike,
    seed: int,
    max_steps: int,
) -> DriveLog:
    """Reset ``env`` at ``start`` and steer it with ``controller`` until it is done.

    Parameters
    ----------
    env : WheeledNav env (or a wrapper) whose estimator is ``recorder``.
    recorder : the env's :class:`RecordingOdometry`.
    controller : :class:`Controller`; sees ``info["estimated_pose"]``.
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


class SquareDriver:
    r"""Drive an ``L × L`` square by the odometry estimate, turning on the spot at the corners.

    The robot starts facing +x of its start frame; ``"cw"`` turns right (the
    square lies at ``y ≤ 0``), ``"ccw"`` left. Each leg is tracked with

    .. math::

        v = \min\big(v_c,\ \sqrt{2 a d},\ k_d d + v_0\big), \qquad
        \omega = -k_\perp v\, e_\perp - k_\theta \sin(\theta - \varphi),

    (``d`` the distance left along the leg, ``e_⊥`` the lateral offset, ``φ``
    the leg direction; ``k_d = 4/s``, ``v_0 = 1 cm/s``, ``k_⊥ = 4/m²``,
    ``k_θ = 3/s``) until ``d < 0.5 mm``, and each 90° turn with

    .. math::

        \omega = \operatorname{sign}(e) \min\big(\omega_c,\ \sqrt{2 \alpha |e|},\
        k_e |e| + \omega_0\big)

    (``k_e = 10/s``, ``ω_0 = 0.02 rad/s``) until the heading error ``e`` is
    below ``heading_tol``. After the fourth leg the robot turns back to its
    start heading and rests for half a second, as in Borenstein's UMBmark.

    Parameters
    ----------
    start : array_like, shape (3,)
        Start pose in the world, m, m, rad.
    side : float
        Side of the square, m.
    direction : {"cw", "ccw"}
    v_cruise, w_cruise : float
        Leg speed (m/s) and turn rate (rad/s).
    accel, alpha : float
        Deceleration used to approach a corner (m/s²) and a heading (rad/s²).
    heading_tol : float
        Heading tolerance of the turns, rad.
    """

    def __init__(
        self,
        start: npt.ArrayLike,
        side: float,
        direction: str,
        *,
        v_cruise: float = 0.25,
        w_cruise: float = 0.8,
        accel: float = 0.4,
        alpha: float = 1.5,
        heading_tol: float = 1.5e-3,
    ):
        from realitygap.core.geometry import check_finite

        if direction not in ("cw", "ccw"):
            raise ValueError(f"direction must be 'cw' or 'ccw', got {direction!r}")
        if not side > 0:
            raise ValueError(f"side must be a positive length in m, got {side!r}")
        self.start = check_finite("start", start, (3,))
        self.side = float(side)
        self.direction = direction
        sign = -1.0 if direction == "cw" else 1.0
        corners = np.array([[0, 0], [side, 0], [side, sign * side], [0, sign * side], [0, 0]])
        self._corners = corners.astype(float)
        # leg directions 0, ±π/2, ±π, ±3π/2 and the final heading ±2π ≡ 0 (start frame)
        self._headings = [sign * k * math.pi / 2.0 for k in range(5)]
        self.v_cruise, self.w_cruise = float(v_cruise), float(w_cruise)
        self.accel, self.alpha = float(accel), float(alpha)
        self.heading_tol = float(heading_tol)
        self._leg = 0
        self._turning = False
        self._rest = 0

    def command(self, pose: FloatArray, t: float) -> tuple[float, float, bool]:
        from realitygap.core.geometry import se2_between, wrap_angle

        x, y, th = se2_between(self.start, pose)
        if self._turning:
            err = float(wrap_angle(self._headings[self._leg] - th))
            if abs(err) < self.heading_tol:
                self._turning = False
                return 0.0, 0.0, False
            w = min(self.w_cruise, math.sqrt(2.0 * self.alpha * abs(err)), 10.0 * abs(err) + 0.02)
            return 0.0, math.copysign(w, err), False
        if self._leg >= 4:
            self._rest += 1
            return 0.0, 0.0, self._rest > 10
        a, b = self._corners[self._leg], self._corners[self._leg + 1]
        phi = self._headings[self._leg]
        u = np.array([math.cos(phi), math.sin(phi)])
        rel = np.array([x, y]) - a
        remaining = float(np.linalg.norm(b - a) - rel @ u)
        lateral = float(rel @ np.array([-u[1], u[0]]))
        if remaining < 5e-4:
            self._leg += 1
            self._turning = True
            return 0.0, 0.0, False
        v = min(self.v_cruise, math.sqrt(2.0 * self.accel * remaining), 4.0 * remaining + 0.01)
        w = -4.0 * v * lateral - 3.0 * math.sin(float(wrap_angle(th - phi)))
        return v, w, False


class PathFollower:
    """Track a :class:`~realitygap.controllers.TimedReference` with the Kanayama law.

    Parameters
    ----------
    reference : TimedReference
        Timed path in the world frame.
    settle_s : float
        Time (s) after the reference ends during which the tracker keeps
        correcting before the drive ends.
    """

    def __init__(self, reference: Any, settle_s: float = 1.0):
        from realitygap.controllers import KanayamaTracker

        self.reference = reference
        self.tracker = KanayamaTracker()
        self.settle_s = float(settle_s)

    def command(self, pose: FloatArray, t: float) -> tuple[float, float, bool]:
        if t > self.reference.duration + self.settle_s:
            return 0.0, 0.0, True
        ref = self.reference.sample(t)
        v, w = self.tracker.command(pose, ref.pose, ref.v, ref.w)
        return v, w, False


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


def _timed(path: Any, v_max: float = 0.3, w_max: float = 1.0) -> Any:
    from realitygap.controllers import TimedReference, VelocityLimits

    limits = VelocityLimits(v_max=v_max, w_max=w_max, a_max=0.5, alpha_max=2.0)
    return TimedReference(path, limits, speed_fraction=0.9)


# --------------------------------------------------------------------------- camera geometry


def _T_base_camera_planar(mounting: npt.ArrayLike, height: float = 0.30) -> FloatArray:
    """4×4 optical-frame pose in the base for a level camera at planar mounting ``[x, y, θ]``."""
    from realitygap.core.geometry import rot_z
    from realitygap.estimators.vo import T_BASE_CAMERA_FORWARD

    l = np.asarray(mounting, dtype=float)
    T = np.eye(4)
    T[:3, :3] = rot_z(float(l[2])) @ T_BASE_CAMERA_FORWARD[:3, :3]
    T[:3, 3] = (l[0], l[1], height)
    return T


def _sensor_motion_from_camera(T_prev_curr: FloatArray) -> FloatArray:
    """Planar ego-motion ``[x, y, θ]`` of the sensor frame (optical axis on the floor plane)."""
    from realitygap.estimators.vo import planar_motion_from_camera

    return np.array(planar_motion_from_camera(T_prev_curr))


def _vo_chain(
    frames: Sequence[Any], params: Any
) -> tuple[FloatArray, npt.NDArray[np.bool_], list[Any]]:
    """Camera poses (M, 4, 4) relative to the first frame, per-frame success and the results."""
    from realitygap.estimators.vo import RGBDVisualOdometry

    vo = RGBDVisualOdometry(params)
    vo.reset(np.eye(4))
    results = [vo.update(f) for f in frames]
    poses = np.array([r.T_world_camera for r in results])
    ok = np.array([r.ok for r in results], dtype=bool)
    return poses, ok, results


@dataclass(frozen=True)
class EndPose:
    """End pose of a run relative to its start, measured by the camera.

    Attributes
    ----------
    base_motion : ndarray, shape (3,)
        ``⊖q_start ⊕ q_end`` of the base (m, m, rad).
    source : str
        ``"loop closure"`` (last frame registered against the first) or
        ``"chained VO"``.
    n_inliers : int
        Inliers of the loop-closure registration (0 if it failed).
    """

    base_motion: FloatArray
    source: str
    n_inliers: int


def end_pose_from_frames(
    frames: Sequence[Any], mounting: npt.ArrayLike, params: Any = None, min_inliers: int = 40
) -> EndPose:
    """Absolute end pose of a run from its camera frames (the "map" reference of UMBmark).

    The last frame is registered directly against the first one; when the
    robot came back close to its start pose the two views overlap and this
    loop closure is accurate to millimetres. Otherwise the frame-to-frame
    visual-odometry chain is used. The sensor motion is carried to the base
    with the planar mounting ``l``: ``⊖q_0 ⊕ q_N = l ⊕ z ⊕ ⊖l``.

    Parameters
    ----------
    frames : sequence of RGBDFrame
        Frames of the run, the first at the start pose.
    mounting : array_like, shape (3,)
        Current estimate of the camera mounting ``[l_x, l_y, l_θ]`` (m, m, rad).
    params : VOParams, optional
    min_inliers : int
        Fewest inliers for the loop closure to be trusted.

    Returns
    -------
    EndPose
    """
    from realitygap.core.geometry import se2_compose, se2_inverse
    from realitygap.estimators.vo import RGBDVisualOdometry, VOParams

    params = params if params is not None else VOParams()
    if len(frames) < 2:
        raise ValueError(f"need at least two frames (start and end), got {len(frames)}")
    l = np.asarray(mounting, dtype=float)
    vo = RGBDVisualOdometry(params)
    vo.reset(np.eye(4))
    vo.update(frames[0])
    res = vo.update(frames[-1])
    if res.ok and res.n_inliers >= min_inliers:
        T, source, n_in = res.T_prev_curr, "loop closure", int(res.n_inliers)
    else:
        poses, _, _ = _vo_chain(frames, params)
        T, source, n_in = poses[-1], "chained VO", 0
    z = _sensor_motion_from_camera(T)
    return EndPose(se2_compose(se2_compose(l, z), se2_inverse(l)), source, n_in)


# =============================================================================
# calib000
# =============================================================================


@dataclass(frozen=True)
class CalibConfig:
    """Settings of ``calib000``.

    Attributes
    ----------
    left_diameter_factor, right_diameter_factor : float
        True wheel diameters relative to nominal (seed 000: 1.05 and 0.98).
    wheelbase_factor : float
        True wheelbase relative to nominal (seed 000: 1.05).
    camera_offset : tuple of 3 floats
        True camera mounting minus nominal ``(dx, dy, dyaw)`` in m, m, rad.
    iterations : int
        Calibration iterations (UMBmark + EKF each).
    square_side : float
        UMBmark square side, m.
    runs_per_direction : int
        UMBmark squares per direction per iteration.
    excitation : tuple of (radius, laps)
        Figure-eights of the online calibration: lobe radius (m) and count.
    first_excitation : tuple of (radius, laps)
        Shorter figure-eights for the first iteration, which still steers on
        the coarse first UMBmark result (its heading drift would carry the
        robot out of the free area on the long run).
    excitation_speed : float
        Top speed on the figure-eights, m/s.
    frame_hz : float
        Camera rate, Hz (a divisor of the 20 Hz control rate).
    straight_length : float
        Length of the straight test trajectory, m.
    curve_radius : float
        Radius of the semicircular test trajectory, m.
    n_positions : int
        Positions sampled per test trajectory.
    umbmark_only_iterations : int
        Iterations of the UMBmark-only contrast (squares only, no camera
        calibration; its first iteration is shared with the main loop).
    room_half_size : float
        Half the side of the room, m.
    """

    left_diameter_factor: float = 1.05
    right_diameter_factor: float = 0.98
    wheelbase_factor: float = 1.05
    camera_offset: tuple[float, float, float] = (0.011, 0.008, math.radians(-1.0))
    iterations: int = 3
    square_side: float = 1.0
    runs_per_direction: int = 2
    excitation: tuple[tuple[float, int], ...] = ((0.5, 2), (0.8, 2))
    first_excitation: tuple[tuple[float, int], ...] = ((0.5, 1),)
    excitation_speed: float = 0.5
    frame_hz: float = 5.0
    straight_length: float = 2.4
    curve_radius: float = 1.0
    n_positions: int = 20
    umbmark_only_iterations: int = 3
    room_half_size: float = 2.5

    @classmethod
    def quick(cls) -> CalibConfig:
        """A shorter run (one square per direction, one figure-eight per iteration)."""
        return cls(
            runs_per_direction=1,
            square_side=0.8,
            excitation=((0.5, 1), (0.8, 1)),
            umbmark_only_iterations=1,
        )

    def reality(self) -> Any:
        """The "real" robot: effects built into the body and the camera link."""
        from realitygap.robots.effects import Reality, make_effect

        left, right = self.left_diameter_factor, self.right_diameter_factor
        dx, dy, dyaw = self.camera_offset
        return Reality(
            (
                make_effect("wheel_radius_scale", scale=(left + right) / 2.0),
                make_effect("wheel_diameter_ratio", E_d=right / left),
                make_effect("wheelbase_error", E_b=self.wheelbase_factor),
                make_effect("camera_mount_offset", dx=dx, dy=dy, dyaw=dyaw),
            ),
            name="seed000",
        )


def _nominal_kinematics(params: Any) -> Any:
    from realitygap.estimators.diffdrive_model import DiffDriveKinematics

    return DiffDriveKinematics(
        params.wheel_radius_left, params.wheel_radius_right, params.wheelbase, params.ticks_per_rev
    )


def _mounting_of(camera: Any) -> FloatArray:
    return np.array([camera.mount_xyz[0], camera.mount_xyz[1], camera.mount_yaw])


def _factors(kin: Any, nominal: Any) -> FloatArray:
    """``[k_L, k_R, k_b]`` of ``kin`` relative to ``nominal``."""
    return np.array(
        [
            kin.wheel_radius_left / nominal.wheel_radius_left,
            kin.wheel_radius_right / nominal.wheel_radius_right,
            kin.wheelbase / nominal.wheelbase,
        ]
    )


_PRIOR_FLOOR = np.array([5e-4, 5e-4, math.radians(0.05), 3e-4, 3e-4, 3e-4])
"""Standard deviations added to a carried-over posterior: 0.5 mm, 0.5 mm, 0.05°, 0.03 % ×3
(about the size of a later iteration's UMBmark correction)."""


def _make_calib_env(cfg: CalibConfig, recorder: RecordingOdometry, frame_hz: float) -> Any:
    import gymnasium as gym

    import realitygap  # noqa: F401  (registers the ids)

    return gym.make(
        "realitygap/WheeledNav-v0",
        sensor_mode="image",
        estimator=recorder,
        reality=cfg.reality(),
        obstacles=calibration_room(cfg.room_half_size),
        room_half_size=cfg.room_half_size,
        start=(0.0, 0.0, 0.0),
        goal=(0.0, 0.5, 0.0),
        camera_hz=frame_hz,
        scan_hz=frame_hz,
        terminate_on_success=False,
        max_episode_steps=100_000,
    )


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


_DEFAULT_PRIOR = np.diag([0.1, 0.1, 0.2, 0.05, 0.05, 0.05]) ** 2
"""Prior covariance of ``[l_x, l_y, l_θ, k_L, k_R, k_b]`` (the filter's defaults)."""


def _predicted_sensor_motions(
    inc: FloatArray, nominal: Any, scales: FloatArray, mounting: FloatArray
) -> FloatArray:
    """``⊖l ⊕ δ(n_L, n_R; k) ⊕ l`` for every interval, shape (K, 3)."""
    from realitygap.estimators.diffdrive_model import arc_increment
    from realitygap.estimators.mounting_calibration import sensor_motion

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
    from realitygap.core.geometry import wrap_angle
    from realitygap.estimators.mounting_calibration import (
        MountingCalibrationEKF,
        MountingNoise,
        mounting_observability,
    )

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


_REFERENCE_INLIERS = 50
"""Inlier count that gives a visual-odometry motion the weight 1 in the calibration."""


def _sensor_motions_of(
    log: DriveLog, params: Any
) -> tuple[FloatArray, list[FloatArray | None], FloatArray, int]:
    """Tick increments, VO sensor motions and their weights between consecutive frames.

    The weight of a frame pair is ``min(n_inliers) / 50`` over its two
    registrations (clipped to ``[0.1, 2]``): information grows with the number
    of independent point pairs.
    """
    poses, ok, results = _vo_chain(log.frames, params)
    fi = log.frame_index
    inc = log.ticks[fi[1:]] - log.ticks[fi[:-1]]
    n_in = np.array([r.n_inliers if r.status == "ok" else np.inf for r in results], dtype=float)
    motions: list[FloatArray | None] = []
    weights = np.ones(len(fi) - 1)
    for k in range(1, len(fi)):
        if ok[k] and ok[k - 1]:
            motions.append(_sensor_motion_from_camera(np.linalg.inv(poses[k - 1]) @ poses[k]))
            n = min(n_in[k - 1], n_in[k])
            weights[k - 1] = float(np.clip(n / _REFERENCE_INLIERS, 0.1, 2.0))
        else:
            motions.append(None)
    return inc, motions, weights, int(np.count_nonzero(~ok))


def _figure_eight(start: FloatArray, laps: Sequence[tuple[float, int]]) -> Any:
    segs: list[tuple[float, float]] = []
    for radius, n in laps:
        for _ in range(int(n)):
            segs += [
                (2.0 * math.pi * radius, 1.0 / radius),
                (2.0 * math.pi * radius, -1.0 / radius),
            ]
    return arc_path(start, segs)


def _umbmark_iteration(
    env: Any,
    recorder: RecordingOdometry,
    cfg: CalibConfig,
    kin: Any,
    mounting: FloatArray,
    seed: int,
    vo_params: Any,
) -> tuple[Any, list[dict[str, Any]]]:
    from realitygap.core.geometry import se2_between, wrap_angle
    from realitygap.estimators.umbmark import umbmark

    L = cfg.square_side
    errors: dict[str, list[FloatArray]] = {"cw": [], "ccw": []}
    rows = []
    for direction in ("cw", "ccw"):
        for r in range(cfg.runs_per_direction):
            offset = 0.05 * r
            y0 = L / 2.0 if direction == "cw" else -L / 2.0
            start = np.array([-L / 2.0 + offset, y0 + offset, 0.0])
            recorder.kinematics = kin
            log = drive(env, recorder, SquareDriver(start, L, direction), start, seed, 4000)
            odo_end = se2_between(start, log.estimate[-1])
            measured = end_pose_from_frames(log.frames, mounting, vo_params)
            eps = measured.base_motion - odo_end
            eps[2] = wrap_angle(eps[2])
            true_end = se2_between(log.gt[0], log.gt[-1])
            errors[direction].append(eps)
            rows.append(
                {
                    "direction": direction,
                    "eps_x_mm": 1e3 * eps[0],
                    "eps_y_mm": 1e3 * eps[1],
                    "eps_theta_deg": math.degrees(eps[2]),
                    "absolute_source": measured.source,
                    "absolute_err_mm": 1e3
                    * float(np.hypot(*(measured.base_motion - true_end)[:2])),
                    "collision": log.collided,
                }
            )
    res = umbmark(errors["cw"], errors["ccw"], L, kin.wheelbase)
    return res, rows


def _test_trajectories(cfg: CalibConfig) -> dict[str, tuple[FloatArray, Any]]:
    half = cfg.straight_length / 2.0
    straight_start = np.array([-half, 0.0, 0.0])
    r = cfg.curve_radius
    curve_start = np.array([0.0, -r, 0.0])
    return {
        "straight": (straight_start, arc_path(straight_start, [(cfg.straight_length, 0.0)])),
        "curve": (curve_start, arc_path(curve_start, [(math.pi * r, 1.0 / r)])),
    }


def _sample_errors(log: DriveLog, poses: FloatArray, n: int) -> FloatArray:
    """Position errors (m) at ``n`` equally spaced times after the start."""
    idx = np.round(np.linspace(0, len(log.t) - 1, n + 1)[1:]).astype(int)
    return np.hypot(*(poses[idx, :2] - log.gt[idx, :2]).T)


def _fused_poses(log: DriveLog, kin: Any, mounting: FloatArray, vo_params: Any) -> FloatArray:
    """Calibrated odometry fused with key-frame VO motions (OdomVOFusionEKF), (N, 3)."""
    from realitygap.estimators.base import WheelTicks
    from realitygap.estimators.diffdrive_model import OdometryNoise
    from realitygap.estimators.fusion_ekf import FusionSettings, OdomVOFusionEKF
    from realitygap.estimators.vo import RGBDVisualOdometry, VOStatus, planar_motion_from_camera

    T_bc = _T_base_camera_planar(mounting)
    vo = RGBDVisualOdometry(vo_params, T_base_camera=T_bc)
    settings = FusionSettings(
        odometry_noise=OdometryNoise(
            distance_var_per_m=4e-6, heading_var_per_rad=4e-6, heading_var_per_m=4e-6
        ),
        vo_timeout=math.inf,
    )
    ekf = OdomVOFusionEKF(kin, settings)
    ekf.reset(log.gt[0])
    cov = np.diag([3e-3, 3e-3, 3e-3]) ** 2
    frame_at = {int(i): f for i, f in zip(log.frame_index, log.frames)}
    out = np.empty_like(log.gt)
    tpr = log.ticks_per_rev
    for k in range(len(log.t)):
        t = float(log.t[k])
        ekf.update(WheelTicks(t, int(log.ticks[k, 0]), int(log.ticks[k, 1]), tpr))
        frame = frame_at.get(k)
        if frame is not None:
            res = vo.update(frame)
            if res.status == VOStatus.OK.value and res.keyframe:
                motion = np.array(planar_motion_from_camera(res.T_prev_curr, T_bc))
                ekf.update_relative(motion, cov, new_keyframe=True, t=t)
            elif res.status in (VOStatus.INITIALISED.value, VOStatus.REINITIALISED.value):
                ekf.set_keyframe(t)
        out[k] = ekf.x
    out[:, 2] = np.unwrap(out[:, 2])
    return out


@experiment(
    "calib000",
    "seed 000: UMBmark + EKF odometry/camera-mount calibration in simulation, 3 iterations",
)
def calib000(ctx: RunContext) -> dict[str, Any]:
    """Seed 000's odometry + camera-mounting calibration (see the module docstring).

    Figures: ``E_d_err``, ``E_b_err`` (absolute errors of the final ``E_d = k_R/k_L``
    and ``E_b = k_b`` against the true body), ``mount_err_mm``, ``mount_err_deg``
    (planar camera mounting), ``max_err_mm_straight``, ``max_err_mm_curve``
    (largest of 20 position errors of the calibrated odometry on each test
    drive) and the same maxima for the VO-fused, UMBmark-only and nominal
    estimates. Tables: per iteration, per UMBmark run, per test drive.
    """
    from realitygap.core.geometry import wrap_angle
    from realitygap.estimators.vo import VOParams
    from realitygap.robots.diffdrive import DiffDriveParams

    cfg = CalibConfig.quick() if ctx.quick else CalibConfig()
    vo_params = VOParams(seed=ctx.seed)
    nominal_params = DiffDriveParams()
    nominal = _nominal_kinematics(nominal_params)
    true_params = cfg.reality().apply_params(nominal_params)
    true_E_d = (true_params.wheel_radius_right / true_params.wheel_radius_left) / (
        nominal.wheel_radius_right / nominal.wheel_radius_left
    )
    true_E_b = true_params.wheelbase / nominal.wheelbase
    true_mount = _mounting_of(true_params.camera)
    true_kin = _nominal_kinematics(true_params)  # sim-only floor: odometry with the true body
    mounting = _mounting_of(nominal_params.camera)
    kin = nominal
    seed = int(ctx.seed)
    t_start = time.perf_counter()

    recorder = RecordingOdometry(nominal)
    env = _make_calib_env(cfg, recorder, cfg.frame_hz)
    iteration_rows: list[dict[str, Any]] = []
    square_rows: list[dict[str, Any]] = []
    umb_only_kin = None
    prior_cov = None
    try:
        for it in range(1, cfg.iterations + 1):
            res, rows = _umbmark_iteration(env, recorder, cfg, kin, mounting, seed, vo_params)
            for row in rows:
                square_rows.append({"iteration": it, **row})
            kin_umb = kin.with_umbmark(res.E_d, res.E_b)
            if umb_only_kin is None:
                umb_only_kin = kin_umb
            f_umb = _factors(kin_umb, nominal)
            ctx.progress(
                f"calib000 iteration {it}: UMBmark E_d={f_umb[1] / f_umb[0]:.4f} "
                f"E_b={f_umb[2]:.4f} (E_max,syst {1e3 * res.E_max_syst:.1f} mm, "
                f"{rows[0]['absolute_source']})"
            )
            recorder.kinematics = kin_umb
            start = np.array([0.0, 0.0, 0.0])
            laps = cfg.first_excitation if it == 1 else cfg.excitation
            log = drive(
                env,
                recorder,
                PathFollower(_timed(_figure_eight(start, laps), cfg.excitation_speed)),
                start,
                seed,
                20_000,
            )
            inc, motions, weights, n_lost = _sensor_motions_of(log, vo_params)
            fit = fit_odometry_and_mounting(
                inc, motions, nominal, f_umb, mounting, prior_cov=prior_cov, sensor_weights=weights
            )
            # the next iteration starts from this posterior, widened so that its UMBmark seed
            # (and any error of this linearisation) can still move the estimate
            prior_cov = np.diag(np.diag(fit.cov) + np.square(_PRIOR_FLOOR))
            kin = nominal.scaled(*fit.scales)
            mounting = fit.mounting
            E_d, E_b = fit.scales[1] / fit.scales[0], fit.scales[2]
            row = {
                "iteration": it,
                "umbmark_E_d": f_umb[1] / f_umb[0],
                "umbmark_E_b": f_umb[2],
                "umbmark_E_max_syst_mm": 1e3 * res.E_max_syst,
                "ekf_k_left": fit.scales[0],
                "ekf_k_right": fit.scales[1],
                "ekf_k_wheelbase": fit.scales[2],
                "E_d": E_d,
                "E_b": E_b,
                "E_d_err": abs(E_d - true_E_d),
                "E_b_err": abs(E_b - true_E_b),
                "mount_mm": (1e3 * mounting[:2]).tolist(),
                "mount_deg": math.degrees(mounting[2]),
                "mount_err_mm": 1e3 * float(np.hypot(*(mounting[:2] - true_mount[:2]))),
                "mount_err_deg": abs(math.degrees(float(wrap_angle(mounting[2] - true_mount[2])))),
                "std_mount_mm": (1e3 * fit.std[:2]).tolist(),
                "std_mount_deg": math.degrees(float(fit.std[2])),
                "std_scales": fit.std[3:].tolist(),
                "vo_frames_lost": n_lost,
                "vo_updates": fit.n_updates,
                "vo_outliers": fit.n_outliers,
                "observable": fit.observable,
                "excitation_collision": log.collided,
            }
            iteration_rows.append(row)
            ctx.progress(
                f"calib000 iteration {it}: EKF E_d={E_d:.5f} (true {true_E_d:.5f}), "
                f"E_b={E_b:.5f} (true {true_E_b:.5f}), mount err {row['mount_err_mm']:.2f} mm / "
                f"{row['mount_err_deg']:.3f}°, k=({fit.scales[0]:.4f}, {fit.scales[1]:.4f}), "
                f"{time.perf_counter() - t_start:.0f} s"
            )

        # contrast: UMBmark alone, iterated on its own result (camera mounting left nominal)
        assert umb_only_kin is not None
        nominal_mount = _mounting_of(nominal_params.camera)
        for it in range(2, cfg.umbmark_only_iterations + 1):
            res, _ = _umbmark_iteration(
                env, recorder, cfg, umb_only_kin, nominal_mount, seed, vo_params
            )
            umb_only_kin = umb_only_kin.with_umbmark(res.E_d, res.E_b)
            f_only = _factors(umb_only_kin, nominal)
            ctx.progress(
                f"calib000 UMBmark-only iteration {it}: E_d={f_only[1] / f_only[0]:.5f} "
                f"E_b={f_only[2]:.5f}"
            )

        recorder.kinematics = kin
        test_rows = []
        figures_err: dict[str, float] = {}
        for name, (start, path) in _test_trajectories(cfg).items():
            log = drive(env, recorder, PathFollower(_timed(path)), start, seed, 20_000)
            estimates = {
                "true_geometry": log.dead_reckon(true_kin),
                "calibrated": log.dead_reckon(kin),
                "fused": _fused_poses(log, kin, mounting, vo_params),
                "umbmark_only": log.dead_reckon(umb_only_kin),
                "nominal": log.dead_reckon(nominal),
            }
            test_row: dict[str, Any] = {"trajectory": name, "collision": log.collided}
            for label, poses in estimates.items():
                err = _sample_errors(log, poses, cfg.n_positions)
                test_row[f"max_err_mm_{label}"] = 1e3 * float(err.max())
                test_row[f"mean_err_mm_{label}"] = 1e3 * float(err.mean())
                figures_err[f"{label}_{name}"] = 1e3 * float(err.max())
            test_row["length_m"] = float(np.sum(np.hypot(*np.diff(log.gt[:, :2], axis=0).T)))
            test_rows.append(test_row)
            ctx.progress(
                f"calib000 {name}: max error calibrated "
                f"{test_row['max_err_mm_calibrated']:.1f} mm, fused "
                f"{test_row['max_err_mm_fused']:.1f} mm, nominal "
                f"{test_row['max_err_mm_nominal']:.1f} mm"
            )
    finally:
        env.close()

    last = iteration_rows[-1]
    figures = {
        "E_d_err": last["E_d_err"],
        "E_b_err": last["E_b_err"],
        "mount_err_mm": last["mount_err_mm"],
        "mount_err_deg": last["mount_err_deg"],
        "max_err_mm_straight": figures_err["calibrated_straight"],
        "max_err_mm_curve": figures_err["calibrated_curve"],
        "max_err_mm_straight_fused": figures_err["fused_straight"],
        "max_err_mm_curve_fused": figures_err["fused_curve"],
        "max_err_mm_straight_umbmark_only": figures_err["umbmark_only_straight"],
        "max_err_mm_curve_umbmark_only": figures_err["umbmark_only_curve"],
        "max_err_mm_straight_nominal": figures_err["nominal_straight"],
        "max_err_mm_curve_nominal": figures_err["nominal_curve"],
        "max_err_mm_straight_true_geometry": figures_err["true_geometry_straight"],
        "max_err_mm_curve_true_geometry": figures_err["true_geometry_curve"],
    }
    return {
        "figures": figures,
        "config": {
            "true_E_d": true_E_d,
            "true_E_b": true_E_b,
            "true_wheel_diameter_factors": [cfg.left_diameter_factor, cfg.right_diameter_factor],
            "true_mount_offset_mm_deg": [
                1e3 * cfg.camera_offset[0],
                1e3 * cfg.camera_offset[1],
                math.degrees(cfg.camera_offset[2]),
            ],
            "iterations": cfg.iterations,
            "square_side_m": cfg.square_side,
            "runs_per_direction": cfg.runs_per_direction,
            "excitation_figure_eights": [list(e) for e in cfg.excitation],
            "first_excitation_figure_eights": [list(e) for e in cfg.first_excitation],
            "excitation_speed_m_s": cfg.excitation_speed,
            "frame_hz": cfg.frame_hz,
            "vo": "SIFT + GTM + RANSAC/ICP (VOParams defaults)",
            "umbmark_absolute_reference": "camera: loop closure of the last frame on the first, "
            "else chained VO; converted to the base with the current mounting estimate",
            "positions_per_trajectory": cfg.n_positions,
            "umbmark_only_iterations": cfg.umbmark_only_iterations,
            "test_trajectories": f"straight {cfg.straight_length} m; semicircle of radius "
            f"{cfg.curve_radius} m; positions at equal time steps after the start",
            "load_avg_1min": _load_average(),
            "calibrated": {
                "wheel_radius_left": kin.wheel_radius_left,
                "wheel_radius_right": kin.wheel_radius_right,
                "wheelbase": kin.wheelbase,
                "mounting_xy_yaw": [float(v) for v in mounting],
            },
        },
        "tables": {"iterations": iteration_rows, "umbmark_runs": square_rows, "test": test_rows},
        "notes": [
            "max_err_mm_* use the calibrated wheel odometry (dead reckoning from the known start); "
            "*_fused adds key-frame VO motions in OdomVOFusionEKF; *_nominal is the same drive "
            "dead-reckoned with the nominal geometry; *_umbmark_only with UMBmark alone "
            "(config umbmark_only_iterations), which cannot see the mean wheel size; the test "
            "table's *_true_geometry (odometry with the true body, sim-only) is the floor that "
            "wheel slip and contact dynamics leave",
        ],
    }


# =============================================================================
# vo
# =============================================================================


def match_precision(
    points_prev: npt.ArrayLike,
    pixels_curr: npt.ArrayLike,
    T_prev_curr: npt.ArrayLike,
    intrinsics: Any,
    tol_px: float = 3.0,
) -> npt.NDArray[np.bool_]:
    r"""Which matches agree with the true camera motion (ground-truth correspondence test).

    A match pairs a 3-D point ``p`` seen in the previous camera frame with a
    pixel ``u`` in the current image. It is correct when ``p``, moved by the
    true relative camera motion, reprojects within ``tol_px`` of ``u``:

    .. math::

        \big\| \pi\big(K\, T_{prev,curr}^{-1}\, p\big) - u \big\| \le \text{tol}_{px},

    with ``π`` the perspective division. Points that end up behind the
    camera count as wrong. The reprojection test is used rather than a 3-D
    distance because the depth noise of a far point (≈ 2 cm at 3 m) would
    otherwise reject correct matches.

    Parameters
    ----------
    points_prev : array_like, shape (N, 3)
        Matched points in the previous camera's optical frame, m.
    pixels_curr : array_like, shape (N, 2)
        Their matched pixels ``(u, v)`` in the current image.
    T_prev_curr : array_like, shape (4, 4)
        True pose of the current camera in the previous one.
    intrinsics : CameraIntrinsics
        Pinhole intrinsics of the current image.
    tol_px : float
        Reprojection tolerance, pixels.

    Returns
    -------
    ndarray of bool, shape (N,)
        True where the match is correct.

    Examples
    --------
    >>> from realitygap.estimators.base import CameraIntrinsics
    >>> K = CameraIntrinsics(320, 240, 200.0, 200.0, 160.0, 120.0)
    >>> p = np.array([[0.0, 0.0, 2.0], [0.5, 0.1, 3.0]])
    >>> u = np.array([[160.0, 120.0], [0.0, 0.0]])  # second match is wrong
    >>> match_precision(p, u, np.eye(4), K).tolist()
    [True, False]
    """
    from realitygap.core.geometry import check_finite
    from realitygap.estimators.registration import check_transform

    P = check_finite("points_prev", points_prev)
    U = check_finite("pixels_curr", pixels_curr)
    if P.ndim != 2 or P.shape[1] != 3 or U.shape != (P.shape[0], 2):
        raise ValueError(
            f"points_prev must have shape (N, 3) and pixels_curr (N, 2), got {P.shape} and {U.shape}"
        )
    if not tol_px > 0:
        raise ValueError(f"tol_px must be > 0 pixels, got {tol_px!r}")
    T = check_transform("T_prev_curr", T_prev_curr)
    R, t = T[:3, :3], T[:3, 3]
    Q = (P - t) @ R  # R^T (p - t): the point in the current camera frame
    z = Q[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = intrinsics.fx * Q[:, 0] / z + intrinsics.cx
        v = intrinsics.fy * Q[:, 1] / z + intrinsics.cy
    err = np.hypot(u - U[:, 0], v - U[:, 1])
    return np.asarray((z > 1e-6) & (err <= tol_px), dtype=bool)


def relative_pose_errors(
    gt: npt.ArrayLike, estimate: npt.ArrayLike, segment_m: float = 1.0
) -> tuple[FloatArray, FloatArray]:
    """Relative pose errors over segments of ``segment_m`` metres of true travel.

    For every sample ``i`` the first ``j`` with a true path length from ``i``
    to ``j`` of at least ``segment_m`` is found, and the estimated relative
    motion ``⊖e_i ⊕ e_j`` is compared with the true one ``⊖g_i ⊕ g_j``.

    Parameters
    ----------
    gt, estimate : array_like, shape (N, 3)
        True and estimated planar poses (m, m, rad) at the same instants.
    segment_m : float
        Segment length, m.

    Returns
    -------
    trans_err : ndarray, shape (M,)
        Translation error of each segment, m.
    rot_err : ndarray, shape (M,)
        Absolute heading error of each segment, rad.
    """
    from realitygap.core.geometry import se2_between, wrap_angle

    g = np.asarray(gt, dtype=float)
    e = np.asarray(estimate, dtype=float)
    if g.ndim != 2 or g.shape[1] != 3 or e.shape != g.shape:
        raise ValueError(f"gt and estimate must both have shape (N, 3), got {g.shape}, {e.shape}")
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(g[:, :2], axis=0).T))])
    trans, rot = [], []
    for i in range(len(s)):
        j = int(np.searchsorted(s, s[i] + segment_m))
        if j >= len(s):
            break
        dg = se2_between(g[i], g[j])
        de = se2_between(e[i], e[j])
        trans.append(float(np.hypot(*(de[:2] - dg[:2]))))
        rot.append(abs(float(wrap_angle(de[2] - dg[2]))))
    return np.array(trans), np.array(rot)


def _rigid_align_2d(src: FloatArray, dst: FloatArray) -> FloatArray:
    """``src`` (N, 2) moved by the rotation + translation that best fits it onto ``dst``."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    H = (src - mu_s).T @ (dst - mu_d)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, d]) @ U.T
    return (src - mu_s) @ R.T + mu_d


@dataclass(frozen=True)
class _PairFeatures:
    pixels: FloatArray
    points: FloatArray
    descriptors: Any


def _features(detector: Any, frame: Any, params: Any) -> _PairFeatures:
    """Keypoints, their back-projected 3-D points (nan without depth) and descriptors."""
    import cv2

    gray = cv2.cvtColor(np.asarray(frame.rgb), cv2.COLOR_RGB2GRAY)
    kps, desc = detector.detectAndCompute(gray, None)
    pixels = np.array([kp.pt for kp in kps], dtype=float).reshape(-1, 2)
    intr = frame.intrinsics
    depth = np.asarray(frame.depth, dtype=float)
    # the 2×2 neighbourhood rule of the VO front end: valid, in range, not on a depth edge
    u0 = np.clip(np.floor(pixels[:, 0]).astype(int), 0, intr.width - 2)
    v0 = np.clip(np.floor(pixels[:, 1]).astype(int), 0, intr.height - 2)
    z4 = np.stack([depth[v0, u0], depth[v0, u0 + 1], depth[v0 + 1, u0], depth[v0 + 1, u0 + 1]])
    with np.errstate(invalid="ignore"):
        zmin, zmax = z4.min(axis=0), z4.max(axis=0)
        good = (
            np.all(np.isfinite(z4), axis=0)
            & (zmin >= params.depth_min_m)
            & (zmax <= params.depth_max_m)
            & (zmax - zmin <= params.depth_edge_ratio * zmin)
        )
    z = np.where(good, z4.mean(axis=0), np.nan)
    points = np.stack(
        [(pixels[:, 0] - intr.cx) * z / intr.fx, (pixels[:, 1] - intr.cy) * z / intr.fy, z], 1
    )
    return _PairFeatures(pixels, points, desc)


def _gtm_precision_pair(
    prev: _PairFeatures,
    curr: _PairFeatures,
    matcher: Any,
    params: Any,
    T_prev_curr: FloatArray,
    intrinsics: Any,
) -> tuple[int, int, int, int]:
    """(ratio-test matches, correct ones, kept by GTM, correct ones) for one frame pair."""
    from realitygap.estimators.gtm import gtm_filter

    if prev.descriptors is None or curr.descriptors is None or len(prev.pixels) < 2:
        return 0, 0, 0, 0
    knn = matcher.knnMatch(curr.descriptors, prev.descriptors, k=2)
    pairs = [
        (m[0].trainIdx, m[0].queryIdx)
        for m in knn
        if len(m) == 2 and m[0].distance < params.ratio * m[1].distance
    ]
    if len(pairs) < 3:
        return 0, 0, 0, 0
    i_prev, i_curr = np.array(pairs).T
    has_depth = np.all(np.isfinite(prev.points[i_prev]), axis=1)
    i_prev, i_curr = i_prev[has_depth], i_curr[has_depth]
    if len(i_prev) < 3:
        return 0, 0, 0, 0
    correct = match_precision(prev.points[i_prev], curr.pixels[i_curr], T_prev_curr, intrinsics)
    keep = gtm_filter(prev.pixels[i_prev], curr.pixels[i_curr], tolerance=params.gtm_tolerance)
    return len(correct), int(correct.sum()), int(keep.sum()), int(correct[keep].sum())


def _load_average() -> float | None:
    """1-minute load average of the machine (timings are wall-clock), if known."""
    import os

    try:
        return float(os.getloadavg()[0])
    except (AttributeError, OSError):
        return None


def _vo_room(ctx: RunContext, panelled: bool, seconds: float) -> dict[str, Any]:
    """Drive a figure-eight in a WheeledNav room, rendering frames at 10 Hz."""
    import gymnasium as gym

    import realitygap  # noqa: F401
    from realitygap.envs.layouts import random_layout
    from realitygap.robots.diffdrive import DiffDriveParams

    half = 2.5 if panelled else 3.5
    radius = 0.9 if panelled else 1.3
    start = np.array([0.0, 0.0, 0.0])
    path = _figure_eight(start, ((radius, 2),))  # longer than the drive; cut at `seconds`
    rng = np.random.default_rng(ctx.seed)
    params = DiffDriveParams()
    if panelled:
        obstacles = calibration_room(half)
    else:
        keep = [tuple(p) for p in path.xy[:: max(1, len(path.xy) // 80)]]
        obstacles = random_layout(
            rng,
            8,
            half,
            keep_clear=keep,
            clear_radius=params.body_radius + 0.25,
            robot_radius=params.body_radius,
        )
    nominal = _nominal_kinematics(params)
    recorder = RecordingOdometry(nominal)
    env = gym.make(
        "realitygap/WheeledNav-v0",
        sensor_mode="image",
        estimator=recorder,
        obstacles=obstacles,
        room_half_size=half,
        start=tuple(start),
        goal=(0.0, 0.5, 0.0),
        camera_hz=10.0,
        scan_hz=10.0,
        terminate_on_success=False,
    )
    try:
        log = drive(
            env,
            recorder,
            PathFollower(_timed(path, v_max=0.3)),
            start,
            int(ctx.seed),
            int(round(seconds * 20.0)),
        )
    finally:
        env.close()
    return {"log": log, "mounting": params.camera.T_base_camera(), "obstacles": len(obstacles)}


def _evaluate_vo(log: DriveLog, T_base_camera: FloatArray, params: Any) -> dict[str, Any]:
    """Run VO over the frames of ``log`` and score it against ground truth."""
    from realitygap.estimators.vo import RGBDVisualOdometry

    vo = RGBDVisualOdometry(params, T_base_camera=T_base_camera)
    vo.reset(log.T_world_camera[0])
    results = []
    elapsed = 0.0
    for frame in log.frames:
        t0 = time.perf_counter()
        results.append(vo.update(frame))
        elapsed += time.perf_counter() - t0
    est = np.array([r.pose for r in results])
    est[:, 2] = np.unwrap(est[:, 2])
    gt = log.gt[log.frame_index]
    err = np.hypot(*(est[:, :2] - gt[:, :2]).T)
    aligned = _rigid_align_2d(est[:, :2], gt[:, :2])
    err_rigid = np.hypot(*(aligned - gt[:, :2]).T)
    trans, rot = relative_pose_errors(gt, est, 1.0)
    # precision of the final (RANSAC/ICP) inliers against the true key-frame → frame motion
    kf = 0
    n_in = n_ok = 0
    for k, r in enumerate(results):
        if r.status == "ok" and len(r.inlier_points_prev):
            T_true = np.linalg.inv(log.T_world_camera[kf]) @ log.T_world_camera[k]
            good = match_precision(
                r.inlier_points_prev, r.inlier_pixels_curr, T_true, log.frames[k].intrinsics
            )
            n_in += len(good)
            n_ok += int(good.sum())
        if r.keyframe:
            kf = k
    path_len = float(np.sum(np.hypot(*np.diff(gt[:, :2], axis=0).T)))
    return {
        "ate_cm": 100.0 * float(np.sqrt(np.mean(err**2))),
        "ate_cm_rigid": 100.0 * float(np.sqrt(np.mean(err_rigid**2))),
        "final_err_cm": 100.0 * float(err[-1]),
        "rpe_cm_per_m": 100.0 * float(np.mean(trans)) if len(trans) else float("nan"),
        "rpe_deg_per_m": math.degrees(float(np.mean(rot))) if len(rot) else float("nan"),
        "vo_fps": len(results) / elapsed,
        "ransac_inlier_precision": n_ok / n_in if n_in else float("nan"),
        "frames_failed": int(sum(not r.ok for r in results)),
        "frames": len(results),
        "mean_inliers": float(np.mean([r.n_inliers for r in results])),
        "path_m": path_len,
    }


def _gtm_precision(log: DriveLog, params: Any, every: int = 2) -> dict[str, float]:
    """Precision of ratio-test matches and of the matches GTM keeps, consecutive frames."""
    import cv2

    detector = cv2.SIFT.create(nfeatures=params.max_features)
    matcher = cv2.BFMatcher(cv2.NORM_L2)
    totals = np.zeros(4)
    for k in range(1, len(log.frames), every):
        prev = _features(detector, log.frames[k - 1], params)
        curr = _features(detector, log.frames[k], params)
        T_true = np.linalg.inv(log.T_world_camera[k - 1]) @ log.T_world_camera[k]
        totals += _gtm_precision_pair(prev, curr, matcher, params, T_true, log.frames[k].intrinsics)
    n_ratio, ok_ratio, n_gtm, ok_gtm = totals
    return {
        "ratio_match_precision": ok_ratio / n_ratio if n_ratio else float("nan"),
        "gtm_inlier_precision": ok_gtm / n_gtm if n_gtm else float("nan"),
        "gtm_kept_fraction": n_gtm / n_ratio if n_ratio else float("nan"),
    }


@experiment(
    "vo",
    "RGB-D visual odometry on a 60 s drive through the textured room: ATE, RPE, fps, GTM precision",
)
def vo(ctx: RunContext) -> dict[str, Any]:
    """RGB-D VO on 60 s (quick: 15 s) of driving, in the panelled room and the env's own room.

    Figures without suffix: the panelled room (:func:`calibration_room`), SIFT.
    ``*_orb``: ORB on the same frames; ``*_default_room``: the env's default
    room, whose walls each carry one texture stretched over 7 m.
    """
    from realitygap.estimators.vo import VOParams

    seconds = 15.0 if ctx.quick else 60.0
    rows = []
    figures: dict[str, float] = {}
    for room, panelled in (("default", False), ("panelled", True)):
        drive_out = _vo_room(ctx, panelled, seconds)
        log: DriveLog = drive_out["log"]
        ctx.progress(
            f"vo {room} room: drove {log.t[-1]:.0f} s, {len(log.frames)} frames, "
            f"collision={log.collided}"
        )
        for detector in ("sift", "orb"):
            params = VOParams(detector=detector, seed=int(ctx.seed))
            row = {"room": room, "detector": detector, "obstacles": drive_out["obstacles"]}
            row.update(_evaluate_vo(log, drive_out["mounting"], params))
            if detector == "sift":
                row.update(_gtm_precision(log, params))
            rows.append(row)
            ctx.progress(
                f"vo {room}/{detector}: ATE {row['ate_cm']:.1f} cm, RPE {row['rpe_cm_per_m']:.2f} "
                f"cm/m {row['rpe_deg_per_m']:.2f} °/m, {row['vo_fps']:.0f} fps"
            )
    by = {(r["room"], r["detector"]): r for r in rows}
    head, orb = by[("panelled", "sift")], by[("panelled", "orb")]
    bare, bare_orb = by[("default", "sift")], by[("default", "orb")]
    figures = {
        "ate_cm": head["ate_cm"],
        "ate_cm_rigid": head["ate_cm_rigid"],
        "rpe_cm_per_m": head["rpe_cm_per_m"],
        "rpe_deg_per_m": head["rpe_deg_per_m"],
        "vo_fps": head["vo_fps"],
        "gtm_inlier_precision": head["gtm_inlier_precision"],
        "ratio_match_precision": head["ratio_match_precision"],
        "ransac_inlier_precision": head["ransac_inlier_precision"],
        "ate_cm_orb": orb["ate_cm"],
        "rpe_cm_per_m_orb": orb["rpe_cm_per_m"],
        "vo_fps_orb": orb["vo_fps"],
        "ate_cm_default_room": bare["ate_cm"],
        "rpe_cm_per_m_default_room": bare["rpe_cm_per_m"],
        "frames_failed_default_room": bare["frames_failed"],
        "frames_default_room": bare["frames"],
        "ate_cm_default_room_orb": bare_orb["ate_cm"],
        "gtm_inlier_precision_default_room": bare["gtm_inlier_precision"],
    }
    return {
        "figures": figures,
        "config": {
            "seconds": seconds,
            "resolution": [320, 240],
            "camera_hz": 10,
            "drive": "figure-eight tracked on wheel odometry (Kanayama), 0.3 m/s",
            "room": "WheeledNav-v0, image mode, half-size 2.5 m, walls lined with 0.5 m textured "
            "panels (calibration_room) plus four pieces of furniture; figures without suffix",
            "default_room": "*_default_room: the env's own room (half-size 3.5 m, one texture "
            "stretched over each wall) with 8 random obstacles kept off the path",
            "load_avg_1min": _load_average(),
            "ate": "RMS planar position error, VO started at the true first pose (no further "
            "alignment); ate_cm_rigid after a best-fit rotation + translation",
            "rpe": "mean over all 1 m segments of true travel",
            "correct_match": "3-D point of the previous frame, moved by the true camera motion, "
            "reprojects within 3 px of the matched keypoint",
            "vo_fps": "RGBDVisualOdometry.update only (rendering excluded)",
        },
        "tables": {"runs": rows},
    }


# =============================================================================
# umbmark-real
# =============================================================================


def _session_time(session_id: str) -> float | None:
    """Recording time (days since 2000) from an id ``DDMMYYYYhhmm``, or ``None``."""
    import datetime as dt

    try:
        when = dt.datetime.strptime(session_id, "%d%m%Y%H%M")
    except ValueError:
        return None
    return (when - dt.datetime(2000, 1, 1)).total_seconds() / 86400.0


def _same_period(session_id: str, calibrations: Sequence[Any]) -> list[Any]:
    """The square calibrations of the day of the square session recorded closest in time.

    Falls back to all of them when the recording times are unknown.
    """
    t = _session_time(session_id)
    times = [_session_time(c.session_id) for c in calibrations]
    if t is None or any(x is None for x in times):
        return list(calibrations)
    nearest = int(np.argmin([abs(float(x) - t) for x in times]))  # type: ignore[arg-type]
    day = calibrations[nearest].session_id[:8]
    return [c for c in calibrations if c.session_id[:8] == day]


def umbmark_real_calibration(
    root: Any,
) -> tuple[list[Any], list[Any]]:
    """UMBmark per square session below ``root`` and the other (held-out) sessions.

    Parameters
    ----------
    root : path-like
        Folder holding OptiOdom session folders (any depth).

    Returns
    -------
    calibrations : list of SessionCalibration
        One per square session.
    held_out : list of OptiOdomSession
        Every session that is not a square session.

    Raises
    ------
    ValueError
        If ``root`` holds no square session or no other session.
    """
    from realitygap.calibrate import calibrate_session
    from realitygap.diagnosis.importers.optiodom import PathType, find_sessions, read_session

    sessions = [read_session(p) for p in find_sessions(root)]
    squares = [s for s in sessions if s.path_type is PathType.SQUARE]
    held_out = [s for s in sessions if s.path_type is not PathType.SQUARE]
    if not squares:
        raise ValueError(f"{root}: no square (UMBmark) session to calibrate on")
    if not held_out:
        raise ValueError(f"{root}: no circular, Ivanjko or free-path session to check on")
    return [calibrate_session(s.path) for s in squares], held_out


@experiment(
    "umbmark-real",
    "UMBmark on the real OptiOdom squares, scored on held-out circular/Ivanjko/free sessions",
    data_subdir="optiodom_diffdrive",
)
def umbmark_real(ctx: RunContext) -> dict[str, Any]:
    """UMBmark on the real square sessions, scored on the held-out sessions' ground truth.

    Each held-out session keeps its own nominal kinematics; the calibration of
    the same period (see :func:`_same_period`) enters as ``E_d`` and the
    dimensionless wheelbase ``b/D̄``.
    """
    from realitygap.calibrate import pool_calibrations

    root = ctx.data_subdir("optiodom_diffdrive")
    calibrations, held_out = umbmark_real_calibration(root)
    pooled_all = pool_calibrations(calibrations)
    ctx.progress(
        f"umbmark-real: {len(calibrations)} square sessions, pooled E_d={pooled_all.E_d:.5f}, "
        f"b/D={pooled_all.b_over_D:.4f}; {len(held_out)} held-out sessions"
    )
    run_rows = []
    for session in held_out:
        nominal = session.kinematics()
        period = pool_calibrations(_same_period(session.session_id, calibrations))
        variants = {
            "nominal": nominal,
            "calibrated": period.kinematics_for(nominal),
            "pooled": pooled_all.kinematics_for(nominal),
        }
        for run in session.runs:
            row: dict[str, Any] = {
                "session": session.session_id,
                "path_type": session.path_type.value,
                "run": run.index,
                "length_m": float(np.sum(np.hypot(*np.diff(run.gt_pose[:, :2], axis=0).T))),
                "calibrated_from": list(period.sessions),
            }
            for label, kin in variants.items():
                odo = run.odometry(kin)
                err = np.hypot(*(odo[:, :2] - run.gt_pose[:, :2]).T)
                row[f"end_err_cm_{label}"] = 100.0 * float(err[-1])
                row[f"ate_cm_{label}"] = 100.0 * float(np.sqrt(np.mean(err**2)))
            run_rows.append(row)

    def stat(rows: list[dict[str, Any]], key: str, fn: Any) -> float:
        return float(fn([r[key] for r in rows]))

    type_rows = []
    for kind in [*sorted({r["path_type"] for r in run_rows}), "all"]:
        rows = run_rows if kind == "all" else [r for r in run_rows if r["path_type"] == kind]
        entry: dict[str, Any] = {"path_type": kind, "runs": len(rows)}
        for label in ("nominal", "calibrated", "pooled"):
            for metric in ("end_err_cm", "ate_cm"):
                key = f"{metric}_{label}"
                entry[f"mean_{key}"] = stat(rows, key, np.mean)
                entry[f"median_{key}"] = stat(rows, key, np.median)
        type_rows.append(entry)
        ctx.progress(
            f"umbmark-real {kind}: median end error {entry['median_end_err_cm_nominal']:.1f} cm "
            f"nominal → {entry['median_end_err_cm_calibrated']:.1f} cm calibrated ({len(rows)} runs)"
        )
    total = type_rows[-1]
    circ = next((r for r in type_rows if r["path_type"] == "circular"), None)
    figures: dict[str, float] = {
        "heldout_end_err_cm_nominal": total["mean_end_err_cm_nominal"],
        "heldout_end_err_cm_calibrated": total["mean_end_err_cm_calibrated"],
        "heldout_ate_cm_nominal": total["mean_ate_cm_nominal"],
        "heldout_ate_cm_calibrated": total["mean_ate_cm_calibrated"],
        "E_d": pooled_all.E_d,
        "E_b": pooled_all.E_b_for(0.084, 0.200),
        "heldout_end_err_cm_pooled": total["mean_end_err_cm_pooled"],
        "heldout_runs": float(total["runs"]),
    }
    if circ is not None:
        figures["circular_median_end_err_mm_nominal"] = 10.0 * circ["median_end_err_cm_nominal"]
        figures["circular_median_end_err_mm_calibrated"] = (
            10.0 * circ["median_end_err_cm_calibrated"]
        )
    return {
        "figures": figures,
        "config": {
            "data": str(root),
            "square_sessions": [c.session_id for c in calibrations],
            "heldout_sessions": [s.session_id for s in held_out],
            "calibration_transfer": (
                "each held-out session keeps its own nominal D and b from its metadata; the "
                "UMBmark result enters as E_d and the dimensionless corrected wheelbase b/D "
                "(what UMBmark observes), i.e. E_b = (b/D)·D_nominal/b_nominal of that session. "
                "'calibrated': the square sessions of the day of the square session recorded "
                "closest in time (same period), pooled; 'pooled': all square sessions"
            ),
            "E_d_E_b": "all square sessions pooled, relative to D = 0.084 m, b = 0.200 m",
            "end_err": "distance between the dead-reckoned and the ground-truth end position, "
            "start frame",
            "ate": "RMS position error over the run, both trajectories from the same start "
            "pose (no further alignment)",
        },
        "tables": {
            "calibrations": [c.to_dict() for c in calibrations],
            "path_types": type_rows,
            "runs": run_rows,
        },
    }
