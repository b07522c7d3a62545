"""Import a log from a CSV file with a column map.

The map says which CSV column (by header name or 0-based index) feeds which
channel column of the :class:`~realitygap.diagnosis.logs.log.Log`, and in which
unit the file stores it; values are converted to the log's SI units::

    t=time:ms, cmd.v=vx:mm/s, cmd.w=wz:deg/s,
    ticks.left=encL, ticks.right=encR,
    pose_gt.x=x:mm, pose_gt.y=y:mm, pose_gt.theta=yaw:deg

Separators (``,``, ``;``, tab) are detected, as are decimal commas (only
unambiguous in ``;``- or tab-separated files). Encoder columns may hold
cumulative counts or per-row increments. Missing values (empty cells, ``nan``)
raise by default; ``nan="interpolate"`` fills them linearly, ``nan="drop"``
drops the rows. Every error names the file, the line or column and the fix.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.checks import ResourceLimits, check_regular_file, check_rows_limit
from realitygap.diagnosis.logs.log import (
    Log,
    LogError,
    convert_units,
    fill_gaps,
    sniff_file_kind,
    standard_channels,
)
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.diffdrive_replay import params_to_meta

FloatArray = npt.NDArray[np.float64]

__all__ = ["ColumnMap", "read_csv_log"]

_TARGET = re.compile(r"^(t|[a-z_]+\.[a-z_]+)$")


@dataclass(frozen=True)
class ColumnMap:
    """Which CSV column feeds which log column, and its unit in the file.

    Attributes
    ----------
    entries : mapping of str to (str or int, str)
        ``"t"`` or ``"channel.column"`` → ``(csv column, unit)``; the CSV column
        is a header name or a 0-based index.
    ticks : {"cumulative", "increments"}
        How the encoder columns count.
    """

    entries: Mapping[str, tuple[str | int, str]] = field(default_factory=dict)
    ticks: str = "cumulative"

    def __post_init__(self) -> None:
        if "t" not in self.entries:
            raise LogError("column map: the time column 't' is required (e.g. 't=time:s')")
        for target in self.entries:
            if not _TARGET.match(target):
                raise LogError(
                    f"column map: target {target!r} must be 't' or 'channel.column' "
                    "(e.g. 'cmd.v', 'pose_gt.theta')"
                )
            if target != "t":
                chan, col = target.split(".", 1)
                spec = standard_channels().get(chan)
                if spec is None:
                    raise LogError(
                        f"column map: unknown channel {chan!r} in {target!r}; channels: "
                        f"{', '.join(standard_channels())}"
                    )
                if col not in spec.columns:
                    raise LogError(
                        f"column map: channel {chan!r} has columns {spec.columns}, not {col!r}"
                    )
        if self.ticks not in ("cumulative", "increments"):
            raise LogError(
                f"column map: ticks must be 'cumulative' or 'increments', got {self.ticks!r}"
            )

    @classmethod
    def parse(cls, text: str) -> ColumnMap:
        """Parse ``"t=time:ms, cmd.v=vx:mm/s, …[, ticks=increments]"`` or a JSON file path.

        A JSON file holds ``{"t": ["time", "ms"], "cmd.v": ["vx", "mm/s"], …}``
        (a bare column name means the log's own unit) and optionally
        ``"ticks": "increments"``.
        """
        text = text.strip()
        if text.endswith(".json") and os.path.isfile(text):
            with open(text, encoding="utf-8") as fh:
                raw = json.load(fh)
            return cls.from_dict(raw)
        raw_map: dict[str, Any] = {}
        for part in filter(None, (p.strip() for p in text.split(","))):
            if "=" not in part:
                raise LogError(
                    f"column map: expected 'target=column[:unit]', got {part!r} "
                    "(e.g. 't=time:s,cmd.v=vx,cmd.w=wz')"
                )
            target, source = (s.strip() for s in part.split("=", 1))
            if target == "ticks":
                raw_map["ticks"] = source
                continue
            col, _, unit = source.partition(":")
            raw_map[target] = [col.strip(), unit.strip()] if unit else col.strip()
        return cls.from_dict(raw_map)

    @classmethod
    def from_dict(cls, raw: Mapping[str, Any]) -> ColumnMap:
        entries: dict[str, tuple[str | int, str]] = {}
        ticks = str(raw.get("ticks", "cumulative"))
        for target, value in raw.items():
            if target == "ticks":
                continue
            if isinstance(value, (list, tuple)):
                col, unit = value[0], value[1] if len(value) > 1 else ""
            else:
                col, unit = value, ""
            if not unit:
                unit = "s" if target == "t" else (_default_unit(target) if _known(target) else "1")
            if isinstance(col, str) and col.isdigit():
                col = int(col)
            entries[target] = (col, str(unit))
        return cls(entries, ticks)


def _known(target: str) -> bool:
    chan, _, col = target.partition(".")
    return chan in standard_channels() and col in standard_channels()[chan].columns


def _default_unit(target: str) -> str:
    chan, col = target.split(".", 1)
    spec = standard_channels()[chan]
    return spec.units[spec.columns.index(col)]


def _sniff_delimiter(lines: list[str]) -> str:
    sample = "\n".join(lines[:20])
    try:
        return csv.Sniffer().sniff(sample, delimiters=",;\t").delimiter
    except csv.Error:
        counts = {d: sample.count(d) for d in (";", "\t", ",")}
        best = max(counts, key=lambda d: counts[d])
        return best if counts[best] else ","


def regularise_rounded_time(t: FloatArray, quantum: float) -> tuple[FloatArray, bool]:
    """A regular time base if ``t`` is one written with too few decimals.

    A 20 Hz log written with 3 decimals has steps of 49–51 ms: each stamp is a
    regular grid point ``t0 + k·dt`` rounded to ``quantum`` (s). When every stamp
    lies within ``quantum / 2`` of the least-squares grid (plus float noise) the
    grid is returned (and ``True``); otherwise ``t`` itself (and ``False``): real
    jitter or gaps are never smoothed away.
    """
    n = t.shape[0]
    if n < 3 or not np.all(np.isfinite(t)) or quantum <= 0:
        return t, False
    k = np.arange(n, dtype=float)
    dt, t0 = np.polyfit(k, t, 1)
    grid = t0 + dt * k
    if dt <= 0 or np.max(np.abs(t - grid)) > 0.5 * quantum + 1e-9 * max(abs(t[-1]), 1.0):
        return t, False
    step = np.diff(t)
    if np.allclose(step, dt, rtol=1e-9, atol=0.0):
        return t, False
    return grid, True


def _data_lines(fh: Iterable[str]) -> Iterator[str]:
    """The lines of a CSV file that are neither blank nor ``#`` comments."""
    for line in fh:
        if line.strip() and not line.lstrip().startswith("#"):
            yield line


def _scan_lines(path: Path, encoding: str) -> tuple[list[str], int, str, bool]:
    """One streaming pass: the first 60 data lines, their count, the last one, and
    whether the file ends with a newline."""
    head: list[str] = []
    n = 0
    last = ""
    with open(path, encoding=encoding, newline="") as fh:
        for line in _data_lines(fh):
            if n < 60:
                head.append(line.rstrip("\r\n"))
            n += 1
            last = line
    with open(path, "rb") as fb:
        fb.seek(max(path.stat().st_size - 1, 0))
        ends_newline = fb.read(1) in (b"\n", b"\r")
    return head, n, last, ends_newline


_DEC_COMMA = re.compile(r"^\s*[-+]?\d+,\d+([eE][-+]?\d+)?\s*$")


def _to_float(text: str, decimal: str) -> float:
    s = text.strip()
    if s == "" or s.lower() in ("nan", "na", "null", "none"):
        return math.nan
    if decimal == ",":
        s = s.replace(".", "").replace(",", ".") if s.count(",") == 1 else s
    return float(s)


def read_csv_log(
    path: str | os.PathLike[str],
    column_map: ColumnMap | str | Mapping[str, Any],
    *,
    delimiter: str | None = None,
    decimal: str | None = None,
    params: DiffDriveParams | Mapping[str, Any] | None = None,
    meta: Mapping[str, Any] | None = None,
    nan: str = "raise",
    robot: str = "diffdrive",
) -> Log:
    """Read a CSV file into a :class:`~realitygap.diagnosis.logs.log.Log`.

    Parameters
    ----------
    path : path-like
    column_map : ColumnMap, str or mapping
        See :class:`ColumnMap` (a string is parsed with :meth:`ColumnMap.parse`).
    delimiter : str, optional
        Field separator (default: detected).
    decimal : {".", ","}, optional
        Decimal mark (default: detected; ``","`` only with ``;`` or tab separators).
    params : DiffDriveParams or mapping, optional
        Nominal robot parameters for ``meta["params"]`` (default: the Kobuki-like defaults).
    meta : mapping, optional
        Extra metadata (e.g. ``{"firmware": {"a_max": 1.0, "alpha_max": 4.0}}``).
    nan : {"raise", "interpolate", "drop"}
        What to do with missing values.
    robot : str

    Raises
    ------
    LogError
        With the file name and the fix: not a text file, missing columns,
        non-numeric or missing values, unknown or mismatched units,
        non-monotonic time.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"CSV file not found: {path}")
    try:
        check_regular_file(path, "CSV file")
    except ValueError as exc:
        raise LogError(str(exc)) from None
    cmap = (
        column_map
        if isinstance(column_map, ColumnMap)
        else (
            ColumnMap.parse(column_map)
            if isinstance(column_map, str)
            else ColumnMap.from_dict(column_map)
        )
    )
    if nan not in ("raise", "interpolate", "drop"):
        raise ValueError(f"nan must be 'raise', 'interpolate' or 'drop', got {nan!r}")
    kind = sniff_file_kind(path)
    if kind != "text":
        raise LogError(
            f"{path}: not a text CSV file (its content looks like {kind}); whatever its extension, "
            "pass it with the matching importer (a .npz log, a ROS bag)"
        )
    lim = ResourceLimits.from_environment()
    size = path.stat().st_size
    if size > lim.max_file_bytes:
        raise LogError(
            f"{path}: {size / 2**20:.0f} MB is more than the {lim.max_file_bytes / 2**20:.0f} MB a "
            "CSV log may have. Fix: split the file, or raise the limit with the environment "
            "variable REALITYGAP_MAX_FILE_MB"
        )
    encoding = "utf-8-sig"
    try:
        head, n_lines, last, ends_newline = _scan_lines(path, encoding)
    except UnicodeDecodeError:
        encoding = "latin-1"
        head, n_lines, last, ends_newline = _scan_lines(path, encoding)
    if n_lines < 3:
        raise LogError(f"{path}: expected a header row and at least two data rows")
    delim = delimiter or _sniff_delimiter(head)
    header = [h.strip() for h in next(csv.reader([head[0]], delimiter=delim))]
    width = len(header)
    sample_rows = list(csv.reader(head[1:], delimiter=delim))
    if decimal is None:
        decimal = "."
        if delim != ",":
            sample = [c for r in sample_rows[:50] for c in r]
            if sum(bool(_DEC_COMMA.match(c)) for c in sample) > 0:
                decimal = ","
    elif decimal not in (".", ","):
        raise ValueError(f"decimal must be '.' or ',', got {decimal!r}")

    def col_index(target: str, col: str | int) -> int:
        if isinstance(col, int):
            if not 0 <= col < width:
                raise LogError(
                    f"{path}: column index {col} for {target!r} is out of range (0..{width - 1})"
                )
            return col
        if col not in header:
            import difflib

            close = difflib.get_close_matches(col, header, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise LogError(
                f"{path}: no column {col!r} for {target!r}{hint}; the header has "
                f"{', '.join(repr(h) for h in header)}. Fix the column map"
            )
        return header.index(col)

    targets = list(cmap.entries)
    index = [col_index(t, cmap.entries[t][0]) for t in targets]
    n_rows = n_lines - 1
    try:
        check_rows_limit(n_rows, len(targets), str(path), lim)
    except ValueError as exc:
        raise LogError(str(exc)) from None
    table = np.empty((n_rows, len(targets)))
    widths: list[list[int]] = []
    with open(path, encoding=encoding, newline="") as fh:
        rows = csv.reader(_data_lines(fh), delimiter=delim)
        next(rows)
        for i, r in enumerate(rows):
            line_no = i + 2
            if len(r) != width:
                hint = ""
                if delim == "," and len(r) > width:
                    hint = (
                        " — decimal commas in a comma-separated file? Fix: export with ';' as "
                        "the separator (decimal commas are then understood) or with '.' decimals"
                    )
                if i == n_rows - 1 and not ends_newline:
                    hint += " — the last line has no newline: the file looks cut off"
                raise LogError(
                    f"{path}, line {line_no}: {len(r)} fields but the header has {width}{hint}"
                )
            if i >= n_rows - 21:
                widths.append([len(r[j].strip()) for j in index])
            for k, j in enumerate(index):
                cell = r[j]
                try:
                    table[i, k] = _to_float(cell, decimal)
                except ValueError:
                    hint = ""
                    if decimal == "." and _DEC_COMMA.match(cell):
                        hint = " — a decimal comma; Fix: pass decimal=',' (CLI --decimal ,)"
                    raise LogError(
                        f"{path}, line {line_no}, column {header[j]!r} ({targets[k]}): expected "
                        f"a number, got {cell.strip()!r}{hint}"
                    ) from None
    if not ends_newline and len(widths) > 1:
        before = np.min(np.asarray(widths[:-1]), axis=0)
        short = [k for k, w in enumerate(widths[-1]) if w < before[k]]
        if short:
            k = short[0]
            raise LogError(
                f"{path}: the last line ({last.strip()!r:.80}) has no newline and its field "
                f"{header[index[k]]!r} is narrower than in every line before it: the file looks "
                "cut off mid-write. Fix: delete the last line, or end the file with a newline "
                "if the line is complete"
            )
    values: dict[str, FloatArray] = {}
    for k, target in enumerate(targets):
        unit = cmap.entries[target][1]
        si = "s" if target == "t" else _default_unit(target)
        values[target] = convert_units(
            table[:, k], unit, si, what=f"{path}: column {header[index[k]]!r} ({target})"
        )
    del table

    stacked = np.column_stack(list(values.values()))
    bad = ~np.isfinite(stacked)
    if bad.any():
        names = list(values)
        if nan == "raise":
            row, c = (int(v) for v in np.argwhere(bad)[0])
            raise LogError(
                f"{path}, line {row + 2}: missing or non-finite value in column for "
                f"{names[c]!r} ({int(bad.sum())} such cells). Fix: clean the file, or pass "
                "nan='interpolate' (CLI --nan interpolate) or nan='drop'"
            )
        if nan == "drop":
            keep = ~bad.any(axis=1)
            values = {k: v[keep] for k, v in values.items()}
        else:
            t_ok = np.isfinite(values["t"])
            if not t_ok.all():
                raise LogError(
                    f"{path}: the time column has missing values; they cannot be interpolated"
                )
            for k in values:
                if k != "t":
                    values[k] = fill_gaps(values["t"], values[k])

    t = values.pop("t")
    t_col = index[targets.index("t")]
    decimals = max(
        (len(r[t_col].strip().partition(".")[2]) for r in sample_rows if len(r) > t_col), default=0
    )
    quantum = float(convert_units(10.0**-decimals, cmap.entries["t"][1], "s"))
    t, regularised = regularise_rounded_time(t, quantum)
    channels: dict[str, FloatArray] = {}
    by_channel: dict[str, dict[str, FloatArray]] = {}
    for target, v in values.items():
        chan, col = target.split(".", 1)
        by_channel.setdefault(chan, {})[col] = v
    for chan, cols in by_channel.items():
        spec = standard_channels()[chan]
        missing = [c for c in spec.columns if c not in cols]
        if missing:
            raise LogError(
                f"{path}: channel {chan!r} needs columns {', '.join(spec.columns)}; the column map "
                f"gives no {', '.join(missing)}"
            )
        arr = np.column_stack([cols[c] for c in spec.columns])
        for j in spec.angle_columns:
            arr[:, j] = np.unwrap(arr[:, j])
        if chan == "ticks" and cmap.ticks == "increments":
            arr = np.cumsum(arr, axis=0) - arr[0]
        channels[chan] = arr

    if isinstance(params, DiffDriveParams):
        pmeta: dict[str, Any] = params_to_meta(params)
    elif params is None:
        pmeta = params_to_meta(DiffDriveParams())
    else:
        pmeta = dict(params)
    full_meta: dict[str, Any] = {
        "robot": robot,
        "params": pmeta,
        "name": path.stem,
        "source": str(path),
    }
    full_meta.update(dict(meta or {}))
    if regularised:
        full_meta["time_regularised"] = (
            f"time written with {decimals} decimals; stamps replaced by the regular grid they "
            "round to"
        )
    return Log(t=t, channels=channels, meta=full_meta, source=str(path))
