"""Discovery: a planted term is recovered with its coefficient, pure noise yields nothing."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.diagnosis.stages.discovery import DiscoverySettings, fit_terms

NAMES = ["v", "w", "dv", "dw", "|v|", "sign_w", "v*w", "t"]
UNITS = ["m/s", "rad/s", "m/s²", "rad/s²", "m/s", "", "m·rad/s²", "s"]


def _features(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.uniform(-0.5, 0.5, n)
    w = rng.uniform(-1.5, 1.5, n)
    dv = rng.normal(0.0, 0.5, n)
    dw = rng.normal(0.0, 2.0, n)
    t = np.linspace(0.0, 60.0, n)
    return np.column_stack([v, w, dv, dw, np.abs(v), np.sign(w), v * w, t])


def test_recovers_planted_term() -> None:
    rng = np.random.default_rng(3)
    X, Xh = _features(rng, 400), _features(rng, 200)
    noise = 0.004
    y = 0.012 * X[:, 3] + rng.normal(0, noise, 400)
    yh = 0.012 * Xh[:, 3] + rng.normal(0, noise, 200)
    fit = fit_terms(X, y, Xh, yh, NAMES, UNITS, groups=np.arange(400) // 80, unit="rad")
    assert fit.found
    assert [t["term"] for t in fit.terms] == ["dw"]
    assert fit.terms[0]["coef"] == pytest.approx(0.012, rel=0.05)
    # the planted term carries ~ 0.024 rad of 0.0247 rad RMS: the held-out shrink is large
    assert fit.heldout_shrink_pct > 60.0
    assert "dw" in fit.phrase() and "rad" in fit.phrase()


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_pure_noise_finds_nothing(seed: int) -> None:
    rng = np.random.default_rng(seed)
    X, Xh = _features(rng, 300), _features(rng, 150)
    y, yh = rng.normal(0, 0.01, 300), rng.normal(0, 0.01, 150)
    fit = fit_terms(X, y, Xh, yh, NAMES, UNITS, groups=np.arange(300) // 60)
    assert not fit.found


def test_selection_uses_heldout_not_training_fit() -> None:
    # a residual that is a pure function of time in training but not in held-out data:
    # whatever the training fit picks must not count as a finding
    rng = np.random.default_rng(5)
    X, Xh = _features(rng, 300), _features(rng, 150)
    y = 0.02 * np.sin(X[:, 7]) + rng.normal(0, 0.002, 300)
    yh = rng.normal(0, 0.01, 150)
    fit = fit_terms(X, y, Xh, yh, NAMES, UNITS, groups=np.arange(300) // 60)
    assert not fit.found


def test_shapes_are_checked() -> None:
    with pytest.raises(ValueError, match="expected X"):
        fit_terms(np.zeros((10, 2)), np.zeros(10), np.zeros((5, 3)), np.zeros(5), NAMES, UNITS)
    with pytest.raises(ValueError, match="min_shrink"):
        DiscoverySettings(min_shrink=1.5)
