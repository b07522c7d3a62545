"""The policies the benchmark scores: classical, random, shipped and trained files."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from realitygap.baselines.rl import (
    load_policy,
    shipped_policy,
)
from realitygap.cards import ENV_CARDS, load_object

POLICY_KINDS: tuple[str, ...] = ("classical", "ppo", "sac", "random")
"""Policy names the benchmark knows; ``name=path/to/model.zip`` adds a trained file."""


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
            if not name or not path:
                raise ValueError(
                    f"--policies: {item!r} needs a name and a path, name=path/to/model.zip. "
                    "Fix: e.g. mine=runs/train/WheeledNav-v0/ppo/seed0/model.zip"
                )
            if not os.path.lexists(path):
                where = "" if Path(path).is_absolute() else f" (relative to {Path.cwd()})"
                raise FileNotFoundError(
                    f"--policies {name}: no file {path}{where}. Fix: give the path of a "
                    "model.zip written by `realitygap train`, or of exported weights (.pth)"
                )
            out.append(check_policy_spec(PolicySpec(name, "file", (("*", path),))))
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


def check_policy_spec(spec: Any) -> PolicySpec:
    """``spec`` if it is a :class:`PolicySpec` of a known kind whose model files are readable
    policy files (an SB3 zip with its ``data`` entry, or ``.pth`` weights with their
    ``.json``), read without unpickling anything.

    Raises
    ------
    TypeError
        Not a :class:`PolicySpec`.
    FileNotFoundError, ValueError
        An unknown kind or name, or a model file that is missing or no policy file; the
        message names ``--policies`` and the policy.
    """
    from realitygap.baselines.rl import read_policy_meta

    if not isinstance(spec, PolicySpec):
        raise TypeError(
            f"--policies (policies) must hold PolicySpec objects (parse_policies), got "
            f"{type(spec).__name__}"
        )
    if not isinstance(spec.name, str) or not spec.name.strip():
        raise ValueError(f"--policies (policies): a policy needs a name, got {spec.name!r}")
    if spec.kind not in (*POLICY_KINDS, "file"):
        raise ValueError(
            f"--policies (policies): policy {spec.name!r} has unknown kind {spec.kind!r}; "
            f"expected one of {', '.join(POLICY_KINDS)} or 'file'"
        )
    if spec.kind == "file" and not spec.paths:
        raise ValueError(f"--policies (policies): policy {spec.name!r} names no model file")
    for _, path in spec.paths:
        read_policy_meta(path, f"--policies {spec.name}")
    return spec


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
