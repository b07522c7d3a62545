"""End-to-end evaluation of the climbing-robot localisation on the blade.

* :func:`synthesise_recording` — a ground-truth trajectory on the blade surface (a
  closed excitation loop for the global initialisation, then a lawn-mower sweep),
  and the IMU, visual relative-motion and tether measurements generated from it
  with realistic noise (:class:`NoiseModel`);
* :func:`evaluate_recording` — runs :class:`.ClimbLocaliser` on any
  :class:`ClimbRecording` (synthetic here, simulated or real later) and scores
  three estimators on the same VIO run: VIO alone (mapped into the CAD frame by the
  global initialisation), VIO + tether, and VIO + tether + adsorption;
* :func:`evaluate` — several seeded runs of a :class:`ClimbScenario` and a summary;
* :func:`render_planar_view` — an image of a textured plane for the image front-end.

Drift is the largest position error over the tracked part of the run divided by the
distance travelled in that part (the figure the source reports as 0.51 %).
Frames: ``cad`` (blade frame, z up), ``world`` (VIO frame).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TypeAlias

import cv2
import numpy as np
import numpy.typing as npt
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation

from realitygap.core.geometry import rot_z, so3_exp, so3_log, wrap_angle
from realitygap.estimators.climb.constrained import ConstrainedConfig, ConstrainedEstimator
from realitygap.estimators.climb.localiser import ClimbLocaliser, LocaliserConfig, LocaliserPhase
from realitygap.estimators.climb.measurements import (
    CameraFrame,
    ClimbEstimate,
    ImuSample,
    RelativeMotion,
    TetherReading,
)
from realitygap.estimators.climb.surface import SurfaceModel
from realitygap.estimators.climb.vio import VioConfig
from realitygap.robots.blade_geometry import BladeParams, BladeSurface, cad_point_cloud, deformed

FloatArray = npt.NDArray[np.float64]
Measurement: TypeAlias = ImuSample | CameraFrame | RelativeMotion | TetherReading

__all__ = [
    "ClimbRecording",
    "ClimbScenario",
    "EstimatorMetrics",
    "EvaluationReport",
    "NoiseModel",
    "RunMetrics",
    "TruthTrajectory",
    "evaluate",
    "evaluate_recording",
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
    """Measurements with ground truth; the input of :func:`evaluate_recording`.

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


# --------------------------------------------------------------------------- evaluation


@dataclass(frozen=True)
class EstimatorMetrics:
    """Position accuracy of one estimator over the tracked part of a run.

    Attributes
    ----------
    max_error
        Largest position error, m.
    final_error
        Position error at the end, m.
    rms_error
        m.
    max_drift_pct
        ``100 · max_error / distance``.
    max_yaw_error_deg
        Largest heading error, deg.
    """

    max_error: float
    final_error: float
    rms_error: float
    max_drift_pct: float
    max_yaw_error_deg: float


@dataclass(frozen=True)
class RunMetrics:
    """Scores of one run.

    Attributes
    ----------
    distance
        Distance travelled while tracking, m.
    vio, vio_tether, constrained
        :class:`EstimatorMetrics` of VIO alone (mapped by the global
        initialisation), VIO + tether, VIO + tether + adsorption.
    vio_aligned
        VIO alone, aligned to the truth at the start of tracking (pure VIO drift).
    init_yaw_error_deg
        Error of the global initialisation's yaw (the rotation between the VIO frame
        at its start and the CAD frame), deg.
    init_heading_error_deg
        Heading error of the pose tracking starts from (the transform applied to the
        VIO pose at the end of the excitation path, so it includes the VIO's yaw
        drift along that path), deg.
    init_position_error_cm
        Error of the CAD-frame position at the start of tracking, cm.
    init_translation_error_cm
        Error of the translation :math:`t` of the 4-DOF transform, cm.
    init_status
        The global initialisation's status.
    status_counts
        How often each status flag of the constrained estimator occurred.
    """

    distance: float
    vio: EstimatorMetrics
    vio_tether: EstimatorMetrics
    constrained: EstimatorMetrics
    vio_aligned: EstimatorMetrics
    init_yaw_error_deg: float
    init_heading_error_deg: float
    init_position_error_cm: float
    init_translation_error_cm: float
    init_status: str
    status_counts: tuple[tuple[str, int], ...]


