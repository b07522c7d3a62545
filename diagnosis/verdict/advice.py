"""Identifiability advice: close contenders the logged motions cannot tell from the best model.

:func:`advise` checks the best model against its (at most two) close contenders with
:func:`~realitygap.diagnosis.fit.identifiability.identifiability` and returns an
:class:`Advice`: every check (the diagnosis JSON's ``identifiability``) and what it does to
the draft — the contenders a named draft cannot be told from join its ``ambiguous_with``,
and its confidence becomes "not identifiable". The rules apply it
(:func:`~realitygap.diagnosis.verdict.rules.decide`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from realitygap.diagnosis.fit.identifiability import identifiability
from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.problem.problem import Problem
from realitygap.diagnosis.verdict.types import Confidence, Judgement, VerdictKind

__all__ = ["Advice", "advise"]


@dataclass(frozen=True)
class Advice:
    """What identifiability says of a judgement.

    Attributes
    ----------
    identifiability : list of dict
        Each check of the best model against a close contender.
    ambiguous_with : tuple of str
        The draft's ``ambiguous_with`` with the contenders its named model cannot be told
        from.
    confidence : Confidence
        The draft's confidence: "not identifiable" when a model of effects has any such
        contender, else as drawn.
    """

    identifiability: list[dict[str, Any]]
    ambiguous_with: tuple[str, ...]
    confidence: Confidence

    def applied(self, judgement: Judgement) -> Judgement:
        """``judgement`` with its draft's contenders and confidence as advised."""
        return judgement.revised(ambiguous_with=self.ambiguous_with, confidence=self.confidence)


def advise(problem: Problem, ranking: Sequence[ModelFit], judgement: Judgement) -> Advice:
    """Identifiability of the best model against its close contenders.

    A contender (neither a sub- nor a super-model) within
    :attr:`AttributionSettings.margin_strong` of the best model's score is checked; one the
    logged motions cannot tell from a named model is added to ``ambiguous_with`` (its
    confidence becomes "not identifiable").
    """
    st = problem.settings
    best, draft = judgement.best, judgement.draft
    ident: list[dict[str, Any]] = []
    ambiguous = list(draft.ambiguous_with)
    confidence = draft.confidence
    contenders = [f for f in ranking if f.effects and f.effects != best.effects]
    close = [f for f in contenders if f.rank_score - best.rank_score < st.margin_strong][:2]
    if best.effects:
        for other in close:
            if set(other.effects) >= set(best.effects) or set(best.effects) >= set(other.effects):
                continue
            info = identifiability(problem, best, other)
            ident.append(info)
            if not info["separable"] and draft.kind is VerdictKind.EFFECTS:
                ambiguous.append(other.name)
        if ambiguous:
            confidence = Confidence.NOT_IDENTIFIABLE
    return Advice(ident, tuple(ambiguous), confidence)
