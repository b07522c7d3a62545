"""Sensor pipelines calibrated to a reality (``estimator_reality``): each correction is the
exact inverse of the sensor model it undoes."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import realitygap  # noqa: F401  (registers the envs)
from realitygap.estimators.climb.measurements import ImuSample, TetherReading
from realitygap.robots.climber import ClimberParams
from realitygap.robots.climber_sensors import calibrated_measurement, tether_distance
from realitygap.robots.effects import Reality, make_effect


@pytest.mark.parametrize(
    ("k", "eps", "s"), [(0.0, 0.0, 1.0), (0.002, 0.005, 1.01), (0.005, -0.01, 0.98)]
)
def test_tether_distance_inverts_the_tether_model(k: float, eps: float, s: float) -> None:
    prm = ClimberParams().replace(tether_sag=k, tether_stretch=eps, spool_scale=s)
    for d in np.linspace(0.0, 9.0, 19):
        reading = s * (d + k * d * d + eps * d)  # TetherModel.read without noise
        assert tether_distance(reading, prm) == pytest.approx(d, rel=1e-12, abs=1e-12)


def test_calibrated_imu_samples_lose_the_constant_biases() -> None:
    prm = ClimberParams().replace(gyro_bias=(0.0, 0.0, 0.01), accel_bias=(0.1, 0.0, 0.0))
    m = calibrated_measurement(
        ImuSample(0.0, np.array([0.0, 0.0, 0.03]), np.array([0.1, 0.0, 9.81])), prm
    )
    assert np.allclose(m.gyro, [0.0, 0.0, 0.02]) and np.allclose(m.accel, [0.0, 0.0, 9.81])
    t = calibrated_measurement(TetherReading(1.0, 2.0 * 1.01, True), prm.replace(spool_scale=1.01))
    assert t.length == pytest.approx(2.0) and t.ok and t.t == 1.0


def test_arm_link_angles_invert_the_encoder_reading() -> None:
    reality = Reality(
        (
            make_effect("arm_backlash", b2=1e-3, b3=8e-4),
            make_effect("arm_joint_compliance", c2=3e-5, c3=3e-5),
        )
    )
    env = gym.make("realitygap/ArmCalib-v0", reality=reality)
    env.reset(seed=0)
    base = env.unwrapped
    robot = base.robot
    for q in (base.home, base.home + np.array([0.1, -0.2, 0.3, 0.1, -0.1, 0.2])):
        robot.move_to(q)
        truth = robot.joint_positions()
        reading = robot.read_encoders()  # noise-free, quantised
        inferred = robot.link_angles_from_encoders(reading, base.true_params)
        nominal = robot.link_angles_from_encoders(reading, base.params)
        res = base.true_params.encoder_resolution
        assert np.max(np.abs(inferred - truth)) < 2 * res + 1e-9
        assert np.max(np.abs(nominal - truth)) > 10 * np.max(np.abs(inferred - truth))
    env.close()


def test_the_climber_calibration_needs_a_default_estimator() -> None:
    env = gym.make("realitygap/WallClimb-v0")
    plugin = env.unwrapped.estimator  # a valid plug-in estimator object
    with pytest.raises(ValueError, match="estimator is a plug-in"):
        gym.make("realitygap/WallClimb-v0", estimator=plugin, estimator_reality="climber-worn")
    env.close()
