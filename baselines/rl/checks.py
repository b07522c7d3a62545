"""Checks of a training run's inputs, all made before any env starts or any step is spent.

One place for each kind of input of :func:`~realitygap.baselines.rl.training.train` (and so of
``realitygap train`` and ``realitygap benchmark --train``):

* :func:`check_hyperparams_table` / :func:`check_hyperparams` — a hyperparameter file's
  content: a mapping of env id → mapping, each known key of the right type.
* :func:`check_init_model` — the model a run continues: an SB3 ``.zip`` that holds SB3's
  ``data`` entry, or exported weights (``.pth`` with its ``.json``); nothing is unpickled.
* :func:`check_env_count` — the cost of ``n_envs`` PyBullet envs (memory, processes), known
  before it is spent.
* :func:`check_training` — all of the above for one :class:`TrainConfig` (its own fields
  are checked when it is made), resolving the hyperparameters, the budget and the env count.

Every message names the option (``--n-envs``) and the config field, what was expected,
what came, and the fix.
"""

from __future__ import annotations

import difflib
import math
import numbers
import os
import warnings
import zipfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from realitygap.core.checks import check_input_path, load_json_or_yaml

__all__ = [
    "DUMMY_ENV_BYTES",
    "MAIN_PROCESS_BYTES",
    "SUBPROC_WORKER_BYTES",
    "TrainPlan",
    "available_memory_bytes",
    "check_env_count",
    "check_hyperparams",
    "check_hyperparams_table",
    "check_init_model",
    "check_training",
]

# --------------------------------------------------------------------------- cost of envs
SUBPROC_WORKER_BYTES = 400 * 2**20
"""Memory of one ``SubprocVecEnv`` worker: a Python process that imports gymnasium,
PyBullet, torch and stable-baselines3 (≈ 240 MB resident, measured) and builds one
PyBullet env (≈ 50–130 MB for the first), rounded up."""
DUMMY_ENV_BYTES = 64 * 2**20
"""Memory of one more PyBullet env in this process (``DummyVecEnv``; ≈ 12–47 MB measured
after the first), rounded up."""
MAIN_PROCESS_BYTES = 512 * 2**20
"""Memory of the training process itself (torch, the model, the rollout buffer)."""


