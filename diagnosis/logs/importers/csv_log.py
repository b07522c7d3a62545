"""Import logs from table files (CSV, TSV, ``|`` or whitespace text, ``.mat``, ``.npz``) with a
column map.

The map (:class:`~realitygap.diagnosis.logs.importers.column_map.ColumnMap`)
says which file column feeds which log column, in which unit, with which sign,
scale and offset::

    t=time:ms, cmd.v=vx:mm/s, cmd.w=wz:deg/s,
    ticks.left=-encL, ticks.right=encR,
    pose_gt.x=x:mm, pose_gt.y=y:mm, pose_gt.theta=-yaw:deg

The files are read by :func:`~realitygap.diagnosis.logs.importers.table.read_table`
(title lines, comments, delimiters and decimal commas detected). Values are
converted to the log's SI units.

**Channels at their own rates.** A channel's samples are the rows where all
its columns hold a value; a row where they are all empty is not a sample of
that channel (another stream's row, in a file that interleaves streams, or a
dropout). A row where only some are empty is a missing value: an error by
default, ``nan="interpolate"`` fills it over the channel's own samples,
``nan="drop"`` drops the row. When every channel is sampled on the same rows
the log keeps those rows. Otherwise each channel is aligned on its own stamps:
the log takes the stamps of one channel (the wheel encoders, else the
commands, else the densest), the others are interpolated there (commands held,
angles unwrapped), never extrapolated; where a channel has a gap longer than
``max_gap`` the log is split, so no gap is bridged by invented values.
Several files (``read_table_logs([enc, mocap], …)``) are aligned the same way,
each on its own time column. Repeated stamps within a channel follow
``duplicates``: ``"raise"`` (default), ``"last"`` or ``"mean"``.

Every error names the file, the line or column and the fix.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.checks import ResourceLimits
from realitygap.diagnosis.logs.align import (
    BASE_CHANNEL_ORDER,
    HELD_CHANNELS,
    MIN_PIECE_S,
    align_streams,
    whole,
)
from realitygap.diagnosis.logs.channels import ROBOT_CHANNELS
from realitygap.diagnosis.logs.importers.column_map import ColumnMap, Source
from realitygap.diagnosis.logs.importers.streams import (
    DUPLICATE_POLICIES,
    Stream,
    dedupe,
    reset_pieces,
)
from realitygap.diagnosis.logs.importers.table import Table, read_table
from realitygap.diagnosis.logs.log import (
    Log,
    LogError,
    convert_units,
    fill_gaps,
    standard_channels,
)
from realitygap.diagnosis.logs.schema import (
    SchemaError,
    check_counts,
    fill_time,
    unwrap_counter,
)
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.diffdrive_replay import params_to_meta

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "BASE_CHANNEL_ORDER",
    "HELD_CHANNELS",
    "MIN_PIECE_S",
    "ColumnMap",
    "read_csv_log",
    "read_table_logs",
    "regularise_rounded_time",
]

"""What to do with repeated time stamps within one channel."""

POSE_ROW_CHANNELS = ("joints", "tool_pos")
"""Channels of logs whose rows are poses (an arm measured at rest), not instants: they are
never interpolated, and a log of them needs no time."""


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


def _literal(src: Source, tables: Sequence[Table]) -> Source:
    """``src`` read as a plain column name when a file's header holds its text exactly (a
    column named ``x-1`` is that column, not ``x`` minus one)."""
    if src.affine and src.body and any(src.body in t.names for t in tables):
        return Source(column=src.body, unit=src.unit, text=src.text, body=src.body)
    return src


def _resolve(tables: Sequence[Table], src: Source, target: str) -> tuple[int, int]:
    """(table, column) of ``src``."""
    hits: list[tuple[int, int]] = []
    errors: list[LogError] = []
    for k, tab in enumerate(tables):
        if not src.matches_file(tab.source):
            continue
        try:
            hits.append((k, tab.index(src.column)))
        except LogError as exc:
            errors.append(exc)
    if src.file is not None and not any(src.matches_file(t.source) for t in tables):
        names = ", ".join(t.source.name for t in tables)
        raise LogError(
            f"column map: {target}={src.text}: no file {src.file!r} among {names}. Fix: qualify "
            "the column with one of those names (FILE::column)"
        )
    if len(hits) == 1:
        return hits[0]
    if not hits:
        refused = _refused_dtype(tables, src)
        if refused:
            raise LogError(f"column map entry {target}={src.text}: {refused}")
        if len(errors) == 1:
            raise LogError(f"column map entry {target}={src.text}: {errors[0]}") from None
        raise LogError(
            f"column map: {target}={src.text}: no file has that column ("
            + "; ".join(str(e) for e in errors)
            + "). Fix the column map"
        )
    names = ", ".join(tables[k].source.name for k, _ in hits)
    raise LogError(
        f"column map: {target}={src.text}: the column is in several files ({names}); say which "
        f"with FILE::column (e.g. {tables[hits[0][0]].source.stem}::{src.column})"
    )


def _refused_dtype(tables: Sequence[Table], src: Source) -> str | None:
    """What an array file said about the variable ``src`` names when its dtype kept it out of
    the table (booleans, complex numbers, objects: see
    :func:`~realitygap.diagnosis.logs.schema.dtype_problem`), else ``None``."""
    if src.column is None:
        return None
    base = str(src.column).split("[", 1)[0]
    for tab in tables:
        if tab.kind == "text" or not src.matches_file(tab.source):
            continue
        for note in tab.skipped:
            head = f"variable {base} not read: "
            if note.startswith(head) and "expected" in note:
                return f"{tab.source}: variable {base!r}: {note[len(head) :]}"
    return None


def _values(tab: Table, j: int, src: Source, si: str, target: str) -> FloatArray:
    raw = tab.column(j)
    name = tab.names[j]
    if name in tab.text_columns and np.isnan(raw).all():
        line, text = tab.text_columns[name]
        raise LogError(
            f"{tab.source}, line {line}, column {name!r} ({target}): expected numbers, got "
            f"{text!r}. Fix: map a numeric column, or export the values as numbers"
        )
    if name in tab.text_columns:
        line, text = tab.text_columns[name]
        hint = "Fix: repair or delete that row"
        if tab.decimal == "." and re.match(r"^\s*[-+]?\d+,\d+([eE][-+]?\d+)?\s*$", text):
            hint = "a decimal comma; Fix: pass decimal=',' (CLI --decimal ,)"
            if tab.delimiter == ",":  # quoted; digit groups of three are read as thousands
                hint = (
                    "a decimal comma in a comma-separated file with '.' decimals elsewhere "
                    "(a number with ',' between groups of three digits, '19,548', is read as "
                    "thousands); Fix: export the column with '.' decimals, or the file with ';' "
                    "as the separator and pass decimal=','"
                )
        raise LogError(
            f"{tab.source}, line {line}, column {name!r} ({target}): expected a number, got "
            f"{text!r} — {hint}"
        )
    if target.startswith("ticks.") and src.factor == 1.0 and src.unit in ("", "count"):
        try:  # counts are whole numbers, unless the map scales them (derived values)
            check_counts(raw, f"{tab.source}: column {name!r} ({target})", tab.lines)
        except SchemaError as exc:
            raise LogError(str(exc)) from None
    with np.errstate(over="ignore", invalid="ignore"):
        v = src.sign * raw * src.factor + src.offset
    row_unit = tab.units[j] if tab.units else ""
    unit = src.unit or row_unit or si
    what = f"{tab.source}: column {name!r} ({target})"
    if not src.unit and row_unit:
        what += f" in {row_unit!r} by the units row under the header"
    return convert_units(v, unit, si, what=what)


def _time_of(tab: Table, src: Source | None, robot_rows: bool) -> tuple[FloatArray, str]:
    """The stamps (s) of ``tab``'s rows and how they were made."""
    if src is None:
        if robot_rows:
            return np.arange(tab.n_rows, dtype=float), "row"
        raise LogError(
            f"{tab.source}: the column map gives no time for this file. Fix: add 't=COLUMN[:unit]' "
            "(or 't=FILE::COLUMN' per file, or 't=row*DT' for rows at a fixed period DT)"
        )
    if src.row_period is not None:
        period = float(convert_units(src.row_period, src.unit or "s", "s", what="t=row*DT"))
        if not (math.isfinite(period) and period > 0):
            raise LogError(f"column map: t={src.text}: the row period must be positive")
        return np.arange(tab.n_rows, dtype=float) * period, "row"
    j = tab.index(src.column)
    t = _values(tab, j, src, "s", "t")
    ok = np.isfinite(t)
    if ok.sum() >= 2 and np.ptp(t[ok]) == 0.0:
        raise LogError(
            f"{tab.source}: the time column {tab.names[j]!r} is constant ({t[ok][0]:g}) and "
            "cannot order the rows. Fix: if the rows come at a fixed rate, give it instead: "
            "'t=row*DT' (e.g. t=row*0.02 for 50 Hz)"
        )
    return t, "column"


