"""The classical baseline policy, closed loop in the simulator."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import realitygap  # noqa: F401
from realitygap.baselines import ClassicalNavPolicy
from realitygap.experiments.nav import run_episode


def test_reaches_a_goal_pose_precisely_from_the_estimate() -> None:
    env = gym.make(
        "realitygap/WheeledNav-v0",
        n_obstacles=0,
        start=(-2.4, 0.0, 0.0),
        goal=(0.0, 0.0, math.pi / 2),
        terminate_on_success=False,
    )
    policy = ClassicalNavPolicy.from_env(env)
    ep = run_episode(env, policy, seed=0, settle=True)
    env.close()
    info = ep["info"]
    assert policy.is_done()
    assert info["pos_error"] < 0.01
    assert math.degrees(info["heading_error"]) < 1.0
    assert not ep["collision"]


@pytest.mark.parametrize("seed", [11, 12])
def test_avoids_obstacles_it_only_sees_through_the_scan(seed: int) -> None:
    env = gym.make("realitygap/WheeledNav-v0", n_obstacles=8)
    policy = ClassicalNavPolicy.from_env(env)
    ep = run_episode(env, policy, seed=seed)
    env.close()
    assert not ep["collision"]
    assert ep["success"]


def test_batch_predict_and_bad_shapes() -> None:
    env = gym.make("realitygap/WheeledNav-v0", n_obstacles=0)
    policy = ClassicalNavPolicy.from_env(env)
    obs, _ = env.reset(seed=0)
    env.close()
    actions, state = policy.predict(np.stack([obs, obs]), episode_start=np.array([True, True]))
    assert actions.shape == (2, 2) and state is None
    assert np.all(np.abs(actions) <= 1.0)
    single, _ = policy.predict(obs)
    assert single.shape == (2,)
    with pytest.raises(ValueError, match="observation must have shape"):
        policy.predict(obs[:10])


def test_a_failed_plan_makes_the_robot_wait_not_crash(monkeypatch: pytest.MonkeyPatch) -> None:
    env = gym.make("realitygap/WheeledNav-v0", n_obstacles=0, sensor_mode="fast")
    policy = ClassicalNavPolicy.from_env(env)
    obs, _ = env.reset(seed=0)
    env.close()
    calls = []

    def no_route(st: Any, pose: Any, goal: Any) -> bool:
        calls.append(1)
        st.plans += 1
        st.last_replan = st.t
        st.reference = None
        return False

    monkeypatch.setattr(policy, "_plan", no_route)
    # the planner gives up; until the next attempt is due the robot stands still
    for _ in range(5):
        action, _ = policy.predict(obs)
        assert np.all(action == 0.0)
    assert len(calls) == 1


@pytest.mark.parametrize("lead", [None, 0.3])
def test_a_lead_reference_makes_the_command_a_function_of_the_state(lead: float | None) -> None:
    from realitygap.baselines.classical import ClassicalNavConfig

    env = gym.make(
        "realitygap/WheeledNav-v0", n_obstacles=0, start=(-2.4, 0.0, 0.0), goal=(2.0, 0.5, 0.0)
    )
    config = ClassicalNavConfig(reference_lead=lead, ramp_commands=lead is None)
    policy = ClassicalNavPolicy.from_env(env, config)
    obs, _ = env.reset(seed=0)
    start = True
    while policy.episode_stats()["phase"] != "track":
        action, _ = policy.predict(obs, episode_start=np.array([start]))
        start = False
        obs, *_ = env.step(action)
    for _ in range(20):  # drive on a while, then freeze the observation
        action, _ = policy.predict(obs)
        obs, *_ = env.step(action)
    repeated = np.array([policy.predict(obs)[0] for _ in range(10)])
    env.close()
    spread = float(np.ptp(repeated, axis=0).max())
    if lead is None:
        assert spread > 1e-3  # the clock reference runs on while the robot stands still
    else:
        assert spread == 0.0  # the same state gets the same command
