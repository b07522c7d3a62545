"""Fixtures shared by the diagnosis tests (the suite imports test modules in importlib
mode, so shared helpers live here as fixtures)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from realitygap.diagnosis.fit.model import ModelFit


def _model_fit(
    effects: tuple[str, ...], z: np.ndarray, values: dict[str, float] | None = None
) -> ModelFit:
    """A fitted model with held-out residual ``z`` and parameter ``values`` (standard error
    0.01 each, uncorrelated); scores zero."""
    values = dict(values or {})
    return ModelFit(
        effects,
        tuple(values),
        values,
        {k: 0.01 for k in values},
        np.eye(len(values)),
        0.0,
        0.0,
        0.0,
        0.0,
        float(np.sqrt(np.mean(np.asarray(z) ** 2))),
        z,
    )


@pytest.fixture
def model_fit() -> Callable[..., ModelFit]:
    """Build a :class:`ModelFit` from effects, a held-out residual and parameter values."""
    return _model_fit
