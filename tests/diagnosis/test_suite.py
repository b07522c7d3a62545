"""The blind validation suite on a few cases (slow; the full run is ``diagnose-suite``)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from realitygap.diagnosis.adapters.registry import get_adapter
from realitygap.diagnosis.validation.suite import (
    BlindCase,
    SuiteSettings,
    draw_cases,
    run_suite,
    summarise,
    withheld_exercised,
)
from realitygap.diagnosis.verdict.types import Confidence, Verdict, VerdictKind, VerdictNotes
from realitygap.robots.effects import blind_ranges


def test_cases_are_seeded_balanced_and_a_quarter_open() -> None:
    a, b = draw_cases(20, seed=3), draw_cases(20, seed=3)
    assert a == b
    assert draw_cases(20, seed=4) != a
    assert sum(c.open_set for c in a) == 5
    hidden = {name for c in a for name in c.truth_names}
    assert hidden == set(blind_ranges("diffdrive"))
    for c in a:
        for name, values in c.truth:
            for param, value in values:
                spec = next(s for s in c.reality().effects if s.name == name).spec(param)
                assert spec.low <= value <= spec.high


@pytest.mark.slow
def test_a_small_blind_suite(request: pytest.FixtureRequest) -> None:
    if "slow" not in (request.config.getoption("markexpr") or ""):
        pytest.skip("slow (a few minutes): run with -m slow")
    cases = [c for c in draw_cases(8, seed=11) if len(c.truth) == 1][:3]
    outcomes = run_suite(cases)
    figures, tables = summarise(outcomes)
    assert figures["false_attribution_rate"] == 0.0
    assert all(o["correct"] for o in outcomes), tables["cases"]


def _outcome(truth: list[str], verdict: object, alias_aware: bool, open_set: bool = False) -> dict:
    named = isinstance(verdict, list) and sorted(verdict) == sorted(truth)
    return {
        "index": 0,
        "truth": {t: {} for t in truth},
        "truth_names": truth,
        "withheld": [truth[0]] if open_set else [],
        "open_set": open_set,
        "verdict": verdict,
        "reason": "r",
        "correct": (verdict == VerdictKind.UNEXPLAINED) if open_set else named,
        "correct_alias_aware": alias_aware,
        "top1": (not open_set) and named,
        "top2": (not open_set) and named,
        "best": "+".join(truth),
        "best_params": {},
        "param_rel_err": {},
        "heldout_shrink_pct": 90.0,
        "heldout_shrink_pct_best": 90.0,
    }


def test_alias_aware_top1_is_reported_beside_the_strict_one() -> None:
    outcomes = [
        _outcome(["wheelbase_error"], ["wheelbase_error"], True),
        # "wheel_radius_scale or wheelbase_error (aliases on this data)"
        _outcome(["wheelbase_error"], ["wheel_radius_scale"], True),
        _outcome(["wheelbase_error"], VerdictKind.UNEXPLAINED, False),
        _outcome(["wheelbase_error"], ["encoder_scale"], False),
        _outcome(["command_latency"], VerdictKind.UNEXPLAINED, True, open_set=True),
    ]
    figures, tables = summarise(outcomes)
    assert figures["top1_accuracy"] == pytest.approx(1 / 4)
    assert figures["top1_alias_aware_accuracy"] == pytest.approx(2 / 4)
    assert figures["open_set_unexplained_rate"] == 1.0
    assert [c["correct_alias_aware"] for c in tables["cases"]] == [True, True, False, False, True]


def test_verdict_alternatives_lists_the_model_then_its_aliases(
    make_verdict: Callable[..., Verdict],
) -> None:
    from realitygap.diagnosis.verdict.notes import verdict_alternatives

    aliases = (
        {"model": "wheelbase_error", "effects": ["wheelbase_error"]},
        {"model": "encoder_scale + timestamp_offset"},  # no effects key: read from the name
    )
    v = make_verdict(
        effects=("wheel_radius_scale",),
        confidence=Confidence.NOT_IDENTIFIABLE,
        notes=VerdictNotes(aliases=aliases),
    )
    assert verdict_alternatives(v) == [
        ("wheel_radius_scale",),
        ("wheelbase_error",),
        ("encoder_scale", "timestamp_offset"),
    ]
    assert verdict_alternatives(make_verdict(kind=VerdictKind.UNEXPLAINED)) == []


def test_the_first_budget_entry_and_the_open_set_are_scored() -> None:
    partial_open = _outcome(
        ["torque_speed_saturation"], ["velocity_saturation"], True, open_set=True
    )
    partial_open["first_entry"] = "velocity_saturation"
    # run_case: an open set is right when the named effects leave ≥ 50 % unexplained
    partial_open.update(correct=True, unexplained_share_pct=70.0)
    right = _outcome(["wheelbase_error"], ["wheelbase_error"], True)
    right["first_entry_right"] = True
    extra = _outcome(["wheelbase_error"], ["wheelbase_error", "command_latency"], False)
    extra["first_entry_right"] = True
    figures, tables = summarise([partial_open, right, extra])
    # the first entry is right in both in-library cases, the whole verdict in one
    assert figures["first_entry_accuracy"] == 1.0
    assert figures["top1_accuracy"] == 0.5
    # an open set whose named effects leave half the gap or more is right, not a false
    # attribution; an extra effect beside the truth is one
    assert figures["open_set_right_rate"] == 1.0
    assert figures["false_attribution_rate"] == pytest.approx(1 / 3)
    assert tables["cases"][0]["first_entry"] == "velocity_saturation"


@pytest.mark.slow
def test_a_withheld_effect_that_never_acts_is_not_an_open_set_case() -> None:
    settings = SuiteSettings()
    adapter = get_adapter("diffdrive")
    base = ("wheelbase_error", (("E_b", 1.03),))

    def exercised(v_limit: float) -> bool:
        cap = ("velocity_saturation", (("v_limit", v_limit),))
        case = BlindCase(0, (base, cap), ("velocity_saturation",), 11)
        rng = np.random.default_rng(11)
        train, holdout = adapter.record_blind_logs(case.reality(), rng, settings.blind_logs)
        return withheld_exercised(settings, case, train, holdout)

    # a speed cap far above every commanded speed never acts; one below them does
    assert not exercised(5.0)
    assert exercised(0.2)
    # a case whose only effect is withheld stays an open-set case
    only = BlindCase(
        0, (("velocity_saturation", (("v_limit", 5.0),)),), ("velocity_saturation",), 11
    )
    assert withheld_exercised(settings, only, [], [])
