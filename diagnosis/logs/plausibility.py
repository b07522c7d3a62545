"""Plausibility of a whole log against its channels' schemas (:func:`check_log`): the row
rate, counters that still wrap, every :class:`~realitygap.diagnosis.logs.schema.Bound` of
every channel (speeds, turn rates, wheel rates, an arm's reach), a heading that turns the
other way than the path, and the wheel path against the true one — each with the likely
unit or sign mistake and its fix."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from realitygap.diagnosis.logs.channels import standard_channels
from realitygap.diagnosis.logs.schema import (
    HEADING_AGREEMENT,
    HEADING_PATH_RATIO,
    MIN_TURN_RAD,
    ODOMETRY_RATIO_RANGE,
    PATH_STRIDE_S,
    SCHEMAS,
    SPREAD_RATIO_RANGE,
    STRAIGHT_CHORD_RAD,
    TIME,
    TURN_STRIDE_S,
    UNEVEN_INTERVALS,
    UNIT_WORDS,
    Bound,
    ChannelSchema,
    FloatArray,
    Measure,
    SchemaError,
    counter_wrap,
)

__all__ = ["check_log"]


def check_log(log: Any, columns: Mapping[str, str] | None = None) -> None:
    """Check a log's numbers against the schema of its time and of each standard channel.

    ``columns`` maps a log column (``"ticks.left"``) to the column-map entry that gave it
    (``"enc_l"``), for fixes that name the entry.

    Checked, in order: the row rate (robots whose rows are instants, :class:`TimeSchema`),
    ticks that still wrap, then every :class:`Bound` of every standard channel the log holds
    (:data:`SCHEMAS`), the wheel path against the true one last.

    Raises
    ------
    SchemaError
        Naming the file, the channel, the value with its unit, the bound and the likely fix.
    """
    if log.n < 3:
        return
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        _check_log(log, columns or {})


def _negated(columns: Mapping[str, str], target: str) -> str:
    """The column-map entry for ``target`` with its sign flipped (``-COLUMN`` when unknown)."""
    text = columns.get(target, "COLUMN")
    return f"{target}={text[1:] if text.startswith('-') else '-' + text}"


def _check_log(log: Any, columns: Mapping[str, str]) -> None:
    src = log.source or log.name
    robot = str(log.meta.get("robot", "diffdrive"))
    raw_params = log.meta.get("params", {})
    params: Mapping[str, Any] = raw_params if isinstance(raw_params, Mapping) else {}
    dt = np.diff(log.t)
    rate = 1.0 / float(np.median(dt))
    clock = _clock_hint(dt)
    low = dict(TIME.min_rate_hz).get(robot)
    if low is not None and rate < low:
        raise SchemaError(
            f"{src}: rows arrive at {rate:.3g} Hz over {log.duration / 3600:.3g} h, implausible "
            f"for a {robot} log (at least {low:g} Hz expected). Fix: a time column in ms or µs "
            "declared as s? give its unit in the column map, e.g. 't=time:ms'"
        )
    if log.has("ticks"):
        for j, col in enumerate(SCHEMAS["ticks"].spec.columns):
            m = counter_wrap(log["ticks"][:, j])
            if m is not None:
                raise SchemaError(
                    f"{src}: channel 'ticks' column {col!r}: the tick counter wraps at {m} (it "
                    f"jumps by about ±{m}); expected cumulative counts. Fix: unwrap it "
                    f"(numpy.unwrap(ticks, period={m})); the table reader (CSV, .mat, .npz with "
                    "a column map) does so itself"
                )
    checks = {
        Measure.VALUE: _check_value,
        Measure.SPEED: _check_speed,
        Measure.TURN_RATE: _check_turn_rate,
        Measure.WHEEL_RATE: _check_wheel_rate,
        Measure.SPREAD: _check_spread,
    }
    last: list[tuple[ChannelSchema, Bound]] = []
    for name in log.channels:
        schema = SCHEMAS.get(name)
        if schema is None or name not in standard_channels():
            continue
        for b in schema.bounds:
            if b.measure is Measure.WHEEL_PATH:
                last.append((schema, b))
                continue
            if b.measure in (Measure.TURN_RATE, Measure.WHEEL_RATE) and robot != "diffdrive":
                continue
            if name == "cmd" and robot != "diffdrive":
                continue
            if b.measure is Measure.TURN_RATE:
                _check_turn_rate(log, schema, b, params, src, clock, columns)
            else:
                checks[b.measure](log, schema, b, params, src, clock)
    for schema, b in last:
        if robot == "diffdrive":
            _check_wheel_path(log, schema, b, params, src, clock, columns)


def _cols(log: Any, schema: ChannelSchema, b: Bound) -> FloatArray:
    idx = [schema.spec.columns.index(c) for c in b.columns]
    return np.asarray(log[schema.name][:, idx], dtype=float)


def _target(schema: ChannelSchema, b: Bound) -> str:
    return ", ".join(f"{schema.name}.{c}" for c in b.columns)


def _check_value(
    log: Any, schema: ChannelSchema, b: Bound, params: Mapping[str, Any], src: str, clock: str
) -> None:
    vals = np.abs(_cols(log, schema, b))
    limit, how = b.bound(params)
    tops = np.percentile(vals, 99, axis=0)
    j = int(np.argmax(tops))
    col = b.columns[j]
    unit = schema.spec.units[schema.spec.columns.index(col)]
    if not float(tops[j]) <= limit:
        raise SchemaError(
            f"{src}: {schema.name}.{col} reaches {float(tops[j]):.4g} {unit} ({schema.what}, 99th "
            f"percentile), implausible (expected {UNIT_WORDS.get(unit, unit)}, ≤ {how} {unit}): "
            "it " + b.mistake.format(channel=schema.name, column=col)
        )


def _check_speed(
    log: Any, schema: ChannelSchema, b: Bound, params: Mapping[str, Any], src: str, clock: str
) -> None:
    pos = _cols(log, schema, b)
    dt = np.diff(log.t)
    step = np.linalg.norm(np.diff(pos, axis=0), axis=1)
    speed = float(np.percentile(step / dt, 99))
    limit, _ = b.bound(params)
    if not speed <= limit:
        raise SchemaError(
            f"{src}: channel {schema.name!r} moves at {speed:.4g} m/s (99th percentile), "
            f"implausible for a robot (≤ {limit:g} m/s). Fix: "
            + (clock or b.mistake.format(channel=schema.name, column=b.columns[0]))
        )


def _stride(log: Any, seconds: float) -> int:
    return max(1, int(round(seconds / float(np.median(np.diff(log.t))))))


def _check_turn_rate(
    log: Any,
    schema: ChannelSchema,
    b: Bound,
    params: Mapping[str, Any],
    src: str,
    clock: str,
    columns: Mapping[str, str] | None = None,
) -> None:
    th = _cols(log, schema, b)[:, 0]
    limit, how = b.bound(params)
    mistake = b.mistake.format(channel=schema.name, column=b.columns[0])
    k = _stride(log, TURN_STRIDE_S)
    t = log.t
    rate = np.abs(np.diff(th[::k])) / np.diff(t[::k])
    if rate.size:
        top = float(np.percentile(rate, 99))
        if not top <= limit:
            raise SchemaError(
                f"{src}: {schema.name}.theta turns at {top:.4g} rad/s (99th percentile over "
                f"{TURN_STRIDE_S:g} s), beyond the robot's limit ({how} rad/s): the heading "
                f"{mistake}" + (f" (or: {clock})" if clock else "")
            )
    # the heading of a differential drive follows the direction of its path
    xy = log[schema.name][:, :2]
    k = _stride(log, PATH_STRIDE_S)
    chord = np.diff(xy[::k], axis=0)
    length = np.hypot(chord[:, 0], chord[:, 1])
    moving = length > 0.02
    psi = np.arctan2(chord[:, 1], chord[:, 0])
    mid = 0.5 * (th[::k][:-1] + th[::k][1:])
    pair = moving[:-1] & moving[1:]
    if not pair.any():
        return
    dpsi = np.diff(psi)[pair]
    dpsi = (dpsi + 0.5 * math.pi) % math.pi - 0.5 * math.pi  # driving backwards flips ψ by π
    dth = np.diff(mid)[pair]
    path_turn = float(np.abs(dpsi).sum())
    head_turn = float(np.abs(dth).sum())
    if path_turn >= MIN_TURN_RAD and head_turn > HEADING_PATH_RATIO * path_turn:
        raise SchemaError(
            f"{src}: {schema.name}.theta turns {head_turn:.4g} rad while the path of "
            f"{schema.name}.x, y turns {path_turn:.3g} rad ({head_turn / path_turn:.3g} × as "
            f"much; a heading follows its path): the heading {mistake}"
        )
    # the heading turns with its path, not against it (the inspector's test, one definition)
    from realitygap.diagnosis.logs.guesses import turn_agreement

    full = log[schema.name]
    agree = turn_agreement(full[:, 0], full[:, 1], th)
    if path_turn >= MIN_TURN_RAD and agree is not None and agree <= -HEADING_AGREEMENT:
        raise SchemaError(
            f"{src}: the heading turns the other way than the path: a clockwise heading? "
            f"({schema.name}.theta against the path of {schema.name}.x, y: agreement "
            f"{agree:.2f}, −1 = always against, over {path_turn:.3g} rad of path turning). Fix: "
            f"-heading ({_negated(columns or {}, schema.name + '.theta')} in the column map)"
        )


def _check_wheel_rate(
    log: Any, schema: ChannelSchema, b: Bound, params: Mapping[str, Any], src: str, clock: str
) -> None:
    tpr = params.get("ticks_per_rev")
    if not isinstance(tpr, (int, float)) or not tpr > 0:
        return
    dt = np.diff(log.t)
    dticks = np.abs(np.diff(_cols(log, schema, b), axis=0))
    rpm = float(np.percentile(dticks.max(axis=1) / dt, 99)) / tpr * 60.0
    limit, _ = b.bound(params)
    if not rpm <= limit:
        raise SchemaError(
            f"{src}: channel 'ticks' turns a wheel at {rpm:.4g} rev/min (99th percentile, "
            f"with ticks_per_rev={tpr:g}), implausible (≤ {limit:g} rev/min). Fix: "
            + (clock or b.mistake)
        )


def _check_wheel_path(
    log: Any,
    schema: ChannelSchema,
    b: Bound,
    params: Mapping[str, Any],
    src: str,
    clock: str,
    columns: Mapping[str, str] | None = None,
) -> None:
    """Wheel travel against the true path, over straight chords :data:`PATH_STRIDE_S` apart (a
    tracked point off the axle circles it on every turn, which the wheels' mean travel does not
    see; a fast, noisy truth lengthens its row-to-row path by its noise)."""
    tpr = params.get("ticks_per_rev")
    if not log.has("pose_gt") or not isinstance(tpr, (int, float)) or not tpr > 0:
        return
    radius = 0.5 * (
        float(params.get("wheel_radius_left", 0.0)) + float(params.get("wheel_radius_right", 0.0))
    )
    k = _stride(log, PATH_STRIDE_S)
    gt = log["pose_gt"][::k]
    straight = np.abs(np.diff(np.unwrap(gt[:, 2]))) < STRAIGHT_CHORD_RAD
    truth = float(np.hypot(*np.diff(gt[:, :2], axis=0).T)[straight].sum())
    if not (radius > 0 and truth > 0.5):
        return
    ticks = log["ticks"][::k]
    scale = 2.0 * math.pi * radius / tpr / truth

    def ratio_of(signs: tuple[float, float]) -> float:
        mean = np.diff(0.5 * (signs[0] * ticks[:, 0] + signs[1] * ticks[:, 1]))
        return float(np.sum(np.abs(mean[straight]))) * scale

    ratio = ratio_of((1.0, 1.0))
    lo, hi = ODOMETRY_RATIO_RANGE
    if lo <= ratio <= hi:
        return
    head = (
        f"{src}: the wheels travelled {ratio:.3g} × the true path length "
        f"({truth:.3g} m of 'pose_gt'), outside the plausible {lo:g}–{hi:g}"
    )
    flipped = ratio_of((-1.0, 1.0))  # one wheel's ticks negated (either: the same length)
    if lo <= flipped <= hi:
        # the mirrored wheel is the one that counts down while the truth moves forward
        d = np.diff(gt[:, :2], axis=0)
        mid = 0.5 * (gt[1:, 2] + gt[:-1, 2])
        forward = np.sign(d[:, 0] * np.cos(mid) + d[:, 1] * np.sin(mid))[straight]
        net = [float(np.sum(np.diff(ticks[:, j])[straight] * forward)) for j in (0, 1)]
        back = [side for side, n in zip(("left", "right"), net, strict=True) if n < 0]
        which = (
            _negated(columns or {}, f"ticks.{back[0]}")
            if len(back) == 1
            else f"{_negated(columns or {}, 'ticks.left')} (or ticks.right)"
        )
        raise SchemaError(
            head + f": one wheel's encoder counts the other way (mirrored): with its ticks "
            f"negated the wheels travel {flipped:.3g} × the true path. Fix: {which} in the "
            f"column map (else: {b.mistake})"
        )
    raise SchemaError(f"{head}. Fix: {b.mistake}")


def _arm_points(log: Any, params: Mapping[str, Any]) -> tuple[FloatArray | None, float | None]:
    """The forward kinematics of the log's joints (N, 3) (m) with the nominal MDH table and
    tool, and the arm's reach (m): each ``None`` when the metadata does not say."""
    from realitygap.estimators.arm.mdh import MDHTable, tool_positions

    reach = params.get("reach")
    reach_m = float(reach) if isinstance(reach, (int, float)) and reach > 0 else None
    mdh = params.get("mdh")
    if not isinstance(mdh, Mapping):
        return None, reach_m
    try:
        base = MDHTable(np.zeros(6), np.zeros(6), np.zeros(6), np.zeros(6), np.zeros(6))
        names = base.param_names()
        table = base.with_params([float(mdh[n]) for n in names], names)
        tool = np.asarray(log.meta.get("tool", (0.0, 0.0, 0.0)), dtype=float).reshape(3)
    except (KeyError, TypeError, ValueError):
        return None, reach_m
    if reach_m is None:
        reach_m = float(np.hypot(table.a, table.d).sum() + np.linalg.norm(tool))
    if not log.has("joints"):
        return None, reach_m
    return tool_positions(table, log["joints"], tool), reach_m


