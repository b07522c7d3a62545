"""Read any numeric table file as named columns: :func:`read_table` → :class:`Table`.

A table is a file of rows of numbers: a CSV export, a whitespace-aligned text
dump, a MATLAB ``.mat`` file or a NumPy ``.npz`` archive. :func:`read_table`
turns each into the same :class:`Table` — column names, a float64 array and the
line of the file each row came from — so that an importer that maps columns to
a log's channels points its errors at the file's own line and column.

Text files
----------
* **Delimiter** (``,`` ``;`` tab ``|`` or runs of whitespace): the one that
  splits most sample lines into the same number of mostly numeric fields.
  ``|`` tables may have leading / trailing bars (markdown, psql); their
  separator rows (``|---|---|``, ``-----+----``) and a psql ``(N rows)`` footer
  are skipped.
* **Header**: the line just above the first block of lines with a constant
  field count that are mostly numbers, when it has that field count (in a
  whitespace-aligned file, names may also be separated by runs of two or more
  spaces, so that a name may hold one space). Lines above it (a title,
  ``key: value`` lines) are skipped and kept in :attr:`Table.skipped`. A file
  whose first data line is numeric has no header; its columns are named
  ``"0"``, ``"1"``, …
* **Comments**: lines starting with ``#`` or ``%`` are skipped wherever they
  are; a comment line just above the data with the right field count is the
  header (``rostopic echo -p`` writes ``%time,field.header.stamp,…``).
* **Decimal comma**: detected in ``;``-, tab-, ``|``- and whitespace-separated
  files (never in comma-separated ones, where it would be ambiguous).
* **Cells**: numbers; empty, ``nan``, ``NA``, ``null`` → NaN; ISO 8601 dates
  and date-times (``2023-05-01T12:00:00.125``, also with a space, a ``Z`` or an
  offset) → POSIX seconds (UTC when no zone is given); any other text → NaN,
  with its first occurrence per column in :attr:`Table.text_columns` (a text
  column does not make the file unreadable; a consumer that maps it says so).
* **Errors** (:class:`~realitygap.diagnosis.logs.log.LogError`, naming the file and
  line): a row with another field count than the header (with the likely cause: an
  empty cell in a whitespace-aligned file, decimal commas in a comma-separated one),
  a last line cut off mid-write (no newline, a field narrower than in every row
  before it), a file with no line of numbers.
* UTF-8 (with or without a byte-order mark), UTF-16 or UTF-32 with a byte-order
  mark (little- or big-endian), else latin-1. The file size, the length of each line
  and cell, and rows × columns are checked against
  :class:`~realitygap.core.checks.ResourceLimits` before anything is allocated; an
  error of the CSV parser is reported with the file and line, never passed on.

Binary files
------------
MATLAB v4–v7 ``.mat`` files (:func:`scipy.io.loadmat`, which creates plain
arrays and never runs code) and NumPy ``.npz`` archives (read without
unpickling, array headers checked first): every 1-D numeric vector is a column
named by its variable, a 2-D numeric matrix ``M`` (n × k) gives the columns
``M[0]`` … ``M[k-1]``, and a struct's numeric fields are ``struct.field``. The
vectors of the longest length form the table; the others, and arrays that are
not columns (3-D arrays, scalars, text, cell arrays), are named in
:attr:`Table.skipped`. A saved realitygap log (``Log.save``) is refused: it is
read by :func:`~realitygap.diagnosis.logs.read.read_logs` without a column map.
"""

from __future__ import annotations

import csv
import difflib
import math
import os
import re
from collections import Counter
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from realitygap.core.checks import (
    ResourceLimits,
    check_regular_file,
    check_rows_limit,
    text_encoding_of,
)
from realitygap.diagnosis.logs.importers.table_cells import (
    DEC_COMMA,
    ISO_SPACE,
    SplitError,
    cell_number,
    numeric_share,
    split_fields,
    splitter,
)
from realitygap.diagnosis.logs.log import LogError, sniff_file_kind

__all__ = ["DELIMITERS", "Table", "check_format", "read_table"]

