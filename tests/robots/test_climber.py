"""Properties of the simulated climber: adsorption, tether, IMU, effects."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.robots.climber import (
    BodyState,
    ClimberParams,
    ClimberRobot,
    ClimbFaults,
    ClimbWorld,
    chart_pose,
)
from realitygap.robots.climber_sensors import ImuModel, TetherModel
from realitygap.robots.effects import Reality, make_effect


def _hold(pitch: float, scale: float, seconds: float = 2.0) -> tuple[float, float]:
    prm = ClimberParams(mount_pitch=pitch)
    scene = ClimbWorld(prm)
    try:
        robot = ClimberRobot(scene, prm)
        pos, R = chart_pose(scene.surface, prm, 3.0, 0.3, 0.0, prm.h_true)
        robot.reset(pos, R)
        robot.adsorption_scale = scale
        c = scene.world.bullet
        for _ in range(int(seconds * 240)):
            robot.apply_adsorption()
            c.stepSimulation()
        moved = float(np.linalg.norm(robot.state(0.0).position - pos))
        return moved, robot.height_above_surface()
    finally:
        scene.close()


def test_adsorption_holds_on_a_steep_blade_and_a_weak_force_slips() -> None:
    moved, height = _hold(1.1, 1.0)  # 63° slope, tan > friction coefficient
    assert moved < 0.02
    assert abs(height - ClimberParams().h) < 0.01
    moved_weak, _ = _hold(1.1, 0.0)
    assert moved_weak > 0.5


def test_tether_length_is_the_anchor_distance_on_the_nominal_robot() -> None:
    prm = ClimberParams(tether_sigma=0.0)
    tether = TetherModel(prm, np.random.default_rng(0), ClimbFaults())
    rng = np.random.default_rng(1)
    for p in rng.uniform(-3, 8, (5, 3)):
        reading = tether.read(1.0, p, 0.1)
        assert reading.ok
        assert reading.length == pytest.approx(np.linalg.norm(p - prm.anchor_world), abs=1e-12)


def test_spool_scale_and_anchor_effects_change_the_reading() -> None:
    reality = Reality(
        (
            make_effect("climber_spool_scale", s=1.01),
            make_effect("climber_anchor_error", dx=0.02),
        )
    )
    prm = reality.apply_params(ClimberParams(tether_sigma=0.0))
    tether = TetherModel(prm, np.random.default_rng(0), ClimbFaults())
    p = np.array([3.0, 0.1, 2.0])
    expected = 1.01 * np.linalg.norm(p - (ClimberParams().anchor_world + np.array([0.02, 0, 0])))
    assert tether.read(0.0, p, 0.1).length == pytest.approx(expected, abs=1e-12)


def test_imu_at_rest_measures_minus_gravity_and_the_bias() -> None:
    bias_g, bias_a = (0.01, -0.02, 0.005), (0.05, 0.0, -0.1)
    prm = ClimberParams(
        gyro_noise_density=0.0,
        accel_noise_density=0.0,
        gyro_bias_walk=0.0,
        accel_bias_walk=0.0,
        gyro_bias_sigma=0.0,
        accel_bias_sigma=0.0,
        gyro_bias=bias_g,
        accel_bias=bias_a,
    )
    imu = ImuModel(prm, np.random.default_rng(0))
    rng = np.random.default_rng(3)
    from scipy.spatial.transform import Rotation

    R = Rotation.from_rotvec(rng.normal(0, 0.7, 3)).as_matrix()
    p, z = np.array([1.0, 2.0, 3.0]), np.zeros(3)
    s0 = BodyState(0.0, p, R, z, z)
    s1 = BodyState(1 / 120, p, R, z, z)
    m = imu.sample(s0, s1)
    np.testing.assert_allclose(m.gyro, bias_g, atol=1e-12)
    # specific force = -gravity expressed in the body frame
    np.testing.assert_allclose(m.accel, R.T @ [0, 0, 9.81] + np.asarray(bias_a), atol=1e-9)


def test_bad_parameters_are_clear_errors() -> None:
    with pytest.raises(ValueError, match="mount_pitch"):
        ClimberParams(mount_pitch=2.0)
    with pytest.raises(ValueError, match="caster_radius"):
        ClimberParams(caster_radius=0.05)
    with pytest.raises(ValueError, match="probability"):
        ClimbFaults(visual_dropout=2.0)
    with pytest.raises(ValueError, match="≥ 0"):
        ClimbFaults(tether_slack_rate=-1.0)
    with pytest.raises(TypeError, match="did you mean 's'"):
        make_effect("climber_spool_scale", ss=1.0)


def test_caster_pitch_limit_is_where_a_caster_touches_the_contact_plane() -> None:
    """Turned about the axle by the limit, the front caster sphere touches the wheels'
    contact plane z = -r (body frame, flat surface); at half the limit it is clear."""
    prm = ClimberParams()
    r, rc, a = prm.wheel_radius, prm.caster_radius, prm.caster_offset
    cz = -(r - rc) + prm.caster_clearance

    def caster_gap(theta: float) -> float:  # caster-sphere bottom above z = -r, m
        z = -a * np.sin(theta) + cz * np.cos(theta)  # (a, 0, cz) turned about y
        return z - rc + r

    limit = prm.caster_pitch_limit
    assert caster_gap(limit) == pytest.approx(0.0, abs=1e-12)
    assert caster_gap(0.5 * limit) > 0.0
    assert limit == pytest.approx(prm.caster_clearance / prm.caster_offset, rel=0.05)
    cfg = prm.constrained_config()
    assert cfg.wheel_track == prm.wheelbase and cfg.pitch_sigma == limit


def test_local_nearest_sample_matches_the_tree() -> None:
    from scipy.spatial import cKDTree

    from realitygap.robots.climber import _LocalNearest

    rng = np.random.default_rng(0)
    pts = rng.uniform(0.0, 1.0, (5000, 3))
    pts[:, 2] = 0.02 * np.sin(6 * pts[:, 0])
    tree = cKDTree(pts)
    nearest = _LocalNearest(tree, pts, radius=0.05)
    q = np.array([0.5, 0.5, 0.04])
    for k in range(3000):
        q = q + rng.normal(0.0, 0.003, 3)
        q[:2] = np.clip(q[:2], 0.05, 0.95)
        q[2] = 0.04 + 0.03 * np.sin(k / 50)
        if k == 1500:
            q = q + np.array([0.3, 0.0, 0.5])  # a jump far off the cloud
        assert nearest(q) == tree.query(q)[1]
