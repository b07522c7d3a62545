"""Building blocks shared by the planar extended Kalman filters.

:func:`joseph_update` is the EKF measurement update in Joseph form and
:func:`all_finite` the guard the filters apply to every input (the planar
rotation and its generator are :mod:`realitygap.core.geometry`'s
``rotation_2d`` and ``SKEW_2D``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

__all__ = ["all_finite", "joseph_update"]


def all_finite(*values: Any) -> bool:
    """Whether every value converts to a float array with only finite entries."""
    try:
        return all(bool(np.all(np.isfinite(np.asarray(v, dtype=float)))) for v in values)
    except (TypeError, ValueError):
        return False


def joseph_update(
    x: FloatArray, P: FloatArray, innovation: FloatArray, H: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray, float]:
    """EKF update in Joseph form; returns the new state, covariance and NIS."""
    S = H @ P @ H.T + R
    S = 0.5 * (S + S.T)
    K = np.linalg.solve(S, H @ P).T
    nis = float(innovation @ np.linalg.solve(S, innovation))
    x_new = x + K @ innovation
    I_KH = np.eye(P.shape[0]) - K @ H
    P_new = I_KH @ P @ I_KH.T + K @ R @ K.T
    return x_new, 0.5 * (P_new + P_new.T), nis
