"""A diagnosis's answer exported as a reality file (:mod:`realitygap.diagnosis.export`): which
values go in, with which uncertainty, and what is left out and why."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from realitygap.diagnosis.budget.budget import Budget, BudgetEntry
from realitygap.diagnosis.export import acts_on_robot, twin_of
from realitygap.robots.effects import Twin


def _entry(effect: str, values: dict[str, float], stderr: dict[str, float], **kw) -> BudgetEntry:  # type: ignore[no-untyped-def]
    return BudgetEntry(
        effect=effect,
        scale="run",
        values=values,
        stderr=stderr,
        share={"run": kw.get("share", 40.0)},
        interval={"run": kw.get("interval", (20.0, 60.0))},
        cv_gain=1.0,
        p_value=0.001,
        folds=4,
        aliases=(),
        stability=kw.get("stability", {"constant": True, "parameters": {}}),
    )


def _diagnosis(
    entries: tuple[BudgetEntry, ...], budget_values: dict[str, float]
) -> SimpleNamespace:
    budget = Budget(
        entries=entries,
        gap={"run": 1.0},
        remainder={"run": {"remaining_pct": 10.0, "noise_pct": 5.0, "structured_pct": 5.0}},
        kind="effects",
        rule="",
        folds={},
        structured_baseline=False,
        values=budget_values,
    )
    return SimpleNamespace(
        settings=SimpleNamespace(robot="diffdrive"),
        baseline=SimpleNamespace(
            values={
                "timestamp_offset.offset": 0.01,
                "truth_frame_offset.x": 0.003,
                "command_latency.delay": 0.02,
            }
        ),
        budget=budget,
        prepared=[
            SimpleNamespace(name="a.csv", split="train"),
            SimpleNamespace(name="b.csv", split="holdout"),
        ],
        verdict=SimpleNamespace(label=[e.effect for e in entries]),
    )


def test_acts_on_robot_separates_the_robot_from_the_recording() -> None:
    assert acts_on_robot("wheel_diameter_ratio", {"E_d": 1.01}, "diffdrive")
    assert acts_on_robot("command_latency", {"delay": 0.05}, "diffdrive")
    assert not acts_on_robot("timestamp_offset", {"offset": 0.05}, "diffdrive")
    assert not acts_on_robot("truth_frame_offset", {"x": 0.01, "y": 0.0, "yaw": 0.0}, "diffdrive")


def test_the_twin_holds_the_budget_values_with_errors_and_the_robots_baseline() -> None:
    varies = {
        "constant": False,
        "unit": "session",
        "parameters": {"wheelbase_error.E_b": {"min": 1.02, "max": 1.05}},
    }
    d = _diagnosis(
        (
            _entry(
                "wheel_diameter_ratio",
                {"wheel_diameter_ratio.E_d": 1.0},
                {"wheel_diameter_ratio.E_d": 2e-4},
            ),
            _entry(
                "wheelbase_error",
                {"wheelbase_error.E_b": 1.0},
                {"wheelbase_error.E_b": 1e-3},
                stability=varies,
            ),
        ),
        {"wheel_diameter_ratio.E_d": 1.012, "wheelbase_error.E_b": 1.035},
    )
    twin = twin_of(d)  # type: ignore[arg-type]
    values = {e.name: e.values for e in twin.reality.effects}
    # the jointly refitted values of the budget's model, not the entries' own
    assert values["wheel_diameter_ratio"]["E_d"] == 1.012
    assert values["wheelbase_error"]["E_b"] == 1.035
    assert values["command_latency"]["delay"] == 0.02  # the baseline acts on the robot
    assert "timestamp_offset" not in values and "truth_frame_offset" not in values
    assert "recording" in twin.source["left_out"]["timestamp_offset"]
    assert twin.stderr["wheel_diameter_ratio.E_d"] == 2e-4
    assert twin.observed == {"wheelbase_error.E_b": (1.02, 1.05)}
    lo, hi = twin.randomize["wheelbase_error.E_b"]
    assert lo == 1.02 and hi == 1.05  # the sessions' range holds the 95 % interval
    assert "command_latency.delay" not in twin.randomize  # no error bar: no spread invented
    assert twin.origin == {
        "command_latency": "baseline",
        "wheel_diameter_ratio": "budget",
        "wheelbase_error": "budget",
    }
    assert twin.source["logs"] == {"train": ["a.csv"], "holdout": ["b.csv"]}
    assert Twin.from_dict(twin.to_dict()).to_dict() == twin.to_dict()


def test_an_entry_that_made_the_held_out_data_worse_is_left_out() -> None:
    bad = _entry(
        "encoder_scale",
        {"encoder_scale.scale": 1.01},
        {"encoder_scale.scale": 1e-3},
        share=-20.0,
        interval=(-40.0, -5.0),
    )
    twin = twin_of(_diagnosis((bad,), {"encoder_scale.scale": 1.01}))  # type: ignore[arg-type]
    assert "encoder_scale" not in twin.reality.effect_names
    assert "worse" in twin.source["left_out"]["encoder_scale"]


def test_a_diagnosis_without_a_budget_exports_its_baseline() -> None:
    d = _diagnosis((), {})
    d.budget = None
    twin = twin_of(d)  # type: ignore[arg-type]
    assert twin.reality.effect_names == ("command_latency",)
    assert twin.source["budget_kind"] is None and math.isnan(twin.stderr.get("x", math.nan))


@pytest.mark.parametrize("name", ["", "twin of mine"])
def test_the_twin_is_named(name: str) -> None:
    twin = twin_of(_diagnosis((), {}), name)  # type: ignore[arg-type]
    assert twin.reality.name == (name or "twin of diffdrive")
