"""Training a PPO or SAC policy from a hyperparameter file.

Training is seeded (algorithm, every env worker, the curriculum) and runs
single-threaded torch, so a run repeats exactly on the same machine and
library versions. It writes, under ``out_dir``::

    model.zip           the SB3 model (``Algo.save``)
    model.json          metadata: env id and kwargs, spaces, algorithm, seed, steps,
                        wall time, policy I/O, observation normalisation (plain JSON)
    episodes.csv        one row per training episode (learning curve)
    eval.csv            deterministic evaluations on held-out seeds: the env's criterion,
                        and the current curriculum stage's
    checkpoints/        intermediate models
    learning_curve.png  when matplotlib is installed

A long training can be split into runs of bounded wall time with
``TrainConfig(init_model=...)`` (``realitygap train --init-model``); a PPO run can also
start from a shipped policy's exported weights.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from realitygap.baselines.rl.callbacks import evaluate_model, make_callback
from realitygap.baselines.rl.config import (
    EVAL_SEED_OFFSET,
    TRAIN_KEYS,
    Curriculum,
    TrainConfig,
    TrainResult,
    algo_class,
    check_algo,
    check_env_id,
    load_hyperparams,
    resolve_policy_kwargs,
)
from realitygap.baselines.rl.persistence import (
    LearnedPolicy,
    check_policy_matches,
    jsonable,
    read_policy_meta,
    save_policy,
    space_summary,
    write_csv_atomic,
)
from realitygap.baselines.rl.plots import plot_learning_curve
from realitygap.baselines.rl.policy_io import ObsNormalizer, PolicyIO
from realitygap.baselines.rl.vec_env import make_vec_env
from realitygap.baselines.rl.wrappers import check_train_wrappers
from realitygap.core.io import atomic_write_text

logger = logging.getLogger(__name__)


# --------------------------------------------------------------------------- training
def train(cfg: TrainConfig) -> TrainResult:
    """Train ``cfg.algo`` on ``cfg.env_id``; see the module docstring for what is written.

    With ``cfg.init_model`` the run continues a saved model (its step count, observation
    normalisation and curriculum stage), so a long training can be split into shorter runs.

    Returns
    -------
    TrainResult
        Paths of the model and its metadata, wall-clock seconds, steps, final evaluation.
    """
    env_id = check_env_id(cfg.env_id)
    algo = check_algo(cfg.algo)
    cls = algo_class(algo)
    import torch

    hp = dict(cfg.hyperparams) if cfg.hyperparams is not None else load_hyperparams(algo, env_id)
    hp = {k: v for k, v in hp.items() if not k.startswith("_")}
    budget = int(hp["n_timesteps"])
    total = int(cfg.total_timesteps if cfg.total_timesteps is not None else budget)
    n_envs = int(cfg.n_envs if cfg.n_envs is not None else hp.get("n_envs", 1))
    vec_kind = str(cfg.vec_env if cfg.vec_env is not None else hp.get("vec_env", "dummy"))
    env_kwargs = dict(hp.get("env_kwargs", {}))
    curriculum = Curriculum.from_dict(hp["curriculum"]) if hp.get("curriculum") else None
    normalize = dict(hp.get("normalize", {}) or {})
    io = PolicyIO.from_dict(hp)  # unknown feature names fail before any env starts
    train_wrappers = check_train_wrappers(hp.get("train_wrappers", ()) or ())
    probe = gym.make(env_id, **env_kwargs)
    io = io.for_env(probe)
    raw_obs_space, raw_action_space = probe.observation_space, probe.action_space
    env_spaces = {
        "env_observation_space": space_summary(raw_obs_space),
        "env_action_space": space_summary(raw_action_space),
    }
    probe.close()
    algo_kwargs = resolve_policy_kwargs({k: v for k, v in hp.items() if k not in TRAIN_KEYS})

    out_dir = Path(cfg.out_dir)
    (out_dir / "checkpoints").mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    torch.manual_seed(cfg.seed)

    max_steps = hp.get("train_max_episode_steps")
    venv = make_vec_env(
        env_id,
        env_kwargs,
        n_envs,
        cfg.seed,
        vec_kind,
        io,
        None if max_steps is None else int(max_steps),
        train_wrappers,
    )
    init_meta: dict[str, Any] = {}
    if cfg.init_model is not None:
        init_meta = read_policy_meta(cfg.init_model)
        if PolicyIO.from_dict(init_meta) != io:
            raise ValueError(
                f"{cfg.init_model} was trained with {PolicyIO.from_dict(init_meta)}, the "
                f"hyperparameters say {io}; continue with the same settings"
            )
        check_policy_matches(init_meta, env_id, raw_obs_space, raw_action_space, cfg.init_model)
    if normalize:
        from stable_baselines3.common.vec_env import VecNormalize

        venv = VecNormalize(
            venv,
            norm_obs=bool(normalize.get("obs", True)),
            norm_reward=bool(normalize.get("reward", False)),
            gamma=float(algo_kwargs.get("gamma", 0.99)),
        )
        if init_meta.get("obs_normalizer"):
            prev = ObsNormalizer.from_dict(init_meta["obs_normalizer"])
            rms = venv.obs_rms
            assert not isinstance(rms, dict), "Box observations have one running mean"
            rms.mean, rms.var = prev.mean.copy(), prev.var.copy()
            rms.count = float(init_meta.get("timesteps", 1e4))
    demo_rows: list[dict[str, float]] = list(init_meta.get("demonstrations", []) or [])
    if cfg.init_model is not None:
        if Path(cfg.init_model).suffix == ".pth":
            model = _model_from_weights(cls, hp, venv, cfg, init_meta, algo_kwargs)
        else:
            model = cls.load(cfg.init_model, env=venv, device="cpu")
            model.set_random_seed(cfg.seed)
            _continue_with(model, algo_kwargs)
        if init_meta.get("obs_norm_frozen") and normalize:
            venv.training = False
    else:
        model = cls(
            hp.get("policy", "MlpPolicy"),
            venv,
            seed=cfg.seed,
            verbose=0,
            device="cpu",
            **algo_kwargs,
        )
        if hp.get("demonstrations"):
            demo_rows = _pretrain_from_demonstrations(
                cfg,
                hp,
                model,
                venv,
                env_kwargs,
                io,
                train_wrappers,
                max_steps,
                algo_kwargs,
                env_spaces,
            )
            write_csv_atomic(out_dir / "demonstrations.csv", demo_rows)

    def normalizer() -> ObsNormalizer | None:
        if not normalize or not getattr(venv, "norm_obs", False):
            return None
        return ObsNormalizer(
            np.asarray(venv.obs_rms.mean, float),
            np.asarray(venv.obs_rms.var, float),
            float(venv.clip_obs),
        )

    t0 = time.perf_counter()
    prior_wall = float(init_meta.get("train_wall_seconds", 0.0))

    def extra() -> dict[str, Any]:
        return {
            **io.to_dict(),
            **env_spaces,
            "curriculum_stage": callback.stage,
            "init_model": str(cfg.init_model) if cfg.init_model is not None else None,
            "obs_norm_frozen": bool(normalize) and not getattr(venv, "training", True),
            "demonstrations": demo_rows,
        }

    def save(path: Path) -> Path:
        return save_policy(
            model,
            path,
            env_id,
            env_kwargs,
            algo,
            cfg.seed,
            model.num_timesteps,
            prior_wall + time.perf_counter() - t0,
            hp,
            normalizer(),
            extra(),
        )

    def current_policy() -> LearnedPolicy:
        meta: dict[str, Any] = {"obs_normalizer": None, **io.to_dict(), **env_spaces}
        norm = normalizer()
        if norm is not None:
            meta["obs_normalizer"] = norm.to_dict()
        return LearnedPolicy(model, meta, name=algo)

    callback = make_callback(
        cfg,
        total,
        budget,
        curriculum,
        int(init_meta.get("curriculum_stage", 0)),
        env_kwargs,
        out_dir,
        save,
        current_policy,
        append=cfg.init_model is not None and (out_dir / "episodes.csv").is_file(),
        log_std_max=(
            (float(hp["log_std_max"][0]), float(hp["log_std_max"][1]))
            if hp.get("log_std_max")
            else None
        ),
        train_wrappers=train_wrappers,
    )
    logger.info(
        f"[{time.strftime('%H:%M:%S')}] training {algo} on {env_id}: {total} steps "
        f"(from {model.num_timesteps}), {n_envs} x {vec_kind} envs, seed {cfg.seed} -> {out_dir}"
    )
    try:
        model.learn(
            total_timesteps=total,
            callback=callback,
            reset_num_timesteps=cfg.init_model is None,
        )
    finally:
        venv.close()
    wall = time.perf_counter() - t0
    model_path = out_dir / "model.zip"
    meta_path = save(model_path)
    final = (
        evaluate_model(
            current_policy(), env_id, env_kwargs, cfg.eval_episodes, cfg.seed + EVAL_SEED_OFFSET
        )
        if cfg.eval_episodes > 0
        else {}
    )
    meta = json.loads(meta_path.read_text(encoding="utf-8"))
    meta["final_eval"] = final
    atomic_write_text(meta_path, json.dumps(meta, indent=2) + "\n")
    plot_learning_curve(out_dir)
    logger.info(f"[{time.strftime('%H:%M:%S')}] done in {wall / 60:.1f} min: {final}")
    return TrainResult(model_path, meta_path, prior_wall + wall, int(model.num_timesteps), final)


_CONTINUE_KEYS = ("learning_rate", "clip_range", "target_kl", "n_epochs", "batch_size", "ent_coef")
"""Optimisation settings a continued run takes from the hyperparameter file (the network,
its buffers and everything else come from the saved model)."""


def _continue_with(model: Any, algo_kwargs: Mapping[str, Any]) -> None:
    """Apply the file's optimisation settings (:data:`_CONTINUE_KEYS`) to a loaded model,
    so a run can continue a model with, e.g., a smaller learning rate."""
    from stable_baselines3.common.utils import FloatSchedule

    for key in _CONTINUE_KEYS:
        if key not in algo_kwargs or not hasattr(model, key):
            continue
        value = algo_kwargs[key]
        if key == "learning_rate":
            model.learning_rate = float(value)
            model._setup_lr_schedule()
        elif key == "clip_range":
            model.clip_range = FloatSchedule(float(value))
        elif key == "ent_coef" and isinstance(value, str):
            continue  # SAC's "auto" entropy coefficient lives in the saved optimiser
        else:
            setattr(model, key, value)


def _model_from_weights(
    cls: Any,
    hp: Mapping[str, Any],
    venv: Any,
    cfg: TrainConfig,
    init_meta: Mapping[str, Any],
    algo_kwargs: Mapping[str, Any],
) -> Any:
    """A new PPO model on ``venv`` whose policy network is the exported weights
    ``cfg.init_model`` (``.pth`` + ``.json``, :func:`export_policy`): a shipped policy can be
    trained on. The optimiser starts afresh; the step count continues from the metadata."""
    import torch

    assert cfg.init_model is not None

    if cfg.algo != "ppo" or init_meta.get("algo") != "ppo":
        raise ValueError(
            f"continuing from exported weights works for PPO (the whole actor-critic is "
            f"exported); {cfg.init_model} is {init_meta.get('algo')!r}, the run is {cfg.algo!r}. "
            "Continue a SAC run from its model.zip"
        )
    if init_meta.get("policy_kwargs", {}) != jsonable(hp.get("policy_kwargs", {})):
        raise ValueError(
            f"{cfg.init_model} has policy_kwargs {init_meta.get('policy_kwargs')}, the "
            f"hyperparameters say {hp.get('policy_kwargs')}; continue with the same network"
        )
    model = cls(
        hp.get("policy", "MlpPolicy"), venv, seed=cfg.seed, verbose=0, device="cpu", **algo_kwargs
    )
    state = torch.load(Path(cfg.init_model), map_location="cpu", weights_only=True)
    model.policy.load_state_dict(state)
    model.num_timesteps = int(init_meta.get("timesteps", 0))
    return model


def _pretrain_from_demonstrations(
    cfg: TrainConfig,
    hp: Mapping[str, Any],
    model: Any,
    venv: Any,
    env_kwargs: Mapping[str, Any],
    io: PolicyIO,
    train_wrappers: Sequence[Mapping[str, Any]],
    max_steps: Any,
    algo_kwargs: Mapping[str, Any],
    env_spaces: Mapping[str, Any],
) -> list[dict[str, float]]:
    """Warm-start ``model`` by DAgger from the expert the settings name
    (:mod:`realitygap.baselines.imitation`) and freeze the observation normalisation
    at the one the network was cloned with. Returns the per-round figures."""
    from realitygap.baselines.imitation import DemoSettings, pretrain

    if cfg.algo != "ppo":
        raise ValueError(f"demonstrations warm-start PPO only, not {cfg.algo}")
    if not getattr(venv, "norm_obs", False):
        raise ValueError('demonstrations need "normalize": {"obs": true}')
    settings = DemoSettings.from_dict(hp["demonstrations"])

    def evaluate(norm: ObsNormalizer) -> dict[str, float]:
        meta = {"obs_normalizer": norm.to_dict(), **io.to_dict(), **env_spaces}
        policy = LearnedPolicy(model, meta, name="cloned")
        return evaluate_model(
            policy, cfg.env_id, env_kwargs, cfg.eval_episodes, cfg.seed + EVAL_SEED_OFFSET
        )

    norm, rows = pretrain(
        model,
        cfg.env_id,
        env_kwargs,
        io,
        settings,
        cfg.seed,
        float(algo_kwargs.get("gamma", 0.99)),
        ObsNormalizer,
        train_wrappers,
        None if max_steps is None else int(max_steps),
        evaluate=evaluate if cfg.eval_episodes > 0 else None,
        log=logger.info,
    )
    rms = venv.obs_rms
    rms.mean, rms.var = norm.mean.copy(), norm.var.copy()
    venv.training = False
    return rows
