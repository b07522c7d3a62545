"""Adsorption-constrained EKF on synthetic odometry."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from realitygap.core.geometry import quat_xyzw_from_matrix, rot_z
from realitygap.estimators.climb.constrained import ConstrainedConfig, ConstrainedEstimator
from realitygap.estimators.climb.measurements import ClimbEstimate, TetherReading
from realitygap.estimators.climb.surface import SurfaceModel
from realitygap.robots.blade_geometry import BladeSurface
from realitygap.robots.climb_synthetic import (
    ClimbScenario,
    TruthTrajectory,
)

SC = ClimbScenario()
ANCHOR = np.asarray(SC.anchor_cad)
PATH = (*SC.init_waypoints, (4.5, 0.12), (4.5, 0.3), (1.5, 0.3))


@pytest.fixture(scope="module")
def truth() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    traj = TruthTrajectory(
        BladeSurface(SC.blade),
        PATH,
        h=SC.h,
        speed=SC.speed,
        static_duration=0.0,
        corner_radius=SC.corner_radius,
    )
    t = np.arange(0.0, traj.duration, 0.1)
    p, R = traj.pose(t)
    return t, p, R


def _odometry(
    truth: tuple,
    rng: np.random.Generator | None,
    yaw_walk: float = 0.0,
    trans_sigma: float = 0.0,
    scale: float = 0.0,
) -> list[ClimbEstimate]:
    """VIO-like world-frame poses: true increments with yaw random walk and noise."""
    t, p, R = truth
    R_wg = rot_z(0.4)
    drift = np.zeros(len(t))
    if rng is not None:
        drift = np.cumsum(rng.normal(0, yaw_walk, len(t)))
    out: list[ClimbEstimate] = []
    pw = R_wg @ p[0] + [1.0, -2.0, 0.3]
    for k in range(len(t)):
        if k:
            step = p[k] - p[k - 1]
            noise = rng.normal(0, trans_sigma, 3) if rng is not None else 0.0
            pw = pw + R_wg @ rot_z(drift[k]) @ ((1 + scale) * step + noise)
        Rw = R_wg @ rot_z(drift[k]) @ R[k]
        out.append(ClimbEstimate(t=t[k], position=pw.copy(), quat_xyzw=quat_xyzw_from_matrix(Rw)))
    return out


def _run(
    surface: SurfaceModel,
    truth: tuple,
    vio: list[ClimbEstimate],
    config: ConstrainedConfig | None = None,
    lengths: np.ndarray | None = None,
    valid: np.ndarray | None = None,
) -> tuple[np.ndarray, list]:
    t, p, R = truth
    ekf = ConstrainedEstimator(surface, ANCHOR, SC.h, config)
    ekf.reset(
        ClimbEstimate(t=t[0], position=p[0], quat_xyzw=quat_xyzw_from_matrix(R[0]), frame="cad"),
        np.diag([1e-4] * 3 + [1e-4] * 3),
    )
    if lengths is None:
        lengths = np.linalg.norm(p - ANCHOR, axis=1)
    errors, estimates = [], []
    for k in range(len(t)):
        ekf.update(vio[k])
        ok = True if valid is None else bool(valid[k])
        est = ekf.update(TetherReading(t[k], float(lengths[k]), ok))
        errors.append(np.linalg.norm(est.position - p[k]))
        estimates.append(est)
    return np.array(errors), estimates


def _odometry_errors(truth: tuple, vio: list[ClimbEstimate]) -> np.ndarray:
    """Odometry error after aligning its start with the truth (its best case)."""
    _, p, _ = truth
    R_wg = rot_z(0.4)
    pw = np.array([e.position for e in vio])
    p_from_vio = (pw - pw[0]) @ R_wg + p[0]
    return np.linalg.norm(p_from_vio - p, axis=1)


@pytest.mark.slow
def test_perfect_odometry_stays_exact(surface: SurfaceModel, truth: tuple) -> None:
    errors, est = _run(surface, truth, _odometry(truth, None))
    assert errors.max() < 0.002
    assert all(e.ok and e.status == "ok" and e.frame == "cad" for e in est)
    assert np.all(np.linalg.eigvalsh(est[-1].cov) > 0)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(5))
def test_constrained_beats_odometry_and_is_bounded(
    surface: SurfaceModel, truth: tuple, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    vio = _odometry(truth, rng, yaw_walk=0.002, trans_sigma=3e-4, scale=0.005)
    odo = _odometry_errors(truth, vio)
    constrained, _ = _run(surface, truth, vio)
    tether_only, _ = _run(surface, truth, vio, ConstrainedConfig(use_surface=False))
    assert constrained.max() < odo.max()
    assert constrained.max() < tether_only.max()
    # bounded: no growth with distance (the second half is no worse than a fixed bound)
    half = len(constrained) // 2
    assert constrained.max() < 0.05
    assert constrained[half:].max() < 0.05


def test_slack_tether_is_down_weighted(surface: SurfaceModel, truth: tuple) -> None:
    t, p, _ = truth
    lengths = np.linalg.norm(p - ANCHOR, axis=1)
    slack = (t > 10.0) & (t < 11.0)
    lengths[slack] += 0.04
    errors, est = _run(surface, truth, _odometry(truth, None), lengths=lengths)
    flagged = [e for e, s in zip(est, slack) if s]
    assert all("tether_slack" in e.status for e in flagged)
    assert all(e.extras["tether_weight"] < 1.0 for e in flagged)
    assert errors.max() < 0.01
    assert est[-1].status == "ok"


def test_jump_and_invalid_readings_are_skipped(surface: SurfaceModel, truth: tuple) -> None:
    t, p, _ = truth
    lengths = np.linalg.norm(p - ANCHOR, axis=1)
    k = int(np.searchsorted(t, 12.0))
    lengths[k] += 0.3
    valid = np.ones(len(t), bool)
    valid[k + 5] = False
    errors, est = _run(surface, truth, _odometry(truth, None), lengths=lengths, valid=valid)
    assert "tether_jump" in est[k].status
    assert "tether_invalid" in est[k + 5].status
    assert errors.max() < 0.002


def test_detachment_is_detected(surface: SurfaceModel, truth: tuple) -> None:
    t, p, R = truth
    vio = _odometry(truth, None)
    lifted = vio[:60] + [
        dataclasses.replace(e, position=e.position + 0.06 * (rot_z(0.4) @ R[k][:, 2]))
        for k, e in enumerate(vio[60:80], start=60)
    ]
    ekf = ConstrainedEstimator(surface, ANCHOR, SC.h, ConstrainedConfig(use_tether=False))
    ekf.reset(
        ClimbEstimate(t=t[0], position=p[0], quat_xyzw=quat_xyzw_from_matrix(R[0]), frame="cad"),
        np.diag([1e-6] * 6),
    )
    statuses = [ekf.update(e) for e in lifted]
    assert all(e.ok for e in statuses[:60])
    assert "detached" in statuses[-1].status and not statuses[-1].ok


def test_errors(surface: SurfaceModel) -> None:
    with pytest.raises(ValueError, match="anchor_cad"):
        ConstrainedEstimator(surface, [0.0, 1.0], 0.08)
    with pytest.raises(TypeError, match="SurfaceModel"):
        ConstrainedEstimator("cad", ANCHOR, 0.08)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="tether_sigma"):
        ConstrainedConfig(tether_sigma=0.0)
    ekf = ConstrainedEstimator(surface, ANCHOR, 0.08)
    assert not ekf.update(None).ok and ekf.estimate().status == "not_initialised"
    world = ClimbEstimate(t=0.0, position=np.zeros(3), quat_xyzw=np.array([0, 0, 0, 1.0]))
    with pytest.raises(ValueError, match="CAD-frame"):
        ekf.reset(world)
    ekf.reset(dataclasses.replace(world, frame="cad"))
    with pytest.raises(ValueError, match="world frame"):
        ekf.update(dataclasses.replace(world, frame="cad"))
    with pytest.raises(TypeError, match="ClimbEstimate"):
        ekf.update(3.0)  # type: ignore[arg-type]


def test_increment_is_taken_within_the_current_vio_solution(surface: SurfaceModel) -> None:
    """The previous keyframe as re-estimated in the VIO's current window (extras) is
    the start of the increment, not its stale estimate from one keyframe earlier."""
    cfg = ConstrainedConfig(use_tether=False, use_surface=False, use_gravity=False)
    ekf = ConstrainedEstimator(surface, ANCHOR, SC.h, cfg)
    start = ClimbEstimate(t=0.0, position=np.zeros(3), quat_xyzw=np.array([0, 0, 0, 1.0]))
    ekf.reset(dataclasses.replace(start, frame="cad"))
    ekf.update(start)
    refined_prev = (0.0, np.array([0.004, -0.003, 0.0]), np.eye(3))
    new = ClimbEstimate(
        t=0.1,
        position=np.array([0.1, 0.0, 0.0]),
        quat_xyzw=np.array([0, 0, 0, 1.0]),
        extras={"previous_keyframe": refined_prev},
    )
    est = ekf.update(new)
    np.testing.assert_allclose(est.position, [0.096, 0.003, 0.0], atol=1e-12)
    # a previous keyframe of another time (e.g. after a reset) is not used
    later = ClimbEstimate(
        t=0.2,
        position=np.array([0.2, 0.0, 0.0]),
        quat_xyzw=np.array([0, 0, 0, 1.0]),
        extras={"previous_keyframe": (0.15, np.zeros(3), np.eye(3))},
    )
    np.testing.assert_allclose(ekf.update(later).position, [0.196, 0.003, 0.0], atol=1e-12)
