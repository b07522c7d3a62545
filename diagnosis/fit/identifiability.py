"""Can the logged motions tell two explanations apart, and which motion would?

:func:`identifiability` compares two fitted models through the correlation of
their parameters in the surrogate's finite-difference Jacobian on the
training windows; when they are confounded it tries each probe manoeuvre of
the robot adapter and names the one that separates them best, described for the logs' robot
(:meth:`~realitygap.diagnosis.adapters.contract.RobotAdapter.probe_description`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.fit.model import ModelFit, parameter_correlation
from realitygap.diagnosis.problem.parameters import (
    from_range_position,
    model_keys,
    param_spec,
    split_key,
)
from realitygap.diagnosis.problem.problem import Problem
from realitygap.estimators.arm.identifiability import analyse_identifiability

FloatArray = npt.NDArray[np.float64]

__all__ = ["dependent_parameters", "identifiability", "jacobian"]


def jacobian(
    residual: Callable[[dict[str, FloatArray]], FloatArray],
    keys: Sequence[str],
    point: Mapping[str, float],
) -> FloatArray:
    """Finite-difference Jacobian (n, p) of a batched residual in natural parameter units."""
    p = len(keys)
    steps = []
    for k in keys:
        spec = param_spec(k)
        h = 1e-3 * (spec.high - spec.low)
        if spec.log_scale:
            h = 1e-3 * max(point[k], 0.2)
        steps.append(h if point[k] + h <= spec.high else -h)
    # row 0: the point; row j + 1: the point with key j stepped
    batch = {
        k: np.array([point[k]] + [point[k] + (steps[i] if i == j else 0.0) for j in range(p)])
        for i, k in enumerate(keys)
    }
    z = residual(batch)
    return ((z[1:] - z[0]) / np.asarray(steps)[:, None]).T


def _corr(J: FloatArray) -> FloatArray:
    """Parameter correlations of a Jacobian (n, p) (:func:`parameter_correlation`), its
    columns scaled to unit norm first so that the pseudo-inverse's cut-off does not depend
    on the parameters' units; NaN for a parameter the residual does not depend on."""
    norms = np.linalg.norm(J, axis=0)
    live = norms > 1e-12 * max(float(norms.max(initial=0.0)), 1e-300)
    out = np.full((J.shape[1], J.shape[1]), np.nan)
    if live.any():
        Jn = J[:, live] / norms[live]
        out[np.ix_(live, live)] = parameter_correlation(np.linalg.pinv(Jn.T @ Jn))
    return out


def _cross(C: FloatArray, a: Sequence[int], b: Sequence[int]) -> float:
    """Largest |correlation| between a parameter of ``a`` and one of ``b`` (0 when none is
    defined)."""
    vals = [abs(C[i, j]) for i in a for j in b if np.isfinite(C[i, j])]
    return float(max(vals, default=0.0))


def identifiability(problem: Problem, a: ModelFit, b: ModelFit) -> dict[str, Any]:
    """Can the logged motions tell model ``a`` from ``b``? Which motion would?"""
    effects = tuple(dict.fromkeys(a.effects + b.effects))
    keys = model_keys(effects)
    point: dict[str, float] = {}
    for k in keys:
        point[k] = param_spec(k).nominal
    point.update(b.values)
    point.update(a.values)

    def train_res(batch: dict[str, FloatArray]) -> FloatArray:
        n = len(next(iter(batch.values())))
        return problem.surrogate_residuals(problem.train, batch, n)

    J = jacobian(train_res, keys, point)
    C = _corr(J)
    ka = [j for j, k in enumerate(keys) if split_key(k)[0] in a.effects]
    kb = [j for j, k in enumerate(keys) if split_key(k)[0] not in a.effects]
    cross = _cross(C, ka, kb)
    out: dict[str, Any] = {
        "effects": [a.name, b.name],
        "correlation": float(cross),
        "separable": bool(cross < problem.settings.confound_corr),
    }
    if out["separable"]:
        return out
    best = None
    ref = problem.logs[0]
    probes = problem.adapter.probe_manoeuvres()
    for name in probes:

        def probe_res(batch: dict[str, FloatArray], name: str = name) -> FloatArray:
            feats, groups = problem.adapter.probe_features(name, ref, batch)
            parts = [
                (feats[g] / problem.features.scale(g)).reshape(feats[g].shape[0], -1)
                for g in groups
            ]
            return np.concatenate(parts, axis=1)

        Jm = jacobian(probe_res, keys, point)
        Cm = _corr(np.vstack([J, Jm]))
        cross_m = _cross(Cm, ka, kb)
        if best is None or cross_m < best[1]:
            best = (name, cross_m)
    assert best is not None
    description = problem.adapter.probe_description(best[0], ref)
    out["separating_motion"] = {
        "name": best[0],
        "description": description,
        "correlation_after": float(best[1]),
    }
    out["message"] = (
        f"the logged motions cannot tell {a.name} from {b.name} (parameter correlation "
        f"{cross:.2f}); recording '{best[0]}' ({description}) would "
        f"separate them (correlation {best[1]:.2f})"
    )
    return out


