"""Pieces shared by the environments: action checks and constructor-argument checks."""

from __future__ import annotations

import ctypes
import ctypes.util
import math
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.checks import check_finite_float, check_positive_int

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "MAX_PHYSICS_HZ",
    "check_action_array",
    "check_bool",
    "check_rates",
    "check_twist_action",
    "release_freed_memory",
]

MAX_PHYSICS_HZ = 10_000.0
"""Highest physics rate an env accepts (Hz): beyond it a second of simulation takes minutes."""


def release_freed_memory() -> None:
    """Hand memory freed by the C heap back to the operating system (glibc only; else nothing).

    A PyBullet client with a large triangle mesh (the climber's blade) frees its
    tens of megabytes on disconnect, but glibc keeps them in fragmented arenas, so
    making and closing envs in a loop grows the resident size by ~2 MB per env;
    ``malloc_trim(0)`` returns them.
    """
    global _LIBC
    if _LIBC is None:
        try:
            _LIBC = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
            _LIBC.malloc_trim  # noqa: B018  (glibc has it; musl and macOS do not)
        except (OSError, AttributeError):
            _LIBC = False
    if _LIBC:
        _LIBC.malloc_trim(0)


_LIBC: Any = None


def check_action_array(action: Any, shape: tuple[int, ...], name: str = "action") -> FloatArray:
    """``action`` as a finite float64 array of ``shape``.

    Raises
    ------
    TypeError
        Strings, ``None`` or objects that are not numbers, naming the expected
        dtype and shape.
    ValueError
        A wrong shape or a NaN/inf entry.
    """
    raw = np.asarray(action) if not isinstance(action, (str, bytes)) else None
    if raw is None or raw.dtype.kind not in "biuf":
        got = type(action).__name__ if raw is None else f"dtype {raw.dtype}"
        expected = f"a float array of shape {shape} with entries in [-1, 1]"
        raise TypeError(f"{name} must be {expected}, got {got}: {action!r:.60}")
    a = np.asarray(raw, dtype=np.float64)  # no copy for a float64 action (the hot path)
    if not np.isfinite(a).all():
        raise ValueError(f"{name} must be finite, got {a.reshape(-1).tolist()}")
    if a.size != math.prod(shape):
        expected = f"a float array of shape {shape} with entries in [-1, 1]"
        raise ValueError(f"{name} must be {expected}, got shape {raw.shape}")
    return a.reshape(shape)


def check_twist_action(action: npt.ArrayLike) -> tuple[float, float]:
    """Validate a normalised ``(v, ω)`` action and clip it to ``[-1, 1]``.

    Raises ``TypeError`` for a non-numeric action and ``ValueError`` for a wrong
    shape or a non-finite entry (a NaN action would otherwise drive the simulation
    into NaN states silently).
    """
    if type(action) is np.ndarray and action.shape == (2,) and action.dtype.char in "fde":
        # the hot path (a policy's float array): the same checks on two floats
        a0, a1 = action.tolist()
        if -1.0 <= a0 <= 1.0 and -1.0 <= a1 <= 1.0:  # within the box (NaN is not): as is
            return a0, a1
        if math.isfinite(a0) and math.isfinite(a1):
            return min(1.0, max(-1.0, a0)), min(1.0, max(-1.0, a1))
    a = check_action_array(action, (2,))  # any other form, and the errors
    return min(1.0, max(-1.0, float(a[0]))), min(1.0, max(-1.0, float(a[1])))


def check_bool(value: Any, name: str) -> bool:
    """``value`` if it is a ``bool`` (or NumPy bool), else ``TypeError``."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be True or False, got {value!r} ({type(value).__name__})")
    return bool(value)


def check_rates(physics_hz: Any, control_hz: Any) -> tuple[float, float, int]:
    """Physics and control rates (Hz) and the physics sub-steps per control step.

    Raises
    ------
    TypeError, ValueError
        Non-numbers, NaN, rates ≤ 0, ``physics_hz`` above :data:`MAX_PHYSICS_HZ`,
        or a ratio that is not a positive whole number.
    """
    ph = check_finite_float(
        physics_hz, "physics_hz", low=0.0, high=MAX_PHYSICS_HZ, strict_low=True, unit="Hz"
    )
    too_fast = isinstance(control_hz, (int, float)) and control_hz > ph
    ch = check_finite_float(
        control_hz,
        "control_hz",
        low=0.0,
        high=ph,
        strict_low=True,
        unit="Hz",
        fix="the control rate cannot exceed physics_hz" if too_fast else "",
    )
    ratio = ph / ch
    if abs(ratio - round(ratio)) > 1e-9:
        raise ValueError(
            f"physics_hz / control_hz must be a positive whole number, got {ph:g} / {ch:g} = "
            f"{ratio:g}. Fix: choose a control rate that divides the physics rate"
        )
    return ph, ch, check_positive_int(round(ratio), "physics_hz / control_hz")
