"""Saving, exporting, loading and shipping learned policies; run files.

.. warning::
   ``PPO.load`` / ``SAC.load`` unpickle parts of the zip file (cloudpickle), which
   can run arbitrary code. :func:`load_policy` therefore checks the JSON metadata
   beside the zip first, and it should only be given files this package ships
   (``baselines/policies/``) or that you trained yourself.
"""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import numpy.typing as npt

from realitygap.baselines.rl.config import (
    POLICIES_DIR,
    algo_class,
    check_algo,
    env_slug,
    require_sb3,
    resolve_policy_kwargs,
)
from realitygap.baselines.rl.policy_io import ObsNormalizer, PolicyIO
from realitygap.core.io import atomic_write, atomic_write_bytes, atomic_write_text


# --------------------------------------------------------------------------- save / load
def space_summary(space: gym.Space[Any]) -> dict[str, Any]:
    return {
        "type": type(space).__name__,
        "shape": list(space.shape) if space.shape is not None else None,
        "dtype": str(getattr(space, "dtype", "")),
    }


def save_policy(
    model: Any,
    path: str | os.PathLike[str],
    env_id: str,
    env_kwargs: Mapping[str, Any],
    algo: str,
    seed: int,
    timesteps: int,
    wall_seconds: float,
    hyperparams: Mapping[str, Any] | None = None,
    obs_normalizer: ObsNormalizer | None = None,
    extra: Mapping[str, Any] | None = None,
) -> Path:
    """Save ``model`` to ``path`` (SB3 zip) and its metadata beside it (``.json``).

    Both are written to temporary files first and renamed, so a crash never leaves a
    half-written policy. Returns the metadata path.
    """
    path = atomic_write(path, model.save)
    import stable_baselines3

    meta = {
        "format": "realitygap-policy/1",
        "env_id": env_id,
        "env_kwargs": jsonable(dict(env_kwargs)),
        "algo": algo,
        "seed": int(seed),
        "timesteps": int(timesteps),
        "train_wall_seconds": float(wall_seconds),
        "observation_space": space_summary(model.observation_space),
        "action_space": space_summary(model.action_space),
        "obs_normalizer": obs_normalizer.to_dict() if obs_normalizer is not None else None,
        "hyperparams": jsonable(dict(hyperparams or {})),
        "stable_baselines3": stable_baselines3.__version__,
        **jsonable(dict(extra or {})),
    }
    meta_path = path.with_suffix(".json")
    atomic_write_text(meta_path, json.dumps(meta, indent=2) + "\n")
    return meta_path


def read_policy_meta(path: str | os.PathLike[str], name: str = "policy") -> dict[str, Any]:
    """The JSON metadata of a saved policy (``model.zip`` → ``model.json``), without unpickling.

    Falls back to the readable part of the SB3 zip's ``data`` entry when the metadata
    file is missing; exported weights (``.pth``) need theirs.

    Raises
    ------
    FileNotFoundError
        No file at ``path``, or a ``.pth`` without its ``.json``.
    ValueError
        Unreadable, empty, or not a policy file; the message names ``name`` and the path.
    """
    import zipfile

    from realitygap.core.checks import check_input_path, load_json_or_yaml

    if not os.path.lexists(path):
        raise FileNotFoundError(
            f"{name}: no policy file {path}. Fix: give a model.zip written by `realitygap "
            "train`, or exported weights (.pth with its .json)"
        )
    path = check_input_path(path, name, kind="file", needs="a saved policy needs content")
    meta_path = path.with_suffix(".json")
    if meta_path.is_file() and meta_path != path:
        return dict(load_json_or_yaml(meta_path, f"{name} metadata", expect=dict))
    if path.suffix.lower() == ".pth":
        raise FileNotFoundError(
            f"{name}: exported weights {path} need their metadata {meta_path.name} beside "
            "them. Fix: copy the .json along with the .pth"
        )
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data").decode())
    except (zipfile.BadZipFile, KeyError, OSError, UnicodeDecodeError, ValueError) as exc:
        raise ValueError(
            f"{name}: {path} is not a stable-baselines3 policy file (a zip archive with a "
            f"'data' entry): {exc}. Fix: pass a model.zip written by `realitygap train`, or "
            "exported weights (.pth with its .json)"
        ) from None
    if not isinstance(data, Mapping):
        raise ValueError(f"{name}: {path}: the 'data' entry is not SB3's JSON object")
    obs = data.get("observation_space", {})
    act = data.get("action_space", {})
    obs = obs if isinstance(obs, Mapping) else {}
    act = act if isinstance(act, Mapping) else {}
    return {
        "format": "sb3-zip",
        "env_id": None,
        "observation_space": {"shape": obs.get("_shape"), "type": obs.get(":type:", "")},
        "action_space": {"shape": act.get("_shape"), "type": act.get(":type:", "")},
        "obs_normalizer": None,
    }


