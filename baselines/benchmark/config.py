"""The settings of a benchmark run and the episodes they give each cell.

Below :mod:`~realitygap.baselines.benchmark.runner` (which runs them) and
:mod:`~realitygap.baselines.benchmark.vector` (whose surrogate column the runner adds), so
that both read the same counts and seeds without importing each other.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from realitygap.baselines.benchmark.policies import PolicySpec

__all__ = ["BenchmarkConfig", "episode_seeds", "n_episodes"]


@dataclass(frozen=True)
class BenchmarkConfig:
    """Settings of one benchmark run.

    Parameters
    ----------
    env_ids : environments (default: every registered one).
    policies : policy specs (see
        :func:`~realitygap.baselines.benchmark.policies.parse_policies`).
    episodes : episodes per cell (env × policy × reality × sensor mode).
    realities : reality profiles besides ``nominal``; profiles for another robot are
        skipped for an env.
    sensor_modes : ``fast`` and/or ``image``.
    seed : episode ``k`` of an env uses env seed ``1000 * seed + k`` for every policy.
    env_kwargs : extra ``gym.make`` kwargs per env id.
    episode_counts : episode counts overriding ``episodes``, keyed ``"<env_id>:<mode>"``,
        ``"<env_id>"`` or ``"<mode>"`` (most specific first); 0 leaves the cells out. Image
        mode renders and is ~50x slower than fast mode.
    policies_by_mode : policy names allowed per sensor mode (default: all).
    chunk : episodes per task sent to a worker (streaming granularity).
    """

    env_ids: tuple[str, ...]
    policies: tuple[PolicySpec, ...]
    episodes: int = 20
    realities: tuple[str, ...] = ("kobuki-worn",)
    sensor_modes: tuple[str, ...] = ("fast",)
    seed: int = 0
    env_kwargs: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    episode_counts: Mapping[str, int] = field(default_factory=dict)
    policies_by_mode: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    chunk: int = 5


def n_episodes(cfg: BenchmarkConfig, env_id: str, mode: str) -> int:
    """Episodes per cell of ``env_id`` in sensor ``mode`` (see ``episode_counts``)."""
    for key in (f"{env_id}:{mode}", env_id, mode):
        if key in cfg.episode_counts:
            return int(cfg.episode_counts[key])
    return int(cfg.episodes)


def episode_seeds(cfg: BenchmarkConfig, n: int) -> list[int]:
    """The episode seeds every policy runs: ``1000 * seed + k``."""
    return [1000 * cfg.seed + k for k in range(n)]
