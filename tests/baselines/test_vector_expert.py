"""The batched privileged expert and the DAgger warm start on the vector env."""

from __future__ import annotations

import types
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import realitygap  # noqa: F401  (registers the ids)
from realitygap.baselines import rl
from realitygap.baselines.imitation import DemoSettings, expert_action_to_model
from realitygap.baselines.privileged import BatchGeodesicExpert, GeodesicNavExpert
from realitygap.baselines.rl.vector_imitation import (
    collect_vector,
    network_actions,
    pretrain_vector,
)

VEC_ID = "realitygap/WheeledNavVec-v0"


def _single_expert(base: object, i: int) -> GeodesicNavExpert:
    """The single-robot expert on robot ``i``'s layout of the vector env ``base``."""
    view = types.SimpleNamespace(
        obstacles=base.obstacles[i],  # type: ignore[attr-defined]
        room_half_size=base.room_half_size,  # type: ignore[attr-defined]
        params=base.params,  # type: ignore[attr-defined]
        scan_angles=base.scan_angles,  # type: ignore[attr-defined]
    )
    view.unwrapped = view
    return GeodesicNavExpert(view)


@pytest.mark.slow
def test_batched_expert_equals_the_single_robot_expert_on_the_same_states() -> None:
    n = 6
    env = gym.make_vec(VEC_ID, num_envs=n)
    env.reset(seed=11)
    base = env.unwrapped
    expert = BatchGeodesicExpert(env)
    rng = np.random.default_rng(0)
    compared = 0
    regimes = set()
    for step in range(160):
        pose, goal = base.estimate.copy(), base.goal.copy()
        a = expert.act(pose, goal)
        if step % 8 == 0:
            for i in range(n):
                obs = np.concatenate(
                    [
                        pose[i, :2],
                        [np.cos(pose[i, 2]), np.sin(pose[i, 2])],
                        goal[i, :2],
                        [np.cos(goal[i, 2]), np.sin(goal[i, 2])],
                    ]
                )
                b = _single_expert(base, i).act(0, obs)
                np.testing.assert_allclose(a[i], b, atol=1e-9, rtol=0)
                d = np.hypot(*(goal[i, :2] - pose[i, :2]))
                regimes.add("path" if d > 0.2 else "near")
                compared += 1
        # a little noise on the expert's command visits states off its own path
        env.step(np.clip(a + 0.2 * rng.standard_normal(a.shape), -1.0, 1.0))
    assert compared == 20 * n and regimes == {"path", "near"}
    env.close()


def test_batched_expert_refuses_wrong_shapes_and_single_envs() -> None:
    env = gym.make_vec(VEC_ID, num_envs=3)
    env.reset(seed=0)
    expert = BatchGeodesicExpert(env)
    with pytest.raises(ValueError, match=r"shape \(3, 3\)"):
        expert.act(np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(TypeError, match="needs a vector WheeledNav env"):
        BatchGeodesicExpert(gym.make("realitygap/WheeledNav-v0"))
    env.close()


def _demo_env(io: rl.PolicyIO, n: int) -> Callable[[int, Sequence[Any]], Any]:
    def make(seed: int, wrappers: Sequence[Any]) -> Any:
        return rl.make_vector_train_env(VEC_ID, {}, n, seed, io, 600, wrappers)

    return make


@pytest.mark.slow
def test_warm_started_policy_matches_the_expert_on_held_out_states() -> None:
    """DAgger on the vector env (2 rounds of 24 episodes, 8 robots): on states of other
    episodes the cloned network's motion command is within 0.15 (RMS, of the normalised
    command) of the expert's, under half the expert's own spread about its mean, and
    its stop gate agrees on 95 % of the states."""
    from stable_baselines3 import PPO

    hp = rl.load_hyperparams("ppo", VEC_ID)
    io = rl.PolicyIO.from_dict(hp)
    make = _demo_env(io, 8)
    venv = make(0, ())
    model = PPO(
        "MlpPolicy",
        venv,
        seed=0,
        device="cpu",
        policy_kwargs={"net_arch": [128, 128], "log_std_init": -1.6},
    )
    settings = DemoSettings(
        expert="geodesic", rounds=2, episodes=24, epochs=25, small_action_scale=0.2
    )
    norm, rows = pretrain_vector(
        model, make, io, settings, seed=0, gamma=0.99, normalizer_cls=rl.ObsNormalizer
    )
    assert [r["round"] for r in rows] == [0.0, 1.0] and rows[0]["rollout_success"] > 0.9
    held = make(777, ())
    expert = BatchGeodesicExpert(held.venv)
    data = collect_vector(held, expert, io, 8, 1.0, np.random.default_rng(1))
    x = np.asarray(data.inputs)
    y = np.asarray(data.targets)
    pred = network_actions(model, x, norm)
    rms = float(np.sqrt(np.mean((pred[:, :2] - y[:, :2]) ** 2)))
    spread = float(np.sqrt(np.mean((y[:, :2] - y[:, :2].mean(axis=0)) ** 2)))
    gate = float(np.mean(np.sign(pred[:, 2]) == np.sign(y[:, 2])))
    assert rms < 0.15 and rms < 0.5 * spread and gate > 0.95, (rms, spread, gate)
    venv.close()
    held.close()


def test_expert_targets_map_back_to_the_expert_action() -> None:
    io = rl.PolicyIO(action_stop_gate=True)
    a = np.array([[0.3, -0.2], [0.0, 0.0], [0.0, 0.5]])
    np.testing.assert_allclose(io.action(expert_action_to_model(a, 0.0, True)), a, atol=1e-7)


def test_vector_demonstrations_need_a_batched_expert() -> None:
    hp = rl.load_hyperparams("ppo", VEC_ID)
    io = rl.PolicyIO.from_dict(hp)
    with pytest.raises(ValueError, match="need a batched expert"):
        pretrain_vector(
            None,
            _demo_env(io, 2),
            io,
            DemoSettings(expert="classical", rounds=1, episodes=1),
            seed=0,
            gamma=0.99,
            normalizer_cls=rl.ObsNormalizer,
        )


def test_a_vector_trained_policy_ships_under_a_name_of_its_own(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="variant must be a non-empty name"):
        rl.ship_policy(tmp_path, "realitygap/WheeledNav-v0", "ppo", "../vector")
