"""The array formats of :func:`~realitygap.diagnosis.logs.importers.table.read_table`: MATLAB
``.mat`` files and NumPy ``.npz`` archives as named columns (see that module's docstring).

Each reader returns :data:`Columns`: the column names, the ``(n, k)`` float array and the
notes on what was not read; ``read_table`` makes the :class:`Table` of them. The dtypes follow
:mod:`~realitygap.diagnosis.logs.schema`: float and integer arrays are columns, ``datetime64``
and ``timedelta64`` arrays are converted to seconds (POSIX seconds for dates), booleans and
complex numbers are not read (a column map that names one is told why), and object arrays are
never unpickled (``allow_pickle=False``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from realitygap.core.checks import ResourceLimits, check_rows_limit
from realitygap.diagnosis.logs.log import LogError
from realitygap.diagnosis.logs.schema import as_seconds, dtype_problem

__all__ = ["Columns", "read_mat", "read_npz"]

Columns = tuple[list[str], np.ndarray, tuple[str, ...]]
"""Column names, values (n, k) and notes on the variables not read."""


def read_mat(path: Path, lim: ResourceLimits) -> Columns:
    from scipy.io import loadmat, whosmat
    from scipy.io.matlab import matfile_version

    try:
        major, _ = matfile_version(str(path))
    except Exception as exc:  # scipy raises several types on foreign content
        raise LogError(f"{path}: not a readable MATLAB file ({exc})") from None
    if major == 2:
        raise LogError(
            f"{path}: a MATLAB v7.3 file (HDF5), which this reader does not open. Fix: save it "
            "again in MATLAB with save(FILE, ..., '-v7'), or export CSV (writetable)"
        )
    try:
        listing = whosmat(str(path))
        cells = sum(int(np.prod(shape, dtype=np.float64)) for _, shape, _ in listing)
        check_rows_limit(cells, 1, f"{path} (all variables together)", lim)
        raw = loadmat(str(path), squeeze_me=True, struct_as_record=False)
    except ValueError as exc:
        raise LogError(f"{path}: {exc}") from None
    except Exception as exc:  # a damaged file: scipy raises many types
        raise LogError(f"{path}: unreadable MATLAB file ({type(exc).__name__}: {exc})") from None
    arrays = [(k, v) for k, v in raw.items() if not k.startswith("__")]
    return _columns(path, arrays, lim)


def read_npz(path: Path, lim: ResourceLimits) -> Columns:
    from realitygap.diagnosis.logs.importers.archive import (
        ArchiveError,
        archive_members,
        read_log_archive,
    )

    try:
        members = archive_members(path)
        if {"t.npy", "meta.json.npy"} <= members:
            raise LogError(
                f"{path}: a saved realitygap log (Log.save), not a table; it needs no column "
                f"map: read it with read_logs (realitygap diagnose {path})"
            )
        raw = read_log_archive(path, lim)
    except ArchiveError as exc:
        raise LogError(str(exc).replace("; not a realitygap log", "")) from None
    return _columns(path, list(raw.items()), lim)


def _collect(
    name: str, value: Any, out: list[tuple[str, np.ndarray]], notes: list[str], depth: int = 0
) -> None:
    """Numeric vectors and matrices of one variable (struct fields recursively)."""
    if hasattr(value, "_fieldnames") and depth < 4:  # a MATLAB struct
        for f in value._fieldnames:
            _collect(f"{name}.{f}", getattr(value, f), out, notes, depth + 1)
        return
    if isinstance(value, str):
        notes.append(f"variable {name} not read: text")
        return
    arr = np.asarray(value)
    arr = np.squeeze(arr) if arr.ndim > 1 else arr
    if arr.dtype.kind in "Mm" and arr.ndim >= 1 and arr.size > 1:
        # dates and durations are time stamps: seconds (POSIX seconds for dates)
        notes.append(
            f"variable {name}: {'dates' if arr.dtype.kind == 'M' else 'durations'} "
            f"({arr.dtype}) read as {'POSIX ' if arr.dtype.kind == 'M' else ''}seconds"
        )
        arr = as_seconds(arr)
    if arr.dtype.kind in "bc":
        # the schema's dtypes: a flag is no measurement, a complex number no real one
        notes.append(f"variable {name} not read: {dtype_problem(arr.dtype, '')}")
    elif arr.dtype.kind not in "iuf":
        what = {"O": "a cell or struct array", "U": "text", "S": "text"}
        notes.append(f"variable {name} not read: {what.get(arr.dtype.kind, str(arr.dtype))}")
    elif arr.ndim == 0 or arr.size == 1:
        notes.append(f"variable {name} not read: a single value ({arr.reshape(-1)[0]!r:.30})")
    elif arr.ndim > 2:
        shape = "×".join(map(str, arr.shape))
        notes.append(f"variable {name} ({shape}) not read: a {arr.ndim}-D array, not columns")
    else:
        out.append((name, arr))


def _columns(path: Path, arrays: list[tuple[str, Any]], lim: ResourceLimits) -> Columns:
    found: list[tuple[str, np.ndarray]] = []
    notes: list[str] = []
    for name, value in arrays:
        _collect(name, value, found, notes)
    lengths = {a.shape[0] for _, a in found if a.ndim == 1}
    columns: list[tuple[str, np.ndarray]] = []
    for name, a in found:
        if a.ndim == 1:
            columns.append((name, a))
            continue
        rows_first = a.shape[0] in lengths or not (
            a.shape[1] in lengths or (a.shape[0] <= 16 and a.shape[1] >= 10 * a.shape[0])
        )
        m = a if rows_first else a.T
        if not rows_first:
            notes.append(f"matrix {name} ({a.shape[0]}×{a.shape[1]}) read as {m.shape[0]} rows")
        columns += [(f"{name}[{j}]", m[:, j]) for j in range(m.shape[1])]
    if not columns:
        listing = "; ".join(notes) or "none"
        raise LogError(
            f"{path}: no numeric vector or matrix to read as columns (variables: {listing}). "
            "Fix: store the signals as numeric vectors of one length, or export CSV"
        )
    n = max(len(c) for _, c in columns)
    for name, c in columns:
        if len(c) != n:
            notes.append(
                f"variable {name} ({len(c)} rows) not read: its length differs from the "
                f"{n} rows of the table"
            )
    keep = [(name, c) for name, c in columns if len(c) == n]
    try:
        check_rows_limit(n, len(keep), str(path), lim)
    except ValueError as exc:
        raise LogError(str(exc)) from None
    data = np.column_stack([np.asarray(c, dtype=np.float64) for _, c in keep])
    return [name for name, _ in keep], data, tuple(notes)
