"""The joint fit of wheel scale factors and sensor mounting on synthetic increments."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.estimators.diffdrive_model import DiffDriveKinematics, arc_increment
from realitygap.estimators.mounting_calibration import sensor_motion
from realitygap.estimators.odometry_mounting import (
    calibrate_until_precise,
    dead_reckoning_covariance,
    dispersion_ratio,
    fit_odometry_and_mounting,
    fit_pooled_drives,
    predicted_position_error,
    ticks_for_path,
)

NOMINAL = DiffDriveKinematics(0.035, 0.035, 0.23, 2578.0)
SCALES = np.array([1.02, 0.99, 1.04])
MOUNT = np.array([0.08, -0.02, 0.05])


def _samples(seed: int, n: int = 300, noise: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Tick increments of turns in both directions and the exact sensor motions of the true body."""
    rng = np.random.default_rng(seed)
    base = rng.uniform(80.0, 200.0, n)
    turn = rng.uniform(-120.0, 120.0, n)
    inc = np.round(np.stack([base - turn, base + turn], 1))
    ds, dth = NOMINAL.scaled(*SCALES).increment_from_ticks(inc[:, 0], inc[:, 1])
    z = np.asarray(sensor_motion(MOUNT, arc_increment(ds, dth)))
    return inc, z + noise * rng.standard_normal(z.shape)


@pytest.mark.parametrize("seed", range(2))
def test_recovers_scales_and_mounting(seed: int) -> None:
    inc, z = _samples(seed, noise=1e-4)
    fit = fit_odometry_and_mounting(inc, list(z), NOMINAL, np.ones(3), np.zeros(3))
    np.testing.assert_allclose(fit.scales, SCALES, atol=2e-3)
    np.testing.assert_allclose(fit.mounting, MOUNT, atol=5e-3)
    assert fit.observable and fit.n_updates + fit.n_outliers == len(z)
    assert fit.cov.shape == (6, 6) and fit.std.shape == (6,)


def test_missing_motions_only_predict_and_inputs_are_checked() -> None:
    inc, z = _samples(0, n=60)
    motions: list[np.ndarray | None] = list(z)
    motions[5] = None
    fit = fit_odometry_and_mounting(inc, motions, NOMINAL, np.ones(3), np.zeros(3), n_passes=1)
    assert fit.n_updates == 59 and fit.n_outliers == 0
    with pytest.raises(ValueError, match=r"shape \(K, 2\)"):
        fit_odometry_and_mounting(inc[:-1], motions, NOMINAL, np.ones(3), np.zeros(3))
    with pytest.raises(ValueError, match="n_passes"):
        fit_odometry_and_mounting(inc, motions, NOMINAL, np.ones(3), np.zeros(3), n_passes=0)
    with pytest.raises(ValueError, match="sensor_weights"):
        fit_odometry_and_mounting(
            inc, motions, NOMINAL, np.ones(3), np.zeros(3), sensor_weights=-np.ones(60)
        )
    with pytest.raises(ValueError, match="prior_cov"):
        fit_odometry_and_mounting(
            inc, motions, NOMINAL, np.ones(3), np.zeros(3), prior_cov=np.eye(3)
        )


def _drive(
    rng: np.random.Generator, n: int = 60, noise: float = 1e-3
) -> tuple[np.ndarray, list[np.ndarray | None], np.ndarray]:
    """One drive of the true body: tick increments, sensor motions with known noise, weights."""
    base = rng.uniform(80.0, 200.0, n)
    turn = rng.uniform(-120.0, 120.0, n)
    inc = np.round(np.stack([base - turn, base + turn], 1))
    ds, dth = NOMINAL.scaled(*SCALES).increment_from_ticks(inc[:, 0], inc[:, 1])
    z = np.asarray(sensor_motion(MOUNT, arc_increment(ds, dth)))
    w = rng.uniform(0.5, 2.0, n)
    z = z + noise * rng.standard_normal(z.shape) / np.sqrt(w)[:, None]
    return inc, list(z), w


def _semicircle(radius: float = 1.0, n: int = 300) -> tuple[np.ndarray, np.ndarray]:
    ds = np.full(n, np.pi * radius / n)
    return ds, ds / radius


