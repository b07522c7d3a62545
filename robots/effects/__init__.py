"""Effects: named, parameterised ways in which a real robot differs from its model.

The vocabulary (:class:`Effect`, :class:`ParamSpec`, :class:`BlindRange`,
:class:`Stage`, :class:`Channel`, :class:`Reality`) lives in
:mod:`~realitygap.robots.effects.base`; the effects of each robot in one module
(:mod:`~realitygap.robots.effects.diffdrive`,
:mod:`~realitygap.robots.effects.arm`,
:mod:`~realitygap.robots.effects.climber`), one class per effect. Importing this
package registers them all in :data:`EFFECTS`.

Adding an effect is writing one class in its robot's module: registration,
the diagnosis library, the blind suite and the surrogate read it from there.
"""

from __future__ import annotations

from realitygap.robots.effects import arm as _arm  # noqa: F401  (registers the arm's effects)
from realitygap.robots.effects import climber as _climber  # noqa: F401
from realitygap.robots.effects import diffdrive as _diffdrive  # noqa: F401
from realitygap.robots.effects import diffdrive_drivetrain as _drivetrain  # noqa: F401
from realitygap.robots.effects.arm import (
    arm_base_compliance,
    arm_measurement_scale,
    arm_tool_offset,
)
from realitygap.robots.effects.base import (
    EFFECTS,
    LIBRARY_VERSION,
    BlindRange,
    Channel,
    CommandHook,
    Effect,
    EffectArgumentError,
    ParamSpec,
    Reality,
    Stage,
    TicksHook,
    WheelHook,
    make_effect,
    pipeline_key,
    pipeline_order,
    register_effect,
    register_robot,
    robot_of_params,
)
from realitygap.robots.effects.twin import Twin, draw_reality, load_reality

__all__ = [
    "EFFECTS",
    "LIBRARY_VERSION",
    "BlindRange",
    "Channel",
    "CommandHook",
    "Effect",
    "EffectArgumentError",
    "ParamSpec",
    "Reality",
    "Stage",
    "TicksHook",
    "Twin",
    "WheelHook",
    "arm_base_compliance",
    "arm_measurement_scale",
    "arm_tool_offset",
    "blind_ranges",
    "draw_reality",
    "library",
    "load_reality",
    "make_effect",
    "pipeline_key",
    "pipeline_order",
    "register_effect",
    "register_robot",
    "robot_of_params",
]

# The blind suite of library version 1 draws in this order; it is kept so that
# seeded suite figures stay what they were. Effects of later versions follow in
# registration order.
_BLIND_ORDER_V1 = (
    "wheel_radius_scale",
    "wheel_diameter_ratio",
    "wheelbase_error",
    "longitudinal_slip",
    "command_latency",
    "motor_deadband",
    "velocity_saturation",
    "encoder_scale",
    "camera_mount_offset",
    "timestamp_offset",
    "arm_joint_offset",
    "arm_link_length",
    "arm_parallel_twist",
    "arm_tool_offset",
    "arm_twist_error",
    "arm_joint_compliance",
    "arm_backlash",
    "arm_encoder_scale",
    "climber_tether_sag",
    "climber_anchor_error",
    "climber_spool_scale",
    "climber_adsorption_gap",
)


def library(robot: str, version: int = LIBRARY_VERSION) -> tuple[str, ...]:
    """Names of ``robot``'s effects in library ``version``, in registration order."""
    return tuple(n for n, c in EFFECTS.items() if c.robot == robot and c.since <= version)


def blind_ranges(robot: str, version: int = LIBRARY_VERSION) -> dict[str, tuple[BlindRange, ...]]:
    """The blind suite's table of ``robot``: effect name → its :attr:`Effect.blind` ranges.

    Only effects of library ``version`` that have a blind range, in the
    suite's draw order.
    """
    names = [n for n in library(robot, version) if EFFECTS[n].blind]
    registered = list(EFFECTS)

    def order(name: str) -> tuple[int, int]:
        if name in _BLIND_ORDER_V1:
            return (0, _BLIND_ORDER_V1.index(name))
        return (1, registered.index(name))

    return {n: EFFECTS[n].blind for n in sorted(names, key=order)}
