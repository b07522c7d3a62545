"""Guesses from a column's name and values: what it means, in which unit, how it counts.

Used by :mod:`~realitygap.diagnosis.logs.inspect`; every guess is a proposal the user
checks, never applied silently.
"""

from __future__ import annotations

import re

import numpy as np

__all__ = [
    "CUMULATIVE_SPAN_STEPS",
    "cumulative",
    "name_meaning",
    "name_unit",
    "time_unit",
    "turn_agreement",
]

_TIME_FACTOR = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
_UNIT_WORDS = {u: u for u in ("s", "ms", "us", "ns", "m", "mm", "cm", "rad", "deg", "count")}
_UNIT_WORDS |= {"sec": "s", "µs": "us", "degrees": "deg", "mps": "m/s", "rads": "rad/s"}
_UNIT_WORDS |= {u: u for u in ("m/s", "mm/s", "cm/s", "rad/s", "deg/s")}
_TIME_WORDS = {"t", "time", "stamp", "timestamp", "ts", "secs", "seconds", "elapsed", "%time"}
_GT = {"gt", "mocap", "truth", "true", "vicon", "opti", "optitrack", "qualisys", "ground"}
_EST = {"odom", "est", "estimate", "ekf", "filter", "fused", "odometry"}
_TOOL = {"measurement", "tool", "tcp", "probe"}
_HEADING = {"yaw", "theta", "heading", "th", "psi"}
_ENC = {"enc", "encoder", "tick", "ticks", "count", "counts", "cnt"}
_V = {"v", "vx", "lin", "linear", "vel", "speed"}
_W = {"w", "wz", "omega", "ang", "angular", "yawrate"}
_NOT_POSE = {"goal", "target", "setpoint", "desired", "cmd", "orientation", "quat"}
_COUNTER = {"seq", "id", "index", "idx", "frame", "row"}


def name_unit(name: str) -> str:
    """A unit the name states (``x [mm]``, ``time_ms``, ``yaw(deg)``), else ``""``."""
    m = re.search(r"[\[(]\s*([A-Za-zµ°/]+)\s*[\])]", name)
    if m:
        return _UNIT_WORDS.get(m.group(1).lower().replace("°", "deg"), "")
    split = re.split(r"[^a-zµ/]+", re.sub(r"([a-z])([A-Z])", r"\1_\2", name).lower())
    toks = [t for t in split if t]
    return _UNIT_WORDS.get(toks[-1], "") if len(toks) > 1 else ""


def name_meaning(name: str) -> tuple[str, str]:
    """``(kind, detail)`` from a column name: kind "time", "pose", "heading", "tool", "ticks",
    "cmd.v", "cmd.w", "joint" or ""; detail the qualifier and axis, side or joint number."""
    s = re.sub(r"([a-z])([A-Z])", r"\1 \2", re.sub(r"[\[(]\s*[A-Za-zµ°/%]+\s*[\])]", " ", name))
    toks = [t for t in re.split(r"[^a-z0-9%µ/]+", s.lower()) if t]  # camelCase split, no units
    words = set(toks)
    if words & _TIME_WORDS or any(t.startswith("time") or "stamp" in t for t in toks):
        return "time", ""
    if words & _COUNTER:
        return "", ""
    numbered = re.fullmatch(r"q_?(\d)|joint_?(\d)|j(\d)", name.strip().lower()) or any(
        re.fullmatch(r"q\d|j\d|joint\d", t)
        for t in toks  # q1_deg, joint3 [rad]
    )
    if numbered or words & {"joint", "joints"}:
        digits = re.findall(r"\d+", name)
        return "joint", digits[-1] if digits else ""
    axes = [m.group(1) for t in toks if (m := re.fullmatch(r"(?:pos|position|p)?([xyz])", t))]
    axis = axes[0] if axes else ""
    if axis and words & _TOOL:
        return "tool", axis
    qual = "gt" if words & _GT else "est" if words & _EST else ""
    if words & {"linear", "lin"} and axis in ("", "x"):
        return "cmd.v", ""
    if words & {"angular", "ang"} and axis in ("", "z"):
        return "cmd.w", ""
    if words & _NOT_POSE:
        if "cmd" in words and words & (_V | _W):
            return ("cmd.v" if words & _V else "cmd.w"), ""
        return "", ""
    if axis in ("x", "y", "z"):
        return "pose", f"{qual}.{axis}"  # z: an arm's measured point (no wheeled pose has it)
    if words & _HEADING:
        return "heading", qual
    side = "left" if words & {"l", "left"} else "right" if words & {"r", "right"} else ""
    if words & _ENC or (side and (words & {"odo", "wheel"} or len(toks) == 1)):
        return "ticks", side
    return ("cmd.v", "") if words & _V else ("cmd.w", "") if words & _W else ("", "")


def time_unit(v: np.ndarray, stated: str) -> tuple[str, str]:
    """Unit of a time column and how it was found: named, POSIX-epoch magnitude, or step."""
    if stated in _TIME_FACTOR:
        return stated, "unit from the name"
    ok = v[np.isfinite(v)]
    mag = float(np.median(np.abs(ok))) if ok.size else 0.0
    for unit, f in _TIME_FACTOR.items():
        if 0.9e9 <= mag * f <= 4.2e9:
            return unit, "POSIX epoch time"
    d = np.diff(ok)
    step = float(np.median(d[d > 0])) if np.any(d > 0) else 0.0
    unit = "s" if step < 1 else "ms" if step < 1e3 else "us" if step < 1e6 else "ns"
    return unit, f"unit from the median step {step:.4g}"


CUMULATIVE_SPAN_STEPS = 50.0
"""A counter column spans more than this many of its largest row-to-row steps (99th
percentile): counts that add up. Per-row increments span at most a few of their own steps
(a speed ramps over some rows, and integer counts flicker by one)."""


def cumulative(v: np.ndarray) -> bool:
    """Counts that add up, not per-row increments: the counts travel far in small steps
    (:data:`CUMULATIVE_SPAN_STEPS`), whichever way the wheel turns."""
    ok = v[np.isfinite(v)]
    d = np.abs(np.diff(ok))
    d = d[d > 0]
    if ok.size < 3 or d.size == 0:
        return False
    return float(np.ptp(ok)) > CUMULATIVE_SPAN_STEPS * float(np.percentile(d, 99))


# ------------------------------------------------------------------------------ conventions
def turn_agreement(x: np.ndarray, y: np.ndarray, th: np.ndarray) -> float | None:
    """How far the heading turns with the path (+1) or against it (−1), None if it hardly turns:
    the turns of successive displacements (cross products) against the heading's changes."""
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(th)
    if ok.sum() < 10:
        return None
    k = max(1, int(ok.sum()) // 300)
    xs, ys, ths = x[ok][::k], y[ok][::k], np.unwrap(th[ok][::k])
    d = np.column_stack([np.diff(xs), np.diff(ys)])
    step = np.hypot(d[:, 0], d[:, 1])
    moving = step > 0.2 * np.percentile(step, 90)
    turn = np.arctan2(d[:-1, 0] * d[1:, 1] - d[:-1, 1] * d[1:, 0], np.sum(d[:-1] * d[1:], axis=1))
    use = moving[:-1] & moving[1:] & (np.abs(turn) > 1e-4)
    weight = np.abs(turn[use])
    if weight.sum() < 0.3:
        return None
    dth = (ths[2:] - ths[:-2])[use]
    return float(np.sum(np.sign(turn[use]) * np.sign(dth) * weight) / weight.sum())
