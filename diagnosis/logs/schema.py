"""One declared schema per channel: what every reader checks a log's numbers against.

A log's channels (:mod:`~realitygap.diagnosis.logs.channels`: columns, SI units, role) say
*what* a column is; this module says what its numbers may be. :data:`SCHEMAS` holds one
:class:`ChannelSchema` per standard channel, :data:`TIME` the schema of the time stamps:

==============  =======  ===============================================  ===========================
channel         dtype    plausible (bound in the SI unit)                 likely mistake it names
==============  =======  ===============================================  ===========================
``t``           time     rate ≥ 1 Hz (wheeled logs); no backward jump     time in ms/µs declared s;
                         (a jump back by more than                        a clock reset (split there)
                         :data:`RESET_PERIODS` periods is a clock reset)
``cmd.v``       real     ``|v| ≤ 2 · v_max``                              mm/s or cm/s declared m/s
``cmd.w``       real     ``|ω| ≤ 2 · w_max``                              deg/s declared rad/s
``ticks``       count    wheel ≤ 3000 rev/min; wheel path 0.5–2 × truth;  counter wrap (unwrapped),
                         whole numbers                                    quadrature ×4, ticks_per_rev
``pose_*.x,y``  real     planar speed ≤ 10 m/s                            mm or cm declared m
``pose_*.θ``    real     turn rate ≤ 2 · w_max, turning with the path     deg declared rad
``joints``      real     ``|q| ≤ 4π``                                     deg declared rad
``tool_pos``    real     spread of the points = spread of the arm's       mm declared m, m declared mm
                         forward kinematics (× 1/4…4), within its reach
``pose3_gt``    real     speed ≤ 10 m/s; ``|r| ≤ 2π``                     mm declared m; deg declared rad
``tether``      real     ``|length| ≤ 1000 m``                            mm declared m
==============  =======  ===============================================  ===========================

(``pose_*`` is ``pose_gt``, ``pose_est`` and ``pose_cam``; ``v_max``, ``w_max`` and
``ticks_per_rev`` come from the log's ``meta["params"]``, the defaults of
:class:`~realitygap.robots.diffdrive.DiffDriveParams` when it has none.)

**Dtypes.** :func:`as_real` accepts float and integer arrays and refuses booleans (a flag
replayed as 1 m/s), complex numbers, text, objects and dates, saying which; :func:`as_seconds`
converts ``datetime64`` (POSIX seconds) and ``timedelta64`` stamps to float seconds; a
``count`` column read from a file holds whole numbers (:func:`check_counts`), unless the
column map scales it (a factor says the values are derived).

**Counters.** An encoder counter that wraps (at 2¹⁵, 2¹⁶, 2²⁴ or 2³²) is unwrapped by the
table reader (:func:`unwrap_counter`, with a note); a log whose ticks still wrap is refused
by :func:`~realitygap.diagnosis.logs.plausibility.check_log`, naming the modulus.

**Discontinuities.** A single step of a position (``pose_*.x, y``) or a tick count no robot
can make — more than :data:`JUMP_FACTOR` times what the schema's rate limit (10 m/s; 3000
rev/min) allows over that step's interval, in a channel whose ordinary steps keep to the limit
— is a discontinuity: two recordings joined with continuous time (a teleport). It is handled
like a clock reset, by the same principle: the rows on either side are each a consistent
recording, only the join is not, so a table file is read as the pieces split there, with a
warning naming the line and the jump (:func:`discontinuities`); nothing is bridged or dropped
silently. More than :data:`MAX_JUMPS` such steps in one channel are no join but a broken
channel (a glitching tracker, a wrong column) and are refused, naming the first line.
Ordinary steps beyond the limit are a unit mistake, which :func:`~realitygap.diagnosis.logs.plausibility.check_log` names instead.

**Conventions.** A heading that turns the other way than its path (a clockwise-positive
heading mapped without ``-``, :func:`~realitygap.diagnosis.logs.guesses.turn_agreement`, the
same test ``realitygap inspect`` makes) is refused when the path turns enough to tell
(:data:`MIN_TURN_RAD`); a wheel path that matches the truth only with one wheel's ticks negated
is named as a mirrored encoder first.

**Clock resets.** A time column that jumps back by more than :data:`RESET_PERIODS` of its
periods was reset (a logger restarted): a table file is read as the pieces between resets, as
a gap splits a log (:func:`clock_resets`); a smaller backward step is rows out of order, an
error. A missing stamp between regular neighbours may be interpolated (:func:`fill_time`).

Every failure raises :class:`SchemaError` (a ``ValueError``) naming the file, the channel and
column, what was expected, what came and the fix; the readers re-raise it as
:class:`~realitygap.diagnosis.logs.log.LogError`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum
from types import MappingProxyType
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.logs.channels import ChannelSpec, standard_channels

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "COUNTER_MODULI",
    "RESET_PERIODS",
    "SCHEMAS",
    "TIME",
    "Bound",
    "ChannelSchema",
    "DType",
    "Measure",
    "SchemaError",
    "TimeSchema",
    "as_real",
    "as_seconds",
    "check_counts",
    "check_values",
    "clock_resets",
    "counter_wrap",
    "discontinuities",
    "dtype_problem",
    "fill_time",
    "unwrap_counter",
]


class SchemaError(ValueError):
    """A value does not fit its channel's schema; the message names where, what and the fix."""