def _spread(points: FloatArray) -> float:
    """RMS distance (m) of points (N, 3) from their centroid."""
    return float(np.sqrt(np.mean(np.sum((points - points.mean(axis=0)) ** 2, axis=1))))


def _unit_word(ratio: float) -> str:
    """The unit mix-up a length ratio (measured / expected) points at."""
    for factor, text in (
        (1000.0, "millimetres declared as metres"),
        (100.0, "centimetres declared as metres"),
        (1e-3, "metres declared as millimetres"),
        (1e-2, "metres declared as centimetres"),
    ):
        if 0.3 * factor <= ratio <= 3.0 * factor:
            return f"looks like {text} (×{factor:g})"
    return "a wrong unit or the wrong columns"


def _check_spread(
    log: Any, schema: ChannelSchema, b: Bound, params: Mapping[str, Any], src: str, clock: str
) -> None:
    pts = _cols(log, schema, b)
    measured = _spread(pts)
    fk, reach = _arm_points(log, params)
    mistake = b.mistake.format(channel=schema.name, column=b.columns[0])
    if fk is not None:
        expected = _spread(fk)
        if expected > 1e-3 and measured > 0:
            ratio = measured / expected
            lo, hi = SPREAD_RATIO_RANGE
            if not lo <= ratio <= hi:
                raise SchemaError(
                    f"{src}: the points of {_target(schema, b)} spread {measured:.4g} m about "
                    f"their centre, but the arm's joints put its tool {expected:.4g} m about "
                    f"theirs ({ratio:.3g} ×, expected {lo:g}–{hi:g} ×: a rigid tracker frame "
                    f"keeps distances): {_unit_word(ratio)}. Fix: {mistake}"
                )
    if reach is not None and measured > 2.0 * reach:
        raise SchemaError(
            f"{src}: the points of {_target(schema, b)} spread {measured:.4g} m about their "
            f"centre, beyond what an arm of reach {reach:.3g} m can ({2 * reach:.3g} m): "
            f"{_unit_word(measured / reach)}. Fix: {mistake}"
        )


def _clock_hint(dt: FloatArray) -> str:
    """What to say when the rows' own intervals explain an implausible rate: rows of streams at
    different rates (or a clock that stalls and catches up) give intervals of two sizes, and a
    change over a short one looks fast ("" when the 90th percentile of the intervals is within
    :data:`UNEVEN_INTERVALS` of the 10th)."""
    lo, hi = (float(v) for v in np.percentile(dt, [10, 90]))
    if not hi > UNEVEN_INTERVALS * lo:
        return ""
    return (
        f"the rows come at uneven intervals ({1e3 * lo:.3g} ms to {1e3 * hi:.3g} ms, 10th to "
        "90th percentile): a clock or rate mismatch, not the robot — two streams interleaved in "
        "one file, or stamps of another clock? Map each stream's columns (a table's channels "
        "are aligned on their own stamps; 'realitygap inspect FILE' shows the streams and their "
        "rates) or fix the time column"
    )