def test_dead_reckoning_covariance_of_a_straight_drive_has_its_closed_form() -> None:
    """Straight drive of length L, only k_L uncertain (σ): σ_x = σL/2, σ_θ = σL/b, σ_y = σL²/2b."""
    L, sigma = 2.0, 1e-3
    ds = np.full(2000, L / 2000)
    inc = ticks_for_path(NOMINAL, ds, 0.0 * ds)
    cov = dead_reckoning_covariance(inc, NOMINAL, np.ones(3), np.diag([sigma**2, 0.0, 0.0]))
    b = NOMINAL.wheelbase
    np.testing.assert_allclose(
        np.sqrt(np.diag(cov[-1])), [sigma * L / 2, sigma * L**2 / (2 * b), sigma * L / b], rtol=5e-3
    )
    np.testing.assert_allclose(cov[0], 0.0, atol=1e-18)
    # ticks_for_path is the inverse of the kinematics: the drive ends where the path does
    end = NOMINAL.scaled(*SCALES).integrate(
        np.zeros(3), *ticks_for_path(NOMINAL.scaled(*SCALES), *_semicircle()).T, wrap=False
    )[-1]
    np.testing.assert_allclose(end, [0.0, 2.0, np.pi], atol=1e-9)
    with pytest.raises(ValueError, match="scales_cov must be a finite"):
        dead_reckoning_covariance(inc, NOMINAL, np.ones(3), np.eye(2))
    with pytest.raises(ValueError, match="reference path must be two equally long"):
        ticks_for_path(NOMINAL, ds, ds[:-1])


@pytest.mark.slow
def test_propagated_error_matches_the_scatter_over_repeated_draws() -> None:
    """Predicted RMS position error of a semicircle vs the empirical one over 40 calibrations."""
    rng = np.random.default_rng(7)
    path = _semicircle()
    sq_err, predicted = [], []
    for _ in range(40):
        fit = fit_pooled_drives([_drive(rng), _drive(rng)], NOMINAL, np.ones(3), np.zeros(3))
        predicted.append(
            predicted_position_error(path, NOMINAL, fit.scales, fit.cov[3:, 3:], n_sigma=1.0)
        )
        # the robot steers the path on its estimate; the true body goes elsewhere
        inc = ticks_for_path(NOMINAL.scaled(*fit.scales), *path)
        true = NOMINAL.scaled(*SCALES).integrate(np.zeros(3), inc[:, 0], inc[:, 1], wrap=False)
        believed = NOMINAL.scaled(*fit.scales).integrate(
            np.zeros(3), inc[:, 0], inc[:, 1], wrap=False
        )
        sq_err.append(np.sum((true[:, :2] - believed[:, :2]) ** 2, axis=1))
    empirical = float(np.sqrt(np.mean(sq_err, axis=0)).max())
    # 40 draws: the empirical RMS is known to about ±15 %
    assert 0.7 < empirical / float(np.mean(predicted)) < 1.4
    assert np.std(predicted) < 0.2 * np.mean(predicted)  # the prediction itself is stable


def test_sequential_calibration_stops_once_the_prediction_meets_the_target() -> None:
    rng = np.random.default_rng(11)
    path = _semicircle()

    def one_drive(r: int) -> tuple[list, np.ndarray, np.ndarray]:
        return [_drive(rng)], np.ones(3), np.zeros(3)

    free = calibrate_until_precise(one_drive, NOMINAL, [path], 1e-9, max_rounds=4)
    assert not free.reached and free.rounds == 4 and free.n_drives == 4
    h = np.array(free.predicted_error_m)
    # information grows with the drives: four drives ≈ half the error of one
    assert 0.35 < h[3] / h[0] < 0.7
    target = 0.5 * (h[1] + h[2])  # between the 2nd and 3rd round's predictions
    seen: list[int] = []
    seq = calibrate_until_precise(
        one_drive,
        NOMINAL,
        [path, (np.full(100, 0.02), np.zeros(100))],
        target,
        min_rounds=2,
        max_rounds=10,
        on_round=lambda r, fit, e: seen.append(r),
    )
    assert seq.reached and seq.predicted_error_m[-1] <= target
    assert all(e > target for e in seq.predicted_error_m[1:-1])  # never stopped late
    assert seen == list(range(1, seq.rounds + 1)) and seq.rounds < 10
    assert seq.fit.n_updates + seq.fit.n_outliers == 60 * seq.rounds
    with pytest.raises(ValueError, match="target_error_m must be a positive length"):
        calibrate_until_precise(one_drive, NOMINAL, [path], 0.0)
    with pytest.raises(ValueError, match="min_rounds <= max_rounds"):
        calibrate_until_precise(one_drive, NOMINAL, [path], 1e-3, min_rounds=3, max_rounds=2)
    with pytest.raises(ValueError, match="at least one"):
        calibrate_until_precise(one_drive, NOMINAL, [], 1e-3)


