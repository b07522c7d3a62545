"""How one cell of a text table reads: a number (either decimal mark), a missing value, an
ISO 8601 date (as POSIX seconds), or text (:func:`cell_number`)."""

from __future__ import annotations

import math
import re
from datetime import datetime, timezone

__all__ = ["DEC_COMMA", "ISO_SPACE", "NAN_WORDS", "cell_number", "iso_seconds", "numeric_share"]

NAN_WORDS = frozenset({"", "nan", "-nan", "na", "n/a", "null", "none"})
"""Cells that mean a missing value."""
DEC_COMMA = re.compile(r"^\s*[-+]?\d+,\d+([eE][-+]?\d+)?\s*$")
"""A number written with a decimal comma."""
_COMMA_NUMBER = re.compile(r"^[-+]?(\d{1,3}(\.\d{3})+|\d*),\d+([eE][-+]?\d+)?$")
_ISO = re.compile(
    r"^(\d{4})-(\d{2})-(\d{2})(?:[T ](\d{2}):(\d{2})(?::(\d{2})([.,]\d+)?)?)?"
    r"\s*(Z|[+-]\d{2}(?::?\d{2})?)?$"
)
ISO_SPACE = re.compile(r"(\d{4}-\d{2}-\d{2}) (\d{2}:\d{2})")
"""A date and a time separated by a space (which a whitespace table must not split)."""


def iso_seconds(text: str) -> float | None:
    """POSIX seconds of an ISO 8601 date or date-time (UTC unless it names a zone), else None."""
    m = _ISO.match(text)
    if m is None:
        return None
    y, mo, d, h, mi, s, frac, tz = m.groups()
    try:
        when = datetime(int(y), int(mo), int(d), int(h or 0), int(mi or 0), int(s or 0))
    except ValueError:
        return None
    value = when.replace(tzinfo=timezone.utc).timestamp()
    if frac:
        value += float("0." + frac[1:])
    if tz and tz != "Z":
        digits = tz[1:].replace(":", "")
        offset = int(digits[:2]) * 3600 + (int(digits[2:4]) * 60 if len(digits) > 2 else 0)
        value -= offset if tz[0] == "+" else -offset
    return value


def cell_number(text: str, decimal: str) -> float | None:
    """The value of a cell, NaN for a missing one, None for text."""
    s = text.strip().strip('"').strip()
    if s.lower() in NAN_WORDS:
        return math.nan
    if decimal == "," and _COMMA_NUMBER.match(s):
        s = s.replace(".", "").replace(",", ".")
    try:
        return float(s)
    except ValueError:
        return iso_seconds(s)


def numeric_share(fields: list[str], decimal: str | None) -> float:
    """Share of ``fields`` that are numbers, dates or missing (either decimal mark if None)."""
    if not fields:
        return 0.0
    marks = (".", ",") if decimal is None else (decimal,)
    good = sum(any(cell_number(f, m) is not None for m in marks) for f in fields)
    return good / len(fields)
