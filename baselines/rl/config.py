"""Training settings: algorithms, hyperparameter files, the curriculum, run configuration.

Hyperparameters live in files, one per algorithm, keyed by environment id as in
rl-baselines3-zoo (``baselines/hyperparams/ppo.json``, ``sac.json``)::

    {"realitygap/WheeledNav-v0": {"n_timesteps": 1500000, "n_envs": 8, "vec_env": "subproc",
                                  "env_kwargs": {...}, "policy": "MlpPolicy", ...}}

An env without an entry has no learned baseline yet; :func:`load_hyperparams` says so.
Keys that are not arguments of the algorithm are read by :func:`~realitygap.baselines.rl.training.train`:

=============================  ==============================================================
key                            meaning
=============================  ==============================================================
``n_timesteps``                training budget (env steps over all workers); the curriculum
                               and ``log_std_max`` schedules refer to it
``n_envs``                     parallel envs of the vectorised env
``vec_env``                    ``"subproc"`` (one process per env) or ``"dummy"`` (in-process)
``env_kwargs``                 ``gym.make`` keyword arguments (fast sensor mode); also used
                               by the evaluations
``policy``                     SB3 policy name (``"MlpPolicy"``)
``curriculum``                 optional curriculum on env / wrapper attributes
                               (:class:`Curriculum`)
``normalize``                  optional ``{"obs": bool, "reward": bool}`` running
                               normalisation; the observation statistics are saved as JSON
``obs_features``               optional feature map (:data:`OBS_FEATURES`) appended to the
                               observation — part of the policy (:class:`PolicyIO`)
``action_deadband``            optional dead band width on each action component — part of
                               the policy (:func:`deadband`)
``action_stop_gate``           optional extra network output that stops the robot — part of
                               the policy (:func:`stop_gate`)
``train_wrappers``             optional training-only wrappers ``[{"name": ..., **params}]``
                               (:data:`TRAIN_WRAPPERS`)
``train_max_episode_steps``    optional shorter time limit of training episodes
``log_std_max``                optional ``[start, end]`` upper bound of a Gaussian policy's
                               log standard deviation, linear over ``n_timesteps`` (PPO)
``obs_memory``                 optional obstacle memory (``{"n_sectors", "horizon", "cell"}``,
                               :mod:`realitygap.baselines.episode_features`) — part of the policy
``obs_rest_timer``             optional column for how long the robot has stood still
                               (``{"horizon_steps"}``, same module) — part of the policy
``obs_scene_fade``             optional radius (m) within which WheeledNav's scan and obstacle
                               memory fade to "nothing seen" as the goal nears
                               (:func:`scene_fade`) — part of the policy
``demonstrations``             optional DAgger warm start from an expert before PPO
                               (:class:`~realitygap.baselines.imitation.DemoSettings`)
=============================  ==============================================================

Whatever the training used, evaluations and the benchmark score the policy on the
env as registered, with its default success criterion.
"""

from __future__ import annotations

import difflib
import math
import numbers
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from realitygap.core.checks import load_json_or_yaml

ALGOS: tuple[str, ...] = ("ppo", "sac")
"""Learning algorithms with hyperparameter files."""

HYPERPARAMS_DIR = Path(__file__).resolve().parent.parent / "hyperparams"
"""Folder of the per-algorithm hyperparameter files."""

POLICIES_DIR = Path(__file__).resolve().parent.parent / "policies"
"""Folder of the policies this package ships (trained by :func:`train`)."""

EVAL_SEED_OFFSET = 50_000
"""Evaluation during training uses seeds from here on, apart from the benchmark's."""

TRAIN_KEYS = frozenset(
    {
        "n_timesteps",
        "n_envs",
        "vec_env",
        "env_kwargs",
        "policy",
        "curriculum",
        "normalize",
        "action_deadband",
        "train_max_episode_steps",
        "obs_features",
        "action_stop_gate",
        "log_std_max",
        "train_wrappers",
        "obs_memory",
        "obs_rest_timer",
        "obs_scene_fade",
        "demonstrations",
        "vector_env_kwargs",
    }
)
_INSTALL_RL = "pip install 'realitygap[rl]'  (stable-baselines3 and torch)"


