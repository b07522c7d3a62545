"""What each robot's windows are compared by: feature groups, their schemas and the regimes.

A :class:`FeatureGroup` names a group of window features with columns, SI units and
default residual scales; a robot's :class:`FeatureSchema` is its groups and its motion
regimes. The schemas of every robot are declared here, below the adapters that compute
the features (:data:`DIFFDRIVE_SCHEMA`, :data:`ARM_SCHEMA`, :data:`CLIMBER_SCHEMA`), so
that the generic settings find a group's default scales (:func:`feature_group`) without
building any adapter.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "ARM_REGIMES",
    "ARM_SCHEMA",
    "CLIMBER_REGIMES",
    "CLIMBER_SCHEMA",
    "DIFFDRIVE_REGIMES",
    "DIFFDRIVE_SCHEMA",
    "FEATURE_SCHEMAS",
    "TOOL_DIST_COLUMNS",
    "FeatureGroup",
    "FeatureSchema",
    "feature_group",
]


@dataclass(frozen=True)
class FeatureGroup:
    """One group of window features: its columns, their SI units and default residual scales.

    Attributes
    ----------
    name : str
        Group name, e.g. ``"pose_gt"``.
    columns : tuple of str
    units : tuple of str
        SI unit of each column.
    scales : tuple of float
        Residual size that counts as one unit per column (SI units per window),
        unless :attr:`~realitygap.diagnosis.problem.features.FeatureSettings.scales` gives
        another.
    """

    name: str
    columns: tuple[str, ...]
    units: tuple[str, ...]
    scales: tuple[float, ...]

    def __post_init__(self) -> None:
        if not (len(self.columns) == len(self.units) == len(self.scales)):
            raise ValueError(
                f"feature group {self.name!r}: columns, units and scales must have one length"
            )


@dataclass(frozen=True)
class FeatureSchema:
    """What a robot's windows are compared by: its feature groups and its motion regimes.

    Attributes
    ----------
    groups : tuple of FeatureGroup
        In the order of every table of the diagnosis.
    regimes : tuple of str
        Regime labels a window can have, in table order.
    """

    groups: tuple[FeatureGroup, ...]
    regimes: tuple[str, ...]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(g.name for g in self.groups)

    def group(self, name: str) -> FeatureGroup:
        for g in self.groups:
            if g.name == name:
                return g
        raise KeyError(f"no feature group {name!r}; known: {', '.join(self.names)}")

    def columns(self, name: str) -> tuple[str, ...]:
        return self.group(name).columns

    def units(self, name: str) -> tuple[str, ...]:
        return self.group(name).units


# --------------------------------------------------------------------------- differential drive
DIFFDRIVE_REGIMES: tuple[str, ...] = (
    "standing",
    "straight",
    "turning_ccw",
    "turning_cw",
    "accelerating",
)
"""Regimes :func:`~realitygap.diagnosis.problem.features.classify_regimes` gives a
differential drive's windows."""

DIFFDRIVE_SCHEMA = FeatureSchema(
    groups=(
        FeatureGroup("pose_gt", ("dx", "dy", "dtheta"), ("m", "m", "rad"), (0.002, 0.002, 0.002)),
        FeatureGroup("ticks", ("left", "right"), ("m", "m"), (0.002, 0.002)),
        FeatureGroup("pose_cam", ("ex", "ey", "etheta"), ("m", "m", "rad"), (0.002, 0.002, 0.003)),
    ),
    regimes=DIFFDRIVE_REGIMES,
)
"""Window features of a differential drive (default scales 2 mm, 2 mm, 2 mrad for the
ground truth; 2 mm per wheel; 2 mm, 2 mm, 3 mrad for the camera) and its regimes."""

# --------------------------------------------------------------------------- arm
TOOL_DIST_COLUMNS: tuple[str, ...] = ("d01", "d02", "d03", "d12", "d13", "d23")
"""Pairs of the four poses of an arm window whose tool-point distance is compared."""

ARM_REGIMES: tuple[str, ...] = ("folded", "mid_reach", "outstretched")
"""Arm windows, by how far the wrist reaches out from the base axis."""

ARM_SCHEMA = FeatureSchema(
    groups=(
        FeatureGroup(
            "tool_dist",
            TOOL_DIST_COLUMNS,
            ("m",) * len(TOOL_DIST_COLUMNS),
            (1e-4,) * len(TOOL_DIST_COLUMNS),
        ),
    ),
    regimes=ARM_REGIMES,
)
"""The arm's window features (tool-point distances, default scale 0.1 mm) and regimes."""

# --------------------------------------------------------------------------- climber
CLIMBER_REGIMES: tuple[str, ...] = ("standing", "climbing", "descending", "traversing")
"""Climber windows, by the true motion on the blade."""

CLIMBER_SCHEMA = FeatureSchema(
    groups=(
        FeatureGroup("tether", ("length",), ("m",), (1e-3,)),
        FeatureGroup("surface", ("height",), ("m",), (1e-3,)),
    ),
    regimes=CLIMBER_REGIMES,
)
"""The climber's window features (tether reading, ride height; default scale 1 mm) and
regimes."""

FEATURE_SCHEMAS: tuple[FeatureSchema, ...] = (DIFFDRIVE_SCHEMA, ARM_SCHEMA, CLIMBER_SCHEMA)
"""Every robot's schema, in the order of the adapter registry."""


def feature_group(name: str) -> FeatureGroup:
    """The feature group ``name`` as the robot that compares it declares it."""
    for schema in FEATURE_SCHEMAS:
        if name in schema.names:
            return schema.group(name)
    raise KeyError(f"no robot adapter compares a feature group {name!r}")
