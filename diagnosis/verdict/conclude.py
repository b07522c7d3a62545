"""The one writer of the verdict: the gap budget's answer in the verdict's form.

The budget (:mod:`~realitygap.diagnosis.budget`) has chosen the effects by its one
cross-validated rule and set the kind (:func:`~realitygap.diagnosis.budget.kind_of`);
:func:`conclude` states it as a :class:`~realitygap.diagnosis.verdict.types.Verdict`: the
named effects, the rule as the reason, the first entry's aliases with the manoeuvre that
would separate them, and what the pipeline measured beside (discovery, the fitted robot,
the drive train, the library's reach). A verdict, once written, does not change (it is
frozen).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from realitygap.diagnosis.budget import Budget
from realitygap.diagnosis.verdict.types import (
    Confidence,
    CoverageNote,
    Judgement,
    Verdict,
    VerdictKind,
    VerdictNotes,
)

__all__ = ["conclude", "confidence_of"]


def confidence_of(budget: Budget) -> Confidence:
    """The confidence of a budget's first named effect: not identifiable when it has
    aliases, else graded by its cross-validated test's p-value (strong below 10⁻⁴, moderate
    below 10⁻², weak above); not applicable when nothing is named."""
    named = [e for e in budget.entries if e.named]
    if not named:
        return Confidence.NOT_APPLICABLE
    first = named[0]
    if first.aliases:
        return Confidence.NOT_IDENTIFIABLE
    if first.p_value < 1e-4:
        return Confidence.STRONG
    if first.p_value < 1e-2:
        return Confidence.MODERATE
    return Confidence.WEAK


def conclude(
    budget: Budget,
    judgement: Judgement,
    *,
    residual: dict[str, Any],
    aliases: Sequence[dict[str, Any]] = (),
    regime_consistency: Sequence[dict[str, Any]] = (),
    parameter_status: dict[str, dict[str, str]] | None = None,
    discovery: dict[str, Any] | None = None,
    coverage: CoverageNote | None = None,
    robot: dict[str, Any] | None = None,
    actuation: dict[str, Any] | None = None,
    tracking: dict[str, Any] | None = None,
    reach: dict[str, Any] | None = None,
    gap_words: dict[str, str] | None = None,
) -> Verdict:
    """Write the verdict of ``budget``.

    Parameters
    ----------
    budget : Budget
    judgement : Judgement
        The held-out figures of the budget's model
        (:func:`~realitygap.diagnosis.verdict.judge.heldout_view`).
    residual : dict
        What the budget's model leaves on the held-out windows
        (:func:`~realitygap.diagnosis.verdict.judge.describe_fit_residual`).
    aliases : sequence of dict
        The first entry's aliases, with the manoeuvre that would separate them.
    discovery, coverage, robot, actuation, tracking, reach
        What the pipeline measured beside the budget (noted whatever the kind).
    gap_words : dict, optional
        A scale's gap in physical units for the sentence.
    """
    kind = VerdictKind(budget.kind)
    named = budget.named if kind in (VerdictKind.EFFECTS, VerdictKind.PARTIAL) else ()
    first = next((e for e in budget.entries if e.named), None)
    notes = VerdictNotes(
        verdict_text=budget.sentence(gap_words),
        aliases=tuple(aliases),
        regime_consistency=tuple(regime_consistency),
        parameter_status=parameter_status or {},
        discovery=discovery,
        coverage=coverage,
        robot=robot,
        actuation=actuation,
        tracking=tracking,
        reach=reach,
    )
    return Verdict(
        kind=kind,
        effects=tuple(named),
        reason=budget.rule,
        margin=first.cv_gain if first is not None else float("nan"),
        confidence=confidence_of(budget) if named else Confidence.NOT_APPLICABLE,
        residual=residual,
        ambiguous_with=tuple(first.aliases) if first is not None and named else (),
        notes=notes,
    )