class DType(str, Enum):
    """What kind of numbers a channel holds."""

    REAL = "real"
    """Real numbers: float or integer arrays."""
    COUNT = "count"
    """Counts (encoder ticks): integer arrays, or floats that are whole numbers."""
    TIME = "time"
    """Seconds: real numbers, or ``datetime64`` / ``timedelta64`` converted to seconds."""


class Measure(str, Enum):
    """What a :class:`Bound` measures on its columns (99th percentiles: a spike is no unit)."""

    VALUE = "value"  #: ``|value|``
    SPEED = "speed"  #: the speed of a position over rows
    TURN_RATE = "turn_rate"  #: ``|dθ/dt|`` over short chords; θ's turning against the path's
    WHEEL_RATE = "wheel_rate"  #: wheel rev/min from the counts and ``ticks_per_rev``
    WHEEL_PATH = "wheel_path"  #: wheel travel against the true path over straight chords
    SPREAD = "spread"  #: 3-D points' spread against the arm's forward kinematics and reach


@dataclass(frozen=True)
class Bound:
    """A plausible range of some columns of a channel.

    Attributes
    ----------
    columns : tuple of str
        The channel's columns the bound is about.
    measure : Measure
    limit : float
        The bound in the channel's SI unit; with ``param`` a multiple of that parameter.
    param : str or None
        ``meta["params"]`` field the limit multiplies (``w_max``: the robot's turn-rate limit).
    default : float
        The parameter's value when the log's metadata has none.
    mistake : str
        The likely mistake behind a value beyond the bound and its fix (``{channel}`` and
        ``{column}`` are filled in).
    """

    columns: tuple[str, ...]
    measure: Measure
    limit: float
    param: str | None = None
    default: float = math.nan
    mistake: str = ""

    def bound(self, params: Mapping[str, Any]) -> tuple[float, str]:
        """The bound for a robot of ``params`` and how it was made (for messages)."""
        if self.param is None:
            return self.limit, f"{self.limit:g}"
        value = params.get(self.param, self.default)
        try:
            value = float(value)
        except (TypeError, ValueError):
            value = self.default
        if not (math.isfinite(value) and value > 0):
            value = self.default
        return self.limit * value, f"{self.limit:g} × {self.param} = {self.limit * value:.3g}"


@dataclass(frozen=True)
class ChannelSchema:
    """The declared schema of one standard channel: its dtype, what its values are (for
    messages) and its plausible ranges (the columns and SI units are its
    :class:`~realitygap.diagnosis.logs.channels.ChannelSpec`)."""

    name: str
    dtype: DType
    what: str
    bounds: tuple[Bound, ...]

    @property
    def spec(self) -> ChannelSpec:
        """Columns, SI units and role of the channel."""
        return standard_channels()[self.name]


