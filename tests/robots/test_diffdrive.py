"""The simulated differential drive: body from params, kinematics, sensors, effects."""

from __future__ import annotations

import math

import numpy as np
import pytest

from realitygap.envs.layouts import room_walls
from realitygap.robots.diffdrive import (
    DiffDriveParams,
    DiffDriveRobot,
    encoder_ticks,
    urdf_from_params,
)
from realitygap.robots.effects import EFFECTS, Reality, make_effect
from realitygap.robots.sensors import PlanarScanner
from realitygap.robots.world import Primitive, Shape, World, ray_cast_primitives


@pytest.fixture
def world():
    w = World()
    w.add_floor()
    yield w
    w.close()


def drive(
    world: World, robot: DiffDriveRobot, w_left: float, w_right: float, seconds: float
) -> None:
    robot.set_wheel_speeds(w_left, w_right)
    for _ in range(int(round(seconds / world.dt))):
        world.step()


def test_negative_wheel_radius_is_rejected() -> None:
    with pytest.raises(ValueError, match="wheel_radius_left must be a number in"):
        DiffDriveParams(wheel_radius_left=-0.035)


def test_urdf_really_changes_with_params() -> None:
    a = urdf_from_params(DiffDriveParams())
    b = urdf_from_params(DiffDriveParams(wheel_radius_right=0.036))
    assert 'radius="0.036"' in b and 'radius="0.036"' not in a


def test_straight_drive_matches_wheel_kinematics(world: World) -> None:
    params = DiffDriveParams()
    robot = DiffDriveRobot(world, params)
    robot.reset([0.0, 0.0, 0.0])
    omega = 10.0  # rad/s on both wheels: v = ω r
    drive(world, robot, omega, omega, 2.0)
    x, y, th = robot.pose2d()
    expected = omega * params.wheel_radius_left * 2.0
    assert x == pytest.approx(expected, rel=0.03)
    assert abs(y) < 2e-3 and abs(th) < 2e-3
    v, _ = robot.twist()
    # no slip: the body moves exactly as fast as the measured wheel rotation says
    states = world.bullet.getJointStates(robot.body, robot.wheel_joints)
    wheel_speed = (states[0][1] + states[1][1]) / 2.0
    assert v == pytest.approx(wheel_speed * params.wheel_radius_left, rel=2e-3)
    # the velocity motors track the command to within 2 %
    assert wheel_speed == pytest.approx(omega, rel=0.02)


def test_turn_rate_follows_the_true_wheelbase(world: World) -> None:
    # a wheelbase 10 % wider turns 10 % slower for the same wheel speeds
    rates = []
    for b in (0.23, 0.253):
        w = World()
        w.add_floor()
        robot = DiffDriveRobot(w, DiffDriveParams(wheelbase=b))
        robot.reset([0.0, 0.0, 0.0])
        drive(w, robot, -5.0, 5.0, 1.0)
        rates.append(robot.twist()[1])
        w.close()
    expected = [2 * 5.0 * 0.035 / 0.23, 2 * 5.0 * 0.035 / 0.253]
    np.testing.assert_allclose(rates, expected, rtol=0.02)


def test_encoder_ticks_quantise_angles() -> None:
    ticks = encoder_ticks(0.0, (2 * math.pi, -math.pi), 2000.0)
    assert (ticks.left, ticks.right) == (2000, -1000)


def test_analytic_ray_cast_closed_form() -> None:
    box = Primitive("b", Shape.BOX, (2.0, 0.0), 1.0, half_extents=(0.5, 0.5))
    cyl = Primitive("c", Shape.CYLINDER, (0.0, 3.0), 1.0, radius=0.5)
    dirs = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])
    r = ray_cast_primitives([0.0, 0.0], dirs, [box, cyl], range_max=8.0)
    np.testing.assert_allclose(r[:2], [1.5, 2.5])
    assert math.isinf(r[2])
    # a rotated box: the ray meets the corner of a 45° square at distance c - h√2
    diamond = Primitive("d", Shape.BOX, (3.0, 0.0), 1.0, yaw=math.pi / 4, half_extents=(0.5, 0.5))
    r = ray_cast_primitives([0.0, 0.0], dirs[:1], [diamond], range_max=8.0)
    assert r[0] == pytest.approx(3.0 - 0.5 * math.sqrt(2))


def test_fast_scan_sees_a_wall_at_the_right_range(world: World) -> None:
    for prim in room_walls(2.0):
        world.add_primitive(prim)
    params = DiffDriveParams()
    robot = DiffDriveRobot(world, params)
    robot.reset([0.0, 0.0, 0.0])
    scanner = PlanarScanner(robot, params.camera, n_beams=33)
    scan = scanner.scan_fast(0.0, np.random.default_rng(0))
    centre = scan.ranges[16]
    assert centre == pytest.approx(2.0, abs=0.05)  # noise σ ≈ 9 mm at 2 m
    # off-axis beams hit the same wall at 2 / cos(angle)
    np.testing.assert_allclose(scan.ranges, 2.0 / np.cos(scan.angles), atol=0.06)


def test_effect_library_validates_parameters() -> None:
    assert {"wheel_diameter_ratio", "wheelbase_error", "command_latency"} <= set(EFFECTS)
    with pytest.raises(TypeError, match="did you mean 'E_d'"):
        make_effect("wheel_diameter_ratio", E_dd=1.02)
    with pytest.raises(KeyError, match="wheelbase_error"):
        make_effect("wheelbase_eror", E_b=1.0)


def test_reality_builds_a_different_body() -> None:
    reality = Reality(
        (make_effect("wheel_diameter_ratio", E_d=1.04), make_effect("wheelbase_error", E_b=1.05))
    )
    true = reality.apply_params(DiffDriveParams())
    assert true.wheel_radius_right / true.wheel_radius_left == pytest.approx(1.04)
    assert (true.wheel_radius_right + true.wheel_radius_left) / 2 == pytest.approx(0.035)
    assert true.wheelbase == pytest.approx(0.230 * 1.05)
    again = Reality.from_dict(reality.to_dict()).apply_params(DiffDriveParams())
    assert again == true


def test_latency_hook_delays_commands() -> None:
    hook = make_effect("command_latency", delay=0.1).make_command_hook(0.05)
    assert hook is not None
    out = [hook(float(i), 0.0, 0.05)[0] for i in range(5)]
    assert out == [0.0, 0.0, 0.0, 1.0, 2.0][: len(out)] or out[2:] == [0.0, 1.0, 2.0]
    np.testing.assert_allclose(out[2:], [0.0, 1.0, 2.0])