def _metrics(
    t: FloatArray, p: FloatArray, R: FloatArray, rec: ClimbRecording, distance: float
) -> EstimatorMetrics:
    p_true, R_true = rec.truth_at(t)
    err = np.linalg.norm(p - p_true, axis=1)
    yaw_err = np.array(
        [
            abs(float(wrap_angle(math.atan2(Ra[1, 0], Ra[0, 0]) - math.atan2(Rb[1, 0], Rb[0, 0]))))
            for Ra, Rb in zip(R, R_true)
        ]
    )
    return EstimatorMetrics(
        max_error=float(err.max()),
        final_error=float(err[-1]),
        rms_error=float(np.sqrt(np.mean(err**2))),
        max_drift_pct=float(100.0 * err.max() / max(distance, 1e-9)),
        max_yaw_error_deg=float(np.degrees(yaw_err.max())),
    )


def _zyx_yaw(R: FloatArray) -> float:
    return float(Rotation.from_matrix(R).as_euler("ZYX")[0])


def evaluate_recording(
    recording: ClimbRecording,
    surface: SurfaceModel,
    *,
    vio_config: VioConfig | None = None,
    constrained_config: ConstrainedConfig | None = None,
    localiser_config: LocaliserConfig | None = None,
) -> RunMetrics:
    """Run the localisation on a recording and score VIO, VIO + tether and constrained.

    One :class:`.ClimbLocaliser` run provides the VIO keyframes, the global
    initialisation and the constrained (VIO + tether + adsorption) track; VIO + tether
    replays :class:`.ConstrainedEstimator` without the adsorption updates on the same
    VIO keyframes and tether readings from the same starting state.

    Parameters
    ----------
    recording
        Measurements and ground truth.
    surface
        The CAD surface model (nominal).
    vio_config, constrained_config
        Settings; ``localiser_config`` defaults to the recording's excitation length.

    Raises
    ------
    ValueError
        If the global initialisation never completes.
    """
    cc = ConstrainedConfig() if constrained_config is None else constrained_config
    lc = localiser_config or LocaliserConfig(
        init_path_length=0.97 * recording.init_path_length,
        init_max_path_length=max(6.0, 1.5 * recording.init_path_length),
    )
    loc = ClimbLocaliser(
        surface,
        recording.anchor_cad,
        recording.h,
        vio_config=vio_config,
        config=cc,
        localiser_config=lc,
    )
    vio_kf: list[ClimbEstimate] = []
    tracked: list[ClimbEstimate] = []
    tethers: list[TetherReading] = []
    start: ClimbEstimate | None = None
    start_cov: FloatArray | None = None
    kf_count = 0
    flags: dict[str, int] = {}
    for m in recording.measurements:
        was_tracking = loc.phase is LocaliserPhase.TRACKING
        est = loc.update(m)
        if isinstance(m, TetherReading):
            if was_tracking:
                tethers.append(m)
            continue
        if loc.vio.keyframe_count != kf_count:
            kf_count = loc.vio.keyframe_count
            kf = loc.vio.keyframe_estimate()
            vio_kf.append(kf)
            if loc.phase is LocaliserPhase.TRACKING:
                if start is None:
                    start = est
                    start_cov = est.cov
                tracked.append(est)
                for f in est.status.split("|"):
                    flags[f] = flags.get(f, 0) + 1
    if start is None or loc.global_init is None or loc.vio.static_init is None:
        raise ValueError("the global initialisation never completed on this recording")
    gi = loc.global_init
    t_start = start.t
    # VIO + tether replay
    vt = ConstrainedEstimator(
        surface, recording.anchor_cad, recording.h, dataclasses.replace(cc, use_surface=False)
    )
    vt.reset(start, start_cov)
    stream: list[tuple[float, int, ClimbEstimate | TetherReading]] = [
        (k.t, 0, k) for k in vio_kf if k.t >= t_start - 1e-9
    ] + [(r.t, 1, r) for r in tethers]
    stream.sort(key=lambda item: (item[0], item[1]))
    vt_track: list[ClimbEstimate] = []
    for _, kind, item in stream:
        e = vt.update(item)
        if kind == 0:
            vt_track.append(e)
    # tracks
    tk = np.array([e.t for e in tracked])
    p_true, _ = recording.truth_at(tk)
    distance = float(np.sum(np.linalg.norm(np.diff(p_true, axis=0), axis=1)))
    constrained = _metrics(
        tk,
        np.array([e.position for e in tracked]),
        np.array([e.rotation for e in tracked]),
        recording,
        distance,
    )
    vt_m = _metrics(
        np.array([e.t for e in vt_track]),
        np.array([e.position for e in vt_track]),
        np.array([e.rotation for e in vt_track]),
        recording,
        distance,
    )
    vio_track = [k for k in vio_kf if k.t >= t_start - 1e-9]
    tv = np.array([k.t for k in vio_track])
    pw = np.array([k.position for k in vio_track])
    Rw = np.array([k.rotation for k in vio_track])
    Rgw = gi.R_world_cad.T
    vio_m = _metrics(tv, gi.cad_from_world(pw), Rgw @ Rw, recording, distance)
    # VIO aligned to the truth at the start of tracking (4 DOF)
    p0, R0 = recording.truth_at(tv[0])
    dyaw = _zyx_yaw(R0[0]) - _zyx_yaw(Rw[0])
    Ra = rot_z(dyaw)
    vio_al = _metrics(tv, (pw - pw[0]) @ Ra.T + p0[0], Ra @ Rw, recording, distance)
    # global initialisation vs truth: the VIO world frame is the body frame at the
    # static initialisation, yaw only
    t_init = loc.vio.static_init.t
    pi, Ri = recording.truth_at(t_init)
    psi0 = _zyx_yaw(Ri[0])
    yaw_true = -psi0
    t_true = -rot_z(yaw_true) @ pi[0]
    p_start_true, R_start_true = recording.truth_at(t_start)
    R_s, R_t = start.rotation, R_start_true[0]
    heading_err = float(
        wrap_angle(math.atan2(R_s[1, 0], R_s[0, 0]) - math.atan2(R_t[1, 0], R_t[0, 0]))
    )
    return RunMetrics(
        distance=distance,
        vio=vio_m,
        vio_tether=vt_m,
        constrained=constrained,
        vio_aligned=vio_al,
        init_yaw_error_deg=abs(math.degrees(float(wrap_angle(gi.yaw - yaw_true)))),
        init_heading_error_deg=abs(math.degrees(heading_err)),
        init_position_error_cm=float(100 * np.linalg.norm(start.position - p_start_true[0])),
        init_translation_error_cm=float(100 * np.linalg.norm(gi.t - t_true)),
        init_status=gi.status,
        status_counts=tuple(sorted(flags.items())),
    )


