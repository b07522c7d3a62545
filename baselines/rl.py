"""Learned baselines: stable-baselines3 PPO and SAC for every registered environment.

Hyperparameters live in files, one per algorithm, keyed by environment id as in
rl-baselines3-zoo (``baselines/hyperparams/ppo.json``, ``sac.json``)::

    {"realitygap/WheeledNav-v0": {"n_timesteps": 1500000, "n_envs": 8, "vec_env": "subproc",
                                  "env_kwargs": {...}, "policy": "MlpPolicy", ...}}

An env without an entry has no learned baseline yet; :func:`load_hyperparams` says so.
Keys that are not arguments of the algorithm are read by :func:`train`:

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

WheeledNav recipe. Success needs the robot *at rest* (``|v| < 0.01`` m/s,
``|ω| < 0.05`` rad/s) within 3 cm and 5° of the goal pose, among obstacles seen only
through a 70° camera. PPO from scratch learns to approach the goal but seldom to dock
(10 % strict success after 700 k steps with a curriculum on the tolerances). The
recipe in ``ppo.json`` (93 % strict success on the benchmark's 100 episodes, where the
classical pipeline reaches 97 %; the shipped policy is this recipe's, seed 0):

1. **Inputs.** Everything in the estimated robot frame
   (:func:`wheeled_nav_egocentric_features`): a network that also reads the absolute pose
   learns a bias that depends on where in the room it is, which next to the goal cancels
   the last small turn. The goal in polar form and "zoomed", so centimetre and degree
   errors are visible after normalisation, with a goal bearing that fades out at the goal
   instead of spinning round it (:func:`wheeled_nav_goal_smooth_features`); an obstacle memory
   all around the robot (``obs_memory``,
   :class:`~realitygap.baselines.episode_features.ObstacleMemory`); and a rest timer
   (``obs_rest_timer``, :class:`~realitygap.baselines.episode_features.RestTimer`), without
   which "stopped short of the goal" is a fixed point of a deterministic policy. Within
   0.2 m of the goal the scan and the memory fade to "nothing seen" (``obs_scene_fade``,
   :func:`scene_fade`): the goal is kept clear of obstacles, and a network that still
   reads them there learns a turn bias from how the obstacles around each goal happen to
   lie, which stalls it 5–6° off the goal heading.
2. **Outputs.** A stop gate (:func:`stop_gate`): stopping is one decision, not two
   commands that must both be near zero.
3. **Warm start.** DAgger (:mod:`realitygap.baselines.imitation`) from a privileged
   teacher that plans shortest paths on the episode's true map
   (:class:`~realitygap.baselines.privileged.GeodesicNavExpert`, ``"expert":
   "geodesic"``): ten rounds of 80 episodes, the network fitted to the teacher's
   commands, small commands weighted up; the observation normalisation is then frozen.
   The teacher's command is a function of the estimated pose, so its labels never
   contradict each other. The classical pipeline (``"expert": "classical"``) chooses the
   side of an obstacle from the plan it made at its last re-plan and its turn direction
   from the phase it is in; a network fitted by least squares to those labels averages
   the choices — straight at the obstacle, or no turn — and that capped the recipe at
   72–77 % on the benchmark's episodes.
4. **Fine-tuning.** PPO with a small learning rate (5e-5), clipping 0.1 and a KL limit,
   low exploration noise, on the env's reward plus a precision potential and a larger
   collision penalty (:class:`WheeledNavShaping`), with the env's own success criterion.
   Training episodes are cut at 600 steps (30 s).
5. **Docking starts**: 30 % of the demonstration episodes and 15 % of the PPO episodes
   start next to the goal facing anywhere (:class:`WheeledNavDockingStarts`). A robot
   that reaches the goal position with a large heading error must turn in place; the
   expert seldom arrives that way, so without these starts the network never learns it
   and stalls there.

The from-scratch settings of earlier versions (curriculum, dead band, relaxed
at-rest condition) remain available as hyperparameter keys, as does
``demonstrations.mirror`` (fit the left–right mirror image of each sample too), which left
success where it was and is off.

The network still reads only the observation; the true map shapes its labels, never its
inputs, so the shipped policy runs on a robot that has no map.

ArmCalib recipe. A campaign is good when its poses are spread so that the
identification is well conditioned. A Gaussian policy trained by PPO from scratch
gets that spread from its exploration noise: its success in training is that of random
poses, while its deterministic action (the mean, what the benchmark scores) hardly
depends on the state and asks for nearly the same pose twenty times (0 % success). The
recipe in ``ppo.json`` clones the observability-greedy selector (one round of
demonstrations, :mod:`realitygap.baselines.imitation`), then fine-tunes with small
exploration noise on the env's reward plus an observability potential
(:class:`ArmObservabilityShaping`), which pays from the second pose on instead of only
after the first identification.

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

.. warning::
   ``PPO.load`` / ``SAC.load`` unpickle parts of the zip file (cloudpickle), which
   can run arbitrary code. :func:`load_policy` therefore checks the JSON metadata
   beside the zip first, and it should only be given files this package ships
   (``baselines/policies/``) or that you trained yourself.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
import tempfile
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import numpy.typing as npt

ALGOS: tuple[str, ...] = ("ppo", "sac")
"""Learning algorithms with hyperparameter files."""

HYPERPARAMS_DIR = Path(__file__).resolve().parent / "hyperparams"
"""Folder of the per-algorithm hyperparameter files."""

POLICIES_DIR = Path(__file__).resolve().parent / "policies"
"""Folder of the policies this package ships (trained by :func:`train`)."""

EVAL_SEED_OFFSET = 50_000
"""Evaluation during training uses seeds from here on, apart from the benchmark's."""