@dataclass(frozen=True)
class TimeSchema:
    """The schema of the time stamps: the slowest plausible row rate (Hz) by robot kind (robots
    whose rows are instants); a backward jump longer than ``reset_periods`` median periods is a
    clock reset; a missing stamp is interpolated when its neighbours' steps are within
    ``fill_jitter`` of the median step."""

    dtype: DType = DType.TIME
    min_rate_hz: tuple[tuple[str, float], ...] = (("diffdrive", 1.0),)
    reset_periods: float = 3.0
    fill_jitter: float = 0.25


TIME = TimeSchema()
"""The time stamps' schema."""

RESET_PERIODS = TIME.reset_periods
"""A time that jumps back by more than this many median periods was reset."""

MAX_BASE_SPEED = 10.0
"""Fastest plausible speed of a wheeled base or a climber (m/s)."""

MAX_WHEEL_RPM = 3000.0
"""Fastest plausible wheel rotation (rev/min)."""

LIMIT_MARGIN = 2.0
"""How far beyond the robot's own speed limits (``v_max``, ``w_max``) a command or a measured
turn rate may go (requests the firmware clips, a bump)."""

ODOMETRY_RATIO_RANGE = (0.5, 2.0)
"""Plausible ratio of wheel-odometry path length to true path length."""

SPREAD_RATIO_RANGE = (0.25, 4.0)
"""Plausible ratio of the measured tool points' spread to their forward kinematics' spread."""

STRAIGHT_CHORD_RAD = 0.05
"""A chord turns less than this (rad) to count as straight in the wheel-to-truth path ratio."""

PATH_STRIDE_S = 0.5
"""Time between the samples path lengths and path directions are measured over (s): row-to-row
steps of a fast, noisy ground truth add its noise; half-second chords do not."""

TURN_STRIDE_S = 0.2
"""Time between the samples a heading's turn rate is measured over (s)."""

HEADING_PATH_RATIO = 10.0
"""A heading that turns this many times more than its path's direction (over at least
:data:`MIN_TURN_RAD` of path turning) is in degrees: 1° read as 1 rad turns 57 times too far."""

MIN_TURN_RAD = 0.5
"""Least total turning of a path (rad) for its heading to be compared with it."""

HEADING_AGREEMENT = 0.5
"""A heading whose turns agree with its path's at most ``-HEADING_AGREEMENT`` (−1: always
against) turns the other way (:func:`~realitygap.diagnosis.logs.guesses.turn_agreement`)."""

JUMP_FACTOR = 10.0
"""A step this many times longer than the schema's rate limit allows over its interval is a
discontinuity (:func:`discontinuities`), not motion."""

MAX_JUMPS = 5
"""More discontinuities than this in one channel are a broken channel, refused."""

UNEVEN_INTERVALS = 4.0
"""Row intervals whose 90th percentile is this many times their 10th come at two rates."""

COUNTER_MODULI = (2**15, 2**16, 2**24, 2**32)
"""Where encoder counters wrap: 15- and 16-bit (signed or not), 24- and 32-bit registers."""