def read_table_logs(
    paths: Sequence[str | os.PathLike[str]],
    column_map: ColumnMap | str | Mapping[str, Any],
    *,
    delimiter: str | None = None,
    decimal: str | None = None,
    params: DiffDriveParams | Mapping[str, Any] | None = None,
    meta: Mapping[str, Any] | None = None,
    nan: str = "raise",
    robot: str = "diffdrive",
    duplicates: str = "raise",
    max_gap: float | None = None,
    warn: Callable[[str], None] | None = None,
    limits: ResourceLimits | None = None,
) -> list[Log]:
    """Read one recording (one file, or several files of one run) into logs.

    Parameters
    ----------
    paths : sequence of path-like
        The files of one recording; several files are aligned on their own stamps.
    column_map : ColumnMap, str or mapping
        See :mod:`~realitygap.diagnosis.logs.importers.column_map`.
    delimiter, decimal : str, optional
        Forced field separator and decimal mark (default: detected per file).
    params : DiffDriveParams or mapping, optional
        Nominal robot parameters for ``meta["params"]`` (default: the Kobuki-like
        defaults for a differential drive; required for an arm).
    meta : mapping, optional
        Extra metadata (e.g. ``{"firmware": {"a_max": 1.0, "alpha_max": 4.0}}``).
    nan : {"raise", "interpolate", "drop"}
        Missing values within a channel's sample.
    robot : str
    duplicates : {"raise", "last", "mean"}
        Repeated stamps within a channel.
    max_gap : float, optional
        Longest gap (s) in a channel that may be interpolated over when channels are
        aligned; default ``limits.max_gap_steps`` of the channel's median period.
        A longer gap splits the log.
    warn : callable, optional
        Receives a message for every piece split off or dropped.

    Returns
    -------
    list of Log
        One log, or the pieces of one split at gaps (named ``<name>_part-K``).

    Raises
    ------
    LogError
        With the file name, line or column and the fix.
    """
    if not paths:
        raise LogError("no file given to read")
    files = [Path(p) for p in paths]
    cmap = (
        column_map
        if isinstance(column_map, ColumnMap)
        else (
            ColumnMap.parse(column_map)
            if isinstance(column_map, str)
            else ColumnMap.from_dict(column_map)
        )
    )
    try:
        return _read_mapped(
            files,
            cmap,
            delimiter,
            decimal,
            params,
            meta,
            nan,
            robot,
            duplicates,
            max_gap,
            warn,
            limits,
        )
    except LogError as exc:
        if cmap.source and cmap.source not in str(exc) and "column map" in str(exc):
            raise LogError(f"{exc} (the column map is {cmap.source})") from None
        raise


