"""The benchmark harness: every policy on identical seeded episodes, nominal and "real".

Every policy — classical pipeline, trained PPO/SAC, uniform random — goes
through one episode loop (:func:`run_episode`) that calls SB3's
``predict(obs, state, episode_start, deterministic=True)`` and also collects
the env's ``info``. For each environment, policy, reality profile and sensor
mode the harness runs the same episode seeds, so differences in the table are
the policies', and the drop from the nominal robot to a reality profile is each
policy's own sim-to-real drop.

Reality profiles are named sets of effects (:data:`REALITY_PROFILES`), e.g.
``kobuki-worn``: right wheel 2 % larger than the left, wheelbase 4 % wider, 60 ms
command latency. A JSON file in :meth:`Reality.to_dict` format works as well.

Episode metrics (:func:`run_episode`)

======================  =====================================================
``success``             the env reported ``is_success`` (default criterion)
``reached_10cm``        the true position came within 10 cm of the goal before
                        any collision (a looser figure)
``final_pos_error_cm``  true position error at the end (cm)
``final_heading_deg``   true heading error at the end (deg)
``path_length_m``       length of the true path (m)
``time_to_goal_s``      time of the first success (s; successful episodes only)
``collision``           the robot touched an obstacle or wall (or detached, climber)
``effort``              mean squared action, ``mean(|a|²)`` (normalised units)
``jerk``                mean ``|a_t − 2a_{t−1} + a_{t−2}| / dt²`` (1/s²), normalised
``compute_ms``          mean wall time of one ``predict`` call (ms)
``error``               the exception that ended the episode, if the policy or env raised
                        one (the episode counts as failed; its other metrics are NaN)
======================  =====================================================

Aggregates per cell are mean ± standard deviation and a 95 % confidence
interval: Student-t for continuous metrics, Wilson score for rates.

Results are streamed: each finished episode is appended to ``episodes.jsonl``
(flushed and synced) as soon as it ends, so a crashed worker or an interrupted
run loses nothing that finished, and a re-run with the same output folder
resumes where it stopped. Tables (CSV, Markdown) and plots are written
atomically at the end.

Backends: ``local`` (this process, or a pool of ``workers`` processes) and
``ray`` (a local Ray cluster by default, ``address`` for a real one; installed
with ``pip install 'realitygap[ray]'``).
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from realitygap.baselines.rl import (
    check_env_id,
    env_slug,
    load_policy,
    shipped_policy,
    write_csv_atomic,
)
from realitygap.cards import ENV_CARDS, load_object
from realitygap.core import parallel
from realitygap.core.io import atomic_write, atomic_write_text

logger = logging.getLogger(__name__)

INSTALL_RAY = "pip install 'realitygap[ray]'"
POLICY_KINDS: tuple[str, ...] = ("classical", "ppo", "sac", "random")
"""Policy names the benchmark knows; ``name=path/to/model.zip`` adds a trained file."""

SENSOR_MODES: tuple[str, ...] = ("fast", "image")

REALITY_PROFILES: dict[str, dict[str, Any]] = {
    "kobuki-worn": {
        "robot": "diffdrive",
        "description": "worn Kobuki: right wheel 2 % larger, wheelbase 4 % wider, 60 ms command latency",
        "effects": [
            {"name": "wheel_diameter_ratio", "values": {"E_d": 1.02}},
            {"name": "wheelbase_error", "values": {"E_b": 1.04}},
            {"name": "command_latency", "values": {"delay": 0.06}},
        ],
    },
    "kobuki-mild": {
        "robot": "diffdrive",
        "description": "slightly worn Kobuki: right wheel 0.5 % larger, wheelbase 1 % wider, 20 ms latency",
        "effects": [
            {"name": "wheel_diameter_ratio", "values": {"E_d": 1.005}},
            {"name": "wheelbase_error", "values": {"E_b": 1.01}},
            {"name": "command_latency", "values": {"delay": 0.02}},
        ],
    },
    "arm-worn": {
        "robot": "arm",
        "extends": "env-default",
        "description": "the default cell plus unmodelled joint compliance and gear backlash",
        "effects": [
            {"name": "arm_joint_compliance", "values": {"c2": 3e-5, "c3": 3e-5}},
            {"name": "arm_backlash", "values": {"b2": 1e-3, "b3": 1e-3}},
        ],
    },
    "climber-worn": {
        "robot": "climber",
        "description": "sagging, stretched tether read by a mis-scaled spool, and a gyro bias",
        "effects": [
            {"name": "climber_tether_sag", "values": {"k": 0.002}},
            {"name": "climber_tether_stretch", "values": {"strain": 0.005}},
            {"name": "climber_spool_scale", "values": {"s": 1.01}},
            {"name": "climber_gyro_bias", "values": {"bz": 0.01}},
        ],
    },
    "kobuki-slippery": {
        "robot": "diffdrive",
        "description": "polished floor (tyre friction 0.3) and a 2 cm/s motor dead-band",
        "effects": [
            {"name": "longitudinal_slip", "values": {"mu": 0.3}},
            {"name": "motor_deadband", "values": {"threshold": 0.02}},
        ],
    },
    "kobuki-miscalibrated": {
        "robot": "diffdrive",
        "description": "wheels 3 % smaller than believed, encoders count 1 % more, camera yawed 2°",
        "effects": [
            {"name": "wheel_radius_scale", "values": {"scale": 0.97}},
            {"name": "encoder_scale", "values": {"scale": 1.01}},
            {"name": "camera_mount_offset", "values": {"dyaw": 0.035}},
        ],
    },
}
"""Named reality profiles (effects with values), by robot. A profile with
``"extends": "env-default"`` adds its effects to the env's own default reality (see
:attr:`~realitygap.cards.EnvCard.default_reality`)."""

METRICS: tuple[str, ...] = (
    "success",
    "reached_10cm",
    "final_pos_error_cm",
    "final_heading_deg",
    "path_length_m",
    "time_to_goal_s",
    "collision",
    "effort",
    "jerk",
    "compute_ms",
    "steps",
    "return",
)
RATE_METRICS = frozenset({"success", "reached_10cm", "collision"})
REACHED_RADIUS = 0.10
"""Radius (m) of the looser "reached" figure."""


# --------------------------------------------------------------------------- statistics
def t_interval(
    values: npt.ArrayLike, confidence: float = 0.95
) -> tuple[float, float, float, float]:
    r"""Mean, sample standard deviation and Student-t confidence interval of the mean.

    .. math:: \bar x \pm t_{1-\alpha/2,\,n-1}\, s / \sqrt{n}

    Returns ``(mean, std, low, high)``; NaN where undefined (no values, or ``n = 1`` for
    the spread). NaN values are ignored.
    """
    from scipy import stats

    x = np.asarray(values, dtype=float).reshape(-1)
    x = x[np.isfinite(x)]
    n = len(x)
    if n == 0:
        return (math.nan, math.nan, math.nan, math.nan)
    mean = float(np.mean(x))
    if n == 1:
        return (mean, math.nan, math.nan, math.nan)
    std = float(np.std(x, ddof=1))
    half = float(stats.t.ppf(0.5 + confidence / 2.0, n - 1)) * std / math.sqrt(n)
    return (mean, std, mean - half, mean + half)


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    r"""Wilson score interval of a rate ``successes / n``.

    .. math::

        \frac{\hat p + z^2/2n \pm z\sqrt{\hat p(1-\hat p)/n + z^2/4n^2}}{1 + z^2/n}
    """
    from scipy import stats

    if n <= 0:
        return (math.nan, math.nan)
    if not 0 <= successes <= n:
        raise ValueError(f"successes must be in [0, n={n}], got {successes}")
    z = float(stats.norm.ppf(0.5 + confidence / 2.0))
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == n else min(1.0, centre + half)
    return (low, high)


# --------------------------------------------------------------------------- realities
def reality_from_profile(name: str) -> Any:
    """The :class:`~realitygap.robots.effects.Reality` of profile ``name`` (or a JSON file).

    ``"nominal"`` is the nominal robot. A path to a JSON file is read in
    :meth:`Reality.to_dict` format.
    """
    import difflib

    from realitygap.robots.effects import Reality

    if name == "nominal":
        return Reality()
    if name in REALITY_PROFILES:
        prof = REALITY_PROFILES[name]
        return Reality.from_dict({"name": name, "effects": prof["effects"]})
    path = Path(name)
    if path.suffix == ".json" and path.is_file():
        data = json.loads(path.read_text(encoding="utf-8"))
        return Reality.from_dict({"name": data.get("name", path.stem), **data})
    close = difflib.get_close_matches(name, list(REALITY_PROFILES), n=2)
    hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
    raise ValueError(
        f"unknown reality profile {name!r}.{hint} Known: nominal, {', '.join(REALITY_PROFILES)} "
        "(or a JSON file in Reality.to_dict() format)"
    )


def reality_for(env_id: str, name: str) -> Any:
    """The ``reality`` keyword for ``env_id`` under profile ``name``; ``None`` for ``nominal``
    (the env's default), else a :class:`Reality`, extending the env's default where the
    profile says so."""
    if name == "nominal":
        return None
    reality = reality_from_profile(name)
    prof = REALITY_PROFILES.get(name, {})
    card = ENV_CARDS.get(env_id)
    default = card.default_reality if card is not None else None
    if prof.get("extends") == "env-default" and default is not None:
        from realitygap.robots.effects import Reality

        base = load_object(default)()
        reality = Reality(effects=(*base.effects, *reality.effects), name=name)
    return reality


def env_sensor_mode(env_id: str, mode: str) -> str:
    """The env's ``sensor_mode`` value for the benchmark's ``mode`` (``fast``/``image``)."""
    card = ENV_CARDS.get(env_id)
    return card.sensor_modes.get(mode, mode) if card is not None else mode


def profile_robot(name: str) -> str | None:
    """The robot a named profile is for (``None`` for ``nominal`` and JSON files)."""
    prof = REALITY_PROFILES.get(name)
    return None if prof is None else str(prof["robot"])


# --------------------------------------------------------------------------- policies
class RandomPolicy:
    """Uniform random actions from the action space, re-seeded per episode.

    Parameters
    ----------
    action_space : a ``gymnasium.spaces.Box``.
    seed : base seed; :meth:`seed` sets the generator for one episode.
    """

    def __init__(self, action_space: gym.spaces.Box, seed: int = 0):
        self.low = np.asarray(action_space.low, dtype=np.float64)
        self.high = np.asarray(action_space.high, dtype=np.float64)
        self.shape = tuple(action_space.shape)
        self.dtype = action_space.dtype
        self.rng = np.random.default_rng(seed)

    def seed(self, seed: int) -> None:
        """Restart the generator (the harness calls this with each episode's seed)."""
        self.rng = np.random.default_rng(seed)

    def predict(
        self,
        observation: npt.ArrayLike,
        state: Any = None,
        episode_start: npt.ArrayLike | None = None,
        deterministic: bool = True,
    ) -> tuple[npt.NDArray[Any], Any]:
        obs = np.asarray(observation)
        batch = obs.shape[0] if obs.ndim > 1 else None
        size = (batch, *self.shape) if batch is not None else self.shape
        return self.rng.uniform(self.low, self.high, size=size).astype(self.dtype), state


@dataclass(frozen=True)
class PolicySpec:
    """A policy of the benchmark: ``kind`` is ``classical``, ``random``, ``ppo``, ``sac`` or
    ``file``; ``paths`` maps env id → model file for learned policies."""

    name: str
    kind: str
    paths: tuple[tuple[str, str], ...] = ()

    def path_for(self, env_id: str) -> Path | None:
        for eid, path in self.paths:
            if eid == env_id or eid == "*":
                return Path(path)
        return None


def parse_policies(text: str | Sequence[str]) -> list[PolicySpec]:
    """``"classical,ppo,sac,random"`` or ``"mine=runs/ppo/model.zip"`` → policy specs."""
    items = [t.strip() for t in (text.split(",") if isinstance(text, str) else text) if t.strip()]
    if not items:
        raise ValueError("no policies given; expected e.g. classical,ppo,sac,random")
    out = []
    for item in items:
        if "=" in item:
            name, path = (s.strip() for s in item.split("=", 1))
            if not Path(path).is_file():
                raise FileNotFoundError(f"policy {name!r}: no file {path}")
            out.append(PolicySpec(name, "file", (("*", path),)))
            continue
        if item not in POLICY_KINDS:
            import difflib

            close = difflib.get_close_matches(item, POLICY_KINDS, n=1)
            hint = f" Did you mean {close[0]!r}?" if close else ""
            raise ValueError(
                f"unknown policy {item!r}.{hint} Expected some of {', '.join(POLICY_KINDS)} "
                "or name=path/to/model.zip"
            )
        out.append(PolicySpec(item, item))
    names = [p.name for p in out]
    if len(set(names)) != len(names):
        raise ValueError(f"policy names must be unique, got {names}")
    return out


def build_policy(spec: PolicySpec, env: gym.Env[Any, Any], env_id: str, seed: int = 0) -> Any:
    """The policy object of ``spec`` for ``env`` (a ``predict``-able object)."""
    if spec.kind == "classical":
        if env_id not in ENV_CARDS:
            raise ValueError(f"no classical baseline registered for {env_id}")
        return load_object(ENV_CARDS[env_id].classical_policy)(env)
    if spec.kind == "random":
        if not isinstance(env.action_space, gym.spaces.Box):
            raise ValueError(
                f"the random baseline needs a Box action space, {env_id} has "
                f"{type(env.action_space).__name__}"
            )
        return RandomPolicy(env.action_space, seed)
    path = spec.path_for(env_id)
    if path is None:
        path = shipped_policy(env_id, spec.kind)
    return load_policy(path, env, env_id=env_id)


def resolve_learned_paths(
    specs: Sequence[PolicySpec], env_ids: Sequence[str], notes: list[str] | None = None
) -> list[PolicySpec]:
    """Fill in the shipped model files of ``ppo``/``sac`` specs, before any episode runs.

    A missing stable-baselines3 raises an ``ImportError`` with the install hint. An env
    without a shipped file for a policy is left out for that policy, with a line appended
    to ``notes`` (a ``FileNotFoundError`` when no env has one and ``notes`` is ``None``).
    """
    from realitygap.baselines.rl import read_policy_meta, require_sb3

    out = []
    for spec in specs:
        if spec.kind in ("classical", "random"):
            out.append(spec)
            continue
        require_sb3()
        paths = dict(spec.paths)
        missing = []
        for env_id in env_ids:
            if env_id in paths or "*" in paths:
                continue
            try:
                paths[env_id] = str(shipped_policy(env_id, spec.kind))
            except FileNotFoundError as exc:
                missing.append(str(exc))
        if not paths and notes is None:
            raise FileNotFoundError("; ".join(missing))
        if notes is not None:
            notes.extend(f"{spec.name} left out: {m}" for m in missing)
        for path in paths.values():
            read_policy_meta(path)  # readable, without unpickling
        if paths:
            out.append(PolicySpec(spec.name, spec.kind, tuple(sorted(paths.items()))))
    return out


# --------------------------------------------------------------------------- the episode loop
def run_episode(
    env: gym.Env[Any, Any],
    policy: Any,
    seed: int,
    deterministic: bool = True,
    pose_shape: tuple[int, ...] | None = None,
) -> dict[str, Any]:
    """Run one seeded episode of ``policy`` through SB3's ``predict``; return its metrics.

    The policy is told the episode start (``episode_start``), and re-seeded with
    ``seed`` when it has a ``seed`` method (random policy), so an episode depends on
    ``seed`` only. The path length follows ``info["true_pose"]``, whose shape
    ``pose_shape`` is (default: the env card's ``info`` schema, see
    :class:`~realitygap.cards.EnvCard`): ``(3,)`` planar ``[x, y, θ]``, ``(7,)`` position
    and quaternion, ``(4, 4)`` a homogeneous transform. Without a known shape the path
    length is NaN.
    """
    if pose_shape is None:
        pose_shape = _pose_shape(env)
    if hasattr(policy, "seed") and callable(policy.seed):
        policy.seed(seed)
    obs, info = env.reset(seed=seed)
    dt = float(getattr(env.unwrapped, "dt", 1.0))
    state: Any = None
    start = True
    done = False
    steps = 0
    total_reward = 0.0
    compute = 0.0
    actions: list[npt.NDArray[np.float64]] = []
    path = 0.0
    prev_xy = _xy(info, pose_shape)
    best_before_collision = _float(info.get("pos_error"))
    collided = False
    success = False
    t_success = math.nan
    while not done:
        t0 = time.perf_counter()
        action, state = policy.predict(
            obs, state=state, episode_start=np.array([start]), deterministic=deterministic
        )
        compute += time.perf_counter() - t0
        start = False
        obs, reward, terminated, truncated, info = env.step(action)
        steps += 1
        done = bool(terminated or truncated)
        total_reward += float(reward)
        actions.append(np.asarray(action, dtype=np.float64).reshape(-1))
        xy = _xy(info, pose_shape)
        if xy is not None and prev_xy is not None:
            path += float(np.linalg.norm(xy - prev_xy))
        prev_xy = xy
        collided |= bool(info.get("collision", False) or info.get("detached", False))
        if not collided:
            best_before_collision = min(best_before_collision, _float(info.get("pos_error")))
        if info.get("is_success", False) and not success:
            success = True
            t_success = steps * dt
    a = np.asarray(actions) if actions else np.zeros((0, 1))
    effort = float(np.mean(np.sum(a * a, axis=1))) if len(a) else math.nan
    jerk = (
        float(np.mean(np.linalg.norm(np.diff(a, n=2, axis=0), axis=1))) / dt**2
        if len(a) > 2
        else math.nan
    )
    return {
        "seed": int(seed),
        "success": bool(success),
        "reached_10cm": (
            bool(best_before_collision <= REACHED_RADIUS)
            if math.isfinite(best_before_collision)
            else None
        ),
        "final_pos_error_cm": 100.0 * _float(info.get("pos_error")),
        "final_heading_deg": math.degrees(_float(info.get("heading_error"))),
        "path_length_m": path if prev_xy is not None else math.nan,
        "time_to_goal_s": t_success,
        "collision": bool(collided),
        "effort": effort,
        "jerk": jerk,
        "compute_ms": 1000.0 * compute / max(steps, 1),
        "steps": steps,
        "return": total_reward,
        "truncated": bool(not success and not collided),
        "final_info": {
            k: float(v)
            for k, v in info.items()
            if isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool)
        },
    }


def _pose_shape(env: gym.Env[Any, Any]) -> tuple[int, ...] | None:
    """Shape of ``info["true_pose"]`` declared by the env's card (``None`` without one)."""
    spec = getattr(env, "spec", None)
    card = ENV_CARDS.get(spec.id) if spec is not None else None
    if card is None or "true_pose" not in card.info:
        return None
    return card.info["true_pose"].shape


def _xy(
    info: Mapping[str, Any], pose_shape: tuple[int, ...] | None
) -> npt.NDArray[np.float64] | None:
    """Position from ``info["true_pose"]`` of the declared shape: ``[x, y, θ]`` → ``(x, y)``;
    ``[x, y, z, quaternion]`` → ``(x, y, z)``; a 4×4 transform → its translation."""
    pose = info.get("true_pose")
    if pose is None or pose_shape is None:
        return None
    arr = np.asarray(pose, dtype=float).reshape(pose_shape)
    if pose_shape == (3,):
        return arr[:2].copy()
    if pose_shape == (7,):
        return arr[:3].copy()
    if pose_shape == (4, 4):
        return arr[:3, 3].copy()
    return None


def _extra_metrics(env_id: str) -> tuple[str, ...]:
    """The env's own metrics (:attr:`~realitygap.cards.EnvCard.metrics`); none for an unknown id."""
    card = ENV_CARDS.get(env_id)
    return card.metrics if card is not None else ()


def _float(value: Any) -> float:
    return math.nan if value is None else float(value)


# --------------------------------------------------------------------------- tasks
@dataclass(frozen=True)
class BenchmarkConfig:
    """Settings of one benchmark run.

    Parameters
    ----------
    env_ids : environments (default: every registered one).
    policies : policy specs (see :func:`parse_policies`).
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


@dataclass(frozen=True)
class ChunkTask:
    """Episodes of one cell for one worker (picklable)."""

    env_id: str
    env_kwargs: tuple[tuple[str, Any], ...]
    reality: str
    sensor_mode: str
    policy: PolicySpec
    seeds: tuple[int, ...]

    @property
    def cell(self) -> tuple[str, str, str, str]:
        return (self.env_id, self.policy.name, self.reality, self.sensor_mode)


def n_episodes(cfg: BenchmarkConfig, env_id: str, mode: str) -> int:
    """Episodes per cell of ``env_id`` in sensor ``mode`` (see ``episode_counts``)."""
    for key in (f"{env_id}:{mode}", env_id, mode):
        if key in cfg.episode_counts:
            return int(cfg.episode_counts[key])
    return int(cfg.episodes)


def episode_seeds(cfg: BenchmarkConfig, n: int) -> list[int]:
    """The episode seeds every policy runs: ``1000 * seed + k``."""
    return [1000 * cfg.seed + k for k in range(n)]


def plan_tasks(
    cfg: BenchmarkConfig, done: set[tuple[str, str, str, str, int]] | None = None
) -> list[ChunkTask]:
    """Split the run into worker tasks, leaving out episodes already in ``done``."""
    done = done or set()
    tasks = []
    for env_id in cfg.env_ids:
        robot = ENV_CARDS[env_id].robot if env_id in ENV_CARDS else None
        kwargs = tuple(sorted(dict(cfg.env_kwargs.get(env_id, {})).items()))
        realities = ["nominal"] + [
            r for r in cfg.realities if r != "nominal" and profile_robot(r) in (None, robot)
        ]
        for mode in cfg.sensor_modes:
            n = n_episodes(cfg, env_id, mode)
            allowed = cfg.policies_by_mode.get(mode)
            for reality in realities:
                for pol in cfg.policies:
                    if allowed is not None and pol.name not in allowed:
                        continue
                    if pol.kind == "classical" and env_id not in ENV_CARDS:
                        continue
                    if pol.kind in ("ppo", "sac") and pol.path_for(env_id) is None:
                        continue  # no trained policy for this env (reported by the caller)
                    seeds = [
                        s
                        for s in episode_seeds(cfg, n)
                        if (env_id, pol.name, reality, mode, s) not in done
                    ]
                    for i in range(0, len(seeds), max(1, cfg.chunk)):
                        tasks.append(
                            ChunkTask(
                                env_id, kwargs, reality, mode, pol, tuple(seeds[i : i + cfg.chunk])
                            )
                        )
    return tasks


def _error_record(seed: int, exc: BaseException) -> dict[str, Any]:
    """The record of an episode that ended in an exception: failed, metrics unknown."""
    rec: dict[str, Any] = {m: math.nan for m in METRICS}
    rec.update(
        seed=int(seed),
        success=False,
        reached_10cm=None,
        collision=None,
        truncated=False,
        final_info={},
        error=f"{type(exc).__name__}: {exc}".strip(),
    )
    return rec


def run_chunk(task: ChunkTask) -> list[dict[str, Any]]:
    """Run one task's episodes (in any process); returns one record per episode."""
    return list(iter_chunk(task))


def iter_chunk(task: ChunkTask) -> Iterator[dict[str, Any]]:
    """Run one task's episodes, yielding each record as soon as its episode ends."""
    import realitygap  # noqa: F401  (registers the ids in a fresh worker)

    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:
        pass
    kwargs = dict(task.env_kwargs)
    reality = reality_for(task.env_id, task.reality)
    if reality is not None:
        kwargs["reality"] = reality
    env = gym.make(
        task.env_id, sensor_mode=env_sensor_mode(task.env_id, task.sensor_mode), **kwargs
    )
    extra = _extra_metrics(task.env_id)
    try:
        policy = build_policy(
            task.policy, env, task.env_id, seed=task.seeds[0] if task.seeds else 0
        )
        for seed in task.seeds:
            t0 = time.perf_counter()
            try:
                record = run_episode(env, policy, seed)
            except Exception as exc:  # a crashing policy fails its episode, not the run
                record = _error_record(seed, exc)
                policy = build_policy(task.policy, env, task.env_id, seed=seed)
            record["wall_s"] = time.perf_counter() - t0
            final = record.pop("final_info")
            for key in extra:
                record[key] = final.get(key, math.nan)
            yield {
                "env_id": task.env_id,
                "policy": task.policy.name,
                "reality": task.reality,
                "sensor_mode": task.sensor_mode,
                **record,
            }
    finally:
        env.close()


# --------------------------------------------------------------------------- backends
RAY_MISSING = (
    f"--backend ray needs Ray, which is not installed: {INSTALL_RAY} (or use --backend local)"
)


def require_ray() -> Any:
    """Import Ray, or raise an ``ImportError`` with the install command."""
    return parallel.require_ray(RAY_MISSING)


class ResultStore:
    """Append-only JSON-lines store of finished episodes (flushed and fsynced per record)."""

    def __init__(self, path: str | os.PathLike[str]):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)

    def load(self) -> list[dict[str, Any]]:
        """Every complete record; a torn last line (crash while writing) is ignored."""
        if not self.path.is_file():
            return []
        out = []
        for line in self.path.read_text(encoding="utf-8").splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue
        return out

    def append(self, records: Iterable[Mapping[str, Any]]) -> None:
        with self.path.open("a", encoding="utf-8") as fh:
            for rec in records:
                fh.write(json.dumps(_clean(rec), allow_nan=True) + "\n")
            fh.flush()
            os.fsync(fh.fileno())


