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

import realitygap  # noqa: F401  (registers the envs)
from realitygap import ENV_IDS

NAN, INF = math.nan, math.inf
BAD_TYPES = ["a", None, [1.0], True]

# argument → values that must be refused; 0 or negatives only where they are invalid
COMMON_RATES = {
    "physics_hz": [*BAD_TYPES, NAN, INF, 0, -240.0, 1e9],
    "control_hz": [*BAD_TYPES, NAN, 0, -20.0, 1e6, 7.0],
}
TABLE: dict[str, dict[str, list[object]]] = {
    "realitygap/WheeledNav-v0": {
        **COMMON_RATES,
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
        "reality": ["a", 1.0],
        "board": ["a", 1.0],
        "view": ["a", 1.0],
    },
    "realitygap/WallClimb-v0": {
        **COMMON_RATES,
        "success_tol": [*BAD_TYPES, NAN, 0, -1.0, 1e6],
        "detach_margin": [*BAD_TYPES, NAN, 0, -1.0, 1e6],
        "faults": ["a", 1.0],
        "reality": ["a", 1.0],
        "reward_weights": ["a", 1.0],
        "estimator": [1.0, None],
    },
}

CASES = [
    pytest.param(env_id, arg, value, id=f"{env_id.split('/')[1]}-{arg}-{value!r}")
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
