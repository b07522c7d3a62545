"""The verdict is a typed value with one writer: frozen, its notes typed with the JSON the
diagnosis has always written, and constructed by ``conclude`` alone."""

from __future__ import annotations

import ast
import dataclasses
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from realitygap.diagnosis.budget import Budget, BudgetEntry
from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.report.writer import jsonable
from realitygap.diagnosis.stages.reach import Reach
from realitygap.diagnosis.verdict.conclude import conclude
from realitygap.diagnosis.verdict.types import (
    Confidence,
    CoverageNote,
    Judgement,
    Verdict,
    VerdictKind,
    VerdictNotes,
)

DIAGNOSIS = Path(__file__).resolve().parents[2] / "diagnosis"


def test_the_kinds_and_confidences_are_the_words_the_json_holds() -> None:
    assert [k.value for k in VerdictKind] == ["effects", "partial", "unexplained", "none"]
    assert {c.value for c in Confidence} == {
        "strong",
        "moderate",
        "weak",
        "not identifiable",
        "n/a",
    }
    # a string enum equals its word, prints as it and serialises as it
    assert VerdictKind.UNEXPLAINED == "unexplained" and f"{VerdictKind.NONE}" == "none"
    assert str(Confidence.NOT_IDENTIFIABLE) == "not identifiable"
    assert json.dumps(jsonable([VerdictKind.EFFECTS, Confidence.NOT_APPLICABLE])) == (
        '["effects", "n/a"]'
    )


def test_a_verdict_cannot_be_changed_once_written(make_verdict: Callable[..., Verdict]) -> None:
    v = make_verdict(effects=("wheelbase_error",), notes=VerdictNotes(verdict_text="x"))
    with pytest.raises(dataclasses.FrozenInstanceError):
        v.kind = VerdictKind.UNEXPLAINED  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        v.notes.verdict_text = "y"  # type: ignore[misc]
    with pytest.raises(AttributeError):
        v.ambiguous_with.append("other")  # type: ignore[attr-defined]
    assert v.label == ["wheelbase_error"]
    assert make_verdict(kind=VerdictKind.NONE).label == "none"


def test_the_notes_give_the_json_keys_in_their_order() -> None:
    notes = VerdictNotes(
        verdict_text="t",
        coverage=CoverageNote("beyond", "record more"),
        robot={"message": "r"},
    )
    js = notes.to_json()
    assert list(js) == [
        "verdict_text",
        "aliases",
        "regime_consistency",
        "parameter_status",
        "discovery",
        "coverage",
        "fitted_robot",
    ]
    assert js["coverage"] == {"summary": "beyond", "suggestion": "record more"}
    assert js["discovery"] is None


def _entry(
    effect: str, *, constant: bool = True, aliases: tuple[str, ...] = (), p: float = 1e-6
) -> BudgetEntry:
    return BudgetEntry(
        effect=effect,
        scale="run",
        values={f"{effect}.E_b": 1.01},
        stderr={f"{effect}.E_b": 0.001},
        share={"run": 60.0, "window": 10.0},
        interval={"run": (50.0, 70.0), "window": (5.0, 15.0)},
        cv_gain=0.5,
        p_value=p,
        folds=6,
        aliases=aliases,
        stability={"unit": "session", "constant": constant, "parameters": {}},
    )


def test_conclude_writes_the_budget_with_what_the_pipeline_measured(
    model_fit: Callable[..., ModelFit], make_judgement: Callable[..., Judgement]
) -> None:
    entry = _entry("wheelbase_error", aliases=("wheel_radius_scale",))
    remainder = {
        s: {"remaining_pct": 30.0, "noise_pct": 25.0, "structured_pct": 5.0, "rms": 1.0}
        for s in ("run", "window")
    }
    budget = Budget(
        (entry,),
        {"run": 3.0, "window": 2.0},
        remainder,
        "effects",
        "the rule",
        {},
        True,
        dict(entry.values),
    )
    best = model_fit(effects=("wheelbase_error",), z_heldout=np.zeros(4))
    j = make_judgement(best=best, nominal_heldout=np.ones(4))
    reach = Reach(rows=[{"model": "m"}], message="far")
    v = conclude(
        budget, j, residual={"structured": False}, robot={"message": "r"}, reach=reach.to_json()
    )
    assert (v.kind, v.effects, v.reason) == (VerdictKind.EFFECTS, ("wheelbase_error",), "the rule")
    # an alias makes the first entry not identifiable
    assert v.confidence is Confidence.NOT_IDENTIFIABLE
    assert v.ambiguous_with == ("wheel_radius_scale",)
    assert v.notes.verdict_text == budget.sentence()
    assert "wheelbase error" in v.notes.verdict_text and "60 % [50, 70]" in v.notes.verdict_text
    assert v.notes.robot == {"message": "r"} and v.notes.reach == reach.to_json()
    # an entry whose value varies between sessions is not named
    varying = Budget(
        (_entry("wheelbase_error", constant=False),),
        budget.gap,
        remainder,
        "unexplained",
        "r",
        {},
        True,
    )
    v2 = conclude(varying, j, residual={})
    assert v2.kind is VerdictKind.UNEXPLAINED and v2.effects == ()
    assert v2.confidence is Confidence.NOT_APPLICABLE
    assert "varies between sessions" in varying.sentence()


def _called(node: ast.Call) -> str:
    f = node.func
    return f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""


def _calls(path: Path, name: str) -> list[tuple[str, ast.Call]]:
    """Each call of ``name`` in the module at ``path`` (by name or as an attribute), with the
    function it is in (``""``: at module level)."""
    out: list[tuple[str, ast.Call]] = []

    def visit(node: ast.AST, where: str) -> None:
        for child in ast.iter_child_nodes(node):
            inner = where
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                inner = child.name
            if isinstance(child, ast.Call) and _called(child) == name:
                out.append((inner, child))
            visit(child, inner)

    visit(ast.parse(path.read_text(encoding="utf-8")), "")
    return out


def test_one_function_of_the_diagnosis_writes_a_verdict() -> None:
    """``Verdict(`` is called in one module of the diagnosis, by one function: ``conclude``;
    and no ``dataclasses.replace`` takes a verdict."""
    modules = sorted(DIAGNOSIS.rglob("*.py"))
    assert len(modules) > 40  # the whole package is read
    writers = {
        (str(path.relative_to(DIAGNOSIS)), where)
        for path in modules
        for where, _ in _calls(path, "Verdict")
    }
    assert writers == {("verdict/conclude.py", "conclude")}
    for path in modules:
        for _, call in _calls(path, "replace"):
            target = ast.unparse(call.args[0]) if call.args else ""
            assert "verdict" not in target.lower(), f"{path}:{call.lineno}: replace({target}, …)"
