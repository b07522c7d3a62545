"""Physical quantities in words: a value in the engineering units a person reads, rounded
to what its uncertainty resolves.

:func:`quantity` is the one place where a fitted value gets its human form (lengths in mm,
times in ms, angles in degrees, ratios plain); the report's sentences and tables
(:mod:`realitygap.diagnosis.report.summary`) and the stages that put values into words
(:mod:`realitygap.diagnosis.stages.reach`) use it alike.
"""

from __future__ import annotations

import math

__all__ = ["ENGINEERING_UNITS", "quantity"]

ENGINEERING_UNITS: dict[str, tuple[str, float]] = {
    "m": ("mm", 1e3),
    "s": ("ms", 1e3),
    "rad": ("°", 180.0 / math.pi),
    "rad/s": ("°/s", 180.0 / math.pi),
    "m/s": ("mm/s", 1e3),
}
"""SI unit → (the unit a value is shown in, the factor to it)."""


def _digits(step: float) -> int:
    """Decimals that show ``step`` with two significant digits (0 … 6)."""
    if not (math.isfinite(step) and step > 0):
        return 3
    return int(min(6, max(0, 1 - math.floor(math.log10(step)))))


def quantity(value: float, unit: str, stderr: float | None = None) -> str:
    """``value`` (SI ``unit``) in engineering units, rounded to what ``stderr`` resolves.

    Lengths go to mm, times to ms, angles to degrees; ratios (unit ``"1"``) stay
    plain. With a finite ``stderr`` the value keeps two significant digits of the
    uncertainty and the uncertainty is shown (``"1.70 ± 0.21 ms"``); without one,
    three significant digits.

    Examples
    --------
    >>> quantity(0.0017, "s", 0.00021)
    '1.70 ± 0.21 ms'
    >>> quantity(1.008, "1")
    '1.01'
    >>> quantity(1.0712, "m")
    '1.07 m'
    """
    if not math.isfinite(value):
        return f"{value} {unit}".strip()
    shown_unit, factor = ENGINEERING_UNITS.get(unit, ("" if unit == "1" else unit, 1.0))
    if factor > 1.0 and abs(value * factor) >= 1e3:
        shown_unit, factor = unit, 1.0  # 1.07 m, not 1.07e+03 mm
    v = value * factor
    if stderr is not None and math.isfinite(stderr) and stderr > 0:
        e = stderr * factor
        nd = _digits(e)
        text = f"{v:.{nd}f} ± {e:.{nd}f}"
    else:
        text = f"{v:.3g}" if abs(v) >= 1e-3 or v == 0 else f"{v:.2e}"
    sep = "" if shown_unit in ("°", "°/s", "") else " "
    return f"{text}{sep}{shown_unit}" if shown_unit else text