_DEG = "looks like degrees{why}; fix: add :deg to the column map ('{channel}.{column}=COLUMN:deg')"
_MM = "looks like mm or cm declared as m; fix: give the unit in the column map ('{channel}.x=x:mm')"
_FAST = ", or state the robot's {} in --params if it really goes this fast"
_POSE_BOUNDS = (
    Bound(("x", "y"), Measure.SPEED, MAX_BASE_SPEED, mistake=_MM),
    Bound(("theta",), Measure.TURN_RATE, LIMIT_MARGIN, "w_max", math.pi,
          _DEG.replace("{why}", "") + _FAST.format("w_max")),
)  # fmt: skip
_SCHEMAS = (
    ChannelSchema("cmd", DType.REAL, "commanded twist", (
        Bound(("v",), Measure.VALUE, LIMIT_MARGIN, "v_max", 0.70,
              "looks like mm/s or cm/s; fix: add :mm/s or :cm/s to the column map "
              "('cmd.v=COLUMN:mm/s')" + _FAST.format("v_max")),
        Bound(("w",), Measure.VALUE, LIMIT_MARGIN, "w_max", math.pi,
              "looks like degrees per second; fix: add :deg/s to the column map "
              "('cmd.w=COLUMN:deg/s')" + _FAST.format("w_max")),
    )),
    ChannelSchema("ticks", DType.COUNT, "tick count", (
        Bound(("left", "right"), Measure.WHEEL_RATE, MAX_WHEEL_RPM,
              mistake="check ticks_per_rev in --params and whether the counts are scaled"),
        Bound(("left", "right"), Measure.WHEEL_PATH, math.nan,
              mistake="scaled tick counts (e.g. quadrature ×4), a wrong ticks_per_rev or wheel "
              "radius in --params, or pose_gt in the wrong unit"),
    )),
    ChannelSchema("pose_gt", DType.REAL, "pose", _POSE_BOUNDS),
    ChannelSchema("pose_est", DType.REAL, "pose", _POSE_BOUNDS),
    ChannelSchema("pose_cam", DType.REAL, "pose", _POSE_BOUNDS),
    ChannelSchema("joints", DType.REAL, "joint angle", (
        Bound(tuple(f"q{i}" for i in range(1, 7)), Measure.VALUE, 4.0 * math.pi,
              mistake=_DEG.replace("{why}", " (beyond ±4π rad)")),
    )),
    ChannelSchema("tool_pos", DType.REAL, "tool position", (
        Bound(("x", "y", "z"), Measure.SPREAD, SPREAD_RATIO_RANGE[1],
              mistake="fix the unit in the column map ('tool_pos.x=COLUMN:mm' for millimetres, "
              "':m' for metres)"),
    )),
    ChannelSchema("pose3_gt", DType.REAL, "pose", (
        Bound(("x", "y", "z"), Measure.SPEED, MAX_BASE_SPEED, mistake=_MM),
        Bound(("rx", "ry", "rz"), Measure.VALUE, 2.0 * math.pi,
              mistake=_DEG.replace("{why}", " (a rotation vector beyond 2π rad)")),
    )),
    ChannelSchema("tether", DType.REAL, "tether length", (
        Bound(("length",), Measure.VALUE, 1000.0, mistake=_MM),
    )),
)  # fmt: skip
SCHEMAS: Mapping[str, ChannelSchema] = MappingProxyType({s.name: s for s in _SCHEMAS})
"""The schema of every standard channel, by name (see the module docstring's table)."""


# --------------------------------------------------------------------------- dtypes
UNIT_WORDS = {"rad": "radians", "m": "metres", "m/s": "metres per second", "rad/s": "radians "
               "per second"}  # fmt: skip
_KIND_TEXT = {"b": "booleans (True/False)", "c": "complex numbers", "O": "Python objects",
              "U": "text", "S": "bytes", "V": "raw records", "M": "dates (datetime64)",
              "m": "durations (timedelta64)"}  # fmt: skip


def dtype_problem(dtype: np.dtype[Any], channel: str) -> str | None:
    """Why an array of ``dtype`` cannot be the channel ``channel`` (``"t"`` for the time), or
    ``None`` when it can (float and integer kinds; dates and durations for the time)."""
    kind = dtype.kind
    if kind in "fiu" or (channel == "t" and kind in "Mm"):
        return None
    what = _KIND_TEXT.get(kind, str(dtype))
    expected = "counts (integers)" if channel == "ticks" else "real numbers (float or integer)"
    fix = {
        "b": "store or map numbers; a flag is no measurement (True would replay as 1)",
        "c": "store the real part (or the magnitude) as a float array",
        "O": "store a numeric array (objects are never unpickled)",
        "M": "give the time column these stamps, or store seconds",
        "m": "give the time column these durations, or store seconds",
    }.get(kind, "store the values as numbers")
    return f"expected {expected}, got {what} (dtype {dtype}). Fix: {fix}"


