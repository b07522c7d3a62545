"""Verification: a second effect is named only if it improves the held-out residual."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np

from realitygap.diagnosis.verify import heldout_gain_significant


def _fit(z: Any) -> Any:
    return SimpleNamespace(z_heldout=np.asarray(z, dtype=float))


def test_heldout_gain_counts_only_beyond_noise() -> None:
    rng = np.random.default_rng(4)
    noise = rng.normal(0.0, 1.0, 2000)
    single = _fit(noise + 0.5)  # a systematic part the second effect removes
    assert heldout_gain_significant(_fit(noise), single)
    # a second effect that only reshuffles noise (held-out residual as large as before)
    jiggle = _fit(noise + rng.normal(0.0, 0.05, noise.size))
    assert not heldout_gain_significant(jiggle, _fit(noise))
    # a model that is worse on held-out data never counts
    assert not heldout_gain_significant(single, _fit(noise))
    # the threshold is the paired standard error: a tiny but consistent gain counts
    assert heldout_gain_significant(_fit(0.99 * noise), _fit(noise))
    # no held-out residual: nothing to judge by, the gain is taken as given
    assert heldout_gain_significant(_fit([]), _fit([]))
