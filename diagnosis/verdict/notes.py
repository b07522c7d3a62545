"""What the verdict notes beside the budget: regimes, aliases, discovery.

These functions describe; none decides. The budget's one rule
(:mod:`~realitygap.diagnosis.budget`) has chosen the effects and the kind:

* :func:`regime_consistency` — what a model does in each motion regime of the held-out
  windows (improved, worsened, unchanged);
* :func:`alias_notes` — the budget's aliases of its first entry, each with the manoeuvre
  that would separate them where the logged motions cannot
  (:func:`~realitygap.diagnosis.fit.identifiability.identifiability`);
* :func:`run_discovery` — discovery on what the budget leaves when a structured part
  remains;
* :func:`verdict_alternatives` — the effect sets a verdict names, for alias-aware scoring.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.budget import Budget
from realitygap.diagnosis.fit.identifiability import identifiability
from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.problem.problem import Problem
from realitygap.diagnosis.problem.shrink import overall_shrink
from realitygap.diagnosis.stages.discovery import Discovery, discover
from realitygap.diagnosis.verdict.types import Judgement, Verdict, VerdictKind

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "alias_notes",
    "improved_words",
    "regime_consistency",
    "run_discovery",
    "verdict_alternatives",
]


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


def improved_words(c: Mapping[str, Any]) -> str:
    """What a model of :func:`regime_consistency` row ``c`` improves, in words."""
    if c["improved"]:
        return f"the {', '.join(c['improved'])} windows"
    return f"the held-out gap as a whole ({c['shrink_pct']:.0f} %)"


def alias_notes(
    problem: Problem, budget: Budget, ranking: Sequence[ModelFit]
) -> list[dict[str, Any]]:
    """The first named entry's aliases (effects whose cross-validated gain at its step is
    not significantly smaller), each with why and, where the logged motions cannot tell
    the two apart, the manoeuvre that would (from the single fits of the ranking)."""
    first = next((e for e in budget.entries if e.named), None)
    if first is None:
        return []
    singles = {f.effects[0]: f for f in ranking if len(f.effects) == 1}
    out: list[dict[str, Any]] = []
    for name in first.aliases:
        entry: dict[str, Any] = {
            "model": name,
            "effects": [name],
            "why": [
                f"its cross-validated gain is not significantly smaller than {first.effect}'s "
                f"over {first.folds} folds"
            ],
        }
        a, b = singles.get(first.effect), singles.get(name)
        if a is not None and b is not None:
            info = identifiability(problem, a, b)
            entry["correlation"] = info.get("correlation")
            entry["identifiability"] = info
            if "separating_motion" in info:
                entry["separating_motion"] = info["separating_motion"]
        out.append(entry)
    return out


def run_discovery(problem: Problem, judgement: Judgement, structured: bool) -> Discovery | None:
    """Discovery on the residual the budget's model leaves, when a structured part remains
    (``structured``) or nothing is named; ``None`` otherwise. Discovery never changes the
    verdict."""
    if judgement.kind is VerdictKind.NONE or (
        judgement.kind is VerdictKind.EFFECTS and not structured
    ):
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
    if verdict.kind not in (VerdictKind.EFFECTS, VerdictKind.PARTIAL):
        return []
    out = [tuple(verdict.effects)]
    for a in verdict.notes.aliases:
        eff = tuple(a.get("effects") or str(a.get("model", "")).split(" + "))
        if eff and eff not in out:
            out.append(eff)
    return out
