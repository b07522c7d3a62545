"""The differential drive's firmware: limits, command hooks, inverse kinematics, encoders."""

from __future__ import annotations

import math

import numpy as np
import pytest

from realitygap.robots.diffdrive import DiffDriveParams, DiffDriveRobot, FirmwareLimits
from realitygap.robots.effects import Reality, make_effect
from realitygap.robots.world import World


@pytest.fixture
def world():
    w = World()
    w.add_floor()
    yield w
    w.close()


class _Recorder:
    """A stand-in reality whose command hook records what it sees and doubles v."""

    def __init__(self) -> None:
        self.seen: list[tuple[float, float, float]] = []

    def command_hooks(self, dt: float, nominal: object = None):
        def hook(v: float, w: float, dt_: float) -> tuple[float, float]:
            self.seen.append((v, w, dt_))
            return 2.0 * v, w

        return [hook]

    def ticks_hooks(self):
        return []

    def ticks_inverse_hooks(self):
        return []

    def wheel_hooks(self, dt: float, nominal: object = None):
        return []


def test_limits_clip_speed_then_rate() -> None:
    lim = FirmwareLimits(v_max=0.5, w_max=1.0, a_max=1.0, alpha_max=4.0)
    assert lim.limit(2.0, -3.0, 0.0, 0.0, 0.05) == pytest.approx((0.05, -0.2))
    assert lim.limit(2.0, -3.0, 0.48, -0.9, 0.05) == pytest.approx((0.5, -1.0))
    assert lim.limit(0.3, 0.2, 0.3, 0.2, 0.05) == (0.3, 0.2)


def test_infinite_limits_pass_the_request() -> None:
    assert FirmwareLimits().limit(0.7, -2.0, 0.0, 0.0, 0.05) == (0.7, -2.0)


def test_limits_from_params() -> None:
    P = DiffDriveParams()
    assert FirmwareLimits.from_params(P) == FirmwareLimits(P.v_max, P.w_max, P.a_max, P.alpha_max)


def test_inverse_kinematics_uses_the_nominal_geometry(world: World) -> None:
    nominal = DiffDriveParams()
    true = nominal.replace(wheel_radius_left=0.04, wheelbase=0.25)
    robot = DiffDriveRobot(world, true)
    robot.attach_firmware(world.dt, nominal=nominal)
    v, w = 0.3, 1.2
    wl, wr = robot.wheel_speeds_from_twist(v, w)
    assert wl == pytest.approx((v - w * 0.115) / 0.035)
    assert wr == pytest.approx((v + w * 0.115) / 0.035)
    robot.attach_firmware(world.dt)  # without a nominal: the body's own geometry
    assert robot.wheel_speeds_from_twist(v, w)[0] == pytest.approx((v - w * 0.125) / 0.04)


def test_command_twist_limits_then_hooks(world: World) -> None:
    robot = DiffDriveRobot(world, DiffDriveParams())
    recorder = _Recorder()
    robot.attach_firmware(0.05, limits=FirmwareLimits(a_max=1.0, alpha_max=4.0), reality=recorder)
    applied = robot.command_twist(0.7, 1.0)
    assert applied == pytest.approx((0.05, 0.2))
    np.testing.assert_allclose(robot.command, [0.05, 0.2])
    assert recorder.seen == [(pytest.approx(0.05), pytest.approx(0.2), 0.05)]
    robot.attach_firmware(0.05, reality=recorder)  # no limits: the twist as given
    assert robot.command_twist(0.7, 1.0) == (0.7, 1.0)
    assert robot.command.tolist() == [0.7, 1.0]


def test_commanded_twist_drives_the_body(world: World) -> None:
    robot = DiffDriveRobot(world, DiffDriveParams())
    robot.reset([0.0, 0.0, 0.0])
    robot.attach_firmware(world.dt)
    for _ in range(int(round(2.0 / world.dt))):
        robot.command_twist(0.2, 0.0)
        world.step()
    x, y, th = robot.pose2d()
    assert x == pytest.approx(0.4, abs=0.02) and abs(y) < 0.01 and abs(th) < 0.02


def test_encoder_hooks_and_their_inverse(world: World) -> None:
    robot = DiffDriveRobot(world, DiffDriveParams())
    robot.reset([0.0, 0.0, 0.0])
    reality = Reality((make_effect("encoder_scale", scale=1.02),))
    robot.attach_firmware(world.dt, reality=reality)
    robot.set_wheel_speeds(5.0, 5.0)
    for _ in range(10):
        world.step()
    true = np.array(robot.wheel_angles())
    seen = np.array(robot.encoder_angles())
    assert not np.allclose(seen, true)
    back = robot.wheel_angles_from_encoder(seen[None, :])
    np.testing.assert_allclose(back[0], true, rtol=1e-12)


def test_an_encoder_effect_without_inverse_cannot_be_inverted(world: World) -> None:
    class _NoInverse(_Recorder):
        def ticks_inverse_hooks(self):
            raise ValueError("no inverse")

    robot = DiffDriveRobot(world, DiffDriveParams())
    robot.attach_firmware(world.dt, reality=_NoInverse())
    with pytest.raises(ValueError, match="no inverse"):
        robot.wheel_angles_from_encoder(np.zeros((2, 2)))
    assert math.isfinite(robot.control_dt)
