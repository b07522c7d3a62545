"""Reading comma-separated numeric text files, with errors that name the file, line and column.

Used by the OptiOdom importer (:mod:`.optiodom`), which parses whole files of
numbers; a malformed row is reported precisely (slow path only on failure).
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

__all__ = [
    "locate_bad_row",
    "make_readonly",
    "numeric_file",
    "numeric_rows",
    "read_text_lines",
    "whole_ticks",
]


def read_text_lines(path: Path) -> list[str]:
    """The lines of a UTF-8 text file (a BOM is dropped); ``ValueError`` naming the file if it
    cannot be read or is not UTF-8 text."""
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise ValueError(f"{path}: cannot read file ({exc})") from exc
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: expected UTF-8 text, {exc}") from exc
    return text.splitlines()


def locate_bad_row(
    path: Path, numbered: list[tuple[int, str]], columns: tuple[str, ...]
) -> ValueError:
    """Build the error for the first malformed row (slow path)."""
    n = len(columns)
    for line_no, line in numbered:
        fields = line.split(",")
        if len(fields) != n:
            return ValueError(
                f"{path}, line {line_no}: expected {n} comma-separated fields "
                f"({', '.join(columns)}), got {len(fields)}: {line.strip()!r}"
            )
        for col, text in enumerate(fields):
            try:
                value = float(text)
            except ValueError:
                return ValueError(
                    f"{path}, line {line_no}, column {col + 1} ({columns[col]}): expected a "
                    f"number, got {text.strip()!r}"
                )
            if not math.isfinite(value):
                return ValueError(
                    f"{path}, line {line_no}, column {col + 1} ({columns[col]}): expected a "
                    f"finite number, got {text.strip()!r}"
                )
    return ValueError(f"{path}: could not parse the numeric rows ({', '.join(columns)})")


def numeric_rows(
    path: Path, numbered: list[tuple[int, str]], columns: tuple[str, ...]
) -> FloatArray:
    """Parse ``(line_no, text)`` rows of ``len(columns)`` numbers each."""
    n = len(columns)
    if not numbered:
        return np.zeros((0, n))
    try:
        data = np.loadtxt(
            io.StringIO("\n".join(line for _, line in numbered)),
            delimiter=",",
            ndmin=2,
            dtype=float,
        )
    except ValueError:
        raise locate_bad_row(path, numbered, columns) from None
    if data.shape != (len(numbered), n) or not np.all(np.isfinite(data)):
        raise locate_bad_row(path, numbered, columns)
    return data


def numeric_file(path: Path, columns: tuple[str, ...]) -> FloatArray:
    """Every non-empty line of ``path`` as a row of ``len(columns)`` finite numbers."""
    lines = read_text_lines(path)
    numbered = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip()]
    if not numbered:
        raise ValueError(
            f"{path}: empty file, expected rows of {len(columns)} comma-separated numbers "
            f"({', '.join(columns)})"
        )
    return numeric_rows(path, numbered, columns)


def whole_ticks(path: Path, values: FloatArray, column: str, first_line: int = 1) -> IntArray:
    """``values`` as int64 tick counts; ``ValueError`` naming the line of the first fraction."""
    rounded = np.rint(values)
    bad = np.flatnonzero(np.abs(values - rounded) > 1e-9)
    if bad.size:
        i = int(bad[0])
        raise ValueError(
            f"{path}, line {first_line + i}: column {column} must hold whole tick counts, "
            f"got {values[i]!r}"
        )
    return rounded.astype(np.int64)


def make_readonly(*arrays: np.ndarray | None) -> None:
    """Mark the given arrays (``None`` skipped) read-only."""
    for a in arrays:
        if a is not None:
            a.flags.writeable = False
