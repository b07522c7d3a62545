"""The verdict's types: what it can say, how sure it is, and what it notes.

A diagnosis ends in a :class:`Verdict`, a frozen value written by one function,
:func:`~realitygap.diagnosis.verdict.conclude.conclude`. The steps before it return values
of their own:

* the held-out tests (:func:`~realitygap.diagnosis.verdict.judge.judge`) give a
  :class:`Judgement`: a :class:`Draft` of the verdict and the held-out figures it rests on;
* the two-scale test (:func:`~realitygap.diagnosis.verdict.scales.judge_scales`) and the
  rules (:func:`~realitygap.diagnosis.verdict.rules.decide`) give new judgements from old
  ones, the rules a :class:`Decision` with the verdict's :class:`VerdictNotes`;
* the pipeline adds what it measures for the decision's kind (the fitted robot, the drive
  train, the library's reach, discovery), and ``conclude`` writes the verdict.

:class:`VerdictKind` and :class:`Confidence` are string enums: each equals, and serialises
as, the word the JSON has always held (``"effects"``, ``"not identifiable"``, …).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from enum import Enum
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.fit.model import ModelFit

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "Confidence",
    "CoverageNote",
    "Decision",
    "Draft",
    "Judgement",
    "NuisancePartner",
    "PartialExplanation",
    "TrainingOnly",
    "Verdict",
    "VerdictKind",
    "VerdictNotes",
    "WholeRuns",
]


class VerdictKind(str, Enum):
    """What a verdict says: effects named, a gap left unexplained, or no gap."""

    EFFECTS = "effects"
    UNEXPLAINED = "unexplained"
    NONE = "none"

    def __str__(self) -> str:
        return self.value


class Confidence(str, Enum):
    """How far a verdict can be trusted.

    ``STRONG``, ``MODERATE`` and ``WEAK`` grade the score margin of a named model to the
    runner-up (:func:`~realitygap.diagnosis.verdict.judge.confidence_of`); a named model the
    data cannot tell from another is ``NOT_IDENTIFIABLE``; one that rests on the training
    windows alone ``TRAINING_ONLY``; a verdict that names nothing ``NOT_APPLICABLE``.
    """

    STRONG = "strong"
    MODERATE = "moderate"
    WEAK = "weak"
    NOT_IDENTIFIABLE = "not identifiable"
    TRAINING_ONLY = "training only"
    NOT_APPLICABLE = "n/a"

    def __str__(self) -> str:
        return self.value


# --------------------------------------------------------------------------- notes
@dataclass(frozen=True)
class TrainingOnly:
    """A model named on the training windows alone (their gap, its share closed, its aliases)."""

    model: str
    train_gap_excess: float
    train_shrink_pct_above_noise: float
    aliases: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {
            "model": self.model,
            "train_gap_excess": self.train_gap_excess,
            "train_shrink_pct_above_noise": self.train_shrink_pct_above_noise,
            "aliases": list(self.aliases),
        }


@dataclass(frozen=True)
class WholeRuns:
    """A model named on whole held-out runs: both shrinks and what it leaves in the windows."""

    run_shrink_pct: float
    window_shrink_pct: float
    remainder: tuple[str, ...]
    clock_like: bool
    timing_share_pct: float

    def to_json(self) -> dict[str, Any]:
        return {
            "run_shrink_pct": self.run_shrink_pct,
            "window_shrink_pct": self.window_shrink_pct,
            "remainder": list(self.remainder),
            "clock_like": self.clock_like,
            "timing_share_pct": self.timing_share_pct,
        }


@dataclass(frozen=True)
class NuisancePartner:
    """The partner of a named effect that only refines a calibrated-baseline nuisance inside
    its range: the effect, its parameters' values, units and nuisance ranges."""

    effect: str
    values: Mapping[str, float]
    units: Mapping[str, str]
    ranges: Mapping[str, tuple[float, float]]

    def to_json(self) -> dict[str, Any]:
        return {
            "effect": self.effect,
            "values": dict(self.values),
            "units": dict(self.units),
            "ranges": {k: list(r) for k, r in self.ranges.items()},
        }