DELIMITERS: dict[str, str] = {
    ",": "comma",
    ";": "semicolon",
    "\t": "tab",
    "|": "bar",
    " ": "whitespace",  # any run of spaces or tabs
}
"""The delimiters :func:`read_table` knows, with their names for messages."""

_ALIASES = {"tab": "\t", "\\t": "\t", "space": " ", "whitespace": " ", "comma": ",", "pipe": "|"}
_PRIORITY = ("\t", ";", "|", ",", " ")  # on a tie, the more specific delimiter wins
_SEPARATOR = re.compile(r"^[\s|+:=-]*[-=]{2,}[\s|+:=-]*$")
_FOOTER = re.compile(r"^\(\d+ rows?\)$")
HEAD_LINES = 400
"""Lines of a text file looked at to find its layout (delimiter, header, decimal mark)."""


@dataclass(frozen=True)
class Table:
    """A numeric table read from a file.

    Attributes
    ----------
    source : Path
        The file.
    names : tuple of str
        Column names: the header's, or ``"0"``, ``"1"``, … when the file has none.
    data : ndarray, shape (n_rows, n_cols)
        float64, NaN for empty, missing or text cells; read-only.
    lines : ndarray, shape (n_rows,)
        int64, the 1-based line of the file of each row (row index + 1 for binary formats).
    kind : {"text", "mat", "npz"}
    delimiter : str or None
        ``","``, ``";"``, ``"\\t"``, ``"|"`` or ``" "`` (any run of whitespace); None for binary.
    decimal : {".", ","}
    skipped : tuple of str
        Lines above the header (title, preamble, comments), and for binary files the
        variables that are not columns, with the reason.
    has_header : bool
    text_columns : mapping of str to (int, str)
        Column name → (line, text) of its first cell that is not a number.
    decimals : tuple of int
        Text files: per column, the most digits written after the decimal mark in the
        first :data:`DECIMALS_ROWS` rows (the resolution the values were written with);
        empty for binary files.
    encoding : str
        Text files: the encoding read (``"UTF-8"``, ``"latin-1"``, ``"UTF-16 LE"`` …);
        empty for binary files.
    units : tuple of str
        Per column, the unit a units row under the header gives (``""`` where it gives
        none); empty when the file has no units row.
    """

    source: Path
    names: tuple[str, ...]
    data: np.ndarray
    lines: np.ndarray
    kind: str
    delimiter: str | None
    decimal: str
    skipped: tuple[str, ...] = ()
    has_header: bool = True
    text_columns: Mapping[str, tuple[int, str]] = field(default_factory=dict)
    decimals: tuple[int, ...] = ()
    encoding: str = ""
    units: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        data = np.asarray(self.data, dtype=np.float64).view()
        lines = np.asarray(self.lines, dtype=np.int64).view()
        if data.ndim != 2 or data.shape[1] != len(self.names) or lines.shape != data.shape[:1]:
            raise ValueError(
                f"Table: data {data.shape}, {len(self.names)} names and lines {lines.shape} "
                "do not match (expected data (n_rows, n_names) and lines (n_rows,))"
            )
        data.flags.writeable = False
        lines.flags.writeable = False
        object.__setattr__(self, "data", data)
        object.__setattr__(self, "lines", lines)
        object.__setattr__(self, "names", tuple(self.names))
        object.__setattr__(self, "text_columns", MappingProxyType(dict(self.text_columns)))

    @property
    def n_rows(self) -> int:
        """Number of rows."""
        return int(self.data.shape[0])

    def index(self, column: str | int) -> int:
        """The 0-based index of ``column``: a name, or a 0-based index (also as digits).

        Raises
        ------
        LogError
            Naming the file, the column asked for, the close matches and the header.
        """
        n = len(self.names)
        if isinstance(column, (int, np.integer)) and not isinstance(column, bool):
            if 0 <= int(column) < n:
                return int(column)
            raise LogError(
                f"{self.source}: column index {int(column)} is out of range: the file has {n} "
                f"column(s), 0..{n - 1} ({self._header_text()}). Fix: give a 0-based index "
                "below the column count, or a column name"
            )
        text = str(column)
        for cand in (text, text.strip()):
            if cand in self.names:
                return self.names.index(cand)
        if text.strip().isdigit() and int(text) < n:
            return int(text)
        folded = [nm for nm in self.names if nm.casefold() == text.strip().casefold()]
        close = folded or difflib.get_close_matches(text.strip(), self.names, n=3, cutoff=0.6)
        hint = f" (did you mean {' or '.join(repr(c) for c in close)}?)" if close else ""
        above = ""
        if not self.has_header and self.skipped:
            above = f"; lines skipped above the data: {' | '.join(self.skipped[-3:])!r:.200}"
        raise LogError(
            f"{self.source}: no column {text!r}{hint}; {self._header_text()}{above}. Fix: use "
            "one of these names (or a 0-based column index)"
        )

    def column(self, column: str | int) -> np.ndarray:
        """The values of ``column`` (a name or 0-based index), read-only."""
        return self.data[:, self.index(column)]

    def _header_text(self) -> str:
        names = ", ".join(repr(nm) for nm in self.names[:40])
        more = f", … ({len(self.names)} in all)" if len(self.names) > 40 else ""
        if self.has_header:
            return f"the {'header' if self.kind == 'text' else 'file'} has {names}{more}"
        return f"the file has no header row; its columns are {names}{more}"


