"""The training callback (learning curve, curriculum, evaluations, checkpoints) and evaluation."""

from __future__ import annotations

import csv
import functools
import logging
import math
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from realitygap.baselines.rl.config import EVAL_SEED_OFFSET, Curriculum, TrainConfig, env_slug
from realitygap.baselines.rl.persistence import LearnedPolicy, read_csv, write_csv_atomic
from realitygap.baselines.rl.wrappers import apply_train_wrappers, set_env_attrs

logger = logging.getLogger(__name__)


# --------------------------------------------------------------------------- callbacks
EPISODE_COLUMNS: tuple[str, ...] = (
    "timesteps",
    "wall_s",
    "return",
    "length",
    "success",
    "pos_error",
    "collision",
    "stage",
)
"""Columns of a run's ``episodes.csv`` (one row per training episode)."""


@dataclass(frozen=True)
class RecorderSettings:
    """What the training callback records and how (see :func:`make_callback`)."""

    cfg: TrainConfig
    total: int
    budget: int
    curriculum: Curriculum | None
    initial_stage: int
    env_kwargs: Mapping[str, Any]
    out_dir: Path
    save_fn: Callable[[Path], Any]
    policy_fn: Callable[[], LearnedPolicy]
    append: bool = False
    log_std_max: tuple[float, float] | None = None
    train_wrappers: Sequence[Mapping[str, Any]] = ()


def make_callback(
    cfg: TrainConfig,
    total: int,
    budget: int,
    curriculum: Curriculum | None,
    initial_stage: int,
    env_kwargs: Mapping[str, Any],
    out_dir: Path,
    save_fn: Callable[[Path], Any],
    policy_fn: Callable[[], LearnedPolicy],
    append: bool = False,
    log_std_max: tuple[float, float] | None = None,
    train_wrappers: Sequence[Mapping[str, Any]] = (),
) -> Any:
    """The SB3 callback of a training run: learning curve (``episodes.csv``), curriculum,
    evaluations (``eval.csv``), checkpoints, ``log_std`` bound and progress lines.

    ``total`` is this run's step count and ``budget`` the file's ``n_timesteps`` (the
    curriculum and ``log_std_max`` schedules refer to it); ``save_fn(path)`` saves a
    checkpoint and ``policy_fn()`` gives the current policy for evaluations. With
    ``append`` a continued run adds to the folder's CSV files.
    """
    settings = RecorderSettings(
        cfg,
        total,
        budget,
        curriculum,
        initial_stage,
        env_kwargs,
        out_dir,
        save_fn,
        policy_fn,
        append,
        log_std_max,
        tuple(train_wrappers),
    )
    return _recorder_class()(settings)


@functools.cache
def _recorder_class() -> type:
    from stable_baselines3.common.callbacks import BaseCallback

    return type("TrainingRecorder", (_RecorderSteps, BaseCallback), {})


