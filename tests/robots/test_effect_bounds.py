"""Every effect checks its parameters against its own declared physical bounds, and a
:class:`Reality` checks its effects against the robot it is built onto."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from realitygap.estimators.diffdrive_model import UMBMARK_RATIO_BOUNDS, DiffDriveKinematics
from realitygap.robots.arm import ArmParams
from realitygap.robots.climber import ClimberParams
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import (
    EFFECTS,
    Effect,
    EffectArgumentError,
    Reality,
    make_effect,
    robot_of_params,
)

PARAMS = [(name, s) for name, cls in EFFECTS.items() for s in cls.specs]
IDS = [f"{name}.{s.name}" for name, s in PARAMS]
ROBOT_PARAMS = {"diffdrive": DiffDriveParams, "arm": ArmParams, "climber": ClimberParams}


def _names(effect: str, param: str) -> str:
    """A pattern requiring the effect's and the parameter's names in the message."""
    return rf"(?s)effect {re.escape(repr(effect))}.*{re.escape(repr(param))}"


# ------------------------------------------------------------------------ the specs


@pytest.mark.parametrize(("effect", "spec"), PARAMS, ids=IDS)
def test_declared_bounds_are_an_interval_holding_the_nominal(effect: str, spec) -> None:
    assert math.isfinite(spec.low) and math.isfinite(spec.high)
    assert spec.low < spec.high
    assert spec.low <= spec.nominal <= spec.high
    assert spec.unit
    if spec.log_scale:
        assert spec.low > 0.0


@pytest.mark.parametrize(
    ("effect", "param"),
    [
        ("command_latency", "delay"),
        ("motor_response", "tau"),
        ("wheel_velocity_lag", "tau_left"),
        ("wheel_velocity_lag", "tau_right"),
        ("torque_speed_saturation", "t_m"),
        ("traction_slip", "t_slip"),
        ("motor_deadband", "threshold"),
        ("wheel_dead_zone", "dz_left"),
        ("arm_backlash", "b1"),
        ("arm_joint_compliance", "c2"),
        ("arm_base_compliance", "k"),
        ("climber_tether_sag", "k"),
        ("climber_surface_deviation", "d"),
    ],
)
def test_delays_time_constants_plays_and_compliances_cannot_be_negative(
    effect: str, param: str
) -> None:
    assert EFFECTS[effect].spec(param).low == 0.0


@pytest.mark.parametrize(
    ("effect", "param"),
    [
        ("wheel_radius_scale", "scale"),
        ("wheel_diameter_ratio", "E_d"),
        ("wheelbase_error", "E_b"),
        ("encoder_scale", "scale"),
        ("encoder_ratio", "E_c"),
        ("climber_spool_scale", "s"),
        ("arm_camera_intrinsics", "f_scale"),
        ("velocity_saturation", "v_limit"),
        ("torque_speed_saturation", "v_top"),
        ("longitudinal_slip", "mu"),
    ],
)
def test_ratios_speeds_and_friction_are_positive(effect: str, param: str) -> None:
    assert EFFECTS[effect].spec(param).low > 0.0


@pytest.mark.parametrize("effect", list(EFFECTS))
def test_blind_draws_and_surrogate_examples_lie_within_the_bounds(effect: str) -> None:
    cls = EFFECTS[effect]
    for r in cls.blind:
        s = cls.spec(r.param)
        if r.absolute:
            values = [r.low, r.high]
        else:
            values = [s.nominal + r.low, s.nominal + r.high]
            values += [s.nominal - r.low, s.nominal - r.high] if r.symmetric else []
        for v in values:
            cls(**{r.param: v})
    cls(**dict(cls.surrogate_example))


# -------------------------------------------------------------- the one check


@pytest.mark.parametrize(("effect", "spec"), PARAMS, ids=IDS)
def test_nominal_and_the_bounds_themselves_are_accepted(effect: str, spec) -> None:
    assert make_effect(effect).values[spec.name] == spec.nominal
    for v in (spec.nominal, spec.low, spec.high, np.float64(spec.high)):
        e = make_effect(effect, **{spec.name: v})
        assert e[spec.name] == float(v) and type(e[spec.name]) is float
    assert EFFECTS[effect](**{spec.name: spec.low})[spec.name] == spec.low


@pytest.mark.parametrize(("effect", "spec"), PARAMS, ids=IDS)
def test_a_round_off_past_a_bound_is_the_bound(effect: str, spec) -> None:
    """A fit's transform to range positions and back may land an ulp outside."""
    assert make_effect(effect, **{spec.name: np.nextafter(spec.high, np.inf)})[spec.name] == (
        spec.high
    )
    assert make_effect(effect, **{spec.name: np.nextafter(spec.low, -np.inf)})[spec.name] == (
        spec.low
    )