# ------------------------------------------------------------------------------ cells
# ------------------------------------------------------------------------------ text layout
class _DecodeError(LogError):
    """Text that is not in the encoding it was read with."""


def _max_line_chars(lim: ResourceLimits) -> int:
    """Longest line read: a wide table's row, far below what would exhaust memory."""
    return max(8 * 2**20, 4 * lim.max_cell_chars)


def _lines(fh: Any, path: Path, lim: ResourceLimits) -> Iterator[tuple[int, str]]:
    """``(line, raw text)`` of an open text file, refusing a line longer than
    :func:`_max_line_chars` before it is read whole."""
    limit = _max_line_chars(lim)
    line_no = 0
    while True:
        try:
            raw = fh.readline(limit + 1)
        except UnicodeDecodeError as exc:
            raise _DecodeError(
                f"{path}, after line {line_no}: cannot be decoded as {fh.encoding} ({exc.reason})."
                " Fix: save the file as UTF-8 text"
            ) from None
        if not raw:
            return
        line_no += 1
        if len(raw) > limit and not raw.endswith(("\n", "\r")):
            raise LogError(
                f"{path}, line {line_no}: longer than {limit:,} characters (a table row is "
                "far shorter; is this a binary file, or one without line breaks?). Fix: pass a "
                "table with one row per line, or raise REALITYGAP_MAX_CELL_KB"
            )
        yield line_no, raw


def _is_significant(stripped: str) -> bool:
    """A line that holds data or a header: not blank, a comment, a separator row or a footer."""
    if not stripped or stripped[0] in "#%":
        return False
    return not (_SEPARATOR.match(stripped) or _FOOTER.match(stripped))


@dataclass
class _Scan:
    head: list[tuple[int, str]]  # (line, text) of the first lines: significant and comments
    n_significant: int
    last: tuple[int, str]
    ends_newline: bool


def _scan(path: Path, encoding: str, lim: ResourceLimits) -> _Scan:
    """One streaming pass: the first lines, the count of data-like lines, the last one."""
    head: list[tuple[int, str]] = []
    n = 0
    last = (0, "")
    ends_newline = False
    with open(path, encoding=encoding, newline="") as fh:
        for line_no, raw in _lines(fh, path, lim):
            ends_newline = raw.endswith(("\n", "\r"))
            text = raw.rstrip("\r\n")
            stripped = text.strip()
            if _is_significant(stripped):
                n += 1
                last = (line_no, text)
            elif not stripped or stripped[0] not in "#%":
                continue
            if len(head) < HEAD_LINES:
                head.append((line_no, text))
    return _Scan(head, n, last, ends_newline)


@dataclass
class _Layout:
    delimiter: str
    decimal: str
    width: int
    names: tuple[str, ...] | None  # None: no header
    header_line: int  # the header's line, or the line before the first data line
    skipped: tuple[str, ...]
    trailing: bool  # every row ends with a delimiter (an empty last field to drop)
    iso_space: bool
    units: tuple[str, ...] = ()  # a units row under the header, normalised ("" where none)