def _read_mapped(
    files: list[Path],
    cmap: ColumnMap,
    delimiter: str | None,
    decimal: str | None,
    params: DiffDriveParams | Mapping[str, Any] | None,
    meta: Mapping[str, Any] | None,
    nan: str,
    robot: str,
    duplicates: str,
    max_gap: float | None,
    warn: Callable[[str], None] | None,
    limits: ResourceLimits | None,
) -> list[Log]:
    """:func:`read_table_logs` once the column map is parsed."""
    if nan not in ("raise", "interpolate", "drop"):
        raise ValueError(f"nan must be 'raise', 'interpolate' or 'drop', got {nan!r}")
    if duplicates not in DUPLICATE_POLICIES:
        raise ValueError(
            f"duplicates must be one of {', '.join(DUPLICATE_POLICIES)}, got {duplicates!r}"
        )
    if max_gap is not None and not (isinstance(max_gap, (int, float)) and max_gap > 0):
        raise ValueError(f"max_gap must be a positive number of seconds, got {max_gap!r}")
    _check_robot_channels(cmap, robot, files)
    lim = limits if limits is not None else ResourceLimits.from_environment()
    say = warn if warn is not None else (lambda msg: None)
    tables = [read_table(p, delimiter=delimiter, decimal=decimal, limits=lim) for p in files]
    chans = cmap.channels()
    pose_rows = bool(chans) and all(c in POSE_ROW_CHANNELS for c in chans)
    for tab in tables:
        if tab.n_rows < 2:
            raise LogError(f"{tab.source}: expected at least two data rows, found {tab.n_rows}")

    # ---- every channel's samples, on its own stamps
    times: dict[int, tuple[FloatArray, str]] = {}
    streams: dict[str, Stream] = {}
    drop_rows: dict[int, npt.NDArray[np.bool_]] = {
        k: np.zeros(t.n_rows, bool) for k, t in enumerate(tables)
    }
    for chan, cols in chans.items():
        spec = standard_channels()[chan]
        missing = [c for c in spec.columns if c not in cols]
        if missing:
            raise LogError(
                f"{', '.join(str(p) for p in files)}: channel {chan!r} needs columns "
                f"{', '.join(spec.columns)}; the column map gives no {', '.join(missing)}"
            )
        cols = {c: _literal(src, tables) for c, src in cols.items()}
        where = [_resolve(tables, cols[c], f"{chan}.{c}") for c in spec.columns]
        ks = {k for k, _ in where}
        if len(ks) > 1:
            raise LogError(
                f"column map: channel {chan!r} takes columns from several files "
                f"({', '.join(tables[k].source.name for k in sorted(ks))}); a channel's columns "
                "must come from one file (one stream)"
            )
        k = ks.pop()
        tab = tables[k]
        if k not in times:
            times[k] = _time_of(tab, cmap.time_for(tab.source), pose_rows)
        vals = np.column_stack(
            [
                _values(tab, j, cols[c], spec.units[i], f"{chan}.{c}")
                for i, (c, (_, j)) in enumerate(zip(spec.columns, where))
            ]
        )
        ok = np.isfinite(vals)
        full, empty = ok.all(axis=1), ~ok.any(axis=1)
        partial = ~full & ~empty
        if partial.any():
            if nan == "raise":
                r = int(np.flatnonzero(partial)[0])
                c = int(np.flatnonzero(~ok[r])[0])
                name = tab.names[where[c][1]]
                raise LogError(
                    f"{tab.source}, line {tab.lines[r]}: missing or non-finite value in column "
                    f"{name!r} for {chan + '.' + spec.columns[c]!r} ({int(partial.sum())} such "
                    "rows). Fix: clean the file, or pass nan='interpolate' (CLI --nan "
                    "interpolate) or nan='drop'"
                )
            if nan == "drop":
                drop_rows[k] |= partial
        streams[chan] = Stream(chan, tab, times[k][0], vals, tab.lines, np.arange(tab.n_rows))
    # ---- missing stamps of rows that hold a sample: filled (between regular neighbours),
    # dropped or refused, per nan=
    for k, tab in enumerate(tables):
        if k not in times:
            continue
        t_all, how = times[k]
        sample = np.zeros(tab.n_rows, bool)
        for s in streams.values():
            if s.table is tab:
                sample |= np.isfinite(s.values).any(axis=1)
        bad_t = sample & ~np.isfinite(t_all)
        if not bad_t.any():
            continue
        r = int(np.flatnonzero(bad_t)[0])
        if nan == "interpolate":
            try:
                times[k] = (fill_time(t_all, str(tab.source), tab.lines), how)
            except SchemaError as exc:
                raise LogError(str(exc)) from None
            say(
                f"{tab.source}: {int(bad_t.sum())} missing time stamp(s), the first at line "
                f"{tab.lines[r]}, interpolated between their regular neighbours (nan='interpolate')"
            )
        elif nan == "drop":
            drop_rows[k] |= bad_t
        else:
            raise LogError(
                f"{tab.source}, line {tab.lines[r]}: a row holds a sample but its time stamp is "
                f"missing ({int(bad_t.sum())} such rows). Fix: repair the time column, or pass "
                "nan='interpolate' (CLI --nan interpolate: fills a stamp between regular "
                "neighbours) or nan='drop' (CLI --nan drop)"
            )
    for chan, s in list(streams.items()):
        k = tables.index(s.table)
        streams[chan] = Stream(chan, s.table, times[k][0], s.values, s.lines, s.rows)

    # ---- rows: drop, fill, select each channel's samples
    for chan, s in list(streams.items()):
        k = tables.index(s.table)
        vals = s.values
        ok = np.isfinite(vals)
        keep = ok.any(axis=1) & ~drop_rows[k] & np.isfinite(s.t)
        if nan == "interpolate" and (keep & ~ok.all(axis=1)).any():
            vals = vals.copy()
            try:
                vals[keep] = fill_gaps(s.t[keep], vals[keep])
            except LogError as exc:
                raise LogError(f"{s.table.source}: channel {chan!r}: {exc}") from None
        if int(keep.sum()) < 2:
            raise LogError(
                f"{s.table.source}: channel {chan!r} has {int(keep.sum())} complete sample(s); a "
                "log needs at least two. Fix: check the column map"
            )
        streams[chan] = Stream(chan, s.table, s.t[keep], vals[keep], s.lines[keep], s.rows[keep])

    name = files[0].stem if len(files) == 1 else "+".join(p.stem for p in files)
    source = ",".join(str(p) for p in files)
    full_meta = _meta(params, meta, robot, name, source)
    read = _Assembly(cmap, times, tables, duplicates, pose_rows, max_gap, lim, say)

    # ---- clock resets and discontinuities: the recording is read as the pieces between them
    pieces = reset_pieces(streams, tables, say, full_meta.get("params"), cmap.ticks)
    if len(pieces) == 1:
        return read.logs(streams, name, source, full_meta)
    out: list[Log] = []
    for p, part in enumerate(pieces):
        pname = f"{name}_part-{p + 1}"
        if any(s.t.shape[0] < 2 for s in part.values()):
            say(f"{source}: piece {p + 1} between the splits dropped: fewer than two samples")
            continue
        out += read.logs(part, pname, source, {**full_meta, "name": pname, "piece_of": name})
    if not out:
        raise LogError(f"{source}: no piece between the splits (clock resets, jumps) holds a log")
    return out


