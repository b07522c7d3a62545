"""The batched episode features equal the single-robot ones on the same observations."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import realitygap  # noqa: F401  (registers the ids)
from realitygap.baselines.episode_features import EpisodeFeatures
from realitygap.baselines.rl.batch_features import (
    BatchEpisodeFeatures,
    BatchObstacleMemory,
    BatchRestTimer,
)

VEC_ID = "realitygap/WheeledNavVec-v0"


def _spec(base: object) -> dict[str, object]:
    return {
        "n_sectors": 36,
        "horizon": 2.0,
        "cell": 0.05,
        "scan_angles": [float(a) for a in base.scan_angles],  # type: ignore[attr-defined]
        "range_max": float(base.scan_range_max),  # type: ignore[attr-defined]
    }


def test_batched_features_equal_single_robot_features_over_episodes_with_resets() -> None:
    n, steps = 8, 160
    env = gym.make_vec(VEC_ID, num_envs=n, max_episode_steps=60)
    base = env.unwrapped
    spec = _spec(base)
    timer = {"horizon_steps": 5}
    batch = BatchEpisodeFeatures(n, spec, timer)
    singles = [EpisodeFeatures(spec, timer) for _ in range(n)]
    rng = np.random.default_rng(3)
    obs, _ = env.reset(seed=11)
    kept = 0
    resets = 0
    for t in range(steps):
        want = np.stack([s.update(o) for s, o in zip(singles, obs)])
        got = batch.update(obs)
        np.testing.assert_array_equal(got, want)
        mem = batch.parts[0]
        assert [len(s.parts[0]) for s in singles] == mem.count.tolist()
        kept = max(kept, int(mem.count.max()))
        # turn on the spot, drive, and stand still now and then (the rest timer)
        act = rng.uniform(-1.0, 1.0, (n, 2)).astype(np.float32)
        act[(t // 7) % 3 == 0] = 0.0
        obs, _, term, trunc, info = env.step(act)
        done = np.flatnonzero(term | trunc)
        if done.size:
            final = info["final_obs"][done]
            want = np.stack([singles[i].update(o) for i, o in zip(done, final)])
            np.testing.assert_array_equal(batch.update(final, done), want)
            batch.reset(done)
            for i in done:
                singles[i].reset()
            resets += done.size
    env.close()
    assert kept > 20, "the sequence must keep obstacle points"
    assert resets >= n, "the sequence must reset robots mid-run"


def test_batched_memory_shows_a_planted_point_in_its_sector() -> None:
    # one beam straight ahead; robot 1 at the origin facing +y sees a hit 1 m ahead
    mem = BatchObstacleMemory(2, [0.0], 4.0, n_sectors=4, horizon=2.0)
    obs = np.ones((2, 13))
    obs[:, :4] = [0.0, 0.0, 0.0, 1.0]  # x, y, cos θ, sin θ (θ = 90°)
    obs[1, 12] = 0.25  # 1 m of 4 m
    f = mem.update(obs)
    np.testing.assert_array_equal(f[0], np.ones(4))
    np.testing.assert_allclose(f[1], [0.5, 1.0, 1.0, 1.0])
    # robot 1 turns to face −x: the point is now on its right (sector 3)
    obs[:, 2:4] = [-1.0, 0.0]
    obs[1, 12] = 1.0
    np.testing.assert_allclose(mem.update(obs)[1], [1.0, 1.0, 1.0, 0.5])
    mem.reset([1])
    np.testing.assert_array_equal(mem.update(obs)[1], np.ones(4))


def test_batched_features_reject_bad_input() -> None:
    mem = BatchObstacleMemory(3, [0.0, 0.1], 4.0)
    with pytest.raises(ValueError, match=r"shape \(3, 14\)"):
        mem.update(np.ones((3, 13)))
    with pytest.raises(ValueError, match=r"row indices must be in \[0, 3\)"):
        mem.reset([3])
    with pytest.raises(ValueError, match="horizon_steps must be >= 1"):
        BatchRestTimer(3, 0)
    with pytest.raises(ValueError, match="unknown obs_rest_timer"):
        BatchEpisodeFeatures(3, None, {"steps": 4})


class _Spy(gym.vector.VectorWrapper):
    """Keeps the raw observations of the last reset/step."""

    def reset(self, **kwargs):  # type: ignore[no-untyped-def]
        self.last = super().reset(**kwargs)
        return self.last

    def step(self, actions):  # type: ignore[no-untyped-def]
        self.last = super().step(actions)
        return self.last


def test_sb3_vector_env_inputs_equal_the_policys_per_robot_inputs() -> None:
    from realitygap.baselines import rl

    n = 6
    probe = gym.make("realitygap/WheeledNav-v0", sensor_mode="fast")
    io = rl.PolicyIO.from_dict(
        {
            "obs_features": "wheeled_nav_egocentric",
            "obs_memory": {"n_sectors": 36, "horizon": 2.0},
            "obs_rest_timer": {"horizon_steps": 40},
            "obs_scene_fade": 0.2,
        }
    ).for_env(probe)
    probe.close()
    spy = _Spy(gym.make_vec(VEC_ID, num_envs=n, max_episode_steps=40))
    venv = rl.sb3_vector_env(spy, io)
    venv.seed(5)
    states = [io.new_episode_features() for _ in range(n)]
    x = venv.reset()
    np.testing.assert_array_equal(x, io.observation(spy.last[0], states))
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(90):
        x, _, done, infos = venv.step(rng.uniform(-1, 1, (n, 2)).astype(np.float32))
        obs, _, _, _, info = spy.last
        for i in np.flatnonzero(done):
            last = io.observation(info["final_obs"][i : i + 1], [states[i]])[0]
            np.testing.assert_array_equal(infos[i]["terminal_observation"], last)
            states[i] = io.new_episode_features()
            ends += 1
        np.testing.assert_array_equal(x, io.observation(obs, states))
    assert ends >= n