def _choose_delimiter(lines: list[str], decimal: str | None) -> tuple[str, int]:
    """The delimiter that splits most lines into the same count of numeric fields, and it."""
    best: tuple[float, int, str, int] | None = None
    for rank, delim in enumerate(_PRIORITY):
        if delim == "," and decimal == ",":
            continue
        split = splitter(delim, iso_space=True)
        rows = [_split_or_whole(split, line) for line in lines]
        share = [numeric_share(r, decimal, thousands=delim == ",") for r in rows]
        widths = Counter(len(r) for r, s in zip(rows, share, strict=True) if s >= 0.5)
        if not widths:
            continue
        width = max(widths, key=lambda w: (widths[w] * (w > 1), w))
        score = sum(s for r, s in zip(rows, share, strict=True) if len(r) == width and s >= 0.5)
        key = (score * (width > 1), -rank, delim, width)
        if best is None or key[:2] > best[:2]:
            best = key
    if best is None:
        return ",", 1
    return best[2], best[3]


def _split_or_whole(split: Callable[[str], list[str]], line: str) -> list[str]:
    """``split(line)``, or the line as one field where the CSV parser refuses it (the
    reading pass then reports it with its line)."""
    try:
        return split(line)
    except SplitError:
        return [line]


def _layout(
    path: Path, scan: _Scan, delimiter: str | None, decimal: str | None, lim: ResourceLimits
) -> _Layout:
    """Delimiter, decimal mark, header and preamble of a text file from its first lines."""
    sig = [(no, t) for no, t in scan.head if _is_significant(t.strip())]
    if not sig:
        raise LogError(
            f"{path}: no data rows (only blank, comment or separator lines). Fix: pass the "
            "file that holds the numbers"
        )
    texts = [t for _, t in sig]
    delim, width = (
        (delimiter, 0) if delimiter is not None else _choose_delimiter(texts[-200:], decimal)
    )
    iso_space = delim == " " and any(ISO_SPACE.search(t) for t in texts)
    split = splitter(delim, iso_space)
    rows = [split_fields(split, path, no, t, lim) for no, t in sig]
    share = [numeric_share(r, decimal, thousands=delim == ",") for r in rows]
    if not width:
        counts = Counter(len(r) for r, s in zip(rows, share, strict=True) if s >= 0.5)
        width = max(counts, key=lambda w: (counts[w], w)) if counts else len(rows[-1])

    def data_like(i: int) -> bool:
        return len(rows[i]) == width and share[i] >= 0.5

    def block(i: int) -> bool:  # mostly numeric lines of the data's width from line i on
        ahead = range(i, min(i + 5, len(rows)))
        return data_like(i) and sum(map(data_like, ahead)) >= min(3, len(ahead))

    start = next((i for i in range(len(rows)) if block(i)), None)
    if start is None and decimal == ".":
        for no, text in sig:
            if any(DEC_COMMA.match(c) for c in re.split(r"[;\t|]", text)):
                raise LogError(
                    f"{path}, line {no}: the numbers are written with a decimal comma "
                    f"({text.strip()!r:.60}) but decimal='.' was given. Fix: pass decimal=',' "
                    "(CLI --decimal ,), or leave the decimal mark to be detected"
                )
    if start is None and decimal == "," and delimiter is None:
        if _choose_delimiter(texts[-200:], ".")[0] == ",":
            raise LogError(
                f"{path}: decimal=',' (CLI --decimal ,) was given, but the file is "
                f"comma-separated with '.' decimals (line {sig[-1][0]}: {texts[-1].strip()!r:.60}):"
                " a decimal comma clashes with the commas between the columns. Fix: leave the "
                "decimal mark to be detected (drop --decimal ,)"
            )
    if start is None:
        raise LogError(
            f"{path}: no line of numbers with a constant field count ({DELIMITERS[delim]}-"
            f"separated); first line: {texts[0]!r:.120}. Fix: pass a numeric table, or "
            f"{'check' if delimiter else 'give'} the delimiter (CLI --delimiter)"
        )
    data_rows = [rows[i] for i in range(start, len(rows)) if data_like(i)]
    if decimal is None:
        decimal = "."
        if delim != ",":
            cells = (c for r in data_rows[:50] for c in r)
            if any(DEC_COMMA.match(c) for c in cells):
                decimal = ","
    # every row ending with a delimiter: an empty last field, dropped unless the header names it
    trailing = width > 1 and all(not r[-1].strip() for r in data_rows)
    first_data = sig[start][0]
    above = [(no, t) for no, t in scan.head if no < first_data]
    names: tuple[str, ...] | None = None
    units: tuple[str, ...] = ()
    notes: list[str] = []
    header_line = above[-1][0] if above else 0
    for no, text in reversed(above):  # the nearest header-like line above the data
        fields = _header_fields(text, split, width, decimal, delim)
        if fields is not None and trailing and fields[-1]:
            trailing = False
        elif fields is not None and trailing:
            fields = fields[:-1]
        elif fields is None and trailing:
            fields = _header_fields(text, split, width - 1, decimal, delim)
        if fields is not None:
            names, header_line = _unique(fields), no
            units = _units_row(fields)
            names_above = [
                _header_fields(t, split, width, decimal, delim) for n2, t in above if n2 < no
            ]
            if units and names_above and names_above[-1] and not _units_row(names_above[-1]):
                # a row of unit words right under the header: the columns' units
                names = _unique(names_above[-1])
                notes.append(
                    f"line {no}: a units row under the header ({', '.join(fields)}), used as "
                    "the columns' units where the column map gives none"
                )
            else:
                units = ()
            break
        if _is_significant(text.strip()):
            # the nearest non-comment line above the data is no header of the data's width;
            # a line of names with another count there is a header the rows do not fit
            # (decimal commas in a comma-separated file, a column added or lost), not a title
            names_there = [f.strip() for f in _split_or_whole(split, text)]
            if (
                delim != " "
                and len(names_there) >= 2
                and all(names_there)
                and numeric_share(names_there, decimal) == 0.0
            ):
                header_like = _Layout(
                    delim, decimal, len(names_there), tuple(names_there), no, (), False, False
                )
                raise _width_error(
                    path, first_data, data_rows[0], len(names_there), header_like, False, scan
                )
            break  # a title or preamble line: the file has no header
    skipped = tuple(t.strip() for no, t in above if no < header_line or names is None)
    if units:
        skipped = tuple(notes)
    return _Layout(delim, decimal, width, names, header_line, skipped, trailing, iso_space, units)


