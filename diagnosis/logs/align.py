"""Channels recorded at their own rates, aligned on one channel's stamps without inventing data.

A robot's encoders, its commands and a motion-capture system each stamp their own
samples, at their own rates. :func:`align_streams` makes one log of them: it keeps
the stamps of one channel as recorded (the wheel encoders, else the commands:
what the replay is driven by; :data:`BASE_CHANNEL_ORDER`) and interpolates the
others there — commands held until their next sample (:data:`HELD_CHANNELS`),
angles unwrapped, nothing extrapolated. Where a channel has a gap longer than
``max_gap`` (a motion-capture dropout), the rows inside it are not covered and the
log is cut there into pieces (``meta["piece_of"]``); pieces shorter than
:data:`MIN_PIECE_S` are dropped and named. Table files
(:mod:`~realitygap.diagnosis.logs.importers.csv_log`) and bags
(:mod:`~realitygap.diagnosis.logs.importers.rosbag`) both align this way.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.checks import ResourceLimits
from realitygap.diagnosis.logs.log import Log, LogError

FloatArray = npt.NDArray[np.float64]

__all__ = ["BASE_CHANNEL_ORDER", "HELD_CHANNELS", "MIN_PIECE_S", "align_streams", "whole"]

BASE_CHANNEL_ORDER = ("ticks", "cmd", "joints", "pose_gt", "pose_est", "pose_cam", "tether")
"""Whose stamps a log of channels at different rates takes: the first present (else the
channel with the most samples). The replay is driven by the encoders or the commands, so their
samples are kept as recorded and the rest are interpolated onto them."""

HELD_CHANNELS = ("cmd",)
"""Channels whose value holds until the next sample (zero-order hold) when aligned; the others
are interpolated linearly (angles unwrapped by the caller)."""

MIN_PIECE_S = 1.0
"""Shortest piece (s) of a log cut at a channel's gap that is kept as a log."""


def _align(
    name: str, t: FloatArray, v: FloatArray, base_t: FloatArray, max_gap: float
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """A channel's values at ``base_t`` and where they are covered (inside its span and not in
    a gap longer than ``max_gap``)."""
    covered = (base_t >= t[0]) & (base_t <= t[-1])
    for g in np.flatnonzero(np.diff(t) > max_gap):
        covered &= ~((base_t > t[g]) & (base_t < t[g + 1]))
    out = np.empty((base_t.shape[0], v.shape[1]))
    if name in HELD_CHANNELS:
        idx = np.clip(np.searchsorted(t, base_t, side="right") - 1, 0, t.shape[0] - 1)
        out[:] = v[idx]
    else:
        for j in range(v.shape[1]):
            out[:, j] = np.interp(base_t, t, v[:, j])
    return out, covered


def _runs(mask: npt.NDArray[np.bool_]) -> list[tuple[int, int]]:
    """``[(start, stop), …]`` of the runs of True in ``mask``."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def align_streams(
    streams: Mapping[str, tuple[FloatArray, FloatArray]],
    *,
    name: str,
    source: str,
    meta: Mapping[str, Any],
    max_gap: float | None = None,
    limits: ResourceLimits | None = None,
    warn: Callable[[str], None] | None = None,
    shift_time: bool = False,
) -> list[Log]:
    """One log (or the pieces of one) from channels sampled at their own stamps.

    Parameters
    ----------
    streams : mapping of channel name to (stamps (n,), values (n, k))
        Each channel's samples, stamps strictly increasing, angles already unwrapped.
    name, source : str
        The log's name and where it came from (for the pieces' names and messages).
    meta : mapping
        The log's metadata (``aligned`` is added; pieces get ``name`` and ``piece_of``).
    max_gap : float, optional
        Longest gap (s) of a channel that may be interpolated over; default
        ``limits.max_gap_steps`` of the channel's median period.
    warn : callable, optional
        Receives a message when rows are cut off or pieces dropped.
    shift_time : bool
        Start each log's time at zero (for stamps of a wall clock).

    Raises
    ------
    LogError
        When no piece of :data:`MIN_PIECE_S` seconds is covered by every channel, naming the
        channels' spans and the fix.
    """
    lim = limits if limits is not None else ResourceLimits.from_environment()
    say = warn if warn is not None else (lambda msg: None)
    order = [c for c in BASE_CHANNEL_ORDER if c in streams]
    base = order[0] if order else max(streams, key=lambda c: streams[c][0].shape[0])
    base_t = streams[base][0]
    aligned: dict[str, FloatArray] = {base: streams[base][1]}
    covered = np.ones(base_t.shape[0], bool)
    notes: list[str] = []
    for chan, (t, v) in streams.items():
        if chan == base:
            continue
        period = float(np.median(np.diff(t)))
        gap = max_gap if max_gap is not None else lim.max_gap_steps * period
        aligned[chan], cov = _align(chan, t, v, base_t, max(gap, period * 1.5))
        covered &= cov
        notes.append(f"{chan} at {1.0 / period if period > 0 else math.inf:.4g} Hz")
    full_meta = dict(meta)
    if notes:
        full_meta["aligned"] = (
            f"channels at their own rates aligned on the stamps of {base!r} "
            f"({1.0 / float(np.median(np.diff(base_t))):.4g} Hz): " + ", ".join(notes)
        )
    pieces = _runs(covered)
    out: list[Log] = []
    for a, b in pieces:
        if b - a < 3 or base_t[b - 1] - base_t[a] < MIN_PIECE_S:
            say(
                f"{source}: rows at t={base_t[a]:.6g}…{base_t[b - 1]:.6g} s dropped: shorter than "
                f"{MIN_PIECE_S:g} s between gaps of the aligned channels"
            )
            continue
        m = dict(full_meta)
        if len(pieces) > 1:
            m["name"] = f"{name}_part-{len(out) + 1}"
            m["piece_of"] = name
        t = base_t[a:b] - (base_t[a] if shift_time else 0.0)
        out.append(
            Log(t=t, channels={c: v[a:b] for c, v in aligned.items()}, meta=m, source=source)
        )
    if len(pieces) > 1 or (pieces and (pieces[0][0] > 0 or pieces[0][1] < base_t.shape[0])):
        lost = base_t.shape[0] - sum(b - a for a, b in pieces)
        say(
            f"{source}: {lost} of {base_t.shape[0]} rows of {base!r} lie outside another "
            f"channel's samples or in a gap longer than its limit (--max-gap); the log is cut "
            f"there into {len(out)} piece(s) instead of inventing values"
        )
    if not out:
        spans = ", ".join(f"{c}: {t[0]:.6g}…{t[-1]:.6g} s" for c, (t, _) in streams.items())
        raise LogError(
            f"{source}: the channels never overlap for {MIN_PIECE_S:g} s without a gap ({spans}). "
            "Fix: check that the channels' stamps share one clock and unit, or raise --max-gap"
        )
    return out


def whole(read: Callable[[Callable[[str], None]], list[Log]], path: Any, reader: str) -> Log:
    """The one log ``read(warn)`` returns for ``path``, or a :class:`LogError` when the
    recording's gaps cut it (what ``warn`` heard, and ``reader``, which returns the pieces)."""
    said: list[str] = []
    logs = read(said.append)
    if len(logs) != 1 or said:
        raise LogError(
            f"{path}: its channels have gaps that cut it ({'; '.join(said)}); read it with "
            f"{reader} (or the command line), which returns the pieces"
        )
    return logs[0]
