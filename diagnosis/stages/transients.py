r"""Transient events: windows disturbed by something no drive-train effect describes.

A real robot stalls against an obstacle, is bumped, is lifted, or the motion
capture loses its markers for a moment. Such a window can carry a residual a
hundred times the noise (a heading error of 0.4 rad where the encoders say the
robot turned on the spot and the body hardly moved), and a fit that tries to
explain it spends itself on it. :func:`detect_transients` lists these windows
so that they are set aside from the attribution and from the shrink, and says
what the signals show.

Two tests per window of a time series:

**Residual outlier** (against the noise model). For each feature column the
reference residual :math:`z_m` (real minus replay, in feature-scale units) is
compared with its robust spread over all windows,

.. math::  r_m = \frac{|z_m - \operatorname{med}(z)|}
                {\max\big(1.4826\,\operatorname{MAD}(z),\ ε\big)},

and the window's score is the largest :math:`r_m` over its columns
(:attr:`TransientSettings.outlier_threshold`, default 6: a Gaussian window
exceeds it with probability 2·10⁻⁹). ``ε`` is the attribution's structure
floor.

**Signals** (what the log says happened), over sub-intervals of
:attr:`TransientSettings.sub_interval_s` inside the window. The wheels' travel
(encoders, or the applied commands when there are no encoders) predicts a
motion of magnitude :math:`m_w = |d_w| + \tfrac{b}{2}|θ_w|` (m: the arc of a wheel);
the ground truth shows :math:`m_b = |Δp| + \tfrac{b}{2}|Δθ|`. A sub-interval
is a **stall or slip** when :math:`m_w` exceeds :attr:`min_motion_m`
(:attr:`min_command_motion_m` from commands) and
:math:`m_b < ρ\, m_w` (:attr:`stall_ratio`, default ¼: the body covered less
than a quarter of what the wheels turned — no tyre on a floor slips that much
while driving, a stalled, lifted or wedged robot does), and **ground truth
frozen** when the logged pose repeats exactly while the wheels move.

A window with such a signal is a transient event and is excluded; a residual
outlier whose signals look normal is listed as ``kept`` — it may be the
systematic effect the diagnosis is looking for (a hard start, a saturated
turn), which the robust loss of the fit already keeps from dominating.

A log whose moving windows are (nearly) all disturbed — a robot held in the
air, a ground truth that never moves — has not enough clean data;
:func:`detect_transients` raises :class:`~realitygap.diagnosis.logs.log.LogError`
naming the run.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import wrap_angle
from realitygap.diagnosis.adapters.contract import PreparedLog
from realitygap.diagnosis.logs.log import LogError
from realitygap.diagnosis.problem.problem import Problem
from realitygap.diagnosis.problem.residual import robust_spread

FloatArray = npt.NDArray[np.float64]

__all__ = ["TransientEvent", "TransientReport", "TransientSettings", "detect_transients"]


@dataclass(frozen=True)
class TransientSettings:
    """Thresholds of :func:`detect_transients` (documented in the module).

    Attributes
    ----------
    outlier_threshold : float
        Robust score (MAD-based standard deviations) above which a window's
        residual is an outlier.
    sub_interval_s : float
        Length of the sub-intervals the signal tests look at, s.
    stall_ratio : float
        Body motion below this fraction of the wheel motion is a stall or slip.
    min_motion_m : float
        Least wheel motion (m, encoders) in a sub-interval for the stall test.
    min_command_motion_m : float
        The same when the wheel motion comes from the commands (no encoders): larger,
        so that a dead zone (commanded creeping that does not move the robot) is not
        taken for a stall.
    min_clean_share : float
        A log needs at least this share of its moving windows clean (and two of them).
    """

    outlier_threshold: float = 6.0
    sub_interval_s: float = 0.25
    stall_ratio: float = 0.25
    min_motion_m: float = 0.01
    min_command_motion_m: float = 0.04
    min_clean_share: float = 0.2

    def __post_init__(self) -> None:
        for name in ("outlier_threshold", "sub_interval_s", "min_motion_m", "min_command_motion_m"):
            v = getattr(self, name)
            if not (v > 0 and math.isfinite(v)):
                raise ValueError(f"TransientSettings.{name}: expected a positive number, got {v!r}")
        for name in ("stall_ratio", "min_clean_share"):
            v = getattr(self, name)
            if not 0.0 <= v < 1.0:
                raise ValueError(f"TransientSettings.{name}: expected a value in [0, 1), got {v!r}")


@dataclass
class TransientEvent:
    """One disturbed stretch of a run (consecutive windows of the same kind).

    Attributes
    ----------
    run : str
        Log name.
    log_index : int
    windows : list of int
    start_s, end_s : float
        Time span, s from the log's first sample.
    kind : {"stall or slip", "ground truth frozen", "residual outlier"}
    channel : str
        The feature column with the largest robust score (``"pose_gt.dtheta"``).
    size : float
        Largest residual of that column in the event, SI units.
    unit : str
    score : float
        Largest robust score (MAD standard deviations).
    signals : str
        What the signals say.
    excluded : bool
        Set aside from attribution and shrink.
    """

    run: str
    log_index: int
    windows: list[int]
    start_s: float
    end_s: float
    kind: str
    channel: str
    size: float
    unit: str
    score: float
    signals: str
    excluded: bool

    def to_json(self) -> dict[str, Any]:
        return {
            "run": self.run,
            "start_s": self.start_s,
            "end_s": self.end_s,
            "windows": self.windows,
            "kind": self.kind,
            "channel": self.channel,
            "size": self.size,
            "unit": self.unit,
            "robust_score": self.score,
            "signals": self.signals,
            "excluded": self.excluded,
        }


@dataclass
class TransientReport:
    """Outcome of :func:`detect_transients`.

    Attributes
    ----------
    events : list of TransientEvent
    masks : dict of int to ndarray of bool
        Excluded windows per log index.
    n_windows : int
        Windows of all logs.
    settings : TransientSettings
    """

    events: list[TransientEvent] = field(default_factory=list)
    masks: dict[int, npt.NDArray[np.bool_]] = field(default_factory=dict)
    n_windows: int = 0
    settings: TransientSettings = field(default_factory=TransientSettings)

    @property
    def n_excluded(self) -> int:
        return int(sum(int(m.sum()) for m in self.masks.values()))

    @property
    def share_excluded(self) -> float:
        return self.n_excluded / self.n_windows if self.n_windows else 0.0

    def summary(self) -> str:
        kept = sum(1 for e in self.events if not e.excluded)
        return (
            f"transient events: {self.n_excluded} of {self.n_windows} windows set aside "
            f"({100 * self.share_excluded:.1f} %)"
            + (f"; {kept} residual outlier(s) with normal signals kept" if kept else "")
        )

    def to_json(self) -> dict[str, Any]:
        s = self.settings
        return {
            "n_windows": self.n_windows,
            "n_excluded": self.n_excluded,
            "share_excluded": self.share_excluded,
            "thresholds": {
                "outlier_threshold_mad_sd": s.outlier_threshold,
                "stall_ratio": s.stall_ratio,
                "sub_interval_s": s.sub_interval_s,
            },
            "events": [e.to_json() for e in self.events],
        }


# --------------------------------------------------------------------------- residual scores
def _robust_scores(problem: Problem) -> dict[int, tuple[FloatArray, list[str]]]:
    """Per log: robust score (M, columns) of every window's reference residual, column names."""
    logs = problem.logs
    floor = problem.settings.floor
    cols: list[tuple[str, int, str]] = []
    for g in problem.adapter.schema.names:
        if any(g in p.groups for p in logs):
            for j, c in enumerate(problem.adapter.schema.columns(g)):
                cols.append((g, j, c))
    resid: dict[int, FloatArray] = {}
    for i, p in enumerate(logs):
        ref = problem.baseline_features.get(i, p.nominal)
        z = np.full((p.bounds.shape[0], len(cols)), np.nan)
        for k, (g, j, _) in enumerate(cols):
            if g in p.groups:
                z[:, k] = (p.real[g][:, j] - ref[g][:, j]) / problem.features.scale(g)[j]
        resid[i] = z
    allz = np.vstack(list(resid.values())) if resid else np.zeros((0, len(cols)))
    out = {}
    med, spread = robust_spread(allz, axis=0) if allz.size else (np.zeros(len(cols)),) * 2
    sd = np.maximum(np.nan_to_num(spread), floor)
    for i, z in resid.items():
        out[i] = (np.nan_to_num(np.abs(z - med) / sd), [f"{g}.{c}" for g, _, c in cols])
    return out


