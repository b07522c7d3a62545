"""DAgger warm start on the vectorised WheeledNav: the privileged expert for ``N`` robots
per call.

The same procedure as :func:`realitygap.baselines.imitation.pretrain` (DAgger rounds,
behaviour cloning of the action mean and of the value, observation normalisation fitted
on round 0 and then frozen), with the rollouts on ``realitygap/WheeledNavVec-v0``
instead of PyBullet worker processes:

* every robot of the vector env is labelled at every step by
  :class:`~realitygap.baselines.privileged.BatchGeodesicExpert`, which reads the vector
  env's state (estimated poses, goals, true layouts) — one numpy call for all robots;
* in round ``k`` each robot's step is driven by the expert with probability
  ``beta_decay^k`` and by the current network (its deterministic action, one batched
  torch call) otherwise;
* a round runs the ``N`` robots until ``episodes`` episodes have ended; steps of
  episodes still running at the end of a round count as truncated (their value targets
  are the discounted rewards seen so far).

The network inputs are those of training (:meth:`~realitygap.baselines.rl.PolicyIO.observation`
through the SB3 view :func:`~realitygap.baselines.rl.vec_env.sb3_vector_env`), so the
cloned network is the one PPO then fine-tunes.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.baselines.imitation import (
    DemoSettings,
    Rollouts,
    clone_round,
    expert_action_to_model,
)

logger = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]

__all__ = ["VECTOR_EXPERTS", "collect_vector", "network_actions", "pretrain_vector"]

VECTOR_EXPERTS: dict[str, str] = {
    "geodesic": "realitygap.baselines.privileged:BatchGeodesicExpert",
}
"""Demonstration experts that act on a whole vector env per call, by the name
:class:`~realitygap.baselines.imitation.DemoSettings` gives them."""

DEMO_SEED_OFFSET = 10_000
"""Robot ``i`` of the demonstration env of a run with seed ``s`` is seeded
``s * 100_000 + DEMO_SEED_OFFSET + i`` (as the PyBullet demonstrations' episodes)."""


def _vector_expert(name: str, env: Any) -> Any:
    from realitygap.cards import load_object

    if name not in VECTOR_EXPERTS:
        raise ValueError(
            f"demonstrations on the vector env need a batched expert; expert {name!r} has none "
            f"(batched experts: {', '.join(VECTOR_EXPERTS)})"
        )
    return load_object(VECTOR_EXPERTS[name])(env)


def network_actions(model: Any, x: npt.NDArray[np.float32], normalizer: Any) -> FloatArray:
    """Deterministic actions (the Gaussian mean, clipped to [-1, 1]) of ``model.policy`` for
    network inputs ``x`` (N, D) before normalisation."""
    import torch

    policy = model.policy
    with torch.no_grad():
        z = torch.as_tensor(normalizer(x), dtype=torch.float32)
        latent_pi, _ = policy.mlp_extractor(policy.extract_features(z))
        mean = policy.action_net(latent_pi)
    return np.clip(mean.numpy().astype(np.float64), -1.0, 1.0)


def collect_vector(
    venv: Any,
    expert: Any,
    io: Any,
    episodes: int,
    beta: float,
    rng: np.random.Generator,
    model: Any = None,
    normalizer: Any = None,
    max_calls: int = 100_000,
) -> Rollouts:
    """One DAgger round on the SB3 view ``venv`` of a vector env (see the module docstring).

    Parameters
    ----------
    venv : :func:`~realitygap.baselines.rl.vec_env.sb3_vector_env` of a WheeledNav vector env.
    expert : batched expert with ``act(pose, goal) -> (N, 2)`` on the env's state.
    io : the policy's :class:`~realitygap.baselines.rl.PolicyIO`.
    episodes : the round ends once this many episodes have ended.
    beta : probability that the expert drives a robot's step (1: the expert alone).
    rng : draws which robots the expert drives.
    model, normalizer : the network that drives otherwise, and its input normalisation.
    max_calls : bound on the env calls of the round.

    Returns
    -------
    Rollouts
        Each robot's steps in order, one robot after the other; every step labelled with
        the expert's action in the network's action space.
    """
    if beta < 1.0 and (model is None or normalizer is None):
        raise ValueError("a round where the network drives needs the model and its normaliser")
    base = venv.venv.unwrapped
    n = venv.num_envs
    x = venv.reset()
    xs, ys, rs, es = [], [], [], []
    out = Rollouts()
    ended = 0
    for _ in range(int(max_calls)):
        a_exp = expert.act(base.estimate, base.goal)
        target = expert_action_to_model(a_exp, io.action_deadband, io.action_stop_gate)
        action = target.astype(np.float64)
        if beta < 1.0:
            net = network_actions(model, x, normalizer)
            by_net = rng.random(n) >= beta
            action[by_net] = net[by_net]
        x_next, reward, done, infos = venv.step(action.astype(np.float32))
        ends = np.zeros(n, dtype=np.int8)
        for i in np.flatnonzero(done):
            d = infos[i]
            ends[i] = 2 if d.get("TimeLimit.truncated", False) else 1
            out.episodes.append(
                {
                    "success": float(bool(d.get("is_success", False))),
                    "collision": float(bool(d.get("collision", False))),
                }
            )
        xs.append(x)
        ys.append(target)
        rs.append(np.asarray(reward, dtype=np.float64))
        es.append(ends)
        x = x_next
        ended += int(np.sum(done))
        if ended >= episodes:
            break
    end = np.array(es)
    end[-1][end[-1] == 0] = 2  # episodes still running: cut here
    order = (1, 0)  # (T, N, ...) -> robot by robot
    x_all = np.transpose(np.array(xs), (*order, 2)).reshape(-1, xs[0].shape[-1])
    y_all = np.transpose(np.array(ys), (*order, 2)).reshape(-1, ys[0].shape[-1])
    out.inputs = list(x_all.astype(np.float32))
    out.targets = list(y_all.astype(np.float32))
    out.rewards = np.transpose(np.array(rs), order).reshape(-1).tolist()
    out.ends = np.transpose(end, order).reshape(-1).astype(int).tolist()
    return out


def pretrain_vector(
    model: Any,
    make_env: Callable[[int, Sequence[Mapping[str, Any]]], Any],
    io: Any,
    settings: DemoSettings,
    seed: int,
    gamma: float,
    normalizer_cls: Any,
    train_wrappers: Sequence[Mapping[str, Any]] = (),
    log: Callable[[str], None] | None = None,
) -> tuple[Any, list[dict[str, float]]]:
    """DAgger + behaviour cloning of ``model`` on a vector env (see the module docstring).

    Parameters
    ----------
    model : the SB3 PPO model whose policy is fitted.
    make_env : ``make_env(seed, train_wrappers)`` returns the SB3 view of the vector env
        (robot ``i`` seeded ``seed + i``); its number of robots is the rollout batch.
    io, settings, seed, gamma, normalizer_cls, train_wrappers, log :
        as :func:`realitygap.baselines.imitation.pretrain`.

    Returns
    -------
    tuple
        The fitted observation normaliser and one row of figures per round (rollout
        success of the mixed policy, losses, samples, env steps, wall seconds).
    """
    if log is None:
        log = logger.info
    wrappers = train_wrappers if settings.train_wrappers is None else settings.train_wrappers
    venv = make_env(seed * 100_000 + DEMO_SEED_OFFSET, wrappers)
    try:
        expert = _vector_expert(settings.expert, venv.venv)
        rng = np.random.default_rng([seed, 20])
        data = Rollouts()
        normalizer = None
        rows: list[dict[str, float]] = []
        motion_dims = int(model.action_space.shape[0]) - int(bool(io.action_stop_gate))
        t0 = time.perf_counter()
        for k in range(settings.rounds):
            beta = settings.beta_decay**k if k > 0 else 1.0
            part = collect_vector(venv, expert, io, settings.episodes, beta, rng, model, normalizer)
            data.extend(part)
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
            rows.append(row)
            log(
                f"[{time.strftime('%H:%M:%S')}] vector DAgger round {k + 1}/{settings.rounds} "
                f"(beta {beta:.2f}): "
                + ", ".join(
                    f"{key} {v:.3g}" for key, v in row.items() if key not in ("round", "beta")
                )
            )
    finally:
        venv.close()
    return normalizer, rows
