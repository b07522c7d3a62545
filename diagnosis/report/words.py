"""The verdict in words: one line for the verdict and its reason, then one for each thing
it notes — aliases and the manoeuvre that would separate them, compensators, parameters that
are not findings, the two scales, the fitted robot, the drive train, discovery, the
library's reach and the motions the training never exercised.

The terminal (``realitygap diagnose``), the experiments and the report
(:mod:`realitygap.diagnosis.report.writer`, :func:`explain_markdown`) print the same lines.
"""

from __future__ import annotations

from collections.abc import Sequence

from realitygap.diagnosis.verdict.notes import improved_words
from realitygap.diagnosis.verdict.types import Verdict, VerdictKind

__all__ = ["explain", "explain_markdown"]

STATUS_WORDS: dict[str, str] = {
    "at bound": "sits at a bound of its physical range",
    "untestable": "is not exercised by the logged motions",
    "one-sided": "is bounded on one side only by the logged motions",
    "not identifiable": "cannot be identified from the training data and was held at nominal",
    "nuisance at range bound": "(a calibrated-baseline nuisance) ends at the edge "
    "of its nuisance range: the baseline absorbs part of a gap the model leaves",
}
"""A parameter status of :func:`~realitygap.diagnosis.fit.status.parameter_status` in words."""


def parameter_words(key: str) -> str:
    """``"effect.param"`` in words: the effect's name with spaces and the parameter's
    description where the effect states one (``truth_frame_offset.x`` → "ground-truth
    frame offset: x")."""
    from realitygap.robots.effects import EFFECTS

    effect, _, param = key.partition(".")
    cls = EFFECTS.get(effect)
    spec = next((p for p in getattr(cls, "specs", ()) if p.name == param), None)
    desc = str(getattr(spec, "description", "") or "").strip()
    name = effect.replace("_", " ")
    return f"{name}: {desc}" if desc else f"{name} {param}"


def explain(verdict: Verdict, top_models: Sequence[str] = ()) -> list[str]:
    """The verdict in words, then numbers: one line each for the verdict with its
    aliases, every alias and the manoeuvre that would separate it, compensators,
    parameters that are not findings (of ``top_models``, default all) and what
    discovery found in an unexplained residual."""
    notes = verdict.notes
    named = verdict.kind in (VerdictKind.EFFECTS, VerdictKind.PARTIAL)
    label = notes.verdict_text or (" + ".join(verdict.effects) if named else verdict.kind.value)
    lines = [f"verdict: {label}", f"reason: {verdict.reason}"]
    for a in notes.aliases:
        line = f"alias: {a['model']} fits as well ({'; '.join(a['why'])})"
        motion = a.get("separating_motion")
        if motion:
            line += (
                f"; recording '{motion['name']}' ({motion['description']}) would tell them apart"
            )
        else:
            line += "; no probe manoeuvre of this robot separates them"
        lines.append(line)
    for c in notes.regime_consistency:
        if c["compensator"]:
            lines.append(
                f"compensator: {c['model']} improves {improved_words(c)} and worsens the "
                f"{', '.join(c['worsened'])} windows: it makes up for something else rather "
                "than causing the gap"
            )
    # one line per reason, the parameters it applies to listed (not one line each)
    grouped: dict[str, list[str]] = {}
    for model, status in notes.parameter_status.items():
        if top_models and model not in top_models:
            continue
        for key, why in status.items():
            grouped.setdefault(why, []).append(f"{parameter_words(key)} ({model})")
    for why, where in grouped.items():
        what = STATUS_WORDS.get(why, why)
        shown = ", ".join(where[:4]) + (f" and {len(where) - 4} more" if len(where) > 4 else "")
        lines.append(f"not a finding (no error bar): {shown} — each {what}")
    if notes.robot is not None:
        lines.append(f"fitted robot: {notes.robot['message']}")
    if notes.actuation is not None:
        lines.append(f"drive train: {notes.actuation['message']}")
    if notes.tracking is not None:
        lines.append(f"wheels: {notes.tracking['message']}")
    if notes.discovery is not None:
        lines.append(f"discovery: {notes.discovery['message']}")
    if notes.reach is not None:
        lines.append(f"reach: {notes.reach['message']}")
    cov = notes.coverage
    if cov is not None:
        lines.append(f"beyond the training: {cov.summary}")
        if cov.suggestion:
            lines.append(f"experiment: {cov.suggestion}")
    return lines


def explain_markdown(verdict: Verdict, top_models: Sequence[str] = ()) -> list[str]:
    """:func:`explain` as Markdown bullet lines for a report, without the verdict and
    reason lines a report states itself, except when aliases change the verdict's words."""
    lines = explain(verdict, top_models)
    extra = lines[2:]
    if verdict.notes.aliases:
        extra = [lines[0], *extra]
    return [""] + [f"- {line}" for line in extra] if extra else []
