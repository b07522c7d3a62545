"""The registry of diagnosis adapters: the one map from robot names to adapters."""

from __future__ import annotations

import importlib

from realitygap.diagnosis.adapters.contract import RobotAdapter

__all__ = [
    "ADAPTERS",
    "ADAPTER_CLASSES",
    "close_adapters",
    "get_adapter",
    "known_robots",
]


# --------------------------------------------------------------------------- the registry
ADAPTER_CLASSES: dict[str, str] = {
    "diffdrive": "realitygap.diagnosis.adapters.diffdrive.adapter:DiffDriveAdapter",
    "arm": "realitygap.diagnosis.adapters.arm.adapter:ArmAdapter",
    "climber": "realitygap.diagnosis.adapters.climber.adapter:ClimberAdapter",
}
"""``robot`` → ``"module:Class"`` of its adapter: the one map from robot names to adapters."""


ADAPTERS: dict[str, RobotAdapter] = {}
"""Adapters of this process by robot name, built on first use (:func:`get_adapter`); an
entry set here replaces the default one."""


def known_robots() -> tuple[str, ...]:
    """Names of every robot with a diagnosis adapter, in registry order."""
    return tuple(dict.fromkeys([*ADAPTER_CLASSES, *ADAPTERS]))


def get_adapter(robot: str) -> RobotAdapter:
    """The adapter of ``robot``; a ``ValueError`` listing the known robots otherwise."""
    if robot not in ADAPTERS and robot in ADAPTER_CLASSES:
        module, _, cls = ADAPTER_CLASSES[robot].partition(":")
        ADAPTERS[robot] = getattr(importlib.import_module(module), cls)()
    if robot not in ADAPTERS:
        raise ValueError(
            f"no diagnosis adapter for robot {robot!r}; known: {', '.join(sorted(known_robots()))}"
        )
    return ADAPTERS[robot]


def close_adapters() -> None:
    """Close every adapter of this process (their simulator scenes) and forget them."""
    while ADAPTERS:
        _, adapter = ADAPTERS.popitem()
        adapter.close()