def check_policy_matches(
    meta: Mapping[str, Any],
    env_id: str,
    observation_space: gym.Space[Any],
    action_space: gym.Space[Any],
    path: Any = "policy",
) -> None:
    """Raise a ``ValueError`` when a saved policy does not fit ``env_id`` and its spaces."""
    trained_for = meta.get("env_id")
    if trained_for is not None and trained_for != env_id:
        raise ValueError(
            f"{path} was trained for {trained_for!r}, not {env_id!r}; train one for this env with "
            f"`realitygap train --env {env_id} --algo {meta.get('algo', 'ppo')}`"
        )
    spaces = {
        "observation": meta.get("env_observation_space") or meta.get("observation_space") or {},
        "action": meta.get("env_action_space") or meta.get("action_space") or {},
    }
    for name, space in (("observation", observation_space), ("action", action_space)):
        want = tuple(space.shape or ())
        got = spaces[name].get("shape")
        if got is not None and tuple(got) != want:
            raise ValueError(
                f"{path} expects {name}s of shape {tuple(got)}, but {env_id} has {want} "
                "(other env kwargs such as n_beams?); retrain with this env's settings"
            )


class LearnedPolicy:
    """A trained SB3 model behind the common ``predict`` interface.

    The policy is the whole chain the model was trained in: env observation → feature map
    → observation normalisation → network → stop gate and dead band (:class:`PolicyIO`),
    all read from the metadata, so the benchmark scores exactly what was trained.
    Observations of the wrong shape are refused.
    """

    def __init__(self, model: Any, meta: Mapping[str, Any], name: str = "learned"):
        self.model = model
        self.meta = dict(meta)
        self.name = name
        norm = self.meta.get("obs_normalizer")
        self.obs_normalizer = ObsNormalizer.from_dict(norm) if norm else None
        self.io = PolicyIO.from_dict(self.meta)
        shape = (self.meta.get("env_observation_space") or {}).get("shape")
        self.obs_shape = tuple(shape) if shape else tuple(model.observation_space.shape)
        self._episode_features: Any = None

    def predict(
        self,
        observation: npt.ArrayLike,
        state: Any = None,
        episode_start: npt.ArrayLike | None = None,
        deterministic: bool = True,
    ) -> tuple[npt.NDArray[np.float32], Any]:
        obs = np.asarray(observation, dtype=np.float32)
        if obs.shape[-len(self.obs_shape) :] != self.obs_shape:
            raise ValueError(
                f"{self.name} expects observations of shape {self.obs_shape} (or a batch of them), "
                f"got {obs.shape}"
            )
        obs = self._network_input(obs, episode_start)
        if self.obs_normalizer is not None:
            obs = self.obs_normalizer(obs)
        action, state = self.model.predict(
            obs, state=state, episode_start=episode_start, deterministic=deterministic
        )
        return self.io.action(action), state

    def _network_input(
        self, obs: npt.NDArray[np.float32], episode_start: npt.ArrayLike | None
    ) -> npt.NDArray[np.float32]:
        """The network input of a batch, with the episode features (obstacle memory, rest
        timer) of each env of the batch, reset where an episode starts (a policy without them
        keeps none). Without ``episode_start`` a call with a batch of another size starts new
        episodes."""
        if not self.io.has_episode_features:
            return self.io.observation(obs)
        from realitygap.baselines.common import episode_starts
        from realitygap.baselines.rl.batch_features import BatchEpisodeFeatures

        lead = obs.shape[: obs.ndim - len(self.obs_shape)]
        rows = obs.reshape(-1, obs.shape[-1])
        n = rows.shape[0]
        if self._episode_features is None or self._episode_features.n != n:
            if not self.io.complete:
                raise ValueError(
                    "obs_memory lacks the scan geometry; complete it with for_env(env)"
                )
            self._episode_features = BatchEpisodeFeatures(
                n, self.io.obs_memory, self.io.obs_rest_timer
            )
        else:
            starts = np.flatnonzero(episode_starts(episode_start, n))
            if starts.size:
                self._episode_features.reset(starts)
        x = self.io.network_input(rows, self._episode_features.update(rows))
        return x.reshape(*lead, x.shape[-1])


