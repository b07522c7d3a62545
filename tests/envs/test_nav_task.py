"""The WheeledNav task: start/goal sampling, reward terms, success, termination."""

from __future__ import annotations

import dataclasses
import math

import gymnasium as gym
import numpy as np
import pytest

import realitygap  # noqa: F401
from realitygap.envs.tasks.nav import NavRewardWeights, NavTask


class _Twist:
    def __init__(self, v: float, w: float) -> None:
        self.v, self.w = v, w
        self.calls = 0

    def twist(self) -> np.ndarray:
        self.calls += 1
        return np.array([self.v, self.w])


def test_reward_weights_are_frozen() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        NavRewardWeights().progress = 1.0  # type: ignore[misc]


def test_reward_terms_closed_form() -> None:
    task = NavTask(n_obstacles=0)
    d0, a0 = task.reset(np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.5]))
    assert (d0, a0) == pytest.approx((1.0, 0.5))
    reward, terms = task.get_reward(0.9, 0.3, (0.5, -1.0), collision=False, success=False)
    assert terms == pytest.approx(
        {
            "progress": 0.2,
            "heading": 0.5 * math.exp(-0.9 / 0.3) * 0.2,
            "time": -0.01,
            "effort": -0.002 * 1.25,
            "collision": 0.0,
            "success": 0.0,
        }
    )
    assert reward == pytest.approx(sum(terms.values()))
    _, terms = task.get_reward(0.9, 0.3, (0.0, 0.0), collision=True, success=True)
    assert terms["progress"] == 0.0 and terms["collision"] == -5.0 and terms["success"] == 5.0


def test_reward_weights_scale_their_terms() -> None:
    task = NavTask(weights=NavRewardWeights(progress=4.0, collision=1.0))
    task.reset(np.zeros(3), np.array([1.0, 0.0, 0.0]))
    _, terms = task.get_reward(0.5, 0.0, (0.0, 0.0), collision=True, success=False)
    assert terms["progress"] == pytest.approx(2.0) and terms["collision"] == -1.0


def test_heading_error_wraps() -> None:
    task = NavTask()
    task.reset(np.array([0.0, 0.0, math.pi - 0.1]), np.zeros(3))
    assert task.pose_error(np.array([3.0, 4.0, -math.pi + 0.1])) == pytest.approx((5.0, 0.2))


def test_success_needs_tolerance_and_rest() -> None:
    task = NavTask(success_pos_tol=0.05, success_ang_tol=0.1)
    far = _Twist(0.0, 0.0)
    assert not task.is_success(0.06, 0.0, far) and far.calls == 0
    assert task.is_success(0.05, 0.1, _Twist(0.005, 0.04))
    assert not task.is_success(0.01, 0.0, _Twist(0.02, 0.0))
    assert not task.is_success(0.01, 0.0, _Twist(0.0, 0.06))


def test_termination() -> None:
    assert NavTask().is_terminated(collision=True, success=False)
    assert NavTask().is_terminated(collision=False, success=True)
    assert not NavTask(terminate_on_success=False).is_terminated(collision=False, success=True)
    assert not NavTask().is_terminated(collision=False, success=False)


def test_sampled_goal_is_away_from_the_start() -> None:
    task = NavTask()
    rng = np.random.default_rng(3)
    for _ in range(20):
        start, goal = task.sample_start_goal(rng, {}, 0.176)
        assert np.hypot(*(goal[:2] - start[:2])) > 1.0
        assert np.all(np.abs(start[:2]) <= 3.5 - 0.6) and np.all(np.abs(goal[:2]) <= 3.5 - 0.6)


def test_fixed_and_optional_poses_win_over_sampling() -> None:
    task = NavTask(start=(0.0, 0.0, 0.0), goal=(1.0, 1.0, 0.5))
    start, goal = task.sample_start_goal(np.random.default_rng(0), {"goal": [2, 0, 0]}, 0.176)
    assert start.tolist() == [0.0, 0.0, 0.0] and goal.tolist() == [2.0, 0.0, 0.0]
    with pytest.raises(ValueError, match="outside the room"):
        task.sample_start_goal(np.random.default_rng(0), {"start": [3.4, 0, 0]}, 0.176)


def test_negative_obstacle_count_is_rejected() -> None:
    with pytest.raises(ValueError, match="n_obstacles"):
        NavTask(n_obstacles=-1)


def test_empty_arena_is_the_four_walls() -> None:
    arena = NavTask(n_obstacles=0).sample_arena(
        np.random.default_rng(0), np.zeros(3), np.ones(3), 0.176
    )
    assert len(arena) == 4


def test_env_tolerances_are_the_tasks() -> None:
    env = gym.make("realitygap/WheeledNav-v0", n_obstacles=0, success_pos_tol=0.2)
    base = env.unwrapped
    assert base.task.success_pos_tol == 0.2 and base.success_pos_tol == 0.2
    base.success_pos_tol = 0.05
    base.success_ang_tol = 0.3
    assert base.task.success_pos_tol == 0.05 and base.task.success_ang_tol == 0.3
    env.close()


def test_env_reward_weights_reach_the_reward() -> None:
    weights = NavRewardWeights(time=0.5)
    env = gym.make("realitygap/WheeledNav-v0", n_obstacles=0, reward_weights=weights)
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(2, dtype=np.float32))
    assert info["reward_terms"]["time"] == -0.5
    env.close()
