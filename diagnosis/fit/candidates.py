"""Fitting the candidates: screen every single effect and pair on the surrogate, then fit
fully only those that can still reach the top of the ranking.

A screening fit (:func:`~realitygap.diagnosis.fit.model.fit_model` with ``screen=True``)
holds the calibrated baseline's nuisances; it ranks the candidates at a fraction of the
full fit's cost. :func:`settle_ranking` then fits fully (grid, starts and the nuisances
freed, the screening optimum one more start), best first, until the next candidate cannot reach the top ``verify_top + 1``
(its screening score, less twice the largest gain a refinement has shown, is worse
than the score it would have to beat): branch and bound on the ranking, so the answer
(the top, verified in PyBullet, and the runner-up it is measured against) is the one
full fits would give, at the cost of a few.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from realitygap.core.parallel import Backend
from realitygap.diagnosis.fit.model import ModelFit, fit_model
from realitygap.diagnosis.problem.parameters import split_key
from realitygap.diagnosis.problem.problem import Problem
from realitygap.robots.effects import EFFECTS

__all__ = ["GAIN_MARGIN", "fit_candidates", "settle_ranking"]

GAIN_MARGIN = 2.0
"""A screened model is settled once its score, less this many times the largest gain a
full fit has shown, cannot reach the top: the one bound of :func:`settle_ranking`."""


def _full_task(problem: Problem, item: tuple[tuple[str, ...], list[dict[str, float]]]) -> ModelFit:
    """The full fit of ``item = (effects, starts)``: grid, starts and the baseline nuisances
    refined with the model."""
    effects, starts = item
    return fit_model(problem, effects, starts=starts)


def _screen_task(
    problem: Problem, item: tuple[tuple[str, ...], list[dict[str, float]]]
) -> ModelFit:
    """Screening fit of ``item = (effects, starts)``."""
    effects, starts = item
    return fit_model(problem, effects, starts=starts, screen=True)


def _screen(
    problem: Problem,
    items: Sequence[tuple[tuple[str, ...], list[dict[str, float]]]],
    backend: Backend,
    say: Callable[[str], None],
    what: str,
) -> list[ModelFit]:
    if not items:
        return []
    say(f"screening {len(items)} {what} on the surrogate")
    return backend.map(_screen_task, list(items), problem)


def settle_ranking(
    problem: Problem,
    fits: list[ModelFit],
    items: Sequence[tuple[tuple[str, ...], list[dict[str, float]]]],
    backend: Backend,
    say: Callable[[str], None],
) -> None:
    """Fit fully, in place, every screened model that can still reach the top of the ranking.

    The full fit is the fit every model had before screening (``items``: each model's
    effects and starts), with the screening optimum as one more start. The answer
    rests on the top ``verify_top + 1`` models of the ranking (those
    verified in PyBullet and the runner-up they are measured against). A full fit
    refines the baseline nuisances too, so its score is the screening score less a
    gain; the gain is measured on the models fitted so far (the largest seen, and
    never less than ``score_floor``). Candidates are fitted fully in order of their
    screening scores, a batch of ``backend.workers`` at a time, until the next one's
    screening score less twice the largest gain is worse than the
    ``verify_top + 1``-th best full score: it, and every one after it, can no longer
    change the top of the ranking, and keeps its screening fit (marked ``screened``).
    """
    settings = problem.settings
    need = settings.verify_top + 1
    batch = max(1, int(getattr(backend, "workers", 1) or 1))
    order = sorted(range(len(fits)), key=lambda i: fits[i].rank_score)
    gain = settings.score_floor
    full: list[float] = []
    pos = 0
    while pos < len(order):
        if len(full) >= need:
            bar = sorted(full)[need - 1]
            if fits[order[pos]].rank_score - GAIN_MARGIN * gain > bar:
                break
        picked = order[pos : pos + batch]
        pos += len(picked)
        # the full fit from its own starts and the screening optimum
        jobs = [(items[i][0], [*items[i][1], fits[i].values]) for i in picked]
        done: list[ModelFit] = backend.map(_full_task, jobs, problem)
        for i, f in zip(picked, done):
            gain = max(gain, fits[i].rank_score - f.rank_score)
            fits[i] = f
            full.append(f.rank_score)
    say(
        f"fitted {pos} of {len(fits)} models fully (baseline nuisances refined); "
        f"{len(fits) - pos} cannot reach the top {need} and keep their screening fits"
    )


def fit_candidates(
    problem: Problem,
    candidates: Sequence[str],
    backend: Backend,
    say: Callable[[str], None],
    done: Callable[[str, float], None] | None = None,
) -> tuple[list[ModelFit], list[ModelFit], ModelFit]:
    """Fit every single candidate, then pairs; returns ``(singles, pairs, nominal_fit)``.

    Pairs are the best single with every other candidate (forward selection:
    a second effect is often masked by a dominant one) and every pair among
    the best singles. Every model is screened on the surrogate first
    (:func:`fit_model` with ``screen=True``); :func:`settle_ranking` then fits fully
    those that can still reach the top of the ranking. ``done(stage, seconds)`` hears of
    each finished stage (``"screen singles"``, ``"screen pairs"``, ``"refine"``).
    """
    settings = problem.settings
    clock = [time.perf_counter()]

    def finished(stage: str) -> None:
        now = time.perf_counter()
        if done is not None:
            done(stage, now - clock[0])
        clock[0] = now

    single_items = [((e,), []) for e in candidates]
    singles = _screen(problem, single_items, backend, say, "single effects")
    nominal_fit = fit_model(problem, ())
    finished("screen singles")
    ranked = sorted(singles, key=lambda f: f.rank_score)
    top = [f for f in ranked if f.rank_score < nominal_fit.rank_score][: settings.pair_candidates]
    combos: dict[frozenset[str], tuple[ModelFit, ModelFit]] = {}
    if top:
        for other in ranked:
            if other.effects != top[0].effects:
                combos.setdefault(frozenset(top[0].effects + other.effects), (top[0], other))
    for fa, fb in ((x, y) for i, x in enumerate(top) for y in top[i + 1 :]):
        combos.setdefault(frozenset(fa.effects + fb.effects), (fa, fb))
    pairs_items: list[tuple[tuple[str, ...], list[dict[str, float]]]] = []
    for fa, fb in combos.values():
        nominal_b = {k: EFFECTS[fb.effects[0]]().spec(split_key(k)[1]).nominal for k in fb.keys}
        starts = [{**fa.values, **fb.values}, {**fa.values, **nominal_b}]
        pairs_items.append(((fa.effects[0], fb.effects[0]), starts))
    pairs = _screen(problem, pairs_items, backend, say, "pairs")
    finished("screen pairs")
    fits = [*singles, *pairs]
    settle_ranking(problem, fits, [*single_items, *pairs_items], backend, say)
    finished("refine")
    singles, pairs = fits[: len(singles)], fits[len(singles) :]
    singles.sort(key=lambda f: f.rank_score)
    return singles, pairs, nominal_fit
