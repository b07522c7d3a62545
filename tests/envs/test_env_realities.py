"""The envs simulate a reality file: per-episode robots drawn from its boxes
(``randomize``) and a default estimator calibrated to it (``estimator_reality``)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import realitygap  # noqa: F401  (registers the envs)
from realitygap.robots.effects import Reality, make_effect

BIG_WHEELS = {"effects": [{"name": "wheel_radius_scale", "values": {"scale": 1.04}}]}
FAST_ENCODERS = {"effects": [{"name": "encoder_scale", "values": {"scale": 0.96}}]}
UNEVEN_ENCODERS = {"effects": [{"name": "encoder_ratio", "values": {"E_c": 1.03}}]}


def test_each_episode_draws_its_robot_from_the_episode_seed() -> None:
    env = gym.make(
        "realitygap/WheeledNav-v0",
        reality=Reality((make_effect("command_latency", delay=0.05),)),
        randomize={"command_latency.delay": (0.02, 0.1), "wheelbase_error.E_b": (0.98, 1.02)},
    )
    base = env.unwrapped
    robots = []
    for seed in (1, 2, 1):
        env.reset(seed=seed)
        robots.append(base.reality.to_dict())
        assert 0.02 <= base.reality.effects[0].values["delay"] <= 0.1
        assert base.true_params.wheelbase != base.params.wheelbase
    env.close()
    assert robots[0] == robots[2] and robots[0] != robots[1]
    assert base.nominal_reality.effects[0].values["delay"] == 0.05  # the centre is kept


def _straight_error(make, estimator_reality):  # type: ignore[no-untyped-def]
    env = make(estimator_reality)
    _, info = env.reset(seed=0)
    for _ in range(40):
        *_, info = env.step(np.array([1.0, 0.0], dtype=np.float32))
    err = float(
        np.linalg.norm(np.asarray(info["true_pose"])[:2] - np.asarray(info["estimated_pose"])[:2])
    )
    env.close()
    return err


@pytest.mark.parametrize("reality", [BIG_WHEELS, FAST_ENCODERS, UNEVEN_ENCODERS])
def test_an_estimator_calibrated_to_the_reality_removes_its_odometry_drift(reality) -> None:  # type: ignore[no-untyped-def]
    def make(est):  # type: ignore[no-untyped-def]
        return gym.make(
            "realitygap/WheeledNav-v0",
            reality=reality,
            estimator_reality=est,
            n_obstacles=0,
            start=(0.0, 0.0, 0.0),
            goal=(1.5, 1.5, 0.0),
        )

    drift = _straight_error(make, None)
    calibrated = _straight_error(make, reality)
    assert drift > 0.02  # 4 % of the distance driven
    assert calibrated < 0.1 * drift


@pytest.mark.parametrize("reality", [BIG_WHEELS, FAST_ENCODERS])
def test_the_vector_env_calibrates_its_odometry_alike(reality) -> None:  # type: ignore[no-untyped-def]
    def run(est):  # type: ignore[no-untyped-def]
        env = gym.make_vec(
            "realitygap/WheeledNavVec-v0",
            num_envs=2,
            reality=reality,
            estimator_reality=est,
            n_obstacles=0,
            start=(0.0, 0.0, 0.0),
            goal=(1.5, 1.5, 0.0),
        )
        env.reset(seed=0)
        for _ in range(40):
            *_, info = env.step(np.tile([1.0, 0.0], (2, 1)).astype(np.float32))
        err = np.linalg.norm(info["true_pose"][:, :2] - info["estimated_pose"][:, :2], axis=1)
        env.close()
        return float(err.max())

    drift, calibrated = run(None), run(reality)
    assert drift > 0.02 and calibrated < 0.1 * drift


def test_an_estimator_and_an_estimator_reality_are_not_both_taken() -> None:
    from realitygap.envs.wheeled_nav import default_estimator
    from realitygap.robots.diffdrive import DiffDriveParams

    with pytest.raises(ValueError, match="estimator and estimator_reality are both given"):
        gym.make(
            "realitygap/WheeledNav-v0",
            estimator=default_estimator(DiffDriveParams()),
            estimator_reality=BIG_WHEELS,
        )


@pytest.mark.parametrize(
    ("env_id", "kwargs", "words"),
    [
        ("realitygap/WheeledNav-v0", {"randomize": {"arm_backlash.b2": (0, 1e-3)}}, "arm_backlash"),
        (
            "realitygap/WheeledNav-v0",
            {"randomize": {"wheelbase_error.E_b": (0.5, 1.0)}},
            "physical bounds",
        ),
        ("realitygap/WheeledNav-v0", {"reality": ""}, "empty path"),
        ("realitygap/WheeledNav-v0", {"reality": 3}, "reality file's path"),
        (
            "realitygap/ArmCalib-v0",
            {"randomize": {"arm_backlash.b2": (0, 1e-3)}, "randomize_reality": True},
            "both given",
        ),
    ],
)
def test_bad_reality_arguments_are_refused(env_id, kwargs, words) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises((ValueError, TypeError), match=words):
        gym.make(env_id, **kwargs)


def test_a_missing_reality_file_names_the_path(tmp_path) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError, match=r"no such file: .*nothing\.json"):
        gym.make("realitygap/WheeledNav-v0", reality=str(tmp_path / "nothing.json"))
