"""Reality profiles (named sets of effects per robot) and sensor-fidelity modes of the benchmark."""

from __future__ import annotations

import os
from typing import Any

from realitygap.cards import ENV_CARDS, load_object

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


# --------------------------------------------------------------------------- realities
_REALITY_EXAMPLE = (
    '{"name": "mine", "effects": [{"name": "command_latency", "values": {"delay": 0.06}}]}'
)


def _looks_like_file(name: str) -> bool:
    return (
        name.lower().endswith((".json", ".yaml", ".yml"))
        or os.sep in name
        or "/" in name
        or os.path.lexists(name)
    )


def reality_from_profile(name: str, option: str = "--reality") -> Any:
    """The :class:`~realitygap.robots.effects.Reality` of profile ``name`` (or a file).

    ``"nominal"`` is the nominal robot. A path (ending in ``.json``, ``.yaml`` or ``.yml``,
    or naming an existing file) is read by :func:`load_reality_file`.

    Raises
    ------
    FileNotFoundError
        A path to nothing.
    ValueError
        An unknown profile name (with close names), or a file that is no valid reality;
        the message names ``option``.
    """
    import difflib

    from realitygap.robots.effects import Reality

    if not isinstance(name, str) or not name.strip():
        raise ValueError(
            f"{option}: expected a reality profile name or a Reality JSON file, got {name!r}. "
            f"Known: nominal, {', '.join(REALITY_PROFILES)}"
        )
    if name == "nominal":
        return Reality()
    if name in REALITY_PROFILES:
        prof = REALITY_PROFILES[name]
        return Reality.from_dict({"name": name, "effects": prof["effects"]})
    if _looks_like_file(name):
        return load_reality_file(name, option)
    close = difflib.get_close_matches(name, list(REALITY_PROFILES), n=2)
    hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
    raise ValueError(
        f"{option}: unknown reality profile {name!r}.{hint} Known: nominal, "
        f"{', '.join(REALITY_PROFILES)} (or a JSON file in Reality.to_dict() format). Fix: "
        "give one of these names, or the path of a reality file"
    )


def load_reality_file(path: str | os.PathLike[str], option: str = "--reality") -> Any:
    """A :class:`~realitygap.robots.effects.Reality` from a reality file (JSON or YAML, the
    schema of :mod:`~realitygap.robots.effects.twin` or :meth:`Reality.to_dict`'s form), every
    effect and parameter checked (bounds included); each message names ``option`` and the file.
    """
    from realitygap.robots.effects import load_reality

    return load_reality(path, option)


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


def default_realities(env_ids: Any, names: tuple[str, ...]) -> tuple[str, ...]:
    """Of the named profiles ``names``, those for the robot of at least one of ``env_ids``
    (a default reality list never asks for a profile no requested env can run)."""
    robots = {ENV_CARDS[e].robot for e in env_ids if e in ENV_CARDS}
    return tuple(n for n in names if REALITY_PROFILES[n]["robot"] in robots)


def check_reality_applies(
    name: str, env_ids: tuple[str, ...] | list[str], option: str = "--reality"
) -> None:
    """Refuse a requested reality that would run no meaningful cell: one whose effects all
    sit at nominal (or that has none), or one for a robot none of ``env_ids`` is. The check
    :func:`~realitygap.baselines.benchmark.config.check_benchmark_config` makes for every
    requested reality before any work (``nominal`` itself is always run and not checked).

    Raises
    ------
    ValueError
        Naming the profile or file, and the envs it applies to.
    """
    if name == "nominal":
        return
    reality = reality_from_profile(name, option)
    kind = "reality profile" if name in REALITY_PROFILES else "reality file"
    if not any(not e.is_nominal() for e in reality.effects):
        what = (
            "has no effects"
            if not reality.effects
            else "sets every effect to its nominal value ("
            + ", ".join(e.name for e in reality.effects)
            + ")"
        )
        raise ValueError(
            f"{option}: {kind} {name!r} {what}, so its cell would be the nominal robot again. "
            "Fix: give at least one effect a value away from nominal, e.g. "
            f"{_REALITY_EXAMPLE}, or drop it (the nominal cell always runs)"
        )
    robot = reality.robot
    fits = sorted(i for i, c in ENV_CARDS.items() if c.robot == robot)
    if not any(ENV_CARDS[e].robot == robot for e in env_ids if e in ENV_CARDS):
        envs = ", ".join(fits) if fits else "no registered env"
        raise ValueError(
            f"{option}: {kind} {name!r} is for the {robot} robot and applies to {envs}, but "
            f"none of the requested envs ({', '.join(env_ids)}) is one; it would run no cell. "
            f"Fix: add {fits[0] if fits else 'an env of that robot'} to --envs, or drop this reality"
        )