def available_memory_bytes() -> int | None:
    """Memory available to new processes (``MemAvailable`` of ``/proc/meminfo``, else the
    free physical pages); ``None`` where unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def _gb(n: float) -> str:
    return f"{n / 1e9:,.1f} GB"


def check_env_count(
    n_envs: int,
    vec_env: str,
    *,
    option: str = "--n-envs (n_envs)",
    available: int | None = None,
    cpus: int | None = None,
    warn: Callable[[str], None] | None = None,
) -> int:
    """Refuse ``n_envs`` PyBullet training envs that would not fit in memory; warn when
    more worker processes than CPUs would start.

    Parameters
    ----------
    n_envs : int
        Envs of the vectorised env.
    vec_env : {"subproc", "dummy"}
        One process per env, or all in this process.
    option : str
        The option named in messages.
    available, cpus : int, optional
        Available memory in bytes and CPU count (default: this machine's).
    warn : callable, optional
        Receives the warning about CPUs (default :func:`warnings.warn`).

    Returns
    -------
    int
        ``n_envs``.

    Raises
    ------
    ValueError
        The estimated memory (:data:`SUBPROC_WORKER_BYTES` or :data:`DUMMY_ENV_BYTES` per
        env, plus :data:`MAIN_PROCESS_BYTES`) exceeds the available memory.
    """
    subproc = vec_env == "subproc" and n_envs > 1
    per_env = SUBPROC_WORKER_BYTES if subproc else DUMMY_ENV_BYTES
    need = MAIN_PROCESS_BYTES + n_envs * per_env
    avail = available_memory_bytes() if available is None else available
    if avail is not None and need > avail:
        fit = max(1, (avail - MAIN_PROCESS_BYTES) // per_env)
        kind = "worker processes (vec_env subproc)" if subproc else "envs in this process"
        raise ValueError(
            f"{option} {n_envs:,}: {n_envs:,} PyBullet {kind} need about {_gb(need)} of "
            f"memory (≈ {per_env / 2**20:.0f} MB each), but {_gb(avail)} is available. Fix: "
            f"use at most {fit:,} envs (--n-envs {min(fit, os.cpu_count() or 1)} is one per CPU)"
        )
    ncpu = (os.cpu_count() or 1) if cpus is None else cpus
    if subproc and n_envs > ncpu:
        text = (
            f"{option} {n_envs} worker processes on {ncpu} CPU(s): the workers share the "
            f"cores, so steps come no faster than with {ncpu}; each adds ≈ "
            f"{per_env / 2**20:.0f} MB"
        )
        if warn is not None:
            warn(text)
        else:
            warnings.warn(text, RuntimeWarning, stacklevel=2)
    return n_envs


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

        from realitygap.baselines.rl.config import algo_class

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
    from realitygap.baselines.rl.config import TRAIN_KEYS

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
def check_init_model(
    path: str | os.PathLike[str], option: str = "--init-model (init_model)"
) -> Path:
    """The model a training run continues, checked without unpickling anything.

    A ``.zip`` must be a zip archive holding SB3's ``data`` entry (JSON); a ``.pth`` (exported
    weights) must be a torch zip archive with its ``.json`` metadata beside it.

    Raises
    ------
    FileNotFoundError
        No file there, or a ``.pth`` without its ``.json``.
    ValueError
        Not a file, unreadable, empty, another suffix, or not the format its suffix says.
    """
    p = check_input_path(path, option, kind="file", needs="a saved model needs content")
    suffix = p.suffix.lower()
    if suffix not in (".zip", ".pth"):
        raise ValueError(
            f"{option}: {p} is neither a model.zip (stable-baselines3) nor exported weights "
            "(.pth with its .json). Fix: pass the model.zip a training run wrote, or a .pth"
        )
    meta = p.with_suffix(".json")
    if suffix == ".pth" and not meta.is_file():
        raise FileNotFoundError(
            f"{option}: exported weights {p} need their metadata {meta.name} beside them "
            "(written together by export_policy). Fix: copy the .json along with the .pth"
        )
    if not zipfile.is_zipfile(p):
        raise ValueError(
            f"{option}: {p} is not a zip archive, so not a "
            f"{'stable-baselines3 model' if suffix == '.zip' else 'torch weights file'} "
            "(a broken copy or another file renamed). Fix: pass the model.zip a training run "
            "wrote (runs/train/<env>/<algo>/seed<k>/model.zip)"
        )
    if suffix == ".zip":
        try:
            with zipfile.ZipFile(p) as archive:
                if "data" not in archive.namelist():
                    raise ValueError(
                        f"{option}: {p} is a zip archive without stable-baselines3's 'data' "
                        "entry, so not an SB3 model. Fix: pass the model.zip a training run wrote"
                    )
                import json

                data = json.loads(archive.read("data").decode("utf-8"))
        except (zipfile.BadZipFile, OSError, UnicodeDecodeError, ValueError) as exc:
            if str(exc).startswith(option):
                raise
            raise ValueError(
                f"{option}: {p} is not a readable stable-baselines3 model ({exc}). Fix: pass "
                "the model.zip a training run wrote"
            ) from None
        if not isinstance(data, Mapping):
            raise ValueError(
                f"{option}: {p}: its 'data' entry is not SB3's JSON object. Fix: pass the "
                "model.zip a training run wrote"
            )
    if meta.is_file():
        got = load_json_or_yaml(meta, f"{option} metadata", expect=dict)
        algo = got.get("algo")
        if algo is not None and algo not in ("ppo", "sac"):
            raise ValueError(
                f"{option} metadata {meta}: 'algo' must be 'ppo' or 'sac', got {_kind(algo)}"
            )
    return p


# --------------------------------------------------------------------------- a whole run
@dataclass(frozen=True)
class TrainPlan:
    """What a checked :class:`TrainConfig` will run: its hyperparameters, budget and envs."""

    hp: dict[str, Any]
    total_timesteps: int
    n_envs: int
    vec_env: str


def check_training(
    cfg: Any, *, explicit: Sequence[str] = (), warn: Callable[[str], None] | None = None
) -> TrainPlan:
    """Every input of a training run, checked before any env starts.

    The config's own fields were checked when it was made (:class:`TrainConfig`); this
    reads and checks the hyperparameters (the file's entry, or ``cfg.hyperparams``),
    resolves the budget, env count and kind, checks the model to continue, and the cost
    of the envs (:func:`check_env_count`; the vectorised surrogate checks its own).

    Parameters
    ----------
    cfg : TrainConfig
    explicit : sequence of str
        Fields the user set on purpose (the CLI's given options): an ``eval_every`` or
        ``checkpoint_every`` among them beyond the budget is refused (nothing would run);
        otherwise it is the default, and a short run just evaluates at its end.
    warn : callable, optional
        Receives warnings (more worker processes than CPUs); default :func:`warnings.warn`.

    Raises
    ------
    ValueError, TypeError, FileNotFoundError, KeyError
        With the option, the file, what was expected, what came and the fix.
    """
    from realitygap.baselines.rl.config import load_hyperparams, option_of, vector_env_id

    hp_id = vector_env_id(cfg.env_id) if cfg.vector else cfg.env_id
    if cfg.hyperparams is not None:
        hp = check_hyperparams(cfg.hyperparams, "hyperparams", algo=cfg.algo)
    else:
        hp = load_hyperparams(cfg.algo, hp_id)
    total = int(cfg.total_timesteps if cfg.total_timesteps is not None else hp["n_timesteps"])
    n_envs = int(cfg.n_envs if cfg.n_envs is not None else hp.get("n_envs", 1))
    vec_kind = str(cfg.vec_env if cfg.vec_env is not None else hp.get("vec_env", "dummy"))
    for name in ("eval_every", "checkpoint_every"):
        every = int(getattr(cfg, name))
        if every > total:
            what = "evaluation" if name == "eval_every" else "checkpoint"
            text = (
                f"{option_of(name)} {every:,} is beyond the budget of {total:,} steps "
                f"(--timesteps or the file's n_timesteps), so no {what} would happen before "
                f"the end"
            )
            if name in explicit:
                raise ValueError(f"{text}. Fix: give {option_of(name)} ≤ {total}")
    if not cfg.vector:
        check_env_count(n_envs, vec_kind, option=option_of("n_envs"), warn=warn)
    if cfg.init_model is not None:
        check_init_model(cfg.init_model, option_of("init_model"))
    return TrainPlan(hp=hp, total_timesteps=total, n_envs=n_envs, vec_env=vec_kind)


def check_seed_list(text: str | Sequence[Any], option: str = "--train-seeds") -> list[int]:
    """``"0,1,2"`` (or a sequence) as distinct non-negative integer seeds below 2³²."""
    from realitygap.baselines.rl.config import MAX_SEED

    items = [t.strip() for t in text.split(",")] if isinstance(text, str) else list(text)
    items = [t for t in items if t != ""]
    if not items:
        raise ValueError(
            f"{option}: expected comma-separated seeds such as 0,1,2, got {str(text)!r}. "
            "Fix: give at least one seed"
        )
    out: list[int] = []
    for item in items:
        value: int | None
        if isinstance(item, str):
            value = (
                int(item)
                if item.lstrip("+").isdigit() or (item.startswith("-") and item[1:].isdigit())
                else None
            )
        else:
            value = int(item) if _is_int(item) else None
        if value is None or not 0 <= value <= MAX_SEED:
            raise ValueError(
                f"{option}: each seed must be an integer in [0, {MAX_SEED}], got {item!r} in "
                f"{str(text)!r}. Fix: give seeds such as 0,1,2"
            )
        out.append(value)
    if len(set(out)) != len(out):
        raise ValueError(
            f"{option}: seeds {out} repeat one; the same seed trains the same policy twice. "
            "Fix: give distinct seeds"
        )
    return out
