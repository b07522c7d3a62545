"""How a line of a text table splits into cells (:func:`splitter`, :func:`split_fields`)
and how one cell reads: a number (either decimal mark), a missing value, an
ISO 8601 date (as POSIX seconds), or text (:func:`cell_number`)."""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path

from realitygap.core.checks import ResourceLimits
from realitygap.diagnosis.logs.log import LogError

__all__ = [
    "DEC_COMMA",
    "ISO_SPACE",
    "NAN_WORDS",
    "THOUSANDS",
    "cell_number",
    "iso_seconds",
    "numeric_share",
]

NAN_WORDS = frozenset({"", "nan", "-nan", "na", "n/a", "null", "none"})
"""Cells that mean a missing value."""
DEC_COMMA = re.compile(r"^\s*[-+]?\d+,\d+([eE][-+]?\d+)?\s*$")
"""A number written with a decimal comma."""
THOUSANDS = re.compile(r"^[-+]?\d{1,3}(,\d{3})+(\.\d+)?$")
"""A number with ',' between groups of three digits (``19,548``, ``1,234,567.5``): how a
spreadsheet exports large numbers, quoted, in a comma-separated file with '.' decimals."""
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


def cell_number(text: str, decimal: str, thousands: bool = False) -> float | None:
    """The value of a cell, NaN for a missing one, None for text.

    ``thousands``: a cell of a comma-separated file with '.' decimals, where a comma inside a
    cell was quoted: digit groups of three (:data:`THOUSANDS`, ``"19,548"``) are one number.
    """
    s = text.strip().strip('"').strip()
    if s.lower() in NAN_WORDS:
        return math.nan
    if decimal == "," and _COMMA_NUMBER.match(s):
        s = s.replace(".", "").replace(",", ".")
    elif thousands and decimal == "." and THOUSANDS.match(s):
        s = s.replace(",", "")
    try:
        return float(s)
    except ValueError:
        return iso_seconds(s)


def numeric_share(fields: list[str], decimal: str | None, thousands: bool = False) -> float:
    """Share of ``fields`` that are numbers, dates or missing (either decimal mark if None;
    ``thousands`` as in :func:`cell_number`)."""
    if not fields:
        return 0.0
    marks = (".", ",") if decimal is None else (decimal,)
    good = sum(any(cell_number(f, m, thousands) is not None for m in marks) for f in fields)
    return good / len(fields)


def splitter(delim: str, iso_space: bool = False) -> Callable[[str], list[str]]:
    """A function that splits one line (without its line break) into fields."""
    if delim == " ":

        def split_ws(line: str) -> list[str]:
            return (ISO_SPACE.sub(r"\1T\2", line) if iso_space else line).split()

        return split_ws
    if delim == "|":

        def split_bar(line: str) -> list[str]:
            s = line.strip()
            s = s[1:] if s.startswith("|") else s
            s = s[:-1] if s.endswith("|") else s
            return s.split("|")

        return split_bar

    def split_csv(line: str) -> list[str]:
        if '"' in line:
            try:
                return next(csv.reader([line], delimiter=delim), [])
            except csv.Error as exc:  # the parser's own error: told with the file and line
                raise SplitError(str(exc)) from None
        return line.split(delim)

    return split_csv


class SplitError(ValueError):
    """A line the CSV parser refuses (the caller adds the file and line)."""


def split_fields(
    split: Callable[[str], list[str]], path: Path, line_no: int, text: str, lim: ResourceLimits
) -> list[str]:
    """``split(text)``, refusing a cell longer than ``lim.max_cell_chars`` and a line the
    CSV parser cannot read, with the file, line and cause."""
    try:
        fields = split(text)
    except SplitError as exc:
        raise LogError(
            f"{path}, line {line_no}: the CSV parser cannot read this line ({exc}): "
            f"{text.strip()!r:.80}. Fix: close the quotes of that line, or export the file again"
        ) from None
    longest = max((len(f) for f in fields), default=0)
    if longest > lim.max_cell_chars:
        j = next(j for j, f in enumerate(fields) if len(f) == longest)
        raise LogError(
            f"{path}, line {line_no}, field {j + 1}: a cell of {longest:,} characters "
            f"({fields[j].strip()[:40]!r}…), more than the {lim.max_cell_chars // 1024} KiB a "
            "table cell may hold; a table's cells are numbers or short text. Fix: drop that "
            "column from the export (an image or blob field), or raise the limit with the "
            "environment variable REALITYGAP_MAX_CELL_KB"
        )
    return fields
