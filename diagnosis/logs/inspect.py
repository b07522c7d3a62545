"""``realitygap inspect FILE...``: what recorded files hold, and the command that diagnoses them.

Tables (text, ``.mat``, ``.npz``): each column's cells, range, order, guessed meaning and unit
(from names such as ``time``, ``x_gt``, ``yaw``, ``encL``, ``cmd_v``, ``q1``, ``tool_x``, and
from values: integer-valued steadily changing columns are encoders, magnitudes give units); the
time base (rate, jitter, gaps, repeated stamps) of each stream (columns empty on some rows form
their own); an encoder counting down while the robot drives forward, a heading turning against
the path's curvature. ROS bags: topics, types, counts, rates and the topics to pass. OptiOdom
sessions, UR10 sets and saved logs need no column map. Then one ``realitygap diagnose`` command,
with a ``<placeholder>`` for what the files do not say.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import shlex
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from realitygap.core.checks import check_distinct, check_input_path
from realitygap.diagnosis.logs.guesses import (
    _TIME_FACTOR,
    cumulative,
    name_meaning,
    name_unit,
    time_unit,
    turn_agreement,
)
from realitygap.diagnosis.logs.importers.archive import ArchiveError, archive_members
from realitygap.diagnosis.logs.importers.table import DELIMITERS, Table, read_table
from realitygap.diagnosis.logs.log import LogError, sniff_file_kind, standard_channels

__all__ = ["ColumnInfo", "FileInspection", "Inspection", "StreamInfo", "inspect_path"]
__all__ += ["add_inspect_parser", "inspect_paths", "run_inspect"]

GAP_STEPS = 3.0
"""A step longer than this many median steps is a gap."""

_MOCAP_TOPIC = re.compile(r"mocap|vicon|opti|natnet|qualisys|vrpn|truth|(^|[/_])gt([/_]|$)")
_COLUMNS = dict(
    cmd="v w", ticks="left right", pose_gt="x y theta", pose_est="x y theta", tool_pos="x y z"
)
_SETS = {chan: tuple(f"{chan}.{c}" for c in cs.split()) for chan, cs in _COLUMNS.items()}
_PLACEHOLDER = {"theta": "heading", "v": "linear speed", "w": "angular speed"}
_WHY = {
    "time": "no time column found: name it (t=COLUMN:unit) or give the row period (t=row*DT, s)",
    "drive": "no command (cmd.v, cmd.w) or encoder (ticks.left, ticks.right) column to replay",
    "truth": "no ground-truth pose (pose_gt.x, .y, .theta, e.g. motion capture) to measure the gap",
    "nan": "a channel has some of its columns empty on a row: --nan interpolate fills them",
}


@dataclass
class ColumnInfo:
    """One column of a table: its numbers, and the column-map target it seems to feed
    (``meaning``, e.g. ``"pose_gt.x"``, with ``unit`` and ``sign``; ``""`` if unknown)."""

    name: str
    index: int
    count: int
    minimum: float = math.nan
    maximum: float = math.nan
    monotonic: str = ""  # "increasing", "non-decreasing", "decreasing", "non-increasing"
    integer: bool = False
    meaning: str = ""
    unit: str = ""
    sign: int = 1
    note: str = ""


@dataclass
class StreamInfo:
    """Rows that fill the same columns (or one bag topic), timed in seconds."""

    name: str
    columns: tuple[str, ...]
    rows: int
    rate_hz: float | None = None
    step_s: float | None = None
    jitter_s: float | None = None
    gaps: int = 0
    largest_gap_s: float | None = None
    duplicates: int = 0
    backwards: int = 0


@dataclass
class FileInspection:
    """What one path holds (``kind``: "table", "bag", "optiodom", "ur10", "log" or
    "unreadable"), the column map and options it needs, and what it does not say."""

    path: str
    kind: str
    summary: str
    columns: list[ColumnInfo] = field(default_factory=list)
    streams: list[StreamInfo] = field(default_factory=list)
    mapping: dict[str, str] = field(default_factory=dict)
    options: list[str] = field(default_factory=list)
    missing: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    error: str | None = None
    diagnose: str | None = None  # the path the command names, when not this one


@dataclass
class Inspection:
    """The inspection of one or more paths and the ``realitygap diagnose`` command for them."""

    files: list[FileInspection]
    command: str
    missing: list[str] = field(default_factory=list)
    checks: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        """A JSON-able dict (NaN and infinities as null)."""
        text = json.dumps(asdict(self))
        return json.loads(text, parse_constant=lambda _: None)

    def to_text(self, verbose: bool = False) -> str:
        """For a person: a short table per file, the proposed command, what to check."""
        out: list[str] = []
        for f in self.files:
            out.append(f"{f.path}: {f.summary}")
            out += [f"  cannot read it: {f.error}"] if f.error else []
            shown = f.columns if verbose else f.columns[:40]
            if shown:
                out.append(f"  {'column':<24} {'cells':>7}  {'min .. max':<27} {'order':<15} guess")
            for c in shown:
                span = f"{c.minimum + 0:.6g} .. {c.maximum + 0:.6g}" if c.count else "(empty)"
                guess = f"{'-' if c.sign < 0 else ''}{c.meaning or '?'}"
                guess += f" [{c.unit}]" if c.unit else ""
                guess += f"  ({c.note})" if c.note else ""
                name = c.name if len(c.name) <= 24 else c.name[:23] + "…"
                out.append(f"  {name:<24} {c.count:>7}  {span:<27} {c.monotonic:<15} {guess}")
            if len(f.columns) > len(shown):
                out.append(f"  … {len(f.columns) - len(shown)} more (--verbose shows all)")
            out += [f"  {s.name}: {_timing_text(s)}" for s in f.streams]
            out += [f"  note: {n}" for n in f.notes] + [""]
        out += ["proposed command:", self.command, ""]
        if self.missing:
            out += ["what the files do not say (the <placeholders>):"]
            out += [f"  - {m}" for m in self.missing]
        if self.checks:
            out += ["check:"] + [f"  - {c}" for c in self.checks]
        return "\n".join(out).rstrip() + "\n"


def _timing_text(s: StreamInfo) -> str:
    cols = ", ".join(s.columns)
    rows = "messages" if s.name.startswith("/") else "rows"  # a bag topic, or table rows
    text = f"{cols if len(cols) < 60 else cols[:59] + '…'} — {s.rows} {rows}"
    if s.step_s is None:
        return f"{text}, no usable time"
    text += f" at {1 / s.step_s:.4g} Hz (step {_duration(s.step_s)}, jitter "
    text += f"{_duration(s.jitter_s or 0.0)})"
    if s.gaps:
        text += f", {s.gaps} gap(s) > {GAP_STEPS:g} steps, largest {_duration(s.largest_gap_s)}"
    text += f", {s.duplicates} repeated stamp(s)" if s.duplicates else ""
    return text + (f", {s.backwards} step(s) back in time" if s.backwards else "")


def _duration(v: float | None) -> str:
    if v is None or not math.isfinite(v) or abs(v) < 1e-9:
        return "?" if v is None or not math.isfinite(v) else "0"
    scale, unit = (1.0, "s") if abs(v) >= 1 else (1e3, "ms") if abs(v) >= 1e-3 else (1e6, "µs")
    return f"{v * scale:.3g} {unit}"


# ------------------------------------------------------------------------------ names
def _ref(table: Table, j: int) -> str:
    """Column ``j`` as the column map writes it: a name (quoted when needed) or an index."""
    name = table.names[j]
    if not table.has_header or '"' in name or "'" in name:
        return str(j)
    quote = re.search(r"[,=:*+\-\s]", name) or (name.isdigit() and name != str(j))
    return f'"{name}"' if quote else name


# ------------------------------------------------------------------------------ numbers
def _column_info(table: Table, j: int) -> ColumnInfo:
    v = table.data[:, j]
    ok = v[np.isfinite(v)]
    c = ColumnInfo(table.names[j], j, int(ok.size))
    text = table.text_columns.get(c.name)
    if text:
        c.note = f"text cells, e.g. {text[1]!r:.30} on line {text[0]}"
    if ok.size == 0:
        c.note = c.note or "empty"
        return c
    c.minimum, c.maximum = float(ok.min()), float(ok.max())
    c.integer = bool(np.all(ok == np.round(ok)))
    d = np.diff(ok)
    if d.size and d.any() and (np.all(d >= 0) or np.all(d <= 0)):
        word = "increasing" if np.all(d >= 0) else "decreasing"
        c.monotonic = word if np.all(d != 0) else f"non-{word}"
    c.note = c.note or ("constant" if c.minimum == c.maximum else "")
    return c


def _timing(name: str, columns: tuple[str, ...], t: np.ndarray) -> StreamInfo:
    """Rate, jitter (std of the regular steps), gaps and repeated stamps of stamps ``t`` (s)."""
    s = StreamInfo(name, columns, int(t.size))
    steps = np.diff(t[np.isfinite(t)])
    pos = steps[steps > 0]
    s.duplicates, s.backwards = int(np.sum(steps == 0)), int(np.sum(steps < 0))
    if pos.size == 0:
        return s
    med = float(np.median(pos))
    s.step_s, s.rate_hz = med, 1.0 / med
    s.jitter_s = float(np.std(pos[pos <= GAP_STEPS * med]))
    gaps = pos[pos > GAP_STEPS * med]
    s.gaps, s.largest_gap_s = int(gaps.size), float(gaps.max()) if gaps.size else None
    return s


def _pick_time(table: Table, cols: list[ColumnInfo]) -> int | None:
    """The time column: by name, else the first steadily increasing column."""
    named = [c for c in cols if c.meaning == "time" and c.count > 1]
    if named:  # a named one even when unusable (then the rows need a period)
        return max(named, key=lambda c: (c.note != "constant", c.count, -c.index)).index
    for c in (c for c in cols if c.meaning == ""):
        d = np.diff(table.data[:, c.index][np.isfinite(table.data[:, c.index])])
        if c.count >= 0.9 * table.n_rows and d.size > 2 and np.mean(d > 0) > 0.9:
            if not (c.integer and np.all(d == 1)):  # a row counter
                return c.index
    return None


def _units(c: ColumnInfo, v: np.ndarray, kind: str) -> str:
    """Unit of a column: stated by its name, else from the range of its values."""
    stated = name_unit(c.name)
    ok = v[np.isfinite(v)]
    if stated or ok.size == 0:
        return stated
    big = float(np.max(np.abs(ok)))
    if kind in ("pose", "tool"):
        return "mm" if float(np.ptp(ok)) > 25.0 or big > 100.0 else "m"
    if kind in ("heading", "joint"):
        jumps = np.abs(np.diff(ok))
        wrapped_deg = jumps.size > 0 and 300.0 < float(jumps.max()) < 370.0
        return "deg" if wrapped_deg or big > 2 * math.pi * 1.1 else "rad"
    if kind == "cmd.v":
        return "mm/s" if big > 5.0 else "m/s"
    if kind == "cmd.w":
        return "deg/s" if big > 10.0 else "rad/s"
    return "count" if kind == "ticks" else ""


def _encoder_directions(t: Any, enc: list[Any], counts_up: bool, pose: Any) -> list[float]:
    """Net count of each encoder over the rows where the robot moves forward (along its
    heading when ``pose`` has one; any displacement otherwise; every row without a pose)."""
    rows = np.all([np.isfinite(e) for e in enc], axis=0) & np.isfinite(t)
    te = t[rows]
    inc = [np.diff(e[rows]) if counts_up else e[rows][1:] for e in enc]
    ok = np.isfinite(pose[0]) & np.isfinite(pose[1]) & np.isfinite(pose[2]) if pose else None
    if pose is None or ok is None or ok.sum() < 3 or te.size < 3:
        return [float(np.sum(i)) for i in inc]
    tp, x, y, th = pose
    order = np.argsort(tp[ok])
    dx, dy = (np.diff(np.interp(te, tp[ok][order], v[ok][order])) for v in (x, y))
    if th is not None and np.isfinite(th[ok]).all():
        h = np.interp(te, tp[ok][order], np.unwrap(th[ok][order]))
        mid = 0.5 * (h[1:] + h[:-1])
        forward = dx * np.cos(mid) + dy * np.sin(mid)
    else:
        forward = np.hypot(dx, dy)
    moving = forward > 0.25 * np.percentile(np.abs(forward), 90)
    return [float(np.sum(i[moving])) for i in inc]


# ------------------------------------------------------------------------------ tables
def _inspect_table(path: Path, table: Table) -> FileInspection:
    n = table.n_rows
    if table.kind == "text":
        where = "a header" if table.has_header else "no header (columns named 0, 1, …)"
        sep = DELIMITERS[table.delimiter or ","]
        summary = f"text, {sep}-separated, decimal '{table.decimal}', {where}, {n} rows"
        summary += f" from line {table.lines[0]}" if n else ""
        if table.skipped:
            summary += f"; {len(table.skipped)} line(s) above skipped: {table.skipped[0]!r:.60}"
    else:
        summary = f"{'MATLAB' if table.kind == 'mat' else 'NumPy'} file, {n} rows"
    f = FileInspection(str(path), "table", summary)
    f.notes += list(table.skipped) if table.kind != "text" else []
    if table.encoding.startswith("UTF-16") or table.encoding.startswith("UTF-32"):
        # diagnose reads UTF-8 text only: the command names the converted copy
        utf8 = path.with_name(f"{path.stem}-utf8{path.suffix}")
        f.summary += f"; {table.encoding} text"
        f.diagnose = str(utf8)
        f.notes.append(
            f"{table.encoding} text: realitygap diagnose reads UTF-8. Fix: convert it first, "
            f"iconv -f {table.encoding.split()[0]} -t UTF-8 {shlex.quote(str(path))} > "
            f"{shlex.quote(str(utf8))} (the command below names the converted file)"
        )
    cols = f.columns = [_column_info(table, j) for j in range(len(table.names))]
    details: dict[int, str] = {}
    for c in cols:
        c.meaning, details[c.index] = name_meaning(c.name)
    tj = _pick_time(table, cols)
    t_s = np.arange(n, dtype=float)
    t_ok = False
    if tj is not None:
        tc = cols[tj]
        unit, how = time_unit(table.data[:, tj], name_unit(tc.name))
        tc.meaning, tc.unit, tc.note = "t", unit, tc.note or how
        t_s = (table.data[:, tj] - np.nanmin(table.data[:, tj])) * _TIME_FACTOR[unit]
        steps = np.diff(t_s[np.isfinite(t_s)])
        t_ok = tc.count > 2 and tc.note != "constant" and bool(np.any(steps > 0))
    f.streams = _streams(table, cols, tj if t_ok else None, t_s)
    for c in cols:  # the other time candidates' own timing
        if c.meaning == "time" and c.index != tj and c.count > 2:
            v = table.data[:, c.index]
            unit, _ = time_unit(v, name_unit(c.name))
            t_c = (v - np.nanmin(v)) * _TIME_FACTOR[unit]
            f.streams.append(_timing(f"time candidate {c.name} [{unit}]", (c.name,), t_c))
    _assign(table, cols, tj, details, f)
    _conventions(table, cols, t_s, f)
    _mapping(table, cols, tj, t_ok, f)
    return f


def _streams(table: Table, cols: list[ColumnInfo], tj: int | None, t_s: Any) -> list[StreamInfo]:
    """Columns grouped by the rows they fill; each group's timing (when there is a time)."""
    filled = np.isfinite(table.data)
    n = table.n_rows
    groups: dict[bytes, list[int]] = {}
    for c in cols:
        if c.index != tj and c.count:
            mask = filled[:, c.index] if c.count < 0.99 * n else np.ones(n, bool)
            groups.setdefault(np.packbits(mask).tobytes(), []).append(c.index)
    if len(groups) <= 1:
        parts = [("rows", [j for g in groups.values() for j in g], np.ones(n, bool))]
    else:
        ordered = sorted(groups.values(), key=lambda g: -cols[g[0]].count)
        parts = [(f"stream {k + 1}", g, filled[:, g[0]]) for k, g in enumerate(ordered)]
    named = [(name, tuple(table.names[j] for j in g), rows) for name, g, rows in parts]
    if tj is None:
        return [StreamInfo(name, g, int(rows.sum())) for name, g, rows in named]
    return [_timing(name, g, t_s[rows]) for name, g, rows in named]