@pytest.mark.parametrize(("effect", "spec"), PARAMS, ids=IDS)
@pytest.mark.parametrize("side", ["below low", "above high"])
def test_a_value_outside_the_bounds_is_refused(effect: str, spec, side: str) -> None:
    span = spec.high - spec.low
    value = spec.low - 0.01 * span if side == "below low" else spec.high + 0.01 * span
    with pytest.raises(ValueError, match=_names(effect, spec.name)) as info:
        make_effect(effect, **{spec.name: value})
    message = str(info.value)
    assert f"[{spec.low:g}, {spec.high:g}]" in message
    assert f"unit {spec.unit!r}" in message
    assert f"{value:g}" in message
    assert "Fix:" in message
    with pytest.raises(ValueError, match=_names(effect, spec.name)):
        EFFECTS[effect](**{spec.name: value})  # the constructor is the one entry


@pytest.mark.parametrize(("effect", "spec"), PARAMS, ids=IDS)
@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
def test_a_value_that_is_not_finite_is_refused(effect: str, spec, value: float) -> None:
    with pytest.raises(ValueError, match=_names(effect, spec.name) + ".*real finite number"):
        make_effect(effect, **{spec.name: value})


@pytest.mark.parametrize(("effect", "spec"), PARAMS, ids=IDS)
@pytest.mark.parametrize(
    "value",
    [True, False, np.bool_(True), "0.0", 1 + 0j, None, [0.0], np.zeros(1)],
    ids=["True", "False", "np.bool_", "str", "complex", "None", "list", "array"],
)
def test_a_value_that_is_not_a_real_number_is_refused(effect: str, spec, value: object) -> None:
    with pytest.raises(
        ValueError, match=_names(effect, spec.name) + ".*real finite number"
    ) as info:
        make_effect(effect, **{spec.name: value})
    assert isinstance(info.value, EffectArgumentError) and isinstance(info.value, TypeError)
    assert type(value).__name__ in str(info.value)


@pytest.mark.parametrize("effect", list(EFFECTS))
def test_an_unknown_parameter_is_refused_listing_the_known_ones(effect: str) -> None:
    cls = EFFECTS[effect]
    with pytest.raises(
        ValueError, match=rf"effect {re.escape(repr(effect))} has no parameter"
    ) as info:
        make_effect(effect, no_such_parameter=0.0)
    assert isinstance(info.value, TypeError)  # as Python's own unexpected keyword
    for s in cls.specs:
        assert s.name in str(info.value)
    if cls.specs:
        typo = cls.specs[0].name + "x"
        with pytest.raises(ValueError, match=rf"did you mean {re.escape(repr(cls.specs[0].name))}"):
            make_effect(effect, **{typo: cls.specs[0].nominal})


@pytest.mark.parametrize(
    ("effect", "values"),
    [
        ("command_latency", {"delay": -0.5}),
        ("command_latency", {"delay": 1e7}),
        ("motor_response", {"tau": -0.1}),
        ("wheel_radius_scale", {"scale": 1e6}),
        ("wheel_diameter_ratio", {"E_d": -1.0}),
        ("wheel_diameter_ratio", {"E_d": 0.0}),
    ],
)
def test_the_reported_instances_are_refused(effect: str, values: dict[str, float]) -> None:
    (param,) = values
    with pytest.raises(ValueError, match=_names(effect, param) + ".*outside its physical bounds"):
        make_effect(effect, **values)