def _clean(rec: Mapping[str, Any]) -> dict[str, Any]:
    out = {}
    for k, v in rec.items():
        if isinstance(v, (np.floating, np.integer, np.bool_)):
            v = v.item()
        out[k] = v
    return out


def record_key(rec: Mapping[str, Any]) -> tuple[str, str, str, str, int]:
    return (rec["env_id"], rec["policy"], rec["reality"], rec["sensor_mode"], int(rec["seed"]))


class Progress:
    """Progress lines (episodes done, rate, ETA) through :mod:`logging` at ``INFO``."""

    def __init__(self, total: int, every_s: float = 10.0, enabled: bool = True):
        self.total, self.done = total, 0
        self.every_s, self.enabled = every_s, enabled
        self.t0 = self.last = time.perf_counter()

    def update(self, n: int, label: str = "", force: bool = False) -> None:
        self.done += n
        now = time.perf_counter()
        if not self.enabled or (
            not force and now - self.last < self.every_s and self.done < self.total
        ):
            return
        self.last = now
        rate = self.done / max(now - self.t0, 1e-9)
        eta = (self.total - self.done) / max(rate, 1e-9)
        pct = 100.0 * self.done / max(self.total, 1)
        logger.info(
            f"[{time.strftime('%H:%M:%S')}] benchmark {self.done}/{self.total} episodes ({pct:.0f} %), "
            f"ETA {eta / 60:.1f} min {label}"
        )


