"""Odometry integration (diffdrive_model) and Borenstein's UMBmark."""

from __future__ import annotations

import math

import numpy as np
import pytest

from realitygap.core.geometry import se2_compose
from realitygap.estimators.base import Estimate, Estimator, WheelTicks
from realitygap.estimators.diffdrive_model import (
    DiffDriveKinematics,
    OdometryNoise,
    WheelOdometry,
    arc_increment,
    arc_increment_jacobian,
    integrate_arcs,
)
from realitygap.estimators.umbmark import (
    UMBmarkRun,
    end_pose_error,
    umbmark,
    umbmark_end_errors,
    umbmark_from_runs,
)

NOMINAL = DiffDriveKinematics.from_diameters(0.084, 0.084, 0.20, 2796.8)


# ---------------------------------------------------------------------------
# kinematics
# ---------------------------------------------------------------------------


def test_kinematics_rejects_bad_parameters() -> None:
    with pytest.raises(ValueError, match="wheelbase must be a finite positive number"):
        DiffDriveKinematics(0.04, 0.04, 0.0, 1000.0)
    with pytest.raises(ValueError, match="ticks_per_rev must be a finite positive number"):
        DiffDriveKinematics(0.04, 0.04, 0.2, float("nan"))


@pytest.mark.parametrize("seed", range(5))
def test_straight_line_is_exact(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pose0 = np.array([*rng.uniform(-2, 2, 2), rng.uniform(-math.pi, math.pi)])
    ticks = rng.integers(-50, 200, size=40).astype(float)
    poses = NOMINAL.integrate(pose0, ticks, ticks)
    dist = np.concatenate(([0.0], np.cumsum(ticks))) * NOMINAL.meters_per_tick_left
    expected_x = pose0[0] + dist * math.cos(pose0[2])
    expected_y = pose0[1] + dist * math.sin(pose0[2])
    np.testing.assert_allclose(poses[:, 0], expected_x, atol=1e-12)
    np.testing.assert_allclose(poses[:, 1], expected_y, atol=1e-12)
    np.testing.assert_allclose(poses[:, 2], pose0[2], atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_pure_rotation_is_exact(seed: int) -> None:
    rng = np.random.default_rng(seed)
    pose0 = np.array([*rng.uniform(-2, 2, 2), rng.uniform(-math.pi, math.pi)])
    ticks = rng.integers(-300, 300, size=25).astype(float)
    poses = NOMINAL.integrate(pose0, -ticks, ticks, wrap=False)
    np.testing.assert_allclose(poses[:, :2], np.broadcast_to(pose0[:2], (26, 2)), atol=1e-12)
    dtheta = 2.0 * ticks * NOMINAL.meters_per_tick_left / NOMINAL.wheelbase
    np.testing.assert_allclose(poses[1:, 2], pose0[2] + np.cumsum(dtheta), atol=1e-12)


def test_constant_curvature_stays_on_the_circle() -> None:
    n_left, n_right = 100.0, 140.0
    poses = NOMINAL.integrate(np.zeros(3), np.full(300, n_left), np.full(300, n_right))
    s_l = n_left * NOMINAL.meters_per_tick_left
    s_r = n_right * NOMINAL.meters_per_tick_right
    radius = 0.5 * NOMINAL.wheelbase * (s_r + s_l) / (s_r - s_l)
    dist_to_centre = np.hypot(poses[:, 0], poses[:, 1] - radius)
    np.testing.assert_allclose(dist_to_centre, radius, rtol=1e-12)


def test_integration_is_invariant_to_subdividing_steps() -> None:
    rng = np.random.default_rng(3)
    d_l, d_r = rng.uniform(-40, 120, 50), rng.uniform(-40, 120, 50)
    coarse = NOMINAL.integrate([0.3, -0.2, 1.0], d_l, d_r)
    fine = NOMINAL.integrate([0.3, -0.2, 1.0], np.repeat(d_l / 7, 7), np.repeat(d_r / 7, 7))
    np.testing.assert_allclose(fine[::7], coarse, atol=1e-12)


def test_integration_matches_sequential_compounding() -> None:
    rng = np.random.default_rng(4)
    ds, dth = rng.uniform(-0.05, 0.1, 200), rng.uniform(-0.4, 0.4, 200)
    poses = integrate_arcs([1.0, 2.0, -3.0], ds, dth)
    q = np.array([1.0, 2.0, -3.0])
    for k in range(200):
        q = se2_compose(q, arc_increment(ds[k], dth[k]))
    np.testing.assert_allclose(poses[-1], q, atol=1e-10)


def test_increment_from_ticks_scalar_and_vector() -> None:
    ds, dth = NOMINAL.increment_from_ticks(4, 0)
    assert isinstance(ds, float)
    assert ds == pytest.approx(2 * math.pi * 0.042 * 4 / 2796.8 / 2)
    assert dth == pytest.approx(-2 * ds / 0.2)
    ds_v, dth_v = NOMINAL.increment_from_ticks(np.array([4, 0]), np.array([0, 4]))
    np.testing.assert_allclose(ds_v, [ds, ds])
    np.testing.assert_allclose(dth_v, [dth, -dth])


def test_integrate_validates_input() -> None:
    with pytest.raises(ValueError, match="equal length"):
        NOMINAL.integrate(np.zeros(3), np.zeros(3), np.zeros(4))
    with pytest.raises(ValueError, match="finite"):
        NOMINAL.integrate(np.zeros(3), [1.0, np.nan], [1.0, 1.0])
    with pytest.raises(ValueError, match=r"pose0 must have shape \(3,\)"):
        NOMINAL.integrate(np.zeros(2), [1.0], [1.0])


@pytest.mark.parametrize("dtheta", [0.0, 1e-7, 3e-3, 9.9e-3, 1.01e-2, 0.3, -2.5])
def test_arc_jacobian_matches_finite_differences(dtheta: float) -> None:
    ds, eps = 0.07, 1e-6
    J = arc_increment_jacobian(ds, dtheta)
    num = np.column_stack(
        [
            (arc_increment(ds + eps, dtheta) - arc_increment(ds - eps, dtheta)) / (2 * eps),
            (arc_increment(ds, dtheta + eps) - arc_increment(ds, dtheta - eps)) / (2 * eps),
        ]
    )
    np.testing.assert_allclose(J, num, atol=1e-9)


def test_with_umbmark_factors() -> None:
    kin = NOMINAL.with_umbmark(1.01, 0.98)
    c_l = kin.wheel_radius_left / NOMINAL.wheel_radius_left
    c_r = kin.wheel_radius_right / NOMINAL.wheel_radius_right
    assert c_l + c_r == pytest.approx(2.0)
    assert c_r / c_l == pytest.approx(1.01)
    assert kin.wheelbase == pytest.approx(0.98 * NOMINAL.wheelbase)
    with pytest.raises(ValueError, match="E_d must be a finite positive number"):
        NOMINAL.with_umbmark(-1.0, 1.0)


# ---------------------------------------------------------------------------
# WheelOdometry
# ---------------------------------------------------------------------------


def _cumulative_ticks(d_left: np.ndarray, d_right: np.ndarray, tpr: float) -> list[WheelTicks]:
    cum_l = np.concatenate(([0], np.cumsum(d_left))).astype(int)
    cum_r = np.concatenate(([0], np.cumsum(d_right))).astype(int)
    return [
        WheelTicks(t=0.05 * k, left=int(cum_l[k]), right=int(cum_r[k]), ticks_per_rev=tpr)
        for k in range(cum_l.shape[0])
    ]


def test_wheel_odometry_matches_integrate_and_grows_covariance() -> None:
    rng = np.random.default_rng(5)
    d_l, d_r = rng.integers(0, 60, 100), rng.integers(0, 60, 100)
    odo = WheelOdometry(NOMINAL, OdometryNoise())
    assert isinstance(odo, Estimator)
    odo.reset([0.5, -0.5, 0.2])
    traces = []
    for m in _cumulative_ticks(d_l, d_r, NOMINAL.ticks_per_rev):
        est = odo.update(m)
        traces.append(np.trace(est.cov))
    expected = NOMINAL.integrate([0.5, -0.5, 0.2], d_l, d_r)[-1]
    np.testing.assert_allclose(est.pose, expected, atol=1e-12)
    assert np.all(np.diff(traces) >= -1e-15) and traces[-1] > 0
    assert np.all(np.linalg.eigvalsh(est.cov) >= -1e-15)
    assert odo.update(None) is est


def test_wheel_odometry_converts_with_measurement_resolution() -> None:
    odo = WheelOdometry(NOMINAL)
    odo.reset()
    odo.update(WheelTicks(0.0, 0, 0, ticks_per_rev=1000.0))
    est = odo.update(WheelTicks(0.1, 1000, 1000, ticks_per_rev=1000.0))
    assert est.pose[0] == pytest.approx(2 * math.pi * NOMINAL.wheel_radius_left)


def test_wheel_odometry_rejects_bad_ticks_and_keeps_state() -> None:
    odo = WheelOdometry(NOMINAL)
    odo.reset(Estimate(t=0.0, pose=np.array([1.0, 2.0, 0.5]), cov=np.eye(3) * 1e-4))
    odo.update(WheelTicks(0.0, 0, 0, NOMINAL.ticks_per_rev))
    good = odo.update(WheelTicks(0.05, 10, 12, NOMINAL.ticks_per_rev))
    bad = odo.update(WheelTicks(0.10, float("nan"), 12, NOMINAL.ticks_per_rev))  # type: ignore[arg-type]
    assert bad.status.startswith("rejected: non-finite")
    assert bad.extras["n_rejected"] == 1
    np.testing.assert_array_equal(bad.pose, good.pose)
    back = odo.update(WheelTicks(0.01, 20, 20, NOMINAL.ticks_per_rev))
    assert "time went backwards" in back.status
    with pytest.raises(TypeError, match="expects WheelTicks or None"):
        odo.update(np.zeros(2))  # type: ignore[arg-type]


# ---------------------------------------------------------------------------
# UMBmark
# ---------------------------------------------------------------------------


def _square_ticks(
    kin: DiffDriveKinematics, side: float, direction: str, steps: int = 40
) -> tuple[np.ndarray, np.ndarray]:
    """Ticks of a robot steering an exact square by its own (nominal) odometry."""
    m = kin.meters_per_tick_left
    leg = np.full(steps, side / m / steps)
    turn = np.full(steps, 0.25 * math.pi * kin.wheelbase / m / steps)
    sign = 1.0 if direction == "ccw" else -1.0
    left, right = [np.zeros(1)], [np.zeros(1)]
    for _ in range(4):
        left += [leg, -sign * turn]
        right += [leg, sign * turn]
    return np.concatenate(left), np.concatenate(right)


def _simulated_runs(
    e_d: float, e_b: float, side: float, n: int = 2, frame: np.ndarray | None = None
) -> list[UMBmarkRun]:
    true = NOMINAL.with_umbmark(e_d, e_b)
    runs = []
    for direction in ("cw", "ccw"):
        left, right = _square_ticks(NOMINAL, side, direction)
        gt = true.integrate(np.zeros(3), left, right)[1:]
        if frame is not None:
            gt = se2_compose(frame, gt)
        runs += [UMBmarkRun(gt, left, right, direction)] * n  # type: ignore[arg-type]
    return runs


def test_first_order_errors_invert_exactly() -> None:
    L, b, alpha, beta = 3.0, 0.4, 0.012, -0.007
    cw = [[-2 * L * (alpha + beta), -2 * L * (alpha + beta), 0.0]]
    ccw = [[2 * L * (beta - alpha), -2 * L * (beta - alpha), 0.0]]
    res = umbmark(cw, ccw, L, b)
    assert res.alpha == pytest.approx(alpha)
    assert res.beta == pytest.approx(beta)
    radius = (L / 2) / math.sin(beta / 2)
    assert res.radius == pytest.approx(radius)
    assert res.E_d == pytest.approx((radius + b / 2) / (radius - b / 2))
    assert res.E_b == pytest.approx((math.pi / 2) / (math.pi / 2 - alpha))
    assert res.c_L == pytest.approx(2 / (res.E_d + 1))
    assert res.c_R == pytest.approx(2 / (1 / res.E_d + 1))
    assert res.E_max_syst == pytest.approx(max(math.hypot(*cw[0][:2]), math.hypot(*ccw[0][:2])))


@pytest.mark.parametrize("seed", range(8))
def test_recovers_simulated_wheel_and_wheelbase_errors(seed: int) -> None:
    rng = np.random.default_rng(seed)
    e_d, e_b = 1.0 + rng.uniform(-3e-3, 3e-3), 1.0 + rng.uniform(-1e-2, 1e-2)
    res = umbmark_from_runs(_simulated_runs(e_d, e_b, 1.0), NOMINAL, 1.0)
    # first order: the remaining error is quadratic in the deviations
    size = max(abs(e_d - 1.0) / 3e-3, abs(e_b - 1.0) / 1e-2)
    assert abs(res.E_d - e_d) < 2e-4 * size**2 + 1e-7
    assert abs(res.E_b - e_b) < 5e-4 * size**2 + 1e-7


def test_residual_error_is_second_order() -> None:
    big = umbmark_from_runs(_simulated_runs(1.004, 1.02, 1.0), NOMINAL, 1.0)
    small = umbmark_from_runs(_simulated_runs(1.002, 1.01, 1.0), NOMINAL, 1.0)
    ratio_b = abs(big.E_b - 1.02) / abs(small.E_b - 1.01)
    ratio_d = abs(big.E_d - 1.004) / abs(small.E_d - 1.002)
    assert 3.0 < ratio_b < 5.0 and 3.0 < ratio_d < 5.0


def test_sign_conventions() -> None:
    res = umbmark_from_runs(_simulated_runs(1.002, 1.0, 1.0), NOMINAL, 1.0)
    assert res.beta > 0 and res.radius > 0 and res.E_d > 1  # D_R > D_L curves left
    res = umbmark_from_runs(_simulated_runs(1.0, 1.01, 1.0), NOMINAL, 1.0)
    assert res.alpha > 0 and res.E_b > 1  # long wheelbase: turns fall short
    assert res.E_d == 1.0 and math.isinf(res.radius)


def test_correction_closes_the_square() -> None:
    runs = _simulated_runs(0.998, 1.008, 1.0)
    res = umbmark_from_runs(runs, NOMINAL, 1.0)
    before = np.abs(np.vstack(umbmark_end_errors(runs, NOMINAL))[:, :2]).max()
    after = np.abs(np.vstack(umbmark_end_errors(runs, res.corrected(NOMINAL)))[:, :2]).max()
    assert before > 0.02
    assert after < before / 20


def test_ground_truth_in_any_fixed_frame() -> None:
    base = umbmark_from_runs(_simulated_runs(1.002, 1.01, 1.0), NOMINAL, 1.0)
    moved = umbmark_from_runs(
        _simulated_runs(1.002, 1.01, 1.0, frame=np.array([3.0, -1.0, 2.0])), NOMINAL, 1.0
    )
    assert moved.E_d == pytest.approx(base.E_d, abs=1e-12)
    assert moved.E_b == pytest.approx(base.E_b, abs=1e-12)


def test_runs_as_plain_tuples() -> None:
    runs = _simulated_runs(1.002, 1.01, 1.0)
    as_tuples = [(r.gt_poses, r.ticks_left, r.ticks_right, r.direction) for r in runs]
    assert umbmark_from_runs(as_tuples, NOMINAL, 1.0) == umbmark_from_runs(runs, NOMINAL, 1.0)


def test_end_pose_error_definition() -> None:
    left, right = _square_ticks(NOMINAL, 1.0, "cw")
    gt = NOMINAL.integrate(np.zeros(3), left, right)[1:]
    gt[-1] += [0.01, -0.02, 0.03]
    eps = end_pose_error(gt, left, right, NOMINAL)
    np.testing.assert_allclose(eps, [0.01, -0.02, 0.03], atol=1e-9)


def test_one_direction_only_raises() -> None:
    cw_only = [r for r in _simulated_runs(1.0, 1.0, 1.0) if r.direction == "cw"]
    with pytest.raises(
        ValueError,
        match="UMBmark needs both clockwise and counter-clockwise runs; got only cw",
    ):
        umbmark_from_runs(cw_only, NOMINAL, 1.0)
    ccw_only = [r for r in _simulated_runs(1.0, 1.0, 1.0) if r.direction == "ccw"]
    with pytest.raises(ValueError, match="got only ccw"):
        umbmark_from_runs(ccw_only, NOMINAL, 1.0)
    with pytest.raises(ValueError, match="got no runs"):
        umbmark_from_runs([], NOMINAL, 1.0)
    with pytest.raises(ValueError, match="clockwise and counter-clockwise"):
        umbmark(np.zeros((0, 3)), np.zeros((2, 3)), 1.0, 0.2)


def test_error_paths() -> None:
    run = _simulated_runs(1.0, 1.0, 1.0)[0]
    bad = UMBmarkRun(run.gt_poses, run.ticks_left, run.ticks_right, "clockwise")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"direction must be 'cw' or 'ccw', got 'clockwise'"):
        umbmark_from_runs([bad], NOMINAL, 1.0)
    with pytest.raises(TypeError, match="must be an UMBmarkRun or a tuple"):
        umbmark_from_runs([42], NOMINAL, 1.0)  # type: ignore[list-item]
    with pytest.raises(ValueError, match="side_length must be a positive length"):
        umbmark(np.zeros((1, 3)), np.zeros((1, 3)), 0.0, 0.2)
    with pytest.raises(ValueError, match="wheelbase must be a positive length"):
        umbmark(np.zeros((1, 3)), np.zeros((1, 3)), 1.0, -0.2)
    with pytest.raises(ValueError, match=r"cw_errors must have shape \(n, 3\)"):
        umbmark(np.zeros((1, 4)), np.zeros((1, 3)), 1.0, 0.2)
    with pytest.raises(ValueError, match="ccw_errors must be finite"):
        umbmark(np.zeros((1, 3)), [[np.nan, 0, 0]], 1.0, 0.2)
    with pytest.raises(ValueError, match="outside the first-order model"):
        umbmark([[-5.0, 0, 0]], [[-5.0, 0, 0]], 1.0, 0.2)
    with pytest.raises(ValueError, match=r"ticks_left/ticks_right must have shape \(5,\)"):
        end_pose_error(np.zeros((5, 3)), np.zeros(4), np.zeros(4), NOMINAL)
