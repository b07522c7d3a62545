"""One card per environment id: what the package knows about each env, in one place.

A card names the env's entry point and time limit (read by :func:`gymnasium.register`),
the robot it drives, its sensor-fidelity modes, its classical baseline and experts,
the metrics the benchmark reports for it, its default reality and the schema of the
``info`` dict its ``reset`` and ``step`` return. Factories are given as import paths
(``"package.module:attribute"``, resolved by :func:`load_object`), so reading a card
imports neither PyBullet nor torch.
"""

from __future__ import annotations

import difflib
import importlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from realitygap.core.checks import UnknownNameError

__all__ = ["ENV_CARDS", "EnvCard", "InfoKey", "card_for", "load_object"]


@dataclass(frozen=True)
class InfoKey:
    """One entry of an env's ``info`` dict.

    Attributes
    ----------
    description : what the value is, with its unit.
    shape : ``numpy.shape`` of the value; ``()`` for a scalar, ``None`` when not an array
        (a string, a dict, or a value that may be ``None``).
    """

    description: str
    shape: tuple[int, ...] | None = ()


@dataclass(frozen=True)
class EnvCard:
    """Everything the package knows about one environment id.

    Attributes
    ----------
    env_id : the Gymnasium id.
    entry_point : ``"module:Class"`` of the env.
    max_episode_steps : time limit given to :func:`gymnasium.register`.
    robot : robot kind (see ``Effect.robot``); reality profiles are per robot.
    sensor_modes : the env's ``sensor_mode`` value for each fidelity mode of the
        benchmark (``"fast"``, ``"image"``).
    classical_policy : import path of a factory ``f(env) -> policy`` of the classical
        baseline (built from the env's nominal parameters).
    experts : expert name → import path of a factory ``f(env) -> policy`` that the
        imitation learning of :mod:`realitygap.baselines.imitation` can label with.
    metrics : scalar ``info`` entries at the end of an episode that the benchmark
        reports for this env, beside the common ones.
    default_reality : import path of a function returning the env's default
        ``Reality`` when the env's default cell is already "real"; ``None`` when the
        default is the nominal robot.
    info : the ``info`` schema: key → :class:`InfoKey`, the keys every ``reset`` and
        ``step`` return.
    """

    env_id: str
    entry_point: str
    max_episode_steps: int
    robot: str
    classical_policy: str
    info: Mapping[str, InfoKey]
    sensor_modes: Mapping[str, str] = field(
        default_factory=lambda: MappingProxyType({"fast": "fast", "image": "image"})
    )
    experts: Mapping[str, str] = field(default_factory=lambda: MappingProxyType({}))
    metrics: tuple[str, ...] = ()
    default_reality: str | None = None


def load_object(path: str) -> Any:
    """The object at ``"package.module:attr.attr"`` (imports the module)."""
    module, _, attrs = path.partition(":")
    obj: Any = importlib.import_module(module)
    for name in attrs.split("."):
        obj = getattr(obj, name)
    return obj


_REWARD_TERMS = InfoKey("reward terms of the step, by name", None)
_ESTIMATE_OK = InfoKey("whether the estimator delivered a usable estimate")
_ESTIMATE_STATUS = InfoKey("estimator status message", None)
_SUCCESS = InfoKey("the env's success criterion holds")