def _header_fields(
    text: str, split: Callable[[str], list[str]], width: int, decimal: str, delim: str
) -> list[str] | None:
    """The column names if ``text`` is a header of ``width`` fields, else None."""
    stripped = text.strip()
    variants = [text]
    if stripped[:1] in "#%":
        rest = stripped[1:].strip()
        variants = [rest, text] if stripped[0] == "#" else [text, rest]
    for v in variants:
        candidates = [_split_or_whole(split, v)]
        if delim == " ":
            candidates.append(re.split(r"\s{2,}|\t", v.strip()))
        for fields in candidates:
            if len(fields) == width + 1 and not fields[-1].strip():
                fields = fields[:-1]
            if len(fields) == width and numeric_share(fields, decimal) < 0.5:
                return [f.strip().strip('"').strip() for f in fields]
    return None


UNIT_ALIASES: Mapping[str, str] = MappingProxyType(
    {"sec": "s", "secs": "s", "msec": "ms", "counts": "count", "ticks": "count", "tick": "count",
     "cnt": "count", "degrees": "deg", "°": "deg", "deg/sec": "deg/s", "rad/sec": "rad/s",
     "mps": "m/s", "-": "", "": ""}
)  # fmt: skip
"""Unit words of a units row beyond the units of
:func:`~realitygap.diagnosis.logs.log.convert_units` (``""``: no unit)."""


def _unit_word(field: str) -> str | None:
    """The unit a cell of a units row names (``s``, ``[mm]``, ``(deg)``, ``counts``), ``""``
    for none (``-`` or empty), None for a word that is no unit."""
    from realitygap.diagnosis.logs.log import known_units

    w = field.strip().strip("[]()").strip()
    if w in known_units():
        return w
    return UNIT_ALIASES.get(w.lower())


