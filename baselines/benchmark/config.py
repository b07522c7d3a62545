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
    realities: tuple[str, ...] | None = None
    sensor_modes: tuple[str, ...] = ("fast",)
    seed: int = 0
    env_kwargs: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    episode_counts: Mapping[str, int] = field(default_factory=dict)
    policies_by_mode: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    chunk: int = 5

    def __post_init__(self) -> None:
        """Check and convert every field (:func:`check_benchmark_config`)."""
        for name, value in check_benchmark_config(self).items():
            object.__setattr__(self, name, value)


BENCHMARK_OPTIONS: dict[str, str] = {
    "env_ids": "--envs",
    "policies": "--policies",
    "episodes": "--episodes",
    "realities": "--reality",
    "sensor_modes": "--sensor-modes",
    "seed": "--seed",
    "episode_counts": "--image-episodes",
}
"""The ``realitygap benchmark`` option of each :class:`BenchmarkConfig` field."""

MAX_BENCHMARK_SEED = (2**32 - 1) // 1000 - 1
"""Largest ``seed``: episode seeds ``1000 * seed + k`` stay below 2³² (NumPy's legacy seeds)."""


def _opt(name: str) -> str:
    opt = BENCHMARK_OPTIONS.get(name)
    return f"{opt} ({name})" if opt else name


def _names(value: Any, name: str, what: str, example: str) -> tuple[str, ...]:
    if isinstance(value, str) or not isinstance(value, (tuple, list)):
        raise TypeError(
            f"{_opt(name)} must be a tuple of {what}, got {value!r:.60}. Fix: e.g. {example}"
        )
    out = tuple(value)
    for v in out:
        if not isinstance(v, str) or not v.strip():
            raise ValueError(
                f"{_opt(name)}: each entry must be a non-empty string ({what}), got {v!r:.60} "
                f"in {list(out)!r:.100}. Fix: e.g. {example}"
            )
    dup = sorted({v for v in out if out.count(v) > 1})
    if dup:
        raise ValueError(
            f"{_opt(name)}: {', '.join(map(repr, dup))} given more than once; each cell would "
            "run twice. Fix: give each once"
        )
    return out


