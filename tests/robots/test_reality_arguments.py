"""A Reality and its effects refuse bad input where it is written, naming it."""

from __future__ import annotations

import pytest

from realitygap.robots.effects import Reality, make_effect


@pytest.mark.parametrize("name", [5, None, 1.5, ("command_latency",)])
def test_effect_name_that_is_not_a_string_names_it_and_the_known_effects(name: object) -> None:
    with pytest.raises(
        TypeError, match=r"effect name must be a str.*Known effects: .*command_latency"
    ):
        make_effect(name)  # type: ignore[arg-type]


def test_an_effect_given_twice_is_refused_naming_it() -> None:
    with pytest.raises(ValueError, match="'command_latency' comes 2 times"):
        Reality(
            (make_effect("command_latency", delay=0.1), make_effect("command_latency", delay=0.2))
        )


def test_from_dict_reads_both_forms() -> None:
    r = Reality((make_effect("command_latency", delay=0.05),), name="lag")
    assert Reality.from_dict(r.to_dict()).to_dict() == r.to_dict()
    short = Reality.from_dict({"command_latency": {"delay": 0.05}})
    assert short.effects[0].to_dict() == r.effects[0].to_dict()


@pytest.mark.parametrize(
    ("data", "error", "match"),
    [
        ({"no_such_effect": {}}, KeyError, "no_such_effect"),
        ({"command_latency": {"delay": -1.0}}, ValueError, "delay"),
        ({"command_latency": 0.05}, TypeError, "command_latency"),
        ({"effects": "command_latency"}, ValueError, "'effects' must be a list"),
        ({"effects": [], "colour": 1}, ValueError, "colour"),
        ("command_latency", TypeError, "mapping"),
    ],
)
def test_from_dict_refuses_what_it_cannot_apply(data: object, error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        Reality.from_dict(data)  # type: ignore[arg-type]
