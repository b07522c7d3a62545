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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from realitygap.baselines.rl.callbacks import evaluate_model, make_callback
from realitygap.baselines.rl.checks import check_training
from realitygap.baselines.rl.config import (
    EVAL_SEED_OFFSET,
    TRAIN_KEYS,
    Curriculum,
    TrainConfig,
    TrainResult,
    algo_class,
    check_algo,
    check_env_id,
    resolve_policy_kwargs,
    vector_env_id,
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
from realitygap.baselines.rl.vec_env import make_vec_env, make_vector_train_env
from realitygap.baselines.rl.wrappers import check_train_wrappers
from realitygap.core.io import atomic_write_text

logger = logging.getLogger(__name__)


# --------------------------------------------------------------------------- training
@dataclass(frozen=True)
class _RunSettings:
    """A run's settings resolved from its :class:`TrainConfig` and hyperparameters."""

    env_id: str
    algo: str
    hp: dict[str, Any]
    budget: int
    total: int
    n_envs: int
    vec_kind: str
    env_kwargs: dict[str, Any]
    curriculum: Curriculum | None
    normalize: dict[str, Any]
    io: PolicyIO
    train_wrappers: tuple[dict[str, Any], ...]
    raw_obs_space: gym.Space[Any]
    raw_action_space: gym.Space[Any]
    env_spaces: dict[str, Any]
    algo_kwargs: dict[str, Any]
    max_steps: int | None
    vector: bool = False


def _resolve_settings(cfg: TrainConfig) -> _RunSettings:
    """Check the names, read the hyperparameters and probe one env for its spaces."""
    env_id = check_env_id(cfg.env_id)
    algo = check_algo(cfg.algo)
    algo_class(algo)
    import torch  # noqa: F401  (after the install hint of algo_class)

    plan = check_training(cfg)  # every input, before any env starts
    hp = {k: v for k, v in plan.hp.items() if not k.startswith("_")}
    budget = int(hp["n_timesteps"])
    env_kwargs = dict(hp.get("env_kwargs", {}))
    curriculum = Curriculum.from_dict(hp["curriculum"]) if hp.get("curriculum") else None
    normalize = dict(hp.get("normalize", {}) or {})
    io = PolicyIO.from_dict(hp)  # unknown feature names fail before any env starts
    train_wrappers = check_train_wrappers(hp.get("train_wrappers", ()) or ())
    probe = gym.make(env_id, **env_kwargs)
    io = io.for_env(probe)
    raw_obs_space, raw_action_space = probe.observation_space, probe.action_space
    probe.close()
    max_steps = hp.get("train_max_episode_steps")
    return _RunSettings(
        env_id=env_id,
        algo=algo,
        hp=hp,
        budget=budget,
        total=plan.total_timesteps,
        n_envs=plan.n_envs,
        vec_kind=plan.vec_env,
        env_kwargs=env_kwargs,
        curriculum=curriculum,
        normalize=normalize,
        io=io,
        train_wrappers=train_wrappers,
        raw_obs_space=raw_obs_space,
        raw_action_space=raw_action_space,
        env_spaces={
            "env_observation_space": space_summary(raw_obs_space),
            "env_action_space": space_summary(raw_action_space),
        },
        algo_kwargs=resolve_policy_kwargs({k: v for k, v in hp.items() if k not in TRAIN_KEYS}),
        max_steps=None if max_steps is None else int(max_steps),
        vector=bool(cfg.vector),
    )


def _read_init_meta(cfg: TrainConfig, rs: _RunSettings) -> dict[str, Any]:
    """Metadata of the model a run continues (empty without one), checked against the run."""
    if cfg.init_model is None:
        return {}
    init_meta = read_policy_meta(cfg.init_model)
    if PolicyIO.from_dict(init_meta) != rs.io:
        raise ValueError(
            f"{cfg.init_model} was trained with {PolicyIO.from_dict(init_meta)}, the "
            f"hyperparameters say {rs.io}; continue with the same settings"
        )
    check_policy_matches(
        init_meta, rs.env_id, rs.raw_obs_space, rs.raw_action_space, cfg.init_model
    )
    return init_meta


def _normalize_env(venv: Any, rs: _RunSettings, init_meta: Mapping[str, Any]) -> Any:
    """Wrap ``venv`` in SB3's running observation (and reward) normalisation, seeded with
    the statistics of a continued model."""
    from stable_baselines3.common.vec_env import VecNormalize

    venv = VecNormalize(
        venv,
        norm_obs=bool(rs.normalize.get("obs", True)),
        norm_reward=bool(rs.normalize.get("reward", False)),
        gamma=float(rs.algo_kwargs.get("gamma", 0.99)),
    )
    if init_meta.get("obs_normalizer"):
        prev = ObsNormalizer.from_dict(init_meta["obs_normalizer"])
        rms = venv.obs_rms
        assert not isinstance(rms, dict), "Box observations have one running mean"
        rms.mean, rms.var = prev.mean.copy(), prev.var.copy()
        rms.count = float(init_meta.get("timesteps", 1e4))
    return venv


def _build_model(
    cfg: TrainConfig,
    rs: _RunSettings,
    venv: Any,
    init_meta: Mapping[str, Any],
    out_dir: Path,
) -> tuple[Any, list[dict[str, float]]]:
    """The model to train: continued from ``cfg.init_model``, or new (and warm-started from
    demonstrations when the hyperparameters ask for it). Returns it with the
    demonstration figures."""
    cls = algo_class(rs.algo)
    demo_rows: list[dict[str, float]] = list(init_meta.get("demonstrations", []) or [])
    if cfg.init_model is not None:
        if Path(cfg.init_model).suffix == ".pth":
            model = _model_from_weights(cls, rs.hp, venv, cfg, init_meta, rs.algo_kwargs)
        else:
            model = cls.load(cfg.init_model, env=venv, device="cpu")
            model.set_random_seed(cfg.seed)
            _continue_with(model, rs.algo_kwargs)
        if init_meta.get("obs_norm_frozen") and rs.normalize:
            venv.training = False
        return model, demo_rows
    model = cls(
        rs.hp.get("policy", "MlpPolicy"),
        venv,
        seed=cfg.seed,
        verbose=0,
        device="cpu",
        **rs.algo_kwargs,
    )
    if rs.hp.get("demonstrations") and rs.vector:
        demo_rows = _pretrain_from_vector_demonstrations(cfg, rs, model, venv)
        write_csv_atomic(out_dir / "demonstrations.csv", demo_rows)
    elif rs.hp.get("demonstrations"):
        demo_rows = _pretrain_from_demonstrations(
            cfg,
            rs.hp,
            model,
            venv,
            rs.env_kwargs,
            rs.io,
            rs.train_wrappers,
            rs.max_steps,
            rs.algo_kwargs,
            rs.env_spaces,
        )
        write_csv_atomic(out_dir / "demonstrations.csv", demo_rows)
    return model, demo_rows


class _Run:
    """A model in training: saves it with its metadata and wraps it as a policy."""

    def __init__(
        self,
        cfg: TrainConfig,
        rs: _RunSettings,
        model: Any,
        venv: Any,
        init_meta: Mapping[str, Any],
        demo_rows: list[dict[str, float]],
    ):
        self.cfg, self.rs, self.model, self.venv = cfg, rs, model, venv
        self.demo_rows = demo_rows
        self.t0 = time.perf_counter()
        self.prior_wall = float(init_meta.get("train_wall_seconds", 0.0))
        self.callback: Any = None

    def normalizer(self) -> ObsNormalizer | None:
        """The observation normalisation in force (``None`` without one)."""
        venv = self.venv
        if not self.rs.normalize or not getattr(venv, "norm_obs", False):
            return None
        return ObsNormalizer(
            np.asarray(venv.obs_rms.mean, float),
            np.asarray(venv.obs_rms.var, float),
            float(venv.clip_obs),
        )

    def extra(self) -> dict[str, Any]:
        """Metadata beyond :func:`save_policy`'s own: policy I/O, spaces, curriculum."""
        cfg = self.cfg
        return {
            **self.rs.io.to_dict(),
            **self.rs.env_spaces,
            "curriculum_stage": self.callback.stage,
            "init_model": str(cfg.init_model) if cfg.init_model is not None else None,
            "obs_norm_frozen": bool(self.rs.normalize) and not getattr(self.venv, "training", True),
            "demonstrations": self.demo_rows,
            "train_env": vector_env_id(self.rs.env_id) if self.rs.vector else self.rs.env_id,
        }

    def save(self, path: Path) -> Path:
        """Save the model and its metadata to ``path``; returns the metadata path."""
        rs = self.rs
        return save_policy(
            self.model,
            path,
            rs.env_id,
            rs.env_kwargs,
            rs.algo,
            self.cfg.seed,
            self.model.num_timesteps,
            self.prior_wall + time.perf_counter() - self.t0,
            rs.hp,
            self.normalizer(),
            self.extra(),
        )

    def current_policy(self) -> LearnedPolicy:
        """The model as it stands, as a ``predict``-able policy."""
        meta: dict[str, Any] = {
            "obs_normalizer": None,
            **self.rs.io.to_dict(),
            **self.rs.env_spaces,
        }
        norm = self.normalizer()
        if norm is not None:
            meta["obs_normalizer"] = norm.to_dict()
        return LearnedPolicy(self.model, meta, name=self.rs.algo)


def _make_run_callback(
    cfg: TrainConfig, rs: _RunSettings, run: _Run, init_meta: Mapping[str, Any], out_dir: Path
) -> Any:
    hp = rs.hp
    return make_callback(
        cfg,
        rs.total,
        rs.budget,
        rs.curriculum,
        int(init_meta.get("curriculum_stage", 0)),
        rs.env_kwargs,
        out_dir,
        run.save,
        run.current_policy,
        append=cfg.init_model is not None and (out_dir / "episodes.csv").is_file(),
        log_std_max=(
            (float(hp["log_std_max"][0]), float(hp["log_std_max"][1]))
            if hp.get("log_std_max")
            else None
        ),
        train_wrappers=rs.train_wrappers,
    )


def _finish(cfg: TrainConfig, rs: _RunSettings, run: _Run, out_dir: Path) -> TrainResult:
    """Save the final model, evaluate it on held-out seeds and plot the learning curve."""
    wall = time.perf_counter() - run.t0
    model_path = out_dir / "model.zip"
    meta_path = run.save(model_path)
    final = (
        evaluate_model(
            run.current_policy(),
            rs.env_id,
            rs.env_kwargs,
            cfg.eval_episodes,
            cfg.seed + EVAL_SEED_OFFSET,
        )
        if cfg.eval_episodes > 0
        else {}
    )
    meta = json.loads(meta_path.read_text(encoding="utf-8"))
    meta["final_eval"] = final
    atomic_write_text(meta_path, json.dumps(meta, indent=2) + "\n")
    plot_learning_curve(out_dir)
    logger.info(f"[{time.strftime('%H:%M:%S')}] done in {wall / 60:.1f} min: {final}")
    return TrainResult(
        model_path, meta_path, run.prior_wall + wall, int(run.model.num_timesteps), final
    )


def train(cfg: TrainConfig) -> TrainResult:
    """Train ``cfg.algo`` on ``cfg.env_id``; see the module docstring for what is written.

    With ``cfg.init_model`` the run continues a saved model (its step count, observation
    normalisation and curriculum stage), so a long training can be split into shorter runs.

    Returns
    -------
    TrainResult
        Paths of the model and its metadata, wall-clock seconds, steps, final evaluation.
    """
    rs = _resolve_settings(cfg)
    import torch

    out_dir = Path(cfg.out_dir)
    (out_dir / "checkpoints").mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    torch.manual_seed(cfg.seed)

    if rs.vector:
        venv = make_vector_train_env(
            vector_env_id(rs.env_id),
            {**rs.env_kwargs, **dict(rs.hp.get("vector_env_kwargs", {}) or {})},
            rs.n_envs,
            cfg.seed,
            rs.io,
            rs.max_steps,
            rs.train_wrappers,
        )
    else:
        venv = make_vec_env(
            rs.env_id,
            rs.env_kwargs,
            rs.n_envs,
            cfg.seed,
            rs.vec_kind,
            rs.io,
            rs.max_steps,
            rs.train_wrappers,
        )
    init_meta = _read_init_meta(cfg, rs)
    if rs.normalize:
        venv = _normalize_env(venv, rs, init_meta)
    model, demo_rows = _build_model(cfg, rs, venv, init_meta, out_dir)
    run = _Run(cfg, rs, model, venv, init_meta, demo_rows)
    run.callback = _make_run_callback(cfg, rs, run, init_meta, out_dir)
    logger.info(
        f"[{time.strftime('%H:%M:%S')}] training {rs.algo} on {rs.env_id}: {rs.total} steps "
        f"(from {model.num_timesteps}), {rs.n_envs} x "
        f"{'vectorised surrogate' if rs.vector else rs.vec_kind} envs, seed {cfg.seed} "
        f"-> {out_dir}"
    )
    try:
        model.learn(
            total_timesteps=rs.total,
            callback=run.callback,
            reset_num_timesteps=cfg.init_model is None,
        )
    finally:
        venv.close()
    return _finish(cfg, rs, run, out_dir)


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


def _pretrain_from_vector_demonstrations(
    cfg: TrainConfig, rs: _RunSettings, model: Any, venv: Any
) -> list[dict[str, float]]:
    """Warm-start ``model`` by DAgger on the vector env with the batched expert the settings
    name (:mod:`realitygap.baselines.rl.vector_imitation`; as many robots as training) and
    freeze the observation normalisation at the one the network was cloned with."""
    from realitygap.baselines.imitation import DemoSettings
    from realitygap.baselines.rl.vector_imitation import pretrain_vector

    if cfg.algo != "ppo":
        raise ValueError(f"demonstrations warm-start PPO only, not {cfg.algo}")
    if not getattr(venv, "norm_obs", False):
        raise ValueError('demonstrations need "normalize": {"obs": true}')
    settings = DemoSettings.from_dict(rs.hp["demonstrations"])
    kwargs = {**rs.env_kwargs, **dict(rs.hp.get("vector_env_kwargs", {}) or {})}

    def make_env(seed: int, wrappers: Sequence[Mapping[str, Any]]) -> Any:
        return make_vector_train_env(
            vector_env_id(rs.env_id), kwargs, rs.n_envs, seed, rs.io, rs.max_steps, wrappers
        )

    norm, rows = pretrain_vector(
        model,
        make_env,
        rs.io,
        settings,
        cfg.seed,
        float(rs.algo_kwargs.get("gamma", 0.99)),
        ObsNormalizer,
        rs.train_wrappers,
        log=logger.info,
    )
    rms = venv.obs_rms
    rms.mean, rms.var = norm.mean.copy(), norm.var.copy()
    venv.training = False
    return rows
