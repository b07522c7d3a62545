"""Training-only Gymnasium wrappers: feature maps, attribute setters, reward shaping, start states."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from realitygap.baselines.rl.features import OBS_FEATURES, OBS_FEATURES_DROP, obs_feature_fn


class ObsFeatures(gym.ObservationWrapper):
    """Appends the columns of feature map ``name`` to each observation (training side)."""

    def __init__(self, env: gym.Env[Any, Any], name: str):
        super().__init__(env)
        fn = obs_feature_fn(name)
        assert fn is not None
        self.fn = fn
        n_extra = OBS_FEATURES[name][1]
        space = env.observation_space
        assert isinstance(space, gym.spaces.Box)
        big = np.float32(1e3)
        n_out = int(space.shape[-1]) + n_extra
        width = int(fn(np.zeros((1, space.shape[-1]), np.float32)).shape[-1])
        if width != n_out:
            raise ValueError(
                f"obs_features {name!r} gives {width} columns for a {space.shape[-1]}-column "
                f"observation, expected {n_out}"
            )
        # the observation's own columns keep their bounds, the map's new ones get wide ones
        drop = OBS_FEATURES_DROP.get(name, 0)
        n_new = n_out - (int(space.shape[-1]) - drop)
        low = np.concatenate([space.low[drop:], np.full(n_new, -big, np.float32)])
        high = np.concatenate([space.high[drop:], np.full(n_new, big, np.float32)])
        self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)

    def observation(self, observation: Any) -> Any:
        return self.fn(observation)


def set_env_attrs(env: gym.Env[Any, Any], values: Mapping[str, Any]) -> None:
    """Set each attribute on the outermost layer of ``env`` (wrappers, then the base env)
    that defines it; ``AttributeError`` naming the env when none does."""
    for name, value in values.items():
        layer: Any = env
        while True:
            if name in vars(layer) or hasattr(type(layer), name):
                setattr(layer, name, value)
                break
            if not isinstance(layer, gym.Wrapper):
                raise AttributeError(
                    f"neither {type(env.unwrapped).__name__} nor its wrappers have an "
                    f"attribute {name!r}"
                )
            layer = layer.env


class AttributeSetter(gym.Wrapper):
    """Lets a vectorised env set attributes of the env and its training wrappers
    (``env_method("set_env_attrs", {...})``, see :func:`set_env_attrs`)."""

    def set_env_attrs(self, values: Mapping[str, Any]) -> None:
        set_env_attrs(self.env, values)


class WheeledNavRestRelaxation(gym.Wrapper):
    """Training only: WheeledNav success with a looser "at rest" condition.

    The env's success needs the pose within tolerance *and* the robot at rest
    (``|v| < 0.01`` m/s, ``|ω| < 0.05`` rad/s), which a stochastic policy in training
    almost never is. This wrapper also declares success — the env's bonus, termination,
    ``info["is_success"]`` — when the pose is within the env's current tolerances and
    ``|v| < rest_v_tol``, ``|ω| < rest_w_tol``; a curriculum can shrink these to the
    env's own values. Evaluation and the benchmark never use it.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        rest_v_tol: float = 10.0,
        rest_w_tol: float = 10.0,
        bonus: float = 5.0,
    ):
        super().__init__(env)
        self.rest_v_tol = float(rest_v_tol)
        self.rest_w_tol = float(rest_w_tol)
        self.bonus = float(bonus)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if terminated or info.get("is_success") or info.get("collision"):
            return obs, reward, terminated, truncated, info
        base: Any = self.env.unwrapped
        if (
            info["pos_error"] <= base.success_pos_tol
            and info["heading_error"] <= base.success_ang_tol
        ):
            v, w = base.robot.twist()
            if abs(v) < self.rest_v_tol and abs(w) < self.rest_w_tol:
                info = {**info, "is_success": True, "relaxed_success": True}
                return obs, float(reward) + self.bonus, True, truncated, info
        return obs, reward, terminated, truncated, info


