"""WallClimb-v0 beyond the battery: detachment, bad input, estimator modes, errors."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import realitygap  # noqa: F401
from realitygap.envs.wall_climb import WallClimbEnv
from realitygap.robots.climber import ClimberParams, ClimbFaults


def test_detachment_is_detected_and_ends_the_episode() -> None:
    env = WallClimbEnv(params=ClimberParams(mount_pitch=1.1))
    env.reset(seed=0, options={"start": (3.0, 0.3, 0.0), "goal": (5.0, 0.3)})
    env.robot.adsorption_scale = 0.0  # suction pump fails on a 63° slope
    info: dict = {}
    for _ in range(100):
        _, _, terminated, _, info = env.step(np.zeros(2))
        if terminated:
            break
    env.close()
    assert info["detached"] and terminated
    assert info["reward_terms"]["detach"] < 0


def test_bad_tether_and_lost_vision_are_reported_not_raised() -> None:
    faults = ClimbFaults(tether_jump_prob=0.3, tether_invalid_prob=0.2, visual_dropout=0.4)
    env = WallClimbEnv(faults=faults)
    obs, info = env.reset(seed=1)
    lost = False
    for _ in range(40):
        obs, _, terminated, _, info = env.step(np.array([0.6, 0.0]))
        lost |= not info["visual_ok"]
        assert np.all(np.isfinite(obs))
        if terminated:
            break
    env.close()
    assert lost
    assert info["estimator_flags"], "no anomaly was flagged"
    assert info["position_error"] < 0.2


def test_localiser_reports_a_pending_global_initialisation() -> None:
    env = WallClimbEnv(estimator="localiser")
    obs, info = env.reset(seed=0)
    for _ in range(20):
        obs, _, _, _, info = env.step(np.array([0.5, 0.0]))
    env.close()
    assert info["localiser_phase"] in ("global_init", "vio_init")
    assert info["anchor_observable"] is None
    assert obs[17] == 0.0


def test_errors_name_the_problem() -> None:
    with pytest.raises(ValueError, match="estimator"):
        WallClimbEnv(estimator="ekf")
    with pytest.raises(ValueError, match="sensor_mode"):
        WallClimbEnv(sensor_mode="lidar")
    env = gym.make("realitygap/WallClimb-v0")
    with pytest.raises(ValueError, match="suction side"):
        env.reset(seed=0, options={"start": (9.0, 0.3)})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3))
    env.close()


def test_image_mode_renders_the_textured_blade() -> None:
    env = WallClimbEnv(sensor_mode="image")
    env.reset(seed=0)
    state = env._state
    assert state is not None
    image = env._camera.render(*env._camera.camera_pose(state))
    for _ in range(4):
        obs, *_ = env.step(np.array([0.5, 0.0]))
    env.close()
    assert image.shape == (96, 96, 3)
    assert image.std() > 10.0, "the down-looking camera sees no texture"
    assert np.all(np.isfinite(obs))
