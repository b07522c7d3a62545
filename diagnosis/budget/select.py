r"""One selection rule: forward selection on a cross-validated score.

Starting from the calibrated baseline, every step tries each remaining candidate effect on
top of the effects already chosen, and adds the best one if the data hold it up. For one
candidate :math:`c` added to the current model :math:`M`:

1. **Fit at its own scale.** The parameters of :math:`c` are fitted on all training
   windows with those of :math:`M` held, except that a run-scale candidate is fitted
   together with the run-scale entries of :math:`M` (geometric factors add up through the
   same integrated motion: an entry that stood in for part of :math:`c` moves back as
   :math:`c` enters); its gains are then measured against :math:`M` with those entries
   refitted the same way without :math:`c` (:func:`_reference`), so that :math:`c` is
   credited only with what it adds.
   An effect that acts at
   run scale (``Effect.scale == "run"``: a wheel size, a wheelbase, an encoder's scale) on
   the run cells of :class:`~realitygap.diagnosis.budget.folds.RunCells`, where it adds up
   and a clock's window-to-window scatter averages out; every other effect on the windows
   with the robust loss of the fits. Start points: the candidate's own fit of the ranking
   and its nominal.
2. **Leave one fold out.** For each training fold :math:`k` (a session, else a run, else a
   segment: :func:`~realitygap.diagnosis.budget.folds.make_folds`) the fit without the fold
   is one Gauss–Newton step from the full optimum on the other folds' rows (with the robust
   loss's weights, inside the bounds) — the approximate leave-one-out of M-estimators —,
   kept only if it lowers the other folds' cost (else the full optimum); the fold's
   residual is then evaluated exactly on the surrogate at that value.
3. **Score.** The fold's score is its windows' robust cost relative to the baseline's total,
   plus (for a robot whose motion integrates, ``RobotAdapter.integrates``) its run cells'
   squared sum relative to the baseline's; the gain of :math:`c` on fold :math:`k` is the
   log ratio of the current model's fold score to the candidate's (:func:`fold_gains`).
4. **Test.** :math:`c` qualifies when its fold gains, over the folds that exercise it
   (where it moves the training residual by at least :attr:`AttributionSettings.floor`
   RMS at its scale: a fold it does not touch is evidence neither way), are positive by a
   paired one-sided Student :math:`t` test (:func:`paired_test`) at :math:`α/m`
   (Bonferroni over the :math:`m` candidates of the step), its parameters stay off the
   far ends of their physical ranges, and no motion regime's fold gains are negative at
   :math:`α/r` (one-sided, :math:`r` regimes). The qualifying candidate with the largest
   mean gain enters; qualifying candidates whose gains are not significantly smaller
   (paired one-sided test at :math:`α`) are its **aliases** on these data.
5. **Refit together.** The entries so far are refitted jointly, scale by scale
   (:func:`_refit`), so that an early entry is not left biased by what a later one models.

The selection stops when nothing qualifies or :data:`MAX_ENTRIES` effects are in. Every
entry's parameters are then fitted per session alone (one Gauss–Newton step on the fold's
rows, with the error the fold's own scatter gives) and tested for **stability** with
Cochran's :math:`Q` (:func:`cochran_q`) over sessions (over runs when the training holds
one session), at 0.01 divided by the effect's number of parameters: a physical constant
has one value in every session.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares
from scipy.stats import chi2
from scipy.stats import t as student_t

from realitygap.core.parallel import Backend
from realitygap.diagnosis.budget.folds import Folds, RunCells
from realitygap.diagnosis.fit.model import ModelFit, _rho
from realitygap.diagnosis.problem.parameters import (
    from_range_position,
    model_keys,
    param_spec,
    range_derivative,
    range_position,
    split_key,
)
from realitygap.diagnosis.problem.problem import Problem
from realitygap.robots.effects import EFFECTS

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "ALPHA",
    "MAX_ENTRIES",
    "Selected",
    "Trial",
    "cochran_q",
    "effect_scale",
    "forward_select",
    "paired_test",
]

ALPHA = 0.05
"""Family-wise level of every test of the selection."""
MAX_ENTRIES = 4
"""The most effects a budget names."""
_STABILITY_ALPHA = 0.01
MIN_TESTED = 3
"""The fewest folds a paired test is drawn on (two give one degree of freedom: two nearly
equal values would pass for certainty)."""
_MAX_STEP = 0.05
"""Largest leave-one-fold-out move of a parameter, in range positions."""


def effect_scale(effect: str) -> str:
    """``"run"`` or ``"window"``: the scale an effect is fitted at (``Effect.scale``)."""
    return str(EFFECTS[effect].scale)


def paired_test(gains: FloatArray) -> tuple[float, float]:
    r"""One-sided paired Student :math:`t` test that the gains (one per fold) are above
    zero: ``(t, p)``. A constant positive set of gains has ``p = 0``; fewer than two folds
    or no spread and no gain, ``p = 1``.

    Gains are log ratios of fold scores, so folds that exercise an effect more do not
    dominate the mean; a test on signs alone (a sign-flip test) would need
    :math:`\log_2(m/α)` exercised folds to reach :math:`α/m` at all, more than an effect
    acting only in fast or slow segments has."""
    g = np.asarray(gains, dtype=float)
    g = g[np.isfinite(g)]
    if g.size < 2:
        return 0.0, 1.0
    mean = float(np.mean(g))
    sd = float(np.std(g, ddof=1))
    if sd <= 1e-12 * max(abs(mean), 1e-300):
        return (math.inf, 0.0) if mean > 0 else (-math.inf if mean < 0 else 0.0, 1.0)
    t = mean / (sd / math.sqrt(g.size))
    return t, float(student_t.sf(t, g.size - 1))


def cochran_q(values: FloatArray, errors: FloatArray) -> tuple[float, float, float]:
    """Cochran's :math:`Q` of per-fold estimates with their standard errors: ``(Q, p, I²)``.

    :math:`Q = Σ w_k (x_k - \\bar x_w)^2`, :math:`w_k = 1/σ_k^2`, against :math:`χ^2_{K-1}`;
    :math:`I^2 = \\max(0, (Q - (K-1))/Q)` is the share of the spread beyond the errors."""
    x = np.asarray(values, dtype=float)
    s = np.asarray(errors, dtype=float)
    ok = np.isfinite(x) & np.isfinite(s) & (s > 0)
    x, s = x[ok], s[ok]
    if x.size < 2:
        return 0.0, 1.0, 0.0
    w = 1.0 / s**2
    mean = float(np.sum(w * x) / np.sum(w))
    q = float(np.sum(w * (x - mean) ** 2))
    dof = x.size - 1
    i2 = max(0.0, (q - dof) / q) if q > 0 else 0.0
    return q, float(chi2.sf(q, dof)), i2


# --------------------------------------------------------------------------- scoring
@dataclass(frozen=True)
class Scorer:
    """Per-fold scores of training residuals at the two scales, relative to the baseline's."""

    folds: Folds
    cells: RunCells | None
    loss: str
    c: float
    w0: float
    r0: float
    sub_cells: RunCells | None = None
    """Run cells per part of a stability group (:attr:`Folds.sub`)."""

    def parts(self, z: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Per-fold window cost and run cost (K,) of a training residual (n,)."""
        k = self.folds.k
        w: FloatArray = np.bincount(
            self.folds.train, _rho(z**2, self.loss, self.c), minlength=k
        ).astype(float)
        if self.cells is None:
            return w, np.zeros(k)
        r: FloatArray = np.bincount(self.cells.unit, self.cells(z) ** 2, minlength=k).astype(float)
        return w, r

    def score(self, z: FloatArray) -> FloatArray:
        w, r = self.parts(z)
        out = w / self.w0
        if self.cells is not None and self.r0 > 0:
            out = out + r / self.r0
        return out

    def regime_scores(self, z: FloatArray, regime: npt.NDArray[np.str_]) -> dict[str, FloatArray]:
        """Per regime, the per-fold score of the entries (and run cells) of that regime."""
        out: dict[str, FloatArray] = {}
        k = self.folds.k
        cells = self.cells(z) ** 2 if self.cells is not None else None
        for r in np.unique(regime):
            sel = regime == r
            s: FloatArray = (
                np.bincount(
                    self.folds.train[sel], _rho(z[sel] ** 2, self.loss, self.c), minlength=k
                )
                / self.w0
            )
            if cells is not None and self.cells is not None and self.r0 > 0:
                cs = self.cells.regime == r
                s = s + np.bincount(self.cells.unit[cs], cells[cs], minlength=k) / self.r0
            out[str(r)] = s
        return out


@dataclass
class Trial:
    """One candidate tried on top of the current model at one step."""

    effect: str
    scale: str
    keys: tuple[str, ...]
    values: dict[str, float]
    stderr: dict[str, float]
    fold_scores: FloatArray
    fold_u: FloatArray
    """Per stability group (:attr:`Folds.groups`), the parameters fitted on it alone."""
    fold_se: FloatArray
    regime_scores: dict[str, FloatArray]
    pinned: tuple[str, ...]
    exposure: FloatArray = field(default_factory=lambda: np.zeros(0))
    """Per fold, the RMS change the candidate makes to the training residual at its scale
    (windows, or run cells; feature-scale units): a fold where it is under the floor does
    not exercise the effect."""
    gains: FloatArray = field(default_factory=lambda: np.zeros(0))
    t: float = 0.0
    p: float = 1.0
    worse_in: tuple[str, ...] = ()
    qualifies: bool = False

    @property
    def mean_gain(self) -> float:
        return float(np.mean(self.gains)) if self.gains.size else 0.0


@dataclass
class Selected:
    """One entry of the selection: the trial that entered, its aliases and its stability."""

    trial: Trial
    aliases: tuple[str, ...]
    stability: dict[str, Any]
    tried: int
    model: dict[str, float] = field(default_factory=dict)
    """The parameters of the model this entry completes (every entry so far, refitted
    together)."""


def fold_gains(before: FloatArray, after: FloatArray) -> FloatArray:
    """Per-fold gains as log ratios of the scores: folds differ in how much motion (and gap)
    they hold, and a log ratio puts each on its own scale, so that a paired test over folds
    asks whether the model helps in each, not how much of the total each fold carries."""
    b = np.maximum(np.asarray(before, dtype=float), 1e-300)
    a = np.maximum(np.asarray(after, dtype=float), 1e-300)
    return np.log(b / a)


def _gn_step(
    J: FloatArray, r: FloatArray, w: FloatArray, rows: npt.NDArray[np.bool_]
) -> tuple[FloatArray, FloatArray]:
    """Weighted Gauss–Newton step on ``rows`` and the covariance of its solution (p, p)
    from those rows' own scatter (in the fit's coordinates)."""
    Jw = J[rows] * np.sqrt(w[rows])[:, None]
    rw = r[rows] * np.sqrt(w[rows])
    A = Jw.T @ Jw
    p = A.shape[0]
    A = A + 1e-9 * np.trace(A) / max(p, 1) * np.eye(p) + 1e-15 * np.eye(p)
    step = -np.linalg.solve(A, Jw.T @ rw)
    dof = max(int(rows.sum()) - p, 1)
    s2 = float(np.sum((rw + Jw @ step) ** 2)) / dof
    return step, s2 * np.linalg.inv(A)


def _try(problem: Problem, shared: tuple[Any, ...], effect: str) -> Trial:
    """Fit ``effect`` on top of the held values, then its leave-one-fold-out scores.

    ``shared`` may end with the keys of the effects already chosen. A candidate that acts on
    whole runs is fitted together with the chosen ones that act on whole runs (the model with
    the candidate, not the candidate alone on the others' values): geometric factors add up
    over a run through the same integrated motion, so an entry stood in for part of the
    candidate — a wheelbase factor that took up a wheel-scale error through the heading —
    and moves back when the candidate enters. Window effects (lags, slips, clocks) stay held:
    refitted beside each other they trade places among aliases rather than reveal a missed
    one. Only the candidate's parameters are reported."""
    held, starts, scorer, integrates, z_cur, *more = shared
    entered: tuple[str, ...] = tuple(more[0]) if more else ()
    scale = effect_scale(effect) if integrates else "window"
    hp = problem.held_parameters([effect])
    own = tuple(k for k in model_keys([effect]) if k not in hp)
    co = tuple(
        k
        for k in entered
        if scale == "run" and k not in own and k in held and effect_scale(split_key(k)[0]) == "run"
    )
    keys = own + co
    tr = problem.train
    cells = scorer.cells
    fixed = {k: np.array([v]) for k, v in held.items() if k not in co}

    def residuals(U: FloatArray) -> FloatArray:
        vals = dict(fixed)
        vals = {k: np.repeat(v, U.shape[0]) for k, v in vals.items()}
        for j, k in enumerate(keys):
            vals[k] = from_range_position(k, U[:, j])
        return problem.surrogate_residuals(tr, vals, U.shape[0])

    def reading(z: FloatArray) -> FloatArray:
        return cells(z) if (scale == "run" and cells is not None) else z

    p = len(keys)
    if p == 0:
        z = residuals(np.zeros((1, 0)))[0]
        return Trial(
            effect,
            scale,
            keys,
            {},
            {},
            scorer.score(z),
            np.zeros((len(scorer.folds.group_labels), 0)),
            np.zeros((len(scorer.folds.group_labels), 0)),
            scorer.regime_scores(z, tr.regime),
            (),
        )
    loss = "linear" if scale == "run" else problem.settings.loss
    c = scorer.c
    u_co = [range_position(k, held[k]) for k in co]  # the entries start where they are
    u_starts = [np.array([range_position(k, param_spec(k).nominal) for k in own] + u_co)]
    if all(k in held for k in own):
        u_starts.append(np.array([range_position(k, held[k]) for k in own] + u_co))
    if effect in starts:
        u_starts.append(
            np.array(
                [range_position(k, starts[effect].get(k, param_spec(k).nominal)) for k in own]
                + u_co
            )
        )
    cache: dict[bytes, FloatArray] = {}

    def fun(u: FloatArray) -> FloatArray:
        b = u.tobytes()
        if b not in cache:
            cache[b] = reading(residuals(u[None])[0])
        return cache[b]

    best = None
    for u0 in u_starts:
        u0 = np.clip(u0, 1e-9, 1 - 1e-9)
        res = least_squares(
            fun,
            u0,
            bounds=(np.zeros(p), np.ones(p)),
            x_scale=0.1,
            diff_step=1e-3,
            loss=loss,
            f_scale=c,
            max_nfev=20 * (p + 1),
            method="trf",
        )
        if best is None or res.cost < best.cost:
            best = res
    assert best is not None
    u_hat = best.x
    # Jacobian of the fit's reading at the optimum, forward differences inside the box
    h = np.where(u_hat + 1e-3 <= 1.0, 1e-3, -1e-3)
    U = np.repeat(u_hat[None], p + 1, axis=0)
    U[1 + np.arange(p), np.arange(p)] += h
    Z = residuals(U)
    # how much the candidate moves each fold's residual, at its own scale (a run-scale
    # effect adds up in the run cells where a window barely shows it)
    moved = reading(Z[0] - z_cur)
    where = cells.unit if (scale == "run" and cells is not None) else scorer.folds.train
    exposure = np.sqrt(
        np.bincount(where, moved**2, minlength=scorer.folds.k)
        / np.maximum(np.bincount(where, minlength=scorer.folds.k), 1)
    )
    Rd = np.stack([reading(z) for z in Z])
    r0 = Rd[0]
    J = ((Rd[1:] - r0) / h[:, None]).T
    w = (
        np.ones_like(r0)
        if loss == "linear"
        else 1.0 / np.sqrt(1.0 + r0**2 / c**2)  # soft_l1's IRLS weight
    )
    folds = scorer.folds
    on_cells = scale == "run" and cells is not None
    unit = cells.unit if on_cells else folds.train
    K = folds.k
    U_cv = np.empty((K, p))
    for k in range(K):
        rows = unit != k
        step, _ = _gn_step(J, r0, w, rows)
        # leaving one fold of several out moves a well-posed estimate a little: a longer
        # step is the linearisation failing (a step-like or bound-pinned parameter)
        step = np.clip(step, -_MAX_STEP, _MAX_STEP)
        U_cv[k] = np.clip(u_hat + step, 0.0, 1.0)
    # stability: each group's estimate from its rows, its error from the spread of its
    # parts' estimates (runs of a session, segments of a run): honest where residuals
    # are correlated in time or the model misses something, which a scatter-based error
    # of correlated rows is not
    sub_cells = scorer.sub_cells
    if scale == "run" and sub_cells is not None:
        R_sub = np.stack([sub_cells(z) for z in Z])
        r_s, w_s, part = R_sub[0], np.ones(R_sub.shape[1]), sub_cells.unit
    else:
        R_sub = Z
        r_s = Z[0]
        w_s = w if loss != "linear" else np.ones_like(r_s)
        if scale == "run":  # a run-scale effect without run cells: its windows
            w_s = np.ones_like(r_s)
        part = folds.sub
    J_s = ((R_sub[1:] - r_s) / h[:, None]).T
    G = len(folds.group_labels)
    U_own = np.full((G, p), np.nan)
    S_own = np.full((G, p), np.nan)
    n_parts = folds.sub_group.size
    U_part = np.full((n_parts, p), np.nan)
    for s_ in range(n_parts):
        mine = part == s_
        if mine.sum() > p:
            U_part[s_] = u_hat + _gn_step(J_s, r_s, w_s, mine)[0]
    for g in range(G):
        mine = folds.sub_group[part] == g
        if mine.sum() <= p:
            continue
        step_g, cov_g = _gn_step(J_s, r_s, w_s, mine)
        U_own[g] = u_hat + step_g
        parts = U_part[folds.sub_group == g]
        parts = parts[np.all(np.isfinite(parts), axis=1)]
        if parts.shape[0] >= 2:
            S_own[g] = np.std(parts, axis=0, ddof=1) / math.sqrt(parts.shape[0])
        else:
            S_own[g] = np.sqrt(np.maximum(np.diag(cov_g), 0.0))
    Z_cv = residuals(U_cv)
    s_hat = scorer.score(Z[0])
    fold_scores = np.empty(K)
    regime: dict[str, FloatArray] = {}
    for k in range(K):
        s = scorer.score(Z_cv[k])
        z_k = Z_cv[k]
        # a safeguarded step: where the Gauss-Newton step makes the other folds' cost worse
        # than the full optimum (a step-like parameter, a linearisation that fails), the
        # estimate without fold k is the full optimum itself
        others = np.arange(K) != k
        if float(np.sum(s[others])) > float(np.sum(s_hat[others])):
            s, z_k = s_hat, Z[0]
        fold_scores[k] = s[k]
        for r, v in scorer.regime_scores(z_k, tr.regime).items():
            regime.setdefault(r, np.zeros(K))[k] = v[k]
    # parameter errors of the full fit, in natural units (the rows' own scatter)
    _, cov = _gn_step(J, r0, w, np.ones(r0.size, dtype=bool))
    se_u = np.sqrt(np.maximum(np.diag(cov), 0.0))
    # the candidate's own parameters are its result; the co-fitted entries are refitted
    # jointly when it enters
    n_own = len(own)
    keys, u_hat, se_u = own, u_hat[:n_own], se_u[:n_own]
    U_own, S_own = U_own[:, :n_own], S_own[:, :n_own]
    values = {k: float(from_range_position(k, np.array([u_hat[j]]))[0]) for j, k in enumerate(keys)}
    # an error wider than the parameter's whole range is no error bar (a dead band between
    # the commanded speeds: the data bound it to an interval, :func:`fit_model`)
    stderr = {
        k: float(se_u[j] * abs(range_derivative(k, values[k]))) if se_u[j] < 1.0 else math.nan
        for j, k in enumerate(keys)
    }
    pinned = []
    for j, k in enumerate(keys):
        spec = param_spec(k)
        if (spec.low != spec.nominal and u_hat[j] < 0.005) or (
            spec.high != spec.nominal and u_hat[j] > 0.995
        ):
            pinned.append(k)
    return Trial(
        effect,
        scale,
        keys,
        values,
        stderr,
        fold_scores,
        U_own,
        S_own,
        regime,
        tuple(pinned),
        exposure=exposure,
    )


def _reference(
    problem: Problem,
    held: Mapping[str, float],
    entered: Sequence[str],
    scale: str,
    scorer: Scorer,
    integrates: bool,
) -> tuple[FloatArray, dict[str, FloatArray]] | None:
    """The current model's fold and regime scores with its entries of ``scale`` refitted on
    that scale's reading, as :func:`_try` refits them beside a candidate (``None`` when none
    is at that scale): the reference a candidate's gains are measured against, so that a
    candidate is credited with what it adds, not with what refitting the others alone does."""
    co = [
        k
        for k in entered
        if scale == "run" and integrates and k in held and effect_scale(split_key(k)[0]) == "run"
    ]
    if not co:
        return None
    tr = problem.train
    cells = scorer.cells
    fixed = {k: np.array([v]) for k, v in held.items() if k not in co}
    on_cells = scale == "run" and cells is not None

    def residual(u: FloatArray) -> FloatArray:
        vals = dict(fixed)
        for j, k in enumerate(co):
            vals[k] = from_range_position(k, u[j : j + 1])
        return problem.surrogate_residuals(tr, vals, 1)[0]

    def fun(u: FloatArray) -> FloatArray:
        z = residual(u)
        return cells(z) if on_cells and cells is not None else z

    u0 = np.clip([range_position(k, held[k]) for k in co], 1e-9, 1 - 1e-9)
    res = least_squares(
        fun,
        u0,
        bounds=(np.zeros(len(co)), np.ones(len(co))),
        x_scale=0.1,
        diff_step=1e-3,
        loss="linear" if scale == "run" else problem.settings.loss,
        f_scale=scorer.c,
        max_nfev=20 * (len(co) + 1),
        method="trf",
    )
    z = residual(res.x)
    return scorer.score(z), scorer.regime_scores(z, tr.regime)


def _try_task(shared: tuple[Any, ...], effect: str) -> Trial:
    problem, rest = shared[0], shared[1:]
    return _try(problem, rest, effect)


def _stability(trial: Trial, folds: Folds) -> dict[str, Any]:
    """Per parameter: the per-fold values, Cochran's Q and whether the value holds across
    folds (only when folds are sessions or runs)."""
    out: dict[str, Any] = {
        "unit": folds.groups_unit,
        "tested": folds.groups_unit != "segment",
        "parameters": {},
    }
    varies = False
    for j, k in enumerate(trial.keys):
        u = trial.fold_u[:, j]
        s = trial.fold_se[:, j]
        ok = np.isfinite(u) & np.isfinite(s)
        vals = np.array([float(from_range_position(k, np.array([x]))[0]) for x in u[ok]])
        q, p, i2 = cochran_q(u[ok], s[ok])
        # an effect varies when any of its parameters does: Bonferroni over them
        holds = not (
            folds.groups_unit != "segment" and p < _STABILITY_ALPHA / max(len(trial.keys), 1)
        )
        varies = varies or not holds
        out["parameters"][k] = {
            "per_fold": [float(v) for v in vals],
            "groups": [folds.group_labels[i] for i in np.flatnonzero(ok)],
            "cochran_q": q,
            "p": p,
            "i2": i2,
            "min": float(vals.min()) if vals.size else math.nan,
            "max": float(vals.max()) if vals.size else math.nan,
            "holds": holds,
        }
    out["constant"] = not varies
    return out


def forward_select(
    problem: Problem,
    candidates: Sequence[str],
    ranking: Sequence[ModelFit],
    folds: Folds,
    integrates: bool,
    backend: Backend,
    say: Callable[[str], None],
) -> tuple[list[Selected], Scorer, FloatArray]:
    """Run the selection (module docstring). Returns the entries in order, the scorer and
    the baseline's per-fold scores."""
    tr = problem.train
    z_base = problem.surrogate_residuals(tr, {}, 1)[0]
    cells = RunCells.of(tr, folds.train) if integrates else None
    c = problem.f_scale
    w_parts = np.bincount(folds.train, _rho(z_base**2, problem.settings.loss, c), minlength=folds.k)
    w0 = float(w_parts.sum())
    r0 = float(np.sum(cells(z_base) ** 2)) if cells is not None else 0.0
    sub_cells = RunCells.of(tr, folds.sub) if integrates else None
    scorer = Scorer(folds, cells, problem.settings.loss, c, max(w0, 1e-300), r0, sub_cells)
    base_scores = scorer.score(z_base)
    base_regimes = scorer.regime_scores(z_base, tr.regime)
    starts: dict[str, dict[str, float]] = {}
    for f in ranking:
        if len(f.effects) == 1 and f.effects[0] not in starts:
            starts[f.effects[0]] = {
                k: v for k, v in f.values.items() if split_key(k)[0] == f.effects[0]
            }
    held: dict[str, float] = {}
    current, current_regimes = base_scores, base_regimes
    chosen: list[Selected] = []
    remaining = [e for e in candidates if model_keys([e])]
    while remaining and len(chosen) < MAX_ENTRIES:
        say(
            f"budget: step {len(chosen) + 1}, {len(remaining)} candidate(s) on {folds.k} {folds.unit} fold(s)"
        )
        z_cur = problem.surrogate_residuals(tr, as_arrays(held), 1)[0]
        entered = tuple(model_keys([sel.trial.effect for sel in chosen]))
        trials: list[Trial] = backend.map(
            _try_task,
            remaining,
            (problem, dict(held), starts, scorer, integrates, z_cur, entered),
        )
        m = len(trials)
        refs = {
            sc: _reference(problem, held, entered, sc, scorer, integrates)
            for sc in {tri.scale for tri in trials}
        }
        for tri in trials:
            ref = refs.get(tri.scale)
            ref_scores, ref_regimes = ref if ref is not None else (current, current_regimes)
            tri.gains = fold_gains(ref_scores, tri.fold_scores)
            # only the folds that exercise the effect are evidence, either way
            exercised = tri.exposure >= problem.settings.floor if tri.exposure.size else None
            tested = tri.gains[exercised] if exercised is not None else tri.gains
            tri.t, tri.p = paired_test(tested) if tested.size >= MIN_TESTED else (0.0, 1.0)
            worse = []
            for r, s in tri.regime_scores.items():
                base_r = ref_regimes.get(r)
                if base_r is None:
                    continue
                g = fold_gains(base_r, s)
                present = np.abs(base_r) > 0
                if present.sum() >= MIN_TESTED:
                    t_r, p_r = paired_test(-g[present])
                    if p_r < ALPHA / max(len(tri.regime_scores), 1) and t_r > 0:
                        worse.append(r)
            tri.worse_in = tuple(worse)
            tri.qualifies = tri.p < ALPHA / m and not tri.pinned and not worse and tri.mean_gain > 0
        ok = [tri for tri in trials if tri.qualifies]
        if not ok:
            near = max(trials, key=lambda tri: tri.mean_gain)
            why = (
                f"pinned at {', '.join(near.pinned)}"
                if near.pinned
                else f"worsens {', '.join(near.worse_in)}"
                if near.worse_in
                else f"p = {near.p:.2g} against {ALPHA / m:.2g}"
            )
            say(
                f"budget: step {len(chosen) + 1}: nothing qualifies (the largest gain, "
                f"{near.effect} {near.mean_gain:+.3g}: {why})"
            )
            break
        ok.sort(key=lambda tri: -tri.mean_gain)
        top = ok[0]
        aliases = tuple(
            tri.effect for tri in ok[1:] if paired_test(top.gains - tri.gains)[1] >= ALPHA
        )
        held.update(top.values)
        effects = [e.trial.effect for e in chosen] + [top.effect]
        # the entries so far refitted together, and the baseline's nuisances with them
        # inside their ranges: a stagewise fit leaves an earlier entry's value, and the
        # nuisances calibrated without any effect, biased by what the later one models
        held = _refit(problem, held, effects, scorer, integrates)
        z = problem.surrogate_residuals(tr, as_arrays(held), 1)[0]
        current, current_regimes = scorer.score(z), scorer.regime_scores(z, tr.regime)
        chosen.append(Selected(top, aliases, {}, m, dict(held)))
        remaining = [e for e in remaining if e != top.effect]
    # each entry's value, error and stability at the joint optimum, the others held
    for sel in chosen:
        mine = set(sel.trial.keys)
        others = {k: v for k, v in held.items() if k not in mine}
        z_others = problem.surrogate_residuals(tr, as_arrays(others), 1)[0]
        shared = (others, {sel.trial.effect: held}, scorer, integrates, z_others)
        final = _try(problem, shared, sel.trial.effect)
        sel.trial.values, sel.trial.stderr = final.values, final.stderr
        sel.trial.fold_u, sel.trial.fold_se = final.fold_u, final.fold_se
        sel.stability = _stability(sel.trial, folds)
    return chosen, scorer, base_scores


def _refit(
    problem: Problem,
    values: Mapping[str, float],
    effects: Sequence[str],
    scorer: Scorer,
    integrates: bool,
) -> dict[str, float]:
    """The parameters of ``effects`` refitted together, scale by scale (run-scale effects on
    the run cells, the others on the windows, each with the other scale's held), then the
    calibrated baseline's nuisances on the windows inside their ranges, from ``values``."""
    out = dict(values)
    tr = problem.train
    cells = scorer.cells
    mine = {k for e in effects for k in model_keys([e])}
    nuisances = [
        k for k in problem.baseline_ranges if k in problem.baseline_values and k not in mine
    ]
    for k in nuisances:
        out.setdefault(k, problem.baseline_values[k])
    for scale in ("run", "window", "nuisance"):
        if scale == "nuisance":
            keys = nuisances
        else:
            keys = [
                k
                for e in effects
                if (effect_scale(e) if integrates else "window") == scale
                for k in model_keys([e])
                if k in out
            ]
        if not keys or (scale == "run" and cells is None):
            continue
        lo, hi = np.zeros(len(keys)), np.ones(len(keys))
        if scale == "nuisance":
            for j, k in enumerate(keys):
                a, b = (range_position(k, x) for x in problem.baseline_ranges[k])
                lo[j], hi[j] = max(min(a, b), 0.0), min(max(a, b), 1.0)

        def fun(u: FloatArray, keys: list[str] = keys, scale: str = scale) -> FloatArray:
            vals = {k: np.array([v]) for k, v in out.items()}
            for j, k in enumerate(keys):
                vals[k] = from_range_position(k, u[j : j + 1])
            z = problem.surrogate_residuals(tr, vals, 1)[0]
            return cells(z) if scale == "run" and cells is not None else z

        span = np.maximum(hi - lo, 1e-12)
        u0 = np.clip([range_position(k, out[k]) for k in keys], lo + 1e-9 * span, hi - 1e-9 * span)
        if np.any(hi - lo <= 1e-12):
            continue
        res = least_squares(
            fun,
            u0,
            bounds=(lo, hi),
            x_scale=0.1,
            diff_step=1e-3,
            loss="linear" if scale == "run" else problem.settings.loss,
            f_scale=scorer.c,
            max_nfev=20 * (len(keys) + 1),
            method="trf",
        )
        for j, k in enumerate(keys):
            out[k] = float(from_range_position(k, res.x[j : j + 1])[0])
    return out


def values_of(entries: Sequence[Selected], upto: int | None = None) -> dict[str, float]:
    """The parameter values of the model of the first ``upto`` entries (all by default), as
    refitted together when the last of them entered."""
    n = len(entries) if upto is None else upto
    return dict(entries[n - 1].model) if n > 0 else {}


def as_arrays(values: Mapping[str, float]) -> dict[str, FloatArray]:
    return {k: np.array([v]) for k, v in values.items()}