def wheeled_nav_potential(
    pos_error: Any, heading_error: Any, pos_scale: float, ang_scale: float
) -> Any:
    r"""The shaping potential :math:`\Phi` of :class:`WheeledNavShaping` for pose errors
    ``pos_error`` (m) and ``heading_error`` (rad), scalars or arrays of one shape."""
    d, a = np.asarray(pos_error, dtype=float), np.abs(np.asarray(heading_error, dtype=float))
    near = np.exp(-d / (3.0 * pos_scale)) * np.exp(-a / ang_scale)
    return 0.5 * np.exp(-d / pos_scale) + 0.5 * near


class WheeledNavShaping(gym.Wrapper):
    r"""Training only: extra WheeledNav reward terms for the final approach and for collisions.

    ``precision`` weighs a potential-based term :math:`F = \Phi(s') - \Phi(s)` on the true
    pose error (distance ``d``, heading error ``a``):

    .. math::

        \Phi = \tfrac12 e^{-d / s_d} + \tfrac12 e^{-d / (3 s_d)}\, e^{-a / s_a}

    which grows from 0 far away to 1 exactly on the goal pose, steeply over the last few
    centimetres and degrees (``s_d = pos_scale``, ``s_a = ang_scale``), where the env's
    progress and heading terms are nearly flat. Its sum over an episode is
    ``Φ(end) − Φ(start)``, so it pays for ending on the goal pose, not for loitering.
    ``collision_penalty`` is subtracted on a collision on top of the env's own penalty: with
    the env's terms alone an early crash can cost less than the time cost of an episode
    that runs out.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        precision: float = 0.0,
        pos_scale: float = 0.05,
        ang_scale: float = 0.1,
        collision_penalty: float = 0.0,
    ):
        super().__init__(env)
        if pos_scale <= 0 or ang_scale <= 0:
            raise ValueError(f"pos_scale and ang_scale must be > 0, got {pos_scale}, {ang_scale}")
        self.precision = float(precision)
        self.pos_scale = float(pos_scale)
        self.ang_scale = float(ang_scale)
        self.collision_penalty = float(collision_penalty)
        self._phi = 0.0

    def potential(self, pos_error: float, heading_error: float) -> float:
        """``Φ`` of a pose error (m, rad); 1 on the goal pose."""
        return float(
            wheeled_nav_potential(pos_error, heading_error, self.pos_scale, self.ang_scale)
        )

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._phi = self.potential(info["pos_error"], info["heading_error"])
        return obs, info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        phi = self.potential(info["pos_error"], info["heading_error"])
        extra = self.precision * (phi - self._phi)
        self._phi = phi
        if info.get("collision"):
            extra -= self.collision_penalty
        return obs, float(reward) + extra, terminated, truncated, info


class WheeledNavDockingStarts(gym.Wrapper):
    """Training only: some episodes start next to the goal, facing anywhere.

    Docking — the last centimetres and the turn onto the goal heading — is a few seconds
    at the end of an episode, and a robot that arrives with a large heading error is
    rarer still, so a network sees little of it. With probability ``probability`` a reset
    draws the episode as usual (layout, goal), then starts it again from a pose within
    ``radius`` (m) of the goal position, with a uniform heading and bearing and the
    distance ``radius · u²`` (``u`` uniform): half of these starts lie within ``radius / 4``
    of the goal, where the robot must turn in place onto the goal heading.
    The env keeps obstacles ``body_radius + 0.25`` m clear of its start and goal, so such
    a start is free. Every draw comes from the env's own seeded generator.
    """

    def __init__(self, env: gym.Env[Any, Any], probability: float = 0.3, radius: float = 0.25):
        super().__init__(env)
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability}")
        if not 0.0 < radius <= 0.25:
            raise ValueError(
                f"radius must be in (0, 0.25] m (the obstacle-free margin around the goal), "
                f"got {radius}"
            )
        self.probability = float(probability)
        self.radius = float(radius)

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        if kwargs.get("options"):
            return obs, info  # the caller chose the poses
        rng: np.random.Generator = self.env.unwrapped.np_random
        if rng.random() >= self.probability:
            return obs, info
        goal = np.asarray(info["goal"], dtype=float)
        r = self.radius * rng.random() ** 2
        phi = rng.uniform(-math.pi, math.pi)
        start = np.array(
            [
                goal[0] + r * math.cos(phi),
                goal[1] + r * math.sin(phi),
                rng.uniform(-math.pi, math.pi),
            ]
        )
        return self.env.reset(options={"start": start, "goal": goal})


class ArmObservabilityShaping(gym.Wrapper):
    r"""Training only: ArmCalib reward for measured poses that make the identification
    better conditioned.

    The env pays for a drop of the validation error, which needs an identification, so
    for the first ``min_poses`` attempts every choice of pose earns nothing. This adds the
    potential-based term :math:`w\,(\Phi' - \Phi)` with

    .. math::

        \Phi = \frac{1}{p} \sum_{i=1}^{p} \log_{10}(\sigma_i + \varepsilon)

    over the singular values :math:`\sigma_i` of the column-scaled pair Jacobian of the
    poses measured so far (the O1 observability index in logarithms, the analysis of
    :class:`~realitygap.baselines.arm_policy.PairObservability` on the *nominal* model,
    as a real cell could compute it). Its sum over a campaign is
    :math:`w(\Phi_\text{end} - \Phi_0)`, so it pays for the final pose set, not for an
    order of visits.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        weight: float = 1.0,
        epsilon: float = 1e-2,
        pool_size: int = 200,
    ):
        super().__init__(env)
        from realitygap.baselines.arm_policy import PairObservability

        if not (weight >= 0.0 and epsilon > 0.0 and pool_size >= 10):
            raise ValueError(
                f"weight >= 0, epsilon > 0 and pool_size >= 10 expected, got {weight}, "
                f"{epsilon}, {pool_size}"
            )
        base: Any = env.unwrapped
        if not hasattr(base, "candidate_pool"):
            raise ValueError(
                f"arm_observability_shaping needs ArmCalib-v0, got {type(base).__name__}"
            )
        self.model = PairObservability.from_env(env, int(pool_size))
        self.weight = float(weight)
        self.epsilon = float(epsilon)
        self._q: list[npt.NDArray[np.float64]] = []
        self._phi0 = self.potential(self._q)
        self._phi = self._phi0

    def potential(self, q: Sequence[npt.ArrayLike]) -> float:
        """``Φ`` of the measured joint readings ``q``."""
        sv = self.model.singular_values_of(np.asarray(q).reshape(-1, 6))
        return float(np.mean(np.log10(sv + self.epsilon)))

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._q = []
        self._phi = self._phi0
        return obs, info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if info.get("outcome") != "ok":
            return obs, reward, terminated, truncated, info  # no new pose: Φ unchanged
        self._q.append(np.asarray(info["q_encoder"], dtype=float))
        phi = self.potential(self._q)
        extra = self.weight * (phi - self._phi)
        self._phi = phi
        return obs, float(reward) + extra, terminated, truncated, info


