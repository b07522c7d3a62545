"""Pieces shared by the environments."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt


def check_twist_action(action: npt.ArrayLike) -> tuple[float, float]:
    """Validate a normalised ``(v, ω)`` action and clip it to ``[-1, 1]``.

    Raises ``ValueError`` for a wrong shape or a non-finite entry (a NaN action would
    otherwise drive the simulation into NaN states silently).
    """
    a = np.asarray(action, dtype=np.float64).reshape(-1)
    if a.shape != (2,):
        raise ValueError(f"action must have shape (2,), got {np.shape(action)}")
    if not (math.isfinite(a[0]) and math.isfinite(a[1])):
        raise ValueError(f"action must be finite, got {a.tolist()}")
    return min(1.0, max(-1.0, float(a[0]))), min(1.0, max(-1.0, float(a[1])))
