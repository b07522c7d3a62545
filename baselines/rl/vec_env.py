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


def sb3_vector_env(env: gym.vector.VectorEnv[Any, Any, Any]) -> Any:
    """A same-step-autoreset Gymnasium ``VectorEnv`` (e.g. ``realitygap/WheeledNavVec-v0``) as
    an SB3 ``VecEnv``: one batched call per step, with SB3's per-env ``infos`` (``is_success``,
    ``collision``, ``pos_error``, ``terminal_observation``, ``TimeLimit.truncated`` and a
    Monitor-style ``episode`` record on the step an episode ends)."""
    require_sb3()
    from gymnasium.vector import AutoresetMode

    if env.metadata.get("autoreset_mode") is not AutoresetMode.SAME_STEP:
        raise ValueError(
            f"{type(env).__name__} must reset finished sub-envs in the same step "
            f"(metadata['autoreset_mode'] = AutoresetMode.SAME_STEP), got "
            f"{env.metadata.get('autoreset_mode')!r}"
        )
    return _SB3VectorEnv(env)


def _make_sb3_vector_env_class() -> type:
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv

    class SB3VectorEnv(VecEnv):  # type: ignore[misc]
        """SB3 view of a batched Gymnasium ``VectorEnv`` (see :func:`sb3_vector_env`)."""

        def __init__(self, venv: gym.vector.VectorEnv[Any, Any, Any]):
            self.venv = venv
            super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
            self._actions: np.ndarray | None = None
            self._seed: int | None = None
            self._returns = np.zeros(venv.num_envs)
            self._lengths = np.zeros(venv.num_envs, dtype=np.int64)
            self._t0 = time.perf_counter()

        def reset(self) -> np.ndarray:
            obs, _ = self.venv.reset(seed=self._seed)
            self._seed = None
            self._returns[:] = 0.0
            self._lengths[:] = 0
            return obs

        def step_async(self, actions: np.ndarray) -> None:
            self._actions = np.asarray(actions)

        def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
            assert self._actions is not None, "step_async before step_wait"
            obs, reward, term, trunc, info = self.venv.step(self._actions)
            done = term | trunc
            self._returns += reward
            self._lengths += 1
            infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
            final = info.get("final_info", info)
            for i in np.flatnonzero(done):
                d = infos[i]
                d["terminal_observation"] = info["final_obs"][i]
                d["TimeLimit.truncated"] = bool(trunc[i] and not term[i])
                for key in ("is_success", "collision", "pos_error"):
                    if key in final:
                        d[key] = final[key][i].item()
                d["episode"] = {
                    "r": float(self._returns[i]),
                    "l": int(self._lengths[i]),
                    "t": round(time.perf_counter() - self._t0, 6),
                }
            self._returns[done] = 0.0
            self._lengths[done] = 0
            return obs, np.asarray(reward, dtype=np.float32), done, infos

        def close(self) -> None:
            self.venv.close()

        def seed(self, seed: int | None = None) -> list[int | None]:
            self._seed = seed
            return [None if seed is None else seed + i for i in range(self.num_envs)]

        def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
            value = getattr(self.venv.unwrapped, attr_name)
            return [value for _ in self._get_indices(indices)]

        def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
            setattr(self.venv.unwrapped, attr_name, value)

        def env_method(
            self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any
        ) -> list[Any]:
            out = getattr(self.venv.unwrapped, method_name)(*method_args, **method_kwargs)
            return [out for _ in self._get_indices(indices)]

        def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
            return [False for _ in self._get_indices(indices)]

        def get_images(self) -> list[Any]:
            return [None for _ in range(self.num_envs)]

    return SB3VectorEnv


def _SB3VectorEnv(env: gym.vector.VectorEnv[Any, Any, Any]) -> Any:
    global _SB3_CLASS
    if _SB3_CLASS is None:
        _SB3_CLASS = _make_sb3_vector_env_class()
    return _SB3_CLASS(env)


_SB3_CLASS: type | None = None
