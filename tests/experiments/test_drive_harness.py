"""The drive harness and the scripted drive controllers on a WheeledNav robot."""

from __future__ import annotations

import math

import numpy as np
import pytest

from realitygap.controllers.drives import SquareDriver
from realitygap.core.geometry import se2_compose, wrap_angle
from realitygap.experiments.drive_harness import (
    RecordingOdometry,
    arc_path,
    drive,
    nominal_kinematics,
)


def test_arc_path_is_exact() -> None:
    start = np.array([0.0, -1.0, 0.0])
    path = arc_path(start, [(math.pi, 1.0), (0.5, 0.0)])
    assert path.length == pytest.approx(math.pi + 0.5)
    np.testing.assert_allclose(path.xy[-1], [-0.5, 1.0], atol=1e-9)
    assert path.heading[-1] == pytest.approx(math.pi)
    assert np.all(np.diff(path.s) > 0) and path.curvature[0] == 1.0
    with pytest.raises(ValueError, match="> 0 m"):
        arc_path(start, [(0.0, 1.0)])


def test_square_driver_closes_the_square_on_exact_odometry() -> None:
    import gymnasium as gym

    import realitygap  # noqa: F401
    from realitygap.robots.diffdrive import DiffDriveParams

    nominal = nominal_kinematics(DiffDriveParams())
    recorder = RecordingOdometry(nominal)
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
            log = drive(env, recorder, SquareDriver(start, 0.6, direction), start, 0, 3000)
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
        SquareDriver((0, 0, 0), 1.0, "left")
