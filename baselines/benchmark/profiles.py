"""Reality profiles (named sets of effects per robot) and sensor-fidelity modes of the benchmark."""

from __future__ import annotations

import os
from pathlib import Path
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
    """A :class:`~realitygap.robots.effects.Reality` from a JSON or YAML file in
    :meth:`Reality.to_dict` format, every effect and parameter checked (bounds included).

    Read with :func:`~realitygap.core.checks.load_json_or_yaml` (errors name the file and
    line); each message names ``option`` and the file.
    """
    from realitygap.core.checks import load_json_or_yaml
    from realitygap.robots.effects import Reality, make_effect

    data = load_json_or_yaml(Path(path), option, expect=dict, example=_REALITY_EXAMPLE)
    where = f"{option} {path}"
    unknown = sorted(set(map(str, data)) - {"name", "effects", "meta"})
    if unknown:
        raise ValueError(
            f"{where}: unknown key(s) {unknown}; a reality file has 'name' and 'effects', e.g. "
            f"{_REALITY_EXAMPLE}. Fix: remove or rename them"
        )
    effects = data.get("effects", [])
    if not isinstance(effects, list):
        raise ValueError(
            f'{where}: \'effects\' must be a list of {{"name": ..., "values": {{...}}}} '
            f"objects, got {type(effects).__name__}. Fix: write it as in {_REALITY_EXAMPLE}"
        )
    built = []
    for i, item in enumerate(effects):
        at = f"{where}: effects[{i}]"
        if not isinstance(item, dict) or not isinstance(item.get("name"), str):
            raise ValueError(
                f"{at} must be an object with a 'name' (str) and 'values', got {item!r:.60}. "
                f"Fix: write it as in {_REALITY_EXAMPLE}"
            )
        values = item.get("values", {})
        if not isinstance(values, dict):
            raise ValueError(
                f"{at} ({item['name']!r}): 'values' must be an object of parameter: number, "
                f"got {values!r:.60}"
            )
        try:
            built.append(make_effect(item["name"], **{str(k): v for k, v in values.items()}))
        except KeyError as exc:
            raise ValueError(f"{at}: {exc.args[0]}") from None
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{at}: {exc}") from None
    name = data.get("name", Path(path).stem)
    try:
        return Reality(effects=tuple(built), name=str(name))
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{where}: {exc}") from None


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
