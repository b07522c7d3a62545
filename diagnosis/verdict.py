"""The verdict: which effects explain the held-out gap, or why none does.

An effect (or pair) is named only if it improves on the nominal replay, closes
enough of the held-out gap in the channels where the gap lives, is not
stretched to the edge of its plausible range, and leaves an unstructured
residual; otherwise the verdict is ``"unexplained"`` (or ``"none"`` when the
nominal replay's residual already looks like noise).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.attribute import (
    AttributionSettings,
    ModelFit,
    Problem,
    Verdict,
    _spec,
    describe_residual,
)
from realitygap.diagnosis.shrink import overall_shrink

FloatArray = npt.NDArray[np.float64]

__all__ = ["Judgement", "judge"]


@dataclass
class Judgement:
    """The verdict and the held-out figures it rests on.

    Attributes
    ----------
    verdict : Verdict
    best : ModelFit
        The top-ranked model.
    nominal_heldout : ndarray, shape (n,)
        Normalised held-out residual of the nominal replay.
    gap_mask : ndarray of bool, shape (n,)
        Entries of the channels where the gap lives (nominal RMS above twice the floor).
    shrink_pct_best : float
        Held-out shrink of the best model in those channels, %.
    """

    verdict: Verdict
    best: ModelFit
    nominal_heldout: FloatArray
    gap_mask: npt.NDArray[np.bool_]
    shrink_pct_best: float


def gap_channels(z_nom: FloatArray, problem: Problem) -> npt.NDArray[np.bool_]:
    """Entries of the held-out groups whose nominal residual exceeds twice the floor (all
    entries if none does): channels the effects do not touch would only add their noise to
    both sides of the shrink."""
    gap_mask = np.zeros(z_nom.shape, dtype=bool)
    for g in np.unique(problem.holdout.group):
        sel = problem.holdout.group == g
        if float(np.sqrt(np.mean(z_nom[sel] ** 2))) > 2.0 * problem.settings.floor:
            gap_mask |= sel
    if not gap_mask.any():
        gap_mask[:] = True
    return gap_mask


def judge(
    problem: Problem,
    ranking: list[ModelFit],
    nominal_fit: ModelFit,
    noise: Mapping[str, float] | None,
) -> Judgement:
    """Draw the verdict from a verified ranking (best first).

    Parameters
    ----------
    problem : Problem
    ranking : list of ModelFit
    nominal_fit : ModelFit
        The model without effects.
    noise : mapping of group to float, optional
        Measurement noise the adapter states (feature-scale units).

    Returns
    -------
    Judgement
    """
    st = problem.settings
    scales = problem.features
    z_nom = problem.nominal_residuals(problem.holdout)
    nominal_desc = describe_residual(z_nom, problem.holdout, st, scales, noise)
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
    gap_mask = gap_channels(z_nom, problem)
    shrink_all = overall_shrink(z_nom[gap_mask], best.z_heldout[gap_mask])
    best_desc = describe_residual(best.z_heldout, problem.holdout, st, scales, noise)
    gain = nominal_fit.rank_score - best.rank_score
    if not nominal_desc["structured"] and gain < st.margin_strong:
        verdict = Verdict(
            "none",
            (),
            "the held-out residual of the nominal replay already looks like noise",
            margin,
            "n/a",
            nominal_desc,
        )
    elif not best.effects:
        verdict = Verdict(
            "unexplained",
            (),
            "no candidate effect improves on the nominal replay on held-out data",
            margin,
            "n/a",
            best_desc,
        )
    elif shrink_all < 100.0 * st.min_shrink:
        verdict = Verdict(
            "unexplained",
            (),
            f"the best candidate ({best.name}) closes only {shrink_all:.0f} % of the held-out "
            f"gap (needs {100 * st.min_shrink:.0f} %)",
            margin,
            "n/a",
            best_desc,
        )
    elif pinned := _pinned(problem, best):
        edges = ", ".join(
            f"{k} = {best.values[k]:.4g} {_spec(k).unit} (range {_spec(k).low:g} … "
            f"{_spec(k).high:g})"
            for k in pinned
        )
        verdict = Verdict(
            "unexplained",
            (),
            f"the best candidate ({best.name}, {shrink_all:.0f} % of the held-out gap) needs "
            f"{edges}: at the edge of the plausible range, so the effect is being stretched to "
            "absorb a gap it does not cause",
            margin,
            "n/a",
            best_desc,
        )
    elif best_desc["structured"]:
        verdict = Verdict(
            "unexplained",
            (),
            f"after the best candidate ({best.name}, {shrink_all:.0f} % of the held-out gap) "
            "the residual is still structured: " + "; ".join(best_desc["reasons"]),
            margin,
            "n/a",
            best_desc,
        )
    else:
        verdict = Verdict(
            "effects",
            best.effects,
            f"{best.name} closes {shrink_all:.0f} % of the held-out gap and leaves unstructured "
            "residuals",
            margin,
            _confidence(margin, st),
            best_desc,
        )
    return Judgement(verdict, best, z_nom, gap_mask, shrink_all)


def _pinned(problem: Problem, fit: ModelFit) -> list[str]:
    """Parameters of ``fit`` that sit at the far edge of their plausible range and matter.

    An effect fitted at the bound of its plausible range (the end away from "no
    effect") is being stretched to absorb a gap it does not cause. Parameters
    the logs cannot see (moving them back to nominal changes the training
    residual by less than the floor) are ignored.
    """
    out = []
    point = {k: np.array([v]) for k, v in fit.values.items()}
    base: FloatArray | None = None
    for key, value in fit.values.items():
        spec = _spec(key)
        span = spec.high - spec.low
        at_low = spec.low != spec.nominal and value - spec.low < 0.005 * span
        at_high = spec.high != spec.nominal and spec.high - value < 0.005 * span
        if not (at_low or at_high):
            continue
        if base is None:
            base = problem.surrogate_residuals(problem.train, point, 1)[0]
        alt = problem.surrogate_residuals(
            problem.train, {**point, key: np.array([spec.nominal])}, 1
        )[0]
        if float(np.sqrt(np.mean((alt - base) ** 2))) > problem.settings.floor:
            out.append(key)
    return out


def _confidence(margin: float, settings: AttributionSettings) -> str:
    if margin >= settings.margin_strong:
        return "strong"
    if margin >= 2.0:
        return "moderate"
    return "weak"