def env_sensor_mode(env_id: str, mode: str) -> str:
    """The env's ``sensor_mode`` value for the benchmark's ``mode`` (``fast``/``image``)."""
    card = ENV_CARDS.get(env_id)
    return card.sensor_modes.get(mode, mode) if card is not None else mode


def profile_robot(name: str) -> str | None:
    """The robot a profile is for: a named profile's, or the effects' of a reality file
    (``None`` for ``nominal`` and a file without effects)."""
    prof = REALITY_PROFILES.get(name)
    if prof is not None:
        return str(prof["robot"])
    if name == "nominal":
        return None
    robot = reality_from_profile(name).robot
    return None if robot is None else str(robot)


def simulator_kwargs(
    env_id: str,
    reality: str | None = None,
    randomize: bool = False,
    estimator_reality: str | None = None,
) -> dict[str, Any]:
    """``gym.make`` keywords (JSON-able) of the simulator ``realitygap train --reality …
    [--randomize] [--estimator-reality …]`` asks for: ``reality`` a profile name or a reality
    file; ``randomize`` draws each episode's robot from the file's uncertainty boxes
    (:attr:`~realitygap.robots.effects.Twin.randomize`); ``estimator_reality`` a profile or
    file whose effects the env's default estimator includes (a twin's calibrated odometry).

    Raises
    ------
    ValueError
        ``--randomize`` without a reality file, with a file that holds no uncertainty, or for
        an env that draws no per-episode robot; an ``--estimator-reality`` for an env without
        that keyword; any error of the profile or file, naming the option.
    """
    from realitygap.robots.effects import Twin

    out: dict[str, Any] = {}
    accepts = env_keywords(env_id)
    if reality is not None and reality != "nominal":
        reality_from_profile(reality, "--reality")  # errors name the option
        out["reality"] = reality_for(env_id, reality).to_dict()
    if randomize:
        if reality is None or reality in REALITY_PROFILES or reality == "nominal":
            raise ValueError(
                "--randomize draws each episode's robot from a reality file's uncertainty, but "
                f"--reality is {reality!r}. Fix: give --reality FILE written by `realitygap "
                "diagnose … --export FILE`, or drop --randomize"
            )
        if "randomize" not in accepts:
            raise ValueError(
                f"--randomize: {env_id} draws no per-episode robot (it has no 'randomize' "
                "keyword). Fix: drop --randomize for this env"
            )
        boxes = Twin.load(reality, "--reality").randomize
        if not boxes:
            raise ValueError(
                f"--randomize: reality file {reality!r} holds no uncertainty (no parameter has "
                "a standard error or an observed range), so every episode would be the same "
                "robot. Fix: drop --randomize, or export the file from a diagnosis"
            )
        out["randomize"] = {k: list(v) for k, v in boxes.items()}
    if estimator_reality is not None:
        if "estimator_reality" not in accepts:
            raise ValueError(
                f"--estimator-reality: {env_id}'s estimator takes no reality (no "
                "'estimator_reality' keyword). Fix: drop --estimator-reality for this env"
            )
        out["estimator_reality"] = reality_from_profile(
            estimator_reality, "--estimator-reality"
        ).to_dict()
    return out


def env_keywords(env_id: str) -> set[str]:
    """The keyword arguments the env registered as ``env_id`` takes."""
    import inspect

    import gymnasium as gym

    from realitygap.cards import load_object

    spec = gym.spec(env_id)
    entry = spec.entry_point or spec.vector_entry_point
    if isinstance(entry, str):
        entry = load_object(entry)
    return set(inspect.signature(entry).parameters)
