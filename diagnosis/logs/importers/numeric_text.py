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

from realitygap.core.checks import check_regular_file

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

__all__ = [
    "check_last_line",
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
    if path.exists():
        check_regular_file(path, "file")  # a FIFO would block the read forever
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
    """Every non-empty line of ``path`` as a row of ``len(columns)`` finite numbers.

    A last line without its newline that looks cut off (:func:`check_last_line`) is
    an error.
    """
    lines = read_text_lines(path)
    numbered = [(i + 1, ln) for i, ln in enumerate(lines) if ln.strip()]
    if not numbered:
        raise ValueError(
            f"{path}: empty file, expected rows of {len(columns)} comma-separated numbers "
            f"({', '.join(columns)})"
        )
    check_last_line(path, numbered, columns)
    return numeric_rows(path, numbered, columns)


def check_last_line(
    path: Path, numbered: list[tuple[int, str]], columns: tuple[str, ...], window: int = 20
) -> None:
    """Refuse a file whose last line has no newline and looks cut off mid-write.

    A writer killed mid-line leaves e.g. ``…,51,6`` for ``…,51,66``: the line
    still parses, silently wrong. When the file does not end with a newline, the
    last line must have as many fields as the header's ``columns`` and no field
    narrower than the same field in every one of the ``window`` lines before it.

    Raises
    ------
    ValueError
        Naming the file, the line, the field and the fix.
    """
    try:
        with open(path, "rb") as fh:
            fh.seek(0, 2)
            if fh.tell() == 0:
                return
            fh.seek(-1, 2)
            if fh.read(1) in (b"\n", b"\r"):
                return
    except OSError:
        return
    line_no, last = numbered[-1]
    fields = last.split(",")
    fix = "Fix: delete the last line, or end the file with a newline if the line is complete"
    if len(fields) != len(columns):
        raise ValueError(
            f"{path}, line {line_no}: the last line has no newline and {len(fields)} of "
            f"{len(columns)} fields ({', '.join(columns)}): the file looks cut off. {fix}"
        )
    before = [ln.split(",") for _, ln in numbered[-window - 1 : -1]]
    before = [b for b in before if len(b) == len(fields)]
    if not before:
        return
    for j, cell in enumerate(fields):
        narrowest = min(len(b[j].strip()) for b in before)
        if len(cell.strip()) < narrowest:
            raise ValueError(
                f"{path}, line {line_no}: the last line has no newline and its field "
                f"{columns[j]} ({cell.strip()!r}) is narrower than in every line before it: "
                f"the file looks cut off mid-write. {fix}"
            )


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