def execute(
    tasks: Sequence[ChunkTask],
    store: ResultStore,
    backend: str = "local",
    workers: int = 1,
    address: str | None = None,
    progress: Progress | None = None,
) -> list[str]:
    """Run ``tasks``, streaming each finished episode to ``store``. Returns error messages of
    tasks that failed (their finished episodes are kept)."""
    progress = progress or Progress(sum(len(t.seeds) for t in tasks), enabled=False)
    runner: parallel.Backend
    if backend == "local":
        if workers <= 1:
            return _execute_inline(tasks, store, progress)
        runner = parallel.ProcessBackend(workers, start_method="forkserver")
    elif backend == "ray":
        runner = parallel.RayBackend(address, missing=RAY_MISSING)
    else:
        raise ValueError(f"backend must be 'local' or 'ray', got {backend!r}")
    return _execute_streaming(runner, tasks, store, progress)


def _label(task: ChunkTask) -> str:
    return f"{env_slug(task.env_id)} {task.policy.name} {task.reality} {task.sensor_mode}"


def _execute_inline(
    tasks: Sequence[ChunkTask], store: ResultStore, progress: Progress
) -> list[str]:
    errors = []
    for task in tasks:
        try:
            for rec in iter_chunk(task):
                store.append([rec])
                progress.update(1, _label(task))
        except (ImportError, FileNotFoundError, ValueError):
            raise
        except Exception as exc:  # a failing episode must not lose the rest of the run
            errors.append(f"{_label(task)} seeds {task.seeds}: {type(exc).__name__}: {exc}")
    return errors