def load_policy(
    path: str | os.PathLike[str], env: gym.Env[Any, Any] | None = None, env_id: str | None = None
) -> LearnedPolicy:
    """Load a policy, checked against ``env``: exported weights (``.pth`` + ``.json``, see
    :func:`export_policy`) or an SB3 model (``.zip`` from :func:`train`).

    The metadata (plain JSON) is checked first: a policy trained for another env or
    observation space is refused with a ``ValueError`` before anything else is read.
    Exported weights load without unpickling (``torch.load(weights_only=True)``).

    .. warning::
       SB3's ``load`` (``.zip``) unpickles objects stored in the zip; only load zip
       files that you trained yourself.
    """
    path = Path(path)
    meta = read_policy_meta(path)
    if path.suffix == ".pth":
        algo = check_algo(meta.get("algo", ""))
    else:
        algo = check_algo(meta.get("algo") or _guess_algo(path))
    if env is not None:
        spec_id = env.spec.id if env.spec is not None else (env_id or "")
        check_policy_matches(meta, env_id or spec_id, env.observation_space, env.action_space, path)
    if path.suffix == ".pth":
        model = _policy_from_weights(path, meta, algo)
    else:
        model = algo_class(algo).load(path, device="cpu")
    return LearnedPolicy(model, meta, name=f"{algo}:{path.name}")


def _box_from_dict(data: Mapping[str, Any]) -> gym.spaces.Box:
    return gym.spaces.Box(
        np.asarray(data["low"], dtype=np.float32),
        np.asarray(data["high"], dtype=np.float32),
        dtype=np.float32,
    )


def _box_to_dict(space: gym.Space[Any]) -> dict[str, Any]:
    if not isinstance(space, gym.spaces.Box):
        raise TypeError(f"only Box spaces can be exported, got {type(space).__name__}")
    return {"low": space.low.tolist(), "high": space.high.tolist()}


def export_policy(model: Any, meta: Mapping[str, Any], dest: str | os.PathLike[str]) -> Path:
    """Write the inference part of a trained ``model`` as plain tensors and JSON.

    ``dest.pth`` holds the network weights (PPO: the actor-critic policy; SAC: the actor)
    saved with ``torch.save`` of a state dict; ``dest.json`` holds ``meta`` plus what is
    needed to rebuild the network (algorithm, ``policy_kwargs``, the network's spaces).
    Both load without unpickling, and are a fraction of the SB3 zip (no optimiser state,
    no critics for SAC). Returns the ``.pth`` path.
    """
    import torch

    dest = Path(dest).with_suffix(".pth")
    algo = check_algo(meta["algo"])
    state = (model.policy.actor if algo == "sac" else model.policy).state_dict()
    policy_kwargs = dict(meta.get("hyperparams", {}).get("policy_kwargs", {}) or {})
    out_meta = {
        **{k: v for k, v in meta.items() if k != "init_model"},
        "format": "realitygap-policy-weights/1",
        "policy_kwargs": jsonable(policy_kwargs),
        "model_observation_space": _box_to_dict(model.observation_space),
        "model_action_space": _box_to_dict(model.action_space),
    }
    weights = {k: v.detach().cpu() for k, v in state.items()}
    atomic_write(dest, lambda fh: torch.save(weights, fh))
    atomic_write_text(dest.with_suffix(".json"), json.dumps(out_meta, indent=2) + "\n")
    return dest