def as_real(values: npt.ArrayLike, channel: str, where: str = "") -> FloatArray:
    """``values`` as float64 when their dtype is one the schema of ``channel`` accepts.

    Raises
    ------
    SchemaError
        Booleans, complex numbers, text, objects or dates, naming ``where`` and ``channel``.
    """
    arr = np.asarray(values)
    if arr.dtype.kind in "Mm" and channel == "t":
        return as_seconds(arr)
    problem = dtype_problem(arr.dtype, channel)
    if problem is not None:
        if arr.dtype.kind in "US" and arr.size:
            try:  # numbers written as text ("1.5") are numbers
                return np.array(arr, dtype=float)
            except ValueError:
                pass
        raise SchemaError(
            f"{where}{'time' if channel == 't' else f'channel {channel!r}'}: {problem}"
        )
    return np.array(arr, dtype=float)


def as_seconds(values: npt.ArrayLike) -> FloatArray:
    """Time stamps in s: ``datetime64`` → POSIX seconds, ``timedelta64`` → seconds, numbers
    as they are (NaT → NaN)."""
    arr = np.asarray(values)
    if arr.dtype.kind == "M":
        nat = np.isnat(arr)
        out = (arr - np.datetime64(0, "s")) / np.timedelta64(1, "ns") * 1e-9
        return np.where(nat, np.nan, out).astype(float)
    if arr.dtype.kind == "m":
        nat = np.isnat(arr)
        out = arr / np.timedelta64(1, "ns") * 1e-9
        return np.where(nat, np.nan, out).astype(float)
    return np.array(arr, dtype=float)


def check_counts(values: FloatArray, where: str, lines: npt.ArrayLike | None = None) -> None:
    """Refuse counts (a raw ``ticks`` column) that are not whole numbers.

    Raises
    ------
    SchemaError
        Naming the first fractional value (and its line) and the fix.
    """
    v = np.asarray(values, dtype=float)
    ok = np.isfinite(v)
    frac = ok & (np.abs(v - np.round(v)) > 1e-6 * np.maximum(1.0, np.abs(v)))
    if frac.any():
        i = int(np.flatnonzero(frac)[0])
        at = f", line {int(np.asarray(lines)[i])}" if lines is not None else f", row {i}"
        raise SchemaError(
            f"{where}{at}: expected encoder counts (whole numbers), got {v[i]!r} "
            f"({int(frac.sum())} fractional value(s)). Fix: map the raw counter column; if the "
            "column is a wheel angle or distance, convert it with a factor in the column map "
            "(e.g. 'ticks.left=wheel_rad*409.8'), which says the values are derived"
        )


def check_values(
    channel: str, values: npt.ArrayLike, where: str, lines: npt.ArrayLike | None = None
) -> None:
    """Check raw values (N, k) of ``channel`` against its :data:`Measure.VALUE` bounds (with the
    defaults of their parameters): for readers that build no log (an arm's own file format,
    whose joint count may differ from the standard channel's).

    Raises
    ------
    SchemaError
        Naming ``where``, the first row beyond the bound (its line when ``lines`` are given),
        the bound and the likely mistake.
    """
    v = np.abs(np.asarray(values, dtype=float))
    v = v[:, None] if v.ndim == 1 else v.reshape(v.shape[0], -1)
    schema = SCHEMAS[channel]
    for b in schema.bounds:
        if b.measure is not Measure.VALUE:
            continue
        limit, how = b.bound({})
        beyond = np.flatnonzero(np.any(v > limit, axis=1))
        if beyond.size:
            i = int(beyond[0])
            at = f", line {int(np.asarray(lines)[i])}" if lines is not None else f", row {i}"
            unit = schema.spec.units[schema.spec.columns.index(b.columns[0])]
            raise SchemaError(
                f"{where}{at}: {schema.what} {float(v[i].max()):.4g} {unit} is beyond ±{how} "
                f"{unit} ({beyond.size} such row(s)); expected {UNIT_WORDS.get(unit, unit)}: it "
                + b.mistake.format(channel=channel, column=b.columns[0])
            )


