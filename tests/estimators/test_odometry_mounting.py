"""The joint fit of wheel scale factors and sensor mounting on synthetic increments."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.estimators.diffdrive_model import DiffDriveKinematics, arc_increment
from realitygap.estimators.mounting_calibration import sensor_motion
from realitygap.estimators.odometry_mounting import fit_odometry_and_mounting

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