# --------------------------------------------------------------------------- signals
def _signals(
    p: PreparedLog, settings: TransientSettings
) -> tuple[list[str], list[str], npt.NDArray[np.bool_]]:
    """Per window: kind (``""``, ``"stall or slip"``, ``"ground truth frozen"``), what the
    signals say, and whether the drive moves the robot in it."""
    log = p.log
    m = p.bounds.shape[0]
    kinds, texts = [""] * m, [""] * m
    moving = np.zeros(m, dtype=bool)
    wheels = p.context.wheels()
    if wheels is None or not log.has("pose_gt"):
        return kinds, texts, moving
    dt = log.dt
    b = float(wheels.wheelbase)
    gt = np.asarray(log["pose_gt"], dtype=float)
    if log.has("ticks"):
        ticks = np.asarray(log["ticks"], dtype=float)
        k = 2.0 * math.pi / wheels.ticks_per_rev
        wheel_angle = ticks * k  # rad
        travel = wheel_angle * np.array([wheels.wheel_radius_left, wheels.wheel_radius_right])
        min_motion = settings.min_motion_m
        source = "wheels"
    else:
        applied = p.context.applied_twist()
        if applied is None:  # wheels but no twist: nothing to measure the wheels by
            return kinds, texts, moving
        twist = np.asarray(applied, dtype=float)
        sl = (twist[:, 0] - 0.5 * b * twist[:, 1]) * dt
        sr = (twist[:, 0] + 0.5 * b * twist[:, 1]) * dt
        travel = np.concatenate([np.zeros((1, 2)), np.cumsum(np.column_stack([sl, sr]), 0)[:-1]])
        wheel_angle = travel / np.array([wheels.wheel_radius_left, wheels.wheel_radius_right])
        min_motion = settings.min_command_motion_m
        source = "commands"
    cmd = np.asarray(log["cmd"], dtype=float) if log.has("cmd") else None
    n_sub = max(2, int(round(settings.sub_interval_s / dt)))
    for w, (a, e) in enumerate(p.bounds):
        e = min(int(e), gt.shape[0] - 1)
        a = int(a)
        dur = max((e - a) * dt, dt)
        d_wheels = travel[e] - travel[a]
        m_w_win = abs(d_wheels.mean()) + 0.5 * abs(d_wheels[1] - d_wheels[0])
        moving[w] = m_w_win > min_motion
        found = ""
        for s in range(a, max(e - n_sub, a) + 1, max(1, n_sub // 2)):
            t = min(s + n_sub, e)
            dw = travel[t] - travel[s]
            m_w = abs(dw.mean()) + 0.5 * abs(dw[1] - dw[0])
            if m_w <= min_motion:
                continue
            seg = gt[s : t + 1]
            if np.all(np.diff(seg, axis=0) == 0.0):
                found = "ground truth frozen"
                break
            m_b = float(np.hypot(*(seg[-1, :2] - seg[0, :2]))) + 0.5 * b * abs(
                float(wrap_angle(seg[-1, 2] - seg[0, 2]))
            )
            if m_b < settings.stall_ratio * m_w:
                found = "stall or slip"
        kinds[w] = found
        wheel_rate = (wheel_angle[e] - wheel_angle[a]) / dur
        v_body = float(np.hypot(*(gt[e, :2] - gt[a, :2]))) / dur
        w_body = float(wrap_angle(gt[e, 2] - gt[a, 2])) / dur
        w_wheels = float((d_wheels[1] - d_wheels[0]) / b) / dur
        commanded = ""
        if cmd is not None:
            c = cmd[a:e].mean(axis=0) if e > a else cmd[a]
            commanded = f"commanded {c[0]:.3f} m/s, {c[1]:+.2f} rad/s; "
        texts[w] = (
            commanded
            + f"{source}: left {wheel_rate[0]:+.2f} rad/s, right {wheel_rate[1]:+.2f} rad/s "
            f"(turn {w_wheels:+.2f} rad/s); body {v_body:.3f} m/s, {w_body:+.2f} rad/s"
            + (f": {found}" if found else "")
        )
    return kinds, texts, moving


# --------------------------------------------------------------------------- detector
def detect_transients(
    problem: Problem, settings: TransientSettings | None = None
) -> TransientReport:
    """List the transient windows of every log of ``problem`` (see the module).

    Parameters
    ----------
    problem : Problem
        Prepared logs with their reference replays.
    settings : TransientSettings, optional

    Returns
    -------
    TransientReport
        Events and the per-log masks of excluded windows (not yet applied:
        :meth:`~realitygap.diagnosis.problem.problem.Problem.exclude` does that).

    Raises
    ------
    LogError
        A log has not enough clean data (its moving windows are nearly all disturbed).
    """
    s = settings if settings is not None else TransientSettings()
    if not isinstance(s, TransientSettings):
        raise TypeError(f"detect_transients: settings must be TransientSettings, got {type(s)}")
    report = TransientReport(settings=s)
    scores = _robust_scores(problem)
    for i, p in enumerate(problem.logs):
        m = p.bounds.shape[0]
        report.n_windows += m
        score, names = scores[i]
        kinds, texts, moving = _signals(p, s)
        worst = score.argmax(axis=1) if score.size else np.zeros(m, dtype=int)
        top = score.max(axis=1) if score.size else np.zeros(m)
        outlier = top > s.outlier_threshold
        kind_w = [
            k if k else ("residual outlier" if outlier[w] else "") for w, k in enumerate(kinds)
        ]
        mask = np.array([bool(k) and k != "residual outlier" for k in kind_w], dtype=bool)
        report.masks[i] = mask
        n_moving = int(moving.sum())
        clean_moving = int((moving & ~mask).sum())
        if n_moving and (clean_moving < 2 or clean_moving < s.min_clean_share * n_moving):
            what = _count_text([k for k, mv in zip(kind_w, moving) if mv and k])
            raise LogError(
                f"not enough clean data in {p.name}: {n_moving - clean_moving} of {n_moving} "
                f"windows in which the drive moves are transient events ({what}); the diagnosis "
                f"needs at least 2 and {100 * s.min_clean_share:.0f} % of them clean. Fix: check "
                "that the robot was on the ground and the ground truth was tracking, or leave "
                "this run out"
            )
        w = 0
        t0 = float(p.log.t[0])
        while w < m:
            if not kind_w[w]:
                w += 1
                continue
            e = w
            while e + 1 < m and kind_w[e + 1] == kind_w[w]:
                e += 1
            wins = list(range(w, e + 1))
            j = int(worst[wins][np.argmax(top[wins])])
            g, _, c = names[j].partition(".")
            col = problem.adapter.schema.columns(g).index(c)
            unit = problem.adapter.schema.units(g)[col]
            ref = problem.baseline_features.get(i, p.nominal)
            size = float(np.max(np.abs(p.real[g][wins, col] - ref[g][wins, col])))
            strongest = wins[int(np.argmax(top[wins]))]
            report.events.append(
                TransientEvent(
                    run=p.name,
                    log_index=i,
                    windows=wins,
                    start_s=float(p.log.t[p.bounds[w, 0]]) - t0,
                    end_s=float(p.log.t[min(p.bounds[e, 1], p.log.n - 1)]) - t0,
                    kind=kind_w[w],
                    channel=names[j],
                    size=size,
                    unit=unit,
                    score=float(top[wins].max()),
                    signals=texts[strongest],
                    excluded=bool(mask[w]),
                )
            )
            w = e + 1
    return report


def _count_text(kinds: Sequence[str]) -> str:
    """``"3 stall or slip, 1 ground truth frozen"``."""
    return ", ".join(f"{n} {k}" for k, n in Counter(kinds).most_common()) or "none"
