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
the held-out windows themselves — two-fold: on every other block of windows of each
held-out run, scored on the blocks between (:meth:`Layout.alternate`), so that an
effect with many parameters gains nothing from fitting the windows it is scored on —
on the bias-corrected surrogate, with the calibrated baseline's nuisances held at
their values so that only the effect moves, and states how much of the held-out gap
each then closes. That figure is what the effect could do with training that
exercised the held-out motions, not a held-out score of the diagnosis: it never
enters the ranking or the verdict.

Example
-------
The OptiOdom robot's command replay (``realitygap run diagnose-real``): trained on
UMBmark squares that never drive a wheel faster than 0.13 m/s, held out on runs where
the left wheel tops out at 0.19 m/s when asked for 0.25 m/s, and whose drive train
turns by a gain that differs from session to session::

    reach: fitted on the held-out runs themselves (every other block of windows, scored
    on the others), timestamp_offset (offset -77 ms) closes 7 % of their gap and no
    single effect more within its physical range (needs 50 %): no fixed value of any
    library effect reproduces the held-out runs, so the cause lies outside the library
    or changes between runs; next: wheelbase_error 6 %, command_latency 4 %
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.parallel import Backend
from realitygap.diagnosis.fit.model import ModelFit, fit_model
from realitygap.diagnosis.fit.status import pinned_parameters
from realitygap.diagnosis.problem.parameters import param_spec
from realitygap.diagnosis.problem.problem import Layout, Problem
from realitygap.diagnosis.problem.shrink import overall_shrink
from realitygap.diagnosis.problem.units import quantity

__all__ = ["TRAINED_SHARE", "Reach", "heldout_problem", "library_reach"]

WHERE = (
    "fitted on the held-out runs themselves (every other block of windows, scored on the others)"
)
"""How every reach message starts: what was fitted where."""

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
        ``shrink_pct`` is the share of the held-out gap (gap channels) the effect closes,
        two-fold on the held-out windows, %; ``params`` the mean of the two folds' values;
        ``pinned`` the parameters that sit at the far edge of their physical range in
        either fold (:func:`~realitygap.diagnosis.fit.status.pinned_parameters`).
    trained_shrink_pct : float
        The held-out shrink of the verdict's best model fitted on the training, %.
    expressible : bool
        Whether some single effect, inside its physical range (no parameter pinned at its
        far edge), reaches the verdict's shrink threshold there.
    training_reaches : bool
        Whether the verdict's model fitted on the training already closes
        :data:`TRAINED_SHARE` of that best (the training is not what falls short).
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


def heldout_problem(problem: Problem, fit_on: Layout, score_on: Layout) -> Problem:
    """A copy of ``problem`` whose fits run on the windows ``fit_on`` and are scored on
    ``score_on`` (parts of its held-out layout), with the calibrated baseline's nuisances
    held at their values (only a model's own parameters move). ``problem`` itself is left
    as it was."""
    if fit_on.n == 0 or score_on.n == 0:
        raise ValueError(
            f"heldout_problem: fit_on and score_on need windows, got {fit_on.n} and "
            f"{score_on.n} entries"
        )
    flipped = copy.copy(problem)
    flipped.__dict__.pop("_held_cache", None)  # identifiability is asked of the new windows
    flipped.train = fit_on
    flipped.holdout = score_on
    flipped.baseline_ranges = {}
    return flipped


def _reach_task(folds: tuple[Problem, Problem], item: tuple[str, int]) -> ModelFit:
    effect, k = item
    return fit_model(folds[k], (effect,))


def _short(params: dict[str, float], n: int = 2) -> str:
    """The fitted values of a model of up to ``n`` parameters (engineering units,
    :func:`~realitygap.diagnosis.problem.units.quantity`), else their count."""
    if len(params) > n:
        return f"{len(params)} parameters"
    return ", ".join(
        f"{k.split('.', 1)[1]} {quantity(v, param_spec(k).unit)}" for k, v in params.items()
    )


def _halves(holdout: Layout, block: int) -> list[tuple[Layout, npt.NDArray[np.int64]]] | None:
    """The two interleaved halves of the held-out layout; finer blocks when a run is too
    short for two blocks; ``None`` when it has a single window."""
    for b in (block, 1):
        halves = [holdout.alternate(b, k) for k in (0, 1)]
        if all(h.n for h, _ in halves):
            return halves
    return None


def library_reach(
    problem: Problem,
    candidates: Sequence[str],
    nominal_heldout: np.ndarray,
    gap_mask: np.ndarray,
    trained_shrink_pct: float,
    backend: Backend,
    say: Callable[[str], None] = lambda msg: None,
    block: int = 10,
) -> Reach | None:
    """Fit each single candidate on the held-out windows, two-fold, and score it there.

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
    block : int
        Windows per block of the two-fold split (:meth:`Layout.alternate`).

    Returns
    -------
    Reach or None
        ``None`` without candidates, a gap or two held-out windows to split.
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
    halves = _halves(problem.holdout, block)
    if halves is None:
        return None
    (h0, i0), (h1, i1) = halves
    folds = (heldout_problem(problem, h0, h1), heldout_problem(problem, h1, h0))
    scored_on = (i1, i0)  # fold k is scored on the other half
    say(
        f"library reach: fitting {len(candidates)} single effects on the held-out windows (two-fold)"
    )
    items = [(e, k) for e in candidates for k in (0, 1)]
    fits: list[ModelFit] = backend.map(_reach_task, items, folds)
    rows = []
    for j in range(len(candidates)):
        pair = fits[2 * j : 2 * j + 2]
        z_cv = np.empty(problem.holdout.n)
        for k, f in enumerate(pair):
            z_cv[scored_on[k]] = f.z_heldout
        keys = list(dict.fromkeys(k for f in pair for k in f.keys))
        rows.append(
            {
                "model": pair[0].name,
                "shrink_pct": overall_shrink(z_nom[mask], z_cv[mask]),
                "params": {k: float(np.mean([f.values[k] for f in pair])) for k in keys},
                # at the far edge of its physical range: stretched, not expressed
                "pinned": sorted(
                    {k for fold, f in zip(folds, pair) for k in pinned_parameters(fold, f)}
                ),
            }
        )
    rows.sort(key=lambda r: -r["shrink_pct"])
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
            f"{WHERE}, {r['model']} ({_short(r['params'])}{edge}) closes "
            f"{r['shrink_pct']:.0f} % of their gap"
        )

    if top["shrink_pct"] <= 0.0:
        message = (
            f"{WHERE}, no single effect of the library closes any of their gap: the cause lies "
            "outside the library or changes between runs"
        )
    elif reaches:
        message = (
            f"{head(top)}, against {trained_shrink_pct:.0f} % for the verdict's model fitted on "
            "the training: the training already gets most of what the library's single effects "
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
