"""A warm start for PPO from demonstrations: DAgger with the classical policy as the expert.

PPO from scratch on WheeledNav learns to approach the goal but rarely to stop within
3 cm and 5° of it among obstacles. The classical pipeline does this from the same
observation, so the learned policy can start from it:

1. **DAgger** (Ross, Gordon & Bagnell 2011). Round 0: the expert drives and every
   step is recorded as (network input, expert action). Round ``k``: at each step the
   expert's action is taken with probability ``β_k = beta_decay^k``, the current
   network's otherwise, and every visited state is labelled with what the expert
   would do there. The expert is stateful (plan, obstacle memory) and keeps observing
   while the network drives, so its labels are its answers to the states the network
   reaches. After each round the network is fitted on all data so far. The expert
   ``classical`` is the classical pipeline in state-feedback form
   (:meth:`~realitygap.baselines.classical.ClassicalNavPolicy.expert_config`): as it runs
   for the benchmark, its command depends on its own past commands and on a clock, so
   its labels for states another driver reaches teach a network to stop. Even so, the
   side it passes an obstacle on still comes from its last plan; the expert ``geodesic``
   (:mod:`realitygap.baselines.privileged`) reads the episode's true map instead and
   its command is a function of the estimated pose alone, so its labels do not
   contradict each other.
2. **Behaviour cloning** fits the Gaussian policy's mean to the expert's actions in the
   network's action space (the inverse of the dead band; the stop gate is +1 where the
   expert stands still, −1 elsewhere), and the value head to the discounted training
   returns of the recorded episodes, so PPO's first updates have a critic.
3. The observation normalisation is fitted on round 0 and then kept fixed, in PPO too,
   so the inputs the cloned network learned on keep their meaning.

PPO then fine-tunes the network on the training reward (:func:`~realitygap.baselines.rl.train`).

ArmCalib uses the same machinery with the observability-greedy pose selector as the
expert, in one round (plain behaviour cloning, see :data:`EXPERT_DRIVES_ONLY`). A
Gaussian policy trained by PPO alone draws its spread of poses from its exploration
noise; its deterministic action (the mean) barely depends on the state and asks for
nearly the same pose twenty times, which no identification can use. The greedy
selector's poses follow from the campaign's state (attempt count, joint readings,
conditioning), which the network can learn.

Rollouts run in worker processes (the network is evaluated there in numpy), each
seeded from the run's seed.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from realitygap.cards import ENV_CARDS, load_object
from realitygap.core.parallel import ProcessBackend

FloatArray = npt.NDArray[np.float64]

logger = logging.getLogger(__name__)

__all__ = [
    "DemoSettings",
    "NumpyActor",
    "Rollouts",
    "clone",
    "collect",
    "expert_action_to_model",
    "pretrain",
]


@dataclass(frozen=True)
class DemoSettings:
    """The ``demonstrations`` entry of a hyperparameter file.

    Parameters
    ----------
    expert : ``"classical"`` (the env's classical baseline) or ``"geodesic"`` (WheeledNav:
        the privileged shortest-path teacher of :mod:`realitygap.baselines.privileged`, whose
        command is a function of the state); see :attr:`~realitygap.cards.EnvCard.experts`.
    rounds : DAgger rounds (round 0: the expert drives alone).
    episodes : episodes per round.
    beta_decay : the expert drives a step of round ``k`` with probability ``beta_decay^k``.
    epochs : behaviour-cloning epochs over all data after each round.
    batch_size, learning_rate : of the cloning optimiser (Adam).
    value_weight : weight of the value loss next to the action loss.
    train_wrappers : training wrappers of the demonstration episodes
        (:data:`~realitygap.baselines.rl.TRAIN_WRAPPERS`), in place of the run's own
        ``train_wrappers`` (``None``: the run's), e.g. more docking starts than PPO gets.
    small_action_scale : each sample's action loss is weighted by
        ``1 / max(‖a‖, small_action_scale)²`` (``a``: the expert's motion command, without
        the stop gate), normalised to mean 1, so the small commands of the last centimetres
        count as much, relatively, as full-speed driving; ``0`` weighs all samples equally.
    workers : rollout processes (1: in this process).
    mirror : also fit the left–right mirror image of every sample
        (:meth:`~realitygap.baselines.rl.PolicyIO.mirror`): the task is symmetric, and
        the fitted network is pushed towards a policy that is too, without a bias to turn
        one way (feature maps in :data:`~realitygap.baselines.rl.OBS_MIRRORS` only).
    """

    expert: str = "classical"
    rounds: int = 4
    episodes: int = 60
    beta_decay: float = 0.5
    epochs: int = 15
    batch_size: int = 512
    learning_rate: float = 1e-3
    value_weight: float = 0.5
    small_action_scale: float = 0.0
    workers: int = 2
    train_wrappers: tuple[Mapping[str, Any], ...] | None = None
    mirror: bool = False

    def __post_init__(self) -> None:
        names = sorted({name for card in ENV_CARDS.values() for name in card.experts})
        if self.expert not in names:
            raise ValueError(f"demonstrations expert must be one of {names}, got {self.expert!r}")
        if self.rounds < 1 or self.episodes < 1 or self.epochs < 1 or self.workers < 1:
            raise ValueError(
                "demonstrations rounds, episodes, epochs and workers must be >= 1, got "
                f"{self.rounds}, {self.episodes}, {self.epochs}, {self.workers}"
            )
        if not 0.0 <= self.beta_decay <= 1.0:
            raise ValueError(f"beta_decay must be in [0, 1], got {self.beta_decay}")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> DemoSettings:
        known = set(cls.__dataclass_fields__)
        unknown = set(data) - known
        if unknown:
            raise ValueError(
                f"unknown demonstrations setting(s) {sorted(unknown)}; known: {', '.join(sorted(known))}"
            )
        values = dict(data)
        if values.get("train_wrappers") is not None:
            from realitygap.baselines.rl.wrappers import check_train_wrappers

            values["train_wrappers"] = check_train_wrappers(values["train_wrappers"])
        return cls(**values)


def expert_action_to_model(
    action: npt.ArrayLike, deadband_width: float, stop_gate: bool
) -> npt.NDArray[np.float32]:
    """The network output that :meth:`PolicyIO.action` maps to the env ``action``.

    The inverse of the dead band (``a ≠ 0`` → ``sign(a)(|a|(1 − δ) + δ)``, ``0`` → ``0``),
    plus, with a stop gate, a last component of +1 where the action is all zeros and
    −1 elsewhere.
    """
    a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    d = float(deadband_width)
    model = np.where(a != 0.0, np.sign(a) * (np.abs(a) * (1.0 - d) + d), 0.0)
    if stop_gate:
        still = np.all(a == 0.0, axis=-1, keepdims=True)
        model = np.concatenate([model, np.where(still, 1.0, -1.0)], axis=-1)
    return model.astype(np.float32)


class NumpyActor:
    """The deterministic action of an SB3 ``MlpPolicy`` (mean of the Gaussian), in numpy,
    from its ``state_dict`` — so rollout workers need no torch model."""

    def __init__(self, state_dict: Mapping[str, Any], activation: str = "tanh"):
        if activation not in ("tanh", "relu"):
            raise ValueError(f"activation must be 'tanh' or 'relu', got {activation!r}")
        self.activation = activation
        layers: list[tuple[FloatArray, FloatArray]] = []
        k = 0
        while f"mlp_extractor.policy_net.{k}.weight" in state_dict:
            layers.append(
                (
                    np.asarray(state_dict[f"mlp_extractor.policy_net.{k}.weight"], dtype=float),
                    np.asarray(state_dict[f"mlp_extractor.policy_net.{k}.bias"], dtype=float),
                )
            )
            k += 2
        self.hidden = layers
        self.out = (
            np.asarray(state_dict["action_net.weight"], dtype=float),
            np.asarray(state_dict["action_net.bias"], dtype=float),
        )

    def __call__(self, x: npt.ArrayLike) -> FloatArray:
        h = np.asarray(x, dtype=float)
        for w, b in self.hidden:
            h = h @ w.T + b
            h = np.tanh(h) if self.activation == "tanh" else np.maximum(h, 0.0)
        w, b = self.out
        return np.clip(h @ w.T + b, -1.0, 1.0)


@dataclass
class Rollouts:
    """Recorded steps: network inputs (before normalisation), expert targets in the
    network's action space, training rewards and episode ends."""

    inputs: list[npt.NDArray[np.float32]] = field(default_factory=list)
    targets: list[npt.NDArray[np.float32]] = field(default_factory=list)
    rewards: list[float] = field(default_factory=list)
    ends: list[int] = field(default_factory=list)
    """1 where an episode ended by termination, 2 by truncation, 0 elsewhere."""
    episodes: list[dict[str, float]] = field(default_factory=list)

    def extend(self, other: Rollouts) -> None:
        self.inputs += other.inputs
        self.targets += other.targets
        self.rewards += other.rewards
        self.ends += other.ends
        self.episodes += other.episodes

    def mirrored(
        self,
        perm: npt.NDArray[np.intp],
        sign: npt.NDArray[np.float32],
        action_sign: npt.NDArray[np.float32],
    ) -> Rollouts:
        """The mirror images of these steps (:meth:`~realitygap.baselines.rl.PolicyIO.mirror`):
        inputs ``x[perm] * sign``, targets ``a * action_sign``, the same rewards and ends;
        no episodes of their own, so rollout summaries count only what was driven."""
        return Rollouts(
            inputs=[(np.asarray(x)[perm] * sign).astype(np.float32) for x in self.inputs],
            targets=[(np.asarray(a) * action_sign).astype(np.float32) for a in self.targets],
            rewards=list(self.rewards),
            ends=list(self.ends),
        )

    def returns(self, gamma: float) -> FloatArray:
        """Discounted return from each step to the end of its episode."""
        out = np.zeros(len(self.rewards))
        g = 0.0
        for i in range(len(self.rewards) - 1, -1, -1):
            if self.ends[i]:
                g = 0.0
            g = self.rewards[i] + gamma * g
            out[i] = g
        return out

    def summary(self) -> dict[str, float]:
        eps = self.episodes
        return {
            "episodes": float(len(eps)),
            "steps": float(len(self.rewards)),
            "success": float(np.mean([e["success"] for e in eps])) if eps else math.nan,
            "collision": float(np.mean([e["collision"] for e in eps])) if eps else math.nan,
        }


@dataclass(frozen=True)
class _CollectTask:
    env_id: str
    expert: str
    env_kwargs: dict[str, Any]
    io: Any
    train_wrappers: tuple[Mapping[str, Any], ...]
    max_episode_steps: int | None
    seeds: tuple[int, ...]
    beta: float
    actor_state: dict[str, Any] | None
    activation: str
    obs_mean: FloatArray | None
    obs_std: FloatArray | None
    clip: float
    rng_seed: int


def _collect(task: _CollectTask) -> Rollouts:
    import realitygap  # noqa: F401  (registers the ids in a fresh worker)
    from realitygap.baselines.rl.wrappers import apply_train_wrappers

    env = gym.make(task.env_id, max_episode_steps=task.max_episode_steps, **task.env_kwargs)
    env = apply_train_wrappers(env, task.train_wrappers)
    expert = load_object(ENV_CARDS[task.env_id].experts[task.expert])(env)
    actor = NumpyActor(task.actor_state, task.activation) if task.actor_state else None
    rng = np.random.default_rng(task.rng_seed)
    io = task.io
    out = Rollouts()
    for seed in task.seeds:
        state = io.new_episode_features()
        states = [state] if state is not None else None
        obs, info = env.reset(seed=seed)
        start, done = True, False
        while not done:
            x = io.observation(np.asarray(obs, dtype=np.float32)[None], states)[0]
            a_exp, _ = expert.predict(obs, episode_start=np.array([start]), deterministic=True)
            start = False
            a_exp = np.asarray(a_exp, dtype=np.float64).reshape(-1)
            if actor is None or rng.random() < task.beta:
                action = a_exp
            else:
                assert task.obs_mean is not None and task.obs_std is not None
                z = np.clip((x - task.obs_mean) / task.obs_std, -task.clip, task.clip)
                action = io.action(actor(z))
            target = expert_action_to_model(a_exp, io.action_deadband, io.action_stop_gate)
            obs, reward, term, trunc, info = env.step(np.asarray(action, dtype=np.float32))
            done = bool(term or trunc)
            out.inputs.append(x)
            out.targets.append(target)
            out.rewards.append(float(reward))
            out.ends.append(1 if term else 2 if trunc else 0)
        out.episodes.append(
            {
                "success": float(bool(info.get("is_success", False))),
                "collision": float(bool(info.get("collision", False))),
            }
        )
    env.close()
    return out


def _collect_shared(shared: None, task: _CollectTask) -> Rollouts:
    """:func:`_collect` in the ``fn(shared, item)`` form of :meth:`ProcessBackend.map`."""
    return _collect(task)


def collect(
    env_id: str,
    env_kwargs: Mapping[str, Any],
    io: Any,
    seeds: Sequence[int],
    beta: float = 1.0,
    actor_state: Mapping[str, Any] | None = None,
    activation: str = "tanh",
    normalizer: Any = None,
    train_wrappers: Sequence[Mapping[str, Any]] = (),
    max_episode_steps: int | None = None,
    workers: int = 1,
    rng_seed: int = 0,
    expert: str = "classical",
) -> Rollouts:
    """Run one DAgger round on the episodes ``seeds`` (see the module docstring).

    ``actor_state`` is the policy's ``state_dict`` (``None``: the expert drives alone),
    ``normalizer`` the :class:`~realitygap.baselines.rl.ObsNormalizer` its inputs go
    through. The episodes are split over ``workers`` processes; the result holds each
    worker's episodes whole, one worker after the other.
    """
    if actor_state is not None and normalizer is None:
        raise ValueError(
            "a network that drives needs the observation normaliser it was fitted with"
        )
    state = (
        {
            k: np.asarray(v.detach().cpu().numpy() if hasattr(v, "detach") else v)
            for k, v in actor_state.items()
        }
        if actor_state is not None
        else None
    )
    mean = std = None
    clip = 10.0
    if normalizer is not None:
        mean = np.asarray(normalizer.mean, dtype=float)
        std = np.sqrt(np.asarray(normalizer.var, dtype=float) + normalizer.eps)
        clip = float(normalizer.clip)
    chunks = [tuple(int(s) for s in seeds[i::workers]) for i in range(max(1, workers))]
    tasks = [
        _CollectTask(
            env_id,
            expert,
            dict(env_kwargs),
            io,
            tuple(dict(w) for w in train_wrappers),
            max_episode_steps,
            chunk,
            float(beta),
            state,
            activation,
            mean,
            std,
            clip,
            rng_seed * 1000 + i,
        )
        for i, chunk in enumerate(chunks)
        if chunk
    ]
    backend = ProcessBackend(max(len(tasks), 1), start_method="forkserver")
    parts = backend.map(_collect_shared, tasks, None)
    out = Rollouts()
    for part in parts:
        out.extend(part)
    return out


def clone(
    model: Any,
    data: Rollouts,
    normalizer: Any,
    settings: DemoSettings,
    gamma: float,
    seed: int = 0,
    motion_dims: int | None = None,
) -> dict[str, float]:
    """Fit ``model.policy`` (SB3 actor-critic) to ``data``: the action mean to the expert's
    targets (mean squared error, weighted as :class:`DemoSettings` says; the first
    ``motion_dims`` target columns are the motion command, default all) and the value to
    the discounted returns. Returns the final losses."""
    import torch

    policy = model.policy
    x = torch.as_tensor(normalizer(np.asarray(data.inputs)), dtype=torch.float32)
    y = torch.as_tensor(np.asarray(data.targets), dtype=torch.float32)
    ret = torch.as_tensor(data.returns(gamma), dtype=torch.float32)
    weight = torch.ones(len(x))
    if settings.small_action_scale > 0.0:
        size = torch.linalg.vector_norm(y[:, :motion_dims], dim=1)
        weight = 1.0 / torch.clamp(size, min=settings.small_action_scale) ** 2
        weight = weight / weight.mean()
    opt = torch.optim.Adam(policy.parameters(), lr=settings.learning_rate)
    gen = torch.Generator().manual_seed(seed)
    n = len(x)
    losses = {"action_mse": math.nan, "value_mse": math.nan}
    policy.set_training_mode(True)
    for _ in range(settings.epochs):
        order = torch.randperm(n, generator=gen)
        sums = np.zeros(2)
        for i in range(0, n, settings.batch_size):
            idx = order[i : i + settings.batch_size]
            features = policy.extract_features(x[idx])
            latent_pi, latent_vf = policy.mlp_extractor(features)
            mean = policy.action_net(latent_pi)
            value = policy.value_net(latent_vf).squeeze(-1)
            a_loss = torch.mean(weight[idx, None] * (mean - y[idx]) ** 2)
            v_loss = torch.mean((value - ret[idx]) ** 2)
            loss = a_loss + settings.value_weight * v_loss
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), 1.0)
            opt.step()
            sums += (a_loss.item() * len(idx), v_loss.item() * len(idx))
        losses = {"action_mse": sums[0] / n, "value_mse": sums[1] / n}
    policy.set_training_mode(False)
    return losses