_TRAIN_KEYS = frozenset(
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
    """The hyperparameters of ``algo`` on ``env_id`` from its file (``hyperparams/<algo>.json``).

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    KeyError
        If the file has no entry for ``env_id``.
    """
    algo = check_algo(algo)
    file = Path(path) if path is not None else HYPERPARAMS_DIR / f"{algo}.json"
    if not file.is_file():
        raise FileNotFoundError(f"no hyperparameter file {file}")
    table = json.loads(file.read_text(encoding="utf-8"))
    if env_id not in table:
        raise KeyError(
            f"{file.name} has no hyperparameters for {env_id!r}; it has: "
            f"{', '.join(sorted(k for k in table if not k.startswith('_')))}. Add an entry "
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
            gate=_check_gate(str(data.get("gate", "train"))),
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


def wheeled_nav_goal_features(obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
    r"""WheeledNav observation plus the goal in polar form in the estimated robot frame.

    Appends five columns to ``obs`` (``(..., 12 + n_beams)``): the distance to the goal
    ``ρ`` (m), ``cos α, sin α`` of the bearing of the goal and ``cos β, sin β`` of the goal
    heading, both relative to the estimated robot heading ``θ``:

    .. math::

        \rho = \lVert p_g^{r} \rVert, \quad \alpha = \operatorname{atan2}(y_g^r, x_g^r),
        \quad \beta = \theta_g - \theta

    These are computed from the observation alone (no ground truth); they spare the network
    from learning products such as :math:`\cos\theta_g\cos\theta + \sin\theta_g\sin\theta`.
    """
    x = np.asarray(obs, dtype=np.float32)
    c, s_, cg, sg = x[..., 2], x[..., 3], x[..., 6], x[..., 7]
    xr, yr = x[..., 8], x[..., 9]
    rho = np.hypot(xr, yr)
    safe = np.where(rho > 1e-6, rho, 1.0)
    cos_a = np.where(rho > 1e-6, xr / safe, 1.0)
    sin_a = np.where(rho > 1e-6, yr / safe, 0.0)
    cos_b = cg * c + sg * s_
    sin_b = sg * c - cg * s_
    extra = np.stack([rho, cos_a, sin_a, cos_b, sin_b], axis=-1).astype(np.float32)
    return np.concatenate([x, extra], axis=-1)


ZOOM_POS_SCALES: tuple[float, ...] = (0.05, 0.3)
"""Length scales (m) of :func:`wheeled_nav_goal_zoom_features`' goal-offset columns."""

ZOOM_ANG_SCALES: tuple[float, ...] = (0.1, 0.5)
"""Angle scales (rad) of :func:`wheeled_nav_goal_zoom_features`' heading-error columns."""


def wheeled_nav_goal_zoom_features(obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
    r"""The polar goal features (:func:`wheeled_nav_goal_features`) plus "zoomed" ones.

    Success needs the robot within 3 cm and 5° of the goal pose, errors that vanish next to
    the metre-scale distances once the observation is normalised. For each length scale
    ``s`` in :data:`ZOOM_POS_SCALES` and each angle scale ``σ`` in :data:`ZOOM_ANG_SCALES`
    this appends

    .. math::

        \tanh(x_g^r / s),\ \tanh(y_g^r / s), \qquad \tanh(\beta / \sigma)

    with the goal position ``(x_g^r, y_g^r)`` in the estimated robot frame and the goal
    heading error ``β = θ_g − θ`` wrapped to ``(−π, π]``: ±1 far away, linear with a steep
    slope close to the goal, so the last centimetres and degrees are visible to the network.
    """
    x = wheeled_nav_goal_features(obs)
    xr, yr = x[..., 8], x[..., 9]
    beta = np.arctan2(x[..., -1], x[..., -2])
    cols = [np.tanh(c / s) for s in ZOOM_POS_SCALES for c in (xr, yr)]
    cols += [np.tanh(beta / s) for s in ZOOM_ANG_SCALES]
    return np.concatenate([x, np.stack(cols, axis=-1).astype(np.float32)], axis=-1)


BEARING_FADE: float = 0.05
"""Distance (m) below which :func:`wheeled_nav_goal_smooth_features` fades the goal bearing."""


def wheeled_nav_goal_smooth_features(obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
    r"""The zoomed goal features (:func:`wheeled_nav_goal_zoom_features`) with a goal
    bearing that is continuous at the goal.

    ``cos α, sin α`` are undefined at the goal position: a millimetre of motion next to it
    swings them through the whole circle, and a network that reads them turns this into
    noise in its command just where it must turn in place and stop. Here the two bearing
    columns are

    .. math::

        \frac{(x_g^r,\ y_g^r)}{\sqrt{\rho^2 + \rho_0^2}}

    the unit bearing far from the goal, fading to zero within ``ρ0`` =
    :data:`BEARING_FADE`; every other column is the zoomed features'.
    """
    x = wheeled_nav_goal_zoom_features(obs)
    n0 = np.shape(obs)[-1]
    xr, yr = x[..., 8], x[..., 9]
    scale = 1.0 / np.sqrt(xr.astype(np.float64) ** 2 + yr.astype(np.float64) ** 2 + BEARING_FADE**2)
    x[..., n0 + 1] = (xr * scale).astype(np.float32)
    x[..., n0 + 2] = (yr * scale).astype(np.float32)
    return x


WORLD_FRAME_COLUMNS: int = 8
"""The leading WheeledNav observation columns given in the world frame: the estimated pose
``x, y, cos θ, sin θ`` and the goal ``x_g, y_g, cos θ_g, sin θ_g``."""


def wheeled_nav_egocentric_features(obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
    r"""The smooth goal features (:func:`wheeled_nav_goal_smooth_features`) without the
    world-frame columns: everything the network reads is in the estimated robot frame.

    The task is the same wherever the room puts the robot and whichever way it faces it:
    the command depends only on where the goal and the obstacles lie relative to the robot.
    A network that also reads the absolute pose and goal (the first
    :data:`WORLD_FRAME_COLUMNS` columns) can, and does, learn a bias that depends on where in
    the room it is. Next to the goal such a bias of a tenth of the turn-rate limit cancels
    the small turn that is left to do, and the robot stalls a few degrees off the goal
    heading. Dropping these columns makes the map invariant to any rigid motion of the
    world by construction; the goal stays visible through the robot-frame columns
    ``x_g^r, y_g^r`` and the polar and zoomed features.
    """
    x = wheeled_nav_goal_smooth_features(obs)
    return np.ascontiguousarray(x[..., WORLD_FRAME_COLUMNS:])


def wheeled_nav_egocentric_mirror(
    n_beams: int, n_sectors: int = 0, rest_timer: bool = False
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.float32]]:
    r"""The left–right mirror of a network input of :func:`wheeled_nav_egocentric_features`.

    Reflecting the world about the robot's heading line maps a WheeledNav scene onto
    another valid scene, and the expert's command ``(v, ω)`` onto ``(v, −ω)``. In the
    robot frame the reflection is ``y → −y``; each input column goes to a column of the
    mirrored input (``perm``) with a sign (``sign``): ``mirrored = x[..., perm] * sign``.

    The input is the env observation less its world-frame columns —
    ``x_g^r, y_g^r, v, ω`` then ``n_beams`` scan beams, whose bearings must be symmetric
    about the optical axis — followed by ``n_sectors`` obstacle-memory sectors (sector
    ``k`` centred on bearing ``2πk / n``), a rest-timer column if ``rest_timer``, and the
    polar and zoomed goal columns
    ``ρ, b_x, b_y, cos β, sin β, tanh(x/s₁), tanh(y/s₁), tanh(x/s₂), tanh(y/s₂),
    tanh(β/σ₁), tanh(β/σ₂)``.
    """
    if n_beams < 1 or n_sectors < 0:
        raise ValueError(f"need n_beams >= 1 and n_sectors >= 0, got {n_beams}, {n_sectors}")
    perm: list[int] = [0, 1, 2, 3]
    sign: list[float] = [1.0, -1.0, 1.0, -1.0]
    k0 = 4
    perm += [k0 + n_beams - 1 - k for k in range(n_beams)]  # beams reversed
    sign += [1.0] * n_beams
    k0 += n_beams
    perm += [k0 + (-k) % n_sectors for k in range(n_sectors)]  # bearing -> -bearing
    sign += [1.0] * n_sectors
    k0 += n_sectors
    if rest_timer:
        perm.append(k0)
        sign.append(1.0)
        k0 += 1
    goal_signs = [1.0, 1.0, -1.0, 1.0, -1.0]  # ρ, b_x, b_y, cos β, sin β
    goal_signs += [1.0, -1.0] * len(ZOOM_POS_SCALES) + [-1.0] * len(ZOOM_ANG_SCALES)
    perm += [k0 + k for k in range(len(goal_signs))]
    sign += goal_signs
    return np.asarray(perm, dtype=np.intp), np.asarray(sign, dtype=np.float32)


OBS_FEATURES: dict[str, tuple[Callable[[npt.ArrayLike], npt.NDArray[np.float32]], int]] = {
    "wheeled_nav_goal_polar": (wheeled_nav_goal_features, 5),
    "wheeled_nav_goal_zoom": (
        wheeled_nav_goal_zoom_features,
        5 + 2 * len(ZOOM_POS_SCALES) + len(ZOOM_ANG_SCALES),
    ),
    "wheeled_nav_goal_smooth": (
        wheeled_nav_goal_smooth_features,
        5 + 2 * len(ZOOM_POS_SCALES) + len(ZOOM_ANG_SCALES),
    ),
    "wheeled_nav_egocentric": (
        wheeled_nav_egocentric_features,
        5 + 2 * len(ZOOM_POS_SCALES) + len(ZOOM_ANG_SCALES) - WORLD_FRAME_COLUMNS,
    ),
}
"""Feature maps a learned policy may apply to its observation: name → (function, change in
the number of columns). A map appends columns to the observation and may first drop some
of its leading ones (:data:`OBS_FEATURES_DROP`)."""

OBS_FEATURES_DROP: dict[str, int] = {"wheeled_nav_egocentric": WORLD_FRAME_COLUMNS}
"""Leading observation columns a feature map drops (none where not listed)."""


def obs_feature_fn(name: str | None) -> Callable[[npt.ArrayLike], npt.NDArray[np.float32]] | None:
    """The feature map called ``name`` (``None`` for none); ``ValueError`` on an unknown name."""
    if not name:
        return None
    if name not in OBS_FEATURES:
        raise ValueError(f"unknown obs_features {name!r}; known: {', '.join(OBS_FEATURES)}")
    return OBS_FEATURES[name][0]


class ObsFeatures(gym.ObservationWrapper):
    """Appends the columns of feature map ``name`` to each observation (training side)."""

    def __init__(self, env: gym.Env[Any, Any], name: str):
        super().__init__(env)
        fn = obs_feature_fn(name)
        assert fn is not None
        self.fn = fn
        n_extra = OBS_FEATURES[name][1]
        space = env.observation_space
        assert isinstance(space, gym.spaces.Box)
        big = np.float32(1e3)
        n_out = int(space.shape[-1]) + n_extra
        width = int(fn(np.zeros((1, space.shape[-1]), np.float32)).shape[-1])
        if width != n_out:
            raise ValueError(
                f"obs_features {name!r} gives {width} columns for a {space.shape[-1]}-column "
                f"observation, expected {n_out}"
            )
        # the observation's own columns keep their bounds, the map's new ones get wide ones
        drop = OBS_FEATURES_DROP.get(name, 0)
        n_new = n_out - (int(space.shape[-1]) - drop)
        low = np.concatenate([space.low[drop:], np.full(n_new, -big, np.float32)])
        high = np.concatenate([space.high[drop:], np.full(n_new, big, np.float32)])
        self.observation_space = gym.spaces.Box(low, high, dtype=np.float32)

    def observation(self, observation: Any) -> Any:
        return self.fn(observation)


def _check_gate(gate: str) -> str:
    if gate not in ("train", "eval"):
        raise ValueError(f"curriculum gate must be 'train' or 'eval', got {gate!r}")
    return gate


def set_env_attrs(env: gym.Env[Any, Any], values: Mapping[str, Any]) -> None:
    """Set each attribute on the outermost layer of ``env`` (wrappers, then the base env)
    that defines it; ``AttributeError`` naming the env when none does."""
    for name, value in values.items():
        layer: Any = env
        while True:
            if name in vars(layer) or hasattr(type(layer), name):
                setattr(layer, name, value)
                break
            if not isinstance(layer, gym.Wrapper):
                raise AttributeError(
                    f"neither {type(env.unwrapped).__name__} nor its wrappers have an "
                    f"attribute {name!r}"
                )
            layer = layer.env


class AttributeSetter(gym.Wrapper):
    """Lets a vectorised env set attributes of the env and its training wrappers
    (``env_method("set_env_attrs", {...})``, see :func:`set_env_attrs`)."""

    def set_env_attrs(self, values: Mapping[str, Any]) -> None:
        set_env_attrs(self.env, values)


class WheeledNavRestRelaxation(gym.Wrapper):
    """Training only: WheeledNav success with a looser "at rest" condition.

    The env's success needs the pose within tolerance *and* the robot at rest
    (``|v| < 0.01`` m/s, ``|ω| < 0.05`` rad/s), which a stochastic policy in training
    almost never is. This wrapper also declares success — the env's bonus, termination,
    ``info["is_success"]`` — when the pose is within the env's current tolerances and
    ``|v| < rest_v_tol``, ``|ω| < rest_w_tol``; a curriculum can shrink these to the
    env's own values. Evaluation and the benchmark never use it.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        rest_v_tol: float = 10.0,
        rest_w_tol: float = 10.0,
        bonus: float = 5.0,
    ):
        super().__init__(env)
        self.rest_v_tol = float(rest_v_tol)
        self.rest_w_tol = float(rest_w_tol)
        self.bonus = float(bonus)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if terminated or info.get("is_success") or info.get("collision"):
            return obs, reward, terminated, truncated, info
        base: Any = self.env.unwrapped
        if (
            info["pos_error"] <= base.success_pos_tol
            and info["heading_error"] <= base.success_ang_tol
        ):
            v, w = base.robot.twist()
            if abs(v) < self.rest_v_tol and abs(w) < self.rest_w_tol:
                info = {**info, "is_success": True, "relaxed_success": True}
                return obs, float(reward) + self.bonus, True, truncated, info
        return obs, reward, terminated, truncated, info


class WheeledNavShaping(gym.Wrapper):
    r"""Training only: extra WheeledNav reward terms for the final approach and for collisions.

    ``precision`` weighs a potential-based term :math:`F = \Phi(s') - \Phi(s)` on the true
    pose error (distance ``d``, heading error ``a``):

    .. math::

        \Phi = \tfrac12 e^{-d / s_d} + \tfrac12 e^{-d / (3 s_d)}\, e^{-a / s_a}

    which grows from 0 far away to 1 exactly on the goal pose, steeply over the last few
    centimetres and degrees (``s_d = pos_scale``, ``s_a = ang_scale``), where the env's
    progress and heading terms are nearly flat. Its sum over an episode is
    ``Φ(end) − Φ(start)``, so it pays for ending on the goal pose, not for loitering.
    ``collision_penalty`` is subtracted on a collision on top of the env's own penalty: with
    the env's terms alone an early crash can cost less than the time cost of an episode
    that runs out.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        precision: float = 0.0,
        pos_scale: float = 0.05,
        ang_scale: float = 0.1,
        collision_penalty: float = 0.0,
    ):
        super().__init__(env)
        if pos_scale <= 0 or ang_scale <= 0:
            raise ValueError(f"pos_scale and ang_scale must be > 0, got {pos_scale}, {ang_scale}")
        self.precision = float(precision)
        self.pos_scale = float(pos_scale)
        self.ang_scale = float(ang_scale)
        self.collision_penalty = float(collision_penalty)
        self._phi = 0.0

    def potential(self, pos_error: float, heading_error: float) -> float:
        """``Φ`` of a pose error (m, rad); 1 on the goal pose."""
        d, a = pos_error, abs(heading_error)
        near = math.exp(-d / (3.0 * self.pos_scale)) * math.exp(-a / self.ang_scale)
        return 0.5 * math.exp(-d / self.pos_scale) + 0.5 * near

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._phi = self.potential(info["pos_error"], info["heading_error"])
        return obs, info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        phi = self.potential(info["pos_error"], info["heading_error"])
        extra = self.precision * (phi - self._phi)
        self._phi = phi
        if info.get("collision"):
            extra -= self.collision_penalty
        return obs, float(reward) + extra, terminated, truncated, info


class WheeledNavDockingStarts(gym.Wrapper):
    """Training only: some episodes start next to the goal, facing anywhere.

    Docking — the last centimetres and the turn onto the goal heading — is a few seconds
    at the end of an episode, and a robot that arrives with a large heading error is
    rarer still, so a network sees little of it. With probability ``probability`` a reset
    draws the episode as usual (layout, goal), then starts it again from a pose within
    ``radius`` (m) of the goal position, with a uniform heading and bearing and the
    distance ``radius · u²`` (``u`` uniform): half of these starts lie within ``radius / 4``
    of the goal, where the robot must turn in place onto the goal heading.
    The env keeps obstacles ``body_radius + 0.25`` m clear of its start and goal, so such
    a start is free. Every draw comes from the env's own seeded generator.
    """

    def __init__(self, env: gym.Env[Any, Any], probability: float = 0.3, radius: float = 0.25):
        super().__init__(env)
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability}")
        if not 0.0 < radius <= 0.25:
            raise ValueError(
                f"radius must be in (0, 0.25] m (the obstacle-free margin around the goal), "
                f"got {radius}"
            )
        self.probability = float(probability)
        self.radius = float(radius)

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        if kwargs.get("options"):
            return obs, info  # the caller chose the poses
        rng: np.random.Generator = self.env.unwrapped.np_random
        if rng.random() >= self.probability:
            return obs, info
        goal = np.asarray(info["goal"], dtype=float)
        r = self.radius * rng.random() ** 2
        phi = rng.uniform(-math.pi, math.pi)
        start = np.array(
            [
                goal[0] + r * math.cos(phi),
                goal[1] + r * math.sin(phi),
                rng.uniform(-math.pi, math.pi),
            ]
        )
        return self.env.reset(options={"start": start, "goal": goal})


class ArmObservabilityShaping(gym.Wrapper):
    r"""Training only: ArmCalib reward for measured poses that make the identification
    better conditioned.

    The env pays for a drop of the validation error, which needs an identification, so
    for the first ``min_poses`` attempts every choice of pose earns nothing. This adds the
    potential-based term :math:`w\,(\Phi' - \Phi)` with

    .. math::

        \Phi = \frac{1}{p} \sum_{i=1}^{p} \log_{10}(\sigma_i + \varepsilon)

    over the singular values :math:`\sigma_i` of the column-scaled pair Jacobian of the
    poses measured so far (the O1 observability index in logarithms, the analysis of
    :class:`~realitygap.baselines.arm_policy.PairObservability` on the *nominal* model,
    as a real cell could compute it). Its sum over a campaign is
    :math:`w(\Phi_\text{end} - \Phi_0)`, so it pays for the final pose set, not for an
    order of visits.
    """

    def __init__(
        self,
        env: gym.Env[Any, Any],
        weight: float = 1.0,
        epsilon: float = 1e-2,
        pool_size: int = 200,
    ):
        super().__init__(env)
        from realitygap.baselines.arm_policy import PairObservability

        if not (weight >= 0.0 and epsilon > 0.0 and pool_size >= 10):
            raise ValueError(
                f"weight >= 0, epsilon > 0 and pool_size >= 10 expected, got {weight}, "
                f"{epsilon}, {pool_size}"
            )
        base: Any = env.unwrapped
        if not hasattr(base, "candidate_pool"):
            raise ValueError(
                f"arm_observability_shaping needs ArmCalib-v0, got {type(base).__name__}"
            )
        self.model = PairObservability.from_env(env, int(pool_size))
        self.weight = float(weight)
        self.epsilon = float(epsilon)
        self._q: list[npt.NDArray[np.float64]] = []
        self._phi0 = self.potential(self._q)
        self._phi = self._phi0

    def potential(self, q: Sequence[npt.ArrayLike]) -> float:
        """``Φ`` of the measured joint readings ``q``."""
        sv = self.model.singular_values_of(np.asarray(q).reshape(-1, 6))
        return float(np.mean(np.log10(sv + self.epsilon)))

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(**kwargs)
        self._q = []
        self._phi = self._phi0
        return obs, info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if info.get("outcome") != "ok":
            return obs, reward, terminated, truncated, info  # no new pose: Φ unchanged
        self._q.append(np.asarray(info["q_encoder"], dtype=float))
        phi = self.potential(self._q)
        extra = self.weight * (phi - self._phi)
        self._phi = phi
        return obs, float(reward) + extra, terminated, truncated, info


TRAIN_WRAPPERS: dict[str, Callable[..., gym.Env[Any, Any]]] = {
    "arm_observability_shaping": ArmObservabilityShaping,
    "wheeled_nav_rest_relaxation": WheeledNavRestRelaxation,
    "wheeled_nav_shaping": WheeledNavShaping,
    "wheeled_nav_docking_starts": WheeledNavDockingStarts,
}
"""Training-only wrappers by name (hyperparameter ``train_wrappers``)."""


def check_train_wrappers(specs: Sequence[Mapping[str, Any]]) -> tuple[dict[str, Any], ...]:
    """The training wrapper specs ``[{"name": ..., **params}, ...]`` as a tuple of dicts;
    ``ValueError`` naming the known wrappers for an unknown name."""
    out = tuple(dict(spec) for spec in specs)
    for spec in out:
        if spec.get("name") not in TRAIN_WRAPPERS:
            raise ValueError(
                f"unknown training wrapper {spec.get('name')!r}; known: {', '.join(TRAIN_WRAPPERS)}"
            )
    return out


def apply_train_wrappers(
    env: gym.Env[Any, Any], specs: Sequence[Mapping[str, Any]] | None
) -> gym.Env[Any, Any]:
    """Wrap ``env`` in the training wrappers ``[{"name": ..., **params}, ...]``."""
    for spec in check_train_wrappers(specs or ()):
        params = dict(spec)
        name = params.pop("name")
        env = TRAIN_WRAPPERS[name](env, **params)
    return env


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


@dataclass(frozen=True)
class TrainResult:
    """What a training run produced."""

    model_path: Path
    meta_path: Path
    wall_seconds: float
    timesteps: int
    final_eval: dict[str, float] = field(default_factory=dict)


# --------------------------------------------------------------------------- env factory
def deadband(action: npt.ArrayLike, width: float) -> npt.NDArray[np.float32]:
    r"""A continuous dead band on each action component in ``[-1, 1]``:

    .. math:: a' = \operatorname{sign}(a)\,\max(0, |a| - \delta) / (1 - \delta)

    Commands within ``δ`` of zero become exactly zero (the robot can stop), the full range
    ``[-1, 1]`` is kept. ``width = 0`` is the identity.
    """
    a = np.asarray(action, dtype=np.float32)
    if width <= 0.0:
        return a
    if not width < 1.0:
        raise ValueError(f"action_deadband must be in [0, 1), got {width}")
    mag = np.maximum(np.abs(a) - width, 0.0) / (1.0 - width)
    return (np.sign(a) * mag).astype(np.float32)


def stop_gate(action: npt.ArrayLike, width: float = 0.0) -> npt.NDArray[np.float32]:
    """Map a model action ``(..., n + 1)`` with a stop gate to an env action ``(..., n)``.

    The last component is the gate: where it is positive the env action is zero (stop);
    elsewhere the first ``n`` components pass (through :func:`deadband` of ``width``).
    Stopping is then one decision of the policy instead of ``n`` components that must all
    be near zero at once.
    """
    a = np.asarray(action, dtype=np.float32)
    motion = deadband(a[..., :-1], width)
    return np.where(a[..., -1:] > 0.0, np.float32(0.0), motion).astype(np.float32)


WHEELED_NAV_SCENE_START: int = 12
"""First scan column of a WheeledNav observation; the goal in the robot frame is in
columns 8 and 9."""


def scene_fade(x: npt.ArrayLike, stop: int, radius: float) -> npt.NDArray[np.float32]:
    r"""WheeledNav inputs with the scene columns faded out next to the goal.

    Columns ``12 … stop − 1`` (the scan, then the obstacle memory; 1 means nothing seen
    there) become :math:`1 - (1 - x) \min(1, \rho / R)`, with :math:`\rho` the distance to
    the goal in the estimated robot frame (columns 8, 9) and :math:`R` ``radius``.

    The env keeps obstacles ``body_radius + 0.25`` m clear of the goal, so the last
    ``R`` (≤ 0.25 m) of a route never depend on them — but a network that reads the scene
    there can, and does, learn a turn bias that depends on how the obstacles around the goal
    happen to lie, which a few degrees off the goal heading cancels the turn that is left.
    Faded, every goal is approached through the same empty scene. The fade is continuous,
    and the identity beyond ``R``.
    """
    out = np.array(x, dtype=np.float32, copy=True)
    rho = np.hypot(out[..., 8].astype(np.float64), out[..., 9].astype(np.float64))
    keep = np.minimum(1.0, rho / float(radius)).astype(np.float32)[..., None]
    scene = out[..., WHEELED_NAV_SCENE_START:stop]
    out[..., WHEELED_NAV_SCENE_START:stop] = np.where(keep < 1.0, 1.0 - (1.0 - scene) * keep, scene)
    return out


@dataclass(frozen=True)
class PolicyIO:
    """What a learned policy does around its network, identical in training and use.

    Parameters
    ----------
    obs_features : name of a feature map in :data:`OBS_FEATURES` appended to the observation.
    action_deadband : width of :func:`deadband` on each action component.
    action_stop_gate : the network has one more action output, a stop gate (:func:`stop_gate`).
    obs_memory : an obstacle memory (:class:`~realitygap.baselines.episode_features.ObstacleMemory`)
        whose sector ranges are appended to the env observation before the feature map;
        a spec completed with the env's scan geometry by :meth:`for_env`.
    obs_rest_timer : a column for how long the robot has stood still
        (:class:`~realitygap.baselines.episode_features.RestTimer`, ``{"horizon_steps"}``),
        after the memory.
    obs_scene_fade : WheeledNav only: radius (m) within which the scan and the memory fade
        to "nothing seen" as the goal nears (:func:`scene_fade`), before the feature map;
        0: off.

    Memory and timer are the policy's episode state (:meth:`new_episode_features`).
    """

    obs_features: str | None = None
    action_deadband: float = 0.0
    action_stop_gate: bool = False
    obs_memory: Mapping[str, Any] | None = None
    obs_rest_timer: Mapping[str, Any] | None = None
    obs_scene_fade: float = 0.0

    def __post_init__(self) -> None:
        obs_feature_fn(self.obs_features)
        if not 0.0 <= self.action_deadband < 1.0:
            raise ValueError(f"action_deadband must be in [0, 1), got {self.action_deadband}")
        if not (math.isfinite(self.obs_scene_fade) and 0.0 <= self.obs_scene_fade <= 0.25):
            raise ValueError(
                "obs_scene_fade must be a radius in [0, 0.25] m (the obstacle-free margin "
                f"around the goal), got {self.obs_scene_fade!r}"
            )
        if self.complete:
            self.new_episode_features()  # validates the specs

    @property
    def complete(self) -> bool:
        """Whether the memory spec holds the env's scan geometry (see :meth:`for_env`)."""
        return not self.obs_memory or "scan_angles" in self.obs_memory

    @property
    def has_episode_features(self) -> bool:
        return bool(self.obs_memory or self.obs_rest_timer)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PolicyIO:
        """From hyperparameters or metadata (missing keys: identity)."""
        memory, timer = data.get("obs_memory"), data.get("obs_rest_timer")
        return cls(
            obs_features=data.get("obs_features") or None,
            action_deadband=float(data.get("action_deadband") or 0.0),
            action_stop_gate=bool(data.get("action_stop_gate", False)),
            obs_memory=dict(memory) if memory else None,
            obs_rest_timer=dict(timer) if timer else None,
            obs_scene_fade=float(data.get("obs_scene_fade") or 0.0),
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "obs_features": self.obs_features,
            "action_deadband": self.action_deadband,
            "action_stop_gate": self.action_stop_gate,
            "obs_memory": dict(self.obs_memory) if self.obs_memory else None,
            "obs_rest_timer": dict(self.obs_rest_timer) if self.obs_rest_timer else None,
            "obs_scene_fade": self.obs_scene_fade,
        }

    def for_env(self, env: gym.Env[Any, Any]) -> PolicyIO:
        """This I/O with the memory spec completed from ``env``'s scan geometry."""
        self._check_scene_fade(env)
        if self.complete:
            return self
        from realitygap.baselines.episode_features import memory_spec_for_env

        return replace(self, obs_memory=memory_spec_for_env(env, self.obs_memory or {}))

    def _check_scene_fade(self, env: gym.Env[Any, Any]) -> None:
        if self.obs_scene_fade > 0.0 and not hasattr(env.unwrapped, "scan_angles"):
            raise ValueError(
                f"obs_scene_fade fades a WheeledNav scan; {type(env.unwrapped).__name__} has none"
            )

    def fade_scene(self, x: npt.NDArray[np.float32]) -> npt.NDArray[np.float32]:
        """:func:`scene_fade` of an observation with this I/O's episode features appended
        (the rest timer, last, is not scene); ``x`` itself without a fade radius."""
        if self.obs_scene_fade <= 0.0:
            return x
        return scene_fade(x, x.shape[-1] - int(bool(self.obs_rest_timer)), self.obs_scene_fade)

    def mirror(
        self, env: gym.Env[Any, Any]
    ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.float32], npt.NDArray[np.float32]]:
        """The left–right mirror of this I/O's network inputs and outputs in ``env``:
        ``(perm, sign, action_sign)`` with mirrored input ``x[..., perm] * sign`` and
        mirrored network action ``a * action_sign``, from the feature map's entry in
        :data:`OBS_MIRRORS`; ``ValueError`` for a feature map without one."""
        builder = OBS_MIRRORS.get(self.obs_features or "")
        if builder is None:
            raise ValueError(
                f"obs_features {self.obs_features!r} has no mirror; feature maps with one: "
                f"{', '.join(OBS_MIRRORS)} (every input in the robot frame)"
            )
        return builder(self, env)

    def new_episode_features(self) -> Any:
        """Fresh episode features of one env (``None`` without memory and timer)."""
        if not self.has_episode_features:
            return None
        from realitygap.baselines.episode_features import EpisodeFeatures

        if not self.complete:
            raise ValueError("obs_memory lacks the scan geometry; complete it with for_env(env)")
        return EpisodeFeatures(self.obs_memory, self.obs_rest_timer)

    def observation(
        self, obs: npt.ArrayLike, states: Sequence[Any] | None = None
    ) -> npt.NDArray[np.float32]:
        """Env observation → network input (before normalisation); with episode features,
        ``states`` holds one :meth:`new_episode_features` per row of the batch, updated here."""
        x = np.asarray(obs, dtype=np.float32)
        if self.has_episode_features:
            if states is None:
                raise ValueError("a policy with obs_memory needs its episode features")
            rows = x.reshape(-1, x.shape[-1])
            if len(states) != len(rows):
                raise ValueError(f"{len(rows)} observations but {len(states)} episode states")
            feats = np.stack([st.update(r) for st, r in zip(states, rows)])
            x = np.concatenate([rows, feats], axis=-1).reshape(*x.shape[:-1], -1)
        x = self.fade_scene(x)
        fn = obs_feature_fn(self.obs_features)
        return fn(x) if fn is not None else x

    def action(self, model_action: npt.ArrayLike) -> npt.NDArray[np.float32]:
        """Network output → env action."""
        if self.action_stop_gate:
            return stop_gate(model_action, self.action_deadband)
        return deadband(model_action, self.action_deadband)

    def wrap(self, env: gym.Env[Any, Any]) -> gym.Env[Any, Any]:
        """The training env as the network sees it."""
        if self.action_deadband > 0.0 or self.action_stop_gate:
            env = _ActionMap(env, self)
        if self.has_episode_features:
            from realitygap.baselines.episode_features import EpisodeFeaturesWrapper

            env = EpisodeFeaturesWrapper(env, self.for_env(env).new_episode_features())
        if self.obs_scene_fade > 0.0:
            self._check_scene_fade(env)
            env = _SceneFade(env, self)
        if self.obs_features:
            env = ObsFeatures(env, self.obs_features)
        return env


class _SceneFade(gym.ObservationWrapper):
    """Training side of :meth:`PolicyIO.fade_scene` in :meth:`PolicyIO.observation`."""

    def __init__(self, env: gym.Env[Any, Any], io: PolicyIO):
        super().__init__(env)
        self.io = io

    def observation(self, observation: Any) -> Any:
        return self.io.fade_scene(np.asarray(observation, dtype=np.float32))


class _ActionMap(gym.ActionWrapper):
    """Training side of :meth:`PolicyIO.action` (dead band, stop gate)."""

    def __init__(self, env: gym.Env[Any, Any], io: PolicyIO):
        super().__init__(env)
        self.io = io
        space = env.action_space
        assert isinstance(space, gym.spaces.Box)
        if io.action_stop_gate:
            self.action_space = gym.spaces.Box(
                np.append(space.low, -1.0).astype(np.float32),
                np.append(space.high, 1.0).astype(np.float32),
                dtype=np.float32,
            )

    def action(self, action: Any) -> Any:
        return self.io.action(action)


def _wheeled_nav_egocentric_io_mirror(
    io: PolicyIO, env: gym.Env[Any, Any]
) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.float32], npt.NDArray[np.float32]]:
    """:meth:`PolicyIO.mirror` of WheeledNav with :func:`wheeled_nav_egocentric_features`:
    the input map of :func:`wheeled_nav_egocentric_mirror` for ``env``'s scan and ``io``'s
    episode features; the turn command changes sign, speed and stop gate do not."""
    base: Any = env.unwrapped
    if not hasattr(base, "scan_angles"):
        raise ValueError(f"a WheeledNav mirror needs a WheeledNav env, got {type(base).__name__}")
    angles = np.asarray(base.scan_angles, dtype=float)
    if not np.allclose(angles, -angles[::-1], atol=1e-9):
        raise ValueError(
            "a mirror needs scan bearings symmetric about the robot's axis; this camera "
            f"is mounted at yaw {float(np.mean(angles)):.4f} rad"
        )
    n_sectors = int((io.for_env(env).obs_memory or {}).get("n_sectors", 0))
    perm, sign = wheeled_nav_egocentric_mirror(
        angles.size, n_sectors, rest_timer=bool(io.obs_rest_timer)
    )
    action_sign = np.array([1.0, -1.0] + [1.0] * int(io.action_stop_gate), np.float32)
    return perm, sign, action_sign


