"""A channel's samples read from a table (:class:`Stream`), and where a recording is cut:
repeated stamps (:func:`dedupe`), clock resets and jumps no robot can make
(:func:`reset_pieces`)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.logs.importers.table import Table
from realitygap.diagnosis.logs.log import LogError
from realitygap.diagnosis.logs.schema import (
    RESET_PERIODS,
    SchemaError,
    clock_resets,
    discontinuities,
    unwrap_counter,
)

__all__ = ["DUPLICATE_POLICIES", "Stream", "dedupe", "jump_rows", "reset_pieces"]

FloatArray = npt.NDArray[np.float64]

DUPLICATE_POLICIES = ("raise", "last", "mean")
"""What :func:`dedupe` does with repeated stamps within a channel."""


@dataclass
class Stream:
    """One channel's samples: its stamps (s), values (SI) and file lines."""

    name: str
    table: Table
    t: FloatArray
    values: FloatArray
    lines: npt.NDArray[np.int64]
    rows: npt.NDArray[np.int64]


def dedupe(stream: Stream, policy: str) -> Stream:
    """``stream`` with strictly increasing stamps (``policy`` for repeated ones)."""
    t = stream.t
    step = np.diff(t)
    back = np.flatnonzero(step < 0)
    if back.size:
        i = int(back[0]) + 1
        raise LogError(
            f"{stream.table.source}: time stamps must increase strictly, but line "
            f"{stream.lines[i]} (t={t[i]:.6g} s) comes after line {stream.lines[i - 1]} "
            f"(t={t[i - 1]:.6g} s) in channel {stream.name!r}: rows out of order (a step back "
            f"of at most {RESET_PERIODS:g} periods; a longer one is read as a clock reset and "
            "splits the recording). Fix: sort the rows by time"
        )
    same = np.flatnonzero(step == 0)
    if not same.size:
        return stream
    if policy == "raise":
        i = int(same[0]) + 1
        raise LogError(
            f"{stream.table.source}: channel {stream.name!r} has {same.size} repeated time "
            f"stamp(s), first at line {stream.lines[i]} (t={t[i]:.6g} s, as line "
            f"{stream.lines[i - 1]}). Fix: say what they mean with --duplicates last (a "
            "re-sent sample: keep the last) or --duplicates mean (average them), or repair the "
            "time column"
        )
    starts = np.concatenate([[0], np.flatnonzero(step > 0) + 1])
    if policy == "last":
        keep = np.concatenate([starts[1:] - 1, [t.shape[0] - 1]])
        return Stream(
            stream.name,
            stream.table,
            t[keep],
            stream.values[keep],
            stream.lines[keep],
            stream.rows[keep],
        )
    sums = np.add.reduceat(stream.values, starts, axis=0)
    counts = np.diff(np.concatenate([starts, [t.shape[0]]]))
    return Stream(
        stream.name,
        stream.table,
        t[starts],
        sums / counts[:, None],
        stream.lines[starts],
        stream.rows[starts],
    )


def jump_rows(
    streams: dict[str, Stream], params: Any, ticks_mode: str
) -> list[tuple[Stream, int, str]]:
    """Each discontinuity of a pose or tick channel (:func:`~realitygap.diagnosis.logs.schema.
    discontinuities`): its stream, the index of the sample after the jump and what jumped."""
    out: list[tuple[Stream, int, str]] = []
    for chan, s in streams.items():
        if chan not in ("ticks", "pose_gt", "pose_est", "pose_cam"):
            continue
        ok = np.isfinite(s.values).all(axis=1) & np.isfinite(s.t)
        t, v = s.t[ok], s.values[ok].copy()
        if t.size < 3 or np.any(np.diff(t) < 0):
            continue  # rows out of order or a reset: found by clock_resets and dedupe
        if chan == "ticks":
            if ticks_mode == "increments":
                v = np.cumsum(v, axis=0)
            else:
                v = np.column_stack([unwrap_counter(v[:, j])[0] for j in range(v.shape[1])])
        try:
            found = discontinuities(chan, t, v, params if isinstance(params, Mapping) else None)
        except SchemaError as exc:
            raise LogError(f"{s.table.source}: {exc}") from None
        idx = np.flatnonzero(ok)
        out += [(s, int(idx[i]), what) for i, what in found]
    return out


def reset_pieces(
    streams: dict[str, Stream],
    tables: Sequence[Table],
    say: Callable[[str], None],
    params: Any = None,
    ticks_mode: str = "cumulative",
) -> list[dict[str, Stream]]:
    """The streams cut at the file's clock resets (a backward jump of the time longer than
    :data:`~realitygap.diagnosis.logs.schema.RESET_PERIODS` periods: a logger restarted), one
    mapping per piece; a warning names each reset. Several files with a reset are refused:
    which piece of one file goes with which of another is not known."""
    cuts: dict[int, list[int]] = {}
    for k, tab in enumerate(tables):
        own = [s for s in streams.values() if s.table is tab]
        if not own:
            continue
        # the table's stamps on the rows any channel samples, in row order
        idx = np.unique(np.concatenate([s.rows for s in own]))
        t = np.full(tab.n_rows, np.nan)
        for s in own:
            t[s.rows] = s.t
        resets, _ = clock_resets(t[idx])
        if resets:
            cuts[k] = [int(idx[i]) for i in resets]
            for i in resets:
                say(
                    f"{tab.source}: the clock was reset at line {tab.lines[idx[i]]} (time goes "
                    f"from {t[idx[i - 1]]:.6g} s back to {t[idx[i]]:.6g} s); the recording is "
                    "read as pieces split there, like a gap (if the rows are only out of order, "
                    "sort them by time instead)"
                )
    jumps = jump_rows(streams, params, ticks_mode)
    for s, i, what in jumps:
        say(
            f"{s.table.source}: line {s.lines[i]} (t={s.t[i]:.6g} s): {what} — a step no robot "
            "can make: two recordings joined? The recording is read as pieces split there, like "
            "a clock reset (if they are one run, repair the channel)"
        )
    if jumps and not cuts and len(tables) > 1:  # continuous time: every file cut at that time
        stamps = sorted({float(s.t[i]) for s, i, _ in jumps})
        out_t: list[dict[str, Stream]] = []
        for a, b in itertools.pairwise([-math.inf, *stamps, math.inf]):
            out_t.append({
                c: Stream(c, s.table, s.t[m], s.values[m], s.lines[m], s.rows[m])
                for c, s in streams.items()
                for m in [(s.t >= a) & (s.t < b)]
            })  # fmt: skip
        return out_t
    for s, i, _ in jumps:
        k = tables.index(s.table)
        cuts[k] = sorted({*cuts.get(k, []), int(s.rows[i])})
    if not cuts:
        return [streams]
    if len(tables) > 1:
        k, at = next(iter(cuts.items()))
        tab = tables[k]
        raise LogError(
            f"{tab.source}, line {tab.lines[at[0]]}: the clock was reset there (the time goes "
            "back) in a recording of several files, whose pieces cannot be paired up. Fix: "
            "split the file at that line and pass each piece with its partner file"
        )
    bounds = [0, *next(iter(cuts.values())), tables[0].n_rows]
    out: list[dict[str, Stream]] = []
    for a, b in itertools.pairwise(bounds):
        part: dict[str, Stream] = {}
        for chan, s in streams.items():
            m = (s.rows >= a) & (s.rows < b)
            part[chan] = Stream(chan, s.table, s.t[m], s.values[m], s.lines[m], s.rows[m])
        out.append(part)
    return out
