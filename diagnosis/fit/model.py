r"""Attribute a sim-to-real gap to effects: fit, score on held-out data, decide or refuse.

For every candidate effect (and pairs of the best ones) the parameters are
fitted on the training windows by robust least squares on the normalised window
residuals

.. math::  z(θ) = \big(f_{real} - f_{sim}(θ)\big) / s , \qquad
           \min_θ \sum_i ρ\big(z_i(θ)^2\big), \quad
           ρ(q) = 2 c^2 \big(\sqrt{1 + q / c^2} - 1\big)

(scipy's ``soft_l1`` loss: quadratic for residuals within ``c``, linear beyond,
so that a few disturbed windows cannot carry the fit), where
:math:`f_{sim}(θ)` is the fast surrogate plus its own error at the reference
point (``bias``: PyBullet replay minus surrogate at the calibrated baseline,
:mod:`realitygap.diagnosis.stages.baseline`), ``s`` the feature scales and ``c``
(``f_scale``) :attr:`AttributionSettings.robust_scale` times the noise level
of the baseline residual (:meth:`Problem.noise_scale`). Parameters are bounded
by the physical bounds of each effect's :class:`~realitygap.robots.effects.base.ParamSpec`,
never by ranges read from the logs. A model is scored by the Gaussian profile likelihood
per feature group ``g`` with a BIC penalty,

.. math::  S = \sum_g n_g \log\big(\overline{z_g^2} + ε^2\big) + p \log n ,

on the training windows (``bic``) and on the held-out windows
(``heldout_score``, the ranking key). The best models are then *verified*:
the bias is recomputed with PyBullet at the fitted parameters, the parameters
refined, and the held-out residual taken from a PyBullet replay — every
reported number after the fit comes from the simulator, not the surrogate.

The verdict names the best model only if it closes at least ``min_shrink`` of
the held-out gap and what remains looks like noise: no group's residual may be
much larger than its white (window-to-window) part, depend on the motion
regime, or follow the commanded speed, turn rate or acceleration. Otherwise
it is ``"unexplained"``, with a description of the remaining residual. When
two explanations fit the logged motions equally well (their parameters are
strongly correlated in a joint fit), the report says so and proposes the
library manoeuvre that separates them best.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.parameters import (
    from_range_position,
    model_keys,
    param_spec,
    range_derivative,
    range_position,
    split_key,
)
from realitygap.diagnosis.problem.problem import (
    AttributionSettings,
    Problem,
    profile_score,
)

FloatArray = npt.NDArray[np.float64]

__all__ = ["ModelFit", "fit_model", "parameter_correlation", "replay_task"]


# --------------------------------------------------------------------------- fits
@dataclass
class ModelFit:
    """One candidate model: its fitted parameters, scores and residuals.

    Scores are the profile scores of :func:`profile_score` (lower is better);
    ``rank_score`` = held-out score + ``p log n_train``. ``keys`` are the fitted
    parameters; ``held`` the model's parameters the training data cannot
    identify (:meth:`Problem.held_parameters`), kept at nominal in ``values``
    with the reason, and without an error bar.
    """

    effects: tuple[str, ...]
    keys: tuple[str, ...]
    values: dict[str, float]
    stderr: dict[str, float]
    corr: FloatArray
    train_score: float
    bic: float
    heldout_score: float
    rank_score: float
    heldout_rms: float
    z_heldout: FloatArray
    verified: bool = False
    message: str = ""
    n_train: int = 0
    effect_sizes: dict[str, float] = field(default_factory=dict)
    held: dict[str, str] = field(default_factory=dict)
    screened: bool = False

    @property
    def name(self) -> str:
        return " + ".join(self.effects) if self.effects else "nominal"

    @property
    def n_params(self) -> int:
        return len(self.keys)


def _grid(
    keys: Sequence[str], settings: AttributionSettings, rng: np.random.Generator
) -> FloatArray:
    p = len(keys)
    if p == 1:
        return np.linspace(0.0, 1.0, settings.grid_points)[:, None]
    if p == 2:
        g = np.linspace(0.0, 1.0, 13)
        return np.array(list(itertools.product(g, g)))
    if p == 3:
        g = np.linspace(0.0, 1.0, 7)
        return np.array(list(itertools.product(g, g, g)))
    n = 300
    # Latin hypercube from the seeded generator
    u = (rng.permuted(np.tile(np.arange(n), (p, 1)), axis=1).T + rng.random((n, p))) / n
    return u


def _values(keys: Sequence[str], U: FloatArray) -> dict[str, FloatArray]:
    return {k: from_range_position(k, U[:, j]) for j, k in enumerate(keys)}


def _rho(q: FloatArray, loss: str, c: float) -> FloatArray:
    """The robust loss of :func:`scipy.optimize.least_squares` at ``q = z²`` (same scaling)."""
    x = q / c**2
    if loss == "soft_l1":
        r = 2.0 * (np.sqrt(1.0 + x) - 1.0)
    elif loss == "cauchy":
        r = np.log1p(x)
    elif loss == "huber":
        r = np.where(x <= 1.0, x, 2.0 * np.sqrt(x) - 1.0)
    elif loss == "arctan":
        r = np.arctan(x)
    else:
        return q
    return c**2 * r


def replay_task(problem: Problem, item: tuple[int, Mapping[str, float]]) -> tuple[Any, Log]:
    """:meth:`Problem.replay` of ``item = (log index, values)``, as a backend maps it."""
    return problem.replay(*item)


def parameter_correlation(cov: FloatArray) -> FloatArray:
    """Correlation matrix of the parameter covariance ``cov`` (p, p): clipped to [-1, 1]
    (a pseudo-inverse's rounding), NaN in the rows and columns of a parameter whose
    variance is zero (the data do not move it: its correlation is undefined)."""
    c = np.asarray(cov, dtype=float)
    sd = np.sqrt(np.maximum(np.diag(c), 0.0))
    live = sd > 1e-12 * max(float(sd.max(initial=0.0)), 1e-300)
    out = np.full(c.shape, np.nan)
    ix = np.ix_(live, live)
    out[ix] = np.clip(c[ix] / np.outer(sd[live], sd[live]), -1.0, 1.0)
    return out


def fit_model(
    problem: Problem,
    effects: Sequence[str],
    *,
    starts: Sequence[Mapping[str, float]] = (),
    bias: Mapping[int, dict[str, FloatArray]] | None = None,
    local_only: bool = False,
    box: Mapping[str, tuple[float, float]] | None = None,
    screen: bool = False,
) -> ModelFit:
    """Fit one model's parameters on the training windows and score it on the held-out ones.

    The fit is :func:`scipy.optimize.least_squares` with the robust loss
    :attr:`AttributionSettings.loss` and ``f_scale`` = :attr:`Problem.f_scale`,
    inside each parameter's physical bounds (its ``ParamSpec``).

    Parameters
    ----------
    problem : Problem
    effects : sequence of str
        Effect names of the model (empty: the reference model, i.e. the
        calibrated baseline when there is one).
    starts : sequence of mappings
        Extra start points ``{"effect.param": value}`` (e.g. single-effect optima).
    bias : mapping, optional
        Per-log surrogate bias replacing the nominal one (PyBullet defect correction).
    local_only : bool
        Skip the grid; refine from ``starts`` only.
    box : mapping of key to (low, high), optional
        Narrower bounds (natural units) for some parameters, inside their
        physical bounds (the baseline's nuisance ranges).
    screen : bool
        A screening fit: the baseline nuisances stay at their calibrated values. It
        costs a fraction of the full fit, and its training cost is an upper bound on the full fit's (the full fit
        has more freedom): it ranks candidates, and
        :func:`~realitygap.diagnosis.fit.candidates.fit_candidates` fits fully those that
        can still change the answer. The result is marked ``screened``.
    """
    settings = problem.settings
    held = problem.held_parameters(effects)
    keys = tuple(k for k in model_keys(effects) if k not in held)
    p = len(keys)
    tr, ho = problem.train, problem.holdout
    if p == 0:
        z_tr = problem.surrogate_residuals(tr, {}, 1, bias)[0]
        z_ho = problem.surrogate_residuals(ho, {}, 1, bias)[0] if ho.n else np.zeros(0)
        return _finish(
            problem, tuple(effects), keys, np.zeros(0), z_tr, z_ho, np.zeros((0, 0)), held=held
        )
    lo_u, hi_u = np.zeros(p), np.ones(p)
    for j, k in enumerate(keys):
        if box and k in box:
            a, b = sorted((range_position(k, box[k][0]), range_position(k, box[k][1])))
            lo_u[j], hi_u[j] = max(a, 0.0), min(b, 1.0)
            if hi_u[j] <= lo_u[j]:
                raise ValueError(
                    f"fit_model: box for {k!r} ({box[k][0]:g} … {box[k][1]:g}) lies outside its "
                    f"physical bounds ({param_spec(k).low:g} … {param_spec(k).high:g})"
                )
    loss, c = settings.loss, problem.f_scale
    # baseline nuisances the model does not fit itself: refined with it inside their ranges
    nuis = tuple(
        k
        for k in problem.baseline_ranges
        if k not in keys and k in problem.baseline_values and not screen
    )
    q = len(nuis)
    all_keys = keys + nuis
    lo_n = np.array([range_position(k, problem.baseline_ranges[k][0]) for k in nuis])
    hi_n = np.array([range_position(k, problem.baseline_ranges[k][1]) for k in nuis])
    lo_n, hi_n = np.minimum(lo_n, hi_n), np.maximum(lo_n, hi_n)
    u_base = np.array([range_position(k, problem.baseline_values[k]) for k in nuis])
    for st in starts:
        if all(k in st for k in nuis):
            u_base = np.array([range_position(k, float(st[k])) for k in nuis])
    u_base = np.clip(u_base, lo_n, hi_n)

    def residual_batch(U: FloatArray, layout: Any) -> FloatArray:
        if U.shape[1] == p + q:
            return problem.surrogate_residuals(layout, _values(all_keys, U), U.shape[0], bias)
        return problem.surrogate_residuals(layout, _values(keys, U), U.shape[0], bias)

    def _cost(U: FloatArray, layout: Any) -> FloatArray:
        """Robust training cost of each row of ``U`` (model parameters only)."""
        out = np.empty(U.shape[0])
        for a in range(0, U.shape[0], 128):
            z = residual_batch(U[a : a + 128], layout)
            out[a : a + 128] = np.sum(_rho(z**2, loss, c), axis=1)
        return out

    seed = settings.seed + sum(ord(c_) for c_ in "".join(effects))
    rng = np.random.default_rng(seed)
    # start points over the model's parameters and the baseline nuisances: a start keeps
    # the nuisances it was found with (a single effect's optimum refined them with it),
    # the grid takes ``u_base``; each is scored at the very point it would start from
    cand: list[FloatArray] = []
    for st in starts:
        u = np.array([range_position(k, float(st.get(k, param_spec(k).nominal))) for k in keys])
        own = all(k in st for k in nuis)
        u_n = np.array([range_position(k, float(st[k])) for k in nuis]) if own else u_base
        cand.append(np.concatenate([np.clip(u, lo_u, hi_u), np.clip(u_n, lo_n, hi_n)]))
    u_nom = np.clip(np.array([range_position(k, param_spec(k).nominal) for k in keys]), lo_u, hi_u)
    if not local_only:
        G = np.vstack([lo_u + _grid(keys, settings, rng) * (hi_u - lo_u), u_nom[None]])
        U = np.vstack([np.hstack([G, np.tile(u_base, (G.shape[0], 1))]), *cand])
        costs = _cost(U, tr)
        if p == 1:
            # a step-like parameter (a dead zone or a speed limit among the commanded
            # speeds) makes the training cost a staircase whose treads can be narrower
            # than the grid's spacing, and the local refinement's gradient is zero on a
            # tread: scan finely around the best few grid points first
            step = float(hi_u[0] - lo_u[0]) / (settings.grid_points - 1)
            U, costs = _refine_one(U, costs, lo_u, hi_u, step, lambda V: _cost(V, tr))
        order = np.argsort(costs)
        picks: list[FloatArray] = []
        for idx in order:
            # distinct in the model's parameters (the nuisances only follow them)
            if all(np.max(np.abs(U[idx, :p] - q[:p])) > 0.08 * np.max(hi_u - lo_u) for q in picks):
                picks.append(U[idx])
            if len(picks) >= 3:
                break
        cand = picks
    if not cand:
        cand = [np.concatenate([u_nom, u_base])]

    h = 1e-3
    cache: dict[bytes, FloatArray] = {}
    # the local refinement runs over the model's parameters and the baseline nuisances
    lo_u, hi_u = np.concatenate([lo_u, lo_n]), np.concatenate([hi_u, hi_n])
    n_all = p + q

    def fun(u: FloatArray) -> FloatArray:
        key = u.tobytes()
        if key not in cache:
            cache[key] = residual_batch(u[None], tr)[0]
        return cache[key]

    def differences(u: FloatArray, cols: Sequence[int]) -> FloatArray:
        """Forward differences (n, len(cols)) of the training residual at ``u``."""
        steps = np.where(u[list(cols)] + h <= hi_u[list(cols)], h, -h)
        U = np.repeat(u[None], len(cols), axis=0)
        U[np.arange(len(cols)), list(cols)] += steps
        z0 = fun(u)
        return ((residual_batch(U, tr) - z0) / steps[:, None]).T

    # The nuisances are small corrections (a clock offset of milliseconds, a frame
    # offset of millimetres) on which the residual depends almost linearly, and
    # barely through the model's parameters: their Jacobian columns are taken once
    # per start and kept (a Broyden-like quasi-Newton step in those directions); the
    # model's columns are differenced at every step. The residual itself is always
    # exact, so the optimum is the same to the tolerance's order.
    frozen: dict[str, FloatArray] = {}

    def jac(u: FloatArray) -> FloatArray:
        J = np.empty((tr.n, n_all))
        if p:
            J[:, :p] = differences(u, range(p))
        if q:
            if "nuisance" not in frozen:
                frozen["nuisance"] = differences(u, range(p, n_all))
            J[:, p:] = frozen["nuisance"]
        return J

    # least_squares needs strictly feasible starts and lower < upper
    span = np.maximum(hi_u - lo_u, 1e-12)
    best = None
    tol = settings.fit_tolerance
    for u0 in cand:
        u0 = np.clip(u0, lo_u + 1e-9 * span, hi_u - 1e-9 * span)
        frozen.clear()
        try:
            res = least_squares(
                fun,
                u0,
                jac=jac,
                bounds=(lo_u, hi_u),
                x_scale=0.1 * span,
                max_nfev=30 * n_all,
                # a refinement from a given optimum starts in its basin, where the
                # nuisances (time shifts of nearly one signature) leave the problem
                # ill-conditioned: dogbox's rectangular trust region converges there in
                # a few steps where trf's ellipsoidal one crawls along the valley
                method="dogbox" if local_only else "trf",
                loss=loss,
                f_scale=c,
                xtol=tol,
                ftol=tol,
            )
        except (ValueError, np.linalg.LinAlgError):  # pragma: no cover - defensive
            continue
        if best is None or res.cost < best.cost:
            best = res
    assert best is not None
    u_all = _toward_nominal(
        lambda U: np.sum(_rho(residual_batch(U, tr) ** 2, loss, c), axis=1),
        best.x,
        np.concatenate([u_nom, best.x[p:]]),
        p,
    )
    z_tr = fun(u_all)
    J = differences(u_all, range(p))
    z_ho = residual_batch(u_all[None], ho)[0] if ho.n else np.zeros(0)
    nuisance = {
        k: float(from_range_position(k, np.array([u_all[p + j]]))[0]) for j, k in enumerate(nuis)
    }
    fit = _finish(
        problem, tuple(effects), keys, u_all[:p], z_tr, z_ho, J, nuisance=nuisance, held=held
    )
    fit.screened = screen
    return fit


def _refine_one(
    U: FloatArray,
    costs: FloatArray,
    lo: FloatArray,
    hi: FloatArray,
    step: float,
    cost: Callable[[FloatArray], FloatArray],
    n_best: int = 3,
    n_fine: int = 33,
) -> tuple[FloatArray, FloatArray]:
    """Points ``U`` (n, 1 + q) of a one-parameter grid of spacing ``step`` (column 0; the
    other columns, baseline nuisances, ride along) with their ``costs``, and a fine scan of
    ``n_fine`` values of column 0 across one step on either side of each of the ``n_best``
    lowest costs, within ``lo[0]`` … ``hi[0]`` (the points and their costs appended)."""
    best = U[np.argsort(costs)[:n_best]]
    fine = np.repeat(best, n_fine, axis=0)
    fine[:, 0] = np.clip(
        (best[:, :1] + np.linspace(-step, step, n_fine)[None]).ravel(), lo[0], hi[0]
    )
    fine = np.unique(fine, axis=0)
    return np.vstack([U, fine]), np.concatenate([costs, cost(fine)])


def _toward_nominal(
    cost: Callable[[FloatArray], FloatArray], u: FloatArray, u_nom: FloatArray, p: int
) -> FloatArray:
    """Move each of the first ``p`` parameters towards nominal while the training cost
    stays where it is.

    A parameter on a plateau of the training cost (a dead band or dead zone between the
    commanded speeds the training logs hold, a speed limit above all of them) is
    identified only up to an interval; of that interval the training data support the
    smallest effect, the end nearest "no effect", and nothing more (the other end is a
    guess the held-out data may refute). Smooth parameters do not move: any step raises
    the cost.
    """
    u = u.copy()
    c0 = float(cost(u[None])[0])
    tol = 1e-9 * (1.0 + abs(c0))
    for j in range(p):
        d = u_nom[j] - u[j]
        if abs(d) < 1e-9:
            continue
        steps = np.linspace(1.0, 0.0, 17)[:-1]  # nominal first, the fitted value excluded
        U = np.repeat(u[None], steps.size, axis=0)
        U[:, j] = u[j] + steps * d
        ok = cost(U) <= c0 + tol
        if not ok.any():
            continue
        lo = float(steps[np.flatnonzero(ok)[0]])  # furthest step that keeps the cost
        hi = float(steps[np.flatnonzero(ok)[0] - 1]) if np.flatnonzero(ok)[0] > 0 else lo
        for _ in range(8):  # bisect between the last good and the first bad step
            if hi <= lo:
                break
            mid = 0.5 * (lo + hi)
            v = u.copy()
            v[j] = u[j] + mid * d
            if float(cost(v[None])[0]) <= c0 + tol:
                lo = mid
            else:
                hi = mid
        u[j] = u[j] + lo * d
    return u


def _finish(
    problem: Problem,
    effects: tuple[str, ...],
    keys: tuple[str, ...],
    u_hat: FloatArray,
    z_tr: FloatArray,
    z_ho: FloatArray,
    J_u: FloatArray,
    verified: bool = False,
    nuisance: Mapping[str, float] | None = None,
    held: Mapping[str, str] | None = None,
) -> ModelFit:
    settings = problem.settings
    p = len(keys)
    n = max(z_tr.shape[0], 1)
    values = {k: float(from_range_position(k, np.array([u_hat[j]]))[0]) for j, k in enumerate(keys)}
    # parameters the training data cannot identify stay at nominal (not findings)
    values.update({k: float(param_spec(k).nominal) for k in held or {}})
    stderr: dict[str, float] = {}
    corr = np.eye(p)
    if p and J_u.shape[-1] == p:
        scale = np.array([range_derivative(k, values[k]) for k in keys])
        J = J_u / scale[None, :]
        dof = max(n - p, 1)
        s2 = float(np.sum(z_tr**2)) / dof
        try:
            cov = s2 * np.linalg.pinv(J.T @ J)
            sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
            stderr = {k: float(sd[j]) for j, k in enumerate(keys)}
            corr = np.nan_to_num(parameter_correlation(cov), nan=0.0)
        except np.linalg.LinAlgError:  # pragma: no cover - pinv does not raise in practice
            stderr = {k: math.inf for k in keys}
    effect_sizes = _effect_sizes(problem, effects, values) if p else {}
    stderr.update({k: math.nan for k in held or {}})
    # the calibrated baseline travels with every model (PyBullet replays use it)
    base = {**problem.baseline_values, **(nuisance or {})}
    values = {**{k: v for k, v in base.items() if k not in values}, **values}
    floor = settings.score_floor
    train_score = float(profile_score(z_tr, problem.train, floor))
    bic = train_score + p * math.log(n)
    if z_ho.size:
        ho_score = float(profile_score(z_ho, problem.holdout, floor))
        ho_rms = float(np.sqrt(np.mean(z_ho**2)))
    else:
        ho_score, ho_rms = math.nan, math.nan
    return ModelFit(
        effects=effects,
        keys=keys,
        values=values,
        stderr=stderr,
        corr=corr,
        train_score=train_score,
        bic=bic,
        heldout_score=ho_score,
        rank_score=ho_score + p * math.log(n),
        heldout_rms=ho_rms,
        z_heldout=z_ho,
        verified=verified,
        n_train=n,
        effect_sizes=effect_sizes,
        held=dict(held or {}),
    )


def _effect_sizes(
    problem: Problem, effects: Sequence[str], values: Mapping[str, float]
) -> dict[str, float]:
    """How much each effect of a fitted model changes the predicted training features.

    RMS (feature-scale units) of the surrogate's features at the fitted point
    minus the same with that effect's parameters put back to nominal.
    """
    keys = list(values)
    rows = [dict(values)]
    for e in effects:
        row = dict(values)
        for k in keys:
            if split_key(k)[0] == e:
                row[k] = param_spec(k).nominal
        rows.append(row)
    batch = {k: np.array([r[k] for r in rows]) for k in keys}
    z = problem.surrogate_residuals(problem.train, batch, len(rows))
    return {e: float(np.sqrt(np.mean((z[j + 1] - z[0]) ** 2))) for j, e in enumerate(effects)}