def dependent_parameters(
    problem: Problem, keys: Sequence[str], rank_tol: float = 1e-6
) -> dict[str, str]:
    """Parameters of ``keys`` the training windows cannot identify, with the reason.

    The Jacobian of the training residuals by the parameters at nominal (central
    differences of the surrogate, a step of 1e-4 of each physical range; one-sided
    where nominal is a bound) goes through the identifiability analysis of the
    kinematic identification
    (:func:`~realitygap.estimators.arm.identifiability.analyse_identifiability`):
    in the order of ``keys``, a parameter whose unit-scaled column adds less than
    ``rank_tol`` of a new direction to the ones admitted before it is not
    identifiable (no effect on the training features, or a linear combination of
    parameters admitted before it: e.g. a wrist offset when the wrist joint stands
    still in every training pose). Meant for parameters the features depend on
    linearly near nominal (small geometric errors); a saturation limit that only
    acts away from nominal would look unidentifiable here. A parameter silent at
    nominal that acts only through another parameter of its effect (the load a
    compliance turns into sag, nothing without the compliance) takes its column
    where the others of its effect act, at the middle of their ranges.

    Parameters
    ----------
    problem : Problem
    keys : sequence of str
        ``"effect.param"`` keys, most wanted first.
    rank_tol : float
        Admission threshold (fraction of a unit column outside the admitted span).

    Returns
    -------
    dict of str to str
        ``{key: reason}`` of the parameters to hold at nominal.
    """
    keys = list(keys)
    if not keys:
        return {}
    if not 0.0 < rank_tol < 1.0:
        raise ValueError(f"dependent_parameters: rank_tol must lie in (0, 1), got {rank_tol!r}")
    rows: list[dict[str, float]] = []
    steps = []
    nominal = {k: float(param_spec(k).nominal) for k in keys}
    for k in keys:
        spec = param_spec(k)
        h = 1e-4 * (spec.high - spec.low)
        up = nominal[k] + h <= spec.high
        down = nominal[k] - h >= spec.low
        hi = nominal[k] + h if up else nominal[k]
        lo = nominal[k] - h if down else nominal[k]
        rows += [{**nominal, k: hi}, {**nominal, k: lo}]
        steps.append(hi - lo)
    batch = {k: np.array([r[k] for r in rows]) for k in keys}
    z = problem.surrogate_residuals(problem.train, batch, len(rows))
    J = ((z[0::2] - z[1::2]) / np.asarray(steps)[:, None]).T
    # a parameter that moves the training residual by less than 1e-6 feature-scale units
    # (RMS) over its whole physical range has no effect: its column is difference noise
    spans = np.array([param_spec(k).high - param_spec(k).low for k in keys])
    silent = np.sqrt(np.mean(J**2, axis=0)) * spans < 1e-6
    for j in np.flatnonzero(silent):
        # a parameter that acts only through another of its effect (a load that a
        # compliance turns into sag) is silent at nominal: its column is taken where the
        # others of its effect act, at the middle of their ranges
        others = [o for o in keys if o != keys[j] and split_key(o)[0] == split_key(keys[j])[0]]
        if not others:
            continue
        at = {**nominal, **{o: float(from_range_position(o, np.array([0.5]))[0]) for o in others}}
        pair = {k: np.array([at[k], at[k]]) for k in keys}
        pair[keys[j]] = np.array([rows[2 * j][keys[j]], rows[2 * j + 1][keys[j]]])
        zj = problem.surrogate_residuals(problem.train, pair, 2)
        col = (zj[0] - zj[1]) / steps[j]
        if float(np.sqrt(np.mean(col**2))) * spans[j] >= 1e-6:
            J[:, j], silent[j] = col, False
    J[:, silent] = 0.0
    ana = analyse_identifiability(J, keys, rank_tol)
    out = {}
    for k in ana.fixed:
        if ana.reasons[k].startswith("linearly dependent"):
            out[k] = "a linear combination of the parameters before it on the training data"
        else:
            out[k] = "no effect on the training data"
    return out
