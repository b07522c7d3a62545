"""The one writer of the verdict.

Every step before it returns a value: the held-out tests a
:class:`~realitygap.diagnosis.verdict.types.Judgement`
(:func:`~realitygap.diagnosis.verdict.judge.judge`), the two-scale test a revised one
(:func:`~realitygap.diagnosis.verdict.scales.judge_scales`), identifiability an
:class:`~realitygap.diagnosis.verdict.advice.Advice`, the rules a
:class:`~realitygap.diagnosis.verdict.types.Decision`
(:func:`~realitygap.diagnosis.verdict.rules.decide`). The pipeline then measures what the
decision's kind calls for — discovery on an unexplained residual, the fitted robot of named
effects, the library's reach — and :func:`conclude` turns the decision and those values
into the :class:`~realitygap.diagnosis.verdict.types.Verdict`. No other function of the
diagnosis constructs one, and a verdict, once written, does not change (it is frozen).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from realitygap.diagnosis.stages.discovery import Discovery
from realitygap.diagnosis.stages.reach import Reach
from realitygap.diagnosis.verdict.types import Decision, Verdict

__all__ = ["conclude"]


def conclude(
    decision: Decision,
    *,
    discovery: Discovery | None = None,
    robot: dict[str, Any] | None = None,
    actuation: dict[str, Any] | None = None,
    tracking: dict[str, Any] | None = None,
    reach: Reach | None = None,
) -> Verdict:
    """Write the verdict of ``decision``.

    Parameters
    ----------
    decision : Decision
        What the rules decided (kind, effects, reason, confidence, notes).
    discovery : Discovery, optional
        What discovery found in the residual the decision leaves
        (:func:`~realitygap.diagnosis.verdict.rules.run_discovery`).
    robot : dict, optional
        The robot a named decision's effects describe (the adapter's ``fitted_robot``).
    actuation, tracking : dict, optional
        A drive train that differs between logs, and wheels that do not follow their
        commands beyond the training (noted whatever the kind).
    reach : Reach, optional
        How far the library reaches on the held-out windows of an unexplained decision
        (:func:`~realitygap.diagnosis.stages.reach.library_reach`).

    Returns
    -------
    Verdict
    """
    draft = decision.judgement.draft
    notes = replace(
        decision.notes,
        discovery=discovery.to_json() if discovery is not None else None,
        robot=robot,
        actuation=actuation,
        tracking=tracking,
        reach=reach.to_json() if reach is not None else None,
    )
    return Verdict(
        kind=draft.kind,
        effects=draft.effects,
        reason=draft.reason,
        margin=draft.margin,
        confidence=draft.confidence,
        residual=draft.residual,
        ambiguous_with=draft.ambiguous_with,
        notes=notes,
    )