# --------------------------------------------------------------------------- optional deps
def require_sb3() -> Any:
    """Import stable-baselines3, or raise an ``ImportError`` saying what to install."""
    try:
        import stable_baselines3
    except ImportError as exc:
        raise ImportError(
            f"learned baselines need stable-baselines3, which is not installed: {_INSTALL_RL}"
        ) from exc
    return stable_baselines3


def algo_class(algo: str) -> Any:
    """The SB3 class of ``algo`` (``"ppo"`` or ``"sac"``)."""
    algo = check_algo(algo)
    sb3 = require_sb3()
    return {"ppo": sb3.PPO, "sac": sb3.SAC}[algo]


def check_algo(algo: str) -> str:
    """``algo`` in lower case, or a ``ValueError`` naming the known algorithms."""
    name = str(algo).lower()
    if name not in ALGOS:
        raise ValueError(f"unknown algorithm {algo!r}; expected one of {', '.join(ALGOS)}")
    return name


def check_env_id(env_id: str) -> str:
    """``env_id`` if registered by this package, else a ``ValueError`` suggesting close ids."""
    import difflib

    import realitygap

    if env_id in realitygap.ENV_IDS:
        return env_id
    if f"realitygap/{env_id}" in realitygap.ENV_IDS:
        return f"realitygap/{env_id}"
    close = difflib.get_close_matches(env_id, realitygap.ENV_IDS, n=2)
    hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
    raise ValueError(
        f"unknown environment {env_id!r}.{hint} Known: {', '.join(realitygap.ENV_IDS)}"
    )


