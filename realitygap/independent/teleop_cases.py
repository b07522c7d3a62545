"""The 20 fixed test cases of the independent teleoperation world.

Every case is a robot of the :class:`~realitygap.independent.teleop.TeleopRobot`
size with a set of hidden effects (:class:`~realitygap.independent.teleop.TeleopHidden`
field values) and the answer a sim-to-real gap diagnosis should give:

* 3 nominal robots: nothing should be named (``nominal=True``, ``accepted=()``);
* 10 in-library cases: ``accepted`` lists the diagnosis-library effect names
  that are the physical equivalent of the hidden mechanism;
* 7 out-of-library cases: mechanisms no library name models; nothing should be
  named (``accepted=()``).

The list was fixed before any data were generated and must not be tuned to
results.

Replays
-------
``drives`` says which replays can show a case: ``"commands"`` (the logged
joystick commands drive the replay, so every effect between the command and
the ground truth shows) and ``"ticks"`` (the logged encoder counts drive the
replay, so only what happens after the wheels shows: geometry, wheel scale,
slip, ground-truth faults; not delays, limits, dead zones or drive-train
dynamics).

:meth:`TeleopCase.expected` gives the names accepted for one replay:
``accepted`` plus ``command_aliases`` for a command replay, and the
tick-visible part of ``accepted`` plus ``ticks_aliases`` for a tick replay.

Aliases are names that are kinematically indistinguishable from the hidden
mechanism in that replay:

* an encoder counting ``k`` times its datasheet counts per revolution makes
  the firmware turn the wheels ``1/k`` as fast (its speed loop believes the
  counts) and makes the counts ``k`` times too many per metre, so from
  commands *and* from ticks it is the same as wheels ``1/k`` as large;
  conversely wheels ``s`` as large are the same as encoders counting ``1/s``;
* unequal wheel diameters and unequal encoder counts per revolution are the
  same pair for the wheel ratio.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["LIBRARY_NAMES", "TELEOP_CASES", "TICKS_SHOWABLE", "TeleopCase"]

#: The diagnosis-library effect names a case may accept.
LIBRARY_NAMES: tuple[str, ...] = (
    "wheel_radius_scale",
    "wheel_diameter_ratio",
    "wheelbase_error",
    "longitudinal_slip",
    "traction_slip",
    "command_latency",
    "motor_deadband",
    "velocity_saturation",
    "encoder_scale",
    "encoder_ratio",
    "wheel_velocity_lag",
    "acceleration_limits",
    "wheel_dead_zone",
    "torque_speed_saturation",
    "timestamp_offset",
)

#: Library names whose mechanism sits after the wheels (or in the count-to-
#: metre conversion), so that a replay driven by the logged counts shows them.
TICKS_SHOWABLE: frozenset[str] = frozenset(
    {
        "wheel_radius_scale",
        "wheel_diameter_ratio",
        "wheelbase_error",
        "longitudinal_slip",
        "traction_slip",
        "encoder_scale",
        "encoder_ratio",
        "timestamp_offset",
    }
)


@dataclass(frozen=True)
class TeleopCase:
    """One test case: hidden effects and the expected diagnosis.

    Parameters
    ----------
    name : str
        Unique case name (never written into the generated data).
    hidden : dict
        :class:`~realitygap.independent.teleop.TeleopHidden` field names
        mapped to values; missing fields keep their "no effect" default.
    accepted : tuple of str
        Library effect names that are the physical equivalent of the hidden
        mechanism in a command-driven replay; ``()`` when nothing should be
        named (nominal and out-of-library cases).
    note : str
        What the hidden mechanism is and how it shows.
    drives : tuple of str
        Replays that can show the case: ``"commands"`` and/or ``"ticks"``.
    nominal : bool
        True for the robots with no hidden effect at all.
    ticks_aliases : tuple of str
        Extra names accepted in a tick-driven replay (kinematic aliases).
    command_aliases : tuple of str
        Extra names accepted in a command-driven replay (kinematic aliases).
    motion : str
        Joystick style: ``"normal"`` or ``"aggressive"`` (hard accelerations).
    """

    name: str
    hidden: dict = field(default_factory=dict)
    accepted: tuple[str, ...] = ()
    note: str = ""
    drives: tuple[str, ...] = ("commands", "ticks")
    nominal: bool = False
    ticks_aliases: tuple[str, ...] = ()
    command_aliases: tuple[str, ...] = ()
    motion: str = "normal"

    @property
    def in_library(self) -> bool:
        """True when a library name is the right answer."""
        return bool(self.accepted)

    def expected(self, drive: str) -> tuple[str, ...]:
        """Names a diagnosis may give for this case in one replay.

        Parameters
        ----------
        drive : str
            ``"commands"`` or ``"ticks"``.

        Returns
        -------
        tuple of str
            Accepted names; ``()`` means nothing should be named (also when
            the replay cannot show the case).
        """
        if drive not in ("commands", "ticks"):
            raise ValueError(f"unknown drive {drive!r}")
        if drive not in self.drives or not self.accepted:
            return ()
        if drive == "commands":
            return self.accepted + self.command_aliases
        shown = tuple(n for n in self.accepted if n in TICKS_SHOWABLE)
        return shown + self.ticks_aliases if shown else ()


TELEOP_CASES: tuple[TeleopCase, ...] = (
    # ------------------------------------------------------------------ nominal
    TeleopCase(
        name="nominal_a",
        hidden={},
        note="Nominal robot, ordinary teleop driving.",
        nominal=True,
    ),
    TeleopCase(
        name="nominal_b_aggressive",
        hidden={},
        note="Nominal robot driven with hard accelerations (within the 3 m/s2 "
        "rating); the floor grips, so there is no slip. Control for the "
        "traction case.",
        nominal=True,
        motion="aggressive",
    ),
    TeleopCase(
        name="nominal_c",
        hidden={},
        note="Nominal robot, ordinary teleop driving (second nominal sample).",
        nominal=True,
    ),
    # ------------------------------------------------------------- in library
    TeleopCase(
        name="wheelbase_plus_2p5pct",
        hidden={"wheelbase_factor": 1.025},
        accepted=("wheelbase_error",),
        note="True wheelbase 2.5 % longer than nominal: the robot turns "
        "1/1.025 as much as commanded / as the counts say.",
    ),
    TeleopCase(
        name="wheelbase_minus_2pct",
        hidden={"wheelbase_factor": 0.98},
        accepted=("wheelbase_error",),
        note="True wheelbase 2 % shorter than nominal: over-turns by 1/0.98.",
    ),
    TeleopCase(
        name="wheel_diameter_ratio_1p012",
        hidden={"wheel_radius_ratio": 1.012},
        accepted=("wheel_diameter_ratio",),
        note="Right wheel 1.2 % larger than the left at a kept mean radius: "
        "the robot curves left when driving straight.",
        ticks_aliases=("encoder_ratio",),
        command_aliases=("encoder_ratio",),
    ),
    TeleopCase(
        name="wheels_3pct_smaller",
        hidden={"wheel_radius_scale": 0.97},
        accepted=("wheel_radius_scale",),
        note="Both wheels 3 % smaller (worn tyres): distances 0.97 of the "
        "commanded / counted ones, turns too (same wheelbase).",
        ticks_aliases=("encoder_scale",),
        command_aliases=("encoder_scale",),
    ),
    TeleopCase(
        name="encoder_4pct_more_counts",
        hidden={"encoder_counts_factor": 1.04},
        accepted=("encoder_scale",),
        note="Both encoders count 4 % more per revolution than the datasheet "
        "4096: the speed loop turns the wheels 1/1.04 as fast; counts-driven "
        "odometry overestimates distance by 4 %.",
        ticks_aliases=("wheel_radius_scale",),
        command_aliases=("wheel_radius_scale",),
    ),
    TeleopCase(
        name="command_delay_120ms",
        hidden={"command_delay_s": 0.12},
        accepted=("command_latency",),
        note="Commands reach the motor controllers 0.12 s late.",
        drives=("commands",),
    ),
    TeleopCase(
        name="top_speed_0p45",
        hidden={"top_speed_limit_mps": 0.45},
        accepted=("velocity_saturation", "torque_speed_saturation"),
        note="PWM voltage limited so that a wheel tops out at about 0.45 m/s "
        "(unloaded, nominal battery); a voltage limit also makes the top speed "
        "fall with load, hence both names. Teleop asks up to 0.6 m/s plus turn.",
        drives=("commands",),
    ),
    TeleopCase(
        name="wheel_dead_zones_40mms",
        hidden={"deadzone_left_mps": 0.04, "deadzone_right_mps": 0.04},
        accepted=("wheel_dead_zone", "motor_deadband"),
        note="Each wheel stands still while its set-point is below 0.04 m/s "
        "(driver dead band, integrator reset, static friction holds).",
        drives=("commands",),
    ),
    TeleopCase(
        name="traction_slip_mu_0p25",
        hidden={"friction_coefficient": 0.25},
        accepted=("traction_slip", "longitudinal_slip"),
        note="Slippery floor, mu = 0.25 (about 2.1 m/s2 of grip) under hard "
        "accelerations and stops: wheels spin up / lock faster than the body.",
        motion="aggressive",
    ),
    TeleopCase(
        name="wheelbase_plus_2pct_delay_80ms",
        hidden={"wheelbase_factor": 1.02, "command_delay_s": 0.08},
        accepted=("wheelbase_error", "command_latency"),
        note="Two effects: wheelbase +2 % and a 0.08 s command delay; a "
        "tick-driven replay shows only the wheelbase.",
    ),
    # ------------------------------------------------------- out of library
    TeleopCase(
        name="caster_side_drag",
        hidden={"caster_side_drag_n_per_radps": 8.0},
        note="A sticky caster 0.25 m behind the axle drags sideways in turns: "
        "lateral force 8 N per rad/s of turn rate, giving inward side-slip of "
        "the axle (tyre slip angle) and a yaw moment the speed loops absorb.",
    ),
    TeleopCase(
        name="out_of_round_right_wheel",
        hidden={"out_of_round_right": 0.02},
        note="Right wheel out of round: rolling radius varies as "
        "r(1 + 0.02 sin(wheel angle)); zero mean, heading wobbles once per "
        "wheel revolution.",
    ),
    TeleopCase(
        name="mocap_yaw_drift_3deg",
        hidden={"mocap_yaw_drift_rad": math.radians(3.0), "mocap_yaw_drift_period_s": 30.0},
        note="Motion-capture calibration fault: reported yaw has a 3 deg, "
        "30 s period sinusoidal drift (positions are right).",
    ),
    TeleopCase(
        name="right_motor_gain_sag_8pct",
        hidden={"right_motor_gain_sag": 0.08},
        note="Right motor heats up: torque and back-EMF constants drop "
        "linearly by 8 % over each run; the speed loop hides most of it.",
        drives=("commands",),
    ),
    TeleopCase(
        name="floor_slope_2deg",
        hidden={"floor_slope_rad": math.radians(2.0)},
        note="Floor tilted 2 deg: gravity pulls along the slope; speed loops "
        "absorb the longitudinal part, tyres creep downhill sideways.",
    ),
    TeleopCase(
        name="right_loop_oscillation_3hz",
        hidden={"right_torque_ripple_nm": 0.5, "right_torque_ripple_hz": 3.0},
        note="Right drive oscillates at 3 Hz (0.5 N m torque ripple from a "
        "drive-train resonance); the wheel speed wobbles, heading weaves. "
        "Counts record the wobble, so only commands show it.",
        drives=("commands",),
    ),
    TeleopCase(
        name="mocap_occlusion_hold",
        hidden={"mocap_occlusion_rate_hz": 1.0 / 12.0, "mocap_occlusion_mean_s": 1.2},
        note="Motion-capture occlusions (about one per 12 s, about 1.2 s "
        "long) during which the ground truth holds its last pose, then jumps.",
    ),
)
