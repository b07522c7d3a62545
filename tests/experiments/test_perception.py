"""Building blocks of the ``calib000``, ``vo`` and ``umbmark-real`` experiments."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from realitygap.calibrate import SessionCalibration, pool_calibrations
from realitygap.core.geometry import se2_compose, transform_from_rt, wrap_angle
from realitygap.estimators.base import CameraIntrinsics
from realitygap.estimators.diffdrive_model import DiffDriveKinematics
from realitygap.experiments import EXPERIMENTS
from realitygap.experiments import perception as P

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "optiodom_diffdrive"
K = CameraIntrinsics(320, 240, 228.0, 208.0, 160.0, 120.0)


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _synthetic_matches(seed: int, n: int = 80) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points in the previous camera, their exact pixels in the current one, and the motion."""
    rng = np.random.default_rng(seed)
    T = transform_from_rt(_rot_y(rng.uniform(-0.2, 0.2)), rng.uniform(-0.1, 0.1, 3))
    z = rng.uniform(1.0, 5.0, n)
    uv = rng.uniform([10, 10], [310, 230], (n, 2))
    Q = np.stack([(uv[:, 0] - K.cx) * z / K.fx, (uv[:, 1] - K.cy) * z / K.fy, z], 1)
    P_prev = Q @ T[:3, :3].T + T[:3, 3]  # the same points seen from the previous camera
    return P_prev, uv, T


# ----------------------------------------------------------------------------- vo helpers


@pytest.mark.parametrize("seed", range(4))
def test_match_precision_is_one_for_exact_correspondences(seed: int) -> None:
    P_prev, uv, T = _synthetic_matches(seed)
    good = P.match_precision(P_prev, uv, T, K)
    assert good.dtype == bool and good.shape == (len(uv),)
    assert good.mean() == 1.0


@pytest.mark.parametrize("seed", range(4))
def test_match_precision_counts_injected_outliers(seed: int) -> None:
    P_prev, uv, T = _synthetic_matches(seed)
    rng = np.random.default_rng(100 + seed)
    bad = rng.choice(len(uv), 12, replace=False)
    wrong = uv.copy()
    wrong[bad] = uv[np.roll(bad, 1)] + 20.0  # swapped partners, clearly displaced
    wrong[bad[:3]] += 0.5  # sub-pixel jitter on three of them stays wrong
    good = P.match_precision(P_prev, wrong, T, K)
    assert not good[bad].any() and good.sum() == len(uv) - 12
    assert good.mean() < 1.0
    # within tolerance is correct, beyond is not
    near = uv.copy()
    near[0] += [2.0, 0.0]
    assert P.match_precision(P_prev, near, T, K, tol_px=3.0)[0]
    assert not P.match_precision(P_prev, near, T, K, tol_px=1.0)[0]


def test_match_precision_validates_input() -> None:
    P_prev, uv, T = _synthetic_matches(0)
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        P.match_precision(P_prev[:, :2], uv, T, K)
    with pytest.raises(ValueError, match="tol_px"):
        P.match_precision(P_prev, uv, T, K, tol_px=0.0)
    with pytest.raises(ValueError, match="T_prev_curr"):
        P.match_precision(P_prev, uv, np.eye(3), K)
    behind = P_prev.copy()
    behind[:, 2] = -behind[:, 2]
    assert not P.match_precision(behind, uv, np.eye(4), K).any()


def test_relative_pose_errors_closed_forms() -> None:
    s = np.linspace(0.0, 5.0, 501)
    gt = np.stack([s, np.zeros_like(s), np.zeros_like(s)], 1)
    t, r = P.relative_pose_errors(gt, gt, 1.0)
    assert len(t) == 401 and np.all(t == 0.0) and np.all(r == 0.0)
    # a rigidly moved estimate has no relative error
    moved = se2_compose(np.array([1.0, -2.0, 0.7]), gt)
    t, r = P.relative_pose_errors(gt, moved, 1.0)
    assert np.max(t) < 1e-12 and np.max(r) < 1e-12
    # a 1 % scale error is 1 cm per metre
    t, r = P.relative_pose_errors(gt, gt * [1.01, 1.0, 1.0], 1.0)
    np.testing.assert_allclose(t, 0.01, rtol=0.011)  # segments of 1.00-1.01 m
    with pytest.raises(ValueError, match=r"shape \(N, 3\)"):
        P.relative_pose_errors(gt, gt[:, :2])


# ----------------------------------------------------------------------------- calib000 blocks


