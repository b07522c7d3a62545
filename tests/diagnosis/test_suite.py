"""The blind validation suite on a few cases (slow; the full run is ``diagnose-suite``)."""

from __future__ import annotations

import pytest

from realitygap.diagnosis.suite import draw_cases, run_suite, summarise
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
