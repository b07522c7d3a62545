"""``realitygap train --reality/--randomize/--estimator-reality`` and the twin-transfer
experiment's hidden robots and plain domain randomisation."""

from __future__ import annotations

import json

import pytest

import realitygap  # noqa: F401  (registers the envs)
from realitygap.baselines.benchmark.profiles import simulator_kwargs
from realitygap.experiments.twin_transfer import NAV_EFFECTS, hidden_robots, library_boxes
from realitygap.robots.effects import EFFECTS, Reality, Twin, make_effect

NAV = "realitygap/WheeledNav-v0"


@pytest.fixture
def twin_file(tmp_path):  # type: ignore[no-untyped-def]
    twin = Twin(
        Reality((make_effect("wheelbase_error", E_b=1.03),), name="mine"),
        stderr={"wheelbase_error.E_b": 0.002},
    )
    return str(twin.save(tmp_path / "twin.json"))


def test_train_options_become_json_able_env_keywords(twin_file) -> None:  # type: ignore[no-untyped-def]
    kw = simulator_kwargs(NAV, twin_file, True, twin_file)
    assert json.loads(json.dumps(kw)) == kw  # stored with the trained model
    assert kw["reality"]["effects"] == [{"name": "wheelbase_error", "values": {"E_b": 1.03}}]
    lo, hi = kw["randomize"]["wheelbase_error.E_b"]
    assert lo < 1.03 < hi
    assert kw["estimator_reality"] == kw["reality"]
    assert simulator_kwargs(NAV, "nominal") == {}
    assert simulator_kwargs("realitygap/WheeledNavVec-v0", twin_file, True)["randomize"]


def test_randomize_needs_a_file_with_uncertainty(tmp_path, twin_file) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(ValueError, match="--randomize draws"):
        simulator_kwargs(NAV, "kobuki-worn", True)
    with pytest.raises(ValueError, match="--randomize draws"):
        simulator_kwargs(NAV, None, True)
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps(Reality((make_effect("wheelbase_error", E_b=1.03),)).to_dict()))
    with pytest.raises(ValueError, match="holds no uncertainty"):
        simulator_kwargs(NAV, str(plain), True)
    with pytest.raises(ValueError, match="no 'randomize' keyword"):
        simulator_kwargs("realitygap/WallClimb-v0", twin_file, True)
    kw = simulator_kwargs("realitygap/ArmCalib-v0", estimator_reality="arm-worn")
    assert [e["name"] for e in kw["estimator_reality"]["effects"]] == [
        "arm_joint_compliance",
        "arm_backlash",
    ]


def test_train_cli_trains_on_the_twin(tmp_path, twin_file) -> None:  # type: ignore[no-untyped-def]
    import argparse

    from realitygap.baselines.cli import add_train_parser, train_config_from_args

    parser = argparse.ArgumentParser()
    add_train_parser(parser.add_subparsers())
    args = parser.parse_args(
        ["train", "--vector", "--reality", twin_file, "--randomize", "--out", str(tmp_path / "o")]
    )
    cfg, _ = train_config_from_args(args)
    kw = dict(cfg.hyperparams["env_kwargs"])
    assert kw["reality"]["effects"][0]["name"] == "wheelbase_error" and "randomize" in kw
    assert kw["sensor_mode"] == "fast"  # the file's keywords are kept


def test_plain_domain_randomisation_spans_the_library_magnitudes() -> None:
    boxes = library_boxes()
    for name in NAV_EFFECTS:
        cls = EFFECTS[name]
        for r in cls.blind:
            s = cls.spec(r.param)
            lo, hi = boxes[f"{name}.{r.param}"]
            assert s.low <= lo <= s.nominal + (0 if r.absolute else r.low) <= hi <= s.high
            if r.symmetric:
                assert lo == pytest.approx(max(s.nominal - r.high, s.low))


def test_hidden_robots_are_seeded_and_the_last_two_withhold_an_effect() -> None:
    a, b = hidden_robots(0, 5), hidden_robots(0, 5)
    assert [r["reality"].to_dict() for r in a] == [r["reality"].to_dict() for r in b]
    assert a[0]["name"] == "kobuki-worn"
    assert [bool(r["withheld"]) for r in a] == [False, False, False, True, True]
    for r in a[3:]:
        assert r["withheld"][0] in r["reality"].effect_names
    assert [r["reality"].to_dict() for r in hidden_robots(1, 5)] != [
        r["reality"].to_dict() for r in a
    ]
