"""Reality files with uncertainty (:mod:`realitygap.robots.effects.twin`): the boxes a
randomised twin draws from, the file's round trip, and its validation."""

from __future__ import annotations

import json
import math

import gymnasium as gym
import numpy as np
import pytest

import realitygap  # noqa: F401  (registers the envs)
from realitygap.robots.effects import EFFECTS, Reality, Twin, draw_reality, make_effect
from realitygap.robots.effects.twin import Z95


def _twin() -> Twin:
    reality = Reality(
        (
            make_effect("command_latency", delay=0.05),
            make_effect("wheel_diameter_ratio", E_d=1.02),
            make_effect("wheelbase_error", E_b=1.03),
        ),
        name="worn",
    )
    return Twin(
        reality,
        stderr={"command_latency.delay": 0.004, "wheel_diameter_ratio.E_d": 0.001},
        observed={"wheelbase_error.E_b": (1.01, 1.05)},
        origin={"command_latency": "budget"},
        source={"logs": {"train": ["a.csv"], "holdout": ["b.csv"]}},
    )


def test_boxes_are_the_95_percent_interval_or_the_observed_range() -> None:
    boxes = _twin().randomize
    lo, hi = boxes["command_latency.delay"]
    assert lo == pytest.approx(0.05 - Z95 * 0.004) and hi == pytest.approx(0.05 + Z95 * 0.004)
    assert boxes["wheelbase_error.E_b"] == pytest.approx((1.01, 1.05))


def test_a_box_is_clipped_to_the_physical_bounds_and_a_value_without_error_is_fixed() -> None:
    spec = EFFECTS["command_latency"].spec("delay")
    twin = Twin(
        Reality((make_effect("command_latency", delay=spec.low + 0.001),)),
        stderr={"command_latency.delay": 0.01},
    )
    lo, hi = twin.randomize["command_latency.delay"]
    assert lo == spec.low and hi == pytest.approx(spec.low + 0.001 + Z95 * 0.01)
    assert Twin(Reality((make_effect("command_latency", delay=0.05),))).randomize == {}


def test_draws_lie_in_their_boxes_and_repeat_with_the_seed() -> None:
    twin = _twin()
    boxes = twin.randomize
    draws = [twin.sample(np.random.default_rng(s)) for s in range(50)]
    for r in draws:
        for e in r.effects:
            for p, v in e.values.items():
                key = f"{e.name}.{p}"
                if key in boxes:
                    assert boxes[key][0] <= v <= boxes[key][1]
    again = twin.sample(np.random.default_rng(3))
    assert again.to_dict() == draws[3].to_dict()
    assert len({r.effects[0].values["delay"] for r in draws}) == 50


def test_plain_randomisation_may_add_effects_the_reality_lacks() -> None:
    r = draw_reality(
        Reality(), {"motor_deadband.threshold": (0.02, 0.06)}, np.random.default_rng(0)
    )
    assert r.effect_names == ("motor_deadband",)
    assert 0.02 <= r.effects[0].values["threshold"] <= 0.06


def test_file_round_trip_is_exact(tmp_path) -> None:  # type: ignore[no-untyped-def]
    twin = _twin()
    path = twin.save(tmp_path / "twin.json")
    back = Twin.load(path)
    assert back.to_dict() == twin.to_dict()
    assert back.reality.to_dict() == twin.reality.to_dict()
    data = json.loads(path.read_text())
    assert data["schema"] == "realitygap.reality/2"
    assert data["robot"] == "diffdrive"
    assert data["nominal"]["wheelbase"] > 0  # the robot's nominal parameters
    row = data["effects"][0]["parameters"]["delay"]
    assert row["unit"] == "s" and row["stderr"] == 0.004 and row["varies"] is False


def test_an_exported_reality_gives_bit_identical_rollouts(tmp_path) -> None:  # type: ignore[no-untyped-def]
    twin = _twin()
    path = twin.save(tmp_path / "twin.json")

    def rollout(reality):  # type: ignore[no-untyped-def]
        env = gym.make("realitygap/WheeledNav-v0", reality=reality)
        obs, _ = env.reset(seed=11)
        out = [obs]
        for k in range(40):
            obs, *_ = env.step(np.array([0.6, 0.3 * math.sin(k / 5)], dtype=np.float32))
            out.append(obs)
        env.close()
        return np.array(out)

    a, b = rollout(twin.reality), rollout(str(path))
    assert np.array_equal(a, b)
    c = rollout(None)
    assert not np.array_equal(a, c)  # the effects act


def test_the_older_form_is_read_without_uncertainty(tmp_path) -> None:  # type: ignore[no-untyped-def]
    path = tmp_path / "old.json"
    path.write_text(
        json.dumps(
            {"name": "old", "effects": [{"name": "command_latency", "values": {"delay": 0.05}}]}
        )
    )
    twin = Twin.load(path)
    assert twin.reality.name == "old" and twin.randomize == {}


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (lambda d: d.update(extra=1), "unknown key(s) ['extra']"),
        (lambda d: d.update(schema="realitygap.reality/9"), "schema 'realitygap.reality/9'"),
        (lambda d: d["effects"][0]["parameters"]["delay"].update(stderr=-1), "'stderr' must be"),
        (
            lambda d: d["effects"][2]["parameters"]["E_b"].update(observed=[2, 1]),
            "'observed' must be",
        ),
        (lambda d: d["effects"][0]["parameters"].update(lag={}), "'parameters' entry 'lag'"),
        (lambda d: d["effects"][0].update(name="command_latancy"), "command_latancy"),
        (lambda d: d["effects"][0]["values"].update(delay=-3.0), "delay"),
        (lambda d: d.update(robot="arm"), "'robot' is 'arm'"),
        (lambda d: d.update(effects={}), "'effects' must be a list"),
    ],
)
def test_a_bad_file_is_refused_naming_the_file_and_entry(tmp_path, edit, words) -> None:  # type: ignore[no-untyped-def]
    data = _twin().to_dict()
    edit(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError) as info:
        Twin.load(path)
    assert words in str(info.value) and "bad.json" in str(info.value)


def test_uncertainty_for_a_parameter_the_reality_lacks_is_refused() -> None:
    with pytest.raises(ValueError, match="no parameters of its effects"):
        Twin(Reality(), stderr={"command_latency.delay": 0.01})
