"""Seeded vectorised training envs."""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from realitygap.baselines.rl.batch_features import BatchEpisodeFeatures
from realitygap.baselines.rl.config import require_sb3
from realitygap.baselines.rl.policy_io import PolicyIO
from realitygap.baselines.rl.wrappers import (
    AttributeSetter,
    apply_train_wrappers,
    wheeled_nav_potential,
)


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


def make_vector_train_env(
    vector_id: str,
    env_kwargs: Mapping[str, Any],
    n_envs: int,
    seed: int,
    io: PolicyIO | None = None,
    max_episode_steps: int | None = None,
    train_wrappers: Sequence[Mapping[str, Any]] = (),
) -> Any:
    """A seeded training env of ``n_envs`` robots in the vector env ``vector_id``
    (``gymnasium.make_vec``), as SB3 sees it (:func:`sb3_vector_env`): robot ``i`` is seeded
    ``seed + i``. ``env_kwargs`` are the PyBullet env's; ``sensor_mode`` must be ``fast``."""
    import realitygap  # noqa: F401  (registers the ids)

    kwargs = dict(env_kwargs)
    mode = kwargs.pop("sensor_mode", "fast")
    if str(getattr(mode, "value", mode)) != "fast":
        raise ValueError(
            f"the vectorised env has the fast sensors only; env_kwargs sensor_mode is {mode!r}"
        )
    if max_episode_steps is not None:
        kwargs["max_episode_steps"] = int(max_episode_steps)
    venv = sb3_vector_env(
        gym.make_vec(vector_id, num_envs=int(n_envs), **kwargs), io, train_wrappers
    )
    venv.seed(seed)
    return venv


def sb3_vector_env(
    env: gym.vector.VectorEnv[Any, Any, Any],
    io: PolicyIO | None = None,
    train_wrappers: Sequence[Mapping[str, Any]] = (),
) -> Any:
    """A same-step-autoreset Gymnasium ``VectorEnv`` (e.g. ``realitygap/WheeledNavVec-v0``) as
    an SB3 ``VecEnv``: one batched call per step, with SB3's per-env ``infos`` (``is_success``,
    ``collision``, ``pos_error``, ``terminal_observation``, ``TimeLimit.truncated`` and a
    Monitor-style ``episode`` record on the step an episode ends).

    ``io`` puts the policy's input and output maps around the env, on the whole batch (the
    training side of :meth:`PolicyIO.wrap`; episode features kept per robot).
    ``train_wrappers`` may hold ``wheeled_nav_shaping`` (its potential and collision
    penalty, :class:`~realitygap.baselines.rl.wrappers.WheeledNavShaping`, on the batch);
    other training wrappers act on single envs and are refused.
    """
    require_sb3()
    from gymnasium.vector import AutoresetMode

    if env.metadata.get("autoreset_mode") is not AutoresetMode.SAME_STEP:
        raise ValueError(
            f"{type(env).__name__} must reset finished sub-envs in the same step "
            f"(metadata['autoreset_mode'] = AutoresetMode.SAME_STEP), got "
            f"{env.metadata.get('autoreset_mode')!r}"
        )
    shaping = docking = None
    for spec in train_wrappers:
        name = spec.get("name")
        kwargs = {k: v for k, v in spec.items() if k != "name"}
        if name == "wheeled_nav_shaping":
            shaping = _VectorShaping(**kwargs)
        elif name == "wheeled_nav_docking_starts" and hasattr(env.unwrapped, "restart_from"):
            docking = _VectorDocking(**kwargs)
        else:
            raise ValueError(
                f"train wrapper {name!r} acts on single envs; a vector env takes "
                "'wheeled_nav_shaping' and, with restart_from, 'wheeled_nav_docking_starts'"
            )
    global _SB3_CLASS
    if _SB3_CLASS is None:
        _SB3_CLASS = _make_sb3_vector_env_class()
    return _SB3_CLASS(env, io or PolicyIO(), shaping, docking)