def env_slug(env_id: str) -> str:
    """A file-name-safe short name of an env id: ``realitygap/WheeledNav-v0`` → ``WheeledNav-v0``."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", env_id.split("/")[-1])


# --------------------------------------------------------------------------- hyperparameters
def load_hyperparams(
    algo: str, env_id: str, path: str | os.PathLike[str] | None = None
) -> dict[str, Any]:
    """The hyperparameters of ``algo`` on ``env_id`` from its file (``hyperparams/<algo>.json``,
    or ``path``: ``--hyperparams``), read with
    :func:`~realitygap.core.checks.load_json_or_yaml` and type-checked
    (:func:`check_hyperparams_table`).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError, TypeError
        If it is no JSON/YAML mapping of env id → hyperparameters of the right types; the
        message names the option, the file and (a syntax error) the line.
    KeyError
        If the file has no entry for ``env_id``.
    """

    algo = check_algo(algo)
    file = Path(path) if path is not None else HYPERPARAMS_DIR / f"{algo}.json"
    option = "--hyperparams" if path is not None else "hyperparameter file"
    table = load_hyperparams_file(file, option, algo=algo)
    if env_id not in table:
        raise KeyError(
            f"{option} {file.name} has no hyperparameters for {env_id!r}; it has: "
            f"{', '.join(sorted(table)) or 'none'}. Add an entry "
            "(rl-zoo style) to train this env."
        )
    return dict(table[env_id])


# --------------------------------------------------------------------------- curriculum
@dataclass(frozen=True)
class Curriculum:
    """Success-gated curriculum on env attributes, e.g. the success tolerances.

    Each attribute starts at ``start[name]``; on each promotion every attribute
    moves one of ``n_stages`` steps (geometrically) towards ``end[name]``; after
    ``n_stages`` promotions it sits at ``end``. A promotion happens when the gate
    passes — ``gate="train"``: the success rate of the last ``window`` training
    episodes reaches ``promote_at``; ``gate="eval"``: at an evaluation, the
    deterministic policy succeeds on ``promote_at`` of its episodes under the
    current stage's values (a stochastic policy can rarely be "at rest") — or when
    a stage has lasted ``max_stage_steps`` env steps (0: no limit). At ``final_fraction`` of
    the training budget the attributes are set to ``end`` whatever the success
    rate, so the last part of training always sees the target task. Attributes whose
    ``start`` and ``end`` are both integers (e.g. ``n_obstacles``) step linearly and are
    rounded.
    """

    start: Mapping[str, float]
    end: Mapping[str, float]
    n_stages: int = 6
    window: int = 100
    promote_at: float = 0.6
    final_fraction: float = 0.8
    gate: str = "train"
    max_stage_steps: int = 0
    integer: frozenset[str] = frozenset()

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Curriculum:
        """Build from a hyperparameter entry ``{"start": {...}, "end": {...}, ...}``."""
        known = {
            "start",
            "end",
            "n_stages",
            "window",
            "promote_at",
            "final_fraction",
            "gate",
            "max_stage_steps",
        }
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown curriculum key(s) {sorted(unknown)}; known: {sorted(known)}")
        if set(data["start"]) != set(data["end"]):
            raise ValueError("curriculum 'start' and 'end' must name the same attributes")
        integer = frozenset(
            k
            for k in data["start"]
            if isinstance(data["start"][k], int) and isinstance(data["end"][k], int)
        )
        return cls(
            integer=integer,
            start={k: float(v) for k, v in data["start"].items()},
            end={k: float(v) for k, v in data["end"].items()},
            n_stages=int(data.get("n_stages", 6)),
            window=int(data.get("window", 100)),
            promote_at=float(data.get("promote_at", 0.6)),
            final_fraction=float(data.get("final_fraction", 0.8)),
            gate=check_gate(str(data.get("gate", "train"))),
            max_stage_steps=int(data.get("max_stage_steps", 0)),
        )

    def values(self, stage: int) -> dict[str, Any]:
        """Attribute values at ``stage`` (0 … ``n_stages``): geometric between start and end
        (linear and rounded for integer attributes)."""
        f = min(max(stage, 0), self.n_stages) / max(self.n_stages, 1)
        out: dict[str, Any] = {}
        for k in self.start:
            a, b = self.start[k], self.end[k]
            if k in self.integer:
                out[k] = int(round(a + f * (b - a)))
            elif a > 0 and b > 0:
                out[k] = float(a * (b / a) ** f)
            else:
                out[k] = float(a + f * (b - a))
        return out


def check_gate(gate: str) -> str:
    if gate not in ("train", "eval"):
        raise ValueError(f"curriculum gate must be 'train' or 'eval', got {gate!r}")
    return gate


# --------------------------------------------------------------------------- settings
@dataclass(frozen=True)
class TrainConfig:
    """One training run.

    Parameters
    ----------
    env_id : registered environment id.
    algo : ``"ppo"`` or ``"sac"``.
    out_dir : folder for the model, metadata, learning curves and checkpoints.
    seed : seed of the algorithm, the env workers and the curriculum.
    total_timesteps : budget; ``None`` takes ``n_timesteps`` of the hyperparameter file.
    n_envs, vec_env : override the file's ``n_envs`` / ``vec_env`` (``"subproc"``, ``"dummy"``).
    hyperparams : override the whole hyperparameter entry (else read from the file).
    checkpoint_every : env steps between checkpoints (0: none).
    eval_every : env steps between deterministic evaluations (0: none).
    eval_episodes : episodes per evaluation (held-out seeds, the env's default criterion).
    progress_every_s : seconds between progress lines.
    init_model : continue training this saved model (same env and algorithm), a
        ``model.zip`` or, for PPO, exported weights (``.pth``; the optimiser starts anew); the
        curriculum schedule keeps referring to the file's ``n_timesteps``, and the file's
        learning rate, clip range, KL target, epochs, batch size and entropy coefficient
        replace the saved ones.
    vector : train on the vectorised surrogate of the env (``realitygap/WheeledNavVec-v0``
        for WheeledNav) with the file's entry for that id; ``n_envs`` robots step in one
        batched call. The policy is the env's (its spaces are the same): every evaluation,
        and the final one, runs in the PyBullet env.
    """

    env_id: str
    algo: str
    out_dir: Path
    seed: int = 0
    total_timesteps: int | None = None
    n_envs: int | None = None
    vec_env: str | None = None
    hyperparams: Mapping[str, Any] | None = None
    checkpoint_every: int = 100_000
    eval_every: int = 50_000
    eval_episodes: int = 20
    progress_every_s: float = 30.0
    init_model: Path | None = None
    vector: bool = False

    def __post_init__(self) -> None:
        """Check and convert every field (see :func:`check_train_fields`)."""
        for name, value in check_train_fields(self).items():
            object.__setattr__(self, name, value)


MAX_SEED = 2**32 - 1
"""Largest seed: NumPy's legacy generator (which SB3 seeds) takes seeds below 2³²."""

TRAIN_OPTIONS: dict[str, str] = {
    "env_id": "--env",
    "algo": "--algo",
    "out_dir": "--out",
    "seed": "--seed",
    "total_timesteps": "--timesteps",
    "n_envs": "--n-envs",
    "vec_env": "--vec-env",
    "hyperparams": "--hyperparams",
    "checkpoint_every": "--checkpoint-every",
    "eval_every": "--eval-every",
    "eval_episodes": "--eval-episodes",
    "init_model": "--init-model",
    "vector": "--vector",
}
"""The ``realitygap train`` option of each :class:`TrainConfig` field."""


def option_of(name: str) -> str:
    """How messages name field ``name``: its option and the field (``--n-envs (n_envs)``)."""
    opt = TRAIN_OPTIONS.get(name)
    return f"{opt} ({name})" if opt else name


def check_train_fields(cfg: TrainConfig) -> dict[str, Any]:
    """Every field of ``cfg`` checked and converted, before any work (the config calls it
    when it is made). What needs files or the hyperparameters is checked by
    :func:`~realitygap.baselines.rl.checks.check_training`.

    Raises
    ------
    TypeError, ValueError
        Naming the option and field, what was expected, what came and the fix.
    """
    from realitygap.core.checks import check_finite_float, check_int

    def count(name: str, low: int, *, none: bool = False, high: int | None = None) -> Any:
        value = getattr(cfg, name)
        if value is None and none:
            return None
        what = {0: "a non-negative integer", 1: "a positive integer"}[low]
        return check_int(value, option_of(name), low=low, high=high, what=what)

    out: dict[str, Any] = {
        "env_id": check_env_id(cfg.env_id) if isinstance(cfg.env_id, str) else None,
        "algo": None,
        "seed": count("seed", 0, high=MAX_SEED),
        "total_timesteps": count("total_timesteps", 1, none=True),
        "n_envs": count("n_envs", 1, none=True),
        "checkpoint_every": count("checkpoint_every", 0),
        "eval_every": count("eval_every", 0),
        "eval_episodes": count("eval_episodes", 0),
        "progress_every_s": check_finite_float(
            cfg.progress_every_s, "progress_every_s", low=0.0, strict_low=True, unit="s"
        ),
        "vector": cfg.vector,
    }
    if out["env_id"] is None:
        raise TypeError(f"{option_of('env_id')} must be an env id (str), got {cfg.env_id!r}")
    if not isinstance(cfg.algo, str):
        raise TypeError(f"{option_of('algo')} must be 'ppo' or 'sac', got {cfg.algo!r}")
    out["algo"] = check_algo(cfg.algo)
    if not isinstance(cfg.out_dir, (str, os.PathLike)) or not str(cfg.out_dir).strip():
        raise TypeError(
            f"{option_of('out_dir')} must be a folder path, got {cfg.out_dir!r}. Fix: give the "
            "folder for the model, its curves and checkpoints"
        )
    out["out_dir"] = Path(cfg.out_dir)
    if cfg.vec_env is not None and cfg.vec_env not in ("subproc", "dummy"):
        raise ValueError(
            f"{option_of('vec_env')} must be 'subproc' (one process per env) or 'dummy' (all in "
            f"this process), got {cfg.vec_env!r}"
        )
    if not isinstance(cfg.vector, bool):
        raise TypeError(f"{option_of('vector')} must be true or false, got {cfg.vector!r}")
    if cfg.vector:
        vector_env_id(out["env_id"])
    if cfg.hyperparams is not None and not isinstance(cfg.hyperparams, Mapping):
        raise TypeError(
            f"{option_of('hyperparams')} must be a mapping of hyperparameters (one env's entry), "
            f"got {type(cfg.hyperparams).__name__}"
        )
    if cfg.init_model is not None:
        if not isinstance(cfg.init_model, (str, os.PathLike)) or not str(cfg.init_model):
            raise TypeError(
                f"{option_of('init_model')} must be the path of a model.zip or .pth, got "
                f"{cfg.init_model!r}"
            )
        out["init_model"] = Path(cfg.init_model)
    return out


VECTOR_ENVS: dict[str, str] = {"realitygap/WheeledNav-v0": "realitygap/WheeledNavVec-v0"}
"""Env id → id of its vectorised surrogate (``gymnasium.make_vec``)."""


def vector_env_id(env_id: str) -> str:
    """The vectorised surrogate of ``env_id``, or a ``ValueError`` naming the envs that have one."""
    if env_id not in VECTOR_ENVS:
        raise ValueError(
            f"{env_id} has no vectorised surrogate; --vector works for {', '.join(VECTOR_ENVS)}"
        )
    return VECTOR_ENVS[env_id]


@dataclass(frozen=True)
class TrainResult:
    """What a training run produced."""

    model_path: Path
    meta_path: Path
    wall_seconds: float
    timesteps: int
    final_eval: dict[str, float] = field(default_factory=dict)


def resolve_policy_kwargs(kwargs: dict[str, Any]) -> dict[str, Any]:
    """Turn JSON-friendly policy kwargs (``"activation_fn": "tanh"``) into objects."""
    out = dict(kwargs)
    pk = dict(out.get("policy_kwargs", {}) or {})
    if "activation_fn" in pk and isinstance(pk["activation_fn"], str):
        import torch.nn as nn

        table = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU, "leaky_relu": nn.LeakyReLU}
        name = pk["activation_fn"].lower()
        if name not in table:
            raise ValueError(f"activation_fn must be one of {sorted(table)}, got {name!r}")
        pk["activation_fn"] = table[name]
    if pk:
        out["policy_kwargs"] = pk
    return out


