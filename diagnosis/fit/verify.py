"""Verification of the best explanations in PyBullet, and the ranking it settles.

A model fitted on the surrogate is refitted with the surrogate's defect
against PyBullet replays removed (defect correction), then scored on PyBullet
replays of every log (:func:`verify_model`). :func:`verify_ranking` verifies
the leading models one by one, prefers simpler sub-models within the parsimony
margin, drops effects whose fitted size is below the noise floor and effects
that do not improve the held-out residual beyond its noise
(:func:`heldout_gain_counts`), until the top of the ranking is settled.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.parallel import Backend
from realitygap.diagnosis.adapters.contract import PreparedLog
from realitygap.diagnosis.fit.model import ModelFit, _finish, fit_model, replay_task
from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.parameters import range_position
from realitygap.diagnosis.problem.problem import Problem

FloatArray = npt.NDArray[np.float64]

__all__ = ["Verification", "heldout_gain_counts", "verify_model", "verify_ranking"]

HELDOUT_GAIN_SIGMAS = 2.0
"""How many standard errors a held-out gain must reach to count whatever its size."""
HELDOUT_GAIN_MIN_SHARE = 0.05
"""Share of the held-out mean square a gain must remove to count whatever its noise."""


def _rescore(problem: Problem, fit: ModelFit, z_tr: FloatArray, z_ho: FloatArray) -> ModelFit:
    u = np.array([range_position(k, fit.values[k]) for k in fit.keys])
    new = _finish(
        problem,
        fit.effects,
        fit.keys,
        u,
        z_tr,
        z_ho,
        np.zeros((z_tr.size, 0)),
        True,
        held=fit.held,
    )
    new.stderr, new.corr = fit.stderr, fit.corr
    return new


def _surrogate_point(values: Mapping[str, float]) -> dict[str, FloatArray]:
    return {k: np.array([v]) for k, v in values.items()}


def verify_model(
    problem: Problem, fit: ModelFit, backend: Backend
) -> tuple[ModelFit, dict[int, Log], dict[str, Any]]:
    """Defect-corrected refit and PyBullet scores for one model."""
    values = dict(fit.values)
    train_idx = [i for i, p in enumerate(problem.logs) if (~p.holdout_windows).any()]
    for _ in range(problem.settings.defect_iterations):
        reps = backend.map(replay_task, [(i, values) for i in train_idx], problem)
        bias = {}
        for i, (feats, _) in zip(train_idx, reps):
            p = problem.logs[i]
            sur = problem.adapter.surrogate_features(p, _surrogate_point(values), problem.drive)
            bias[i] = {g: feats[g] - sur[g][0] for g in p.groups}
        fit = fit_model(problem, fit.effects, starts=[values], bias=bias, local_only=True)
        values = dict(fit.values)
    all_idx = list(range(len(problem.logs)))
    reps = backend.map(replay_task, [(i, values) for i in all_idx], problem)
    pb = {i: feats for i, (feats, _) in zip(all_idx, reps)}
    logs = {i: lg for i, (_, lg) in zip(all_idx, reps)}

    def predict(p: PreparedLog, i: int) -> dict[str, FloatArray]:
        return {g: pb[i][g][None] for g in p.groups}

    z_tr = problem.real_minus(problem.train, predict, 1)[0]
    z_ho = problem.real_minus(problem.holdout, predict, 1)[0] if problem.holdout.n else np.zeros(0)
    verified = _rescore(problem, fit, z_tr, z_ho)
    # surrogate agreement: bias-corrected surrogate vs PyBullet at the fitted point
    num = den = 0.0
    for i, p in enumerate(problem.logs):
        sur = problem.adapter.surrogate_features(p, _surrogate_point(values), problem.drive)
        for g in p.groups:
            s = problem.features.scale(g)
            pred = sur[g][0] + p.bias[g]
            num += float(np.sum(((pred - pb[i][g]) / s) ** 2))
            den += float(np.sum(((pb[i][g] - p.nominal[g]) / s) ** 2))
    agreement = {
        "model": fit.name,
        "values": values,
        "relative_error": math.sqrt(num / den) if den > 0 else 0.0,
        "rms_difference": math.sqrt(num / max(sum(p.bounds.shape[0] for p in problem.logs), 1)),
    }
    return verified, logs, agreement


def heldout_gain_counts(
    larger: ModelFit,
    smaller: ModelFit,
    sigmas: float = HELDOUT_GAIN_SIGMAS,
    min_share: float = HELDOUT_GAIN_MIN_SHARE,
) -> bool:
    r"""Whether ``larger`` improves on its sub-model ``smaller`` on the held-out data.

    A paired comparison of the normalised held-out residuals
    :math:`z^{(s)}_k, z^{(l)}_k` of the same windows and columns, with
    :math:`d_k = (z^{(s)}_k)^2 - (z^{(l)}_k)^2`. The gain counts when it is beyond
    noise, :math:`\bar d > \sigma\, \mathrm{sd}(d) / \sqrt{n}`, or sizeable,
    :math:`\bar d > s_{min}\, \overline{(z^{(s)})^2}` (few held-out windows
    may show a real second effect without statistical power). An effect that a
    training fit gives a size but that leaves the held-out residual where it was
    does not count. Without held-out residuals the gain is taken as given.
    """
    zl, zs = np.asarray(larger.z_heldout), np.asarray(smaller.z_heldout)
    if zl.size == 0 or zl.shape != zs.shape:
        return True
    d = zs**2 - zl**2
    gain = float(d.mean())
    if gain > min_share * float(np.mean(zs**2)):
        return True
    if d.size < 2:
        return False
    return gain > sigmas * float(d.std(ddof=1)) / math.sqrt(d.size)


@dataclass
class Verification:
    """Outcome of :func:`verify_ranking`.

    Attributes
    ----------
    ranking : list of ModelFit
        Every model, best first (verified ones with their PyBullet scores).
    replays : dict
        Effects of each verified model → its PyBullet replays by log index.
    agreement : list of dict
        Surrogate-vs-PyBullet agreement at each verified model's fitted point.
    """

    ranking: list[ModelFit]
    replays: dict[tuple[str, ...], dict[int, Log]]
    agreement: list[dict[str, Any]]


class _Ranker:
    """The ranking while it is being verified; a model "demoted" in favour of a simpler
    sub-model ranks right behind that sub-model."""

    def __init__(
        self,
        problem: Problem,
        nominal_fit: ModelFit,
        backend: Backend,
        say: Callable[[str], None],
    ) -> None:
        self.problem = problem
        self.nominal_fit = nominal_fit
        self.backend = backend
        self.say = say
        self.demoted: dict[tuple[str, ...], tuple[str, ...]] = {}
        self.replays: dict[tuple[str, ...], dict[int, Log]] = {}
        self.agreement: list[dict[str, Any]] = []
        self.ranking: list[ModelFit] = []

    def resort(self, models: list[ModelFit]) -> list[ModelFit]:
        score = {f.effects: f.rank_score for f in models}

        def key(f: ModelFit) -> tuple[float, int]:
            if f.effects in self.demoted:
                return (score[self.demoted[f.effects]], 1)
            return (f.rank_score, 0)

        return sorted(models, key=key)

    def demote(self, fit: ModelFit, candidates: Sequence[ModelFit]) -> None:
        """Rank ``fit`` behind the best of ``candidates`` (its sub-models)."""
        self.demoted[fit.effects] = min(candidates, key=lambda f: f.rank_score).effects
        self.ranking = self.resort(self.ranking)

    def verified(self, fit: ModelFit) -> ModelFit:
        if fit.verified or not fit.effects:
            return fit
        self.say(f"verifying {fit.name} in PyBullet")
        new, reps, agree = verify_model(self.problem, fit, self.backend)
        self.replays[new.effects] = reps
        self.agreement.append(agree)
        self.ranking = self.resort([new if f is fit else f for f in self.ranking])
        return new

    def improves(self, fit: ModelFit) -> bool:
        return fit.rank_score < self.nominal_fit.rank_score - 1.0

    def sub_models(self, fit: ModelFit) -> list[ModelFit]:
        return [f for f in self.ranking if f.effects and set(f.effects) < set(fit.effects)]

    def demote_negligible(self) -> bool:
        """Rank every model with an effect whose fitted size changes the predictions by less
        than the floor behind its sub-model without that effect (no replay needed to see
        it: the two are one model). All at once, so that a library where many pairs add a
        do-nothing partner to the same effect does not spend the verification steps on
        them one by one. ``True`` if any model was demoted."""
        floor = self.problem.settings.floor
        changed = False
        for fit in list(self.ranking):
            if len(fit.effects) < 2 or fit.effects in self.demoted:
                continue
            negligible = {e for e, size in fit.effect_sizes.items() if size < floor}
            drop = [
                f for f in self.sub_models(fit) if set(fit.effects) - set(f.effects) <= negligible
            ]
            if drop:
                self.demoted[fit.effects] = min(drop, key=lambda f: f.rank_score).effects
                changed = True
        if changed:
            self.ranking = self.resort(self.ranking)
        return changed

    def step(self) -> bool:
        """One verification step; ``False`` once the top of the ranking is settled."""
        st = self.problem.settings
        if self.demote_negligible():
            return True
        best = self.ranking[0]
        if best.effects and not best.verified:
            self.verified(best)
            return True
        # Occam: prefer a verified sub-model within the parsimony margin
        if len(best.effects) > 1:
            for sub in self.sub_models(best):
                if not sub.verified and self.improves(sub):
                    self.verified(sub)
            best = self.ranking[0]
            simpler = [
                f
                for f in self.sub_models(best)
                if f.verified and f.rank_score - best.rank_score < st.parsimony_margin
            ]
            if simpler and len(best.effects) > 1:
                self.demote(best, simpler)
                return True
            # a second effect that leaves the held-out residual where it was
            unhelpful = [
                f
                for f in self.sub_models(best)
                if f.verified and best.verified and not heldout_gain_counts(best, f)
            ]
            if unhelpful and len(best.effects) > 1:
                self.demote(best, unhelpful)
                return True
        n_ver = sum(1 for f in self.ranking if f.verified)
        todo = [
            f
            for f in self.ranking[1:]
            if f.effects and not f.verified and self.improves(f) and f.effects not in self.demoted
        ]
        if n_ver < st.verify_top and todo:
            self.verified(todo[0])
            return True
        return False


def verify_ranking(
    problem: Problem,
    models: Sequence[ModelFit],
    nominal_fit: ModelFit,
    backend: Backend,
    say: Callable[[str], None],
) -> Verification:
    """Rank ``models`` (and the nominal fit) and verify the leading ones in PyBullet.

    Parameters
    ----------
    problem : Problem
    models : sequence of ModelFit
        Fitted single effects and pairs.
    nominal_fit : ModelFit
        The model without effects.
    backend : Backend
        Where the replays run.
    say : callable
        Receives progress messages.

    Returns
    -------
    Verification
    """
    ranker = _Ranker(problem, nominal_fit, backend, say)
    ranker.ranking = ranker.resort([*models, nominal_fit])
    for _ in range(3 * problem.settings.verify_top + 6):
        if not ranker.step():
            break
    return Verification(ranker.ranking, ranker.replays, ranker.agreement)
