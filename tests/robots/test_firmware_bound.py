"""``FirmwareLimits.bound``, the per-episode form of ``FirmwareLimits.step`` that
``DiffDriveRobot.command_twist`` calls: the same twists, to the bit, under every convention."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from realitygap.robots.diffdrive import (
    Deceleration,
    DiffDriveParams,
    DiffDriveRobot,
    FirmwareLimits,
    Ramp,
)
from realitygap.robots.world import World


def _requests(rng: np.random.Generator, n: int) -> list[tuple[float, float]]:
    """Requests that speed up, slow down, reverse, stop exactly and exceed the limits."""
    out = [(0.0, 0.0), (-0.0, 0.0), (5.0, -9.0), (-5.0, 9.0)]
    for _ in range(n):
        v, w = rng.uniform(-1.2, 1.2), rng.uniform(-4.0, 4.0)
        out.append((0.0, 0.0) if rng.random() < 0.1 else (float(v), float(w)))
    return out


@pytest.mark.parametrize(
    ("ramp", "deceleration", "decel_factor"),
    [
        (r, d, f)
        for (r, d), f in itertools.product(itertools.product(Ramp, Deceleration), (1.0, 2.5))
    ],
)
def test_bound_step_equals_step(
    ramp: Ramp, deceleration: Deceleration, decel_factor: float
) -> None:
    limits = FirmwareLimits(0.7, 2.8, 1.3, 6.1, ramp, deceleration, decel_factor)
    dt, wheelbase = 0.05, 0.231
    bound = limits.bound(dt, wheelbase)
    rng = np.random.default_rng(int(decel_factor * 10) + len(ramp.value) + len(deceleration.value))
    v_prev = w_prev = 0.0
    for v, w in _requests(rng, 400):
        got = bound(v, w, v_prev, w_prev)
        want = limits.step(v, w, v_prev, w_prev, dt, wheelbase)
        assert np.array(got).tobytes() == np.array(want).tobytes(), (v, w, v_prev, w_prev)
        assert all(type(x) is float for x in got)
        v_prev, w_prev = got


def test_infinite_limits_pass_the_request_through_bound() -> None:
    bound = FirmwareLimits().bound(0.05, 0.23)
    assert bound(0.3, -1.7, 0.0, 0.0) == (0.3, -1.7)
    assert bound(math.inf, 0.0, 0.0, 0.0) == (math.inf, 0.0)


def test_command_twist_follows_limits_replaced_after_attaching() -> None:
    world = World()
    world.add_floor()
    try:
        robot = DiffDriveRobot(world, DiffDriveParams())
        robot.attach_firmware(0.05, limits=FirmwareLimits(1.0, 1.0, 2.0, 2.0))
        assert robot.command_twist(1.0, 1.0) == pytest.approx((0.1, 0.1))
        robot.firmware_limits = FirmwareLimits(1.0, 1.0, 20.0, 20.0)  # a new firmware
        assert robot.command_twist(1.0, 1.0) == pytest.approx((1.0, 1.0))
        robot.attach_firmware(0.1, limits=FirmwareLimits(1.0, 1.0, 2.0, 2.0))
        robot.command = np.zeros(2)
        assert robot.command_twist(1.0, 1.0) == pytest.approx((0.2, 0.2))  # the new period
        robot.control_dt = 0.2  # a period set on the robot itself
        assert robot.command_twist(1.0, 1.0) == pytest.approx((0.6, 0.6))
        robot.firmware_limits = None  # no firmware: as commanded
        assert robot.command_twist(3.0, -3.0) == (3.0, -3.0)
    finally:
        world.close()
