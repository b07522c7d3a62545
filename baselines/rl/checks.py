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

import os
import warnings
import zipfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from realitygap.baselines.rl.config import _is_int, _kind, check_hyperparams
from realitygap.core.checks import check_input_path, load_json_or_yaml

__all__ = [
    "DUMMY_ENV_BYTES",
    "MAIN_PROCESS_BYTES",
    "SUBPROC_WORKER_BYTES",
    "TrainPlan",
    "available_memory_bytes",
    "check_env_count",
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