def _execute_streaming(
    runner: parallel.Backend, tasks: Sequence[ChunkTask], store: ResultStore, progress: Progress
) -> list[str]:
    """Run whole tasks on ``runner``; store each task's episodes as soon as it finishes."""
    from concurrent.futures.process import BrokenProcessPool

    errors: list[str] = []
    for outcome in runner.imap_unordered(run_chunk, tasks):
        task, exc = outcome.item, outcome.error
        if isinstance(exc, BrokenProcessPool):
            errors.append(f"{_label(task)} seeds {task.seeds}: worker crashed ({exc})")
        elif exc is not None:
            errors.append(f"{_label(task)} seeds {task.seeds}: {type(exc).__name__}: {exc}")
        else:
            records = outcome.value or []
            store.append(records)
            progress.update(len(records), _label(task))
    return errors


# --------------------------------------------------------------------------- aggregation
def summarise(
    records: Sequence[Mapping[str, Any]], confidence: float = 0.95
) -> list[dict[str, Any]]:
    """One row per (env, policy, reality, sensor mode): mean, std and CI of every metric."""
    groups: dict[tuple[str, str, str, str], list[Mapping[str, Any]]] = {}
    for rec in records:
        groups.setdefault(record_key(rec)[:4], []).append(rec)
    rows = []
    for (env_id, policy, reality, mode), recs in groups.items():
        recs = sorted(recs, key=lambda r: int(r["seed"]))
        row: dict[str, Any] = {
            "env": env_slug(env_id),
            "env_id": env_id,
            "policy": policy,
            "reality": reality,
            "sensor_mode": mode,
            "n": len(recs),
            "errors": sum(1 for r in recs if r.get("error")),
        }
        extra = _extra_metrics(env_id)
        for m in (*METRICS, *extra):
            if m == "time_to_goal_s":
                vals = [float(r[m]) for r in recs if r.get("success")]
            else:
                vals = [float(r[m]) if r.get(m) is not None else math.nan for r in recs]
            mean, std, lo, hi = t_interval(vals, confidence)
            if m in RATE_METRICS:
                finite = [v for v in vals if math.isfinite(v)]
                k = int(sum(1 for v in finite if v > 0.5))
                lo, hi = wilson_interval(k, len(finite), confidence)
            row[f"{m}_mean"], row[f"{m}_std"] = mean, std
            row[f"{m}_ci_low"], row[f"{m}_ci_high"] = lo, hi
        rows.append(row)
    order = {p: i for i, p in enumerate(POLICY_KINDS)}
    rows.sort(
        key=lambda r: (
            r["env"],
            r["sensor_mode"] != "fast",
            order.get(r["policy"], 99),
            r["policy"],
            r["reality"] != "nominal",
            r["reality"],
        )
    )
    return rows