TRAIN_WRAPPERS: dict[str, Callable[..., gym.Env[Any, Any]]] = {
    "arm_observability_shaping": ArmObservabilityShaping,
    "wheeled_nav_rest_relaxation": WheeledNavRestRelaxation,
    "wheeled_nav_shaping": WheeledNavShaping,
    "wheeled_nav_docking_starts": WheeledNavDockingStarts,
}
"""Training-only wrappers by name (hyperparameter ``train_wrappers``)."""


def check_train_wrappers(specs: Sequence[Mapping[str, Any]]) -> tuple[dict[str, Any], ...]:
    """The training wrapper specs ``[{"name": ..., **params}, ...]`` as a tuple of dicts;
    ``ValueError`` naming the known wrappers for an unknown name."""
    out = tuple(dict(spec) for spec in specs)
    for spec in out:
        if spec.get("name") not in TRAIN_WRAPPERS:
            raise ValueError(
                f"unknown training wrapper {spec.get('name')!r}; known: {', '.join(TRAIN_WRAPPERS)}"
            )
    return out


def apply_train_wrappers(
    env: gym.Env[Any, Any], specs: Sequence[Mapping[str, Any]] | None
) -> gym.Env[Any, Any]:
    """Wrap ``env`` in the training wrappers ``[{"name": ..., **params}, ...]``."""
    for spec in check_train_wrappers(specs or ()):
        params = dict(spec)
        name = params.pop("name")
        env = TRAIN_WRAPPERS[name](env, **params)
    return env