OBS_MIRRORS: dict[
    str,
    Callable[
        [PolicyIO, gym.Env[Any, Any]],
        tuple[npt.NDArray[np.intp], npt.NDArray[np.float32], npt.NDArray[np.float32]],
    ],
] = {"wheeled_nav_egocentric": _wheeled_nav_egocentric_io_mirror}
"""Feature maps whose network inputs have a left–right mirror (:meth:`PolicyIO.mirror`)."""


def make_env_fn(
    env_id: str,
    env_kwargs: Mapping[str, Any],
    seed: int,
    io: PolicyIO | None = None,
    max_episode_steps: int | None = None,
    train_wrappers: Sequence[Mapping[str, Any]] = (),
) -> Callable[[], gym.Env[Any, Any]]:
    """A picklable factory of one seeded training env (for ``SubprocVecEnv``)."""
    return _EnvFactory(
        env_id, dict(env_kwargs), seed, io or PolicyIO(), max_episode_steps, tuple(train_wrappers)
    )


@dataclass(frozen=True)
class _EnvFactory:
    env_id: str
    env_kwargs: dict[str, Any]
    seed: int
    io: PolicyIO = field(default_factory=PolicyIO)
    max_episode_steps: int | None = None
    train_wrappers: tuple[Mapping[str, Any], ...] = ()

    def __call__(self) -> gym.Env[Any, Any]:
        from stable_baselines3.common.monitor import Monitor

        import realitygap  # noqa: F401  (registers the ids in a fresh worker)

        env = gym.make(self.env_id, max_episode_steps=self.max_episode_steps, **self.env_kwargs)
        env = self.io.wrap(apply_train_wrappers(env, self.train_wrappers))
        env = AttributeSetter(Monitor(env))
        env.reset(seed=self.seed)
        env.action_space.seed(self.seed)
        return env


