"""The verdict: which effects explain the held-out gap, or why none does.

An effect (or pair) is named only if it improves on the nominal replay, closes
enough of the held-out gap above the noise floor in the channels where the gap
lives, is not
stretched to the edge of its plausible range, and leaves an unstructured
residual — or, as a single effect, closes nearly all of the gap
(``dominant_shrink``), when a small structured rest says only that its law differs
in detail from the library's (a pair with a structured rest may be one effect and
its compensator);
otherwise the verdict is ``"unexplained"`` (or ``"none"`` when the
nominal replay's residual already looks like noise, on the held-out windows and on the
training windows alike; a gap that only the training windows show — held-out motions that
do not exercise it — is judged there, and its effect named with confidence
``"training only"``, by :func:`training_gap`). A combination of two
effects must also leave noise, at each channel's own resolution, in every
regime where it acts (:func:`combination_check`): two effects fitted together
can stand in for one mechanism outside the library that couples them, and
such a verdict is "unexplained (partially explained by X + Y: N % of the
held-out gap)" — unless X or Y alone closes nearly all of the gap
(:func:`dominant_single`): then the pair's structured rest says that effect's
law differs in detail from the library's, and it is named alone.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.problem.parameters import param_spec, range_position
from realitygap.diagnosis.problem.problem import AttributionSettings, Layout, Problem
from realitygap.diagnosis.problem.residual import (
    above_sample_noise,
    column_levels,
    describe_residual,
    shrink_above_noise,
    white_level,
)
from realitygap.diagnosis.problem.shrink import overall_shrink
from realitygap.diagnosis.verdict.types import Verdict

if TYPE_CHECKING:
    from realitygap.diagnosis.stages.coverage import Coverage

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "Judgement",
    "alias_notes",
    "combination_check",
    "conclude",
    "dominant_single",
    "explain",
    "explain_markdown",
    "judge",
    "parameter_status",
    "regime_consistency",
    "run_discovery",
    "training_gap",
    "verdict_alternatives",
]


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
    shrink_pct_above_noise : float
        The same, of the gap above the noise floor
        (:func:`~realitygap.diagnosis.problem.residual.shrink_above_noise`), %: the share the
        verdict's shrink test compares with ``min_shrink``.
    """

    verdict: Verdict
    best: ModelFit
    nominal_heldout: FloatArray
    gap_mask: npt.NDArray[np.bool_]
    shrink_pct_best: float
    shrink_pct_above_noise: float = math.nan


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
    """Draw the verdict from a verified ranking (best first).

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
    structure = getattr(problem.adapter, "residual_structure", None)  # adapter's own test
    if structure is not None:
        nominal_desc = structure(problem, {}, nominal_desc)
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
    if untested is not None:
        verdict = untested[0]
    elif quiet:
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
    elif shrink_gap < 100.0 * st.min_shrink:
        verdict = Verdict(
            "unexplained",
            (),
            f"the best candidate ({best.name}) closes only {shrink_gap:.0f} % of the held-out "
            f"gap above the noise floor ({shrink_all:.0f} % of the raw gap; needs "
            f"{100 * st.min_shrink:.0f} %)",
            margin,
            "n/a",
            best_desc,
        )
    elif pinned := pinned_parameters(problem, best):
        edges = ", ".join(
            f"{k} = {best.values[k]:.4g} {param_spec(k).unit} (range {param_spec(k).low:g} … "
            f"{param_spec(k).high:g})"
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
    elif (
        best_desc["structured"]
        and len(best.effects) == 1
        and shrink_gap >= 100.0 * st.dominant_shrink
    ):
        confidence = _confidence(margin, st)
        verdict = Verdict(
            "effects",
            best.effects,
            f"{best.name} closes {shrink_gap:.0f} % of the held-out gap above the noise floor "
            f"({shrink_all:.0f} % of the raw gap); what it leaves is small but structured, so "
            "the effect's law differs in detail from the library's: "
            + "; ".join(best_desc["reasons"]),
            margin,
            "moderate" if confidence == "strong" else confidence,
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
            f"{best.name} closes {shrink_gap:.0f} % of the held-out gap above the noise floor "
            f"({shrink_all:.0f} % of the raw gap) and leaves unstructured residuals",
            margin,
            _confidence(margin, st),
            best_desc,
        )
    return Judgement(verdict, best, z_nom, gap_mask, shrink_all, shrink_gap)


TRAINING_ONLY = "training only"
"""The confidence of a verdict that rests on the training windows alone (:func:`training_gap`)."""


def training_gap(
    problem: Problem,
    ranking: Sequence[ModelFit],
    noise: Mapping[str, float] | None,
    margin: float = math.nan,
) -> tuple[Verdict, ModelFit | None] | None:
    """The verdict when the held-out residual of the nominal replay looks like noise but the
    training windows' does not; ``None`` when the training's looks like noise too ("none").

    Held-out motions can fail to exercise an effect that the training shows plainly: a
    tool-point offset is invisible to the distances of held-out poses that keep one
    orientation. "None" would then say the robot is nominal. Instead the candidates are
    judged on the training windows, where the gap is: the one with the best training score
    (BIC) is named, with confidence :data:`TRAINING_ONLY`, when it closes at least
    :attr:`AttributionSettings.dominant_shrink` of the training gap above the noise floor,
    leaves a training residual that looks like noise, sits at no edge of its range, and
    leaves the held-out residual looking like noise (it does not spoil what it cannot be
    tested on). Other models that pass the same tests are its aliases on this data. Else
    the verdict is "unexplained". Returns the verdict and the named model's fit (``None``
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
            Verdict(
                "unexplained",
                (),
                f"{held}, but the training windows' does not ({gap}) and no candidate closes "
                f"at least {100 * st.dominant_shrink:.0f} % of that gap leaving noise: the "
                "held-out motions do not exercise what the training shows",
                margin,
                "n/a",
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
    verdict = Verdict(
        "effects",
        best.effects,
        f"{held}: the held-out motions do not exercise the gap; the training windows' nominal "
        f"residual is up to {excess:.0f}× its noise level, and {best.name} closes "
        f"{closed:.0f} % of that gap above the noise floor and leaves noise{alias} — a finding "
        "of the training alone: held-out runs that exercise it would confirm it",
        margin,
        TRAINING_ONLY,
        held_out,
        ambiguous_with=others[:3],
    )
    verdict.notes["training_only"] = {
        "model": best.name,
        "train_gap_excess": excess,
        "train_shrink_pct_above_noise": closed,
        "aliases": others[:3],
    }
    return verdict, best


def describe_fit_residual(
    problem: Problem, fit: ModelFit, noise: Mapping[str, float] | None
) -> dict[str, Any]:
    """What ``fit`` leaves on the held-out windows
    (:func:`~realitygap.diagnosis.problem.residual.describe_residual`), with the adapter's own
    structure test (``residual_structure``) where it has one and the model has effects."""
    desc = describe_residual(
        fit.z_heldout, problem.holdout, problem.settings, problem.features, noise
    )
    structure = getattr(problem.adapter, "residual_structure", None)
    if structure is not None and fit.effects:
        desc = structure(problem, fit.values, desc)
    return desc


def pinned_parameters(problem: Problem, fit: ModelFit) -> list[str]:
    """Parameters of ``fit`` that sit at the far edge of their plausible range and matter.

    An effect fitted at the bound of its plausible range (the end away from "no
    effect") is being stretched to absorb a gap it does not cause. "At the
    bound" is within 0.5 % of the range in the coordinates the fit searches
    (:func:`~realitygap.diagnosis.problem.parameters.range_position`: logarithmic for a
    parameter spanning decades, such as a speed limit). Parameters
    the logs cannot see (moving them back to nominal changes the training
    residual by less than the floor) are ignored.
    """
    out = []
    point = {k: np.array([v]) for k, v in fit.values.items()}
    base: FloatArray | None = None
    for key, value in fit.values.items():
        spec = param_spec(key)
        if not (math.isfinite(spec.low) and math.isfinite(spec.high)):
            continue
        # in the coordinates the fit searches (log units for a range of decades)
        u = range_position(key, value)
        at_low = spec.low != spec.nominal and u < 0.005
        at_high = spec.high != spec.nominal and u > 0.995
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


# --------------------------------------------------------------------------- after the verdict
def regime_consistency(
    problem: Problem,
    fit: ModelFit,
    z_nom: FloatArray,
    mask: npt.NDArray[np.bool_] | None = None,
    *,
    t_worse: float = 3.0,
    t_better: float = 2.0,
    ratio_worse: float = 1.1,
    min_entries: int = 10,
) -> dict[str, Any]:
    r"""Does ``fit`` improve every regime it touches on held-out data?

    Per regime ``r`` (held-out entries of the gap channels), the paired
    difference of squared residuals :math:`d_i = z_{fit,i}^2 - z_{nom,i}^2`
    decides: the regime is worsened when :math:`\bar d / (s_d / \sqrt{n}) >`
    ``t_worse`` and the RMS grows by more than ``ratio_worse``; improved when
    the same statistic is below ``-t_better``. A model that worsens a regime
    while improving another, or the held-out gap as a whole, is a likely
    compensator: it trades one error for another rather than removing a cause.

    Returns
    -------
    dict
        ``regimes`` (per regime: entries, RMS before / after, shrink %, t and
        ``"improved"`` / ``"worsened"`` / ``"unchanged"``), ``improved``,
        ``worsened`` and ``compensator``.
    """
    lay = problem.holdout
    if z_nom.shape != (lay.n,) or fit.z_heldout.shape != (lay.n,):
        raise ValueError(
            f"regime_consistency: residuals must have the held-out layout's length {lay.n}; got "
            f"{z_nom.shape} and {fit.z_heldout.shape}"
        )
    sel = np.ones(lay.n, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    rows: dict[str, dict[str, Any]] = {}
    improved: list[str] = []
    worsened: list[str] = []
    for r in sorted(set(lay.regime[sel].tolist())):
        m = sel & (lay.regime == r)
        n = int(m.sum())
        if n < min_entries:
            continue
        a, b = z_nom[m], fit.z_heldout[m]
        d = b**2 - a**2
        sd = float(np.std(d, ddof=1))
        t = float(np.mean(d) / (sd / math.sqrt(n))) if sd > 0 else 0.0
        rms_a, rms_b = float(np.sqrt(np.mean(a**2))), float(np.sqrt(np.mean(b**2)))
        if t > t_worse and rms_b > ratio_worse * rms_a:
            state = "worsened"
            worsened.append(r)
        elif t < -t_better:
            state = "improved"
            improved.append(r)
        else:
            state = "unchanged"
        rows[r] = {
            "entries": n,
            "rms_nominal": rms_a,
            "rms_model": rms_b,
            "shrink_pct": overall_shrink(a, b),
            "t": t,
            "state": state,
        }
    return {
        "model": fit.name,
        "regimes": rows,
        "improved": improved,
        "worsened": worsened,
        "shrink_pct": overall_shrink(z_nom[sel], fit.z_heldout[sel]),
        "compensator": bool(
            worsened and (improved or overall_shrink(z_nom[sel], fit.z_heldout[sel]) > 0)
        ),
    }


def combination_check(
    problem: Problem,
    fit: ModelFit,
    z_nom: FloatArray,
    mask: npt.NDArray[np.bool_] | None = None,
    *,
    min_entries: int = 10,
) -> dict[str, Any]:
    r"""Is the residual a combination of effects leaves noise-like wherever it acts?

    Two effects fitted together have the freedom to mimic one mechanism outside
    the library that couples them (a top speed that falls with acceleration
    looks like a speed limit plus an acceleration limit). A combination is
    accepted only if, in every feature group and motion regime where the gap
    lived on held-out data (nominal RMS above ``excess_ratio`` of
    :class:`AttributionSettings` times the noise level) and that it improves,
    the residual it leaves is within ``excess_ratio`` of the noise level, or
    below the structure floor (``floor``: smaller effects are below what the logs
    resolve). Each column of a group is judged on its own (the columns come from
    different sensors or axes: a motion-capture heading's noise is not structure,
    and it does not hide a drift in the quieter position) against the larger of
    its window-to-window level of that residual over the group and within the
    regime (:func:`~realitygap.diagnosis.problem.residual.white_level`), not raised to the
    floor, so a channel that resolves far below the floor (wheel encoders) is
    judged at its own resolution.

    Returns
    -------
    dict
        ``model``, ``checked`` (per group, column and regime: RMS before and after,
        noise level, ratio), ``failed`` (the same rows where the ratio exceeds the
        limit, worst first) and ``passed``.
    """
    lay = problem.holdout
    sel = np.ones(lay.n, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    if z_nom.shape != (lay.n,) or fit.z_heldout.shape != (lay.n,):
        raise ValueError(
            f"combination_check: residuals must have the held-out layout's length {lay.n}; got "
            f"{z_nom.shape} and {fit.z_heldout.shape}"
        )
    limit = problem.settings.excess_ratio
    z = fit.z_heldout
    rows: list[dict[str, Any]] = []
    for g in sorted(set(lay.group[sel].tolist())):
        mg = sel & (lay.group == g)
        for c, column_level in column_levels(z, lay, mg).items():
            mc = mg & (lay.column == c)
            for r in sorted(set(lay.regime[mc].tolist())):
                m = mc & (lay.regime == r)
                n = int(m.sum())
                if n < min_entries:
                    continue
                level = max(column_level, white_level(z, lay, m), 1e-12)
                rms = float(np.sqrt(np.mean(z[m] ** 2)))
                rms_nom = float(np.sqrt(np.mean(z_nom[m] ** 2)))
                if rms_nom <= limit * level or rms >= rms_nom:
                    continue  # no gap lived here, or the combination does not act on it
                rows.append(
                    {
                        "group": g,
                        "column": str(c),
                        "regime": r,
                        "entries": n,
                        "rms_nominal": rms_nom,
                        "rms_model": rms,
                        "noise_level": level,
                        "ratio": rms / level,
                    }
                )
    floor = problem.settings.floor
    failed = sorted(
        (x for x in rows if x["ratio"] > limit and x["rms_model"] > floor),
        key=lambda x: -x["ratio"],
    )
    return {"model": fit.name, "checked": rows, "failed": failed, "passed": not failed}


def parameter_status(problem: Problem, fit: ModelFit, step: float = 0.25) -> dict[str, str]:
    """Which fitted parameters are not findings: ``"at bound"`` or ``"untestable"``.

    A parameter sits *at a bound* when it lies within 0.5 % of its range from
    either end of its physical range (in the coordinates the fit searches:
    logarithmic for a parameter spanning decades), unless that end is its nominal value
    (a lag of 0 s, a dead zone of 0 m/s: the part of the effect is absent, not
    stretched to a limit). It is *untestable* when the training data
    are flat around it: moving it towards either bound by ``step`` of the
    distance to that bound changes no training window by more than the noise
    floor (a speed limit far above anything the robot was commanded, a dead
    zone below every command); *one-sided* when only one of the two moves
    changes anything (the logs bound it on one side only: a speed limit just
    above the fastest command). Parameters the fit held at nominal because the
    training data cannot identify them (:attr:`ModelFit.held`) are *not
    identifiable*. A calibrated-baseline nuisance refined with the model
    (``problem.baseline_ranges``) that ends at an edge of its nuisance range,
    other than its "no effect" value, is a *nuisance at range bound*: the
    baseline is absorbing part of a gap the model leaves. None of these gets an
    error bar.
    """
    held = {k: "not identifiable" for k in fit.held}
    # calibrated-baseline nuisances refined with the model, pinned at an end of their range
    for k, (a, b) in getattr(problem, "baseline_ranges", {}).items():
        if k in fit.keys or k not in fit.values:
            continue
        lo, hi = min(a, b), max(a, b)
        v, nominal, near = fit.values[k], param_spec(k).nominal, 0.005 * (hi - lo)
        if hi > lo and any(abs(v - e) < near and abs(nominal - e) >= near for e in (lo, hi)):
            held[k] = "nuisance at range bound"
    if not fit.keys:
        return held
    keys = list(fit.keys)
    pts: list[dict[str, float]] = [dict(fit.values)]
    for k in keys:
        spec = param_spec(k)
        v = fit.values[k]
        for end in (spec.low, spec.high):
            moved = v + step * (end - v) if math.isfinite(end) else v
            pts.append({**fit.values, k: float(moved)})
    batch = {k: np.array([pt[k] for pt in pts]) for k in keys}
    z = problem.surrogate_residuals(problem.train, batch, len(pts))
    out: dict[str, str] = {}
    for j, k in enumerate(keys):
        spec = param_spec(k)
        span = spec.high - spec.low
        v = fit.values[k]
        change = [float(np.max(np.abs(z[1 + 2 * j + e] - z[0]))) for e in (0, 1)]
        near = 0.005
        finite = math.isfinite(span)
        # positions in the range, in the coordinates the fit searches (log units for decades)
        u = range_position(k, v) if finite else 0.5
        u_nom = range_position(k, spec.nominal) if finite else 0.5
        # "no effect" may sit at a bound (a lag of 0 s): there the fit is absent, not pinned
        nominal_is_bound = min(u_nom, 1.0 - u_nom) < near
        at_nominal_end = nominal_is_bound and abs(u - u_nom) < near
        if finite and min(u, 1.0 - u) < near and not at_nominal_end:
            out[k] = "at bound"
        elif at_nominal_end:  # only the move away from nominal can show anything
            if max(change) < problem.settings.floor:
                out[k] = "untestable"
        elif max(change) < problem.settings.floor:
            out[k] = "untestable"
        elif min(change) < problem.settings.floor:
            out[k] = "one-sided"
    return {**out, **held}


def _known_alias_groups(problem: Problem, effects: Sequence[str]) -> list[set[str]]:
    """Pairs of effects that the adapter's own alias groups measure as aliases on the
    training logs (:meth:`~realitygap.diagnosis.adapters.contract.AdapterBase.alias_groups`)."""
    train = [p for p in problem.logs if p.split == "train"]
    out = []
    for g in problem.adapter.alias_groups(train, effects=list(effects)):
        for pair in g.get("aliases", ()):
            out.append({str(e) for e in pair})
    return out


def alias_notes(
    problem: Problem,
    ranking: Sequence[ModelFit],
    judgement: Judgement,
    ident: Sequence[Mapping[str, Any]],
    *,
    t_equal: float = 2.0,
    identify: Any = None,
) -> list[dict[str, Any]]:
    """Models the data cannot tell from the verdict's model.

    Another model (neither a sub- nor a super-model) is an alias when it closes
    the held-out gap as well within noise (paired squared residuals differ by
    less than ``t_equal`` standard errors and it passes the shrink test too),
    when the identifiability check found their parameters correlated beyond
    ``confound_corr``, or when the adapter lists the two in one alias group
    and the other fits nearly as well. Each alias carries the manoeuvre that
    would separate them, where one exists.
    """
    best, st = judgement.best, problem.settings
    if judgement.verdict.kind != "effects" or not best.effects:
        return []
    mask = judgement.gap_mask
    z_nom = judgement.nominal_heldout
    groups = _known_alias_groups(problem, best.effects)
    by_name = {str(i.get("effects", ["", ""])[1]): i for i in ident if i.get("effects")}
    out: list[dict[str, Any]] = []
    for other in ranking:
        if not other.effects or other.effects == best.effects:
            continue
        if set(other.effects) <= set(best.effects) or set(other.effects) >= set(best.effects):
            continue
        if other.z_heldout.shape != best.z_heldout.shape:
            continue
        why: list[str] = []
        d = other.z_heldout[mask] ** 2 - best.z_heldout[mask] ** 2
        sd = float(np.std(d, ddof=1)) if d.size > 1 else 0.0
        if sd > 0:
            t = float(np.mean(d) / (sd / math.sqrt(d.size)))
        else:  # identical residuals are equal; a constant difference is not
            t = 0.0 if float(np.mean(d)) == 0.0 else math.inf
        shrink = overall_shrink(z_nom[mask], other.z_heldout[mask])
        if abs(t) < t_equal and shrink >= 100.0 * st.min_shrink:
            why.append(
                f"closes the held-out gap as well within noise ({shrink:.0f} %, t = {t:.1f})"
            )
        info = by_name.get(other.name)
        if info is not None and not info.get("separable", True):
            why.append(f"parameter correlation {info['correlation']:.2f}")
        known = any(
            (set(best.effects) & g) and (set(other.effects) & g) - set(best.effects) for g in groups
        )
        if known and shrink >= 100.0 * st.min_shrink:
            why.append("a known alias of this robot")
        if not why:
            continue
        if info is None and identify is not None:
            info = identify(problem, best, other)
        entry: dict[str, Any] = {
            "model": other.name,
            "effects": list(other.effects),
            "why": why,
            "heldout_shrink_pct": shrink,
        }
        if info is not None and "separating_motion" in info:
            entry["separating_motion"] = info["separating_motion"]
        out.append(entry)
        if len(out) >= 3:
            break
    return out


def unsingled_partner(
    problem: Problem,
    ranking: Sequence[ModelFit],
    judgement: Judgement,
    aliases: Sequence[Mapping[str, Any]],
    noise: Mapping[str, float] | None = None,
) -> tuple[ModelFit, list[str]] | None:
    """A pair verdict whose partner the data does not single out, and the effect it does.

    When the verdict's model is a pair A + B and at least two of its aliases are A with
    other partners (A + C, A + D, … closing the held-out gap as well), the data identifies
    A but not which further small term helps it (aliases that do not hold A, such as a
    known alias of A with B, do not count). If A alone closes at least
    :attr:`AttributionSettings.dominant_shrink` of the held-out gap above the noise floor
    with no parameter pinned at the far edge of its range (:func:`dominant_single`; of two
    such members, the one closing more), that is the finding: returns A's fit and the
    partners ``[B, C, D, …]``; else ``None``.
    """
    best, verdict = judgement.best, judgement.verdict
    if verdict.kind != "effects" or len(best.effects) != 2:
        return None
    with_member = {
        e: [a for a in aliases if len(a.get("effects", ())) == 2 and e in a["effects"]]
        for e in best.effects
    }
    kept_ones = [e for e in best.effects if len(with_member[e]) >= 2]
    single = dominant_single(problem, ranking, judgement, kept_ones, noise) if kept_ones else None
    if single is None:
        return None
    (kept,) = single.effects
    partners = [e for e in best.effects if e != kept]
    partners += [
        e for a in with_member[kept] for e in a["effects"] if e != kept and e not in partners
    ]
    return single, partners


def nuisance_partner(problem: Problem, fit: ModelFit) -> tuple[str, str] | None:
    """The effect a pair names when its partner only refines a baseline nuisance.

    For a pair A + N where every parameter of N is a calibrated-baseline nuisance
    (:attr:`Problem.baseline_ranges`, e.g. ``timestamp_offset.offset`` or
    ``command_latency.delay``) and the pair's fit puts each inside its nuisance range,
    N adds no finding: a value in that range is a convention of the recording that the
    baseline refines with every model anyway (:mod:`~realitygap.diagnosis.stages.baseline`),
    and the pair's fit is A with its nuisances refined. Returns ``(A, N)``; ``None``
    for any other model.
    """
    ranges = problem.baseline_ranges
    if len(fit.effects) != 2 or not ranges:
        return None

    def inside(k: str) -> bool:
        if k not in ranges:
            return False
        lo, hi = ranges[k]
        tol = 1e-9 * (hi - lo)  # the fit may end on the range's edge to rounding
        return lo - tol <= fit.values[k] <= hi + tol

    for n in fit.effects:
        keys = [k for k in fit.keys if k.partition(".")[0] == n]
        if keys and all(inside(k) for k in keys):
            (kept,) = (e for e in fit.effects if e != n)
            return kept, n
    return None


def dominant_single(
    problem: Problem,
    ranking: Sequence[ModelFit],
    judgement: Judgement,
    effects: Sequence[str],
    noise: Mapping[str, float] | None = None,
) -> ModelFit | None:
    """The single-effect fit of one of ``effects`` that could be named on its own.

    Of the ranking's single-effect fits of ``effects``, the one closing the most of the
    held-out gap above the noise floor, if that is at least
    :attr:`AttributionSettings.dominant_shrink` (the share at which a single effect is
    named even with a small structured rest, :func:`judge`), with no parameter pinned at
    the far edge of its range and no regime it worsens (:func:`regime_consistency`);
    ``None`` when none qualifies.
    """
    z_nom, mask = judgement.nominal_heldout, judgement.gap_mask
    found: tuple[float, ModelFit] | None = None
    for e in effects:
        single = next((f for f in ranking if f.effects == (e,)), None)
        if single is None or single.z_heldout.shape != z_nom.shape:
            continue
        above = shrink_above_noise(z_nom, single.z_heldout, problem.holdout, mask, noise)
        if above < 100.0 * problem.settings.dominant_shrink or (found and above <= found[0]):
            continue
        if pinned_parameters(problem, single):
            continue
        if regime_consistency(problem, single, z_nom, mask)["worsened"]:
            continue
        found = (above, single)
    return None if found is None else found[1]


def _adopt_single(
    problem: Problem, judgement: Judgement, single: ModelFit, noise: Mapping[str, float] | None
) -> str:
    """Make ``single`` the verdict's model: its held-out figures and residual description;
    returns the words that state its share of the gap."""
    z_nom, mask = judgement.nominal_heldout, judgement.gap_mask
    judgement.best = single
    judgement.shrink_pct_best = overall_shrink(z_nom[mask], single.z_heldout[mask])
    judgement.shrink_pct_above_noise = shrink_above_noise(
        z_nom, single.z_heldout, problem.holdout, mask, noise
    )
    judgement.verdict.residual = describe_fit_residual(problem, single, noise)
    judgement.verdict.kind, judgement.verdict.effects = "effects", single.effects
    judgement.verdict.confidence = "moderate"
    return (
        f"{single.name} alone closes {judgement.shrink_pct_above_noise:.0f} % of the held-out "
        f"gap above the noise floor ({judgement.shrink_pct_best:.0f} % of the raw gap)"
    )


def verdict_alternatives(verdict: Any) -> list[tuple[str, ...]]:
    """The effect sets a verdict names: its model, then each alias of it on this data.

    ``[]`` for ``"unexplained"`` and ``"none"``; a verdict "X or Y (aliases on this
    data)" gives ``[("X",), ("Y",)]``. Scoring that counts a verdict right when one
    of these is the truth is *alias-aware*; strict scoring looks at the first only.
    """
    if verdict.kind != "effects":
        return []
    out = [tuple(verdict.effects)]
    for a in (getattr(verdict, "notes", None) or {}).get("aliases", []):
        eff = tuple(a.get("effects") or str(a.get("model", "")).split(" + "))
        if eff and eff not in out:
            out.append(eff)
    return out


def run_discovery(problem: Problem, judgement: Judgement) -> Any:
    """Discovery on the residual the verdict leaves, when it is unexplained or when a
    model named on whole runs leaves a structured window residual.

    The residual is that of the best model on the bias-corrected surrogate
    (training and held-out alike), or of the nominal replay when no model
    improves on it. Otherwise (a named verdict whose rest is noise, or no gap)
    ``None`` is returned; discovery never changes a verdict.
    """
    from realitygap.diagnosis.stages.discovery import discover

    verdict = judgement.verdict
    whole = verdict.notes.get("whole_runs") or {}
    if verdict.kind != "unexplained" and not (verdict.kind == "effects" and whole.get("remainder")):
        return None
    best = judgement.best
    if best.effects:
        point = {k: np.array([v]) for k, v in best.values.items()}
        z_tr = problem.surrogate_residuals(problem.train, point, 1)[0]
        z_ho = problem.surrogate_residuals(problem.holdout, point, 1)[0]
    else:
        z_tr = problem.nominal_residuals(problem.train)
        z_ho = judgement.nominal_heldout
    return discover(problem, z_tr, z_ho, judgement.gap_mask)


def conclude(
    problem: Problem,
    ranking: Sequence[ModelFit],
    judgement: Judgement,
    ident: Sequence[Mapping[str, Any]],
    coverage: Coverage | None = None,
    noise: Mapping[str, float] | None = None,
) -> dict[str, Any]:
    """What the verdict adds after identifiability: aliases, compensators, honest
    parameters and, for an unexplained gap, what the residual looks like and, with
    ``coverage`` (:func:`~realitygap.diagnosis.stages.coverage.training_coverage`), whether it
    gathers in motions the training never exercised (then the verdict's words say so and
    ``notes["coverage"]`` names the training run that would test it).

    A verdict whose model worsens a regime it touches becomes ``"unexplained"``
    (a likely compensator, not a cause). Parameters at a bound or untestable
    lose their error bars (``stderr`` set to NaN). The notes are stored in
    ``judgement.verdict.notes`` and returned.
    """
    from realitygap.diagnosis.fit.identifiability import identifiability

    verdict, best = judgement.verdict, judgement.best
    z_nom, mask = judgement.nominal_heldout, judgement.gap_mask
    consistency = [
        regime_consistency(problem, f, z_nom, mask)
        for f in ranking[:8]
        if f.effects and f.z_heldout.shape == z_nom.shape
    ]
    by_model = {c["model"]: c for c in consistency}
    status: dict[str, dict[str, str]] = {}
    for f in ranking[:8]:
        st_f = parameter_status(problem, f)
        for k in st_f:
            f.stderr[k] = math.nan
        if st_f:
            status[f.name] = st_f
    comp = by_model.get(best.name)
    if verdict.kind == "effects" and comp is not None and comp["compensator"]:
        verdict.kind, verdict.effects, verdict.confidence = "unexplained", (), "n/a"
        verdict.reason = (
            f"the best candidate ({best.name}) improves "
            f"{_improved_words(comp)} but worsens the {', '.join(comp['worsened'])} windows: "
            "a likely compensator for an effect outside the library, not a cause"
        )
    combo = None
    if verdict.kind == "effects" and len(best.effects) > 1 and best.z_heldout.shape == z_nom.shape:
        combo = combination_check(problem, best, z_nom, mask)
        if not combo["passed"]:
            w = combo["failed"][0]
            where = (
                f"the {w['group']} {w['column']} residual while {w['regime']} is "
                f"{w['ratio']:.1f}× its noise level"
            )
            single = dominant_single(problem, ranking, judgement, best.effects, noise)
            if single is not None:
                # one of the two closes nearly all of the gap alone: the pair's structured rest
                # says that effect's law differs in detail, not that a second cause acts
                pair, pair_shrink = best.name, judgement.shrink_pct_best
                share = _adopt_single(problem, judgement, single, noise)
                best = single
                verdict.reason = (
                    f"{share}; {pair} closes {pair_shrink:.0f} % but leaves a structured residual "
                    f"where it acts ({where}), so its second effect stands in for a difference "
                    f"in detail between {single.name}'s law and the library's, not for a second "
                    "cause"
                )
            else:
                verdict.kind, verdict.effects, verdict.confidence = "unexplained", (), "n/a"
                verdict.reason = (
                    f"partially explained: {best.name} closes {judgement.shrink_pct_best:.0f} % of "
                    f"the held-out gap, but where it acts the residual is still structured "
                    f"({where}): the two effects may stand in for one mechanism outside the "
                    "library that couples them"
                )
    aliases = alias_notes(problem, ranking, judgement, ident, identify=identifiability)
    for a in aliases:
        if a["model"] not in verdict.ambiguous_with:
            verdict.ambiguous_with.append(a["model"])
    if aliases:
        verdict.confidence = "not identifiable"
    unsingled = unsingled_partner(problem, ranking, judgement, aliases, noise)
    partners: list[str] = []
    if unsingled is not None:
        single, partners = unsingled
        pair_shrink = judgement.shrink_pct_best
        share = _adopt_single(problem, judgement, single, noise)
        best = single
        verdict.reason = (
            f"{share}; a further small term closes "
            f"{pair_shrink - judgement.shrink_pct_best:.1f} points more, but "
            f"{' or '.join(partners)} does it equally well, so none of them is singled out"
        )
    absorbed = (
        nuisance_partner(problem, best) if verdict.kind == "effects" and not partners else None
    )
    partner_keys: list[str] = []
    if absorbed is not None:
        kept, partner = absorbed
        verdict.effects = (kept,)
        partner_keys = [k for k in best.keys if k.partition(".")[0] == partner]
        inside = ", ".join(
            f"{k} = {best.values[k]:.4g} {param_spec(k).unit} within "
            f"{problem.baseline_ranges[k][0]:.4g} … {problem.baseline_ranges[k][1]:.4g}"
            for k in partner_keys
        )
        verdict.reason += (
            f"; {partner} only refines a calibrated-baseline nuisance inside its range "
            f"({inside}): a convention of the recording, not a finding, so the verdict is "
            f"{kept} (with that nuisance refined)"
        )
    if verdict.kind == "effects" and partners:
        text = (
            f"{best.name} (+ {' or '.join(partners)}: a further small term this data does not "
            "single out)"
        )
    elif verdict.kind == "effects":
        named = verdict.effects[0] if absorbed is not None else best.name
        names = [named, *(a["model"] for a in aliases)]
        trained = bool(verdict.notes.get("training_only"))
        if trained:
            names += [m for m in verdict.ambiguous_with if m not in names]
        text = " or ".join(names)
        text += " (aliases on this data)" if len(names) > 1 else ""
        if trained:
            text += " (on the training alone: the held-out motions do not exercise it)"
        whole = verdict.notes.get("whole_runs")
        if whole:
            text += (
                " (on whole runs; the 1-s window residual it leaves is unexplained)"
                if whole["remainder"]
                else " (on whole runs)"
            )
    elif combo is not None and not combo["passed"]:
        text = (
            f"unexplained (partially explained by {best.name}: "
            f"{judgement.shrink_pct_best:.0f} % of the held-out gap)"
        )
    else:
        text = verdict.kind
    disc = run_discovery(problem, judgement)
    consistency.sort(key=lambda c: (bool(c["worsened"]), -c["shrink_pct"]))
    notes: dict[str, Any] = {
        "verdict_text": text,
        "aliases": aliases,
        "compensators": [c["model"] for c in consistency if c["compensator"]],
        "regime_consistency": consistency,
        "parameter_status": status,
        "discovery": disc.to_json() if disc is not None else None,
        "heldout_shrink_pct_above_noise": judgement.shrink_pct_above_noise,
        "unsingled_partners": partners,
    }
    if absorbed is not None:
        notes["nuisance_partner"] = {
            "effect": absorbed[1],
            "values": {k: best.values[k] for k in partner_keys},
            "units": {k: param_spec(k).unit for k in partner_keys},
            "ranges": {k: list(problem.baseline_ranges[k]) for k in partner_keys},
        }
    if coverage is not None and coverage.beyond_training and verdict.kind != "effects":
        notes["coverage"] = {"summary": coverage.summary(), "suggestion": coverage.suggestion()}
        if text == verdict.kind:
            notes["verdict_text"] = (
                f"{verdict.kind} ({100 * coverage.residual_share_outside:.0f} % of what remains "
                "lies in motions the training never exercised)"
            )
    if combo is not None:
        notes["combination_check"] = combo
        if not combo["passed"] and verdict.kind != "effects":
            notes["partially_explained_by"] = {
                "model": best.name,
                "effects": list(best.effects),
                "heldout_shrink_pct": judgement.shrink_pct_best,
            }
    verdict.notes.update(notes)
    return notes


def _improved_words(c: Mapping[str, Any]) -> str:
    if c["improved"]:
        return f"the {', '.join(c['improved'])} windows"
    return f"the held-out gap as a whole ({c['shrink_pct']:.0f} %)"


def explain(verdict: Verdict, top_models: Sequence[str] = ()) -> list[str]:
    """The verdict in words, then numbers: one line each for the verdict with its
    aliases, every alias and the manoeuvre that would separate it, compensators,
    parameters that are not findings (of ``top_models``, default all) and what
    discovery found in an unexplained residual."""
    notes = verdict.notes
    label = notes.get("verdict_text") or (
        " + ".join(verdict.effects) if verdict.kind == "effects" else verdict.kind
    )
    lines = [f"verdict: {label}", f"reason: {verdict.reason}"]
    for a in notes.get("aliases", []):
        line = f"alias: {a['model']} fits as well ({'; '.join(a['why'])})"
        motion = a.get("separating_motion")
        if motion:
            line += (
                f"; recording '{motion['name']}' ({motion['description']}) would tell them apart"
            )
        else:
            line += "; no probe manoeuvre of this robot separates them"
        lines.append(line)
    for c in notes.get("regime_consistency", []):
        if c["compensator"]:
            lines.append(
                f"compensator: {c['model']} improves {_improved_words(c)} and worsens the "
                f"{', '.join(c['worsened'])} windows: it makes up for something else rather "
                "than causing the gap"
            )
    for model, status in notes.get("parameter_status", {}).items():
        if top_models and model not in top_models:
            continue
        for key, why in status.items():
            what = {
                "at bound": "sits at a bound of its physical range",
                "untestable": "is not exercised by the logged motions",
                "one-sided": "is bounded on one side only by the logged motions",
                "not identifiable": "cannot be identified from the training data and was "
                "held at nominal",
                "nuisance at range bound": "(a calibrated-baseline nuisance) ends at the edge "
                "of its nuisance range: the baseline absorbs part of a gap the model leaves",
            }.get(why, why)
            lines.append(f"not a finding: {key} of {model} {what} (no error bar)")
    whole = notes.get("whole_runs")
    if whole and verdict.kind == "effects":
        rest = (
            f"is unexplained ({'; '.join(whole['remainder'])})"
            if whole["remainder"]
            else "looks like noise at that scale"
        )
        lines.append(
            f"window scale: {whole['window_shrink_pct']:.0f} % of the 1-s window gap closed "
            f"against {whole['run_shrink_pct']:.0f} % of the whole-run gap; the rest of the "
            f"window residual {rest}"
        )
    robot = notes.get("robot")
    if robot is not None:
        lines.append(f"fitted robot: {robot['message']}")
    act = notes.get("actuation")
    if act is not None:
        lines.append(f"drive train: {act['message']}")
    track = notes.get("tracking")
    if track is not None:
        lines.append(f"wheels: {track['message']}")
    disc = notes.get("discovery")
    if disc is not None:
        lines.append(f"discovery: {disc['message']}")
    reach = notes.get("reach")
    if reach is not None:
        lines.append(f"reach: {reach['message']}")
    cov = notes.get("coverage")
    if cov is not None:
        lines.append(f"beyond the training: {cov['summary']}")
        if cov.get("suggestion"):
            lines.append(f"experiment: {cov['suggestion']}")
    return lines


def explain_markdown(verdict: Verdict, top_models: Sequence[str] = ()) -> list[str]:
    """:func:`explain` as Markdown bullet lines for a report, without the verdict and
    reason lines a report states itself, except when aliases change the verdict's words."""
    lines = explain(verdict, top_models)
    extra = lines[2:]
    if verdict.notes.get("aliases"):
        extra = [lines[0], *extra]
    return [""] + [f"- {line}" for line in extra] if extra else []
