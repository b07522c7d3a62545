"""The battery every registered environment must pass."""

from __future__ import annotations

import resource
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import realitygap

ENV_IDS = realitygap.ENV_IDS


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_check_env_without_warnings(env_id: str) -> None:
    env = gym.make(env_id)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=True)
    env.close()
    messages = [str(w.message) for w in caught]
    assert messages == [], messages


def _rollout(env_id: str, seed: int, n: int = 60) -> tuple[np.ndarray, list[float], np.ndarray]:
    env = gym.make(env_id)
    obs, info = env.reset(seed=seed)
    env.action_space.seed(seed)
    observations, rewards = [obs], []
    for _ in range(n):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        observations.append(obs)
        rewards.append(reward)
        if terminated or truncated:
            obs, info = env.reset()
            observations.append(obs)
    truth = np.asarray(info["true_pose"])
    env.close()
    return np.stack(observations), rewards, truth


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_seeded_rollouts_are_identical(env_id: str) -> None:
    a = _rollout(env_id, seed=3)
    b = _rollout(env_id, seed=3)
    np.testing.assert_array_equal(a[0], b[0])
    assert a[1] == b[1]
    np.testing.assert_array_equal(a[2], b[2])
    c = _rollout(env_id, seed=4)
    assert not np.array_equal(a[0][:5], c[0][:5]), "different seeds gave the same episode"


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_close_twice_and_observations_do_not_alias(env_id: str) -> None:
    env = gym.make(env_id)
    obs0, _ = env.reset(seed=0)
    keep = obs0.copy()
    obs1, *_ = env.step(env.action_space.sample())
    np.testing.assert_array_equal(obs0, keep)
    assert obs1 is not obs0
    env.close()
    env.close()


@pytest.mark.slow
@pytest.mark.parametrize("env_id", ENV_IDS)
def test_no_memory_growth_over_500_resets(env_id: str) -> None:
    env = gym.make(env_id)
    for i in range(50):  # warm-up: allocator pools, caches
        env.reset(seed=i)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss  # KiB on Linux
    for i in range(500):
        env.reset(seed=1000 + i)
        env.step(env.action_space.sample())
    after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    env.close()
    growth_mib = (after - before) / 1024.0
    assert growth_mib < 20.0, f"peak memory grew by {growth_mib:.1f} MiB over 500 resets"


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_non_finite_action_raises(env_id: str) -> None:
    env = gym.make(env_id)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([np.nan, 0.0], dtype=np.float32))
    env.close()


def test_unknown_kwarg_is_a_clear_error() -> None:
    with pytest.raises(TypeError, match="n_obstacle"):
        gym.make("realitygap/WheeledNav-v0", n_obstacle=3)


def test_mistyped_id_suggests_the_close_one() -> None:
    with pytest.raises(gym.error.Error, match="WheeledNav"):
        gym.make("realitygap/WheeledNaw-v0")


def _check_info_against_card(env_id: str, info: dict) -> None:
    schema = realitygap.card_for(env_id).info
    assert set(info) >= set(schema), f"missing info keys: {sorted(set(schema) - set(info))}"
    undeclared = sorted(set(info) - set(schema))
    assert not undeclared, f"info keys not in the card's schema: {undeclared}"
    for key, entry in schema.items():
        if entry.shape is not None:
            assert np.shape(info[key]) == entry.shape, (key, np.shape(info[key]), entry.shape)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_info_follows_the_cards_schema(env_id: str) -> None:
    env = gym.make(env_id)
    _, info = env.reset(seed=0)
    _check_info_against_card(env_id, info)
    env.action_space.seed(0)
    for _ in range(3):
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        _check_info_against_card(env_id, info)
        if terminated or truncated:
            break
    env.close()


def test_every_registered_id_has_a_card() -> None:
    assert set(ENV_IDS) == set(realitygap.ENV_CARDS)
    for env_id, card in realitygap.ENV_CARDS.items():
        assert gym.spec(env_id).max_episode_steps == card.max_episode_steps
        assert gym.spec(env_id).entry_point == card.entry_point
        assert "true_pose" in card.info
    with pytest.raises(KeyError, match="Did you mean"):
        realitygap.card_for("realitygap/WheeledNav-v1")
