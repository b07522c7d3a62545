"""Every env keyword argument over every env id: a bad value fails at construction.

The table lists, per env id, each scalar keyword argument with the values that
must be refused (bad types, NaN, zero, negative, huge). ``gym.make`` must raise
``TypeError``/``ValueError`` whose message names the argument and shows the value
— before any simulation is built, so every case is cheap.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import realitygap
from realitygap import ENV_IDS

NAN, INF = math.nan, math.inf
BAD_TYPES = ["a", None, [1.0], True]

# argument → values that must be refused; 0 or negatives only where they are invalid
COMMON_RATES = {
    "physics_hz": [*BAD_TYPES, NAN, INF, 0, -240.0, 1e9],
    "control_hz": [*BAD_TYPES, NAN, 0, -20.0, 1e6, 7.0],
}
BAD_POSE3 = ["origin", [NAN, 0.0, 0.0], [0.0, 0.0], [[0.0, 0.0, 0.0]], [100.0, 0.0, 0.0]]
BAD_ESTIMATOR = ["ekf", 42, object()]
TABLE: dict[str, dict[str, list[object]]] = {
    "realitygap/WheeledNav-v0": {
        **COMMON_RATES,
        "obstacles": ["none", "a", 3, [1, 2], {"a": 1}],
        "start": BAD_POSE3,
        "goal": BAD_POSE3,
        "estimator": BAD_ESTIMATOR,
        "sensor_mode": ["xray", 3],
        "render_mode": ["human3d"],  # a non-str fails in gym.make itself
        "n_obstacles": [*BAD_TYPES, NAN, -1, 2.5, 10_000, 1e18],
        "room_half_size": [*BAD_TYPES, NAN, INF, 0, -3.5, 1e6],
        "success_pos_tol": [*BAD_TYPES, NAN, 0, -1.0, 1e6],
        "success_ang_tol": [*BAD_TYPES, NAN, 0, -1.0, 100.0],
        "n_beams": [*BAD_TYPES, NAN, 0, -5, 2.5, 10**9],
        "scan_hz": [*BAD_TYPES, NAN, 0, -10.0, 1e6],
        "camera_hz": [*BAD_TYPES, NAN, 0, -20.0, 1e6],
        "terminate_on_success": ["yes", 1, None],
        "reward_weights": ["a", 1.0],
        "params": ["a", 1.0],
        "reality": ["a", 1.0],
    },
    "realitygap/ArmCalib-v0": {
        "budget": [*BAD_TYPES, NAN, 0, -1, 2.5, 10**9],
        "n_validation": [*BAD_TYPES, NAN, 0, -1, 3, 2.5, 10**9],
        "validation_seed": [*BAD_TYPES, NAN, -1, 2.5],
        "min_poses": [*BAD_TYPES, NAN, 0, -1, 2.5],
        "identify_every": [*BAD_TYPES, NAN, 0, -1, 2.5],
        "invalid_penalty": [*BAD_TYPES, NAN, INF, -1.0, 1e9],
        "randomize_reality": ["yes", 1, None],
        "params": ["a", 1.0],
        "reality": ["a", 1.0, {"no_such_effect": {}}, {"command_latency": {"delay": 0.05}}],
        "board": ["a", 1.0],
        "view": ["a", 1.0],
        "identification": ["lm", 1.0],
        "measurement": ["a", 1.0],
        "placement": ["a", 1.0],
        "joint_center": ["home", [NAN] * 6, [0.0, 0.0], None],
        "joint_half_range": ["a", [-0.1] * 6, [0.0] * 6, [INF] * 6, [0.1] * 5],
        "estimator": ["mdh", 42, object()],
        "sensor_mode": ["xray", 3],
    },
    "realitygap/WallClimb-v0": {
        **COMMON_RATES,
        "success_tol": [*BAD_TYPES, NAN, 0, -1.0, 1e6],
        "detach_margin": [*BAD_TYPES, NAN, 0, -1.0, 1e6],
        "faults": ["a", 1.0],
        "reality": ["a", 1.0, {"wheelbase_error": {"E_b": 1.02}}],
        "reward_weights": ["a", 1.0],
        "estimator": [1.0, None, "psychic", object()],
        "start": ["dock", [NAN, 0.0], [0.0], [1.0, 0.5, 0.0, 0.0], [100.0, 100.0]],
        "goal": ["dock", [INF, 0.0], [1.0, 0.5, 0.0], [100.0, 100.0]],
        "vio_config": ["default", 1.0],
        "params": ["a", 1.0],
        "sensor_mode": ["xray", 3],
    },
}

VEC_ID = "realitygap/WheeledNavVec-v0"
VEC_TABLE: dict[str, list[object]] = {
    "num_envs": [*BAD_TYPES, NAN, 0, -1, 2.5],
    "n_obstacles": [*BAD_TYPES, NAN, -1, 2.5, 10**6],
    "room_half_size": [*BAD_TYPES, NAN, INF, 0, -3.5, 1e6],
    "success_pos_tol": [*BAD_TYPES, NAN, 0, -1.0, 1e6],
    "success_ang_tol": [*BAD_TYPES, NAN, 0, -1.0, 100.0],
    "control_hz": [*BAD_TYPES, NAN, INF, 0, -20.0, 1e9],
    "scan_hz": [*BAD_TYPES, NAN, 0, -10.0, 1e6, 7.3],
    "n_beams": [*BAD_TYPES, NAN, 0, 1, 2.5, 10**9],
    "max_episode_steps": [*BAD_TYPES, NAN, 0, -1, 2.5],
    "history_steps": [*BAD_TYPES, NAN, 0, -1, 2.5, 10**9],
    "terminate_on_success": ["yes", 1, None],
    "reward_weights": ["a", 1.0],
    "params": ["a", 1.0],
    "obstacles": ["none", 3, [1, 2]],
    "start": BAD_POSE3,
    "goal": BAD_POSE3,
    "reality": ["worn", 1.0, {"no_such_effect": {}}, {"command_latency": {"delay": -1.0}}],
    "randomize": ["yes", 1.0, {"no_such_effect": {}}, {"command_latency": {"delay": (0.5, 0.1)}}],
    "render_mode": ["human"],
}


def _id(value: object) -> str:
    """A test id that is the same in every process (an object's repr holds its address)."""
    text = repr(value)
    return f"<{type(value).__name__}>" if " at 0x" in text else text


VEC_CASES = [
    pytest.param(arg, value, id=f"vec-{arg}-{_id(value)}")
    for arg, values in VEC_TABLE.items()
    for value in values
]

CASES = [
    pytest.param(env_id, arg, value, id=f"{env_id.split('/')[1]}-{arg}-{_id(value)}")
    for env_id, args in TABLE.items()
    for arg, values in args.items()
    for value in values
]


def test_table_covers_every_env_id() -> None:
    assert set(TABLE) == set(ENV_IDS)


@pytest.mark.parametrize(("env_id", "arg", "value"), CASES)
def test_bad_argument_is_refused_at_construction(env_id: str, arg: str, value: object) -> None:
    with pytest.raises((TypeError, ValueError)) as info:
        env = gym.make(env_id, **{arg: value})
        env.close()
    message = str(info.value)
    assert arg in message, message
    if isinstance(value, (int, float)) and not isinstance(value, bool) and arg != "control_hz":
        assert (repr(value) in message) or (f"{value:g}" in message) or str(value) in message


@pytest.mark.parametrize(("arg", "value"), VEC_CASES)
def test_bad_vector_argument_is_refused_at_construction(arg: str, value: object) -> None:
    kwargs: dict[str, object] = {"num_envs": 2, arg: value}
    with pytest.raises((TypeError, ValueError)) as info:
        env = gym.make_vec(VEC_ID, **kwargs)
        env.close()
    assert arg in str(info.value), str(info.value)


@pytest.mark.parametrize("value", [0, math.nan])
def test_room_half_size_names_its_physical_range(value: float) -> None:
    for make in (
        lambda: gym.make("realitygap/WheeledNav-v0", room_half_size=value),
        lambda: gym.make_vec(VEC_ID, num_envs=2, room_half_size=value),
    ):
        with pytest.raises(ValueError, match=r"room_half_size must be .* in \[1, 50\] m"):
            make()


BAD_SEEDS = [-1, "zero", 1.5, True, [0], np.float64(1.0)]


@pytest.fixture(scope="module", params=ENV_IDS)
def made_env(request: pytest.FixtureRequest) -> object:
    env = gym.make(request.param)
    yield env
    env.close()


@pytest.mark.parametrize("seed", BAD_SEEDS, ids=repr)
def test_bad_seed_is_refused_by_reset(made_env: gym.Env, seed: object) -> None:
    with pytest.raises((TypeError, ValueError), match="seed"):
        made_env.reset(seed=seed)


def test_numpy_integer_seed_is_a_seed() -> None:
    env = gym.make("realitygap/WheeledNav-v0")
    try:
        a, _ = env.reset(seed=np.int64(3))
        b, _ = env.reset(seed=3)
        np.testing.assert_array_equal(a, b)
    finally:
        env.close()


@pytest.mark.parametrize("seed", [*BAD_SEEDS, [0, -1], [0, "a"]], ids=repr)
def test_bad_seed_is_refused_by_vector_reset(seed: object) -> None:
    env = gym.make_vec(VEC_ID, num_envs=2)
    try:
        with pytest.raises((TypeError, ValueError), match="seed"):
            env.reset(seed=seed)
    finally:
        env.close()


def test_vector_env_applies_a_reality_mapping() -> None:
    from realitygap.robots.effects import Reality, make_effect

    env = gym.make_vec(VEC_ID, num_envs=2, reality={"command_latency": {"delay": 0.05}})
    try:
        assert env.unwrapped.reality.effect_names == ("command_latency",)
        assert env.unwrapped.fixed_values["command_latency.delay"] == 0.05
    finally:
        env.close()
    full = Reality((make_effect("command_latency", delay=0.05),)).to_dict()
    env = gym.make_vec(VEC_ID, num_envs=2, reality=full)
    try:
        assert env.unwrapped.fixed_values["command_latency.delay"] == 0.05
    finally:
        env.close()


def test_min_poses_above_budget_names_both() -> None:
    with pytest.raises(ValueError, match=r"min_poses.*budget=20"):
        gym.make("realitygap/ArmCalib-v0", min_poses=1000)
    with pytest.raises(ValueError, match=r"min_poses.*budget=5"):
        gym.make("realitygap/ArmCalib-v0", budget=5)


@pytest.mark.parametrize("env_id", ["realitygap/WheeledNav-v0", "realitygap/WallClimb-v0"])
def test_estimator_protocol_lists_the_missing_methods(env_id: str) -> None:
    class HalfEstimator:
        def reset(self, initial: object = None) -> None: ...

    with pytest.raises(TypeError, match=r"estimator must .*lacks update\(measurement\)"):
        gym.make(env_id, estimator=HalfEstimator())


def test_arm_estimator_protocol_lists_the_missing_methods() -> None:
    with pytest.raises(TypeError, match=r"estimator .*reset\(\).*update\(measurement.*estimate"):
        gym.make("realitygap/ArmCalib-v0", estimator="mdh")


@pytest.mark.parametrize(
    ("module", "cls"),
    [
        ("realitygap.envs.tasks.nav", "NavRewardWeights"),
        ("realitygap.envs.tasks.wall_climb", "WallClimbRewardWeights"),
        ("realitygap.envs.tasks.arm_calib", "ArmCalibRewardWeights"),
        ("realitygap.envs.tasks.arm_calib", "ViewConstraints"),
    ],
)
@pytest.mark.parametrize("value", [NAN, INF, "a", None, True])
def test_settings_fields_are_finite_numbers(module: str, cls: str, value: object) -> None:
    import dataclasses
    import importlib

    kind = getattr(importlib.import_module(module), cls)
    field = dataclasses.fields(kind)[0].name
    with pytest.raises((TypeError, ValueError), match=field):
        kind(**{field: value})


def test_room_that_cannot_hold_the_obstacles_is_named() -> None:
    with pytest.raises(
        ValueError, match=r"n_obstacles must be a non-negative integer in \[0, 189\]"
    ):
        gym.make("realitygap/WheeledNav-v0", n_obstacles=10_000)


@pytest.mark.slow
def test_crowded_room_fails_fast_instead_of_hanging() -> None:
    from realitygap.envs.layouts import random_layout

    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="cannot hold them"):
        random_layout(rng, 150, 3.5, [(-2.0, -2.0), (2.0, 2.0)], 0.45, 0.2)


