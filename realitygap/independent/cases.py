"""The independent cases: one hidden effect per case, with its value.

Each :class:`Case` names a field of :class:`~realitygap.independent.diffdrive.Hidden`
or :class:`~realitygap.independent.ur10.ArmHidden` (our own parametrisation) and
says which effect names of the diagnosis library count as a correct answer
(``accepted``). A case whose ``accepted`` is empty plants an effect that no
library effect models (open set): the right answer is "unexplained" (see
:mod:`realitygap.experiments.independent` for the scoring).

The accepted names are the physical equivalents: e.g. a right wheel 0.8 % larger
than the left is ``wheel_diameter_ratio`` (E_d = 1.008); a constant creep at the
contact makes every wheel roll as a smaller one, so ``wheel_radius_scale`` and
``longitudinal_slip`` are both accepted.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["ARM_CASES", "CASES", "DRIVE_CASES", "QUICK", "Case", "case_by_name"]


@dataclass(frozen=True)
class Case:
    """One hidden effect.

    Attributes
    ----------
    name : str
        Unique case name.
    robot : {"diffdrive", "arm"}
    values : dict
        Fields of ``Hidden`` / ``ArmHidden`` and their values.
    accepted : tuple of str
        Library effects that count as the right answer; empty: out of library.
    note : str
        What the effect is physically.
    drives : tuple of str
        Differential drive: the replays in which the effect shows, ``"commands"``
        (the logged requests drive the replay) and/or ``"ticks"`` (the logged wheel
        rotation does); an actuator effect upstream of the encoders shows only in
        the first. Arm: ``("commands",)`` (the joint readings drive the replay).
    ticks_aliases : tuple of str
        Effects that are exact equivalents of the planted one when the wheel
        rotation drives the replay: there the data fix only the distance per tick,
        so counts per revolution and wheel size are one parameter (an encoder
        counting 4 % more is a wheel 4 % smaller).
    """

    name: str
    robot: str
    values: dict[str, Any]
    accepted: tuple[str, ...]
    note: str
    drives: tuple[str, ...] = ("commands", "ticks")
    ticks_aliases: tuple[str, ...] = ()

    def accepted_for(self, drive: str) -> tuple[str, ...]:
        """Accepted effects when ``drive`` drives the replay (adds :attr:`ticks_aliases`)."""
        return self.accepted + (self.ticks_aliases if drive == "ticks" else ())

    def __post_init__(self) -> None:
        if self.robot not in ("diffdrive", "arm"):
            raise ValueError(
                f"case {self.name}: robot must be 'diffdrive' or 'arm', got {self.robot!r}"
            )
        bad = set(self.drives) - {"commands", "ticks"}
        if bad or not self.drives or (self.robot == "arm" and self.drives != ("commands",)):
            raise ValueError(
                f"case {self.name}: drives must be a non-empty subset of ('commands', 'ticks') "
                f"(arm: ('commands',)), got {self.drives!r}"
            )

    @property
    def in_library(self) -> bool:
        """True when some library effect models the planted one."""
        return bool(self.accepted)


_ARM = ("commands",)


def _j(k: int, v: float) -> tuple[float, ...]:
    out = [0.0] * 6
    out[k - 1] = v
    return tuple(out)


DRIVE_CASES: tuple[Case, ...] = (
    Case("wheelbase_plus3", "diffdrive", {"b_true": 1.03}, ("wheelbase_error",), "axle 3 % wider"),
    Case(
        "wheelbase_minus2", "diffdrive", {"b_true": 0.98}, ("wheelbase_error",), "axle 2 % narrower"
    ),
    Case(
        "right_wheel_big",
        "diffdrive",
        {"d_right": 1.005, "d_left": 0.995},
        ("wheel_diameter_ratio",),
        "right wheel 1 % larger than the left",
    ),
    Case(
        "left_wheel_big",
        "diffdrive",
        {"d_right": 0.996, "d_left": 1.004},
        ("wheel_diameter_ratio",),
        "left wheel 0.8 % larger",
    ),
    Case(
        "worn_tyres",
        "diffdrive",
        {"d_right": 0.96, "d_left": 0.96},
        ("wheel_radius_scale",),
        "both wheels 4 % smaller",
    ),
    Case(
        "driver_delay",
        "diffdrive",
        {"delay": 0.12},
        ("command_latency",),
        "set-points reach the drivers 120 ms late",
        drives=("commands",),
    ),
    Case(
        "speed_cap",
        "diffdrive",
        {"speed_cap": 0.085},
        ("velocity_saturation",),
        "wheels top out at 0.085 m/s, below the 0.113 m/s cruise",
        drives=("commands",),
    ),
    Case(
        "stiction",
        "diffdrive",
        {"stiction": 0.03},
        ("motor_deadband",),
        "wheel set-points below 0.03 m/s do not turn the wheel",
        drives=("commands",),
    ),
    Case(
        "encoder_counts_high",
        "diffdrive",
        {"cpr_left": 1.04, "cpr_right": 1.04},
        ("encoder_scale",),
        "both encoders count 4 % more edges than declared",
        ticks_aliases=("wheel_radius_scale",),
    ),
    Case(
        "right_encoder_high",
        "diffdrive",
        {"cpr_right": 1.03},
        # the library splits one encoder's error into a ratio at a kept mean and a common
        # scale (E_c = 1.03, scale = 1.015 is exactly this encoder): the pair is the answer
        ("encoder_ratio", "encoder_scale"),
        "right encoder counts 3 % more edges",
        ticks_aliases=("wheel_diameter_ratio", "wheel_radius_scale"),
    ),
    Case(
        "mocap_stamp_late",
        "diffdrive",
        {"clock_skew": 0.15},
        ("timestamp_offset",),
        "motion-capture stamps 150 ms late",
    ),
    Case(
        "contact_creep",
        "diffdrive",
        {"creep": 0.05},
        ("wheel_radius_scale", "longitudinal_slip"),
        "5 % of rim speed lost at the contact",
    ),
    # out of the library
    Case(
        "elliptic_wheel",
        "diffdrive",
        {"ellipticity": 0.03},
        (),
        "right wheel elliptical, radius r(1 + 0.03 cos 2φ)",
    ),
    Case(
        "caster_drag",
        "diffdrive",
        {"caster_drag": 0.06},
        (),
        "a dragging caster takes 0.06 rad/s off every turn",
    ),
    Case(
        "floor_slope",
        "diffdrive",
        {"slope": 0.05, "slope_dir": 0.7},
        (),
        "floor tilted 0.05 rad: the robot creeps downhill while it moves",
    ),
    Case(
        "battery_sag",
        "diffdrive",
        {"battery_sag": 0.25},
        (),
        "motor speed falls linearly to 75 % over the session",
        drives=("commands",),
    ),
    Case(
        "marker_offset",
        "diffdrive",
        {"marker_dx": 0.05, "marker_dy": -0.03},
        (),
        "motion-capture body 5 cm ahead of and 3 cm right of the axle centre",
    ),
    Case(
        "turn_skid",
        "diffdrive",
        {"skid": 0.4},
        (),
        "lateral skid 0.4·v·ω on arcs",
    ),
    Case(
        "encoder_wobble",
        "diffdrive",
        {"enc_wobble": 0.15},
        (),
        "left encoder disc eccentric: ±0.15 rad once-per-turn count error",
    ),
)

ARM_CASES: tuple[Case, ...] = (
    Case(
        "zero_j2",
        "arm",
        {"zero_err": _j(2, 8e-4)},
        ("arm_joint_offset",),
        "joint 2 zero 0.8 mrad off",
        drives=_ARM,
    ),
    Case(
        "zero_j3",
        "arm",
        {"zero_err": _j(3, -6e-4)},
        ("arm_joint_offset",),
        "joint 3 zero −0.6 mrad off",
        drives=_ARM,
    ),
    Case(
        "upper_arm_long",
        "arm",
        {"da": _j(2, -1.5e-3)},
        ("arm_link_length",),
        "upper arm (a2) 1.5 mm longer",
        drives=_ARM,
    ),
    Case(
        "forearm_short",
        "arm",
        {"da": _j(3, 1.2e-3)},
        ("arm_link_length",),
        "forearm (a3) 1.2 mm shorter",
        drives=_ARM,
    ),
    Case(
        "probe_long",
        "arm",
        {"probe_err": (0.0, 0.0, 3e-3)},
        ("arm_tool_offset",),
        "probe 3 mm longer than declared",
        drives=_ARM,
    ),
    Case(
        "shoulder_flex",
        "arm",
        {"flex": _j(2, 2.5e-5)},
        ("arm_joint_compliance",),
        "joint 2 yields 2.5e-5 rad per N·m",
        drives=_ARM,
    ),
    Case(
        "elbow_play",
        "arm",
        {"play": _j(3, 1.2e-3)},
        ("arm_backlash",),
        "joint 3 has 1.2 mrad of play",
        drives=_ARM,
    ),
    Case(
        "gear_ratio_j1",
        "arm",
        {"ratio_err": _j(1, 1.5e-3)},
        ("arm_encoder_scale",),
        "joint 1 turns 0.15 % more than read",
        drives=_ARM,
    ),
    Case(
        "twist_j4",
        "arm",
        {"dalpha": _j(4, 2e-3)},
        ("arm_twist_error", "arm_parallel_twist"),
        "twist of DH row 4 off by 2 mrad",
        drives=_ARM,
    ),
    # out of the library
    Case(
        "gear_eccentric_j2",
        "arm",
        {"eccentric": _j(2, 6e-4)},
        (),
        "joint 2 gear eccentricity: 0.6 mrad twice per turn",
        drives=_ARM,
    ),
    Case(
        "thermal_growth",
        "arm",
        {"thermal": 4e-5},
        (),
        "every length grows 40 ppm/K while the cell warms by 3 K",
        drives=_ARM,
    ),
    Case(
        "tracker_cyclic",
        "arm",
        {"tracker_cyclic": 1.5e-4},
        (),
        "tracker range error 0.15 mm with a 0.4 m period",
        drives=_ARM,
    ),
)

CASES: tuple[Case, ...] = DRIVE_CASES + ARM_CASES
"""Every case (31: 21 in the library, 10 outside)."""

QUICK: tuple[str, ...] = (
    "wheelbase_plus3",
    "right_wheel_big",
    "caster_drag",
    "probe_long",
    "gear_eccentric_j2",
)
"""The ``--quick`` subset."""


def case_by_name(name: str) -> Case:
    """The case called ``name``; a ``KeyError`` listing the known ones otherwise."""
    for c in CASES:
        if c.name == name:
            return c
    raise KeyError(f"no independent case {name!r}; known: {', '.join(c.name for c in CASES)}")


def _check() -> None:
    names = [c.name for c in CASES]
    if len(set(names)) != len(names):
        raise ValueError("independent case names must be unique")


_check()