class _RecorderSteps:
    """What :func:`make_callback`'s callback does at each SB3 hook, in named steps.

    Mixed into SB3's ``BaseCallback`` (imported only when a callback is made), whose
    ``num_timesteps``, ``training_env``, ``model`` and ``locals`` it reads.
    """

    num_timesteps: int
    training_env: Any
    model: Any
    locals: dict[str, Any]

    def __init__(self, settings: RecorderSettings) -> None:
        super().__init__(verbose=0)  # type: ignore[call-arg]
        self.settings = s = settings
        curriculum, out_dir, append = s.curriculum, s.out_dir, s.append
        self.t_start = time.perf_counter()
        self.last_print = self.t_start
        self.recent: deque[bool] = deque(maxlen=curriculum.window if curriculum else 100)
        self.stage = s.initial_stage
        self.stage_start = 0
        self.final_forced = False
        self.episodes = 0
        self.start_steps = 0
        self.next_ckpt: float = math.inf
        self.next_eval: float = math.inf
        self.ep_file = (out_dir / "episodes.csv").open(
            "a" if append else "w", newline="", encoding="utf-8"
        )
        self.ep_csv = csv.writer(self.ep_file)
        self.eval_rows: list[dict[str, float]] = (
            [
                {k: float(v) if v != "" else math.nan for k, v in r.items()}
                for r in read_csv(out_dir / "eval.csv")
            ]
            if append and (out_dir / "eval.csv").is_file()
            else []
        )
        if append:
            return
        self.ep_csv.writerow(list(EPISODE_COLUMNS))

    def _on_training_start(self) -> None:
        cfg = self.settings.cfg
        curriculum = self.settings.curriculum
        self.start_steps = self.num_timesteps
        if cfg.checkpoint_every:
            self.next_ckpt = self.num_timesteps + cfg.checkpoint_every
        if cfg.eval_every:
            self.next_eval = self.num_timesteps + cfg.eval_every
        if curriculum is not None:
            self._apply_stage()

    def _apply_stage(self) -> None:
        curriculum = self.settings.curriculum
        assert curriculum is not None
        values = curriculum.values(self.stage)
        self.training_env.env_method("set_env_attrs", values)
        self.recent.clear()
        self.stage_start = self.num_timesteps

    def _promote(self, why: str) -> None:
        curriculum = self.settings.curriculum
        assert curriculum is not None
        self.stage += 1
        self._apply_stage()
        vals = ", ".join(f"{k}={v:.3g}" for k, v in curriculum.values(self.stage).items())
        logger.info(
            f"[{time.strftime('%H:%M:%S')}] curriculum stage {self.stage}/"
            f"{curriculum.n_stages} at {self.num_timesteps} steps ({why}): {vals}"
        )

    def _on_rollout_end(self) -> None:
        log_std_max = self.settings.log_std_max
        budget = self.settings.budget
        if log_std_max is None:
            return
        log_std = getattr(self.model.policy, "log_std", None)
        if log_std is None:
            return
        import torch

        f = min(1.0, self.num_timesteps / max(budget, 1))
        bound = log_std_max[0] + f * (log_std_max[1] - log_std_max[0])
        with torch.no_grad():
            log_std.clamp_(max=bound)

    def _on_step(self) -> bool:
        self._record_episodes()
        if self.settings.curriculum is not None:
            self._update_curriculum()
        self._checkpoint_and_evaluate()
        now = time.perf_counter()
        if now - self.last_print >= self.settings.cfg.progress_every_s:
            self.last_print = now
            self._progress(now)
        return True

    def _record_episodes(self) -> None:
        """One row of ``episodes.csv`` per episode that ended at this step."""
        infos = self.locals.get("infos", [])
        dones = self.locals.get("dones", [])
        for done, info in zip(dones, infos):
            if not done or "episode" not in info:
                continue
            self.episodes += 1
            success = bool(info.get("is_success", False))
            self.recent.append(success)
            self.ep_csv.writerow(
                [
                    self.num_timesteps,
                    round(time.perf_counter() - self.t_start, 2),
                    round(float(info["episode"]["r"]), 4),
                    int(info["episode"]["l"]),
                    int(success),
                    round(float(info.get("pos_error", math.nan)), 4),
                    int(bool(info.get("collision", False))),
                    self.stage,
                ]
            )

    def _checkpoint_and_evaluate(self) -> None:
        """Save a checkpoint and evaluate when their step counts come round."""
        cfg = self.settings.cfg
        if self.num_timesteps >= self.next_ckpt:
            self.next_ckpt += cfg.checkpoint_every
            self.settings.save_fn(
                self.settings.out_dir / "checkpoints" / f"model_{self.num_timesteps}_steps.zip"
            )
        if self.num_timesteps >= self.next_eval:
            self.next_eval += cfg.eval_every
            self._evaluate()

    def _update_curriculum(self) -> None:
        curriculum = self.settings.curriculum
        budget = self.settings.budget
        assert curriculum is not None
        if not self.final_forced and self.num_timesteps >= curriculum.final_fraction * budget:
            self.final_forced = True
            if self.stage < curriculum.n_stages:
                self.stage = curriculum.n_stages
                self._apply_stage()
            return
        if self.stage >= curriculum.n_stages:
            return
        if (
            curriculum.gate == "train"
            and len(self.recent) == self.recent.maxlen
            and float(np.mean(self.recent)) >= curriculum.promote_at
        ):
            self._promote(f"training success {np.mean(self.recent):.2f}")
        elif (
            curriculum.max_stage_steps
            and self.num_timesteps - self.stage_start >= curriculum.max_stage_steps
        ):
            self._promote("stage step limit")

    def _progress(self, now: float) -> None:
        cfg = self.settings.cfg
        curriculum = self.settings.curriculum
        total = self.settings.total
        elapsed = now - self.t_start
        done = self.num_timesteps - self.start_steps
        rate = done / max(elapsed, 1e-9)
        eta = (total - done) / max(rate, 1e-9)
        rec = f"{np.mean(self.recent):.2f}" if self.recent else "-"
        extra = ""
        if curriculum is not None:
            vals = curriculum.values(self.stage)
            extra = " tolerances " + ", ".join(f"{k}={v:.3g}" for k, v in vals.items())
        logger.info(
            f"[{time.strftime('%H:%M:%S')}] {cfg.algo} {env_slug(cfg.env_id)} seed {cfg.seed}: "
            f"{done}/{total} steps ({100 * done / total:.0f} %, {self.num_timesteps} in all), "
            f"{rate:.0f} steps/s, ETA {eta / 60:.1f} min, {self.episodes} episodes, "
            f"recent success {rec}{extra}"
        )
        self.ep_file.flush()

    def _evaluate(self) -> None:
        cfg = self.settings.cfg
        curriculum = self.settings.curriculum
        env_kwargs = self.settings.env_kwargs
        out_dir = self.settings.out_dir
        policy_fn = self.settings.policy_fn
        train_wrappers = self.settings.train_wrappers
        if cfg.eval_episodes <= 0:
            return
        stats = evaluate_model(
            policy_fn(), cfg.env_id, env_kwargs, cfg.eval_episodes, cfg.seed + EVAL_SEED_OFFSET
        )
        row = {
            "timesteps": float(self.num_timesteps),
            "wall_s": time.perf_counter() - self.t_start,
            **stats,
        }
        if curriculum is not None and curriculum.gate == "eval":
            # a stage entered at this very step (step limit) is not judged before it ran
            fresh = self.num_timesteps <= self.stage_start
            if self.stage < curriculum.n_stages and not self.final_forced and not fresh:
                gate = evaluate_model(
                    policy_fn(),
                    cfg.env_id,
                    env_kwargs,
                    cfg.eval_episodes,
                    cfg.seed + EVAL_SEED_OFFSET,
                    train_wrappers,
                    curriculum.values(self.stage),
                )
                row["stage_success"] = gate["success"]
                if gate["success"] >= curriculum.promote_at:
                    self._promote(f"deterministic success {gate['success']:.2f} at this stage")
            row["stage"] = float(self.stage)
        self.eval_rows.append(row)
        write_csv_atomic(out_dir / "eval.csv", self.eval_rows)
        logger.info(
            f"[{time.strftime('%H:%M:%S')}] eval at {self.num_timesteps} steps: strict success "
            f"{stats['success']:.2f}, within 10 cm {stats['reached_10cm']:.2f}, collisions "
            f"{stats['collision']:.2f}, mean return {stats['return']:.2f}"
        )

    def _on_training_end(self) -> None:
        self.ep_file.close()