def _assign(
    table: Table, cols: list[ColumnInfo], tj: int | None, details: dict[int, str], f: FileInspection
) -> None:
    """Column-map targets of the columns, with units; encoders also guessed from the values."""
    taken: dict[str, int] = {}
    numbered = [int(details[c.index]) for c in cols if c.meaning == "joint" and details[c.index]]
    base = 1 if numbered and min(numbered) == 0 else 0  # joints numbered from 0 (M[0], joint_0)
    order = iter(range(1, 100))
    has_gt = any(c.meaning in ("pose", "heading") and details[c.index][:2] == "gt" for c in cols)
    arm = sum(c.meaning == "joint" for c in cols) >= 6  # positions are then the measured point
    for c in cols:
        v = table.data[:, c.index]
        kind, detail = c.meaning, details[c.index]
        if kind == "" and c.index != tj and c.integer and c.count > 3 and not c.note:
            ok = v[np.isfinite(v)]
            d = np.diff(ok)  # many values, changing on many rows; not a row counter
            if np.unique(ok).size > 10 and np.mean(d != 0) > 0.2 and not np.all(d == 1):
                kind, detail, c.note = "ticks", "", "integer-valued, changes steadily"
        if kind in ("", "t", "time") or c.count == 0:
            c.meaning = c.meaning if kind == "t" else ""
            c.note = c.note or ("another time column" if kind == "time" else "")
            continue
        if kind == "pose" and arm:
            kind, detail = "tool", detail.partition(".")[2]
        if kind == "pose" and detail.endswith(".z"):
            c.meaning, c.note = "", c.note or "a height: a wheeled pose is planar"
            continue
        if kind in ("pose", "heading"):
            qual, _, axis = detail.partition(".")
            chan = "pose_est" if qual == "est" or (not qual and has_gt) else "pose_gt"
            target = f"{chan}.{axis or 'theta'}"
        elif kind == "tool":
            target = f"tool_pos.{detail}"
        elif kind == "joint":
            target = f"joints.q{int(detail) + base if detail else next(order)}"
        else:
            target = f"ticks.{detail or '?'}" if kind == "ticks" else kind
        if target in taken:
            c.meaning = ""
            c.note = c.note or f"also looks like {target}; {cols[taken[target]].name} is used"
            continue
        c.meaning, c.unit = target, _units(c, v, kind)
        taken.update({target: c.index} if target != "ticks.?" else {})
    sides = [c for c in cols if c.meaning == "ticks.?"]
    free = [s for s in ("left", "right") if f"ticks.{s}" not in taken]
    for c, side in zip(sides, [*free, "", ""]):
        c.meaning = f"ticks.{side}" if side else ""
        f.notes += [f"{c.name} taken as the {side} encoder by its place: check"] if side else []
    joints = [c for c in cols if c.meaning.startswith("joints.")]
    for c in joints if any(c.unit == "deg" for c in joints) else []:
        c.unit = "deg"


