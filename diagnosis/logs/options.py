"""What the readers of :mod:`~realitygap.diagnosis.logs.read` are told (:class:`ReadOptions`),
checked when it is made: every option's type, choices and range, the robot's nominal
parameters against their physical ranges, the firmware's limits."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from realitygap.core.checks import check_finite_float
from realitygap.robots.diffdrive import PARAM_RANGES, FirmwareLimits, check_param

__all__ = ["ARM_PARAMS", "ReadOptions", "check_read_options", "check_robot_params"]


@dataclass(frozen=True)
class ReadOptions:
    """Options for the importers (all optional).

    Attributes
    ----------
    columns : str or None
        CSV column map (see :class:`~realitygap.diagnosis.logs.importers.csv_log.ColumnMap`).
    decimal, delimiter : str or None
        CSV number format (default: detected).
    nan : {"raise", "interpolate", "drop"}
        Missing CSV values.
    params : mapping or None
        Nominal robot parameters for CSV and bag logs.
    firmware : mapping or None
        ``{"a_max", "alpha_max"}`` if the commands are requests the firmware rate-limits.
    cmd_topic, odom_topic, truth_topic, truth_frame, wheels_topic : str or None
        ROS bag topics.
    rate_hz : float or None
        Resample bags to this rate (Hz); ``None`` (default) aligns their topics on the wheel
        joints' (else the commands') own stamps.
    resample : float or None
        Resample every log to this step (s) — for jittery time stamps.
    check_plausible : bool
        Refuse logs whose numbers do not fit their channels' schema (:func:`check_plausible`:
        speeds, turn rates, wheel rates, row rate, an arm's reach), a sign of a wrong unit.
    meta : mapping or None
        Further metadata of table and bag logs (from a robot file: the declared
        ground-truth tracked point, a skid-steer's wheel track, an arm's tool).
    robot : str or None
        The robot of table logs (``diffdrive``, ``arm``); default: from the column map's
        channels.
    duplicates : {"raise", "last", "mean"}
        Repeated time stamps within a channel of a table log.
    max_gap : float or None
        Longest gap (s) of a channel that aligning channels at different rates may
        interpolate over (default: ``REALITYGAP_MAX_GAP_STEPS`` of its own period).
    """

    columns: str | None = None
    decimal: str | None = None
    delimiter: str | None = None
    nan: str = "raise"
    params: Mapping[str, Any] | None = None
    firmware: Mapping[str, Any] | None = None
    cmd_topic: str = "/cmd_vel"
    odom_topic: str | None = "/odom"
    truth_topic: str | None = None
    truth_frame: str | None = None
    wheels_topic: str | None = None
    rate_hz: float | None = None
    resample: float | None = None
    check_plausible: bool = True
    meta: Mapping[str, Any] | None = None
    robot: str | None = None
    duplicates: str = "raise"
    max_gap: float | None = None

    def __post_init__(self) -> None:
        """Every option checked when given, before any file is read: its type, its choices,
        its range; the message names the option as in Python and on the command line."""
        from realitygap.diagnosis.logs.importers.table import check_format

        if self.columns is not None and not isinstance(self.columns, str | Mapping):
            raise TypeError(
                f"columns (--columns) must be a column map as text ('t=time,cmd.v=v,…'), a "
                f"mapping or a JSON file name, got {type(self.columns).__name__} {self.columns!r}"
            )
        check_format(self.delimiter, self.decimal)
        for name, value, choices in (
            ("nan", self.nan, ("raise", "interpolate", "drop")),
            ("duplicates", self.duplicates, ("raise", "last", "mean")),
        ):
            if value not in choices:
                raise ValueError(
                    f"{name} (--{name}) must be one of {', '.join(choices)}, got {value!r}"
                )
        for name, option, value, unit in (
            ("rate_hz", "--rate", self.rate_hz, "Hz"),
            ("resample", "--resample", self.resample, "s"),
            ("max_gap", "--max-gap", self.max_gap, "s"),
        ):
            if value is not None:
                check_finite_float(value, f"{name} ({option})", low=0.0, strict_low=True, unit=unit)
        if self.robot is not None:
            _check_robot_name(self.robot)
        if self.params is not None:
            check_robot_params(self.params)
        if self.firmware is not None:
            FirmwareLimits.from_mapping(self.firmware, "firmware (--firmware)")


ARM_PARAMS = ("mdh", "mdh_name", "link_masses", "payload_mass", "joint_lower", "joint_upper")
"""Nominal parameters an arm's logs may state: the MDH table (``{name: value}``, m and rad)
and its name, link and payload masses (kg), joint limits (rad)."""


def check_robot_params(params: Mapping[str, Any], name: str = "params (--params)") -> None:
    """Refuse nominal robot parameters that no robot has or that are no physical value: a
    differential drive's :class:`~realitygap.robots.diffdrive.DiffDriveParams` fields (each in
    its :data:`~realitygap.robots.diffdrive.PARAM_RANGES`), or an arm's :data:`ARM_PARAMS`."""
    if not isinstance(params, Mapping):
        raise TypeError(
            f"{name} must be a mapping of parameter → value (e.g. {{'wheelbase': 0.23}}), got "
            f"{type(params).__name__} {params!r}"
        )
    drive = set(PARAM_RANGES) | {"camera"}
    keys = set(map(str, params))
    if keys <= drive:
        for key, value in params.items():
            if key != "camera":
                try:
                    check_param(key, value)
                except ValueError as exc:
                    raise ValueError(f"{name}: {exc}") from None
        return
    if keys <= set(ARM_PARAMS):
        for key, value in params.items():
            if key == "mdh_name":
                continue
            if key == "mdh":
                if not isinstance(value, Mapping):
                    raise ValueError(f"{name}: mdh must be a mapping of MDH parameter → value")
                for k, v in value.items():
                    check_finite_float(v, f"{name} mdh.{k}")
                continue
            values = value if isinstance(value, list | tuple | np.ndarray) else [value]
            mass = key in ("link_masses", "payload_mass")
            for v in values:
                check_finite_float(
                    v, f"{name} {key}", low=0.0 if mass else None, unit="kg" if mass else "rad"
                )
        return
    unknown = sorted(keys - drive - set(ARM_PARAMS))
    raise ValueError(
        f"{name}: unknown robot parameter(s) {unknown}; a differential drive has "
        f"{', '.join(PARAM_RANGES)}; an arm has {', '.join(ARM_PARAMS)}. Fix: use those names"
    )


