"""Optional compilation of small numeric kernels with Numba (the ``fast`` extra).

A kernel is written once, in plain Python on floats and NumPy arrays, and kept
callable as such: that is the reference and the path taken when Numba is not
installed. :func:`compiled` returns its Numba-compiled twin, or ``None`` without
Numba. Callers choose the compiled twin only when :func:`use_compiled` says so, so
that both paths run the same inputs in tests (:func:`numpy_only`).

Kernels are compiled with IEEE semantics (no ``fastmath``: no reassociation and no
fused multiply-add), so a kernel that performs the same operations in the same
order as its NumPy formulation gives the same bits; they are cached on disk
(``cache=True``), so only the first process after an install pays the compilation.
Setting the environment variable ``REALITYGAP_DISABLE_JIT=1`` keeps every caller
on NumPy.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

__all__ = [
    "DISABLE_JIT_ENV",
    "KERNELS",
    "compiled",
    "numba_available",
    "numpy_only",
    "use_compiled",
]

F = TypeVar("F", bound=Callable[..., Any])

DISABLE_JIT_ENV = "REALITYGAP_DISABLE_JIT"
"""Environment variable: set to ``1`` to keep every kernel on its NumPy path."""

_numba: Any = None
if os.environ.get(DISABLE_JIT_ENV, "0") in ("", "0"):
    try:  # the optional ``fast`` extra
        import numba as _numba
    except ImportError:  # pragma: no cover - exercised where numba is absent
        _numba = None


class KernelSwitch:
    """Whether callers take the compiled kernels, as the attribute :attr:`on`: hot paths read
    ``KERNELS.on`` (an attribute, no call), elsewhere :func:`use_compiled` says the same."""

    __slots__ = ("on",)

    def __init__(self, on: bool) -> None:
        self.on = on


KERNELS = KernelSwitch(_numba is not None)
"""The one switch: on where Numba is installed and not disabled, off inside :func:`numpy_only`."""


def numba_available() -> bool:
    """Whether Numba is installed (``pip install realitygap[fast]``) and not disabled by
    :data:`DISABLE_JIT_ENV` (which keeps it from being imported at all)."""
    return _numba is not None


def use_compiled() -> bool:
    """Whether callers take the compiled kernels: Numba is installed, not disabled by
    :data:`DISABLE_JIT_ENV` and not inside :func:`numpy_only`."""
    return KERNELS.on


@contextmanager
def numpy_only() -> Iterator[None]:
    """Within the block every caller takes its NumPy path (to compare the two)."""
    before = KERNELS.on
    KERNELS.on = False
    try:
        yield
    finally:
        KERNELS.on = before


def compiled(fn: F) -> F | None:
    """``fn`` compiled by Numba (lazily, on its first call; cached on disk), or ``None``
    when Numba is not installed. ``fn`` itself is left unchanged."""
    if _numba is None:
        return None
    # the GIL is kept: the kernels take microseconds in the thread that calls them, where
    # releasing and taking it back again would cost a noticeable share of the call
    return _numba.njit(cache=True, error_model="numpy")(fn)