def _col(cols: list[ColumnInfo], target: str) -> ColumnInfo | None:
    return next((c for c in cols if c.meaning == target), None)


def _conventions(table: Table, cols: list[ColumnInfo], t_s: Any, f: FileInspection) -> None:
    """Heading sign against the path's curvature; encoder directions against forward motion."""
    headings: dict[str, np.ndarray] = {}
    for chan in ("pose_gt", "pose_est"):
        x, y, th = (_col(cols, f"{chan}.{a}") for a in ("x", "y", "theta"))
        if x is None or y is None or th is None:
            continue
        theta = table.data[:, th.index] * (math.pi / 180.0 if th.unit == "deg" else 1.0)
        agree = turn_agreement(table.data[:, x.index], table.data[:, y.index], theta)
        if agree is not None and agree < -0.5:
            th.sign = -1
            use = f"use {chan}.theta=-{_ref(table, th.index)}"
            f.notes.append(f"{th.name} turns against the path: clockwise-positive heading? {use}")
        headings[chan] = theta * th.sign
    left, right = _col(cols, "ticks.left"), _col(cols, "ticks.right")
    if left is None or right is None:
        return
    enc = [table.data[:, left.index], table.data[:, right.index]]
    counts_up = cumulative(enc[0]) and cumulative(enc[1])
    left.note = right.note = "cumulative" if counts_up else "counts per row"
    found = [(ch, _col(cols, f"{ch}.x"), _col(cols, f"{ch}.y")) for ch in ("pose_gt", "pose_est")]
    ch, x, y = next(((ch, x, y) for ch, x, y in found if x and y), ("", None, None))
    d = table.data
    pose = (t_s, d[:, x.index], d[:, y.index], headings.get(ch)) if x and y else None
    net = _encoder_directions(t_s, enc, counts_up, pose)
    big = max(abs(net[0]), abs(net[1]))
    if big == 0 or min(abs(net[0]), abs(net[1])) < 0.3 * big:
        return
    flips = [c for c, s in zip((left, right), net, strict=True) if s < 0]
    if len(flips) == 1 and pose is None:
        what = f"{left.name} and {right.name} count in opposite directions: one mirrored"
        f.notes.append(f"{what}, or the robot mostly turns on the spot (no pose to tell)")
    elif len(flips) == 1 or (flips and pose is not None and pose[3] is not None):
        for c in flips:  # both only when a heading says which way is forward
            c.sign = -1
            how = "mostly decreases while the other increases" if len(flips) == 1 else "decreases"
            use = f"use {c.meaning}=-{_ref(table, c.index)}"
            f.notes.append(f"encoder {c.name} {how} as the pose moves forward: mirrored? {use}")


