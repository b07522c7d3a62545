"""The verdict's held-out tests: which model, if any, the held-out windows name.

An effect (or pair) is named only if it improves on the nominal replay, closes
enough of the held-out gap above the noise floor in the channels where the gap
lives, is not stretched to the edge of its plausible range, and leaves an
unstructured residual — or, as a single effect, closes nearly all of the gap
(``dominant_shrink``), when a small structured rest says only that its law differs
in detail from the library's (a pair with a structured rest may be one effect and
its compensator); otherwise the draft is ``"unexplained"`` (or ``"none"`` when the
nominal replay's residual already looks like noise, on the held-out windows and on the
training windows alike; a gap that only the training windows show — held-out motions that
do not exercise it — is judged there, and its effect named with confidence
``"training only"``, by :func:`training_gap`).

:func:`judge` returns a :class:`~realitygap.diagnosis.verdict.types.Judgement`: the draft
and the held-out figures it rests on. The rules (:mod:`realitygap.diagnosis.verdict.rules`)
revise it; :func:`~realitygap.diagnosis.verdict.conclude.conclude` writes the verdict.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.fit.status import pinned_parameters
from realitygap.diagnosis.problem.parameters import param_spec
from realitygap.diagnosis.problem.problem import AttributionSettings, Layout, Problem
from realitygap.diagnosis.problem.residual import (
    above_sample_noise,
    describe_residual,
    shrink_above_noise,
)
from realitygap.diagnosis.problem.shrink import overall_shrink
from realitygap.diagnosis.verdict.types import (
    Confidence,
    Draft,
    Judgement,
    TrainingOnly,
    VerdictKind,
)

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "confidence_of",
    "describe_fit_residual",
    "gap_channels",
    "judge",
    "training_gap",
]


def gap_channels(
    z_nom: FloatArray, problem: Problem, layout: Layout | None = None
) -> npt.NDArray[np.bool_]:
    """Entries of the held-out groups (of ``layout``'s, e.g. the training windows) whose
    nominal residual exceeds twice the floor (all entries if none does): channels the
    effects do not touch would only add their noise to both sides of the shrink."""
    lay = problem.holdout if layout is None else layout
    gap_mask = np.zeros(z_nom.shape, dtype=bool)
    for g in np.unique(lay.group):
        sel = lay.group == g
        if float(np.sqrt(np.mean(z_nom[sel] ** 2))) > 2.0 * problem.settings.floor:
            gap_mask |= sel
    if not gap_mask.any():
        gap_mask[:] = True
    return gap_mask


def confidence_of(margin: float, settings: AttributionSettings) -> Confidence:
    """The confidence of a named model with score ``margin`` to the runner-up: strong from
    :attr:`AttributionSettings.margin_strong`, moderate from 2, else weak."""
    if margin >= settings.margin_strong:
        return Confidence.STRONG
    if margin >= 2.0:
        return Confidence.MODERATE
    return Confidence.WEAK


def describe_fit_residual(
    problem: Problem, fit: ModelFit, noise: Mapping[str, float] | None
) -> dict[str, Any]:
    """What ``fit`` leaves on the held-out windows
    (:func:`~realitygap.diagnosis.problem.residual.describe_residual`), with the adapter's own
    structure test (``residual_structure``) when the model has effects."""
    desc = describe_residual(
        fit.z_heldout, problem.holdout, problem.settings, problem.features, noise
    )
    if fit.effects:
        desc = problem.adapter.residual_structure(problem, fit.values, desc)
    return desc


def _with_reasons(desc: dict[str, Any], reasons: Sequence[str]) -> dict[str, Any]:
    """``desc`` of :func:`~realitygap.diagnosis.problem.residual.describe_residual` with ``reasons``
    of structure added (itself when there are none)."""
    if not reasons:
        return desc
    return {**desc, "structured": True, "reasons": [*desc["reasons"], *reasons]}


def judge(
    problem: Problem,
    ranking: list[ModelFit],
    nominal_fit: ModelFit,
    noise: Mapping[str, float] | None,
    sample_noise: Mapping[str, Mapping[str, float]] | None = None,
) -> Judgement:
    """Draw the draft verdict from a verified ranking (best first).

    Parameters
    ----------
    problem : Problem
    ranking : list of ModelFit
    nominal_fit : ModelFit
        The model without effects.
    noise : mapping of group to float, optional
        Measurement noise the adapter states (feature-scale units).
    sample_noise : mapping of group to mapping of column to float, optional
        The noise the sensors' own samples show (the adapter's ``sample_noise_levels``):
        a nominal residual that passes for white is called noise ("none") only within
        it (:func:`~realitygap.diagnosis.problem.residual.above_sample_noise`).

    Returns
    -------
    Judgement
    """
    st = problem.settings
    scales = problem.features
    z_nom = problem.nominal_residuals(problem.holdout)
    nominal_desc = describe_residual(z_nom, problem.holdout, st, scales, noise)
    nominal_desc = problem.adapter.residual_structure(problem, {}, nominal_desc)
    fast: list[str] = []
    if sample_noise and not nominal_desc["structured"]:
        # white from window to window, but is it as small as the sensors' own noise?
        fast = above_sample_noise(z_nom, problem.holdout, sample_noise, st)
        nominal_desc = _with_reasons(nominal_desc, fast)
    best = ranking[0]
    # the runner-up: the best model that is neither this one nor a superset rejected for it
    runner = next(
        (
            f
            for f in ranking[1:]
            if f.effects != best.effects
            and not (best.effects and set(f.effects) > set(best.effects))
        ),
        None,
    )
    margin = (runner.rank_score - best.rank_score) if runner is not None else math.inf
    gain = nominal_fit.rank_score - best.rank_score
    quiet = not nominal_desc["structured"] and gain < st.margin_strong
    # the held-out windows look like noise: "none" only if the training windows do too; else
    # the held-out motions fail to exercise what the training shows (judged there)
    untested = training_gap(problem, ranking, noise, margin) if quiet else None
    if untested is not None and untested[1] is not None:
        best = untested[1]
    gap_mask = gap_channels(z_nom, problem)
    shrink_all = overall_shrink(z_nom[gap_mask], best.z_heldout[gap_mask])
    # the noise in the held-out gap is closed by no effect: the test counts the gap above it
    shrink_gap = shrink_above_noise(z_nom, best.z_heldout, problem.holdout, gap_mask, noise)
    best_desc = describe_fit_residual(problem, best, noise)
    if not best.effects:  # the nominal is the best: what remains is what it left
        best_desc = _with_reasons(best_desc, fast)
    unexplained, na = VerdictKind.UNEXPLAINED, Confidence.NOT_APPLICABLE
    if untested is not None:
        draft = untested[0]
    elif quiet:
        draft = Draft(
            VerdictKind.NONE,
            (),
            "the held-out residual of the nominal replay already looks like noise",
            margin,
            na,
            nominal_desc,
        )
    elif not best.effects:
        draft = Draft(
            unexplained,
            (),
            "no candidate effect improves on the nominal replay on held-out data",
            margin,
            na,
            best_desc,
        )
    elif shrink_gap < 100.0 * st.min_shrink:
        draft = Draft(
            unexplained,
            (),
            f"the best candidate ({best.name}) closes only {shrink_gap:.0f} % of the held-out "
            f"gap above the noise floor ({shrink_all:.0f} % of the raw gap; needs "
            f"{100 * st.min_shrink:.0f} %)",
            margin,
            na,
            best_desc,
        )
    elif pinned := pinned_parameters(problem, best):
        edges = ", ".join(
            f"{k} = {best.values[k]:.4g} {param_spec(k).unit} (range {param_spec(k).low:g} … "
            f"{param_spec(k).high:g})"
            for k in pinned
        )
        draft = Draft(
            unexplained,
            (),
            f"the best candidate ({best.name}, {shrink_all:.0f} % of the held-out gap) needs "
            f"{edges}: at the edge of the plausible range, so the effect is being stretched to "
            "absorb a gap it does not cause",
            margin,
            na,
            best_desc,
        )
    elif (
        best_desc["structured"]
        and len(best.effects) == 1
        and shrink_gap >= 100.0 * st.dominant_shrink
    ):
        confidence = confidence_of(margin, st)
        draft = Draft(
            VerdictKind.EFFECTS,
            best.effects,
            f"{best.name} closes {shrink_gap:.0f} % of the held-out gap above the noise floor "
            f"({shrink_all:.0f} % of the raw gap); what it leaves is small but structured, so "
            "the effect's law differs in detail from the library's: "
            + "; ".join(best_desc["reasons"]),
            margin,
            Confidence.MODERATE if confidence is Confidence.STRONG else confidence,
            best_desc,
        )
    elif best_desc["structured"]:
        draft = Draft(
            unexplained,
            (),
            f"after the best candidate ({best.name}, {shrink_all:.0f} % of the held-out gap) "
            "the residual is still structured: " + "; ".join(best_desc["reasons"]),
            margin,
            na,
            best_desc,
        )
    else:
        draft = Draft(
            VerdictKind.EFFECTS,
            best.effects,
            f"{best.name} closes {shrink_gap:.0f} % of the held-out gap above the noise floor "
            f"({shrink_all:.0f} % of the raw gap) and leaves unstructured residuals",
            margin,
            confidence_of(margin, st),
            best_desc,
        )
    return Judgement(draft, best, z_nom, gap_mask, shrink_all, shrink_gap)


def training_gap(
    problem: Problem,
    ranking: Sequence[ModelFit],
    noise: Mapping[str, float] | None,
    margin: float = math.nan,
) -> tuple[Draft, ModelFit | None] | None:
    """The draft verdict when the held-out residual of the nominal replay looks like noise
    but the training windows' does not; ``None`` when the training's looks like noise too
    ("none").

    Held-out motions can fail to exercise an effect that the training shows plainly: a
    tool-point offset is invisible to the distances of held-out poses that keep one
    orientation. "None" would then say the robot is nominal. Instead the candidates are
    judged on the training windows, where the gap is: the one with the best training score
    (BIC) is named, with confidence :attr:`Confidence.TRAINING_ONLY`, when it closes at least
    :attr:`AttributionSettings.dominant_shrink` of the training gap above the noise floor,
    leaves a training residual that looks like noise, sits at no edge of its range, and
    leaves the held-out residual looking like noise (it does not spoil what it cannot be
    tested on). Other models that pass the same tests are its aliases on this data. Else
    the draft is "unexplained". Returns the draft and the named model's fit (``None``
    for "unexplained").
    """
    st, scales = problem.settings, problem.features
    if problem.train.n == 0:
        return None
    z0 = problem.nominal_residuals(problem.train)
    desc0 = describe_residual(z0, problem.train, st, scales, noise)
    if not desc0["structured"]:
        return None
    excess = max(
        (g.get("excess_ratio", 0.0) for g in desc0["groups"].values()), default=float("nan")
    )
    gap = "; ".join(desc0["reasons"])
    mask = gap_channels(z0, problem, problem.train)
    passed: list[tuple[ModelFit, float, dict[str, Any]]] = []
    for f in sorted((f for f in ranking if f.effects), key=lambda f: f.bic)[:8]:
        z = problem.surrogate_residuals(
            problem.train, {k: np.array([v]) for k, v in f.values.items()}, 1
        )[0]
        closed = shrink_above_noise(z0, z, problem.train, mask, noise)
        if closed < 100.0 * st.dominant_shrink or pinned_parameters(problem, f):
            continue
        if describe_residual(z, problem.train, st, scales, noise)["structured"]:
            continue
        held_out = describe_fit_residual(problem, f, noise)
        if held_out["structured"]:
            continue
        passed.append((f, closed, held_out))
    held = "the held-out residual of the nominal replay already looks like noise"
    if not passed:
        return (
            Draft(
                VerdictKind.UNEXPLAINED,
                (),
                f"{held}, but the training windows' does not ({gap}) and no candidate closes "
                f"at least {100 * st.dominant_shrink:.0f} % of that gap leaving noise: the "
                "held-out motions do not exercise what the training shows",
                margin,
                Confidence.NOT_APPLICABLE,
                desc0,
            ),
            None,
        )
    best, closed, held_out = passed[0]
    others = [
        f.name
        for f, _, _ in passed[1:]
        if not (set(f.effects) <= set(best.effects) or set(f.effects) >= set(best.effects))
    ]
    alias = f" ({' or '.join(others)} does it as well: aliases on this data)" if others else ""
    draft = Draft(
        VerdictKind.EFFECTS,
        best.effects,
        f"{held}: the held-out motions do not exercise the gap; the training windows' nominal "
        f"residual is up to {excess:.0f}× its noise level, and {best.name} closes "
        f"{closed:.0f} % of that gap above the noise floor and leaves noise{alias} — a finding "
        "of the training alone: held-out runs that exercise it would confirm it",
        margin,
        Confidence.TRAINING_ONLY,
        held_out,
        ambiguous_with=tuple(others[:3]),
        training_only=TrainingOnly(
            model=best.name,
            train_gap_excess=excess,
            train_shrink_pct_above_noise=closed,
            aliases=tuple(others[:3]),
        ),
    )
    return draft, best