def _check_robot_name(robot: object) -> None:
    import realitygap.robots.effects  # noqa: F401 - each robot's effect module registers it
    from realitygap.robots.effects.base import ROBOT_PARAMS

    known = sorted(ROBOT_PARAMS)
    if robot not in known:
        raise ValueError(
            f"robot (--robot) must be one of {', '.join(known)}, got {robot!r}. Fix: name the "
            "robot the logs come from"
        )


def check_read_options(
    options: object, warn: object = None, caller: str = "read_logs"
) -> ReadOptions:
    """``options`` as :class:`ReadOptions` (``None``: the defaults), or a ``TypeError`` naming the
    argument, what came and an example; ``warn`` must be callable or ``None``."""
    if options is None:
        options = ReadOptions()
    if not isinstance(options, ReadOptions):
        hint = (
            f" (a column map? pass ReadOptions(columns={options!r:.60}))"
            if isinstance(options, str)
            else f" (pass ReadOptions(**{options!r:.60}))"
            if isinstance(options, Mapping)
            else ""
        )
        raise TypeError(
            f"{caller}: options must be a ReadOptions or None, got {type(options).__name__} "
            f"{options!r:.80}{hint}; e.g. {caller}('run.csv', ReadOptions(columns='t=time,"
            "cmd.v=v,cmd.w=w'))"
        )
    if warn is not None and not callable(warn):
        raise TypeError(
            f"{caller}: warn must be a function taking one message (e.g. print) or None, got "
            f"{type(warn).__name__} {warn!r:.80}"
        )
    return options
