"""Synthetic recordings of the climbing robot on the blade.

* :func:`synthesise_recording` — a ground-truth trajectory on the blade surface (a
  closed excitation loop for the global initialisation, then a lawn-mower sweep),
  and the IMU, visual relative-motion and tether measurements generated from it
  with realistic noise (:class:`NoiseModel`), as a :class:`ClimbRecording`;
* :func:`render_planar_view` — an image of a textured plane for the image front-end.

:mod:`realitygap.robots.climb_evaluation` scores the localisation on such recordings.
Frames: ``cad`` (blade frame, z up), ``world`` (VIO frame).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TypeAlias

import cv2
import numpy as np
import numpy.typing as npt
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from realitygap.core.geometry import so3_exp, so3_log
from realitygap.estimators.climb.measurements import (
    CameraFrame,
    ImuSample,
    RelativeMotion,
    TetherReading,
)
from realitygap.estimators.climb.vio import VioConfig
from realitygap.robots.blade_geometry import BladeParams, BladeSurface, deformed

FloatArray = npt.NDArray[np.float64]
Measurement: TypeAlias = ImuSample | CameraFrame | RelativeMotion | TetherReading

__all__ = [
    "ClimbRecording",
    "ClimbScenario",
    "NoiseModel",
    "TruthTrajectory",
    "render_planar_view",
    "synthesise_recording",
]


# --------------------------------------------------------------------------- scenario


@dataclass(frozen=True)
class NoiseModel:
    """Sensor noise of the synthetic measurements (SI units).

    Attributes
    ----------
    gyro_noise_density, accel_noise_density
        White noise, rad/s/√Hz and m/s²/√Hz.
    gyro_bias_walk, accel_bias_walk
        Bias random walk, rad/s/√s and m/s²/√s.
    gyro_bias_sigma, accel_bias_sigma
        Standard deviation of the initial biases, rad/s and m/s².
    visual_rotation_sigma
        Per-frame rotation noise of the visual relative motion, rad.
    visual_translation_sigma, visual_translation_rel
        Per-frame translation noise: ``sigma + rel · |step|``, m.
    visual_scale_sigma, visual_scale_tau
        Slowly varying scale error of the visual translation (camera height
        uncertainty): Ornstein–Uhlenbeck with this stationary σ and time constant s.
    visual_dropout
        Probability that a frame's visual motion is lost.
    tether_sigma
        Tether length noise, m.
    tether_slack_rate
        Slack episodes per second (each ~1 s, +2…5 cm).
    tether_invalid
        Probability that a reading is flagged invalid.
    """

    gyro_noise_density: float = 0.005
    accel_noise_density: float = 0.05
    gyro_bias_walk: float = 1e-4
    accel_bias_walk: float = 1e-3
    gyro_bias_sigma: float = 0.01
    accel_bias_sigma: float = 0.05
    visual_rotation_sigma: float = 2e-3
    visual_translation_sigma: float = 2e-4
    visual_translation_rel: float = 0.01
    visual_scale_sigma: float = 0.005
    visual_scale_tau: float = 20.0
    visual_dropout: float = 0.0
    tether_sigma: float = 2e-3
    tether_slack_rate: float = 0.0
    tether_invalid: float = 0.0


@dataclass(frozen=True)
class ClimbScenario:
    """A synthetic run on the blade.

    The path is given in chart coordinates ``(x, ξ)``: span position (m) and chord
    station ξ on the suction side (0 leading edge, 1 trailing edge). The first
    ``init_waypoints`` form the excitation loop of the global initialisation, the
    rest the sweep; corners are rounded with ``corner_radius``.

    Attributes
    ----------
    blade
        Blade geometry.
    surface_deviation
        Largest deviation of the real surface from the CAD surface, m.
    h
        Height of the body origin above the surface, m.
    anchor_cad
        Tether anchor in the CAD frame, m.
    speed
        Cruise speed, m/s.
    imu_rate, camera_rate
        Hz; tether readings come with the camera frames.
    static_duration
        Seconds at rest before moving (≥ the VIO's static initialisation).
    init_waypoints, sweep_waypoints
        Chart waypoints ``(x [m], ξ)``.
    corner_radius
        m.
    noise
        :class:`NoiseModel`.
    """

    blade: BladeParams = field(default_factory=BladeParams)
    surface_deviation: float = 0.0
    h: float = 0.08
    anchor_cad: tuple[float, float, float] = (-0.5, 0.2, 0.9)
    speed: float = 0.15
    imu_rate: float = 200.0
    camera_rate: float = 10.0
    static_duration: float = 2.0
    init_waypoints: tuple[tuple[float, float], ...] = (
        (1.5, 0.12),
        (2.3, 0.12),
        (2.3, 0.5),
        (1.5, 0.5),
        (1.5, 0.12),
    )
    sweep_waypoints: tuple[tuple[float, float], ...] = (
        (6.5, 0.12),
        (6.5, 0.24),
        (1.5, 0.24),
        (1.5, 0.36),
        (6.5, 0.36),
        (6.5, 0.48),
        (1.5, 0.48),
        (1.5, 0.60),
        (6.5, 0.60),
    )
    corner_radius: float = 0.1
    noise: NoiseModel = field(default_factory=NoiseModel)

    def __post_init__(self) -> None:
        for name in ("h", "speed", "imu_rate", "camera_rate", "static_duration", "corner_radius"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"ClimbScenario.{name} must be positive, got {value!r}")
        if self.surface_deviation < 0:
            raise ValueError(
                f"ClimbScenario.surface_deviation must be ≥ 0 m, got {self.surface_deviation!r}"
            )
        if self.imu_rate < 5 * self.camera_rate:
            raise ValueError("ClimbScenario.imu_rate must be at least 5 × camera_rate")
        if len(self.init_waypoints) < 3:
            raise ValueError("ClimbScenario.init_waypoints needs at least 3 points")
        for x, xi in self.init_waypoints + self.sweep_waypoints:
            if not (0 < x < self.blade.length and 0.02 <= xi <= 0.95):
                raise ValueError(
                    f"waypoint ({x}, {xi}) must lie on the blade: 0 < x < {self.blade.length} m, "
                    "0.02 ≤ ξ ≤ 0.95"
                )


# --------------------------------------------------------------------------- truth


def _fillet_path(points: FloatArray, radius: float, step: float) -> tuple[FloatArray, list[int]]:
    """Dense samples of a polyline with rounded corners (2-D), and the sample index
    nearest each waypoint's corner."""
    out: list[FloatArray] = [points[0][None, :]]
    marks = [0]
    count = 1
    cur = points[0]
    for k in range(1, len(points)):
        b = points[k]
        if k == len(points) - 1:
            seg_end = b
            arc = None
        else:
            a, c = points[k - 1], points[k + 1]
            d1 = (b - a) / np.linalg.norm(b - a)
            d2 = (c - b) / np.linalg.norm(c - b)
            cosang = float(np.clip(d1 @ d2, -1.0, 1.0))
            phi = math.acos(cosang)
            if phi < 1e-6:
                seg_end, arc = b, None
            else:
                tan_half = math.tan(phi / 2)
                r = min(radius, 0.49 * min(np.linalg.norm(b - a), np.linalg.norm(c - b)) / tan_half)
                T = r * tan_half
                seg_end = b - T * d1
                turn = 1.0 if d1[0] * d2[1] - d1[1] * d2[0] > 0 else -1.0
                normal = turn * np.array([-d1[1], d1[0]])
                centre = seg_end + r * normal
                n_arc = max(int(math.ceil(r * phi / step)), 2)
                ang0 = math.atan2(seg_end[1] - centre[1], seg_end[0] - centre[0])
                angs = ang0 + turn * np.linspace(0.0, phi, n_arc + 1)[1:]
                arc = centre + r * np.stack([np.cos(angs), np.sin(angs)], axis=1)
        n_seg = max(int(math.ceil(np.linalg.norm(seg_end - cur) / step)), 1)
        lam = np.linspace(0.0, 1.0, n_seg + 1)[1:]
        out.append(cur + lam[:, None] * (seg_end - cur))
        count += n_seg
        if arc is not None:
            out.append(arc)
            marks.append(count + len(arc) // 2)
            count += len(arc)
            cur = arc[-1]
        else:
            marks.append(count - 1)
            cur = seg_end
    pts = np.concatenate(out)
    keep = np.r_[True, np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9]
    new_index = np.cumsum(keep) - 1
    return pts[keep], [int(new_index[m]) for m in marks]


class TruthTrajectory:
    """Smooth body trajectory on a blade surface (CAD frame).

    The body origin is ``h`` above the surface along its normal, the body z-axis is
    the normal and the body x-axis the direction of travel; the robot rests for
    ``static_duration`` s, then accelerates (cosine ramp) to ``speed``, and stops
    smoothly at the end.

    Parameters
    ----------
    surface
        The (real) blade surface.
    waypoints : (K, 2)
        Chart waypoints ``(x [m], ξ)``.
    h, speed, static_duration, corner_radius
        m, m/s, s, m.
    """

    def __init__(
        self,
        surface: BladeSurface,
        waypoints: npt.ArrayLike,
        *,
        h: float,
        speed: float,
        static_duration: float,
        corner_radius: float,
        ramp: float = 1.0,
    ) -> None:
        self.surface = surface
        self.h = h
        self.speed = speed
        self.static_duration = static_duration
        self.ramp = ramp
        c_ref = surface.params.root_chord
        self._c_ref = c_ref
        wp = np.asarray(waypoints, dtype=float)
        chart = np.c_[wp[:, 0], wp[:, 1] * c_ref]
        dense, marks = _fillet_path(chart, corner_radius, 0.002)
        self._chart_knots = chart
        p = self._chart_position(dense[:, 0], dense[:, 1])
        arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
        self._sx = CubicSpline(arc, dense[:, 0])
        self._sw = CubicSpline(arc, dense[:, 1])
        self.length = float(arc[-1])
        self.waypoint_arclength = arc[marks]
        """Arclength (m) at which the path passes each waypoint's corner."""
        cruise = max(self.length - speed * ramp, 0.0) / speed
        self.motion_duration = 2 * ramp + cruise
        self.duration = static_duration + self.motion_duration + 1.0

    def _chart_position(self, x: FloatArray, w: FloatArray) -> FloatArray:
        s, u = self._su(x, w)
        return self.surface.position(s, u) + self.h * self.surface.normal(s, u)

    def _su(self, x: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:
        xi = np.clip(w / self._c_ref, 1e-6, 1.0)
        u = 1.0 - np.arccos(np.sqrt(xi)) / np.pi
        return x / self.surface.params.length, u

    def arclength(self, t: npt.ArrayLike) -> FloatArray:
        """Distance travelled at time(s) ``t``, m."""
        tau = np.asarray(t, dtype=float) - self.static_duration
        v, T = self.speed, self.ramp
        d_ramp = v * T / 2
        total = self.length
        t_dec = self.motion_duration - T
        s = np.where(
            tau <= 0,
            0.0,
            np.where(
                tau <= T,
                v / 2 * (tau - T / np.pi * np.sin(np.pi * tau / T)),
                d_ramp + v * (tau - T),
            ),
        )
        tau_d = tau - t_dec
        dec = total - d_ramp + v / 2 * (tau_d + T / np.pi * np.sin(np.pi * tau_d / T))
        s = np.where(tau > t_dec, np.minimum(dec, total), s)
        s = np.where(tau >= self.motion_duration, total, s)
        return np.clip(s, 0.0, total)

    def time_at_arclength(self, sigma: float) -> float:
        """First time at which ``sigma`` m have been travelled, s."""
        lo, hi = self.static_duration, self.static_duration + self.motion_duration
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if float(self.arclength(mid)) < sigma:
                lo = mid
            else:
                hi = mid
        return hi

    def _at_arclength(self, sigma: FloatArray) -> tuple[FloatArray, FloatArray]:
        x, w = self._sx(sigma), self._sw(sigma)
        s, u = self._su(x, w)
        n = self.surface.normal(s, u)
        p = self.surface.position(s, u) + self.h * n
        eps = 1e-4
        sp = np.clip(sigma + eps, 0, self.length)
        sm = np.clip(sigma - eps, 0, self.length)
        tangent = self._chart_position(self._sx(sp), self._sw(sp)) - self._chart_position(
            self._sx(sm), self._sw(sm)
        )
        tangent = tangent - np.sum(tangent * n, axis=-1, keepdims=True) * n
        tangent /= np.linalg.norm(tangent, axis=-1, keepdims=True)
        y = np.cross(n, tangent)
        R = np.stack([tangent, y, n], axis=-1)
        return p, R

    def pose(self, t: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Position(s) (..., 3) m and rotation(s) :math:`R_{gb}` (..., 3, 3) at ``t``."""
        return self._at_arclength(self.arclength(t))

    def velocity(self, t: npt.ArrayLike, eps: float = 1e-3) -> FloatArray:
        """Velocity (..., 3) in m/s (central differences)."""
        t = np.asarray(t, dtype=float)
        return (self.pose(t + eps)[0] - self.pose(t - eps)[0]) / (2 * eps)


# --------------------------------------------------------------------------- recording


@dataclass(frozen=True, eq=False)
class ClimbRecording:
    """Measurements with ground truth; the input of :func:`.evaluate_recording`.

    Attributes
    ----------
    measurements
        Time-ordered :class:`.ImuSample`, :class:`.RelativeMotion` /
        :class:`.CameraFrame` and :class:`.TetherReading`.
    truth_t : (N,)
        Times of the ground truth, s (increasing).
    truth_position : (N, 3)
        Body origin in the CAD frame, m.
    truth_rotation : (N, 3, 3)
        :math:`R_{gb}`.
    init_path_length
        Length of the excitation path for the global initialisation, m.
    anchor_cad : (3,)
        Tether anchor (CAD frame), m.
    h
        Body height above the surface, m.
    """

    measurements: tuple[Measurement, ...]
    truth_t: FloatArray
    truth_position: FloatArray
    truth_rotation: FloatArray
    init_path_length: float
    anchor_cad: FloatArray
    h: float

    def truth_at(self, t: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Interpolated ground truth (position, rotation) at time(s) ``t``."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        p = np.stack([np.interp(t, self.truth_t, self.truth_position[:, k]) for k in range(3)], -1)
        idx = np.clip(np.searchsorted(self.truth_t, t), 1, len(self.truth_t) - 1)
        t0, t1 = self.truth_t[idx - 1], self.truth_t[idx]
        lam = np.clip((t - t0) / np.maximum(t1 - t0, 1e-12), 0, 1)
        R = np.empty((len(t), 3, 3))
        for k in range(len(t)):
            R0, R1 = self.truth_rotation[idx[k] - 1], self.truth_rotation[idx[k]]
            R[k] = R0 @ so3_exp(lam[k] * so3_log(R0.T @ R1))
        return p, R


def synthesise_recording(
    scenario: ClimbScenario,
    rng: np.random.Generator,
    *,
    vio_config: VioConfig | None = None,
    sweep: bool = True,
) -> ClimbRecording:
    """Ground truth on the (possibly deformed) blade and noisy measurements from it.

    IMU samples hold over ``[t_k, t_{k+1})``: the rate is the one that turns
    :math:`R(t_k)` into :math:`R(t_{k+1})`, the specific force the constant one that
    reproduces the velocity change (so the pre-integration model is exact before
    noise). Visual motions are the true camera motions between frames with noise, a
    slowly varying scale error and dropouts; tether readings the true distance to the
    anchor with noise and slack episodes.

    Parameters
    ----------
    scenario
        :class:`ClimbScenario`.
    rng
        Random generator (surface deviation and all noise).
    vio_config
        Supplies the camera mount :math:`T_{bc}`.
    sweep
        ``False`` stops after the excitation loop (short runs for tests).
    """
    cfg = VioConfig() if vio_config is None else vio_config
    nm = scenario.noise
    surface = (
        deformed(scenario.blade, scenario.surface_deviation, rng)
        if scenario.surface_deviation > 0
        else BladeSurface(scenario.blade)
    )
    waypoints = scenario.init_waypoints + (scenario.sweep_waypoints if sweep else ())
    traj = TruthTrajectory(
        surface,
        waypoints,
        h=scenario.h,
        speed=scenario.speed,
        static_duration=scenario.static_duration,
        corner_radius=scenario.corner_radius,
    )
    init_len = float(traj.waypoint_arclength[len(scenario.init_waypoints) - 1])
    # IMU
    dt = 1.0 / scenario.imu_rate
    t_imu = np.arange(0.0, traj.duration, dt)
    t_edges = np.r_[t_imu, t_imu[-1] + dt]
    _, R_e = traj.pose(t_edges)
    v_e = traj.velocity(t_edges)
    rel = np.einsum("kji,kjl->kil", R_e[:-1], R_e[1:])
    omega = Rotation.from_matrix(rel).as_rotvec() / dt
    g = np.array([0.0, 0.0, -cfg.gravity])
    dv = v_e[1:] - v_e[:-1] - g * dt
    accel = np.empty_like(omega)
    for k in range(len(t_imu)):
        theta = omega[k] * dt
        a = float(np.linalg.norm(theta))
        K = np.array([[0, -theta[2], theta[1]], [theta[2], 0, -theta[0]], [-theta[1], theta[0], 0]])
        if a < 1e-4:
            g1 = np.eye(3) + K / 2 + K @ K / 6
        else:
            g1 = np.eye(3) + (1 - math.cos(a)) / a**2 * K + (a - math.sin(a)) / a**3 * K @ K
        accel[k] = np.linalg.solve(R_e[k] @ g1 * dt, dv[k])
    n = len(t_imu)
    bg = rng.normal(0, nm.gyro_bias_sigma, 3) + np.cumsum(
        rng.normal(0, nm.gyro_bias_walk * math.sqrt(dt), (n, 3)), axis=0
    )
    ba = rng.normal(0, nm.accel_bias_sigma, 3) + np.cumsum(
        rng.normal(0, nm.accel_bias_walk * math.sqrt(dt), (n, 3)), axis=0
    )
    gyro = omega + bg + rng.normal(0, nm.gyro_noise_density / math.sqrt(dt), (n, 3))
    acc = accel + ba + rng.normal(0, nm.accel_noise_density / math.sqrt(dt), (n, 3))
    meas: list[tuple[float, int, Measurement]] = [
        (float(t_imu[k]), 0, ImuSample(float(t_imu[k]), gyro[k], acc[k])) for k in range(n)
    ]
    # camera motions and tether
    t_cam = np.arange(0.0, t_imu[-1] + 1e-9, 1.0 / scenario.camera_rate)
    p_c, R_c = traj.pose(t_cam)
    R_bc, p_bc = cfg.R_bc, cfg.p_bc
    R_wc = R_c @ R_bc
    p_wc = p_c + R_c @ p_bc
    scale = rng.normal(0, nm.visual_scale_sigma)
    anchor = np.asarray(scenario.anchor_cad, dtype=float)
    slack_until, slack_amount = -1.0, 0.0
    dt_cam = 1.0 / scenario.camera_rate
    for k in range(1, len(t_cam)):
        a_ou = math.exp(-dt_cam / nm.visual_scale_tau)
        scale = (
            a_ou * scale + math.sqrt(1 - a_ou**2) * nm.visual_scale_sigma * rng.standard_normal()
        )
        R_rel = R_wc[k - 1].T @ R_wc[k]
        p_rel = R_wc[k - 1].T @ (p_wc[k] - p_wc[k - 1])
        s_t = nm.visual_translation_sigma + nm.visual_translation_rel * float(np.linalg.norm(p_rel))
        R_m = R_rel @ so3_exp(rng.normal(0, nm.visual_rotation_sigma, 3))
        p_m = (1.0 + scale) * p_rel + rng.normal(0, s_t, 3)
        cov = np.diag([nm.visual_rotation_sigma**2] * 3 + [s_t**2] * 3)
        ok = bool(rng.uniform() >= nm.visual_dropout)
        meas.append(
            (
                float(t_cam[k]),
                1,
                RelativeMotion(float(t_cam[k - 1]), float(t_cam[k]), R_m, p_m, cov, ok=ok),
            )
        )
    for k in range(len(t_cam)):
        t = float(t_cam[k])
        if (
            nm.tether_slack_rate > 0
            and t > slack_until
            and rng.uniform() < nm.tether_slack_rate * dt_cam
        ):
            slack_until, slack_amount = t + rng.uniform(0.5, 1.5), rng.uniform(0.02, 0.05)
        extra = slack_amount if t <= slack_until else 0.0
        length = float(np.linalg.norm(p_c[k] - anchor)) + extra + rng.normal(0, nm.tether_sigma)
        ok = bool(rng.uniform() >= nm.tether_invalid)
        meas.append((t, 2, TetherReading(t, length, ok)))
    meas.sort(key=lambda item: (item[0], item[1]))
    return ClimbRecording(
        measurements=tuple(m for _, _, m in meas),
        truth_t=t_cam,
        truth_position=p_c,
        truth_rotation=R_c,
        init_path_length=init_len,
        anchor_cad=anchor,
        h=scenario.h,
    )


# --------------------------------------------------------------------------- images


def render_planar_view(
    texture: npt.NDArray[np.uint8],
    texel_size: float,
    K: npt.ArrayLike,
    image_size: tuple[int, int],
    R_plane_camera: npt.ArrayLike,
    p_plane_camera: npt.ArrayLike,
) -> npt.NDArray[np.uint8]:
    """Image of the textured plane ``z = 0`` (texture tiled, pixel (0, 0) at the origin).

    Parameters
    ----------
    texture
        (H, W) or (H, W, 3) uint8; texel ``(i, j)`` covers ``x = j·texel_size``,
        ``y = i·texel_size``.
    texel_size
        m per texel.
    K : (3, 3)
        Camera intrinsics, pixels.
    image_size
        ``(width, height)`` in pixels.
    R_plane_camera : (3, 3)
        Camera orientation in the plane frame (camera z looking at the plane).
    p_plane_camera : (3,)
        Camera centre, m (``z > 0``: above the plane).
    """
    Km = np.asarray(K, dtype=float)
    R = np.asarray(R_plane_camera, dtype=float)
    c = np.asarray(p_plane_camera, dtype=float)
    if not texel_size > 0:
        raise ValueError(f"texel_size must be positive (m), got {texel_size!r}")
    if c.shape != (3,) or c[2] <= 0:
        raise ValueError(f"p_plane_camera must be (3,) with z > 0 (above the plane), got {c!r}")
    Rt = R.T
    H_img_plane = Km @ np.c_[Rt[:, 0], Rt[:, 1], -Rt @ c]
    H = H_img_plane @ np.diag([texel_size, texel_size, 1.0])
    image = cv2.warpPerspective(
        texture, H, image_size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP
    )
    return np.asarray(image, dtype=np.uint8)
