"""Named robots and conventions of the independent generator.

A :class:`Variant` is one world the generator can write: the differential drive's
nominal robot, firmware and motion capture (a :class:`~realitygap.independent.diffdrive.DriveRobot`)
with the sizes of its test paths, and the arm cell's laser tracker and probe
(a :class:`~realitygap.independent.ur10.Tracker` and a probe point). The values come
from common robots and instruments, not from what any diagnosis finds:

``default``
    A small research robot (the OptiOdom robot's declared geometry): wheels Ø 84 mm,
    wheelbase 0.20 m, 43.7:1 gear and 64 counts per motor turn, a 20 Hz control
    cycle, 0.113 m/s cruise, a wheel ramp of 0.075 m/s², motion capture at 100 Hz
    with 3 ms latency, 0.3 mm / 1.5 mrad noise; a 0.6 m UMBmark square and a
    0.45 m circle. Arm: the tracker 2.8 m from the base, 15 µm noise, a 0.109 m probe.
``large``
    A Pioneer-class robot: wheels Ø 0.15 m, wheelbase 0.38 m, 19.7:1 gear and 64
    counts per motor turn (a coarser 0.37 mm per tick), a 10 Hz control cycle,
    0.30 m/s cruise and 0.5 rad/s turns, a heavier body ramped as a twist (as a
    ``diff_drive_controller`` speed limiter does) at 0.093 m/s² and 0.3 rad/s², a
    slower motor (τ = 0.12 s), motion capture at 100 Hz with 5 ms latency, sampled
    off the control cycle; paths scaled to its size (1.5 m square, 1.0 m circle).
    Arm: a longer probe (0.16 m), the tracker on the other side of the cell 4.0 m
    away and 0.6 m up, 20 µm noise (a tracker's error grows with range), a cell
    warming by 1.5 K.
``fast_noisy``
    The default robot on other conventions: a 50 Hz control cycle (requests and
    ramp restated per cycle, the same speeds and accelerations in SI units), motion
    capture at 120 Hz with 11 ms latency, sampled off the control cycle, and three
    times the pose noise (0.9 mm, 4.5 mrad). Arm: the tracker 2.5 m away on the
    other side, three times the noise (45 µm), a cell warming by 4 K from 24 °C.

The UR10 geometry is the same in every variant: the laser-tracker format names
the arm (its importer reads the published UR10 table), so a UR5 written in it
would be read as a UR10.

The cases' hidden values are physical. Two of them are speeds that only mean the
same thing relative to the robot's own cruise (a motor that tops out below the
cruise, a dead zone a fraction of it): :func:`hidden_values` scales
:data:`SPEED_FIELDS` by the variant's cruise speed over the default's, and leaves
every ratio, time, angle, length and rate as it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from realitygap.independent.diffdrive import DriveRobot
from realitygap.independent.ur10 import PROBE, Tracker

__all__ = ["SPEED_FIELDS", "VARIANTS", "Variant", "hidden_values", "variant_by_name"]

SPEED_FIELDS: tuple[str, ...] = ("speed_cap", "stiction")
"""Fields of :class:`~realitygap.independent.diffdrive.Hidden` in m/s that scale with the
robot's cruise speed."""


@dataclass(frozen=True)
class Variant:
    """One named world of the independent generator.

    Attributes
    ----------
    name : str
    description : str
    drive : DriveRobot
        The differential drive's nominal robot, firmware and motion capture.
    square_side : float
        Side of the UMBmark training squares, m.
    circle_radius : float
        Radius of the held-out circle, m.
    tracker : Tracker
        The arm cell's laser tracker (pose, noise, temperature).
    probe : tuple of float
        Declared probe point in the flange frame, m.
    """

    name: str
    description: str
    drive: DriveRobot
    square_side: float
    circle_radius: float
    tracker: Tracker
    probe: tuple[float, float, float]

    def __post_init__(self) -> None:
        if not self.square_side > 0 or not self.circle_radius > 0:
            raise ValueError(
                f"variant {self.name}: square_side and circle_radius must be > 0 m, got "
                f"{self.square_side!r} and {self.circle_radius!r}"
            )
        if len(self.probe) != 3:
            raise ValueError(f"variant {self.name}: probe needs 3 values (m), got {self.probe!r}")


def _drive(
    *,
    diameter: float,
    wheelbase: float,
    gear: float,
    enc_res: float,
    cycle: float,
    cruise: float,
    turn_rate: float,
    accel: float,
    **conventions: Any,
) -> DriveRobot:
    """A :class:`DriveRobot` from SI speeds: ``cruise`` m/s, ``turn_rate`` rad/s, ``accel`` m/s².

    The requests are whole ticks per cycle (as a firmware takes them); the ramp is
    stated in ticks/cycle² to three significant digits.
    """
    m_per_tick = math.pi * diameter / (gear * enc_res)
    v_nom = float(round(cruise * cycle / m_per_tick))
    dv_max = float(f"{accel * cycle**2 / m_per_tick:.3g}")
    return DriveRobot(
        diameter=diameter,
        wheelbase=wheelbase,
        gear=gear,
        enc_res=enc_res,
        cycle=cycle,
        v_nom=v_nom,
        w_nom=turn_rate * cycle,
        dv_max=dv_max,
        **conventions,
    )