def make_vec_env(
    env_id: str,
    env_kwargs: Mapping[str, Any],
    n_envs: int,
    seed: int,
    vec_env: str = "subproc",
    io: PolicyIO | None = None,
    max_episode_steps: int | None = None,
    train_wrappers: Sequence[Mapping[str, Any]] = (),
) -> Any:
    """A seeded vectorised env: worker ``i`` is seeded ``seed + i``."""
    require_sb3()
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    if vec_env not in ("subproc", "dummy"):
        raise ValueError(f"vec_env must be 'subproc' or 'dummy', got {vec_env!r}")
    fns = [
        make_env_fn(env_id, env_kwargs, seed + i, io, max_episode_steps, train_wrappers)
        for i in range(n_envs)
    ]
    venv: SubprocVecEnv | DummyVecEnv
    if vec_env == "subproc" and n_envs > 1:
        venv = SubprocVecEnv(fns, start_method="forkserver")
    else:
        venv = DummyVecEnv(fns)
    venv.seed(seed)
    return venv


def measure_vec_env_speed(
    env_id: str,
    env_kwargs: Mapping[str, Any] | None = None,
    n_envs: int = 2,
    steps: int = 2000,
    seed: int = 0,
) -> dict[str, float]:
    """Env steps per second of ``SubprocVecEnv`` and ``DummyVecEnv`` with random actions."""
    out = {}
    for kind in ("dummy", "subproc"):
        venv = make_vec_env(env_id, env_kwargs or {}, n_envs, seed, kind)
        rng = np.random.default_rng(seed)
        venv.reset()
        low, high = venv.action_space.low, venv.action_space.high
        n_iter = max(1, steps // n_envs)
        t0 = time.perf_counter()
        for _ in range(n_iter):
            venv.step(rng.uniform(low, high, size=(n_envs, *venv.action_space.shape)))
        out[f"{kind}_steps_per_s"] = n_iter * n_envs / (time.perf_counter() - t0)
        venv.close()
    return out


# --------------------------------------------------------------------------- callbacks
def _make_callback(
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
    from stable_baselines3.common.callbacks import BaseCallback

    class _Recorder(BaseCallback):
        """Learning curve, curriculum, evaluations, checkpoints, progress lines."""

        def __init__(self) -> None:
            super().__init__(verbose=0)
            self.t_start = time.perf_counter()
            self.last_print = self.t_start
            self.recent: deque[bool] = deque(maxlen=curriculum.window if curriculum else 100)
            self.stage = initial_stage
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
            self.ep_csv.writerow(
                [
                    "timesteps",
                    "wall_s",
                    "return",
                    "length",
                    "success",
                    "pos_error",
                    "collision",
                    "stage",
                ]
            )

        def _on_training_start(self) -> None:
            self.start_steps = self.num_timesteps
            if cfg.checkpoint_every:
                self.next_ckpt = self.num_timesteps + cfg.checkpoint_every
            if cfg.eval_every:
                self.next_eval = self.num_timesteps + cfg.eval_every
            if curriculum is not None:
                self._apply_stage()

        def _apply_stage(self) -> None:
            assert curriculum is not None
            values = curriculum.values(self.stage)
            self.training_env.env_method("set_env_attrs", values)
            self.recent.clear()
            self.stage_start = self.num_timesteps

        def _promote(self, why: str) -> None:
            assert curriculum is not None
            self.stage += 1
            self._apply_stage()
            vals = ", ".join(f"{k}={v:.3g}" for k, v in curriculum.values(self.stage).items())
            print(
                f"[{time.strftime('%H:%M:%S')}] curriculum stage {self.stage}/"
                f"{curriculum.n_stages} at {self.num_timesteps} steps ({why}): {vals}",
                flush=True,
            )

        def _on_rollout_end(self) -> None:
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
            if curriculum is not None:
                self._update_curriculum()
            if self.num_timesteps >= self.next_ckpt:
                self.next_ckpt += cfg.checkpoint_every
                save_fn(out_dir / "checkpoints" / f"model_{self.num_timesteps}_steps.zip")
            if self.num_timesteps >= self.next_eval:
                self.next_eval += cfg.eval_every
                self._evaluate()
            now = time.perf_counter()
            if now - self.last_print >= cfg.progress_every_s:
                self.last_print = now
                self._progress(now)
            return True

        def _update_curriculum(self) -> None:
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
            elapsed = now - self.t_start
            done = self.num_timesteps - self.start_steps
            rate = done / max(elapsed, 1e-9)
            eta = (total - done) / max(rate, 1e-9)
            rec = f"{np.mean(self.recent):.2f}" if self.recent else "-"
            extra = ""
            if curriculum is not None:
                vals = curriculum.values(self.stage)
                extra = " tolerances " + ", ".join(f"{k}={v:.3g}" for k, v in vals.items())
            print(
                f"[{time.strftime('%H:%M:%S')}] {cfg.algo} {env_slug(cfg.env_id)} seed {cfg.seed}: "
                f"{done}/{total} steps ({100 * done / total:.0f} %, {self.num_timesteps} in all), "
                f"{rate:.0f} steps/s, ETA {eta / 60:.1f} min, {self.episodes} episodes, "
                f"recent success {rec}{extra}",
                flush=True,
            )
            self.ep_file.flush()

        def _evaluate(self) -> None:
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
            print(
                f"[{time.strftime('%H:%M:%S')}] eval at {self.num_timesteps} steps: strict success "
                f"{stats['success']:.2f}, within 10 cm {stats['reached_10cm']:.2f}, collisions "
                f"{stats['collision']:.2f}, mean return {stats['return']:.2f}",
                flush=True,
            )

        def _on_training_end(self) -> None:
            self.ep_file.close()

    return _Recorder()


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


# --------------------------------------------------------------------------- observation normalisation
@dataclass(frozen=True)
class ObsNormalizer:
    """``clip((obs - mean) / sqrt(var + eps), -clip, clip)``, stored as plain JSON."""

    mean: npt.NDArray[np.float64]
    var: npt.NDArray[np.float64]
    clip: float = 10.0
    eps: float = 1e-8

    def __call__(self, obs: npt.ArrayLike) -> npt.NDArray[np.float32]:
        x = (np.asarray(obs, dtype=np.float64) - self.mean) / np.sqrt(self.var + self.eps)
        return np.clip(x, -self.clip, self.clip).astype(np.float32)

    def to_dict(self) -> dict[str, Any]:
        return {
            "mean": self.mean.tolist(),
            "var": self.var.tolist(),
            "clip": self.clip,
            "eps": self.eps,
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ObsNormalizer:
        return cls(
            np.asarray(data["mean"], dtype=float),
            np.asarray(data["var"], dtype=float),
            float(data.get("clip", 10.0)),
            float(data.get("eps", 1e-8)),
        )


# --------------------------------------------------------------------------- training
def train(cfg: TrainConfig) -> TrainResult:
    """Train ``cfg.algo`` on ``cfg.env_id``; see the module docstring for what is written.

    With ``cfg.init_model`` the run continues a saved model (its step count, observation
    normalisation and curriculum stage), so a long training can be split into shorter runs.

    Returns
    -------
    TrainResult
        Paths of the model and its metadata, wall-clock seconds, steps, final evaluation.
    """
    env_id = check_env_id(cfg.env_id)
    algo = check_algo(cfg.algo)
    cls = algo_class(algo)
    import torch

    hp = dict(cfg.hyperparams) if cfg.hyperparams is not None else load_hyperparams(algo, env_id)
    hp = {k: v for k, v in hp.items() if not k.startswith("_")}
    budget = int(hp["n_timesteps"])
    total = int(cfg.total_timesteps if cfg.total_timesteps is not None else budget)
    n_envs = int(cfg.n_envs if cfg.n_envs is not None else hp.get("n_envs", 1))
    vec_kind = str(cfg.vec_env if cfg.vec_env is not None else hp.get("vec_env", "dummy"))
    env_kwargs = dict(hp.get("env_kwargs", {}))
    curriculum = Curriculum.from_dict(hp["curriculum"]) if hp.get("curriculum") else None
    normalize = dict(hp.get("normalize", {}) or {})
    io = PolicyIO.from_dict(hp)  # unknown feature names fail before any env starts
    train_wrappers = check_train_wrappers(hp.get("train_wrappers", ()) or ())
    probe = gym.make(env_id, **env_kwargs)
    io = io.for_env(probe)
    raw_obs_space, raw_action_space = probe.observation_space, probe.action_space
    env_spaces = {
        "env_observation_space": _space_summary(raw_obs_space),
        "env_action_space": _space_summary(raw_action_space),
    }
    probe.close()
    algo_kwargs = _resolve_policy_kwargs({k: v for k, v in hp.items() if k not in _TRAIN_KEYS})

    out_dir = Path(cfg.out_dir)
    (out_dir / "checkpoints").mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(1)
    torch.manual_seed(cfg.seed)

    max_steps = hp.get("train_max_episode_steps")
    venv = make_vec_env(
        env_id,
        env_kwargs,
        n_envs,
        cfg.seed,
        vec_kind,
        io,
        None if max_steps is None else int(max_steps),
        train_wrappers,
    )
    init_meta: dict[str, Any] = {}
    if cfg.init_model is not None:
        init_meta = read_policy_meta(cfg.init_model)
        if PolicyIO.from_dict(init_meta) != io:
            raise ValueError(
                f"{cfg.init_model} was trained with {PolicyIO.from_dict(init_meta)}, the "
                f"hyperparameters say {io}; continue with the same settings"
            )
        check_policy_matches(init_meta, env_id, raw_obs_space, raw_action_space, cfg.init_model)
    if normalize:
        from stable_baselines3.common.vec_env import VecNormalize

        venv = VecNormalize(
            venv,
            norm_obs=bool(normalize.get("obs", True)),
            norm_reward=bool(normalize.get("reward", False)),
            gamma=float(algo_kwargs.get("gamma", 0.99)),
        )
        if init_meta.get("obs_normalizer"):
            prev = ObsNormalizer.from_dict(init_meta["obs_normalizer"])
            rms = venv.obs_rms
            assert not isinstance(rms, dict), "Box observations have one running mean"
            rms.mean, rms.var = prev.mean.copy(), prev.var.copy()
            rms.count = float(init_meta.get("timesteps", 1e4))
    demo_rows: list[dict[str, float]] = list(init_meta.get("demonstrations", []) or [])
    if cfg.init_model is not None:
        if Path(cfg.init_model).suffix == ".pth":
            model = _model_from_weights(cls, hp, venv, cfg, init_meta, algo_kwargs)
        else:
            model = cls.load(cfg.init_model, env=venv, device="cpu")
            model.set_random_seed(cfg.seed)
            _continue_with(model, algo_kwargs)
        if init_meta.get("obs_norm_frozen") and normalize:
            venv.training = False
    else:
        model = cls(
            hp.get("policy", "MlpPolicy"),
            venv,
            seed=cfg.seed,
            verbose=0,
            device="cpu",
            **algo_kwargs,
        )
        if hp.get("demonstrations"):
            demo_rows = _pretrain_from_demonstrations(
                cfg,
                hp,
                model,
                venv,
                env_kwargs,
                io,
                train_wrappers,
                max_steps,
                algo_kwargs,
                env_spaces,
            )
            write_csv_atomic(out_dir / "demonstrations.csv", demo_rows)

    def normalizer() -> ObsNormalizer | None:
        if not normalize or not getattr(venv, "norm_obs", False):
            return None
        return ObsNormalizer(
            np.asarray(venv.obs_rms.mean, float),
            np.asarray(venv.obs_rms.var, float),
            float(venv.clip_obs),
        )

    t0 = time.perf_counter()
    prior_wall = float(init_meta.get("train_wall_seconds", 0.0))

    def extra() -> dict[str, Any]:
        return {
            **io.to_dict(),
            **env_spaces,
            "curriculum_stage": callback.stage,
            "init_model": str(cfg.init_model) if cfg.init_model is not None else None,
            "obs_norm_frozen": bool(normalize) and not getattr(venv, "training", True),
            "demonstrations": demo_rows,
        }

    def save(path: Path) -> Path:
        return save_policy(
            model,
            path,
            env_id,
            env_kwargs,
            algo,
            cfg.seed,
            model.num_timesteps,
            prior_wall + time.perf_counter() - t0,
            hp,
            normalizer(),
            extra(),
        )

    def current_policy() -> LearnedPolicy:
        meta: dict[str, Any] = {"obs_normalizer": None, **io.to_dict(), **env_spaces}
        norm = normalizer()
        if norm is not None:
            meta["obs_normalizer"] = norm.to_dict()
        return LearnedPolicy(model, meta, name=algo)

    callback = _make_callback(
        cfg,
        total,
        budget,
        curriculum,
        int(init_meta.get("curriculum_stage", 0)),
        env_kwargs,
        out_dir,
        save,
        current_policy,
        append=cfg.init_model is not None and (out_dir / "episodes.csv").is_file(),
        log_std_max=(
            (float(hp["log_std_max"][0]), float(hp["log_std_max"][1]))
            if hp.get("log_std_max")
            else None
        ),
        train_wrappers=train_wrappers,
    )
    print(
        f"[{time.strftime('%H:%M:%S')}] training {algo} on {env_id}: {total} steps "
        f"(from {model.num_timesteps}), {n_envs} x {vec_kind} envs, seed {cfg.seed} -> {out_dir}",
        flush=True,
    )
    try:
        model.learn(
            total_timesteps=total,
            callback=callback,
            reset_num_timesteps=cfg.init_model is None,
        )
    finally:
        venv.close()
    wall = time.perf_counter() - t0
    model_path = out_dir / "model.zip"
    meta_path = save(model_path)
    final = (
        evaluate_model(
            current_policy(), env_id, env_kwargs, cfg.eval_episodes, cfg.seed + EVAL_SEED_OFFSET
        )
        if cfg.eval_episodes > 0
        else {}
    )
    meta = json.loads(meta_path.read_text(encoding="utf-8"))
    meta["final_eval"] = final
    write_text_atomic(meta_path, json.dumps(meta, indent=2) + "\n")
    plot_learning_curve(out_dir)
    print(f"[{time.strftime('%H:%M:%S')}] done in {wall / 60:.1f} min: {final}", flush=True)
    return TrainResult(model_path, meta_path, prior_wall + wall, int(model.num_timesteps), final)


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
    if init_meta.get("policy_kwargs", {}) != _jsonable(hp.get("policy_kwargs", {})):
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
        log=lambda line: print(line, flush=True),
    )
    rms = venv.obs_rms
    rms.mean, rms.var = norm.mean.copy(), norm.var.copy()
    venv.training = False
    return rows


def _resolve_policy_kwargs(kwargs: dict[str, Any]) -> dict[str, Any]:
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


# --------------------------------------------------------------------------- save / load
def _space_summary(space: gym.Space[Any]) -> dict[str, Any]:
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
    path = write_via_temp(path, model.save, ".zip")
    import stable_baselines3

    meta = {
        "format": "realitygap-policy/1",
        "env_id": env_id,
        "env_kwargs": _jsonable(dict(env_kwargs)),
        "algo": algo,
        "seed": int(seed),
        "timesteps": int(timesteps),
        "train_wall_seconds": float(wall_seconds),
        "observation_space": _space_summary(model.observation_space),
        "action_space": _space_summary(model.action_space),
        "obs_normalizer": obs_normalizer.to_dict() if obs_normalizer is not None else None,
        "hyperparams": _jsonable(dict(hyperparams or {})),
        "stable_baselines3": stable_baselines3.__version__,
        **_jsonable(dict(extra or {})),
    }
    meta_path = path.with_suffix(".json")
    write_text_atomic(meta_path, json.dumps(meta, indent=2) + "\n")
    return meta_path


def read_policy_meta(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The JSON metadata of a saved policy (``model.zip`` → ``model.json``), without unpickling.

    Falls back to the readable part of the SB3 zip's ``data`` entry when the metadata
    file is missing.
    """
    import zipfile

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no policy file {path}")
    meta_path = path.with_suffix(".json")
    if meta_path.is_file():
        return dict(json.loads(meta_path.read_text(encoding="utf-8")))
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data").decode())
    except (zipfile.BadZipFile, KeyError) as exc:
        raise ValueError(
            f"{path} is not a stable-baselines3 policy file (zip with 'data')"
        ) from exc
    obs = data.get("observation_space", {})
    act = data.get("action_space", {})
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
        self._episode_states: list[Any] = []

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
        obs = self.io.observation(obs, self._episode_features(obs, episode_start))
        if self.obs_normalizer is not None:
            obs = self.obs_normalizer(obs)
        action, state = self.model.predict(
            obs, state=state, episode_start=episode_start, deterministic=deterministic
        )
        return self.io.action(action), state

    def _episode_features(
        self, obs: npt.NDArray[np.float32], episode_start: npt.ArrayLike | None
    ) -> list[Any] | None:
        """The episode features (obstacle memory, rest timer) of each env of the batch, reset where an
        episode starts (a policy without them keeps none). Without ``episode_start`` a call
        with a batch of another size starts new episodes."""
        if not self.io.has_episode_features:
            return None
        from realitygap.baselines.common import episode_starts

        n = (
            1
            if obs.ndim == len(self.obs_shape)
            else int(np.prod(obs.shape[: -len(self.obs_shape)]))
        )
        if len(self._episode_states) != n:
            self._episode_states = [self.io.new_episode_features() for _ in range(n)]
        else:
            for state, start in zip(self._episode_states, episode_starts(episode_start, n)):
                if start:
                    state.reset()
        return self._episode_states


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
        "policy_kwargs": _jsonable(policy_kwargs),
        "model_observation_space": _box_to_dict(model.observation_space),
        "model_action_space": _box_to_dict(model.action_space),
    }
    weights = {k: v.detach().cpu() for k, v in state.items()}
    write_via_temp(dest, lambda tmp: torch.save(weights, tmp), ".pth")
    write_text_atomic(dest.with_suffix(".json"), json.dumps(out_meta, indent=2) + "\n")
    return dest


def _policy_from_weights(path: Path, meta: Mapping[str, Any], algo: str) -> Any:
    """Rebuild the SB3 policy network of exported weights (no unpickling)."""
    require_sb3()
    import torch

    if meta.get("format") != "realitygap-policy-weights/1":
        raise ValueError(f"{path.with_suffix('.json')} is not the metadata of exported weights")
    obs_space = _box_from_dict(meta["model_observation_space"])
    act_space = _box_from_dict(meta["model_action_space"])
    kwargs = _resolve_policy_kwargs({"policy_kwargs": meta.get("policy_kwargs", {})}).get(
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
def _jsonable(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, (str, int, float, bool)) or value is None:
        return value
    return str(value)


def publish_file(tmp: str | os.PathLike[str], path: str | os.PathLike[str]) -> None:
    """Give the finished temporary file ``tmp`` the usual permissions (``0o666`` minus the
    umask; ``mkstemp`` makes it private) and rename it onto ``path`` atomically."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    os.replace(tmp, path)


def write_via_temp(
    path: str | os.PathLike[str], write: Callable[[str], Any], suffix: str = ""
) -> Path:
    """Let ``write(tmp)`` write a temporary file beside ``path``, then rename it onto ``path``.

    For writers that take a file name (SB3 ``save``, ``torch.save``, ``savefig``): a crash
    never leaves a half-written file. Returns ``path``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        publish_file(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def write_text_atomic(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file in the same folder and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        publish_file(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


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
    write_text_atomic(path, buf.getvalue())


def _csv_cell(value: Any) -> Any:
    if isinstance(value, float):
        return f"{value:.6g}"
    return value


def read_csv(path: str | os.PathLike[str]) -> list[dict[str, str]]:
    """Rows of a CSV file as dicts of strings."""
    with Path(path).open(newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def learning_curve_files(
    run_dir: str | os.PathLike[str], label: str | None = None
) -> tuple[str, Path | None, Path | None]:
    """``(label, episodes.csv, eval.csv)`` of a training folder (missing files as ``None``)."""
    d = Path(run_dir)
    ep, ev = d / "episodes.csv", d / "eval.csv"
    return (label or d.name, ep if ep.is_file() else None, ev if ev.is_file() else None)


def plot_learning_curve(run_dir: str | os.PathLike[str], window: int = 100) -> Path | None:
    """Plot one training folder's learning curve to ``<run_dir>/learning_curve.png``."""
    d = Path(run_dir)
    return plot_learning_curves([learning_curve_files(d)], d / "learning_curve.png", window)


def plot_learning_curves(
    curves: Sequence[tuple[str, Path | None, Path | None]],
    out: str | os.PathLike[str],
    window: int = 100,
) -> Path | None:
    """Plot learning curves: training success and return (rolling mean over ``window``
    episodes) and the strict / within-10-cm success of the evaluations.

    ``curves`` holds ``(label, episodes_csv, eval_csv)`` per run. Returns the PNG path, or
    ``None`` when matplotlib is not installed.
    """
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    out_path = Path(out)
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    for label, ep, ev in curves:
        if ep is not None and Path(ep).is_file():
            rows = read_csv(ep)
            if rows:
                steps = np.array([float(r["timesteps"]) for r in rows])
                succ = np.array([float(r["success"]) for r in rows])
                ret = np.array([float(r["return"]) for r in rows])
                k = max(1, min(window, len(rows)))
                kernel = np.ones(k) / k
                axes[0].plot(
                    steps[k - 1 :],
                    np.convolve(succ, kernel, "valid"),
                    label=f"{label}: training (curriculum tolerances)",
                )
                axes[1].plot(steps[k - 1 :], np.convolve(ret, kernel, "valid"), label=label)
        if ev is not None and Path(ev).is_file():
            rows = read_csv(ev)
            if rows:
                steps = np.array([float(r["timesteps"]) for r in rows])
                axes[0].plot(
                    steps, [float(r["success"]) for r in rows], "o-", label=f"{label}: eval strict"
                )
                axes[0].plot(
                    steps,
                    [float(r["reached_10cm"]) for r in rows],
                    "s--",
                    label=f"{label}: eval within 10 cm",
                )
    axes[0].set_xlabel("env steps")
    axes[0].set_ylabel("success rate")
    axes[0].set_ylim(-0.02, 1.02)
    axes[1].set_xlabel("env steps")
    axes[1].set_ylabel(f"episode return (rolling {window})")
    for ax in axes:
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7)
    fig.tight_layout()
    try:
        return write_via_temp(out_path, lambda tmp: fig.savefig(tmp, dpi=110), ".png")
    finally:
        plt.close(fig)


def ship_policy(run_dir: str | os.PathLike[str], env_id: str, algo: str) -> Path:
    """Export a training folder's model into :data:`POLICIES_DIR` as ``<env>_<algo>.pth`` /
    ``.json`` (:func:`export_policy`), with its learning curves (``.episodes.csv``,
    ``.eval.csv``). The folder's ``model.zip`` is loaded with SB3 (it must be your own)."""
    import shutil

    src = Path(run_dir)
    algo = check_algo(algo)
    meta = read_policy_meta(src / "model.zip")
    if meta.get("env_id") not in (None, env_id):
        raise ValueError(f"{src / 'model.zip'} was trained for {meta.get('env_id')!r}")
    model = algo_class(algo).load(src / "model.zip", device="cpu")
    dest = export_policy(model, meta, POLICIES_DIR / f"{env_slug(env_id)}_{algo}.pth")
    for name, target in (
        ("episodes.csv", dest.with_suffix(".episodes.csv")),
        ("eval.csv", dest.with_suffix(".eval.csv")),
        ("demonstrations.csv", dest.with_suffix(".demonstrations.csv")),
    ):
        if (src / name).is_file():
            tmp = target.with_name(f".{target.name}.tmp")
            shutil.copyfile(src / name, tmp)
            os.replace(tmp, target)
    return dest
