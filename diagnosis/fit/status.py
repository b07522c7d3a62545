"""Which fitted parameters are findings: pinned at the far edge of their range, at a bound,
on a flat stretch of the training cost, or held at nominal.

A parameter the fit stretched to the edge of its plausible range (:func:`pinned_parameters`)
is absorbing a gap it does not cause; one the logs cannot move (:func:`parameter_status`)
is not measured by them. Neither gets an error bar. The held-out tests of the verdict
(:mod:`realitygap.diagnosis.verdict.judge`), its rules and the library's reach
(:mod:`realitygap.diagnosis.stages.reach`) ask these questions alike.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.problem.parameters import param_spec, range_position
from realitygap.diagnosis.problem.problem import Problem

FloatArray = npt.NDArray[np.float64]

__all__ = ["parameter_status", "pinned_parameters"]


def pinned_parameters(problem: Problem, fit: ModelFit) -> list[str]:
    """Parameters of ``fit`` that sit at the far edge of their plausible range and matter.

    An effect fitted at the bound of its plausible range (the end away from "no
    effect") is being stretched to absorb a gap it does not cause. "At the
    bound" is within 0.5 % of the range in the coordinates the fit searches
    (:func:`~realitygap.diagnosis.problem.parameters.range_position`: logarithmic for a
    parameter spanning decades, such as a speed limit). Parameters
    the logs cannot see (moving them back to nominal changes the training
    residual by less than the floor) are ignored.
    """
    out = []
    point = {k: np.array([v]) for k, v in fit.values.items()}
    base: FloatArray | None = None
    for key, value in fit.values.items():
        spec = param_spec(key)
        if not (math.isfinite(spec.low) and math.isfinite(spec.high)):
            continue
        # in the coordinates the fit searches (log units for a range of decades)
        u = range_position(key, value)
        at_low = spec.low != spec.nominal and u < 0.005
        at_high = spec.high != spec.nominal and u > 0.995
        if not (at_low or at_high):
            continue
        if base is None:
            base = problem.surrogate_residuals(problem.train, point, 1)[0]
        alt = problem.surrogate_residuals(
            problem.train, {**point, key: np.array([spec.nominal])}, 1
        )[0]
        if float(np.sqrt(np.mean((alt - base) ** 2))) > problem.settings.floor:
            out.append(key)
    return out


def parameter_status(problem: Problem, fit: ModelFit, step: float = 0.25) -> dict[str, str]:
    """Which fitted parameters are not findings: ``"at bound"`` or ``"untestable"``.

    A parameter sits *at a bound* when it lies within 0.5 % of its range from
    either end of its physical range (in the coordinates the fit searches:
    logarithmic for a parameter spanning decades), unless that end is its nominal value
    (a lag of 0 s, a dead zone of 0 m/s: the part of the effect is absent, not
    stretched to a limit). It is *untestable* when the training data
    are flat around it: moving it towards either bound by ``step`` of the
    distance to that bound changes no training window by more than the noise
    floor (a speed limit far above anything the robot was commanded, a dead
    zone below every command); *one-sided* when only one of the two moves
    changes anything (the logs bound it on one side only: a speed limit just
    above the fastest command). Parameters the fit held at nominal because the
    training data cannot identify them (:attr:`ModelFit.held`) are *not
    identifiable*. A calibrated-baseline nuisance refined with the model
    (``problem.baseline_ranges``) that ends at an edge of its nuisance range,
    other than its "no effect" value, is a *nuisance at range bound*: the
    baseline is absorbing part of a gap the model leaves. None of these gets an
    error bar.
    """
    held = {k: "not identifiable" for k in fit.held}
    # calibrated-baseline nuisances refined with the model, pinned at an end of their range
    for k, (a, b) in problem.baseline_ranges.items():
        if k in fit.keys or k not in fit.values:
            continue
        lo, hi = min(a, b), max(a, b)
        v, nominal, near = fit.values[k], param_spec(k).nominal, 0.005 * (hi - lo)
        if hi > lo and any(abs(v - e) < near and abs(nominal - e) >= near for e in (lo, hi)):
            held[k] = "nuisance at range bound"
    if not fit.keys:
        return held
    keys = list(fit.keys)
    pts: list[dict[str, float]] = [dict(fit.values)]
    for k in keys:
        spec = param_spec(k)
        v = fit.values[k]
        for end in (spec.low, spec.high):
            moved = v + step * (end - v) if math.isfinite(end) else v
            pts.append({**fit.values, k: float(moved)})
    batch = {k: np.array([pt[k] for pt in pts]) for k in keys}
    z = problem.surrogate_residuals(problem.train, batch, len(pts))
    out: dict[str, str] = {}
    for j, k in enumerate(keys):
        spec = param_spec(k)
        span = spec.high - spec.low
        v = fit.values[k]
        change = [float(np.max(np.abs(z[1 + 2 * j + e] - z[0]))) for e in (0, 1)]
        near = 0.005
        finite = math.isfinite(span)
        # positions in the range, in the coordinates the fit searches (log units for decades)
        u = range_position(k, v) if finite else 0.5
        u_nom = range_position(k, spec.nominal) if finite else 0.5
        # "no effect" may sit at a bound (a lag of 0 s): there the fit is absent, not pinned
        nominal_is_bound = min(u_nom, 1.0 - u_nom) < near
        at_nominal_end = nominal_is_bound and abs(u - u_nom) < near
        if finite and min(u, 1.0 - u) < near and not at_nominal_end:
            out[k] = "at bound"
        elif at_nominal_end:  # only the move away from nominal can show anything
            if max(change) < problem.settings.floor:
                out[k] = "untestable"
        elif max(change) < problem.settings.floor:
            out[k] = "untestable"
        elif min(change) < problem.settings.floor:
            out[k] = "one-sided"
    return {**out, **held}