@dataclass(frozen=True)
class CoverageNote:
    """What remains lies in motions the training never exercised: where, and what to record."""

    summary: str
    suggestion: str

    def to_json(self) -> dict[str, Any]:
        return {"summary": self.summary, "suggestion": self.suggestion}


@dataclass(frozen=True)
class PartialExplanation:
    """The combination that closed part of an unexplained gap."""

    model: str
    effects: tuple[str, ...]
    heldout_shrink_pct: float

    def to_json(self) -> dict[str, Any]:
        return {
            "model": self.model,
            "effects": list(self.effects),
            "heldout_shrink_pct": self.heldout_shrink_pct,
        }


@dataclass(frozen=True)
class VerdictNotes:
    """What a verdict notes beside its kind and reason (:meth:`to_json`: the keys the
    diagnosis JSON holds next to ``verdict``).

    Attributes
    ----------
    verdict_text : str
        The verdict in words, with its aliases, partners and scale.
    aliases : tuple of dict
        Models the data cannot tell from the named one (``model``, ``effects``, ``why``,
        ``heldout_shrink_pct``, ``separating_motion`` where a manoeuvre would separate them).
    compensators : tuple of str
        Models that improve some regimes and worsen others.
    regime_consistency : tuple of dict
        Per model of the top of the ranking, what it does in each regime.
    parameter_status : dict
        Per model, the parameters that are not findings and why.
    discovery : dict or None
        What discovery found in the residual the verdict leaves.
    heldout_shrink_pct_above_noise : float
        The named (or best) model's share of the held-out gap above the noise floor, %.
    unsingled_partners : tuple of str
        Small further terms of a named effect that the data does not single out.
    training_only, whole_runs, nuisance_partner, coverage, partially_explained_by
        The rule that shaped the verdict, where one did (``None`` otherwise).
    combination_check : dict or None
        Whether a pair leaves noise wherever it acts.
    robot, actuation, tracking, reach : dict or None
        The fitted robot of a named verdict, a drive train that differs between logs,
        wheels that do not follow their commands, and the library's reach on the held-out
        windows of an unexplained verdict.
    """

    verdict_text: str = ""
    aliases: tuple[dict[str, Any], ...] = ()
    compensators: tuple[str, ...] = ()
    regime_consistency: tuple[dict[str, Any], ...] = ()
    parameter_status: Mapping[str, Mapping[str, str]] = field(default_factory=dict)
    discovery: dict[str, Any] | None = None
    heldout_shrink_pct_above_noise: float = math.nan
    unsingled_partners: tuple[str, ...] = ()
    training_only: TrainingOnly | None = None
    whole_runs: WholeRuns | None = None
    nuisance_partner: NuisancePartner | None = None
    coverage: CoverageNote | None = None
    combination_check: dict[str, Any] | None = None
    partially_explained_by: PartialExplanation | None = None
    robot: dict[str, Any] | None = None
    actuation: dict[str, Any] | None = None
    tracking: dict[str, Any] | None = None
    reach: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        """The notes as the diagnosis JSON holds them, in its order; a note that does not
        apply (``None``) is left out, except ``discovery``, which is always stated."""
        out: dict[str, Any] = {}
        if self.training_only is not None:
            out["training_only"] = self.training_only.to_json()
        if self.whole_runs is not None:
            out["whole_runs"] = self.whole_runs.to_json()
        out.update(
            {
                "verdict_text": self.verdict_text,
                "aliases": list(self.aliases),
                "compensators": list(self.compensators),
                "regime_consistency": list(self.regime_consistency),
                "parameter_status": {k: dict(v) for k, v in self.parameter_status.items()},
                "discovery": self.discovery,
                "heldout_shrink_pct_above_noise": self.heldout_shrink_pct_above_noise,
                "unsingled_partners": list(self.unsingled_partners),
            }
        )
        optional: dict[str, Any] = {
            "nuisance_partner": self.nuisance_partner,
            "coverage": self.coverage,
            "combination_check": self.combination_check,
            "partially_explained_by": self.partially_explained_by,
            "robot": self.robot,
            "actuation": self.actuation,
            "tracking": self.tracking,
            "reach": self.reach,
        }
        for key, note in optional.items():
            if note is not None:
                out[key] = note if isinstance(note, dict) else note.to_json()
        return out