@dataclass(frozen=True)
class EvaluationReport:
    """Runs of :func:`evaluate` and their summary.

    Attributes
    ----------
    seeds
        Seeds of the runs.
    runs
        :class:`RunMetrics` per seed.
    """

    seeds: tuple[int, ...]
    runs: tuple[RunMetrics, ...]

    def summary(self) -> dict[str, float | bool]:
        """Worst and mean figures over the runs (drift in % of distance)."""

        def col(get: Callable[[RunMetrics], float]) -> FloatArray:
            return np.array([get(r) for r in self.runs])

        out: dict[str, float | bool] = {
            "min_distance_m": float(col(lambda r: r.distance).min()),
        }
        for name in ("vio", "vio_tether", "constrained", "vio_aligned"):
            d = np.array([getattr(r, name).max_drift_pct for r in self.runs])
            out[f"{name}_max_drift_pct_worst"] = float(d.max())
            out[f"{name}_max_drift_pct_mean"] = float(d.mean())
        yaw = col(lambda r: r.init_yaw_error_deg)
        heading = col(lambda r: r.init_heading_error_deg)
        pos = col(lambda r: r.init_position_error_cm)
        out["init_yaw_error_deg_worst"] = float(yaw.max())
        out["init_yaw_error_deg_mean"] = float(yaw.mean())
        out["init_heading_error_deg_worst"] = float(heading.max())
        out["init_heading_error_deg_mean"] = float(heading.mean())
        out["init_position_error_cm_worst"] = float(pos.max())
        out["init_position_error_cm_mean"] = float(pos.mean())
        out["constrained_better_than_vio_every_run"] = bool(
            np.all(col(lambda r: r.constrained.max_drift_pct) < col(lambda r: r.vio.max_drift_pct))
        )
        return out


def evaluate(
    scenario: ClimbScenario | None = None,
    seeds: Sequence[int] = (0, 1, 2),
    *,
    cloud_spacing: float = 0.01,
    vio_config: VioConfig | None = None,
    constrained_config: ConstrainedConfig | None = None,
) -> EvaluationReport:
    """Seeded synthetic runs of ``scenario`` scored by :func:`evaluate_recording`.

    The estimators use the nominal blade's CAD cloud (``cloud_spacing`` m) even when
    the scenario deforms the real surface.
    """
    sc = ClimbScenario() if scenario is None else scenario
    pts, nrm = cad_point_cloud(sc.blade, cloud_spacing)
    surface = SurfaceModel(pts, nrm)
    runs = []
    for seed in seeds:
        rec = synthesise_recording(sc, np.random.default_rng(seed), vio_config=vio_config)
        runs.append(
            evaluate_recording(
                rec, surface, vio_config=vio_config, constrained_config=constrained_config
            )
        )
    return EvaluationReport(tuple(int(s) for s in seeds), tuple(runs))


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