def _source(table: Table, c: ColumnInfo) -> str:
    s = f"{'-' if c.sign < 0 else ''}{_ref(table, c.index)}"
    return f"{s}:{c.unit}" if c.unit and c.unit != "count" else s


def _mapping(
    table: Table, cols: list[ColumnInfo], tj: int | None, t_ok: bool, f: FileInspection
) -> None:
    """The column map: the guessed targets, placeholders for what a channel still lacks."""
    m: dict[str, str] = {}
    arm = any(c.meaning.startswith("joints.") for c in cols)
    if tj is not None and t_ok:
        m["t"] = _source(table, cols[tj])
    elif arm:
        m["t"] = "row*1"
        f.notes.append("no time column: t=row*1 counts the poses (one row per measurement)")
    else:
        m["t"] = "<time column>" if tj is None else "row*<period s>"
        bad = f"the time column {cols[tj or 0].name} is unusable: t=row*DT, DT the period (s)"
        f.missing.append(_WHY["time"] if tj is None else bad)
    joints = sorted((c for c in cols if c.meaning.startswith("joints.")), key=lambda c: c.meaning)
    m.update({c.meaning: _source(table, c) for c in joints})
    known = standard_channels()["joints"].columns
    extra = [c.meaning for c in joints if c.meaning.split(".")[1] not in known]
    f.notes += [f"{', '.join(extra)}: the joints channel has {', '.join(known)}"] if extra else []
    sets = ("tool_pos",) if arm else ("cmd", "ticks", "pose_gt", "pose_est")
    present = [s for s in sets if any(_col(cols, t) for t in _SETS[s]) or s == "tool_pos"]
    for s in present:
        for target in _SETS[s]:
            c, what = _col(cols, target), target.split(".")[1]
            m[target] = _source(table, c) if c else f"<{_PLACEHOLDER.get(what, what)} column>"
        lack = [t for t in _SETS[s] if _col(cols, t) is None]
        if lack:
            f.missing.append(f"no column for {', '.join(lack)} ({s} needs all of its columns)")
    left = _col(cols, "ticks.left")
    if left is not None and left.note == "counts per row":
        m["ticks"] = "increments"
    if arm:
        f.options += ["--robot", "arm"]
    elif "cmd" not in present and "ticks" not in present:
        f.missing.append(_WHY["drive"])
    elif "cmd" not in present:
        f.options += ["--drive", "ticks"]
    if not arm and "pose_gt" not in present:
        f.missing.append(_WHY["truth"])
    # a channel empty on whole rows is sampled at its own rate (read as a stream); only a
    # channel with some of its columns empty on a row has missing values
    counts: dict[str, set[int]] = {}
    for t in m:
        c = _col(cols, t) if t not in ("t", "ticks") else None
        if c is not None:
            counts.setdefault(t.split(".")[0], set()).add(c.count)
    if any(len(v) > 1 for v in counts.values()):
        f.options += ["--nan", "interpolate"]
        f.notes.append(_WHY["nan"])
    f.mapping = m


