"""Gains through the origin with an honest error: how a measured quantity scales with the
asked one (a wheel's speed with its command), for a scatter that is correlated in time.

The gap budget (:mod:`~realitygap.diagnosis.budget`) reads residuals at run and window
scale; this module keeps the one statistic the actuation description needs.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

__all__ = ["autocorrelation_widening", "gain_through_origin"]


def autocorrelation_widening(
    d: FloatArray, max_autocorrelation: float = 0.9
) -> tuple[float, float]:
    r"""Lag-1 autocorrelation :math:`ρ` of deviations ``d`` (in order, clipped to
    ``[0, max_autocorrelation]``) and the factor :math:`\sqrt{(1+ρ)/(1-ρ)}` by which it
    widens the standard error of a mean or a slope over them."""
    d = np.asarray(d, dtype=float)
    den = float(d @ d)
    rho = float(d[1:] @ d[:-1]) / den if den > 0 else 0.0
    rho = min(max(rho, 0.0), max_autocorrelation)
    return rho, math.sqrt((1.0 + rho) / (1.0 - rho))


def gain_through_origin(real: FloatArray, asked: FloatArray) -> tuple[float, float]:
    r"""Least-squares slope :math:`g = r·a / a·a` of ``real`` on ``asked`` through the
    origin, and its standard error from the scatter about it, widened for the scatter's
    lag-1 autocorrelation (:func:`autocorrelation_widening`); NaN error with fewer than
    three points, NaN slope when nothing was asked."""
    r, a = np.asarray(real, dtype=float), np.asarray(asked, dtype=float)
    aa = float(a @ a)
    if aa <= 0.0:
        return math.nan, math.nan
    g = float(r @ a) / aa
    if a.size < 3:
        return g, math.nan
    res = r - g * a
    _, widen = autocorrelation_widening(res)
    return g, math.sqrt(float(res @ res) / (a.size - 1) / aa) * widen