def check_benchmark_config(cfg: BenchmarkConfig) -> dict[str, Any]:
    """Every field of ``cfg`` checked and converted before any episode runs: the env ids
    registered, the policies known and their files readable, every reality profile or
    reality file loaded (effects and parameter bounds), the sensor modes known, the counts
    and seeds in range. :class:`BenchmarkConfig` calls it when it is made.

    Returns
    -------
    dict
        Field → checked value.

    Raises
    ------
    TypeError, ValueError, FileNotFoundError
        Naming the option and field, what was expected, what came and the fix.
    """
    from realitygap.baselines.benchmark.policies import POLICY_KINDS, check_policy_spec
    from realitygap.baselines.benchmark.profiles import SENSOR_MODES, check_reality_applies
    from realitygap.baselines.rl import check_env_id
    from realitygap.core.checks import check_int

    out: dict[str, Any] = {}
    env_ids = _names(cfg.env_ids, "env_ids", "env ids", "realitygap/WheeledNav-v0")
    if not env_ids:
        raise ValueError(
            f"{_opt('env_ids')}: expected at least one environment id, got none. Fix: give "
            "comma-separated env ids such as realitygap/WheeledNav-v0, or 'all'"
        )
    try:
        out["env_ids"] = tuple(check_env_id(e) for e in env_ids)
    except ValueError as exc:
        raise ValueError(f"{_opt('env_ids')}: {exc}") from None
    policies = cfg.policies
    if isinstance(policies, (str, bytes)) or not isinstance(policies, (tuple, list)):
        raise TypeError(
            f"{_opt('policies')} must be a tuple of PolicySpec (parse_policies), got "
            f"{policies!r:.60}"
        )
    if not policies:
        raise ValueError(
            f"{_opt('policies')}: expected at least one policy, got none. Fix: e.g. "
            f"{','.join(POLICY_KINDS)}"
        )
    out["policies"] = tuple(check_policy_spec(p) for p in policies)
    names = [p.name for p in out["policies"]]
    if len(set(names)) != len(names):
        raise ValueError(f"{_opt('policies')}: policy names must be unique, got {names}")
    out["episodes"] = check_int(
        cfg.episodes, _opt("episodes"), low=1, what="a positive integer", fix="e.g. 20"
    )
    out["seed"] = check_int(
        cfg.seed, _opt("seed"), low=0, high=MAX_BENCHMARK_SEED, what="a non-negative integer"
    )
    out["chunk"] = check_int(cfg.chunk, "chunk", low=1, what="a positive integer")
    if cfg.realities is None:  # the default: kobuki-worn where a requested env drives it
        from realitygap.baselines.benchmark.profiles import default_realities

        realities = default_realities(out["env_ids"], ("kobuki-worn",))
    else:
        realities = _names(cfg.realities, "realities", "reality profiles", "('kobuki-worn',)")
    for r in realities:
        # every file read, every effect checked; it changes the robot of a requested env
        check_reality_applies(r, out["env_ids"], _opt("realities"))
    out["realities"] = realities
    modes = _names(cfg.sensor_modes, "sensor_modes", "sensor modes", "('fast', 'image')")
    if not modes:
        raise ValueError(
            f"{_opt('sensor_modes')}: expected at least one of {', '.join(SENSOR_MODES)}, "
            "got none. Fix: e.g. fast"
        )
    for m in modes:
        if m not in SENSOR_MODES:
            raise ValueError(
                f"{_opt('sensor_modes')}: unknown sensor mode {m!r}; expected "
                f"{' and/or '.join(SENSOR_MODES)}. Fix: e.g. --sensor-modes fast,image"
            )
    out["sensor_modes"] = modes
    if not isinstance(cfg.episode_counts, Mapping):
        raise TypeError(
            f"{_opt('episode_counts')} must be a mapping, got {cfg.episode_counts!r:.60}"
        )
    counts = {}
    for key, n in cfg.episode_counts.items():
        env_part, _, mode_part = str(key).partition(":")
        ok = (
            (key in SENSOR_MODES)
            or (not mode_part and env_part in out["env_ids"] + tuple(_all_ids()))
            or (mode_part in SENSOR_MODES and env_part in _all_ids())
        )
        if not ok:
            raise ValueError(
                f"{_opt('episode_counts')}: key {key!r} is none of '<env_id>:<mode>', "
                f"'<env_id>' or '<mode>' (modes: {', '.join(SENSOR_MODES)})"
            )
        counts[str(key)] = check_int(
            n, f"{_opt('episode_counts')}[{key!r}]", low=0, what="a non-negative integer"
        )
    out["episode_counts"] = counts
    if not isinstance(cfg.env_kwargs, Mapping) or not all(
        isinstance(v, Mapping) for v in cfg.env_kwargs.values()
    ):
        raise TypeError(
            f"env_kwargs must map env ids to keyword-argument mappings, got {cfg.env_kwargs!r:.80}"
        )
    if not isinstance(cfg.policies_by_mode, Mapping):
        raise TypeError(f"policies_by_mode must be a mapping, got {cfg.policies_by_mode!r:.60}")
    by_mode = {}
    for mode, allowed in cfg.policies_by_mode.items():
        if mode not in SENSOR_MODES:
            raise ValueError(
                f"policies_by_mode: unknown sensor mode {mode!r}; expected one of "
                f"{', '.join(SENSOR_MODES)}"
            )
        by_mode[mode] = tuple(allowed)
    out["policies_by_mode"] = by_mode
    return out


def _all_ids() -> tuple[str, ...]:
    import realitygap

    return tuple(realitygap.ENV_IDS)


def n_episodes(cfg: BenchmarkConfig, env_id: str, mode: str) -> int:
    """Episodes per cell of ``env_id`` in sensor ``mode`` (see ``episode_counts``)."""
    for key in (f"{env_id}:{mode}", env_id, mode):
        if key in cfg.episode_counts:
            return int(cfg.episode_counts[key])
    return int(cfg.episodes)


def episode_seeds(cfg: BenchmarkConfig, n: int) -> list[int]:
    """The episode seeds every policy runs: ``1000 * seed + k``."""
    return [1000 * cfg.seed + k for k in range(n)]