def test_arc_path_is_exact() -> None:
    start = np.array([0.0, -1.0, 0.0])
    path = P.arc_path(start, [(math.pi, 1.0), (0.5, 0.0)])
    assert path.length == pytest.approx(math.pi + 0.5)
    np.testing.assert_allclose(path.xy[-1], [-0.5, 1.0], atol=1e-9)
    assert path.heading[-1] == pytest.approx(math.pi)
    assert np.all(np.diff(path.s) > 0) and path.curvature[0] == 1.0
    with pytest.raises(ValueError, match="> 0 m"):
        P.arc_path(start, [(0.0, 1.0)])


def test_calibrated_reality_is_another_body() -> None:
    from realitygap.robots.diffdrive import DiffDriveParams

    cfg = P.CalibConfig()
    nominal = DiffDriveParams()
    true = cfg.reality().apply_params(nominal)
    assert true.wheel_radius_left == pytest.approx(1.05 * nominal.wheel_radius_left)
    assert true.wheel_radius_right == pytest.approx(0.98 * nominal.wheel_radius_right)
    assert true.wheelbase == pytest.approx(1.05 * nominal.wheelbase)
    np.testing.assert_allclose(
        np.array(true.camera.mount_xyz[:2]) - nominal.camera.mount_xyz[:2], [0.011, 0.008]
    )
    assert math.degrees(true.camera.mount_yaw - nominal.camera.mount_yaw) == pytest.approx(-1.0)


@pytest.fixture(scope="module")
def excitation_log() -> P.DriveLog:
    """A short figure-eight of the seed-000 robot, camera frames at 5 Hz (image mode)."""
    from realitygap.robots.diffdrive import DiffDriveParams

    cfg = P.CalibConfig()
    nominal = P._nominal_kinematics(DiffDriveParams())
    recorder = P.RecordingOdometry(nominal.scaled(1.05, 0.98, 1.05))
    env = P._make_calib_env(cfg, recorder, 5.0)
    start = np.zeros(3)
    try:
        path = P._figure_eight(start, ((0.45, 1),))
        return P.drive(env, recorder, P.PathFollower(P._timed(path, 0.35)), start, 3, 4000)
    finally:
        env.close()


def test_online_calibration_recovers_wheelbase_and_diameter_ratio(
    excitation_log: P.DriveLog,
) -> None:
    from realitygap.estimators.vo import VOParams
    from realitygap.robots.diffdrive import DiffDriveParams

    log = excitation_log
    assert not log.collided and len(log.frames) == len(log.frame_index) > 40
    nominal = P._nominal_kinematics(DiffDriveParams())
    inc, motions, weights, lost = P._sensor_motions_of(log, VOParams(seed=3))
    assert lost == 0
    # a UMBmark-like seed: ratio roughly right, wheelbase and mean size unknown
    fit = P.fit_odometry_and_mounting(
        inc, motions, nominal, [1.03, 0.96, 1.0], np.zeros(3), sensor_weights=weights
    )
    E_d, E_b = fit.scales[1] / fit.scales[0], fit.scales[2]
    assert E_b == pytest.approx(1.05, rel=0.01)
    assert E_d == pytest.approx(0.98 / 1.05, rel=0.01)
    assert fit.observable and fit.n_updates + fit.n_outliers == len(motions)
    assert np.hypot(*(fit.mounting[:2] - [0.011, 0.008])) < 0.01
    # the dead-reckoned drive with the fitted scales stays within a few centimetres
    odo = log.dead_reckon(nominal.scaled(*fit.scales))
    assert np.max(np.hypot(*(odo[:, :2] - log.gt[:, :2]).T)) < 0.03


def test_camera_loop_closure_of_a_frame_on_itself(excitation_log: P.DriveLog) -> None:
    f0 = excitation_log.frames[0]
    end = P.end_pose_from_frames([f0, f0], np.array([0.011, 0.008, -0.02]))
    assert end.source == "loop closure" and end.n_inliers >= 40
    np.testing.assert_allclose(end.base_motion, 0.0, atol=1e-6)
    with pytest.raises(ValueError, match="at least two frames"):
        P.end_pose_from_frames([f0], np.zeros(3))


