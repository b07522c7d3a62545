"""Synthetic ground truth, measurement synthesis and the end-to-end evaluation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from realitygap.core.geometry import so3_log
from realitygap.estimators.climb.measurements import ImuSample, RelativeMotion, TetherReading
from realitygap.estimators.climb.preintegration import Preintegration
from realitygap.estimators.climb.surface import SurfaceModel
from realitygap.estimators.climb.vio import VioConfig
from realitygap.robots.blade_geometry import BladeSurface, cad_point_cloud
from realitygap.robots.climb_evaluation import EvaluationReport, evaluate_recording
from realitygap.robots.climb_synthetic import (
    ClimbScenario,
    NoiseModel,
    TruthTrajectory,
    render_planar_view,
    synthesise_recording,
)

SC = ClimbScenario()
QUIET = NoiseModel(
    gyro_noise_density=0.0,
    accel_noise_density=0.0,
    gyro_bias_walk=0.0,
    accel_bias_walk=0.0,
    gyro_bias_sigma=0.0,
    accel_bias_sigma=0.0,
    visual_rotation_sigma=0.0,
    visual_translation_sigma=0.0,
    visual_translation_rel=0.0,
    visual_scale_sigma=0.0,
    tether_sigma=0.0,
)
FAST = dataclasses.replace(SC, speed=0.2, camera_rate=5.0, sweep_waypoints=((3.2, 0.12),))


@pytest.fixture(scope="module")
def surface() -> SurfaceModel:
    pts, nrm = cad_point_cloud(SC.blade, 0.01)
    keep = pts[:, 0] < 4.0
    return SurfaceModel(pts[keep], nrm[keep])


def test_truth_trajectory_sits_on_the_surface(surface: SurfaceModel) -> None:
    traj = TruthTrajectory(
        BladeSurface(SC.blade),
        SC.init_waypoints,
        h=SC.h,
        speed=SC.speed,
        static_duration=1.0,
        corner_radius=SC.corner_radius,
    )
    t = np.linspace(0.0, traj.duration, 400)
    p, R = traj.pose(t)
    np.testing.assert_allclose(
        np.einsum("kji,kjl->kil", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    pr = surface.project(p, R[:, :, 2], SC.h)
    assert np.all(pr.ok) and np.abs(pr.offset).max() < 1e-4
    angle = np.arccos(np.clip(np.einsum("ij,ij->i", pr.normal, R[:, :, 2]), -1, 1))
    assert np.degrees(angle).max() < 0.1
    v = traj.velocity(t)
    assert np.allclose(v[t < 1.0], 0.0)
    cruise = (t > 2.5) & (t < traj.duration - 2.5)
    speed = np.linalg.norm(v[cruise], axis=1)
    assert np.median(np.abs(speed - SC.speed)) < 1e-4 * SC.speed
    np.testing.assert_allclose(speed, SC.speed, rtol=0.03)  # corners: spline arclength
    # heading along the motion
    assert np.all(np.einsum("ij,ij->i", v[cruise], R[cruise, :, 0]) > 0.95 * SC.speed)
    assert np.all(np.diff(traj.waypoint_arclength) > 0)
    assert traj.waypoint_arclength[-1] == pytest.approx(traj.length, abs=0.01)


def test_noise_free_measurements_match_the_truth() -> None:
    sc = dataclasses.replace(SC, noise=QUIET)
    rec = synthesise_recording(sc, np.random.default_rng(0), sweep=False)
    imu = [m for m in rec.measurements if isinstance(m, ImuSample)]
    vis = [m for m in rec.measurements if isinstance(m, RelativeMotion)]
    teth = [m for m in rec.measurements if isinstance(m, TetherReading)]
    # pre-integrating the IMU between two instants reproduces the truth: the velocity
    # exactly (by construction), the position to O(dt³) per sample
    traj = TruthTrajectory(
        BladeSurface(sc.blade),
        sc.init_waypoints,
        h=sc.h,
        speed=sc.speed,
        static_duration=sc.static_duration,
        corner_radius=sc.corner_radius,
    )
    dt = 1.0 / sc.imu_rate
    for t0, t1 in ((3.0, 5.0), (12.0, 14.0)):
        pre = Preintegration()
        for m in imu:
            if t0 - 1e-9 <= m.t < t1 - 1e-9:
                pre.integrate(m.gyro, m.accel, dt)
        p0, R0 = traj.pose(t0)
        p1, R1 = traj.pose(t1)
        R_j, p_j, v_j = pre.predict(R0, p0, traj.velocity(t0), np.array([0, 0, -9.81]))
        np.testing.assert_allclose(v_j, traj.velocity(t1), atol=1e-9)
        assert np.linalg.norm(p_j - p1) < 1e-5
        assert np.linalg.norm(so3_log(R_j.T @ R1)) < 1e-9
    # visual motions are the true camera motions
    cfg = VioConfig()
    m = vis[90]
    (pa,), (Ra,) = rec.truth_at(m.t0)
    (pb,), (Rb,) = rec.truth_at(m.t1)
    Rca, Rcb = Ra @ cfg.R_bc, Rb @ cfg.R_bc
    np.testing.assert_allclose(m.rotation, Rca.T @ Rcb, atol=1e-9)
    np.testing.assert_allclose(
        m.translation, Rca.T @ (pb + Rb @ cfg.p_bc - pa - Ra @ cfg.p_bc), atol=1e-9
    )
    # tether lengths are the distances to the anchor
    (pt,), _ = rec.truth_at(teth[120].t)
    assert teth[120].length == pytest.approx(np.linalg.norm(pt - rec.anchor_cad), abs=1e-9)
    times = [getattr(x, "t", getattr(x, "t1", 0.0)) for x in rec.measurements]
    assert np.all(np.diff(times) >= 0)


def test_slack_episodes_lengthen_the_tether() -> None:
    noise = dataclasses.replace(QUIET, tether_slack_rate=0.2, tether_invalid=0.1)
    rec = synthesise_recording(
        dataclasses.replace(SC, noise=noise), np.random.default_rng(2), sweep=False
    )
    teth = [m for m in rec.measurements if isinstance(m, TetherReading)]
    p, _ = rec.truth_at(np.array([m.t for m in teth]))
    excess = np.array([m.length for m in teth]) - np.linalg.norm(p - rec.anchor_cad, axis=1)
    assert excess.min() > -1e-9 and excess.max() >= 0.02
    assert 0 < sum(not m.ok for m in teth) < len(teth)


@pytest.mark.slow
def test_end_to_end_evaluation(surface: SurfaceModel) -> None:
    rec = synthesise_recording(FAST, np.random.default_rng(3))
    m = evaluate_recording(rec, surface)
    assert m.distance > 0.5
    for est in (m.vio, m.vio_tether, m.constrained, m.vio_aligned):
        assert np.isfinite(est.max_error) and est.max_error >= est.rms_error >= 0
        assert est.max_drift_pct == pytest.approx(100 * est.max_error / m.distance)
    assert m.constrained.max_error < 0.03
    assert m.init_yaw_error_deg < 1.0 and m.init_position_error_cm < 3.0
    assert m.init_heading_error_deg < 1.0
    assert m.init_status == "ok"
    assert dict(m.status_counts).get("ok", 0) > 0
    summary = EvaluationReport((3,), (m,)).summary()
    assert summary["constrained_max_drift_pct_worst"] == pytest.approx(m.constrained.max_drift_pct)
    assert summary["min_distance_m"] == pytest.approx(m.distance)


def test_errors() -> None:
    with pytest.raises(ValueError, match="speed"):
        ClimbScenario(speed=0.0)
    with pytest.raises(ValueError, match="on the blade"):
        ClimbScenario(sweep_waypoints=((9.0, 0.3),))
    with pytest.raises(ValueError, match="imu_rate"):
        ClimbScenario(imu_rate=20.0)
    tex = np.zeros((8, 8), np.uint8)
    with pytest.raises(ValueError, match="above the plane"):
        render_planar_view(tex, 0.001, np.eye(3), (8, 8), np.eye(3), [0.0, 0.0, -1.0])
    with pytest.raises(ValueError, match="texel_size"):
        render_planar_view(tex, 0.0, np.eye(3), (8, 8), np.eye(3), [0.0, 0.0, 1.0])
