"""The verdict's rules: what the held-out draft becomes once the ranking around it is read.

After the held-out tests (:mod:`realitygap.diagnosis.verdict.judge`), :func:`decide` runs
these rules, in order, on the judgement and returns a
:class:`~realitygap.diagnosis.verdict.types.Decision`:

1. **compensator** — a named model that worsens a regime it touches becomes
   ``"unexplained"``: it trades one error for another (:func:`regime_consistency`);
2. **combination check** — a pair must also leave noise, at each channel's own
   resolution, in every regime where it acts (:func:`combination_check`): two effects
   fitted together can stand in for one mechanism outside the library that couples them,
   and such a verdict is "unexplained (partially explained by X + Y: N % of the held-out
   gap)" — unless X or Y alone closes nearly all of the gap (**dominant single**,
   :func:`dominant_single`): then the pair's structured rest says that effect's law
   differs in detail from the library's, and it is named alone;
3. **aliases** — models the data cannot tell from the named one are listed with the
   manoeuvre that would separate them (:func:`alias_notes`; confidence "not identifiable");
4. **unsingled partner** — a pair A + B whose partner other effects replace equally well
   names A alone when A is dominant (:func:`unsingled_partner`);
5. **nuisance partner** — a partner that only refines a calibrated-baseline nuisance inside
   its range is not named (:func:`nuisance_partner`);
6. the verdict's words (with the **training-only** and **whole-runs** drafts' own), and for
   an unexplained gap whether it gathers beyond the training (**coverage**).

Parameters at a bound or untestable lose their error bars on the way
(:func:`~realitygap.diagnosis.fit.status.parameter_status`). The rules return values and
never run a stage; :func:`run_discovery` is what the pipeline runs on the decision, and
:func:`~realitygap.diagnosis.verdict.conclude.conclude` writes the verdict.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.fit.identifiability import identifiability
from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.fit.status import parameter_status, pinned_parameters
from realitygap.diagnosis.problem.parameters import param_spec, split_key
from realitygap.diagnosis.problem.problem import Problem
from realitygap.diagnosis.problem.residual import (
    column_levels,
    shrink_above_noise,
    white_level,
)
from realitygap.diagnosis.problem.shrink import overall_shrink
from realitygap.diagnosis.stages.coverage import Coverage
from realitygap.diagnosis.stages.discovery import Discovery, discover
from realitygap.diagnosis.verdict.advice import Advice
from realitygap.diagnosis.verdict.judge import describe_fit_residual
from realitygap.diagnosis.verdict.types import (
    Confidence,
    CoverageNote,
    Decision,
    Judgement,
    NuisancePartner,
    PartialExplanation,
    Verdict,
    VerdictKind,
    VerdictNotes,
)

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "adopt_single",
    "alias_notes",
    "combination_check",
    "decide",
    "dominant_single",
    "improved_words",
    "nuisance_partner",
    "regime_consistency",
    "run_discovery",
    "unsingled_partner",
    "verdict_alternatives",
]


# --------------------------------------------------------------------------- regimes, pairs
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


# --------------------------------------------------------------------------- aliases and partners
def _known_alias_groups(problem: Problem, effects: Sequence[str]) -> list[set[str]]:
    """Pairs of effects that the adapter's own alias groups measure as aliases on the
    training logs (:meth:`~realitygap.diagnosis.adapters.contract.RobotAdapter.alias_groups`)."""
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
    identify: Callable[[Problem, ModelFit, ModelFit], Mapping[str, Any]] | None = None,
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
    if judgement.kind is not VerdictKind.EFFECTS or not best.effects:
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
    best = judgement.best
    if judgement.kind is not VerdictKind.EFFECTS or len(best.effects) != 2:
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
        keys = [k for k in fit.keys if split_key(k)[0] == n]
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
    named even with a small structured rest,
    :func:`~realitygap.diagnosis.verdict.judge.judge`), with no parameter pinned at the far
    edge of its range and no regime it worsens (:func:`regime_consistency`); ``None`` when
    none qualifies.
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


def adopt_single(
    problem: Problem, judgement: Judgement, single: ModelFit, noise: Mapping[str, float] | None
) -> tuple[Judgement, str]:
    """``judgement`` with ``single`` as the model its draft names ("moderate" confidence):
    its held-out figures and residual description; and the words that state its share of
    the gap."""
    z_nom, mask = judgement.nominal_heldout, judgement.gap_mask
    adopted = replace(
        judgement,
        best=single,
        shrink_pct_best=overall_shrink(z_nom[mask], single.z_heldout[mask]),
        shrink_pct_above_noise=shrink_above_noise(
            z_nom, single.z_heldout, problem.holdout, mask, noise
        ),
    ).revised(
        kind=VerdictKind.EFFECTS,
        effects=single.effects,
        confidence=Confidence.MODERATE,
        residual=describe_fit_residual(problem, single, noise),
    )
    return adopted, (
        f"{single.name} alone closes {adopted.shrink_pct_above_noise:.0f} % of the held-out "
        f"gap above the noise floor ({adopted.shrink_pct_best:.0f} % of the raw gap)"
    )


def improved_words(c: Mapping[str, Any]) -> str:
    """What a model of :func:`regime_consistency` row ``c`` improves, in words."""
    if c["improved"]:
        return f"the {', '.join(c['improved'])} windows"
    return f"the held-out gap as a whole ({c['shrink_pct']:.0f} %)"


# --------------------------------------------------------------------------- the rules in order
def _compensator(judgement: Judgement, by_model: Mapping[str, Mapping[str, Any]]) -> Judgement:
    """Rule 1: a named model that worsens a regime it touches is a likely compensator."""
    best = judgement.best
    comp = by_model.get(best.name)
    if judgement.kind is not VerdictKind.EFFECTS or comp is None or not comp["compensator"]:
        return judgement
    return judgement.revised(
        kind=VerdictKind.UNEXPLAINED,
        effects=(),
        confidence=Confidence.NOT_APPLICABLE,
        reason=(
            f"the best candidate ({best.name}) improves "
            f"{improved_words(comp)} but worsens the {', '.join(comp['worsened'])} windows: "
            "a likely compensator for an effect outside the library, not a cause"
        ),
    )


def _combination(
    problem: Problem,
    ranking: Sequence[ModelFit],
    judgement: Judgement,
    noise: Mapping[str, float] | None,
) -> tuple[Judgement, dict[str, Any] | None]:
    """Rule 2: a named pair must leave noise wherever it acts, else it is named by its
    dominant member alone or left unexplained; returns the judgement and the check."""
    best, z_nom, mask = judgement.best, judgement.nominal_heldout, judgement.gap_mask
    if (
        judgement.kind is not VerdictKind.EFFECTS
        or len(best.effects) <= 1
        or best.z_heldout.shape != z_nom.shape
    ):
        return judgement, None
    combo = combination_check(problem, best, z_nom, mask)
    if combo["passed"]:
        return judgement, combo
    w = combo["failed"][0]
    where = (
        f"the {w['group']} {w['column']} residual while {w['regime']} is "
        f"{w['ratio']:.1f}× its noise level"
    )
    single = dominant_single(problem, ranking, judgement, best.effects, noise)
    if single is None:
        return judgement.revised(
            kind=VerdictKind.UNEXPLAINED,
            effects=(),
            confidence=Confidence.NOT_APPLICABLE,
            reason=(
                f"partially explained: {best.name} closes {judgement.shrink_pct_best:.0f} % of "
                f"the held-out gap, but where it acts the residual is still structured "
                f"({where}): the two effects may stand in for one mechanism outside the "
                "library that couples them"
            ),
        ), combo
    # one of the two closes nearly all of the gap alone: the pair's structured rest says
    # that effect's law differs in detail, not that a second cause acts
    pair, pair_shrink = best.name, judgement.shrink_pct_best
    adopted, share = adopt_single(problem, judgement, single, noise)
    return adopted.revised(
        reason=(
            f"{share}; {pair} closes {pair_shrink:.0f} % but leaves a structured residual "
            f"where it acts ({where}), so its second effect stands in for a difference "
            f"in detail between {single.name}'s law and the library's, not for a second "
            "cause"
        )
    ), combo


def _aliases(
    problem: Problem,
    ranking: Sequence[ModelFit],
    judgement: Judgement,
    ident: Sequence[Mapping[str, Any]],
) -> tuple[Judgement, list[dict[str, Any]]]:
    """Rule 3: the models the data cannot tell from the named one join its contenders."""
    aliases = alias_notes(problem, ranking, judgement, ident, identify=identifiability)
    ambiguous = list(judgement.draft.ambiguous_with)
    for a in aliases:
        if a["model"] not in ambiguous:
            ambiguous.append(a["model"])
    confidence = Confidence.NOT_IDENTIFIABLE if aliases else judgement.draft.confidence
    return judgement.revised(ambiguous_with=tuple(ambiguous), confidence=confidence), aliases


def _unsingled(
    problem: Problem,
    ranking: Sequence[ModelFit],
    judgement: Judgement,
    aliases: Sequence[Mapping[str, Any]],
    noise: Mapping[str, float] | None,
) -> tuple[Judgement, list[str]]:
    """Rule 4: a pair whose partner other effects replace as well is named by its dominant
    member; returns the judgement and the partners not singled out."""
    unsingled = unsingled_partner(problem, ranking, judgement, aliases, noise)
    if unsingled is None:
        return judgement, []
    single, partners = unsingled
    pair_shrink = judgement.shrink_pct_best
    adopted, share = adopt_single(problem, judgement, single, noise)
    return adopted.revised(
        reason=(
            f"{share}; a further small term closes "
            f"{pair_shrink - adopted.shrink_pct_best:.1f} points more, but "
            f"{' or '.join(partners)} does it equally well, so none of them is singled out"
        )
    ), partners


def _nuisance(problem: Problem, judgement: Judgement) -> tuple[Judgement, str | None, list[str]]:
    """Rule 5: a named pair whose partner only refines a baseline nuisance names the other
    effect; returns the judgement, the partner and its parameters."""
    best = judgement.best
    absorbed = nuisance_partner(problem, best)
    if absorbed is None:
        return judgement, None, []
    kept, partner = absorbed
    keys = [k for k in best.keys if split_key(k)[0] == partner]
    inside = ", ".join(
        f"{k} = {best.values[k]:.4g} {param_spec(k).unit} within "
        f"{problem.baseline_ranges[k][0]:.4g} … {problem.baseline_ranges[k][1]:.4g}"
        for k in keys
    )
    reason = (
        f"{judgement.draft.reason}; {partner} only refines a calibrated-baseline nuisance "
        f"inside its range ({inside}): a convention of the recording, not a finding, so the "
        f"verdict is {kept} (with that nuisance refined)"
    )
    return judgement.revised(effects=(kept,), reason=reason), partner, keys


def _verdict_text(
    judgement: Judgement,
    aliases: Sequence[Mapping[str, Any]],
    partners: Sequence[str],
    nuisance: str | None,
    combo: Mapping[str, Any] | None,
) -> str:
    """The verdict in words: the named model with its aliases or partners and its scale."""
    draft, best = judgement.draft, judgement.best
    if draft.kind is VerdictKind.EFFECTS and partners:
        return (
            f"{best.name} (+ {' or '.join(partners)}: a further small term this data "
            "does not single out)"
        )
    if draft.kind is VerdictKind.EFFECTS:
        named = draft.effects[0] if nuisance is not None else best.name
        names = [named, *(a["model"] for a in aliases)]
        trained = draft.training_only is not None
        if trained:
            names += [m for m in draft.ambiguous_with if m not in names]
        text = " or ".join(names)
        text += " (aliases on this data)" if len(names) > 1 else ""
        if trained:
            text += " (on the training alone: the held-out motions do not exercise it)"
        whole = draft.whole_runs
        if whole is not None:
            text += (
                " (on whole runs; the 1-s window residual it leaves is unexplained)"
                if whole.remainder
                else " (on whole runs)"
            )
        return text
    if combo is not None and not combo["passed"]:
        return (
            f"unexplained (partially explained by {best.name}: "
            f"{judgement.shrink_pct_best:.0f} % of the held-out gap)"
        )
    return draft.kind.value


def decide(
    problem: Problem,
    ranking: Sequence[ModelFit],
    judgement: Judgement,
    advice: Advice,
    coverage: Coverage | None = None,
    noise: Mapping[str, float] | None = None,
) -> Decision:
    """Run the rules on ``judgement`` (with the identifiability ``advice`` applied) and
    return the decision: the final judgement and the verdict's notes.

    Aliases, compensators, honest parameters and, for an unexplained gap, with ``coverage``
    (:func:`~realitygap.diagnosis.stages.coverage.training_coverage`), whether what remains
    gathers in motions the training never exercised (then the verdict's words say so and
    the notes name the training run that would test it). A named model that worsens a
    regime it touches becomes ``"unexplained"`` (a likely compensator, not a cause).
    Parameters at a bound or untestable lose their error bars (``stderr`` of the ranking's
    fits set to NaN).
    """
    judgement = advice.applied(judgement)
    z_nom, mask = judgement.nominal_heldout, judgement.gap_mask
    consistency = [
        regime_consistency(problem, f, z_nom, mask)
        for f in ranking[:8]
        if f.effects and f.z_heldout.shape == z_nom.shape
    ]
    status: dict[str, dict[str, str]] = {}
    for f in ranking[:8]:
        st_f = parameter_status(problem, f)
        for k in st_f:
            f.stderr[k] = math.nan
        if st_f:
            status[f.name] = st_f
    judgement = _compensator(judgement, {c["model"]: c for c in consistency})
    judgement, combo = _combination(problem, ranking, judgement, noise)
    judgement, aliases = _aliases(problem, ranking, judgement, advice.identifiability)
    judgement, partners = _unsingled(problem, ranking, judgement, aliases, noise)
    nuisance: str | None = None
    nuisance_keys: list[str] = []
    if judgement.kind is VerdictKind.EFFECTS and not partners:
        judgement, nuisance, nuisance_keys = _nuisance(problem, judgement)
    text = _verdict_text(judgement, aliases, partners, nuisance, combo)
    draft, best = judgement.draft, judgement.best
    consistency.sort(key=lambda c: (bool(c["worsened"]), -c["shrink_pct"]))
    notes = VerdictNotes(
        verdict_text=text,
        aliases=tuple(aliases),
        compensators=tuple(c["model"] for c in consistency if c["compensator"]),
        regime_consistency=tuple(consistency),
        parameter_status=status,
        heldout_shrink_pct_above_noise=judgement.shrink_pct_above_noise,
        unsingled_partners=tuple(partners),
        training_only=draft.training_only,
        whole_runs=draft.whole_runs,
        combination_check=combo,
    )
    if nuisance is not None:
        notes = replace(
            notes,
            nuisance_partner=NuisancePartner(
                effect=nuisance,
                values={k: best.values[k] for k in nuisance_keys},
                units={k: param_spec(k).unit for k in nuisance_keys},
                ranges={k: problem.baseline_ranges[k] for k in nuisance_keys},
            ),
        )
    named = draft.kind is VerdictKind.EFFECTS
    if coverage is not None and coverage.beyond_training and not named:
        notes = replace(notes, coverage=CoverageNote(coverage.summary(), coverage.suggestion()))
        if text == draft.kind.value:
            notes = replace(
                notes,
                verdict_text=(
                    f"{draft.kind.value} ({100 * coverage.residual_share_outside:.0f} % of what "
                    "remains lies in motions the training never exercised)"
                ),
            )
    if combo is not None and not combo["passed"] and not named:
        notes = replace(
            notes,
            partially_explained_by=PartialExplanation(
                best.name, best.effects, judgement.shrink_pct_best
            ),
        )
    return Decision(judgement, notes)


# --------------------------------------------------------------------------- after the decision
def run_discovery(problem: Problem, judgement: Judgement) -> Discovery | None:
    """Discovery on the residual a decision leaves, when it is unexplained or when a model
    named on whole runs leaves a structured window residual.

    The residual is that of the best model on the bias-corrected surrogate
    (training and held-out alike), or of the nominal replay when no model
    improves on it. Otherwise (a named verdict whose rest is noise, or no gap)
    ``None`` is returned; discovery never changes a verdict.
    """
    kind, whole = judgement.kind, judgement.draft.whole_runs
    remainder = whole is not None and bool(whole.remainder)
    if kind is not VerdictKind.UNEXPLAINED and not (kind is VerdictKind.EFFECTS and remainder):
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


def verdict_alternatives(verdict: Verdict) -> list[tuple[str, ...]]:
    """The effect sets a verdict names: its model, then each alias of it on this data.

    ``[]`` for ``"unexplained"`` and ``"none"``; a verdict "X or Y (aliases on this
    data)" gives ``[("X",), ("Y",)]``. Scoring that counts a verdict right when one
    of these is the truth is *alias-aware*; strict scoring looks at the first only.
    """
    if verdict.kind is not VerdictKind.EFFECTS:
        return []
    out = [tuple(verdict.effects)]
    for a in verdict.notes.aliases:
        eff = tuple(a.get("effects") or str(a.get("model", "")).split(" + "))
        if eff and eff not in out:
            out.append(eff)
    return out
