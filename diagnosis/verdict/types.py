"""The verdict's types: what it can say, how sure it is, and what it notes.

A diagnosis ends in a :class:`Verdict`, a frozen value written by one function,
:func:`~realitygap.diagnosis.verdict.conclude.conclude`, from the gap budget
(:mod:`~realitygap.diagnosis.budget`): its kind is the budget's, its effects the budget's
named entries. :class:`Judgement` holds the held-out figures of the budget's model that the
pipeline's later stages read (coverage, discovery, reach, the gap report).

:class:`VerdictKind` and :class:`Confidence` are string enums: each equals, and serialises
as, the word the JSON has always held (``"effects"``, ``"not identifiable"``, …).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.fit.model import ModelFit

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "Confidence",
    "CoverageNote",
    "Judgement",
    "Verdict",
    "VerdictKind",
    "VerdictNotes",
]


class VerdictKind(str, Enum):
    """What a verdict says: effects named (``PARTIAL``: named, but a structured half of the
    gap or more remains), a gap left unexplained, or no gap."""

    EFFECTS = "effects"
    PARTIAL = "partial"
    UNEXPLAINED = "unexplained"
    NONE = "none"

    def __str__(self) -> str:
        return self.value


class Confidence(str, Enum):
    """How far a verdict can be trusted.

    ``STRONG``, ``MODERATE`` and ``WEAK`` grade the cross-validated evidence of the first
    named effect (its paired test's p-value below 10⁻⁴, 10⁻², or above); a named effect the
    data cannot tell from another is ``NOT_IDENTIFIABLE``; a verdict that names nothing
    ``NOT_APPLICABLE``.
    """

    STRONG = "strong"
    MODERATE = "moderate"
    WEAK = "weak"
    NOT_IDENTIFIABLE = "not identifiable"
    NOT_APPLICABLE = "n/a"

    def __str__(self) -> str:
        return self.value


# --------------------------------------------------------------------------- notes
@dataclass(frozen=True)
class CoverageNote:
    """What remains lies in motions the training never exercised: where, and what to record."""

    summary: str
    suggestion: str

    def to_json(self) -> dict[str, Any]:
        return {"summary": self.summary, "suggestion": self.suggestion}


@dataclass(frozen=True)
class VerdictNotes:
    """What a verdict notes beside its kind and reason (:meth:`to_json`: the keys the
    diagnosis JSON holds next to ``verdict``).

    Attributes
    ----------
    verdict_text : str
        The verdict in words: the budget's sentence.
    aliases : tuple of dict
        Effects the data cannot tell from the first named one (``model``, ``effects``,
        ``why``, ``separating_motion`` where a manoeuvre would separate them).
    regime_consistency : tuple of dict
        Per model of the top of the ranking, what it does in each regime.
    parameter_status : dict
        Per model, the parameters that are not findings and why.
    discovery : dict or None
        What discovery found in the residual the budget leaves.
    coverage : CoverageNote or None
        Where what remains lies beyond the training's motions.
    robot, actuation, tracking, reach : dict or None
        The fitted robot of the named effects, a drive train that differs between logs,
        wheels that do not follow their commands, and the library's reach on the held-out
        windows when nothing is named.
    """

    verdict_text: str = ""
    aliases: tuple[dict[str, Any], ...] = ()
    regime_consistency: tuple[dict[str, Any], ...] = ()
    parameter_status: Mapping[str, Mapping[str, str]] = field(default_factory=dict)
    discovery: dict[str, Any] | None = None
    coverage: CoverageNote | None = None
    robot: dict[str, Any] | None = None
    actuation: dict[str, Any] | None = None
    tracking: dict[str, Any] | None = None
    reach: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        """The notes as the diagnosis JSON holds them, in its order; a note that does not
        apply (``None``) is left out, except ``discovery``, which is always stated."""
        out: dict[str, Any] = {
            "verdict_text": self.verdict_text,
            "aliases": list(self.aliases),
            "regime_consistency": list(self.regime_consistency),
            "parameter_status": {k: dict(v) for k, v in self.parameter_status.items()},
            "discovery": self.discovery,
        }
        optional: dict[str, Any] = {
            "coverage": self.coverage,
            # not "robot": the diagnosis JSON's "robot" is the adapter's name
            "fitted_robot": self.robot,
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
    return list(effects) if kind in (VerdictKind.EFFECTS, VerdictKind.PARTIAL) else kind.value


@dataclass(frozen=True)
class Judgement:
    """The held-out figures of the budget's model.

    Attributes
    ----------
    kind : VerdictKind
        The budget's kind.
    best : ModelFit
        The budget's model (the calibrated baseline when it names nothing).
    nominal_heldout : ndarray, shape (n,)
        Normalised held-out residual of the reference replay.
    gap_mask : ndarray of bool, shape (n,)
        Entries of the channels where the gap lives (reference RMS above twice the floor).
    shrink_pct_best : float
        Held-out shrink of the budget's model in those channels, %.
    shrink_pct_above_noise : float
        The same, of the gap above the noise floor, %.
    """

    kind: VerdictKind
    best: ModelFit
    nominal_heldout: FloatArray
    gap_mask: npt.NDArray[np.bool_]
    shrink_pct_best: float
    shrink_pct_above_noise: float = math.nan


@dataclass(frozen=True)
class Verdict:
    """The conclusion of an attribution (frozen: written once, by
    :func:`~realitygap.diagnosis.verdict.conclude.conclude`).

    ``kind`` is :attr:`VerdictKind.EFFECTS` or :attr:`VerdictKind.PARTIAL` (``effects``
    names them), :attr:`VerdictKind.UNEXPLAINED` or :attr:`VerdictKind.NONE`; ``reason``
    is the rule of the budget that set it.
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
