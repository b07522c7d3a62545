"""What a learned policy reads and writes around its network: PolicyIO and ObsNormalizer."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from realitygap.baselines.rl.features import (
    deadband,
    obs_feature_fn,
    scene_fade,
    stop_gate,
    wheeled_nav_egocentric_mirror,
)
from realitygap.baselines.rl.wrappers import ObsFeatures


@dataclass(frozen=True)
class PolicyIO:
    """What a learned policy does around its network, identical in training and use.

    Parameters
    ----------
    obs_features : name of a feature map in :data:`OBS_FEATURES` appended to the observation.
    action_deadband : width of :func:`deadband` on each action component.
    action_stop_gate : the network has one more action output, a stop gate (:func:`stop_gate`).
    obs_memory : an obstacle memory (:class:`~realitygap.baselines.episode_features.ObstacleMemory`)
        whose sector ranges are appended to the env observation before the feature map;
        a spec completed with the env's scan geometry by :meth:`for_env`.
    obs_rest_timer : a column for how long the robot has stood still
        (:class:`~realitygap.baselines.episode_features.RestTimer`, ``{"horizon_steps"}``),
        after the memory.
    obs_scene_fade : WheeledNav only: radius (m) within which the scan and the memory fade
        to "nothing seen" as the goal nears (:func:`scene_fade`), before the feature map;
        0: off.

    Memory and timer are the policy's episode state (:meth:`new_episode_features`).
    """

    obs_features: str | None = None
    action_deadband: float = 0.0
    action_stop_gate: bool = False
    obs_memory: Mapping[str, Any] | None = None
    obs_rest_timer: Mapping[str, Any] | None = None
    obs_scene_fade: float = 0.0

    def __post_init__(self) -> None:
        obs_feature_fn(self.obs_features)
        if not 0.0 <= self.action_deadband < 1.0:
            raise ValueError(f"action_deadband must be in [0, 1), got {self.action_deadband}")
        if not (math.isfinite(self.obs_scene_fade) and 0.0 <= self.obs_scene_fade <= 0.25):
            raise ValueError(
                "obs_scene_fade must be a radius in [0, 0.25] m (the obstacle-free margin "
                f"around the goal), got {self.obs_scene_fade!r}"
            )
        if self.complete:
            self.new_episode_features()  # validates the specs

    @property
    def complete(self) -> bool:
        """Whether the memory spec holds the env's scan geometry (see :meth:`for_env`)."""
        return not self.obs_memory or "scan_angles" in self.obs_memory

    @property
    def has_episode_features(self) -> bool:
        return bool(self.obs_memory or self.obs_rest_timer)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PolicyIO:
        """From hyperparameters or metadata (missing keys: identity)."""
        memory, timer = data.get("obs_memory"), data.get("obs_rest_timer")
        return cls(
            obs_features=data.get("obs_features") or None,
            action_deadband=float(data.get("action_deadband") or 0.0),
            action_stop_gate=bool(data.get("action_stop_gate", False)),
            obs_memory=dict(memory) if memory else None,
            obs_rest_timer=dict(timer) if timer else None,
            obs_scene_fade=float(data.get("obs_scene_fade") or 0.0),
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "obs_features": self.obs_features,
            "action_deadband": self.action_deadband,
            "action_stop_gate": self.action_stop_gate,
            "obs_memory": dict(self.obs_memory) if self.obs_memory else None,
            "obs_rest_timer": dict(self.obs_rest_timer) if self.obs_rest_timer else None,
            "obs_scene_fade": self.obs_scene_fade,
        }

    def for_env(self, env: gym.Env[Any, Any]) -> PolicyIO:
        """This I/O with the memory spec completed from ``env``'s scan geometry."""
        self._check_scene_fade(env)
        if self.complete:
            return self
        from realitygap.baselines.episode_features import memory_spec_for_env

        return replace(self, obs_memory=memory_spec_for_env(env, self.obs_memory or {}))

    def _check_scene_fade(self, env: gym.Env[Any, Any]) -> None:
        if self.obs_scene_fade > 0.0 and not hasattr(env.unwrapped, "scan_angles"):
            raise ValueError(
                f"obs_scene_fade fades a WheeledNav scan; {type(env.unwrapped).__name__} has none"
            )

    def fade_scene(self, x: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """:func:`scene_fade` of an observation with this I/O's episode features appended
        (the rest timer, last, is not scene); ``x`` itself without a fade radius."""
        if self.obs_scene_fade <= 0.0:
            return x
        return scene_fade(x, x.shape[-1] - int(bool(self.obs_rest_timer)), self.obs_scene_fade)

    def mirror(
        self, env: gym.Env[Any, Any]
    ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """The left–right mirror of this I/O's network inputs and outputs in ``env``:
        ``(perm, sign, action_sign)`` with mirrored input ``x[..., perm] * sign`` and
        mirrored network action ``a * action_sign``, from the feature map's entry in
        :data:`OBS_MIRRORS`; ``ValueError`` for a feature map without one."""
        builder = OBS_MIRRORS.get(self.obs_features or "")
        if builder is None:
            raise ValueError(
                f"obs_features {self.obs_features!r} has no mirror; feature maps with one: "
                f"{', '.join(OBS_MIRRORS)} (every input in the robot frame)"
            )
        return builder(self, env)

    def new_episode_features(self) -> Any:
        """Fresh episode features of one env (``None`` without memory and timer)."""
        if not self.has_episode_features:
            return None
        from realitygap.baselines.episode_features import EpisodeFeatures

        if not self.complete:
            raise ValueError("obs_memory lacks the scan geometry; complete it with for_env(env)")
        return EpisodeFeatures(self.obs_memory, self.obs_rest_timer)

    def observation(
        self, obs: npt.ArrayLike, states: Sequence[Any] | None = None
    ) -> npt.NDArray[np.float32]:
        """Env observation → network input (before normalisation); with episode features,
        ``states`` holds one :meth:`new_episode_features` per row of the batch, updated here."""
        x = np.asarray(obs, dtype=np.float32)
        if self.has_episode_features:
            if states is None:
                raise ValueError("a policy with obs_memory needs its episode features")
            rows = x.reshape(-1, x.shape[-1])
            if len(states) != len(rows):
                raise ValueError(f"{len(rows)} observations but {len(states)} episode states")
            feats = np.stack([st.update(r) for st, r in zip(states, rows)])
            x = np.concatenate([rows, feats], axis=-1).reshape(*x.shape[:-1], -1)
        return self.network_input(x)

    def network_input(
        self, obs: npt.ArrayLike, features: npt.ArrayLike | None = None
    ) -> npt.NDArray[np.float32]:
        """Env observations ``(N, D)`` with their episode-feature columns ``features``
        ``(N, F)`` appended (already appended if ``None``) → network input (before
        normalisation): the scene fade, then the feature map."""
        x = np.asarray(obs, dtype=np.float32)
        if features is not None:
            f = np.asarray(features, dtype=np.float32)
            if f.ndim != 2 or x.ndim != 2 or f.shape[0] != x.shape[0]:
                raise ValueError(
                    f"features must be (N, F) beside observations (N, D), got {f.shape} "
                    f"beside {x.shape}"
                )
            x = np.concatenate([x, f], axis=-1)
        x = self.fade_scene(x)
        fn = obs_feature_fn(self.obs_features)
        return fn(x) if fn is not None else x

    def action(self, model_action: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Network output → env action."""
        if self.action_stop_gate:
            return stop_gate(model_action, self.action_deadband)
        return deadband(model_action, self.action_deadband)

    def wrap(self, env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
        """The training env as the network sees it."""
        if self.action_deadband > 0.0 or self.action_stop_gate:
            env = _ActionMap(env, self)
        if self.has_episode_features:
            from realitygap.baselines.episode_features import EpisodeFeaturesWrapper

            env = EpisodeFeaturesWrapper(env, self.for_env(env).new_episode_features())
        if self.obs_scene_fade > 0.0:
            self._check_scene_fade(env)
            env = _SceneFade(env, self)
        if self.obs_features:
            env = ObsFeatures(env, self.obs_features)
        return env


class _SceneFade(gym.ObservationWrapper):
    """Training side of :meth:`PolicyIO.fade_scene` in :meth:`PolicyIO.observation`."""

    def __init__(self, env: gym.Env[Any, Any], io: PolicyIO):
        super().__init__(env)
        self.io = io

    def observation(self, observation: Any) -> Any:
        return self.io.fade_scene(np.asarray(observation, dtype=np.float32))


class _ActionMap(gym.ActionWrapper):
    """Training side of :meth:`PolicyIO.action` (dead band, stop gate)."""

    def __init__(self, env: gym.Env[Any, Any], io: PolicyIO):
        super().__init__(env)
        self.io = io
        space = env.action_space
        assert isinstance(space, gym.spaces.Box)
        if io.action_stop_gate:
            self.action_space = gym.spaces.Box(
                np.append(space.low, -1.0).astype(np.float32),
                np.append(space.high, 1.0).astype(np.float32),
                dtype=np.float32,
            )

    def action(self, action: Any) -> Any:
        return self.io.action(action)


def _wheeled_nav_egocentric_io_mirror(
    io: PolicyIO, env: gym.Env[Any, Any]
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """:meth:`PolicyIO.mirror` of WheeledNav with :func:`wheeled_nav_egocentric_features`:
    the input map of :func:`wheeled_nav_egocentric_mirror` for ``env``'s scan and ``io``'s
    episode features; the turn command changes sign, speed and stop gate do not."""
    base: Any = env.unwrapped
    if not hasattr(base, "scan_angles"):
        raise ValueError(f"a WheeledNav mirror needs a WheeledNav env, got {type(base).__name__}")
    angles = np.asarray(base.scan_angles, dtype=float)
    if not np.allclose(angles, -angles[::-1], atol=1e-9):
        raise ValueError(
            "a mirror needs scan bearings symmetric about the robot's axis; this camera "
            f"is mounted at yaw {float(np.mean(angles)):.4f} rad"
        )
    n_sectors = int((io.for_env(env).obs_memory or {}).get("n_sectors", 0))
    perm, sign = wheeled_nav_egocentric_mirror(
        angles.size, n_sectors, rest_timer=bool(io.obs_rest_timer)
    )
    action_sign = np.array([1.0, -1.0] + [1.0] * int(io.action_stop_gate), np.float32)
    return perm, sign, action_sign


OBS_MIRRORS: dict[
    str,
    Callable[
        [PolicyIO, gym.Env[Any, Any]],
        tuple[npt.NDArray[np.intp], npt.NDArray[np.float32], npt.NDArray[np.float32]],
    ],
] = {"wheeled_nav_egocentric": _wheeled_nav_egocentric_io_mirror}
"""Feature maps whose network inputs have a left–right mirror (:meth:`PolicyIO.mirror`)."""


# --------------------------------------------------------------------------- observation normalisation
@dataclass(frozen=True)
class ObsNormalizer:
    """``clip((obs - mean) / sqrt(var + eps), -clip, clip)``, stored as plain JSON."""

    mean: npt.NDArray[np.float64]
    var: npt.NDArray[np.float64]
    clip: float = 10.0
    eps: float = 1e-8
    _std: npt.NDArray[np.float64] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        # computed once: the normaliser runs on every observation of a rollout
        object.__setattr__(self, "_std", np.sqrt(self.var + self.eps))

    def __call__(self, obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
        x = (np.asarray(obs, dtype=np.float64) - self.mean) / self._std
        return np.clip(x, -self.clip, self.clip).astype(np.float32)

    def to_dict(self) -> dict[str, Any]:
        return {
            "mean": self.mean.tolist(),
            "var": self.var.tolist(),
            "clip": self.clip,
            "eps": self.eps,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ObsNormalizer:
        return cls(
            np.asarray(data["mean"], dtype=float),
            np.asarray(data["var"], dtype=float),
            float(data.get("clip", 10.0)),
            float(data.get("eps", 1e-8)),
        )