@dataclass(frozen=True)
class _Assembly:
    """What turns one run's channel samples into logs (:meth:`logs`)."""

    cmap: ColumnMap
    times: Mapping[int, tuple[FloatArray, str]]
    tables: Sequence[Table]
    duplicates: str
    pose_rows: bool
    max_gap: float | None
    lim: ResourceLimits
    say: Callable[[str], None]

    def logs(
        self, streams: dict[str, Stream], name: str, source: str, meta: Mapping[str, Any]
    ) -> list[Log]:
        """One run's streams (repeated stamps resolved, angles unwrapped, counters unwrapped
        and accumulated) on one time base: one log, or the pieces of one split at gaps."""
        streams = {c: dedupe(s, self.duplicates) for c, s in streams.items()}
        full_meta = dict(meta)
        # ---- angles continuous, counters unwrapped, increments accumulated (own samples)
        for chan, s in streams.items():
            spec = standard_channels()[chan]
            values = s.values.copy()
            for j in spec.angle_columns:
                values[:, j] = np.unwrap(values[:, j])
            if chan == "ticks" and self.cmap.ticks == "increments":
                values = np.cumsum(values, axis=0) - values[0]
            elif chan == "ticks":
                wraps = []
                for j, col in enumerate(spec.columns):
                    values[:, j], m = unwrap_counter(values[:, j])
                    if m is not None:
                        wraps.append(f"ticks.{col} at {m}")
                if wraps:
                    note = (
                        f"the tick counter wraps ({', '.join(wraps)}); unwrapped into "
                        "cumulative counts"
                    )
                    full_meta["ticks_unwrapped"] = note
                    self.say(f"{s.table.source}: {note}")
            streams[chan] = Stream(chan, s.table, s.t, values, s.lines, s.rows)

        # ---- one time base
        first = next(iter(streams.values()))
        same_rows = len({id(s.table) for s in streams.values()}) == 1 and all(
            np.array_equal(s.rows, first.rows) for s in streams.values()
        )
        if same_rows:
            base_t = first.t
            k = self.tables.index(first.table)
            tsrc = self.cmap.time_for(first.table.source)
            regularised = False
            if tsrc is not None and tsrc.row_period is None and self.times[k][1] == "column":
                decimals, quantum = _time_quantum(first.table, tsrc)
                base_t, regularised = regularise_rounded_time(base_t, quantum)
            if regularised:
                full_meta["time_regularised"] = (
                    f"time written with {decimals} decimals; stamps replaced by the regular grid "
                    "they round to"
                )
            channels = {c: s.values for c, s in streams.items()}
            return [Log(t=base_t, channels=channels, meta=full_meta, source=source)]
        if self.pose_rows:
            raise LogError(
                f"{source}: the arm's channels ({', '.join(streams)}) are not on the same rows; "
                "each row must hold one pose's joint readings and its measurement"
            )
        return align_streams(
            {c: (st.t, st.values) for c, st in streams.items()},
            name=name,
            source=source,
            meta=full_meta,
            max_gap=self.max_gap,
            limits=self.lim,
            warn=self.say,
        )