# --------------------------------------------------------------------------- hyperparameters
def _kind(value: Any) -> str:
    text = repr(value)
    return f"{text if len(text) <= 50 else text[:47] + '...'} ({type(value).__name__})"


def _is_int(v: Any) -> bool:
    return isinstance(v, numbers.Integral) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(float(v))


_EXAMPLE = '{"realitygap/ArmCalib-v0": {"n_timesteps": 20000, "n_envs": 2, "policy": "MlpPolicy"}}'

# key → (what it must be, test)
_TRAIN_KEY_TYPES: dict[str, tuple[str, Any]] = {
    "n_timesteps": ("a positive integer", lambda v: _is_int(v) and v >= 1),
    "n_envs": ("a positive integer", lambda v: _is_int(v) and v >= 1),
    "vec_env": ('"subproc" or "dummy"', lambda v: v in ("subproc", "dummy")),
    "env_kwargs": ("an object of gym.make keyword arguments", lambda v: isinstance(v, Mapping)),
    "vector_env_kwargs": ("an object of keyword arguments", lambda v: isinstance(v, Mapping)),
    "policy": ('an SB3 policy name such as "MlpPolicy"', lambda v: isinstance(v, str) and v),
    "curriculum": ("an object or null", lambda v: v is None or isinstance(v, Mapping)),
    "normalize": (
        'an object {"obs": true/false, "reward": true/false} or null',
        lambda v: (
            v is None
            or (
                isinstance(v, Mapping)
                and set(v) <= {"obs", "reward"}
                and all(isinstance(x, bool) for x in v.values())
            )
        ),
    ),
    "action_deadband": (
        "a number ≥ 0 or null",
        lambda v: v is None or (_is_number(v) and v >= 0),
    ),
    "action_stop_gate": ("true or false", lambda v: isinstance(v, bool)),
    "train_max_episode_steps": (
        "a positive integer or null",
        lambda v: v is None or (_is_int(v) and v >= 1),
    ),
    "obs_features": ("a feature map name or null", lambda v: v is None or isinstance(v, str)),
    "log_std_max": (
        "a list [start, end] of two numbers, or null",
        lambda v: (
            v is None
            or (isinstance(v, (list, tuple)) and len(v) == 2 and all(_is_number(x) for x in v))
        ),
    ),
    "train_wrappers": (
        'a list of objects {"name": ..., ...}',
        lambda v: (
            v is None
            or (
                isinstance(v, (list, tuple))
                and all(isinstance(x, Mapping) and isinstance(x.get("name"), str) for x in v)
            )
        ),
    ),
    "obs_memory": ("an object or null", lambda v: v is None or isinstance(v, Mapping)),
    "obs_rest_timer": ("an object or null", lambda v: v is None or isinstance(v, Mapping)),
    "obs_scene_fade": ("a number ≥ 0 or null", lambda v: v is None or (_is_number(v) and v >= 0)),
    "demonstrations": ("an object or null", lambda v: v is None or isinstance(v, Mapping)),
}