def evaluate_model(
    policy: Any,
    env_id: str,
    env_kwargs: Mapping[str, Any],
    n_episodes: int,
    seed: int,
    train_wrappers: Sequence[Mapping[str, Any]] = (),
    attrs: Mapping[str, Any] | None = None,
) -> dict[str, float]:
    """Deterministic episodes of ``policy`` (anything with ``predict``) on seeds ``seed,
    seed+1, …``. Without ``train_wrappers`` and ``attrs`` this is the env's default success
    criterion; with them (the curriculum gate) the current training stage's. Returns
    success, within-10-cm and collision rates and the mean return."""
    import realitygap  # noqa: F401

    env = apply_train_wrappers(gym.make(env_id, **dict(env_kwargs)), train_wrappers)
    if attrs:
        set_env_attrs(env, attrs)
    success, reached, collision, returns = [], [], [], []
    for k in range(n_episodes):
        obs, info = env.reset(seed=seed + k)
        done, total, best, start = False, 0.0, math.inf, True
        while not done:
            action, _ = policy.predict(obs, episode_start=np.array([start]), deterministic=True)
            start = False
            obs, r, term, trunc, info = env.step(action)
            total += float(r)
            best = min(best, float(info.get("pos_error", math.inf)))
            done = term or trunc
        success.append(bool(info.get("is_success", False)))
        collision.append(bool(info.get("collision", False)))
        reached.append(best <= 0.10 and not collision[-1])
        returns.append(total)
    env.close()
    return {
        "success": float(np.mean(success)),
        "reached_10cm": float(np.mean(reached)),
        "collision": float(np.mean(collision)),
        "return": float(np.mean(returns)),
    }