def _time_quantum(tab: Table, src: Source) -> tuple[int, float]:
    """The decimals and the resolution (s) the time column was written with (text files),
    else ``(0, 0.0)``."""
    if not tab.decimals or src.column is None:
        return 0, 0.0
    decimals = tab.decimals[tab.index(src.column)]
    if decimals == 0:
        return 0, 0.0
    q = 10.0**-decimals * abs(src.factor)
    return decimals, float(convert_units(q, src.unit or "s", "s"))


def _a(word: str) -> str:
    return f"{'an' if word[:1] in 'aeiou' else 'a'} {word}"


def _check_robot_channels(cmap: ColumnMap, robot: str, files: Sequence[Path]) -> None:
    """Refuse a column map that gives none of ``robot``'s channels (a log of another robot, or
    the wrong robot named), before anything else is asked of that robot."""
    own = ROBOT_CHANNELS.get(robot)
    chans = list(cmap.channels())
    if own is None or not chans or any(c.name in chans for c in own):
        return
    other = next(
        (
            r
            for r, specs in ROBOT_CHANNELS.items()
            if all(c in {s.name for s in specs} for c in chans)
        ),
        None,
    )
    fix = (
        f"the map's channels are {_a(other)} log's: read it as one (robot={other!r}, CLI --robot "
        f"{other}, or leave the robot to the column map)"
        if other
        else f"map the {robot} log's channels"
    )
    raise LogError(
        f"{', '.join(map(str, files))}: read as {_a(robot)} log (robot={robot!r}), but the column "
        f"map gives none of its channels ({', '.join(c.name for c in own)}); it gives "
        f"{', '.join(chans)}. Fix: {fix}"
    )