_DEFAULT_DRIVE = DriveRobot()

VARIANTS: dict[str, Variant] = {
    v.name: v
    for v in (
        Variant(
            "default",
            "small research robot (Ø 84 mm wheels, 0.20 m wheelbase, 20 Hz cycle, "
            "100 Hz mocap, 3 ms latency); UR10 with the tracker 2.8 m away, 15 µm noise",
            _DEFAULT_DRIVE,
            0.6,
            0.45,
            Tracker(),
            (float(PROBE[0]), float(PROBE[1]), float(PROBE[2])),
        ),
        Variant(
            "large",
            "Pioneer-class robot (Ø 0.15 m wheels, 0.38 m wheelbase, 0.37 mm/tick, 10 Hz "
            "cycle, body ramp 0.093 m/s², motor τ 0.12 s, 100 Hz mocap, 5 ms latency); UR10 "
            "with a 0.16 m probe, the tracker 4.0 m away, 20 µm noise",
            _drive(
                diameter=0.15,
                wheelbase=0.38,
                gear=19.7,
                enc_res=64.0,
                cycle=0.1,
                cruise=0.30,
                turn_rate=0.5,
                accel=0.093,
                motor_tau=0.12,
                ramp="body",
                angular_ramp=0.003,  # 0.3 rad/s² at 10 Hz
                mocap_rate=100.0,
                mocap_latency=0.005,
                mocap_phase=0.004,
            ),
            1.5,
            1.0,
            Tracker(
                position=(-3.2, 2.4, 0.6),
                yaw=-2.4,
                sigma=2.0e-5,
                temperature_start=20.5,
                temperature_rise=1.5,
            ),
            (0.0, 0.0, 0.16),
        ),
        Variant(
            "fast_noisy",
            "the default robot at a 50 Hz cycle, 120 Hz mocap with 11 ms latency and 3× the "
            "pose noise; UR10 with the tracker 2.5 m away on the other side, 45 µm noise",
            _drive(
                diameter=_DEFAULT_DRIVE.diameter,
                wheelbase=_DEFAULT_DRIVE.wheelbase,
                gear=_DEFAULT_DRIVE.gear,
                enc_res=_DEFAULT_DRIVE.enc_res,
                cycle=0.02,
                cruise=_DEFAULT_DRIVE.cruise_speed,
                turn_rate=_DEFAULT_DRIVE.w_nom / _DEFAULT_DRIVE.cycle,
                accel=_DEFAULT_DRIVE.dv_max * _DEFAULT_DRIVE.m_per_tick / _DEFAULT_DRIVE.cycle**2,
                motor_tau=_DEFAULT_DRIVE.motor_tau,
                mocap_rate=120.0,
                mocap_latency=0.011,
                mocap_phase=0.0031,
                mocap_pos_sigma=3.0 * _DEFAULT_DRIVE.mocap_pos_sigma,
                mocap_yaw_sigma=3.0 * _DEFAULT_DRIVE.mocap_yaw_sigma,
            ),
            0.6,
            0.45,
            Tracker(
                position=(1.4, 2.1, -0.3),
                yaw=-2.0,
                sigma=4.5e-5,
                temperature_start=24.0,
                temperature_rise=4.0,
            ),
            (float(PROBE[0]), float(PROBE[1]), float(PROBE[2])),
        ),
    )
}
"""The named variants (``default``, ``large``, ``fast_noisy``)."""


def variant_by_name(name: str) -> Variant:
    """The variant called ``name``; a ``ValueError`` listing the known names otherwise."""
    if not isinstance(name, str) or name not in VARIANTS:
        raise ValueError(
            f"variant must be one of {', '.join(VARIANTS)}, got {name!r}; pass --variant with "
            "one of these names"
        )
    return VARIANTS[name]


def hidden_values(values: dict[str, Any], variant: Variant) -> dict[str, Any]:
    """A case's hidden ``values`` for ``variant``: :data:`SPEED_FIELDS` scaled by the cruise ratio.

    A speed field planted at ``s`` m/s on the default robot becomes
    ``s · cruise(variant) / cruise(default)``; every other value is returned as it is.
    """
    ratio = variant.drive.cruise_speed / VARIANTS["default"].drive.cruise_speed
    return {
        k: (v * ratio if k in SPEED_FIELDS and math.isfinite(v) else v) for k, v in values.items()
    }
