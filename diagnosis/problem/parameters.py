"""The parameters of candidate effects, and the coordinates the fits search them in.

A model's parameters are keyed ``"effect.param"`` (:func:`model_keys`); each has
a :class:`~realitygap.robots.effects.ParamSpec` with its physical range
(:func:`param_spec`). Fits search every parameter on ``[0, 1]`` over that range
(:func:`range_position` and back, :func:`from_range_position`), logarithmically
for a parameter whose range spans decades, so that a step means the same
relative change everywhere in it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.robots.effects import EFFECTS, Reality, make_effect

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "from_range_position",
    "model_keys",
    "param_spec",
    "range_derivative",
    "range_position",
    "reality_from_values",
    "split_key",
]


def model_keys(effects: Sequence[str]) -> tuple[str, ...]:
    """``"effect.param"`` keys of a model's parameters, in effect order."""
    return tuple(f"{e}.{s.name}" for e in effects for s in EFFECTS[e].specs)


def param_spec(key: str) -> Any:
    """The :class:`~realitygap.robots.effects.ParamSpec` of ``"effect.param"``."""
    effect, param = split_key(key)
    for s in EFFECTS[effect].specs:
        if s.name == param:
            return s
    raise KeyError(key)


def range_position(key: str, x: float) -> float:
    """Where ``x`` sits in the physical range of ``"effect.param"``: 0 at the low bound, 1 at
    the high one, in the coordinates the fit searches (logarithmic for a parameter that spans
    decades, so that a speed limit of 0.085 m/s in 0.05 … 10 m/s is a tenth of the way up,
    not at the low end)."""
    s = param_spec(key)
    if s.log_scale:
        return float((math.log(x) - math.log(s.low)) / (math.log(s.high) - math.log(s.low)))
    return float((x - s.low) / (s.high - s.low))


def from_range_position(key: str, u: FloatArray) -> FloatArray:
    """The values at range positions ``u`` of ``"effect.param"`` (inverse of
    :func:`range_position`)."""
    s = param_spec(key)
    if s.log_scale:
        return np.exp(np.log(s.low) + u * (np.log(s.high) - np.log(s.low)))
    return s.low + u * (s.high - s.low)


def range_derivative(key: str, x: float) -> float:
    """``dx/du`` of ``"effect.param"`` at the value ``x``: how much the value moves per unit of
    range position (turns a fit's standard error in ``u`` into one in SI units)."""
    s = param_spec(key)
    if s.log_scale:
        return x * (math.log(s.high) - math.log(s.low))
    return s.high - s.low


def split_key(key: str) -> tuple[str, str]:
    """``"effect.param"`` → ``("effect", "param")``."""
    effect, _, param = key.partition(".")
    return effect, param


def reality_from_values(values: Mapping[str, float]) -> Reality:
    """A :class:`Reality` from ``{"effect.param": value}`` (effects in first-seen order)."""
    grouped: dict[str, dict[str, float]] = {}
    for key, v in values.items():
        effect, param = split_key(key)
        grouped.setdefault(effect, {})[param] = float(v)
    return Reality(tuple(make_effect(name, **vals) for name, vals in grouped.items()))