def _units_row(fields: list[str]) -> tuple[str, ...]:
    """The units of a row of unit words (at least two, every cell a unit or empty), else ()."""
    units = [_unit_word(f) for f in fields]
    if any(u is None for u in units) or sum(bool(u) for u in units) < 2:
        return ()
    return tuple(u or "" for u in units)


def _unique(names: list[str]) -> tuple[str, ...]:
    """Names made unique (``x``, ``x.1``, …); an empty name becomes its index."""
    out: list[str] = []
    for j, nm in enumerate(names):
        base = nm or str(j)
        cand, k = base, 0
        while cand in out:
            k += 1
            cand = f"{base}.{k}"
        out.append(cand)
    return tuple(out)


# ------------------------------------------------------------------------------ reading
def check_format(delimiter: str | None, decimal: str | None) -> tuple[str | None, str | None]:
    """The ``delimiter`` (a name like ``tab`` resolved) and ``decimal`` mark of a text table,
    or a ``ValueError`` naming the option."""
    if delimiter is not None:
        if not isinstance(delimiter, str):
            raise TypeError(f"delimiter (--delimiter) must be text, got {delimiter!r}")
        if delimiter not in DELIMITERS:
            delimiter = _ALIASES.get(delimiter.lower(), " " if delimiter.isspace() else delimiter)
        if delimiter not in DELIMITERS:
            allowed = ", ".join(f"{d!r} ({n})" for d, n in DELIMITERS.items())
            raise ValueError(f"delimiter (--delimiter) must be one of {allowed}; got {delimiter!r}")
    if decimal is not None and decimal not in (".", ","):
        raise ValueError(f"decimal (--decimal) must be '.' or ',', got {decimal!r}")
    if decimal == "," and delimiter == ",":
        raise ValueError(
            "decimal=',' with delimiter=',' is ambiguous: a decimal comma needs another "
            "delimiter (';', tab, '|' or whitespace). Fix: export the file with ';' as the "
            "separator, or with '.' decimals"
        )
    return delimiter, decimal


def read_table(
    path: str | os.PathLike[str],
    *,
    delimiter: str | None = None,
    decimal: str | None = None,
    limits: ResourceLimits | None = None,
) -> Table:
    """Read a numeric table file (text, ``.mat`` or ``.npz``) into a :class:`Table`.

    Parameters
    ----------
    path : path-like
    delimiter : {",", ";", "\\t", "|", " "}, optional
        Field separator of a text file (``" "``: any run of whitespace; also ``"tab"``,
        ``"space"``); default: detected.
    decimal : {".", ","}, optional
        Decimal mark of a text file; default: detected (``","`` only with a delimiter
        other than ``","``).
    limits : ResourceLimits, optional
        Default: :meth:`ResourceLimits.from_environment`.

    Raises
    ------
    FileNotFoundError
        Nothing at ``path``.
    ValueError
        A ``delimiter`` or ``decimal`` that is not allowed.
    LogError
        A file that is not a table, a row with the wrong field count, a file cut off
        mid-write, a MATLAB v7.3 file, a saved log, a file beyond the limits: the
        message names the file, the line and column, and the fix.
    """
    delimiter, decimal = check_format(delimiter, decimal)
    p = Path(path)
    try:
        check_regular_file(p, "table file", needs="a table needs rows of numbers", unicode="accept")
    except ValueError as exc:
        raise LogError(str(exc)) from None
    lim = limits if limits is not None else ResourceLimits.from_environment()
    size = p.stat().st_size
    if size > lim.max_file_bytes:
        raise LogError(
            f"{p}: {size / 2**20:.3g} MB is more than the {lim.max_file_bytes / 2**20:.3g} MB a "
            "table file may have. Fix: split the file, or raise the limit with the environment "
            "variable REALITYGAP_MAX_FILE_MB"
        )
    kind = sniff_file_kind(p)
    with open(p, "rb") as fh:
        magic = fh.read(20)
    bom = text_encoding_of(magic)
    if kind == "text" or bom is not None:  # UTF-16/32 text holds NUL bytes: no binary
        return _read_text(p, delimiter, decimal, lim, bom[0] if bom else None)
    if magic.startswith(b"MATLAB") or (kind == "binary" and p.suffix.lower() == ".mat"):
        from realitygap.diagnosis.logs.importers.table_arrays import read_mat

        return _arrays_table(p, "mat", *read_mat(p, lim))
    if kind == "npz":
        from realitygap.diagnosis.logs.importers.table_arrays import read_npz

        return _arrays_table(p, "npz", *read_npz(p, lim))
    hints = {
        "npy": "a single NumPy array (.npy). Fix: save it in an archive, np.savez(path, name=a)",
        "rosbag1": "a ROS 1 bag, read by the bag importer (realitygap diagnose BAG …)",
        "sqlite": "an SQLite file (a ROS 2 .db3 bag?); pass the bag folder to the bag importer",
        "mcap": "an MCAP file (a ROS 2 bag?); pass the bag folder to the bag importer",
        "pickle": "a Python pickle, which is never loaded (unsafe). Fix: export CSV or .npz",
    }
    raise LogError(
        f"{p}: not a table file: {hints.get(kind, f'its content looks like {kind}')}. Tables are "
        "text (CSV, TSV, whitespace-aligned), MATLAB .mat (v4 to v7) or NumPy .npz files"
    )


