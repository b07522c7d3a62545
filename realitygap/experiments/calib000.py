r"""The ``calib000`` experiment: odometry and camera-mounting calibration in simulation.

Seed 000's calibration in simulation. The "real" robot is another body: its
left/right wheel diameters are 1.05 / 0.98 × nominal, its wheelbase
1.05 × nominal and its RGB-D camera is mounted off by (1.1 cm, 0.8 cm, −1°);
the firmware still converts ``(v, ω)`` with the nominal geometry. Each
calibration iteration runs

1. **UMBmark** (Borenstein): squares driven clockwise and counter-clockwise
   by a closed-loop controller
   (:class:`~realitygap.controllers.drives.SquareDriver`) whose pose
   estimate is the *current* calibrated odometry. The absolute end pose comes from
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
   translating
   (:func:`~realitygap.estimators.odometry_mounting.fit_odometry_and_mounting`).

The calibration is sequential: after each iteration one joint fit over every
drive so far gives the scale factors and their covariance, which is
propagated to the predicted 2-σ position error of a straight and a
semicircular reference drive (the test drives' shapes; first-order
propagation, :func:`~realitygap.estimators.odometry_mounting.calibrate_until_precise`).
Iterations go on until that prediction is within the target precision
(``CalibConfig.target_error_m``, 5 mm) or ``max_iterations`` ran.

Then a straight and a semicircular trajectory are driven on the calibrated
odometry, and its estimate (and the estimate fused with VO) is compared
with ground truth at 20 positions each; the same drives dead-reckoned with
the nominal geometry, and with UMBmark alone, are the contrast.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import wrap_angle
from realitygap.experiments import RunContext, experiment
from realitygap.experiments.calib_camera import (
    EndPose,
    _drive_samples,
    _T_base_camera_planar,
    end_pose_from_frames,
)
from realitygap.experiments.drive_harness import (
    DriveLog,
    RecordingOdometry,
    arc_path,
    calibration_room,
    drive,
    figure_eight,
    load_average,
    nominal_kinematics,
    timed_reference,
)

FloatArray = npt.NDArray[np.float64]

__all__ = ["CalibConfig", "EndPose", "calib000", "end_pose_from_frames"]


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
        Fewest calibration iterations (UMBmark + EKF each); further ones drive
        the figure-eights only.
    max_iterations : int
        Most calibration iterations: the calibration stops here when the
        target precision is still not predicted.
    target_error_m : float
        Required precision: the predicted ``n_sigma`` position error of the
        calibrated odometry on reference drives of the test drives' shapes
        (straight ``straight_length``, semicircle of ``curve_radius``), m.
    n_sigma : float
        Multiple of the predicted RMS position error held against the target.
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
    pool_squares : bool
        Whether the final joint fit also takes the camera motions of the
        UMBmark squares (straight legs and turns on the spot), besides those of
        the figure-eights.
    """

    left_diameter_factor: float = 1.05
    right_diameter_factor: float = 0.98
    wheelbase_factor: float = 1.05
    camera_offset: tuple[float, float, float] = (0.011, 0.008, math.radians(-1.0))
    iterations: int = 3
    max_iterations: int = 5
    target_error_m: float = 0.005
    n_sigma: float = 2.0
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
    pool_squares: bool = True

    def __post_init__(self) -> None:
        if not 1 <= self.iterations <= self.max_iterations:
            raise ValueError(
                f"CalibConfig needs 1 <= iterations <= max_iterations, got iterations="
                f"{self.iterations}, max_iterations={self.max_iterations}"
            )
        if not (self.target_error_m > 0 and self.n_sigma > 0):
            raise ValueError(
                f"CalibConfig target_error_m (m) and n_sigma must be > 0, got "
                f"{self.target_error_m} and {self.n_sigma}"
            )

    @classmethod
    def quick(cls) -> CalibConfig:
        """A shorter run (one square per direction, one figure-eight per iteration)."""
        return cls(
            runs_per_direction=1,
            square_side=0.8,
            excitation=((0.5, 1), (0.8, 1)),
            umbmark_only_iterations=1,
            max_iterations=3,
        )

    def reference_paths(self, spacing: float = 0.01) -> dict[str, tuple[FloatArray, FloatArray]]:
        """Arc increments ``(Δs, Δθ)`` (m, rad) of the straight and semicircular reference drives."""
        out = {}
        for name, length, curvature in (
            ("straight", self.straight_length, 0.0),
            ("curve", math.pi * self.curve_radius, 1.0 / self.curve_radius),
        ):
            n = max(2, int(math.ceil(length / spacing)))
            ds = np.full(n, length / n)
            out[name] = (ds, curvature * ds)
        return out

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