def _algo_parameters(algo: str | None) -> set[str] | None:
    """Keyword arguments of the SB3 class of ``algo`` (``None`` when SB3 is missing)."""
    if algo is None:
        return None
    try:
        import inspect

        cls = algo_class(algo)
    except (ImportError, ValueError):
        return None
    return set(inspect.signature(cls.__init__).parameters) - {"self", "policy", "env"}


def check_hyperparams(entry: Any, where: str, *, algo: str | None = None) -> dict[str, Any]:
    """One env's hyperparameter entry, type-checked.

    Parameters
    ----------
    entry : mapping
        ``{"n_timesteps": ..., "n_envs": ..., "policy": ..., <algorithm arguments>}``.
    where : str
        Where it came from (``"--hyperparams hp.json, entry 'realitygap/ArmCalib-v0'"``).
    algo : str, optional
        The algorithm: its arguments are checked by name (a typo gets a suggestion).

    Raises
    ------
    TypeError
        Not a mapping.
    ValueError
        A key of the wrong type or value, or a name the algorithm does not take.
    """
    if not isinstance(entry, Mapping):
        raise TypeError(
            f"{where}: expected an object of hyperparameters (key: value), got "
            f"{_kind(entry)}. Fix: write the entry as an object, e.g. {_EXAMPLE}"
        )
    out = {str(k): v for k, v in entry.items()}

    algo_params = _algo_parameters(algo)
    for key, value in out.items():
        if key.startswith("_"):
            continue  # comments
        if key in _TRAIN_KEY_TYPES:
            what, ok = _TRAIN_KEY_TYPES[key]
            if not ok(value):
                raise ValueError(
                    f"{where}: {key!r} must be {what}, got {_kind(value)}. Fix: give {key!r} "
                    f"as {what}"
                )
        elif key not in TRAIN_KEYS and algo_params is not None and key not in algo_params:
            close = difflib.get_close_matches(key, sorted(algo_params | TRAIN_KEYS), n=1)
            hint = f" Did you mean {close[0]!r}?" if close else ""
            raise ValueError(
                f"{where}: {key!r} is neither a training key nor an argument of "
                f"{algo.upper() if algo else 'the algorithm'}.{hint} Fix: correct or remove it"
            )
    if "n_timesteps" not in out:
        raise ValueError(
            f"{where}: no 'n_timesteps' (the training budget). Fix: add "
            '"n_timesteps": <steps>, or give the budget with --timesteps'
        )
    return out