def _read_text(
    path: Path,
    delimiter: str | None,
    decimal: str | None,
    lim: ResourceLimits,
    encoding: str | None = None,
) -> Table:
    if csv.field_size_limit() <= _max_line_chars(lim):  # _lines and _fields limit instead
        csv.field_size_limit(_max_line_chars(lim) + 1)
    if encoding is not None:  # UTF-16/32 by its byte-order mark
        scan = _scan(path, encoding, lim)
        with open(path, "rb") as fb:
            label = (text_encoding_of(fb.read(4)) or ("", encoding))[1]
    else:
        encoding = "utf-8-sig"
        try:
            scan = _scan(path, encoding, lim)
        except _DecodeError:
            encoding = "latin-1"
            scan = _scan(path, encoding, lim)
        label = "UTF-8" if encoding == "utf-8-sig" else encoding
    lay = _layout(path, scan, delimiter, decimal, lim)
    above = sum(1 for no, t in scan.head if no <= lay.header_line and _is_significant(t.strip()))
    n_rows = scan.n_significant - above
    width = lay.width - lay.trailing
    try:
        check_rows_limit(n_rows, width, str(path), lim)
    except ValueError as exc:
        raise LogError(str(exc)) from None
    data = np.full((n_rows, width), np.nan)
    lines = np.zeros(n_rows, dtype=np.int64)
    text_columns: dict[str, tuple[int, str]] = {}
    names = lay.names if lay.names is not None else tuple(str(j) for j in range(width))
    split = splitter(lay.delimiter, lay.iso_space)
    comma = lay.decimal == ","
    thousands = lay.delimiter == "," and lay.decimal == "."
    tail: list[list[int]] = []
    i = 0
    digits = [0] * width
    with open(path, encoding=encoding, newline="") as fh:
        for line_no, raw in _rows_after(_lines(fh, path, lim), lay.header_line):
            fields = split_fields(split, path, line_no, raw, lim)
            if len(fields) == width + 1 and not fields[-1].strip():
                fields.pop()  # a trailing delimiter
            if i >= n_rows:
                raise LogError(
                    f"{path}, line {line_no}: the file grew while it was read (it had "
                    f"{scan.last[0]} lines when reading began). Fix: read a copy made once the "
                    "recording is finished"
                )
            if len(fields) != width:
                raise _width_error(path, line_no, fields, width, lay, i == n_rows - 1, scan)
            row = data[i]
            for j, cell in enumerate(fields):
                try:
                    row[j] = float(cell.replace(",", ".") if comma else cell)
                except ValueError:
                    value = cell_number(cell, lay.decimal, thousands)
                    if value is None:
                        value = math.nan
                        text_columns.setdefault(names[j], (line_no, cell.strip()))
                    row[j] = value
            lines[i] = line_no
            if i < DECIMALS_ROWS:
                for j, cell in enumerate(fields):
                    digits[j] = max(digits[j], len(cell.strip().partition(lay.decimal)[2]))
            if i >= n_rows - 21:
                tail.append([len(c.strip()) for c in fields])
            i += 1
    if not scan.ends_newline and len(tail) > CUT_HISTORY:
        # a writer stopped mid-line leaves every field but the one it was writing complete:
        # only the last field of the last line can be cut (``…,51,6`` for ``…,51,66``); an
        # earlier field that happens to be short (trailing zeros trimmed) is not a cut
        before = np.min(np.asarray(tail[:-1]), axis=0)
        j_last = len(tail[-1]) - 1
        while j_last > 0 and tail[-1][j_last] == 0 and before[j_last] == 0:
            j_last -= 1  # an empty trailing field is no field
        short = [j_last] if tail[-1][j_last] < before[j_last] else []
        if short:
            raise LogError(
                f"{path}, line {scan.last[0]}: the last line ({scan.last[1].strip()!r:.80}) has "
                f"no newline and its field {names[short[0]]!r} is narrower than in every line "
                "before it: the file looks cut off mid-write. Fix: delete the last line, or end "
                "the file with a newline if the line is complete"
            )
    return Table(
        source=path,
        names=names,
        data=data,
        lines=lines,
        kind="text",
        delimiter=lay.delimiter,
        decimal=lay.decimal,
        skipped=lay.skipped,
        has_header=lay.names is not None,
        text_columns=text_columns,
        decimals=tuple(digits),
        encoding=label,
        units=lay.units[:width] if lay.units else (),
    )