def _umbmark_iteration(
    env: Any,
    recorder: RecordingOdometry,
    cfg: CalibConfig,
    kin: Any,
    mounting: FloatArray,
    seed: int,
    vo_params: Any,
    logs: list[DriveLog] | None = None,
) -> tuple[Any, list[dict[str, Any]]]:
    """UMBmark squares both ways on odometry ``kin``; their drive logs go to ``logs`` if given."""
    from realitygap.controllers.drives import SquareDriver
    from realitygap.core.geometry import se2_between
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
            if logs is not None:
                logs.append(log)
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
    from realitygap.estimators.vo import RGBDVisualOdometry, planar_motion_from_camera
    from realitygap.estimators.vo_params import VOStatus

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


def _pooled_fit(
    drives: Sequence[tuple[FloatArray, list[FloatArray | None], FloatArray]],
    nominal: Any,
    scales0: FloatArray,
    mounting0: FloatArray,
) -> Any:
    """One joint odometry/mounting fit over several drives (see
    :func:`~realitygap.estimators.odometry_mounting.fit_pooled_drives`)."""
    from realitygap.estimators.odometry_mounting import fit_pooled_drives

    return fit_pooled_drives(drives, nominal, scales0, mounting0)


def _estimate_row(
    E_d: float,
    E_b: float,
    mounting: npt.NDArray[np.float64],
    std: npt.NDArray[np.float64],
    true_E_d: float,
    true_E_b: float,
    true_mount: npt.NDArray[np.float64],
) -> dict[str, Any]:
    """A calibration estimate and its errors against the true body: UMBmark factors,
    camera mounting (m, rad; reported in mm and degrees) and their standard deviations
    (``std``: mounting x, y, yaw, then the three odometry scales)."""
    return {
        "E_d": E_d,
        "E_b": E_b,
        "E_d_err": abs(E_d - true_E_d),
        "E_b_err": abs(E_b - true_E_b),
        "mount_mm": (1e3 * mounting[:2]).tolist(),
        "mount_deg": math.degrees(mounting[2]),
        "mount_err_mm": 1e3 * float(np.hypot(*(mounting[:2] - true_mount[:2]))),
        "mount_err_deg": abs(math.degrees(float(wrap_angle(mounting[2] - true_mount[2])))),
        "std_mount_mm": (1e3 * std[:2]).tolist(),
        "std_mount_deg": math.degrees(float(std[2])),
        "std_scales": std[3:].tolist(),
    }


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
    from realitygap.controllers.drives import PathFollower
    from realitygap.estimators.odometry_mounting import (
        calibrate_until_precise,
        fit_odometry_and_mounting,
        predicted_position_error,
    )
    from realitygap.estimators.vo_params import VOParams
    from realitygap.robots.diffdrive import DiffDriveParams

    cfg = CalibConfig.quick() if ctx.quick else CalibConfig()
    vo_params = VOParams(seed=ctx.seed)
    nominal_params = DiffDriveParams()
    nominal = nominal_kinematics(nominal_params)
    true_params = cfg.reality().apply_params(nominal_params)
    true_E_d = (true_params.wheel_radius_right / true_params.wheel_radius_left) / (
        nominal.wheel_radius_right / nominal.wheel_radius_left
    )
    true_E_b = true_params.wheelbase / nominal.wheelbase
    true_mount = _mounting_of(true_params.camera)
    true_kin = nominal_kinematics(true_params)  # sim-only floor: odometry with the true body
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
    n_pooled = 0
    drive_seconds = 0.0

    def collect_round(it: int) -> tuple[list[Any], FloatArray, FloatArray]:
        """One iteration: UMBmark squares, then figure-eights fitted on the UMBmark seed.

        Iterations beyond ``cfg.iterations`` drive the figure-eights only, on the current
        estimate: per second of driving they inform the scales about 2.5 times more than
        the squares do."""
        nonlocal kin, mounting, prior_cov, umb_only_kin, n_pooled, drive_seconds
        drives: list[Any] = []
        umb: dict[str, Any] = {}
        if it <= cfg.iterations:
            square_logs: list[DriveLog] = []
            res, rows = _umbmark_iteration(
                env, recorder, cfg, kin, mounting, seed, vo_params, square_logs
            )
            if cfg.pool_squares:  # turns on the spot: the wheelbase's most direct measurement
                drives.extend(_drive_samples(sq, vo_params)[0] for sq in square_logs)
                drive_seconds += sum(float(sq.t[-1] - sq.t[0]) for sq in square_logs)
            for row in rows:
                square_rows.append({"iteration": it, **row})
            kin_umb = kin.with_umbmark(res.E_d, res.E_b)
            if umb_only_kin is None:
                umb_only_kin = kin_umb
            f_umb = _factors(kin_umb, nominal)
            umb = {
                "umbmark_E_d": f_umb[1] / f_umb[0],
                "umbmark_E_b": f_umb[2],
                "umbmark_E_max_syst_mm": 1e3 * res.E_max_syst,
            }
            ctx.progress(
                f"calib000 iteration {it}: UMBmark E_d={f_umb[1] / f_umb[0]:.4f} "
                f"E_b={f_umb[2]:.4f} (E_max,syst {1e3 * res.E_max_syst:.1f} mm, "
                f"{rows[0]['absolute_source']})"
            )
        else:
            kin_umb, f_umb = kin, _factors(kin, nominal)
        recorder.kinematics = kin_umb
        start = np.array([0.0, 0.0, 0.0])
        laps = cfg.first_excitation if it == 1 else cfg.excitation
        log = drive(
            env,
            recorder,
            PathFollower(timed_reference(figure_eight(start, laps), cfg.excitation_speed)),
            start,
            seed,
            20_000,
        )
        drive_seconds += float(log.t[-1] - log.t[0])
        samples, n_lost = _drive_samples(log, vo_params)
        inc, motions, weights, loops = samples
        drives.append(samples)
        n_pooled += len(drives)
        fit = fit_odometry_and_mounting(
            inc,
            motions,
            nominal,
            f_umb,
            mounting,
            prior_cov=prior_cov,
            sensor_weights=weights,
            loop_closures=loops if len(loops[0]) else None,
        )
        # the next iteration starts from this posterior, widened so that its UMBmark seed
        # (and any error of this linearisation) can still move the estimate
        prior_cov = np.diag(np.diag(fit.cov) + np.square(_PRIOR_FLOOR))
        kin = nominal.scaled(*fit.scales)
        mounting = fit.mounting
        E_d, E_b = fit.scales[1] / fit.scales[0], fit.scales[2]
        row = {
            "iteration": it,
            **umb,
            "ekf_k_left": fit.scales[0],
            "ekf_k_right": fit.scales[1],
            "ekf_k_wheelbase": fit.scales[2],
            **_estimate_row(E_d, E_b, mounting, fit.std, true_E_d, true_E_b, true_mount),
            "vo_frames_lost": n_lost,
            "vo_updates": fit.n_updates,
            "vo_outliers": fit.n_outliers,
            "observable": fit.observable,
            "excitation_collision": log.collided,
            "drives_pooled": n_pooled,
            "loop_closures": int(sum(len(d[3][0]) for d in drives)),
            "drive_time_s": drive_seconds,
        }
        iteration_rows.append(row)
        ctx.progress(
            f"calib000 iteration {it}: EKF E_d={E_d:.5f} (true {true_E_d:.5f}), "
            f"E_b={E_b:.5f} (true {true_E_b:.5f}), mount err {row['mount_err_mm']:.2f} mm / "
            f"{row['mount_err_deg']:.3f}°, k=({fit.scales[0]:.4f}, {fit.scales[1]:.4f}), "
            f"{time.perf_counter() - t_start:.0f} s"
        )
        return drives, fit.scales, fit.mounting

    references = cfg.reference_paths()
    try:
        # The drives of all iterations are independent measurements of the same body (raw
        # tick increments and camera ego-motions; the steering only changes the path): one
        # joint fit over all of them, relinearised at the last iteration's estimate under
        # the wide default prior, is the estimate after each iteration. Its scale
        # covariance, propagated to the reference drives, decides whether to go on.
        def report_round(it: int, pooled_fit: Any, predicted: float) -> None:
            ctx.progress(
                f"calib000 after iteration {it}: joint fit E_b={pooled_fit.scales[2]:.5f} ± "
                f"{pooled_fit.std[5]:.5f}, predicted {cfg.n_sigma:g}-σ error "
                f"{1e3 * predicted:.1f} mm (target {1e3 * cfg.target_error_m:g} mm)"
            )

        seq = calibrate_until_precise(
            collect_round,
            nominal,
            list(references.values()),
            cfg.target_error_m,
            min_rounds=cfg.iterations,
            max_rounds=cfg.max_iterations,
            n_sigma=cfg.n_sigma,
            on_round=report_round,
        )
        for row, predicted in zip(iteration_rows, seq.predicted_error_m):
            row["predicted_err_mm_pooled"] = 1e3 * predicted
        fit = seq.fit
        kin = nominal.scaled(*fit.scales)
        mounting = fit.mounting
        E_d, E_b = fit.scales[1] / fit.scales[0], fit.scales[2]
        predicted_mm = {
            name: 1e3
            * predicted_position_error(path, nominal, fit.scales, seq.scales_cov, cfg.n_sigma)
            for name, path in references.items()
        }
        pooled_row = {
            **_estimate_row(E_d, E_b, mounting, fit.std, true_E_d, true_E_b, true_mount),
            "vo_updates": fit.n_updates,
            "vo_outliers": fit.n_outliers,
            "observable": fit.observable,
            "loop_closures": fit.n_loops,
            "loop_heading_std_mrad": 1e3 * fit.loop_heading_std,
            "drives": seq.n_drives,
            "dispersion_per_iteration": list(seq.dispersion),
            "iterations": seq.rounds,
            "target_reached": seq.reached,
            "predicted_err_mm_per_iteration": [1e3 * e for e in seq.predicted_error_m],
        }
        ctx.progress(
            f"calib000 joint fit over {seq.n_drives} drives of {seq.rounds} iterations: "
            f"E_d={E_d:.5f} (true {true_E_d:.5f}), E_b={E_b:.5f} ± {fit.std[5]:.5f} (true "
            f"{true_E_b:.5f}), mount err {pooled_row['mount_err_mm']:.2f} mm; predicted "
            f"{cfg.n_sigma:g}-σ error straight {predicted_mm['straight']:.1f} mm, curve "
            f"{predicted_mm['curve']:.1f} mm (target {1e3 * cfg.target_error_m:g} mm "
            + ("reached)" if seq.reached else f"not reached in {cfg.max_iterations} iterations)")
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
            log = drive(env, recorder, PathFollower(timed_reference(path)), start, seed, 20_000)
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
        "E_d_err": pooled_row["E_d_err"],
        "E_b_err": pooled_row["E_b_err"],
        "E_b_err_last_iteration": last["E_b_err"],
        "E_b_std": pooled_row["std_scales"][2],
        "mount_err_mm": pooled_row["mount_err_mm"],
        "mount_err_deg": pooled_row["mount_err_deg"],
        "max_err_mm_straight": figures_err["calibrated_straight"],
        "max_err_mm_curve": figures_err["calibrated_curve"],
        "predicted_err_mm_straight": predicted_mm["straight"],
        "predicted_err_mm_curve": predicted_mm["curve"],
        "calibration_iterations": float(seq.rounds),
        "calibration_drive_time_s": last["drive_time_s"],
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
            "max_iterations": cfg.max_iterations,
            "target_error_mm": 1e3 * cfg.target_error_m,
            "n_sigma": cfg.n_sigma,
            "target_reached": seq.reached,
            "square_side_m": cfg.square_side,
            "runs_per_direction": cfg.runs_per_direction,
            "excitation_figure_eights": [list(e) for e in cfg.excitation],
            "first_excitation_figure_eights": [list(e) for e in cfg.first_excitation],
            "excitation_speed_m_s": cfg.excitation_speed,
            "frame_hz": cfg.frame_hz,
            "vo": "VOParams defaults: ORB (bucketed) + GTM + RANSAC, maximum-likelihood RGB-D motion",
            "umbmark_absolute_reference": "camera: loop closure of the last frame on the first, "
            "else chained VO; converted to the base with the current mounting estimate",
            "positions_per_trajectory": cfg.n_positions,
            "umbmark_only_iterations": cfg.umbmark_only_iterations,
            "pool_squares": cfg.pool_squares,
            "test_trajectories": f"straight {cfg.straight_length} m; semicircle of radius "
            f"{cfg.curve_radius} m; positions at equal time steps after the start",
            "load_avg_1min": load_average(),
            "final_estimate": "joint fit over the figure-eights"
            + (" and UMBmark squares" if cfg.pool_squares else "")
            + " of all iterations",
            "pooled_fit": pooled_row,
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
            "predicted_err_mm_* is the calibration's own n_sigma (config) position error on "
            "reference drives of the test drives' shapes, from the joint fit's scale covariance "
            "propagated through dead reckoning (first order); the iterations stop when both are "
            "within target_error_mm or at max_iterations (config target_reached); the test "
            "drives themselves take no part in it",
        ],
    }