# --------------------------------------------------------------------------- counters
def counter_wrap(values: npt.ArrayLike) -> int | None:
    """The modulus (one of :data:`COUNTER_MODULI`) a cumulative counter wraps at, or ``None``.

    A counter wraps at ``M`` when it spans at most ``M``, some steps jump by more than
    ``M / 2`` and, less a multiple of ``M``, those steps are no larger than the ordinary ones
    (four times their largest, at least one count).
    """
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size < 3:
        return None
    d = np.diff(v)
    for m in COUNTER_MODULI:
        big = np.abs(d) > m / 2
        if not big.any() or np.ptp(v) > m:
            continue
        rest = np.abs(d[~big])
        ordinary = float(rest.max()) if rest.size else 0.0
        residual = np.abs(d[big] - m * np.round(d[big] / m))
        if float(residual.max()) <= max(4.0 * ordinary, 1.0) and float(residual.max()) < m / 8:
            return int(m)
    return None


def unwrap_counter(values: npt.ArrayLike) -> tuple[FloatArray, int | None]:
    """A cumulative counter unwrapped where it wraps (:func:`counter_wrap`), and the modulus
    (``None``: returned as it is). NaN entries stay NaN."""
    v = np.array(values, dtype=float)
    m = counter_wrap(v)
    if m is None:
        return v, None
    ok = np.isfinite(v)
    v[ok] = np.unwrap(v[ok], period=float(m))
    return v, m


# --------------------------------------------------------------------------- time
def clock_resets(t: npt.ArrayLike) -> tuple[list[int], int | None]:
    """Where a time column was reset, and where it first steps back by less.

    Returns the rows (indices into ``t``) that start a new run after a backward jump longer
    than :data:`RESET_PERIODS` median periods (a reset), and the first row that steps back by
    less (rows out of order; ``None`` when there is none). NaN stamps are skipped.
    """
    t = np.asarray(t, dtype=float)
    idx = np.flatnonzero(np.isfinite(t))
    if idx.size < 2:
        return [], None
    d = np.diff(t[idx])
    fwd = d[d > 0]
    period = float(np.median(fwd)) if fwd.size else 0.0
    back = np.flatnonzero(d < 0)
    resets = [int(idx[b + 1]) for b in back if -d[b] > TIME.reset_periods * period]
    disorder = [int(idx[b + 1]) for b in back if -d[b] <= TIME.reset_periods * period]
    return resets, (disorder[0] if disorder else None)


def discontinuities(
    channel: str, t: npt.ArrayLike, values: npt.ArrayLike, params: Mapping[str, Any] | None = None
) -> list[tuple[int, str]]:
    """Where a pose or tick channel makes a step no robot can make (see the module docstring).

    Parameters
    ----------
    channel : str
        ``pose_gt``, ``pose_est``, ``pose_cam`` (positions x, y, m) or ``ticks`` (cumulative,
        unwrapped counts); any other channel has none.
    t : array, shape (N,)
        The channel's stamps (s), increasing.
    values : array, shape (N, k)
        The channel's values in SI units (the standard columns).
    params : mapping, optional
        ``meta["params"]`` (``ticks_per_rev``; the defaults when absent).

    Returns
    -------
    list of (int, str)
        The rows (indices into ``t``) after each jump and what jumped (for the warning).

    Raises
    ------
    SchemaError
        More than :data:`MAX_JUMPS` jumps: a broken channel, not joined recordings.
    """
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        return _discontinuities(channel, t, values, params)


