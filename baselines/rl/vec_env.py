"""Seeded vectorised training envs."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from realitygap.baselines.rl.config import require_sb3
from realitygap.baselines.rl.policy_io import PolicyIO
from realitygap.baselines.rl.wrappers import AttributeSetter, apply_train_wrappers


def make_env_fn(
    env_id: str,
    env_kwargs: Mapping[str, Any],
    seed: int,
    io: PolicyIO | None = None,
    max_episode_steps: int | None = None,
    train_wrappers: Sequence[Mapping[str, Any]] = (),
) -> Callable[[], gym.Env[Any, Any]]:
    """A picklable factory of one seeded training env (for ``SubprocVecEnv``)."""
    return _EnvFactory(
        env_id, dict(env_kwargs), seed, io or PolicyIO(), max_episode_steps, tuple(train_wrappers)
    )


@dataclass(frozen=True)
class _EnvFactory:
    env_id: str
    env_kwargs: dict[str, Any]
    seed: int
    io: PolicyIO = field(default_factory=PolicyIO)
    max_episode_steps: int | None = None
    train_wrappers: tuple[Mapping[str, Any], ...] = ()

    def __call__(self) -> gym.Env[Any, Any]:
        from stable_baselines3.common.monitor import Monitor

        import realitygap  # noqa: F401  (registers the ids in a fresh worker)

        env = gym.make(self.env_id, max_episode_steps=self.max_episode_steps, **self.env_kwargs)
        env = self.io.wrap(apply_train_wrappers(env, self.train_wrappers))
        env = AttributeSetter(Monitor(env))
        env.reset(seed=self.seed)
        env.action_space.seed(self.seed)
        return env


def make_vec_env(
    env_id: str,
    env_kwargs: Mapping[str, Any],
    n_envs: int,
    seed: int,
    vec_env: str = "subproc",
    io: PolicyIO | None = None,
    max_episode_steps: int | None = None,
    train_wrappers: Sequence[Mapping[str, Any]] = (),
) -> Any:
    """A seeded vectorised env: worker ``i`` is seeded ``seed + i``."""
    require_sb3()
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    if vec_env not in ("subproc", "dummy"):
        raise ValueError(f"vec_env must be 'subproc' or 'dummy', got {vec_env!r}")
    fns = [
        make_env_fn(env_id, env_kwargs, seed + i, io, max_episode_steps, train_wrappers)
        for i in range(n_envs)
    ]
    venv: SubprocVecEnv | DummyVecEnv
    if vec_env == "subproc" and n_envs > 1:
        venv = SubprocVecEnv(fns, start_method="forkserver")
    else:
        venv = DummyVecEnv(fns)
    venv.seed(seed)
    return venv


def measure_vec_env_speed(
    env_id: str,
    env_kwargs: Mapping[str, Any] | None = None,
    n_envs: int = 2,
    steps: int = 2000,
    seed: int = 0,
) -> dict[str, float]:
    """Env steps per second of ``SubprocVecEnv`` and ``DummyVecEnv`` with random actions."""
    out = {}
    for kind in ("dummy", "subproc"):
        venv = make_vec_env(env_id, env_kwargs or {}, n_envs, seed, kind)
        rng = np.random.default_rng(seed)
        venv.reset()
        low, high = venv.action_space.low, venv.action_space.high
        n_iter = max(1, steps // n_envs)
        t0 = time.perf_counter()
        for _ in range(n_iter):
            venv.step(rng.uniform(low, high, size=(n_envs, *venv.action_space.shape)))
        out[f"{kind}_steps_per_s"] = n_iter * n_envs / (time.perf_counter() - t0)
        venv.close()
    return out