def _rows_after(lines: Iterator[tuple[int, str]], header_line: int) -> Iterator[tuple[int, str]]:
    """``(line, text)`` of the data-like lines after ``header_line``."""
    for line_no, raw in lines:
        if line_no <= header_line:
            continue
        text = raw.rstrip("\r\n")
        if _is_significant(text.strip()):
            yield line_no, text


DECIMALS_ROWS = 40
"""Rows whose cells give each column's written resolution (:attr:`Table.decimals`)."""

CUT_HISTORY = 10
"""Lines before the last one that its width is judged against: a last field narrower than in
every one of them (at least this many) looks cut off; against fewer, a short number (``1.``
under ``-108.99996544``) is as likely as a cut."""


_INTEGER = re.compile(r"^\s*[-+]?\d+\s*$")


def _width_error(
    path: Path, line_no: int, fields: list[str], width: int, lay: _Layout, last: bool, scan: _Scan
) -> LogError:
    """The error for a line of ``fields`` where the header (or the rows above) has ``width``;
    the likely cause named only on evidence: decimal commas in a comma-separated file only
    when every cell of the line is a whole number (``0,02`` split into ``0`` and ``02``)."""
    got = len(fields)
    which = "the header has" if lay.names is not None else "the rows above have"
    hint = (
        f" — a stray delimiter, a cell or line cut short, or a line run into the next (a file "
        f"written while it was read?). Fix: repair or delete line {line_no}"
    )
    if lay.delimiter == " ":
        hint = (
            " — in a whitespace-aligned file an empty cell shifts the columns after it. Fix: "
            "export the file with a delimiter (',' or ';') so that empty cells keep their place"
        )
    elif lay.delimiter == "," and got > width and all(_INTEGER.match(f) for f in fields):
        hint = (
            " — decimal commas in a comma-separated file? Fix: export with ';' as the separator "
            "(decimal commas are then understood) or with '.' decimals"
        )
    if last and not scan.ends_newline:
        hint += " — the last line has no newline: the file looks cut off mid-write"
    return LogError(
        f"{path}, line {line_no}: {got} fields ({DELIMITERS[lay.delimiter]}-separated) but "
        f"{which} {width}{hint}"
    )


def _arrays_table(
    path: Path, kind: str, names: list[str], data: np.ndarray, notes: tuple[str, ...]
) -> Table:
    """The :class:`Table` of a binary file's columns (one row per sample)."""
    return Table(
        source=path,
        names=_unique(names),
        data=data,
        lines=np.arange(1, data.shape[0] + 1, dtype=np.int64),
        kind=kind,
        delimiter=None,
        decimal=".",
        skipped=notes,
        has_header=True,
    )
