"""How far the effect library can reach on the held-out data itself.

An "unexplained" verdict has two different causes that call for different next
steps:

* the library *can* express the gap, but the training does not pin the effect
  down (its motions never reach where the effect acts): record other training
  runs;
* no effect of the library, at any value, expresses the gap: the cause lies
  outside the library, or it changes from run to run (then no fixed effect of a
  replay reproduces it).

A third answer says the training is not the limit: the verdict's model, fitted on the
training, already closes about as much as the best single effect does fitted on the
held-out windows (a residual that is structured, not large, and that no single effect
removes).

:func:`library_reach` tells them apart. It fits every single candidate effect on
the held-out windows themselves (in-sample, on the bias-corrected surrogate, the
calibrated baseline's nuisances held at their values so that only the effect
moves) and states how much of the held-out gap each then closes. That figure is
an upper bound of what the effect could do with perfect training, not a
held-out score: it never enters the ranking or the verdict.

Example
-------
The OptiOdom robot's command replay (``realitygap run diagnose-real``): trained on
UMBmark squares that never drive a wheel faster than 0.13 m/s, held out on runs where
the left wheel tops out at 0.19 m/s when asked for 0.25 m/s, and whose drive train
turns by a gain that differs from session to session::

    reach: fitted on the held-out windows themselves, torque_speed_saturation (v_top
    0.191 m/s, t_m 0 s) closes 15 % of their gap and no single effect more (needs 50 %):
    no fixed value of any library effect reproduces the held-out runs, so the cause lies
    outside the library or changes between runs; next: velocity_saturation 15 %, ...
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from realitygap.core.parallel import Backend
from realitygap.diagnosis.attribute import ModelFit, Problem, fit_model
from realitygap.diagnosis.parameters import param_spec
from realitygap.diagnosis.shrink import overall_shrink
from realitygap.diagnosis.verdict import pinned_parameters

__all__ = ["TRAINED_SHARE", "Reach", "heldout_problem", "library_reach"]

TRAINED_SHARE = 0.8
"""The training's fit already reaches the library's ceiling when it closes at least this share
of what the best single effect closes fitted in-sample on the held-out windows."""


@dataclass
class Reach:
    """What each single effect closes when fitted on the held-out windows themselves.

    Attributes
    ----------
    rows : list of dict
        ``{"model", "shrink_pct", "params", "pinned"}`` per candidate, best first;
        ``shrink_pct`` is the in-sample share of the held-out gap (gap channels) the effect
        closes, %; ``pinned`` the parameters that sit at the far edge of their physical
        range there (:func:`~realitygap.diagnosis.verdict.pinned_parameters`).
    trained_shrink_pct : float
        The held-out shrink of the verdict's best model fitted on the training, %.
    expressible : bool
        Whether some single effect, inside its physical range (no parameter pinned at its
        far edge), reaches the verdict's shrink threshold in-sample.
    training_reaches : bool
        Whether the verdict's model fitted on the training already closes
        :data:`TRAINED_SHARE` of that in-sample best (the training pins down what the
        library can do on these runs).
    threshold_pct : float
        That threshold (:attr:`AttributionSettings.min_shrink`), %.
    message : str
    """

    rows: list[dict[str, Any]] = field(default_factory=list)
    trained_shrink_pct: float = 0.0
    expressible: bool = False
    training_reaches: bool = False
    threshold_pct: float = 50.0
    message: str = ""

    def to_json(self) -> dict[str, Any]:
        """Every attribute, as JSON-ready values (a deep copy)."""
        return asdict(self)


def heldout_problem(problem: Problem) -> Problem:
    """A copy of ``problem`` whose fits run on its held-out windows (in-sample), with the
    calibrated baseline's nuisances held at their values (only a model's own
    parameters move). ``problem`` itself is left as it was."""
    if problem.holdout.n == 0:
        raise ValueError("heldout_problem: the problem has no held-out windows")
    flipped = copy.copy(problem)
    flipped.__dict__.pop("_held_cache", None)  # identifiability is asked of the new windows
    flipped.train = problem.holdout
    flipped.baseline_ranges = {}
    return flipped


def _reach_task(problem: Problem, effects: tuple[str, ...]) -> ModelFit:
    return fit_model(problem, effects)


def _short(fit: ModelFit, n: int = 2) -> str:
    """The fitted values of a model of up to ``n`` parameters, else their count."""
    if len(fit.keys) > n:
        return f"{len(fit.keys)} parameters"
    parts = []
    for k in fit.keys[:n]:
        spec = param_spec(k)
        unit = "" if spec.unit in ("", "1") else f" {spec.unit}"
        parts.append(f"{k.split('.', 1)[1]} {fit.values[k]:.3g}{unit}")
    return ", ".join(parts)


def library_reach(
    problem: Problem,
    candidates: Sequence[str],
    nominal_heldout: np.ndarray,
    gap_mask: np.ndarray,
    trained_shrink_pct: float,
    backend: Backend,
    say: Callable[[str], None] = lambda msg: None,
) -> Reach | None:
    """Fit each single candidate on the held-out windows and score it there (in-sample).

    Parameters
    ----------
    problem : Problem
        The diagnosis problem (calibrated baseline set).
    candidates : sequence of str
        The effects the logs can show.
    nominal_heldout : ndarray, shape (n,)
        Held-out residual of the reference replay (what the verdict's shrink is of).
    gap_mask : ndarray of bool, shape (n,)
        Entries of the channels where the gap lives.
    trained_shrink_pct : float
        The verdict's best model's held-out shrink when fitted on the training, %.
    backend : Backend
    say : callable

    Returns
    -------
    Reach or None
        ``None`` without candidates, held-out windows or a gap.
    """
    z_nom = np.asarray(nominal_heldout, dtype=float)
    mask = np.asarray(gap_mask, dtype=bool)
    if not candidates or problem.holdout.n == 0 or not mask.any():
        return None
    if z_nom.shape != (problem.holdout.n,) or mask.shape != z_nom.shape:
        raise ValueError(
            f"library_reach: nominal_heldout and gap_mask must have shape ({problem.holdout.n},) "
            f"(the held-out layout), got {z_nom.shape} and {mask.shape}"
        )
    flipped = heldout_problem(problem)
    say(f"library reach: fitting {len(candidates)} single effects on the held-out windows")
    fits: list[ModelFit] = backend.map(_reach_task, [(e,) for e in candidates], flipped)
    rows = []
    for f in fits:
        rows.append(
            {
                "model": f.name,
                "shrink_pct": overall_shrink(z_nom[mask], f.z_heldout[mask]),
                "params": {k: float(v) for k, v in f.values.items() if k in f.keys},
                # at the far edge of its physical range: stretched, not expressed
                "pinned": pinned_parameters(flipped, f),
                "_fit": f,
            }
        )
    rows.sort(key=lambda r: -r["shrink_pct"])
    fit_of = {r["model"]: r.pop("_fit") for r in rows}
    threshold = 100.0 * problem.settings.min_shrink
    top = rows[0]
    free = next((r for r in rows if not r["pinned"]), None)
    expressible = free is not None and free["shrink_pct"] >= threshold
    reaches = top["shrink_pct"] > 0.0 and trained_shrink_pct >= TRAINED_SHARE * top["shrink_pct"]
    shown = free if expressible and free is not None else top

    def head(r: dict[str, Any]) -> str:
        edge = (
            f", only at the edge of its physical range ({', '.join(r['pinned'])})"
            if r["pinned"]
            else ""
        )
        return (
            f"fitted on the held-out windows themselves, {r['model']} ({_short(fit_of[r['model']])}"
            f"{edge}) closes {r['shrink_pct']:.0f} % of their gap"
        )

    if top["shrink_pct"] <= 0.0:
        message = (
            "fitted on the held-out windows themselves, no single effect of the library closes "
            "any of their gap: the cause lies outside the library or changes between runs"
        )
    elif reaches:
        message = (
            f"{head(top)}, hardly more than the {trained_shrink_pct:.0f} % of the verdict's model "
            "fitted on the training: the training pins down what the library's single effects "
            "can do on these runs, and the verdict's objection to what remains stands"
        )
    elif expressible:
        message = (
            f"{head(shown)}, against {trained_shrink_pct:.0f} % fitted on the training: the "
            "library can express this gap, the training does not pin it down (training runs "
            "that exercise the held-out motions would test it)"
        )
    else:
        message = (
            f"{head(top)} and no single effect more within its physical range (needs "
            f"{threshold:.0f} %): no fixed value of any library effect reproduces the held-out "
            "runs, so the cause lies outside the library or changes between runs"
        )
    others = [r for r in rows if r is not shown and r["shrink_pct"] > 0][:2]
    if others:
        message += "; next: " + ", ".join(f"{r['model']} {r['shrink_pct']:.0f} %" for r in others)
    return Reach(rows, trained_shrink_pct, expressible, reaches, threshold, message)
