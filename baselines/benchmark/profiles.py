"""Reality profiles (named sets of effects per robot) and sensor-fidelity modes of the benchmark."""

from __future__ import annotations

import json
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