ENV_CARDS: Mapping[str, EnvCard] = MappingProxyType(
    {
        card.env_id: card
        for card in (
            EnvCard(
                env_id="realitygap/WheeledNav-v0",
                entry_point="realitygap.envs.wheeled_nav:WheeledNavEnv",
                max_episode_steps=1200,
                robot="diffdrive",
                classical_policy="realitygap.baselines.classical:ClassicalNavPolicy.from_env",
                experts=MappingProxyType(
                    {
                        "classical": "realitygap.baselines.imitation:classical_wheeled_nav_expert",
                        "geodesic": "realitygap.baselines.imitation:geodesic_wheeled_nav_expert",
                    }
                ),
                info=MappingProxyType(
                    {
                        "true_pose": InfoKey("true planar pose [x (m), y (m), θ (rad)]", (3,)),
                        "estimated_pose": InfoKey("estimated pose [x (m), y (m), θ (rad)]", (3,)),
                        "estimate_ok": _ESTIMATE_OK,
                        "estimate_status": _ESTIMATE_STATUS,
                        "goal": InfoKey("goal pose [x (m), y (m), θ (rad)]", (3,)),
                        "pos_error": InfoKey("true distance to the goal position (m)"),
                        "heading_error": InfoKey("true heading error to the goal (rad)"),
                        "collision": InfoKey("the robot touched an obstacle"),
                        "is_success": _SUCCESS,
                        "reward_terms": _REWARD_TERMS,
                        "t": InfoKey("time since reset (s)"),
                    }
                ),
            ),
            EnvCard(
                env_id="realitygap/ArmCalib-v0",
                entry_point="realitygap.envs.arm_calib:ArmCalibEnv",
                max_episode_steps=200,
                robot="arm",
                sensor_modes=MappingProxyType({"fast": "geometric", "image": "image"}),
                classical_policy=(
                    "realitygap.baselines.arm_policy:ObservabilityGreedyPolicy.from_env"
                ),
                experts=MappingProxyType(
                    {"classical": "realitygap.baselines.imitation:greedy_arm_calib_expert"}
                ),
                metrics=("validation_rms_mm", "poses_used"),
                default_reality="realitygap.envs.arm_calib:default_arm_reality",
                info=MappingProxyType(
                    {
                        "true_pose": InfoKey("true flange pose T_base_flange (m)", (4, 4)),
                        "q_command": InfoKey("commanded joint angles (rad)", (6,)),
                        "q_encoder": InfoKey("joint encoder readings (rad)", (6,)),
                        "outcome": InfoKey("outcome of the step's measurement", None),
                        "message": InfoKey("human-readable step message", None),
                        "measurement_status": InfoKey("measurement status", None),
                        "estimate_ok": _ESTIMATE_OK,
                        "estimate_status": _ESTIMATE_STATUS,
                        "poses_used": InfoKey("measurement poses in the identification"),
                        "attempts": InfoKey("poses attempted this episode"),
                        "validation_rms_mm": InfoKey("held-out positioning RMS error (mm)"),
                        "validation_max_mm": InfoKey("held-out positioning max error (mm)"),
                        "nominal_validation_rms_mm": InfoKey(
                            "held-out RMS error of the nominal model (mm)"
                        ),
                        "free_params": InfoKey("identified parameter names", None),
                        "condition_number": InfoKey("condition number of the fit", None),
                        "fit_rms_mm": InfoKey("RMS residual of the fit (mm)", None),
                        "reward_terms": _REWARD_TERMS,
                        "is_success": _SUCCESS,
                    }
                ),
            ),
            EnvCard(
                env_id="realitygap/WallClimb-v0",
                entry_point="realitygap.envs.wall_climb:WallClimbEnv",
                max_episode_steps=1200,
                robot="climber",
                classical_policy="realitygap.baselines.climb_policy:ClimbChartPolicy.from_env",
                metrics=("goal_distance", "position_error"),
                info=MappingProxyType(
                    {
                        "true_pose": InfoKey(
                            "true pose [x, y, z (m), quaternion xyzw] in the world frame", (7,)
                        ),
                        "estimated_pose": InfoKey(
                            "estimated pose [x, y, z (m), quaternion xyzw]", (7,)
                        ),
                        "position_error": InfoKey("estimated-to-true position error (m)"),
                        "estimate_ok": _ESTIMATE_OK,
                        "estimate_status": _ESTIMATE_STATUS,
                        "estimate_frame": InfoKey("frame of the estimated pose", None),
                        "estimator_flags": InfoKey("estimator flags by name", None),
                        "goal": InfoKey("goal position [x, y, z] (m)", (3,)),
                        "goal_distance": InfoKey("true distance to the goal (m)"),
                        "height_above_surface": InfoKey("height above the blade surface (m)"),
                        "adsorption_force": InfoKey("adsorption force (N)"),
                        "tether_length": InfoKey("measured tether length (m)"),
                        "tether_true_distance": InfoKey("true anchor-to-robot distance (m)"),
                        "visual_ok": InfoKey("the camera front end tracked this step"),
                        "detached": InfoKey("the robot lost adhesion"),
                        "is_success": _SUCCESS,
                        "reward_terms": _REWARD_TERMS,
                        "t": InfoKey("time since reset (s)"),
                    }
                ),
            ),
        )
    }
)
"""The card of every environment id this package registers."""


def card_for(env_id: str) -> EnvCard:
    """The card of ``env_id``; ``KeyError`` naming close ids on a typo."""
    try:
        return ENV_CARDS[env_id]
    except KeyError:
        close = difflib.get_close_matches(env_id, list(ENV_CARDS), n=2)
        hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
        raise UnknownNameError(
            f"no environment card for {env_id!r}.{hint} Known: {', '.join(ENV_CARDS)}"
        ) from None