def _meta(
    params: DiffDriveParams | Mapping[str, Any] | None,
    meta: Mapping[str, Any] | None,
    robot: str,
    name: str,
    source: str,
) -> dict[str, Any]:
    if isinstance(params, DiffDriveParams):
        pmeta: dict[str, Any] = params_to_meta(params)
    elif params is None:
        if robot != "diffdrive":
            raise LogError(
                f"{source}: {_a(robot)} log needs its nominal parameters. Fix: pass --robot-file "
                "robot.yaml or --urdf robot.urdf (see docs/your_robot.md)"
            )
        pmeta = params_to_meta(DiffDriveParams())
    else:
        pmeta = dict(params)
    full: dict[str, Any] = {"robot": robot, "params": pmeta, "name": name, "source": source}
    full.update(dict(meta or {}))
    return full


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
    duplicates: str = "raise",
) -> Log:
    """Read one table file into one :class:`~realitygap.diagnosis.logs.log.Log`
    (:func:`read_table_logs` with one file; an error if its channels' gaps would split it).

    Raises
    ------
    LogError
        With the file name and the fix: not a table, missing columns, non-numeric or
        missing values, unknown or mismatched units, non-monotonic time.
    """
    return whole(
        lambda warn: read_table_logs(
            [path],
            column_map,
            delimiter=delimiter,
            decimal=decimal,
            params=params,
            meta=meta,
            nan=nan,
            robot=robot,
            duplicates=duplicates,
            warn=warn,
        ),
        path,
        "read_table_logs",
    )
