"""The verdict is a typed value with one writer: frozen, its notes typed with the JSON the
diagnosis has always written, and constructed by ``conclude`` alone."""

from __future__ import annotations

import ast
import dataclasses
import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.report.writer import jsonable
from realitygap.diagnosis.stages.reach import Reach
from realitygap.diagnosis.verdict.conclude import conclude
from realitygap.diagnosis.verdict.types import (
    Confidence,
    CoverageNote,
    Decision,
    Judgement,
    NuisancePartner,
    PartialExplanation,
    TrainingOnly,
    Verdict,
    VerdictKind,
    VerdictNotes,
    WholeRuns,
)

DIAGNOSIS = Path(__file__).resolve().parents[2] / "diagnosis"


def test_the_kinds_and_confidences_are_the_words_the_json_holds() -> None:
    assert [k.value for k in VerdictKind] == ["effects", "unexplained", "none"]
    assert {c.value for c in Confidence} == {
        "strong",
        "moderate",
        "weak",
        "not identifiable",
        "training only",
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
    full = VerdictNotes(
        verdict_text="a + b",
        aliases=({"model": "c", "effects": ["c"], "why": ["w"], "heldout_shrink_pct": 80.0},),
        compensators=("d",),
        regime_consistency=({"model": "d", "compensator": True},),
        parameter_status={"a": {"a.p": "at bound"}},
        discovery={"found": False, "message": "m"},
        heldout_shrink_pct_above_noise=91.0,
        unsingled_partners=("e",),
        training_only=TrainingOnly("a", 4.0, 95.0, ("c",)),
        nuisance_partner=NuisancePartner(
            "timestamp_offset",
            {"timestamp_offset.offset": 0.01},
            {"timestamp_offset.offset": "s"},
            {"timestamp_offset.offset": (-0.025, 0.025)},
        ),
        coverage=CoverageNote("s", "t"),
        combination_check={"model": "a + b", "passed": False},
        partially_explained_by=PartialExplanation("a + b", ("a", "b"), 60.0),
        robot={"message": "r"},
        actuation={"message": "q"},
        tracking={"message": "w"},
        reach={"message": "x"},
    )
    js = full.to_json()
    assert list(js) == [
        "training_only",
        "verdict_text",
        "aliases",
        "compensators",
        "regime_consistency",
        "parameter_status",
        "discovery",
        "heldout_shrink_pct_above_noise",
        "unsingled_partners",
        "nuisance_partner",
        "coverage",
        "combination_check",
        "partially_explained_by",
        "robot",
        "actuation",
        "tracking",
        "reach",
    ]
    assert js["training_only"] == {
        "model": "a",
        "train_gap_excess": 4.0,
        "train_shrink_pct_above_noise": 95.0,
        "aliases": ["c"],
    }
    assert js["nuisance_partner"]["ranges"] == {"timestamp_offset.offset": [-0.025, 0.025]}
    assert js["partially_explained_by"] == {
        "model": "a + b",
        "effects": ["a", "b"],
        "heldout_shrink_pct": 60.0,
    }
    assert js["coverage"] == {"summary": "s", "suggestion": "t"}
    assert js["aliases"] == [dict(full.aliases[0])] and js["unsingled_partners"] == ["e"]
    # JSON through and back: every value is plain data
    assert json.loads(json.dumps(jsonable(js))) == jsonable(js)
    # a verdict on whole runs states them first; notes that do not apply are left out, and
    # discovery is always stated
    whole = WholeRuns(80.0, 10.0, ("r",), True, 70.0)
    js = VerdictNotes(verdict_text="a (on whole runs)", whole_runs=whole).to_json()
    assert list(js) == [
        "whole_runs",
        "verdict_text",
        "aliases",
        "compensators",
        "regime_consistency",
        "parameter_status",
        "discovery",
        "heldout_shrink_pct_above_noise",
        "unsingled_partners",
    ]
    assert js["whole_runs"] == {
        "run_shrink_pct": 80.0,
        "window_shrink_pct": 10.0,
        "remainder": ["r"],
        "clock_like": True,
        "timing_share_pct": 70.0,
    }
    assert js["discovery"] is None and math.isnan(js["heldout_shrink_pct_above_noise"])


def test_conclude_writes_the_decision_with_what_the_pipeline_measured(
    model_fit: Callable[..., ModelFit], make_judgement: Callable[..., Judgement]
) -> None:
    best = model_fit(effects=("wheelbase_error",), z_heldout=np.zeros(4))
    j = make_judgement(best=best, nominal_heldout=np.ones(4), reason="closes it")
    j = j.revised(ambiguous_with=("wheel_radius_scale",), confidence=Confidence.NOT_IDENTIFIABLE)
    decision = Decision(j, VerdictNotes(verdict_text="wheelbase_error or wheel_radius_scale"))
    reach = Reach(rows=[{"model": "m"}], message="far")
    v = conclude(decision, robot={"message": "r"}, reach=reach)
    assert (v.kind, v.effects, v.reason) == (VerdictKind.EFFECTS, ("wheelbase_error",), "closes it")
    assert v.confidence is Confidence.NOT_IDENTIFIABLE
    assert v.ambiguous_with == ("wheel_radius_scale",)
    assert v.notes.verdict_text == decision.notes.verdict_text
    assert v.notes.robot == {"message": "r"} and v.notes.reach == reach.to_json()
    assert v.notes.discovery is None and v.notes.actuation is None
    # the decision itself is left as it was
    assert decision.notes.robot is None


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
