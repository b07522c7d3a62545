"""Verification: a second effect is named only if it improves the held-out residual."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np

from realitygap.diagnosis.verify import heldout_gain_counts


def _fit(z: Any) -> Any:
    return SimpleNamespace(z_heldout=np.asarray(z, dtype=float))


def test_heldout_gain_counts_only_beyond_noise() -> None:
    rng = np.random.default_rng(4)
    noise = rng.normal(0.0, 1.0, 2000)
    single = _fit(noise + 0.5)  # a systematic part the second effect removes
    assert heldout_gain_counts(_fit(noise), single)
    # a second effect that only reshuffles noise (held-out residual as large as before)
    jiggle = _fit(noise + rng.normal(0.0, 0.05, noise.size))
    assert not heldout_gain_counts(jiggle, _fit(noise))
    # a model that is worse on held-out data never counts
    assert not heldout_gain_counts(single, _fit(noise))
    # a tiny but consistent gain counts (beyond the paired standard error) ...
    assert heldout_gain_counts(_fit(0.99 * noise), _fit(noise))
    # ... and so does a large one that few windows cannot prove (one window in ten)
    few = np.zeros(30)
    few[::10] = rng.normal(0.0, 3.0, 3) + 2.0
    assert heldout_gain_counts(_fit(np.zeros(30)), _fit(few))
    # no held-out residual: nothing to judge by, the gain is taken as given
    assert heldout_gain_counts(_fit([]), _fit([]))