def test_an_effect_round_trips_through_its_dict_and_a_bad_dict_is_refused() -> None:
    r = Reality((make_effect("command_latency", delay=0.1),))
    assert Reality.from_dict(r.to_dict()).effects[0].values == {"delay": 0.1}
    bad = {"effects": [{"name": "command_latency", "values": {"delay": -0.5}}]}
    with pytest.raises(ValueError, match=_names("command_latency", "delay")):
        Reality.from_dict(bad)


def test_every_effect_subclass_uses_the_base_check() -> None:
    """No effect overrides the constructor past the check."""
    for cls in EFFECTS.values():
        assert cls.__init__ is Effect.__init__
        assert cls.checked_values.__func__ is Effect.checked_values.__func__


# ------------------------------------------------------------------ reality × robot


def test_the_robot_of_each_robots_parameters_is_known() -> None:
    for robot, params in ROBOT_PARAMS.items():
        assert robot_of_params(params()) == robot
    assert robot_of_params(object()) is None
    assert {c.robot for c in EFFECTS.values()} == set(ROBOT_PARAMS)


@pytest.mark.parametrize("target", sorted(ROBOT_PARAMS))
@pytest.mark.parametrize("effect", list(EFFECTS))
def test_an_effect_for_another_robot_is_refused_with_a_value_error(
    effect: str, target: str
) -> None:
    reality = Reality((make_effect(effect),))
    params = ROBOT_PARAMS[target]()
    if EFFECTS[effect].robot == target:
        reality.check_robot(target)
        return
    pattern = (
        rf"effect {re.escape(repr(effect))} is for the {EFFECTS[effect].robot}; "
        rf"this reality is built onto a {target} robot.*effects for {target}: "
    )
    with pytest.raises(ValueError, match=pattern):
        reality.apply_params(params)
    with pytest.raises(ValueError, match=pattern):
        reality.check_robot(target)
    if target == "diffdrive":
        with pytest.raises(ValueError, match=pattern):
            reality.command_hooks(0.05, params)
        with pytest.raises(ValueError, match=pattern):
            reality.wheel_hooks(0.05, params)


def test_an_arm_effect_in_a_wheeled_nav_reality_is_a_value_error() -> None:
    gym = pytest.importorskip("gymnasium")
    import realitygap.envs  # noqa: F401  (registers the envs)

    reality = Reality((make_effect("arm_joint_offset", dtheta2=1e-3),))
    with pytest.raises(ValueError, match=r"'arm_joint_offset' is for the arm.*diffdrive robot"):
        gym.make("realitygap/WheeledNav-v0", reality=reality)


def test_a_reality_mixing_robots_is_refused() -> None:
    with pytest.raises(ValueError, match=r"one robot.*'arm_joint_offset' is for the arm"):
        Reality((make_effect("arm_joint_offset"), make_effect("command_latency")))
    assert Reality().robot is None
    assert Reality((make_effect("command_latency"),)).robot == "diffdrive"


# -------------------------------------------------------------------- UMBmark ratios

NOMINAL = DiffDriveKinematics(0.035, 0.035, 0.23, 2048.0)


@pytest.mark.parametrize("name", ["E_d", "E_b"])
@pytest.mark.parametrize("value", [-1.0, 0.0, 0.3, 2.5, math.nan, math.inf])
def test_umbmark_ratios_outside_their_physical_bounds_are_refused(name: str, value: float) -> None:
    args = {"E_d": 1.0, "E_b": 1.0, name: value}
    with pytest.raises(ValueError, match=rf"{name} must be a finite positive number near 1"):
        NOMINAL.with_umbmark(**args)


@pytest.mark.parametrize("value", ["1.0", True, None])
def test_umbmark_ratios_that_are_not_numbers_are_refused(value: object) -> None:
    with pytest.raises(TypeError, match="E_d must be a finite positive number near 1"):
        NOMINAL.with_umbmark(value, 1.0)


def test_umbmark_ratios_at_their_bounds_are_accepted() -> None:
    for v in UMBMARK_RATIO_BOUNDS:
        kin = NOMINAL.with_umbmark(v, v)
        assert kin.wheel_radius_right / kin.wheel_radius_left == pytest.approx(v)
        assert kin.wheelbase == pytest.approx(v * NOMINAL.wheelbase)