def check_hyperparams_table(
    table: Any, where: str, *, algo: str | None = None
) -> dict[str, dict[str, Any]]:
    """A hyperparameter file's content: a mapping of env id → entry (:func:`check_hyperparams`;
    keys starting with ``_`` are comments). ``where`` names the option and file."""
    if not isinstance(table, Mapping):
        raise TypeError(
            f"{where}: expected an object mapping env ids to hyperparameters at the top level, "
            f"got {_kind(table)}. Fix: write it as {_EXAMPLE}"
        )
    out: dict[str, dict[str, Any]] = {}
    for env_id, entry in table.items():
        if str(env_id).startswith("_"):
            continue
        out[str(env_id)] = check_hyperparams(entry, f"{where}, entry {env_id!r}", algo=algo)
    return out


def load_hyperparams_file(
    path: str | os.PathLike[str], option: str = "--hyperparams", *, algo: str | None = None
) -> dict[str, dict[str, Any]]:
    """Read and check a hyperparameter file (JSON, or YAML) with
    :func:`~realitygap.core.checks.load_json_or_yaml`: errors name ``option``, the file and
    the line."""
    table = load_json_or_yaml(Path(path), option, expect=dict, example=_EXAMPLE)
    return check_hyperparams_table(table, f"{option} {path}", algo=algo)


# --------------------------------------------------------------------------- models