def _policy_from_weights(path: Path, meta: Mapping[str, Any], algo: str) -> Any:
    """Rebuild the SB3 policy network of exported weights (no unpickling)."""
    require_sb3()
    import torch

    if meta.get("format") != "realitygap-policy-weights/1":
        raise ValueError(f"{path.with_suffix('.json')} is not the metadata of exported weights")
    obs_space = _box_from_dict(meta["model_observation_space"])
    act_space = _box_from_dict(meta["model_action_space"])
    kwargs = resolve_policy_kwargs({"policy_kwargs": meta.get("policy_kwargs", {})}).get(
        "policy_kwargs", {}
    )
    state = torch.load(path, map_location="cpu", weights_only=True)
    if algo == "sac":
        from stable_baselines3.sac.policies import SACPolicy

        sac = SACPolicy(obs_space, act_space, lambda _: 0.0, **kwargs)
        sac.actor.load_state_dict(state)
        policy: Any = sac
    else:
        from stable_baselines3.common.policies import ActorCriticPolicy

        policy = ActorCriticPolicy(obs_space, act_space, lambda _: 0.0, **kwargs)
        policy.load_state_dict(state)
    policy.set_training_mode(False)
    return policy


def _guess_algo(path: Path) -> str:
    import zipfile

    with zipfile.ZipFile(path) as archive:
        data = json.loads(archive.read("data").decode())
    text = json.dumps(data.get("policy_class", {})).lower()
    if "sac" in text:
        return "sac"
    if "actorcriticpolicy" in text:
        return "ppo"
    raise ValueError(f"cannot tell which algorithm saved {path}; give its model.json")


def shipped_policy(env_id: str, algo: str) -> Path:
    """Path of the shipped ``algo`` policy for ``env_id``; ``FileNotFoundError`` saying how to
    train one when there is none."""
    algo = check_algo(algo)
    path = POLICIES_DIR / f"{env_slug(env_id)}_{algo}.pth"
    if not path.is_file():
        raise FileNotFoundError(
            f"no shipped {algo} policy for {env_id} ({path.name}); train one with "
            f"`realitygap train --env {env_id} --algo {algo}` or run the benchmark with --train"
        )
    return path


# --------------------------------------------------------------------------- files and plots
def jsonable(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    return str(value)


def write_csv_atomic(path: str | os.PathLike[str], rows: Sequence[Mapping[str, Any]]) -> None:
    """Write ``rows`` (dicts with the same keys) as CSV atomically."""
    import io

    buf = io.StringIO()
    if rows:
        keys = list(rows[0])
        for row in rows[1:]:
            keys += [k for k in row if k not in keys]
        writer = csv.DictWriter(buf, fieldnames=keys, lineterminator="\n")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: _csv_cell(row.get(k, "")) for k in keys})
    atomic_write_text(path, buf.getvalue())


def _csv_cell(value: Any) -> Any:
    if isinstance(value, float):
        return f"{value:.6g}"
    return value


def read_csv(path: str | os.PathLike[str]) -> list[dict[str, str]]:
    """Rows of a CSV file as dicts of strings."""
    with Path(path).open(newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def ship_policy(
    run_dir: str | os.PathLike[str], env_id: str, algo: str, variant: str | None = None
) -> Path:
    """Export a training folder's model into :data:`POLICIES_DIR` as ``<env>_<algo>.pth`` /
    ``.json`` (:func:`export_policy`), with its learning curves (``.episodes.csv``,
    ``.eval.csv``). The folder's ``model.zip`` is loaded with SB3 (it must be your own).

    ``variant`` (letters, digits, ``-``) names a policy of its own beside the shipped one,
    ``<env>_<algo>_<variant>.pth`` (e.g. ``vector`` for a policy trained on the vector env).
    """
    src = Path(run_dir)
    algo = check_algo(algo)
    if variant is not None and not (
        variant and all(ch.isascii() and (ch.isalnum() or ch == "-") for ch in variant)
    ):
        raise ValueError(
            f"variant must be a non-empty name of ASCII letters, digits and '-', got {variant!r}"
        )
    stem = f"{env_slug(env_id)}_{algo}" + (f"_{variant}" if variant else "")
    meta = read_policy_meta(src / "model.zip")
    if meta.get("env_id") not in (None, env_id):
        raise ValueError(f"{src / 'model.zip'} was trained for {meta.get('env_id')!r}")
    model = algo_class(algo).load(src / "model.zip", device="cpu")
    dest = export_policy(model, meta, POLICIES_DIR / f"{stem}.pth")
    for name, target in (
        ("episodes.csv", dest.with_suffix(".episodes.csv")),
        ("eval.csv", dest.with_suffix(".eval.csv")),
        ("demonstrations.csv", dest.with_suffix(".demonstrations.csv")),
    ):
        if (src / name).is_file():
            atomic_write_bytes(target, (src / name).read_bytes())
    return dest