# ------------------------------------------------------------------------------ other kinds
def _inspect_bag(path: Path) -> FileInspection:
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        msg = "inspecting ROS bags needs the optional dependency rosbags. Fix: pip install"
        raise ImportError(f'{msg} "realitygap[ros]"') from None
    from realitygap.diagnosis.logs.importers.rosbag import BagTopics

    p = path.parent if (path.parent / "metadata.yaml").is_file() else path
    reader = AnyReader([p], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
    try:
        reader.open()
    except Exception as exc:  # rosbags raises its own error types
        raise LogError(f"{p}: cannot open the bag ({type(exc).__name__}: {exc})") from None
    stamps: dict[str, list[int]] = {}
    try:
        types = {c.topic: c.msgtype for c in reader.connections}
        for conn, t_ns, _ in reader.messages():
            stamps.setdefault(conn.topic, []).append(t_ns)
    except Exception as exc:  # rosbags' own errors (a cut chunk): said with the file
        raise LogError(f"{p}: cannot read the bag ({type(exc).__name__}: {exc})") from None
    finally:
        reader.close()
    f = FileInspection(str(path), "bag", f"ROS bag, {len(types)} topic(s)")
    for topic, msgtype in sorted(types.items()):
        f.streams.append(_timing(topic, (msgtype,), np.asarray(stamps.get(topic, [])) * 1e-9))
    short = {tp: mt.split("/")[-1] for tp, mt in sorted(types.items()) if stamps.get(tp)}
    poses = ("PoseStamped", "TransformStamped", "Odometry", "PoseWithCovarianceStamped")
    default = BagTopics()
    found: dict[str, list[str]] = {}
    for option, kinds, prefer, usual in (  # the types of a topic, the name it must or may have
        ("--truth-topic", poses, _MOCAP_TOPIC, None),
        ("--odom-topic", ("Odometry",), re.compile("odom"), default.odom),
        ("--cmd-topic", ("Twist", "TwistStamped"), re.compile("cmd"), default.cmd),
        ("--wheels-topic", ("JointState",), re.compile("joint_states"), None),
    ):
        taken = {t for v in found.values() for t in v}
        hits = [tp for tp, mt in short.items() if mt in kinds and tp not in taken]
        hits.sort(key=lambda tp: not prefer.search(tp.lower()))
        if option in ("--truth-topic", "--odom-topic"):
            hits = [tp for tp in hits if prefer.search(tp.lower())]
        found[option] = hits
        f.options += [option, hits[0]] if hits and hits[0] != usual else []
        f.notes += [f"{option}: also possible: {', '.join(hits[1:])}"] if hits[1:] else []
    if not found["--truth-topic"]:
        tf = " (or /tf with --truth-frame FRAME)" if "/tf" in types else ""
        f.missing.append(f"no motion-capture pose topic: name it with --truth-topic{tf}")
        f.options += ["--truth-topic", "<truth topic>"]
    if found["--wheels-topic"] and not found["--cmd-topic"]:
        f.options += ["--drive", "ticks"]
    elif not found["--cmd-topic"]:
        f.missing.append("no Twist command topic and no JointState wheel topic to replay")
    return f


def _inspect_one(p: Path, delimiter: str | None, decimal: str | None) -> FileInspection:
    """What one path is: a layout needing no column map, a bag, or a table (then analysed)."""
    from realitygap.diagnosis.logs.importers.franka import REQUIRED_KEYS
    from realitygap.diagnosis.logs.log import Log
    from realitygap.diagnosis.logs.read import _looks_like_optiodom, _looks_like_ur10

    try:  # FileNotFoundError goes on; what is there but unreadable is said per file
        check_input_path(p, "FILE", needs="a log needs rows of data", unicode="accept")
    except ValueError as exc:
        return FileInspection(str(p), "unreadable", "not readable", error=str(exc))
    folder = p.absolute().parent
    session = p.is_file() and p.name.startswith(f"{folder.name}_") and _looks_like_optiodom(folder)
    kind = sniff_file_kind(p)
    try:
        if p.is_dir() and _looks_like_optiodom(p):
            from realitygap.diagnosis.logs.importers.optiodom import read_metadata

            for meta in sorted(p.rglob("*_metadata.csv")):  # cheap: the rest is read whole
                try:
                    read_metadata(meta)
                except ValueError as exc:
                    raise LogError(str(exc)) from None
            runs = sorted(p.rglob("*_run-[0-9][0-9].csv"))
            what = f"OptiOdom data: {len({r.parent for r in runs})} session(s), {len(runs)} run(s)"
            return FileInspection(str(p), "optiodom", f"{what}; read without a column map")
        if _looks_like_ur10(p):
            what = f"UR10 laser-tracker {'set' if p.is_dir() else 'measurement file'}"
            summary = f"{what}: joints and tracker positions, read without a column map"
            return FileInspection(str(p), "ur10", summary, options=["--robot", "arm"])
        if p.is_file() and _looks_like_ur10(p.parent):
            # a transform or hand-eye file of a UR10 series: the set's reader reads it
            note = (
                f"part of the UR10 laser-tracker series {p.parent}, whose reader takes this "
                "file with its measurements; no column map"
            )
            return FileInspection(
                str(p),
                "ur10",
                "a file of a UR10 series",
                notes=[note],
                options=["--robot", "arm"],
                diagnose=str(p.parent),
            )
        if kind == "npz":
            kind = "log" if {"t.npy", "meta.json.npy"} <= archive_members(p) else kind
        if kind == "log":
            log = Log.load(p)
            chans = ", ".join(f"{k} ({', '.join(log.spec(k).columns)})" for k in log.channels)
            what = f"saved realitygap log: {log.n} rows at {1 / log.dt:.4g} Hz, channels {chans}"
            return FileInspection(str(p), "log", f"{what}; needs no column map")
        if kind in ("rosbag1", "sqlite", "mcap") or (p / "metadata.yaml").is_file():
            return _inspect_bag(p)
        if p.is_dir():
            raise LogError(f"{p}: a folder of no known layout. Fix: inspect its files")
        table = read_table(p, delimiter=delimiter, decimal=decimal)
        f = _inspect_table(p, table)
    except (LogError, ArchiveError) as exc:
        if not session:
            return FileInspection(str(p), "unreadable", "not readable", error=str(exc))
        f = FileInspection(str(p), "", "not a table")
    if session:  # the session reader knows its files: no column map
        note = f"part of the OptiOdom session {p.parent}, which is read whole without a column map"
        kept = (f.summary, f.columns, f.streams)
        return FileInspection(str(p), "optiodom", *kept, notes=[note], diagnose=str(p.parent))
    if table.kind == "npz" and all(any(k in t for t in table.skipped) for k in REQUIRED_KEYS[1:]):
        f.notes.append("an FR3 eye-in-hand archive: its 4×4 poses are no columns (see franka.py)")
    return f


def inspect_path(path: str | Path, **options: Any) -> Inspection:
    """:func:`inspect_paths` of one file or folder."""
    return inspect_paths([path], **options)


def inspect_paths(
    paths: Sequence[str | Path], *, delimiter: str | None = None, decimal: str | None = None
) -> Inspection:
    """Inspect paths and propose one ``realitygap diagnose`` command for all of them.

    ``delimiter`` and ``decimal`` go to :func:`read_table`; an unreadable file is reported in
    its :class:`FileInspection` (``error``). Raises FileNotFoundError (no such path),
    ValueError (a bad ``delimiter`` or ``decimal``) or ImportError (a bag without ``rosbags``).
    """
    check_distinct(paths, "FILE")  # the command proposed would be refused so
    files = [_inspect_one(Path(p), delimiter, decimal) for p in paths]
    good = [f for f in files if f.kind != "unreadable"]
    tables = [f for f in good if f.kind == "table"]
    joined = _joined(tables)
    for f in tables if joined else []:  # one recording in several files: FILE::COLUMN
        f.diagnose = "+".join(t.path for t in tables)
    named = dict.fromkeys(f.diagnose or f.path for f in good or files)
    words = ["realitygap", "diagnose", *(shlex.quote(p) for p in named)]
    options: list[str] = []
    for f in good:
        for k in range(0, len(f.options), 2):
            options += f.options[k : k + 2] if f.options[k] not in options else []
    words += [o if o.startswith("<") else shlex.quote(o) for o in options]
    missing = [f"{f.path}: {m}" if len(files) > 1 else m for f in files for m in f.missing]
    have = {k.split(".")[0] for k, v in joined or [] if not v.startswith("<")}
    covered = [_WHY["drive"]] if have & {"cmd", "ticks"} else []
    covered += [_WHY["truth"]] if "pose_gt" in have else []
    missing = [m for m in missing if not any(m.endswith(w) for w in covered)]
    checks: list[str] = []
    if tables:
        words += ["--columns", _map_text(joined or list(tables[0].mapping.items()))]
        for other in tables[1:] if not joined else []:
            if other.mapping != tables[0].mapping:
                own = _map_text(list(other.mapping.items()))
                checks.append(f"{other.path} has another layout: its own map is {own}")
        units = {
            f"{c.name}: {c.unit}" for f in tables for c in f.columns if c.unit not in ("", "count")
        }
        if units:
            checks.append(f"the units guessed from names and values ({', '.join(sorted(units))})")
    if any(f.kind in ("table", "bag") for f in good) and "--robot" not in options:
        checks.append(
            "add --robot-file robot.yaml with the wheel radii and track (see docs/your_robot.md)"
        )
    elif any(f.kind == "table" for f in good):
        checks.append(
            "add --robot-file robot.yaml naming the arm's URDF, the measured point in the flange "
            "frame and the instrument's noise (see docs/your_robot.md)"
        )
    if any(f.kind == "bag" for f in good):
        checks.append(
            "bag topics are aligned on the wheel joints' (else the commands') own stamps; "
            "--rate HZ resamples them instead"
        )
    checks += [f"{f.path} could not be read: fix it first (see above)" for f in files if f.error]
    return Inspection(files, " ".join(words), missing, checks)


def _map_text(pairs: list[tuple[str, str]]) -> str:
    """The column map as one shell word, in single quotes."""
    text = ",".join(f"{k}={v}" for k, v in pairs)
    return f"'{text}'" if "'" not in text else shlex.quote(text)


def _joined(tables: list[FileInspection]) -> list[tuple[str, str]] | None:
    """One map for tables that hold different channels of one recording, each column named
    with its file (``FILE::COLUMN``); None when they share a channel or cannot be named."""
    stems = [Path(f.path).stem for f in tables]
    sets = [set(f.mapping) - {"t", "ticks"} for f in tables]
    clash = len(set().union(*sets)) < sum(map(len, sets)) or len(set(stems)) < len(stems)
    odd = [f for f in tables if set('+:"') & set(f.path) or f.mapping["t"][:4] in ("row*", "<tim")]
    if len(tables) < 2 or clash or odd:
        return None
    pairs: list[tuple[str, str]] = []
    for stem, f in zip(stems, tables):
        for k, v in f.mapping.items():
            sign, body = ("-", v[1:]) if v.startswith("-") else ("", v)
            q = v if k == "ticks" or v.startswith("<") else f"{sign}{stem}::{body}"
            pairs += [(k, q)] if (k, q) not in pairs else []
    return pairs


# ------------------------------------------------------------------------------ CLI
def add_inspect_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``inspect`` sub-command to an ``argparse`` sub-parsers object."""
    p = subparsers.add_parser(
        "inspect",
        help="show what recorded files hold and propose the diagnose command",
        description="Look at recorded files (CSV and other tables, .mat, .npz, ROS bags, OptiOdom "
        "sessions, UR10 sets, saved logs): columns with their guessed meaning and unit, time base, "
        "rate, gaps, streams, sign conventions; then a ready realitygap diagnose command.",
        epilog="example:\n  realitygap inspect run1.csv run2.csv --json inspect.json",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("paths", nargs="+", metavar="FILE", help="files or folders to inspect")
    p.add_argument("--json", metavar="PATH", help="also write the inspection as JSON here")
    p.add_argument("--delimiter", help="text tables: field separator (default: detected)")
    p.add_argument("--decimal", choices=(".", ","), help="text tables: decimal mark (detected)")
    p.set_defaults(func=run_inspect)
    return p


def run_inspect(args: argparse.Namespace) -> int:
    """Run the ``inspect`` sub-command; the exit status is 2 when an input cannot be read."""
    from realitygap.core.io import write_json
    from realitygap.core.outputs import Outputs, command_line

    overwrite = bool(getattr(args, "overwrite", False))
    with Outputs(inputs=args.paths, overwrite=overwrite, command=command_line()) as out:
        try:
            stage = out.file(args.json, "--json") if args.json else None
            result = inspect_paths(args.paths, delimiter=args.delimiter, decimal=args.decimal)
        except (ValueError, FileNotFoundError, ImportError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        if stage is not None:
            write_json(stage, result.to_json())
        out.commit()
    human = sys.stderr if args.json == "-" else sys.stdout  # stdout holds the JSON
    print(result.to_text(verbose=bool(getattr(args, "verbose", False))), end="", file=human)
    if args.json and args.json != "-" and not getattr(args, "quiet", False):
        print(f"wrote {args.json}", file=sys.stderr)
    for f in result.files:
        if f.error:
            print(f"error: {f.error}", file=sys.stderr)
    return 2 if any(f.error for f in result.files) else 0