def _make_sb3_vector_env_class() -> type:
    from stable_baselines3.common.vec_env.base_vec_env import VecEnv

    class SB3VectorEnv(VecEnv):  # type: ignore[misc]
        """SB3 view of a batched Gymnasium ``VectorEnv`` (see :func:`sb3_vector_env`)."""

        def __init__(
            self,
            venv: gym.vector.VectorEnv[Any, Any, Any],
            io: PolicyIO,
            shaping: Any,
            docking: Any,
        ):
            self.venv, self.io, self.shaping, self.docking = venv, io, shaping, docking
            self._rng = np.random.default_rng(0)
            n = venv.num_envs
            if io.has_episode_features and not io.complete:
                io = self.io = io.for_env(venv)
            self.features = (
                BatchEpisodeFeatures(n, io.obs_memory, io.obs_rest_timer)
                if io.has_episode_features
                else None
            )
            space = venv.single_observation_space
            n_feat = 0 if self.features is None else self.features.n_features
            width = io.network_input(
                np.zeros((1, *space.shape), np.float32),
                np.zeros((1, n_feat), np.float32) if n_feat else None,
            ).shape[-1]
            if width == space.shape[-1] and not io.obs_features:
                obs_space = space
            else:
                big = np.float32(1e3)
                obs_space = gym.spaces.Box(-big, big, shape=(width,), dtype=np.float32)
            act_space = venv.single_action_space
            if io.action_stop_gate:
                act_space = gym.spaces.Box(
                    np.append(act_space.low, -1.0).astype(np.float32),
                    np.append(act_space.high, 1.0).astype(np.float32),
                    dtype=np.float32,
                )
            super().__init__(n, obs_space, act_space)
            self._actions: np.ndarray | None = None
            self._seed: int | None = None
            self._phi = np.zeros(n)
            self._returns = np.zeros(n)
            self._lengths = np.zeros(n, dtype=np.int64)
            self._t0 = time.perf_counter()

        def _input(self, obs: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
            """Network input of the robots ``rows`` (all if ``None``) after observations
            ``obs``, updating their episode features."""
            if self.features is None:
                return self.io.observation(obs)
            return self.io.network_input(obs, self.features.update(obs, rows))

        def _potential(self, info: Mapping[str, Any]) -> np.ndarray:
            sh = self.shaping
            return np.asarray(
                wheeled_nav_potential(
                    info["pos_error"], info["heading_error"], sh.pos_scale, sh.ang_scale
                )
            )

        def _dock(self, rows: np.ndarray, obs: np.ndarray, info: dict[str, Any]) -> Any:
            """Training only: restart a share of robots ``rows`` next to their goal
            (:class:`~realitygap.baselines.rl.wrappers.WheeledNavDockingStarts`' draw)."""
            if self.docking is None or rows.size == 0:
                return obs, info
            rng, dk = self._rng, self.docking
            pick = rows[rng.random(rows.size) < dk.probability]
            if pick.size == 0:
                return obs, info
            goal = np.asarray(info["goal"], dtype=float)[pick]
            r = dk.radius * rng.random(pick.size) ** 2
            phi = rng.uniform(-np.pi, np.pi, pick.size)
            starts = np.column_stack(
                [
                    goal[:, 0] + r * np.cos(phi),
                    goal[:, 1] + r * np.sin(phi),
                    rng.uniform(-np.pi, np.pi, pick.size),
                ]
            )
            new_obs, new_info = self.venv.unwrapped.restart_from(pick, starts)
            obs = obs.copy()
            obs[pick] = new_obs[pick]
            info = dict(info)
            for key in ("pos_error", "heading_error"):
                info[key] = np.asarray(info[key], dtype=float).copy()
                info[key][pick] = new_info[key][pick]
            return obs, info

        def reset(self) -> np.ndarray:
            obs, info = self.venv.reset(seed=self._seed)
            if self._seed is not None:
                self._rng = np.random.default_rng([self._seed, 1])
            self._seed = None
            obs, info = self._dock(np.arange(self.num_envs), obs, info)
            self._returns[:] = 0.0
            self._lengths[:] = 0
            if self.features is not None:
                self.features.reset()
            if self.shaping is not None:
                self._phi = self._potential(info)
            return self._input(obs)

        def step_async(self, actions: np.ndarray) -> None:
            self._actions = np.asarray(actions)

        def step_wait(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
            assert self._actions is not None, "step_async before step_wait"
            act = self.io.action(self._actions)
            obs, reward, term, trunc, info = self.venv.step(act)
            done = term | trunc
            final = info.get("final_info", info)
            obs, info = self._dock(np.flatnonzero(done), obs, info)
            reward = np.asarray(reward, dtype=np.float64)
            if self.shaping is not None:
                phi = self._potential(final)
                reward = reward + self.shaping.precision * (phi - self._phi)
                reward = reward - self.shaping.collision_penalty * np.asarray(final["collision"])
                self._phi = np.where(done, self._potential(info), phi)
            self._returns += reward
            self._lengths += 1
            infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
            ended = np.flatnonzero(done)
            if ended.size:
                last = self._input(info["final_obs"][ended], ended)
                if self.features is not None:
                    self.features.reset(ended)
            for j, i in enumerate(ended):
                d = infos[i]
                d["terminal_observation"] = last[j]
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
            x = self._input(obs)
            return x, reward.astype(np.float32), done, infos

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


_SB3_CLASS: type | None = None


@dataclass(frozen=True)
class _VectorDocking:
    """The parameters of :class:`~realitygap.baselines.rl.wrappers.WheeledNavDockingStarts`."""

    probability: float = 0.3
    radius: float = 0.25

    def __post_init__(self) -> None:
        if not 0.0 <= self.probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {self.probability}")
        if not 0.0 < self.radius <= 0.25:
            raise ValueError(
                f"radius must be in (0, 0.25] m (the obstacle-free margin around the goal), "
                f"got {self.radius}"
            )


@dataclass(frozen=True)
class _VectorShaping:
    """The parameters of :class:`~realitygap.baselines.rl.wrappers.WheeledNavShaping`."""

    precision: float = 0.0
    pos_scale: float = 0.05
    ang_scale: float = 0.1
    collision_penalty: float = 0.0

    def __post_init__(self) -> None:
        if self.pos_scale <= 0 or self.ang_scale <= 0:
            raise ValueError(
                f"pos_scale and ang_scale must be > 0, got {self.pos_scale}, {self.ang_scale}"
            )