def _activation_name(model: Any) -> str:
    import torch.nn as nn

    fn = getattr(model.policy, "activation_fn", nn.Tanh)
    if fn is nn.Tanh:
        return "tanh"
    if fn is nn.ReLU:
        return "relu"
    raise ValueError(f"demonstrations support tanh or relu networks, got {fn.__name__}")


def pretrain(
    model: Any,
    env_id: str,
    env_kwargs: Mapping[str, Any],
    io: Any,
    settings: DemoSettings,
    seed: int,
    gamma: float,
    normalizer_cls: Any,
    train_wrappers: Sequence[Mapping[str, Any]] = (),
    max_episode_steps: int | None = None,
    evaluate: Callable[[Any], Mapping[str, float]] | None = None,
    log: Callable[[str], None] | None = None,
) -> tuple[Any, list[dict[str, float]]]:
    """DAgger + behaviour cloning of ``model`` (see the module docstring).

    Returns the fitted observation normaliser and one row of figures per round
    (rollout success of the mixed policy, losses, and ``evaluate(normaliser)`` when given).
    ``log`` receives one progress line per round (default: this module's logger at ``INFO``).
    """
    if log is None:
        log = logger.info
    experts = ENV_CARDS[env_id].experts if env_id in ENV_CARDS else {}
    if settings.expert not in experts:
        known = [f"{e} ({', '.join(c.experts)})" for e, c in ENV_CARDS.items() if c.experts]
        raise ValueError(
            f"no demonstration expert {settings.expert!r} for {env_id}; known: {'; '.join(known)}"
        )
    if env_id in EXPERT_DRIVES_ONLY and settings.rounds != 1:
        raise ValueError(
            f"the expert of {env_id} labels only the episodes it drives; demonstrations "
            f"need rounds = 1 (behaviour cloning), got {settings.rounds}"
        )
    activation = _activation_name(model)
    mirror = None
    if settings.mirror:
        probe = gym.make(env_id, **dict(env_kwargs))
        try:
            mirror = io.mirror(probe)
        finally:
            probe.close()
    data = Rollouts()
    normalizer = None
    rows: list[dict[str, float]] = []
    t0 = time.perf_counter()
    for k in range(settings.rounds):
        beta = settings.beta_decay**k if k > 0 else 1.0
        seeds = [
            seed * 100_000 + 10_000 + k * settings.episodes + i for i in range(settings.episodes)
        ]
        part = collect(
            env_id,
            env_kwargs,
            io,
            seeds,
            beta=beta,
            actor_state=model.policy.state_dict() if k > 0 else None,
            activation=activation,
            normalizer=normalizer,
            train_wrappers=(
                train_wrappers if settings.train_wrappers is None else settings.train_wrappers
            ),
            max_episode_steps=max_episode_steps,
            workers=settings.workers,
            rng_seed=seed * 100 + k,
            expert=settings.expert,
        )
        data.extend(part)
        if mirror is not None:
            data.extend(part.mirrored(*mirror))
        motion_dims = int(model.action_space.shape[0]) - int(bool(io.action_stop_gate))
        normalizer, row = clone_round(
            model,
            data,
            part,
            normalizer,
            normalizer_cls,
            settings,
            gamma,
            seed,
            k,
            beta,
            motion_dims,
            t0,
        )
        if evaluate is not None:
            row.update({f"eval_{key}": float(v) for key, v in evaluate(normalizer).items()})
        rows.append(row)
        log(
            f"[{time.strftime('%H:%M:%S')}] DAgger round {k + 1}/{settings.rounds} (beta {beta:.2f}): "
            + ", ".join(f"{key} {v:.3g}" for key, v in row.items() if key not in ("round", "beta"))
        )
    return normalizer, rows