# --------------------------------------------------------------------------- the verdict
def _label(kind: VerdictKind, effects: tuple[str, ...]) -> str | list[str]:
    return list(effects) if kind is VerdictKind.EFFECTS else kind.value


@dataclass(frozen=True)
class Draft:
    """A verdict before its rules and notes: what the held-out tests (or the two-scale test)
    conclude, and the rules revise.

    ``training_only`` and ``whole_runs`` say that it was drawn on the training windows alone
    or on whole held-out runs.
    """

    kind: VerdictKind
    effects: tuple[str, ...]
    reason: str
    margin: float
    confidence: Confidence
    residual: dict[str, Any]
    ambiguous_with: tuple[str, ...] = ()
    training_only: TrainingOnly | None = None
    whole_runs: WholeRuns | None = None

    @property
    def label(self) -> str | list[str]:
        """A list of effect names, or the kind's word."""
        return _label(self.kind, self.effects)


@dataclass(frozen=True)
class Judgement:
    """A draft verdict and the held-out figures it rests on.

    Attributes
    ----------
    draft : Draft
    best : ModelFit
        The model the draft rests on (the top-ranked one, or the one a rule adopted).
    nominal_heldout : ndarray, shape (n,)
        Normalised held-out residual of the nominal replay.
    gap_mask : ndarray of bool, shape (n,)
        Entries of the channels where the gap lives (nominal RMS above twice the floor).
    shrink_pct_best : float
        Held-out shrink of the best model in those channels, %.
    shrink_pct_above_noise : float
        The same, of the gap above the noise floor
        (:func:`~realitygap.diagnosis.problem.residual.shrink_above_noise`), %: the share the
        verdict's shrink test compares with ``min_shrink``.
    """

    draft: Draft
    best: ModelFit
    nominal_heldout: FloatArray
    gap_mask: npt.NDArray[np.bool_]
    shrink_pct_best: float
    shrink_pct_above_noise: float = math.nan

    @property
    def kind(self) -> VerdictKind:
        return self.draft.kind

    def revised(self, **changes: Any) -> Judgement:
        """This judgement with fields of its draft changed (``kind``, ``reason``, …)."""
        return replace(self, draft=replace(self.draft, **changes))


@dataclass(frozen=True)
class Decision:
    """What the rules decide (:func:`~realitygap.diagnosis.verdict.rules.decide`): the final
    judgement (its draft carries kind, effects, reason and confidence; ``best`` the model
    named) and the notes of the rules. The pipeline reads ``kind`` to run what depends on
    it, then :func:`~realitygap.diagnosis.verdict.conclude.conclude` writes the verdict."""

    judgement: Judgement
    notes: VerdictNotes

    @property
    def kind(self) -> VerdictKind:
        return self.judgement.draft.kind

    @property
    def effects(self) -> tuple[str, ...]:
        return self.judgement.draft.effects


@dataclass(frozen=True)
class Verdict:
    """The conclusion of an attribution (frozen: written once, by
    :func:`~realitygap.diagnosis.verdict.conclude.conclude`).

    ``kind`` is :attr:`VerdictKind.EFFECTS` (``effects`` names them),
    :attr:`VerdictKind.UNEXPLAINED` or :attr:`VerdictKind.NONE` (no significant gap on the
    held-out data, nor on the training data).
    """

    kind: VerdictKind
    effects: tuple[str, ...]
    reason: str
    margin: float
    confidence: Confidence
    residual: dict[str, Any]
    ambiguous_with: tuple[str, ...] = ()
    notes: VerdictNotes = field(default_factory=VerdictNotes)

    @property
    def label(self) -> str | list[str]:
        """What the JSON ``verdict`` holds: a list of effect names or a keyword."""
        return _label(self.kind, self.effects)