def test_square_driver_closes_the_square_on_exact_odometry() -> None:
    import gymnasium as gym

    import realitygap  # noqa: F401
    from realitygap.robots.diffdrive import DiffDriveParams

    nominal = P._nominal_kinematics(DiffDriveParams())
    recorder = P.RecordingOdometry(nominal)
    env = gym.make(
        "realitygap/WheeledNav-v0",
        estimator=recorder,
        n_obstacles=0,
        start=(0.0, 0.0, 0.0),
        goal=(0.0, 0.5, 0.0),
        terminate_on_success=False,
        max_episode_steps=10_000,
    )
    try:
        for direction, start in (("cw", (-0.3, 0.3, 0.2)), ("ccw", (-0.3, -0.3, -0.2))):
            log = P.drive(env, recorder, P.SquareDriver(start, 0.6, direction), start, 0, 3000)
            sign = -1.0 if direction == "cw" else 1.0
            # the heading runs through ∓2π and the far corner is reached
            assert log.gt[-1, 2] - log.gt[0, 2] == pytest.approx(sign * 2 * math.pi, abs=0.02)
            far = se2_compose(np.asarray(start), np.array([0.6, sign * 0.6, 0.0]))
            assert np.min(np.hypot(*(log.gt[:, :2] - far[:2]).T)) < 0.01
            # nominal robot, nominal odometry: it comes back to where it started
            assert np.hypot(*(log.gt[-1, :2] - log.gt[0, :2])) < 0.01
            assert abs(wrap_angle(log.gt[-1, 2] - log.gt[0, 2])) < 0.01
    finally:
        env.close()
    with pytest.raises(ValueError, match="'cw' or 'ccw'"):
        P.SquareDriver((0, 0, 0), 1.0, "left")


# ----------------------------------------------------------------------------- umbmark-real


def _calibration(sid: str, b_nominal: float, d_nominal: float, e_b: float) -> SessionCalibration:
    return SessionCalibration(
        session_id=sid,
        path="",
        side_length=0.75,
        n_cw=3,
        n_ccw=3,
        E_d=0.999,
        E_b=e_b,
        c_L=1.0,
        c_R=1.0,
        alpha=0.0,
        beta=0.0,
        E_max_syst=0.0,
        nominal_D_L=d_nominal,
        nominal_D_R=d_nominal,
        nominal_b=b_nominal,
        D_L=d_nominal,
        D_R=d_nominal,
        b=e_b * b_nominal,
        b_over_D=e_b * b_nominal / d_nominal,
        ticks_per_rev=2796.8,
        recorded="",
    )


def test_transfer_does_not_depend_on_the_nominal_description() -> None:
    # one robot (b/D = 2.4) described once as b = 0.200 m and once as b = 0.205 m
    a = _calibration("230620202042", 0.200, 0.084, 2.4 * 0.084 / 0.200)
    b = _calibration("230620202144", 0.205, 0.084, 2.4 * 0.084 / 0.205)
    pooled = pool_calibrations([a, b])
    assert pooled.b_over_D == pytest.approx(2.4) and pooled.b_over_D_std < 1e-12
    held_out = DiffDriveKinematics.from_diameters(0.084, 0.084, 0.200, 2796.8)
    assert pooled.kinematics_for(held_out).wheelbase == pytest.approx(2.4 * 0.084)
    with pytest.raises(ValueError, match="at least one"):
        pool_calibrations([])


def test_same_period_picks_the_day_of_the_nearest_square_session() -> None:
    cals = [
        _calibration("230620202042", 0.2, 0.084, 1.0),
        _calibration("230620202317", 0.2, 0.084, 1.0),
        _calibration("231220200029", 0.2, 0.084, 1.0),
    ]
    assert [c.session_id for c in P._same_period("231220200121", cals)] == ["231220200029"]
    june = [c.session_id for c in P._same_period("250620202104", cals)]
    assert june == ["230620202042", "230620202317"]
    assert P._same_period("020120212354", cals)[0].session_id == "231220200029"
    assert len(P._same_period("not-a-date", cals)) == 3


def test_umbmark_real_improves_the_held_out_runs() -> None:
    if not DATA.is_dir():
        pytest.skip(f"OptiOdom data not found at {DATA}; needs ../shared/data beside the repo")
    from realitygap.experiments import RunContext

    ctx = RunContext(quick=True, data_dir=DATA.parent, verbose=False)
    out = EXPERIMENTS["umbmark-real"].func(ctx)
    fig = out["figures"]
    assert 0.99 < fig["E_d"] < 1.01 and 0.95 < fig["E_b"] < 1.05
    assert fig["heldout_end_err_cm_calibrated"] < fig["heldout_end_err_cm_nominal"]
    assert fig["heldout_ate_cm_calibrated"] < fig["heldout_ate_cm_nominal"]
    kinds = {r["path_type"] for r in out["tables"]["path_types"]}
    assert {"circular", "all"} <= kinds
    assert all(r["calibrated_from"] for r in out["tables"]["runs"])


def test_experiments_are_registered() -> None:
    for name in ("calib000", "vo", "umbmark-real"):
        assert name in EXPERIMENTS
    assert EXPERIMENTS["umbmark-real"].data_subdir == "optiodom_diffdrive"
    quick = P.CalibConfig.quick()
    assert replace(quick, runs_per_direction=2).iterations == 3