@pytest.mark.slow
def test_dispersion_widens_the_prediction_when_drives_share_an_error() -> None:
    """Each drive's sensor motions carry a scale error of their own (1 %): samples are no
    longer independent, the pooled covariance is too small, and the dispersion of the rounds'
    estimates restores the predicted error to the observed scatter."""
    rng = np.random.default_rng(5)
    path = _semicircle()

    def biased_drive(r: int) -> tuple[list, np.ndarray, np.ndarray]:
        inc, z, w = _drive(rng)
        scale = 1.0 + 0.01 * rng.standard_normal()
        return [(inc, [scale * zk for zk in z], w)], np.ones(3), np.zeros(3)

    sq_err, naive, widened, ratios = [], [], [], []
    for _ in range(16):
        seq = calibrate_until_precise(biased_drive, NOMINAL, [path], 1e-9, max_rounds=4)
        k = seq.fit.scales
        naive.append(predicted_position_error(path, NOMINAL, k, seq.fit.cov[3:, 3:], 1.0))
        widened.append(predicted_position_error(path, NOMINAL, k, seq.scales_cov, 1.0))
        ratios.append(seq.dispersion[-1])
        inc = ticks_for_path(NOMINAL.scaled(*k), *path)
        true = NOMINAL.scaled(*SCALES).integrate(np.zeros(3), inc[:, 0], inc[:, 1], wrap=False)
        sq_err.append(np.sum((true[:, :2] - _believed_positions(inc, k)) ** 2, axis=1))
    empirical = float(np.sqrt(np.mean(sq_err, axis=0)).max())
    assert np.isnan(seq.dispersion[0]) and np.median(ratios) > 1.3
    assert empirical / np.mean(naive) > 1.5  # the independent-sample covariance is too small
    assert 0.7 < empirical / np.mean(widened) < 1.4
    with pytest.raises(ValueError, match="one covariance per estimate"):
        dispersion_ratio([np.ones(3)], [], np.ones(3))


def _believed_positions(inc: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Positions (N, 2) the estimate ``k`` believes for the tick increments."""
    return NOMINAL.scaled(*k).integrate(np.zeros(3), inc[:, 0], inc[:, 1], wrap=False)[:, :2]


def test_loop_closures_remove_a_rotation_scale_error_of_the_frames() -> None:
    """Frame-to-frame motions that under-read rotation by 0.5 % bias the wheelbase scale;
    loop closures (net heading of whole circles, registered directly) recover it."""
    rng = np.random.default_rng(3)
    drives = []
    true = NOMINAL.scaled(*SCALES)
    for sign in (1.0, -1.0, 1.0, -1.0):
        inc, z, w = _drive(rng, n=80)
        z = [zk * np.array([1.0, 1.0, 0.995]) for zk in z]
        # a circle of radius 0.5 m driven both ways: net heading ±2π, measured to 0.3 mrad
        circle = ticks_for_path(
            true, np.full(200, np.pi / 200), np.full(200, sign * 2 * np.pi / 200)
        )
        z_loop = np.array([0.0, 0.0, 3e-4 * rng.standard_normal()])
        drives.append((inc, z, w, (circle.sum(0, keepdims=True), z_loop[None])))
    plain = fit_pooled_drives([d[:3] for d in drives], NOMINAL, np.ones(3), np.zeros(3))
    looped = fit_pooled_drives(drives, NOMINAL, np.ones(3), np.zeros(3))
    assert looped.n_loops == 4 and plain.n_loops == 0 and np.isnan(plain.loop_heading_std)
    assert abs(plain.scales[2] - SCALES[2]) > 3e-3  # the frames' rotation error shows in k_b
    assert abs(looped.scales[2] - SCALES[2]) < 1e-3
    assert looped.std[5] < plain.std[5]
    with pytest.raises(ValueError, match="loop_closures must be finite"):
        fit_odometry_and_mounting(
            drives[0][0],
            drives[0][1],
            NOMINAL,
            np.ones(3),
            np.zeros(3),
            loop_closures=(np.zeros((2, 2)), np.zeros((1, 3))),
        )
