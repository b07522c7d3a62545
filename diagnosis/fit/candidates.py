"""Fitting the candidates: every single effect (and, when asked, pairs of the best) on the
surrogate, the calibrated baseline's nuisances held.

These screening fits (:func:`~realitygap.diagnosis.fit.model.fit_model` with
``screen=True``) rank the candidates for the report and give the gap budget
(:mod:`~realitygap.diagnosis.budget`) its start points, under the same conditions as its
own fits (the baseline beneath); the models verified in PyBullet are refined there with
their nuisances freed (:func:`~realitygap.diagnosis.fit.verify.verify_ranking`).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from realitygap.core.parallel import Backend
from realitygap.diagnosis.fit.model import ModelFit, fit_model
from realitygap.diagnosis.problem.parameters import split_key
from realitygap.diagnosis.problem.problem import Problem
from realitygap.robots.effects import EFFECTS

__all__ = ["fit_candidates"]


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


def fit_candidates(
    problem: Problem,
    candidates: Sequence[str],
    backend: Backend,
    say: Callable[[str], None],
    done: Callable[[str, float], None] | None = None,
) -> tuple[list[ModelFit], list[ModelFit], ModelFit]:
    """Fit every single candidate, then pairs; returns ``(singles, pairs, nominal_fit)``.

    Pairs (:attr:`AttributionSettings.pair_candidates` > 0) are the best single with every
    other candidate and every pair among the best singles. ``done(stage, seconds)`` hears
    of each finished stage (``"screen singles"``, ``"screen pairs"``).
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
    singles.sort(key=lambda f: f.rank_score)
    return singles, pairs, nominal_fit