def clone_round(
    model: Any,
    data: Rollouts,
    part: Rollouts,
    normalizer: Any,
    normalizer_cls: Any,
    settings: DemoSettings,
    gamma: float,
    seed: int,
    k: int,
    beta: float,
    motion_dims: int,
    t0: float,
) -> tuple[Any, dict[str, float]]:
    """One DAgger round's cloning on everything collected so far, and its log row.

    The observation normaliser is fitted on the first round's data and kept after.
    Returns the normaliser and the row: round, beta, the round's rollout summary,
    samples, the cloning losses and the wall time since ``t0`` (s).
    """
    if normalizer is None:
        x = np.asarray(data.inputs, dtype=float)
        normalizer = normalizer_cls(x.mean(axis=0), np.maximum(x.var(axis=0), 1e-3))
    losses = clone(model, data, normalizer, settings, gamma, seed + k, motion_dims)
    row = {
        "round": float(k),
        "beta": beta,
        **{f"rollout_{key}": v for key, v in part.summary().items()},
        "samples": float(len(data.rewards)),
        **losses,
        "wall_s": time.perf_counter() - t0,
    }
    return normalizer, row


def classical_wheeled_nav_expert(env: gym.Env[Any, Any]) -> Any:
    """WheeledNav's classical pipeline with
    :meth:`~realitygap.baselines.classical.ClassicalNavPolicy.expert_config`."""
    from realitygap.baselines.classical import ClassicalNavPolicy

    return ClassicalNavPolicy.from_env(env, ClassicalNavPolicy.expert_config())


def greedy_arm_calib_expert(env: gym.Env[Any, Any]) -> Any:
    """ArmCalib's observability-greedy pose selector
    (:class:`~realitygap.baselines.arm_policy.ObservabilityGreedyPolicy`)."""
    from realitygap.baselines.arm_policy import ObservabilityGreedyPolicy

    return ObservabilityGreedyPolicy.from_env(env)


def geodesic_wheeled_nav_expert(env: gym.Env[Any, Any]) -> Any:
    """WheeledNav's privileged shortest-path teacher, which plans on the episode's true map
    (:class:`~realitygap.baselines.privileged.GeodesicNavExpert`)."""
    from realitygap.baselines.privileged import GeodesicNavExpert

    return GeodesicNavExpert(env)


EXPERT_DRIVES_ONLY: frozenset[str] = frozenset({"realitygap/ArmCalib-v0"})
"""Envs whose expert can label only the episodes it drives itself (``rounds`` must be 1):
the greedy pose selector keeps its own record of the poses it chose, which a step of
another driver would falsify."""