def _discontinuities(
    channel: str, t: npt.ArrayLike, values: npt.ArrayLike, params: Mapping[str, Any] | None
) -> list[tuple[int, str]]:
    t = np.asarray(t, dtype=float)
    v = np.asarray(values, dtype=float)
    if t.size < 3:
        return []
    if channel in ("pose_gt", "pose_est", "pose_cam"):
        step = np.hypot(*np.diff(v[:, :2], axis=0).T)
        limit, unit, what = MAX_BASE_SPEED, "m", "the position jumps"
    elif channel == "ticks":
        tpr = (params or {}).get("ticks_per_rev", 2578.33)
        tpr = float(tpr) if isinstance(tpr, (int, float)) and tpr > 0 else 2578.33
        step = np.abs(np.diff(v, axis=0)).max(axis=1)
        limit, unit, what = MAX_WHEEL_RPM / 60.0 * tpr, "counts", "the encoders jump"
    else:
        return []
    dt = np.diff(t)
    ok = np.isfinite(step) & np.isfinite(dt) & (dt > 0)
    if ok.sum() < 2:
        return []
    ok &= np.isfinite(step / np.where(dt > 0, dt, 1.0))
    if ok.sum() < 2:
        return []
    period = float(np.median(dt[ok]))
    rate = step[ok] / dt[ok]
    if not float(np.percentile(rate, 99)) <= limit:
        return []  # ordinary steps beyond the limit: a unit mistake, for check_log to name
    allowed = JUMP_FACTOR * limit * np.maximum(dt, period)
    jumps = np.flatnonzero(ok & (step > allowed))
    if jumps.size > MAX_JUMPS:
        i = int(jumps[0])
        raise SchemaError(
            f"channel {channel!r}: {what} at {jumps.size} steps, first by "
            f"{step[i]:.4g} {unit} in {dt[i] * 1e3:.3g} ms (row {i + 1}); more than {MAX_JUMPS} "
            "joins of recordings: a broken channel (a tracker losing its body, a wrong column). "
            "Fix: map the right column, or clean the channel"
        )
    return [
        (
            int(i) + 1,
            f"{channel}: {what} by {step[i]:.4g} {unit} in one {dt[i] * 1e3:.3g}-ms step "
            f"(at most {limit * max(dt[i], period):.3g} {unit} at {limit:.4g} {unit}/s)",
        )
        for i in jumps
    ]


def fill_time(t: npt.ArrayLike, where: str, lines: npt.ArrayLike | None = None) -> FloatArray:
    """Missing (NaN) time stamps interpolated over the row number between regular neighbours.

    A run of missing stamps is filled when the steps on either side of it are within
    ``TIME.fill_jitter`` of the median step and the span across it is that many median
    steps (at the start or end of the file, the neighbouring steps on one side).

    Raises
    ------
    SchemaError
        When the neighbours are irregular (a gap, a reset) or there are fewer than three stamps,
        naming the line and the fix.
    """
    t = np.array(t, dtype=float)
    bad = ~np.isfinite(t)
    if not bad.any():
        return t
    ok = np.flatnonzero(~bad)
    at_line = (lambda i: int(np.asarray(lines)[i])) if lines is not None else (lambda i: i + 1)
    if ok.size < 3:
        raise SchemaError(
            f"{where}: fewer than three time stamps; the missing ones cannot be filled"
        )
    steps = np.diff(t[ok]) / np.diff(ok)
    med = float(np.median(steps))
    tol = TIME.fill_jitter * abs(med)
    runs = np.flatnonzero(np.diff(np.concatenate([[0], bad.astype(np.int8), [0]])))
    for a, b in zip(runs[::2], runs[1::2]):
        before = [i for i in (a - 2, a - 1) if i >= 0 and not bad[i]]
        after = [i for i in (b, b + 1) if i < t.size and not bad[i]]
        local: list[float] = []
        if len(before) == 2:
            local.append(t[before[1]] - t[before[0]])
        if len(after) == 2:
            local.append(t[after[1]] - t[after[0]])
        if before and after:
            local.append((t[after[0]] - t[before[-1]]) / (after[0] - before[-1]))
        if not local or med <= 0 or any(abs(s - med) > tol for s in local):
            raise SchemaError(
                f"{where}, line {at_line(a)}: the time stamp is missing and its neighbours are "
                f"not regular (steps {', '.join(f'{s:.4g}' for s in local) or 'unknown'} s "
                f"against a median of {med:.4g} s), so it cannot be interpolated. Fix: repair "
                "the time column, or pass nan='drop' (CLI --nan drop) to drop those rows"
            )
        rows = np.arange(a, b)
        if before and after:
            t[a:b] = np.interp(rows, [before[-1], after[0]], [t[before[-1]], t[after[0]]])
        elif before:
            t[a:b] = t[before[-1]] + med * (rows - before[-1])
        else:
            t[a:b] = t[after[0]] - med * (after[0] - rows)
    return t