def test_string_action_names_dtype_and_shape() -> None:
    env = gym.make("realitygap/WheeledNav-v0")
    try:
        env.reset(seed=0)
        with pytest.raises(TypeError, match=r"action must be a float array of shape \(2,\)"):
            env.step("a")
        with pytest.raises(TypeError, match=r"dtype <U1"):
            env.step(np.array(["a", "b"]))
    finally:
        env.close()


def test_arm_step_before_reset_is_refused() -> None:
    env = gym.make("realitygap/ArmCalib-v0")
    try:
        with pytest.raises(RuntimeError, match="call reset"):
            env.unwrapped.step(np.zeros(6, np.float32))
    finally:
        env.close()


# --------------------------------------------------------------- state errors and reset options
@pytest.mark.parametrize(
    "env_id", ["realitygap/WheeledNav-v0", "realitygap/ArmCalib-v0", "realitygap/WallClimb-v0"]
)
def test_closed_env_says_it_is_closed(env_id: str) -> None:
    import gymnasium as gym
    from gymnasium.error import ResetNeeded

    assert env_id in realitygap.ENV_IDS
    env = gym.make(env_id, render_mode="rgb_array")
    with pytest.raises(ResetNeeded, match="call reset"):
        env.unwrapped.step(env.action_space.sample())
    env.reset(seed=0)
    env.close()
    for call in (
        lambda: env.step(env.action_space.sample()),
        lambda: env.reset(seed=0),
        env.unwrapped.render,
    ):
        with pytest.raises(RuntimeError, match=r"closed env.*gymnasium\.make\('" + env_id):
            call()


def test_every_env_id_is_covered() -> None:

    assert set(realitygap.ENV_IDS) == {
        "realitygap/WheeledNav-v0",
        "realitygap/ArmCalib-v0",
        "realitygap/WallClimb-v0",
    }


@pytest.mark.parametrize(
    "env_id", ["realitygap/WheeledNav-v0", "realitygap/ArmCalib-v0", "realitygap/WallClimb-v0"]
)
@pytest.mark.parametrize("options", ["x", ["start"], 3])
def test_reset_options_must_be_a_mapping(env_id: str, options: object) -> None:
    import gymnasium as gym

    env = gym.make(env_id)
    try:
        with pytest.raises(TypeError, match="options must be None or a dict"):
            env.reset(seed=0, options=options)
        with pytest.raises(ValueError, match=r"unknown reset option.*'nope'"):
            env.reset(seed=0, options={"nope": 1})
    finally:
        env.close()
