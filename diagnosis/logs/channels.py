"""What a log's channels are: :class:`ChannelSpec` and the standard channels of every robot.

A channel has columns, a unit per column and a :class:`Role`. The standard channels
(:func:`standard_channels`) are those the robot adapters read; a log may hold one without
giving its spec, and an importer converts its units to these. Each robot's channels are
declared here, below the adapters that read them
(:data:`DIFFDRIVE_CHANNELS`, :data:`ARM_CHANNELS`, :data:`CLIMBER_CHANNELS`), so that a
log knows them without building any adapter.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum
from types import MappingProxyType
from typing import Any

__all__ = [
    "ARM_CHANNELS",
    "CLIMBER_CHANNELS",
    "DIFFDRIVE_CHANNELS",
    "ROBOT_CHANNELS",
    "ChannelSpec",
    "Role",
    "standard_channels",
]


class Role(str, Enum):
    """What a channel is: an input to the robot, a sensor reading, the truth or an estimate."""

    COMMAND = "command"
    SENSOR = "sensor"
    TRUTH = "truth"
    ESTIMATE = "estimate"
    OTHER = "other"


@dataclass(frozen=True)
class ChannelSpec:
    """Columns, units and role of one channel.

    ``angle_columns`` lists the columns that are angles (rad): they are
    unwrapped before interpolation.
    """

    name: str
    columns: tuple[str, ...]
    units: tuple[str, ...]
    role: Role = Role.OTHER
    description: str = ""
    angle_columns: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if len(self.columns) != len(self.units) or not self.columns:
            raise ValueError(
                f"channel {self.name!r}: need one unit per column, got columns {self.columns} "
                f"and units {self.units}"
            )

    def to_dict(self) -> dict[str, Any]:
        return {
            "columns": list(self.columns),
            "units": list(self.units),
            "role": self.role.value,
            "description": self.description,
            "angle_columns": list(self.angle_columns),
        }

    @classmethod
    def from_dict(cls, name: str, data: Mapping[str, Any]) -> ChannelSpec:
        return cls(
            name=name,
            columns=tuple(str(c) for c in data["columns"]),
            units=tuple(str(u) for u in data["units"]),
            role=Role(data.get("role", "other")),
            description=str(data.get("description", "")),
            angle_columns=tuple(int(i) for i in data.get("angle_columns", ())),
        )


# --------------------------------------------------------------------------- the robots' channels
_POSE = ("x", "y", "theta")
_POSE_UNITS = ("m", "m", "rad")

DIFFDRIVE_CHANNELS: tuple[ChannelSpec, ...] = (
    ChannelSpec(
        "cmd",
        ("v", "w"),
        ("m/s", "rad/s"),
        Role.COMMAND,
        "body twist issued at t[k] and held until t[k+1]",
    ),
    ChannelSpec(
        "ticks", ("left", "right"), ("count", "count"), Role.SENSOR, "cumulative encoder counts"
    ),
    ChannelSpec(
        "pose_gt", _POSE, _POSE_UNITS, Role.TRUTH, "ground-truth base pose", angle_columns=(2,)
    ),
    ChannelSpec(
        "pose_est", _POSE, _POSE_UNITS, Role.ESTIMATE, "estimated base pose", angle_columns=(2,)
    ),
    ChannelSpec(
        "pose_cam",
        _POSE,
        _POSE_UNITS,
        Role.SENSOR,
        "planar camera pose from a camera localisation",
        angle_columns=(2,),
    ),
)
"""Channels of a differential-drive log."""

ARM_CHANNELS: tuple[ChannelSpec, ...] = (
    ChannelSpec(
        "joints",
        ("q1", "q2", "q3", "q4", "q5", "q6"),
        ("rad",) * 6,
        Role.SENSOR,
        "joint encoder readings of the arm at rest",
    ),
    ChannelSpec(
        "tool_pos",
        ("x", "y", "z"),
        ("m", "m", "m"),
        Role.TRUTH,
        "tool point measured by an external instrument (laser tracker), in its own frame",
    ),
)
"""Channels of an arm log: one row per measurement pose, the arm at rest."""

CLIMBER_CHANNELS: tuple[ChannelSpec, ...] = (
    ChannelSpec(
        "pose3_gt",
        ("x", "y", "z", "rx", "ry", "rz"),
        ("m", "m", "m", "rad", "rad", "rad"),
        Role.TRUTH,
        "ground-truth 3-D body pose: position and rotation vector in the world (CAD) frame",
    ),
    ChannelSpec("tether", ("length",), ("m",), Role.SENSOR, "tether length reported by the spool"),
)
"""Channels of a climber log."""


ROBOT_CHANNELS: Mapping[str, tuple[ChannelSpec, ...]] = MappingProxyType(
    {"diffdrive": DIFFDRIVE_CHANNELS, "arm": ARM_CHANNELS, "climber": CLIMBER_CHANNELS}
)
"""Each robot's channels, by robot name: a log of a robot holds some of them."""


def _by_name(*robots: tuple[ChannelSpec, ...]) -> Mapping[str, ChannelSpec]:
    out: dict[str, ChannelSpec] = {}
    for specs in robots:
        for spec in specs:
            out.setdefault(spec.name, spec)
    return MappingProxyType(out)


_STANDARD = _by_name(DIFFDRIVE_CHANNELS, ARM_CHANNELS, CLIMBER_CHANNELS)


def standard_channels() -> Mapping[str, ChannelSpec]:
    """The standard channels: those the robot adapters read, by name, in the order of the
    adapter registry (differential drive, arm, climber).

    A log may hold a standard channel without giving its :class:`ChannelSpec`.
    """
    return _STANDARD