def transfer_rows(summary: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Success under each reality profile next to nominal, per env, policy and sensor mode."""
    nominal = {
        (r["env"], r["policy"], r["sensor_mode"]): r for r in summary if r["reality"] == "nominal"
    }
    out = []
    for r in summary:
        if r["reality"] == "nominal":
            continue
        base = nominal.get((r["env"], r["policy"], r["sensor_mode"]))
        if base is None:
            continue
        out.append(
            {
                "env": r["env"],
                "policy": r["policy"],
                "sensor_mode": r["sensor_mode"],
                "reality": r["reality"],
                "n": r["n"],
                "success_nominal": base["success_mean"],
                "success_reality": r["success_mean"],
                "success_drop_pp": 100.0 * (base["success_mean"] - r["success_mean"]),
                "reached_10cm_nominal": base["reached_10cm_mean"],
                "reached_10cm_reality": r["reached_10cm_mean"],
                "final_pos_error_cm_nominal": base["final_pos_error_cm_mean"],
                "final_pos_error_cm_reality": r["final_pos_error_cm_mean"],
            }
        )
    return out


def _fmt(x: Any, digits: int = 2) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return f"{x:.{digits}f}"


def _rate_cell(row: Mapping[str, Any], m: str) -> str:
    return f"{_fmt(row[f'{m}_mean'])} [{_fmt(row[f'{m}_ci_low'])}, {_fmt(row[f'{m}_ci_high'])}]"


def _pm(row: Mapping[str, Any], m: str, digits: int = 1) -> str:
    return f"{_fmt(row[f'{m}_mean'], digits)} ± {_fmt(row[f'{m}_std'], digits)}"


def markdown_report(
    summary: Sequence[Mapping[str, Any]],
    transfer: Sequence[Mapping[str, Any]],
    notes: Sequence[str] = (),
) -> str:
    """The benchmark tables in Markdown."""
    lines = [
        "# Benchmark",
        "",
        "Success: the env's default criterion (WheeledNav: within 3 cm and 5° of the goal pose, at "
        "rest). Reached: the true position came within 10 cm before any collision. Rates: mean "
        "[95 % Wilson CI]; other metrics: mean ± std over episodes (time to goal over successes).",
        "",
        "| env | mode | policy | reality | n | success | reached ≤10 cm | collision | final pos err (cm) | "
        "heading err (°) | path (m) | time to goal (s) | effort | jerk (1/s²) | compute (ms) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in summary:
        lines.append(
            f"| {r['env']} | {r['sensor_mode']} | {r['policy']} | {r['reality']} | {r['n']} | "
            f"{_rate_cell(r, 'success')} | {_rate_cell(r, 'reached_10cm')} | "
            f"{_rate_cell(r, 'collision')} | {_pm(r, 'final_pos_error_cm')} | "
            f"{_pm(r, 'final_heading_deg')} | {_pm(r, 'path_length_m', 2)} | "
            f"{_pm(r, 'time_to_goal_s')} | {_pm(r, 'effort', 3)} | {_pm(r, 'jerk', 0)} | "
            f"{_pm(r, 'compute_ms', 3)} |"
        )
    if transfer:
        lines += [
            "",
            "## Sim-to-real transfer (success, nominal → reality profile)",
            "",
            "| env | mode | policy | reality | n | success nominal | success reality | drop (pp) | "
            "reached nominal | reached reality | final err nominal (cm) | final err reality (cm) |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for t in transfer:
            lines.append(
                f"| {t['env']} | {t['sensor_mode']} | {t['policy']} | {t['reality']} | {t['n']} | "
                f"{_fmt(t['success_nominal'])} | {_fmt(t['success_reality'])} | "
                f"{_fmt(t['success_drop_pp'], 0)} | {_fmt(t['reached_10cm_nominal'])} | "
                f"{_fmt(t['reached_10cm_reality'])} | {_fmt(t['final_pos_error_cm_nominal'], 1)} | "
                f"{_fmt(t['final_pos_error_cm_reality'], 1)} |"
            )
    extra_rows = [
        (r, _extra_metrics(r["env_id"])) for r in summary if _extra_metrics(r.get("env_id", ""))
    ]
    if extra_rows:
        lines += ["", "## Env-specific metrics (final info, mean ± std)", ""]
        lines += ["| env | mode | policy | reality | n | metrics |", "|---|---|---|---|---|---|"]
        for r, keys in extra_rows:
            cells = ", ".join(f"{k} {_pm(r, k, 3)}" for k in keys)
            lines.append(
                f"| {r['env']} | {r['sensor_mode']} | {r['policy']} | {r['reality']} | {r['n']} "
                f"| {cells} |"
            )
    if notes:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in notes]
    return "\n".join(lines) + "\n"


def plot_success(summary: Sequence[Mapping[str, Any]], out: str | os.PathLike[str]) -> Path | None:
    """Bar charts of strict success and reached-within-10-cm per policy, nominal vs reality,
    with 95 % CI whiskers; ``None`` when matplotlib is missing."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None

    panels = sorted(
        {(r["env"], r["sensor_mode"]) for r in summary}, key=lambda k: (k[0], k[1] != "fast")
    )
    if not panels:
        return None
    fig, axes = plt.subplots(len(panels), 2, figsize=(11, 3.2 * len(panels)), squeeze=False)
    for row_i, (env, mode) in enumerate(panels):
        rows = [r for r in summary if r["env"] == env and r["sensor_mode"] == mode]
        policies = list(dict.fromkeys(r["policy"] for r in rows))
        realities = list(dict.fromkeys(r["reality"] for r in rows))
        width = 0.8 / max(len(realities), 1)
        for col, metric in enumerate(("success", "reached_10cm")):
            ax = axes[row_i][col]
            for j, reality in enumerate(realities):
                vals, lo, hi = [], [], []
                for p in policies:
                    match = [r for r in rows if r["policy"] == p and r["reality"] == reality]
                    r = match[0] if match else None
                    v = r[f"{metric}_mean"] if r else math.nan
                    vals.append(v)
                    lo.append(v - r[f"{metric}_ci_low"] if r else 0.0)
                    hi.append(r[f"{metric}_ci_high"] - v if r else 0.0)
                x = np.arange(len(policies)) + (j - (len(realities) - 1) / 2) * width
                ax.bar(x, vals, width, yerr=[lo, hi], capsize=3, label=reality)
            ax.set_xticks(np.arange(len(policies)), policies)
            ax.set_ylim(0, 1.05)
            title = "strict success" if metric == "success" else "reached ≤ 10 cm"
            ax.set_title(f"{env} ({mode} sensors): {title}", fontsize=9)
            ax.legend(fontsize=7)
    fig.tight_layout()
    try:
        return atomic_write(out, lambda fh: fig.savefig(fh, dpi=110, format="png"))
    finally:
        plt.close(fig)


# --------------------------------------------------------------------------- the whole run
@dataclass(frozen=True)
class BenchmarkResult:
    """Paths and tables of a finished benchmark."""

    out_dir: Path
    summary: list[dict[str, Any]]
    transfer: list[dict[str, Any]]
    errors: list[str]
    files: dict[str, Path]
    wall_seconds: float


def run_benchmark(
    cfg: BenchmarkConfig,
    out_dir: str | os.PathLike[str],
    backend: str = "local",
    workers: int = 1,
    address: str | None = None,
    resume: bool = True,
    verbose: bool = True,
    learning_curves: Sequence[tuple[str, Path | None, Path | None]] = (),
    notes: Sequence[str] = (),
) -> BenchmarkResult:
    """Run the benchmark described by ``cfg`` and write its tables and plots to ``out_dir``.

    Files: ``episodes.jsonl`` (streamed), ``summary.csv``, ``transfer.csv``,
    ``benchmark.md``, ``success.png``, ``learning_curves.png`` (when curves are
    given), ``config.json``.
    """
    t0 = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if backend == "ray":
        require_ray()  # fail before any work with the install hint
    elif backend != "local":
        raise ValueError(f"backend must be 'local' or 'ray', got {backend!r}")
    for env_id in cfg.env_ids:
        check_env_id(env_id)
    for mode in cfg.sensor_modes:
        if mode not in SENSOR_MODES:
            raise ValueError(f"sensor mode must be one of {SENSOR_MODES}, got {mode!r}")
    for r in cfg.realities:
        reality_from_profile(r)
    store = ResultStore(out / "episodes.jsonl")
    if not resume and store.path.exists():
        store.path.unlink()
    config_json = {
        **{k: v for k, v in asdict(cfg).items() if k != "policies"},
        "policies": [asdict(p) for p in cfg.policies],
        "episode_seeds": "1000 * seed + k",
        "backend": backend,
    }
    atomic_write_text(out / "config.json", json.dumps(config_json, indent=2, default=str) + "\n")
    done = {record_key(r) for r in store.load()}
    tasks = plan_tasks(cfg, done)
    n_total = sum(len(t.seeds) for t in tasks)
    progress = Progress(n_total, enabled=verbose)
    if verbose:
        logger.info(
            f"[{time.strftime('%H:%M:%S')}] benchmark: {n_total} episodes in {len(tasks)} tasks "
            f"({len(done)} already done) on backend {backend} -> {out}"
        )
    errors = execute(tasks, store, backend, workers, address, progress)
    wanted = {(t.cell) for t in plan_tasks(cfg)}
    records = [r for r in store.load() if record_key(r)[:4] in wanted]
    summary = summarise(records)
    transfer = transfer_rows(summary)
    files = {
        "episodes": store.path,
        "summary_csv": out / "summary.csv",
        "transfer_csv": out / "transfer.csv",
        "markdown": out / "benchmark.md",
    }
    write_csv_atomic(files["summary_csv"], summary)
    write_csv_atomic(files["transfer_csv"], transfer)
    all_notes = list(notes) + [f"failed task: {e}" for e in errors]
    crashed: dict[tuple[str, ...], list[Mapping[str, Any]]] = {}
    for rec in records:
        if rec.get("error"):
            crashed.setdefault(record_key(rec)[:4], []).append(rec)
    for (env_id, pol, reality, mode), recs in sorted(crashed.items()):
        seeds = ", ".join(str(x["seed"]) for x in recs)
        all_notes.append(
            f"{env_slug(env_id)} {pol} {reality} {mode}: {len(recs)} episode(s) ended in an "
            f"exception, counted as failures (seeds {seeds}; first: {recs[0]['error']})"
        )
    for name in cfg.realities:
        if name in REALITY_PROFILES:
            all_notes.append(f"reality `{name}`: {REALITY_PROFILES[name]['description']}")
    atomic_write_text(files["markdown"], markdown_report(summary, transfer, all_notes))
    png = plot_success(summary, out / "success.png")
    if png is not None:
        files["success_png"] = png
    if learning_curves:
        from realitygap.baselines.rl import plot_learning_curves

        lc = plot_learning_curves(learning_curves, out / "learning_curves.png")
        if lc is not None:
            files["learning_curves_png"] = lc
    return BenchmarkResult(out, summary, transfer, errors, files, time.perf_counter() - t0)
