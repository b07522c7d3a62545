r"""Does the drive train answer the commands the same way in every log?

A command-driven replay sends the logged commands through the nominal drive
train; where the log also holds the encoders, the wheels' own motion shows how
the real drive train answered (the adapter's ``command_wheel_gains``: per log,
the slope :math:`g_i` of the wheels' heading change per window on what the
commands asked of the nominal drive train, with its standard error
:math:`σ_i`). A fixed effect — a lag, a dead zone, a gain — answers every log
alike. When the logs disagree beyond their errors, the drive train changed
between them (a firmware's tuning, a battery, a floor), and no fixed effect of a
command-driven replay can close that part of the gap.

:func:`actuation_spread` tests the logs' gains for a common value with
Cochran's :math:`Q`,

.. math::  Q = \sum_i w_i (g_i - \bar g)^2, \qquad w_i = σ_i^{-2}, \quad
           \bar g = \frac{\sum_i w_i g_i}{\sum_i w_i},

against :math:`χ^2_{k-1}` for :math:`k` logs.

:func:`wheel_tracking` asks the encoders the question the training cannot answer:
where held-out runs ask a wheel for more speed than any training run did, did
the wheel still follow? Per wheel, the gain :math:`g` of the logged wheel travel
on the nominal drive train's (window by window, through the origin,
:func:`~realitygap.diagnosis.stages.scales.gain_through_origin`) in the training is
compared with the same gain over the held-out windows beyond the training's
fastest request. A wheel whose gain falls there (a top speed, a torque limit
reached only beyond the training) is a drive-train effect that no fit on this
training can find, and the experiment that tests it is a training run at those
speeds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.stats import chi2

from realitygap.diagnosis.adapters.contract import PreparedLog
from realitygap.diagnosis.stages.scales import gain_through_origin

__all__ = ["GainsOf", "TravelOf", "actuation_spread", "command_wheel_gains", "wheel_tracking"]

FloatArray = npt.NDArray[np.float64]

WHEELS = ("left", "right")


GainsOf = Callable[[PreparedLog], dict[str, float] | None]
"""A log's drive-train gains (the adapter's ``command_wheel_gains``), or ``None``."""
TravelOf = Callable[[PreparedLog], tuple[FloatArray, FloatArray, FloatArray] | None]
"""A log's wheel travel per window, logged and nominal (M, 2 each, m), and the windows'
durations (M,), s (the adapter's ``wheel_travel``), or ``None``."""


def command_wheel_gains(gains_of: GainsOf, prepared: Sequence[PreparedLog]) -> list[dict[str, Any]]:
    """Per log of a command-driven diagnosis, its gains ``gains_of(log)`` (the adapter's
    ``command_wheel_gains``) with the log's name and split; empty when no log qualifies."""
    rows = []
    for p in prepared:
        g = gains_of(p)
        if g is not None:
            rows.append({"log": p.name, "split": p.split, **g})
    return rows


def actuation_spread(
    rows: Sequence[dict[str, Any]], alpha: float = 0.01, key: str = "turn_gain"
) -> dict[str, Any] | None:
    """Whether the logs' drive-train gains share one value (Cochran's Q).

    Parameters
    ----------
    rows : sequence of dict
        From :func:`command_wheel_gains`: ``log``, ``key`` and ``key + "_se"``.
    alpha : float
        Level of the test, in (0, 1).
    key : str
        The gain to compare.

    Returns
    -------
    dict or None
        ``logs`` (those with a finite gain and error), ``mean`` (weighted), ``min``,
        ``max``, ``q``, ``p``, ``differs`` (``p < alpha``) and ``message``; ``None``
        with fewer than two such logs.
    """
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"actuation_spread: alpha must lie in (0, 1), got {alpha!r}")
    use = [
        r
        for r in rows
        if math.isfinite(r.get(key, math.nan))
        and math.isfinite(r.get(f"{key}_se", math.nan))
        and r[f"{key}_se"] > 0
    ]
    if len(use) < 2:
        return None
    g = np.array([r[key] for r in use])
    w = 1.0 / np.array([r[f"{key}_se"] for r in use]) ** 2
    mean = float(w @ g / w.sum())
    q = float(w @ (g - mean) ** 2)
    p = float(chi2.sf(q, len(use) - 1))
    lo, hi = int(np.argmin(g)), int(np.argmax(g))
    differs = p < alpha
    what = key.replace("_", " ")
    message = (
        f"the drive train's {what} against what the commands asked differs from log to log "
        f"({g[lo]:.3f} in {use[lo]['log']} … {g[hi]:.3f} in {use[hi]['log']}; Cochran's Q = "
        f"{q:.0f} over {len(use)} logs, p = {p:.2g}): a response that changes between "
        "sessions, which no fixed effect of a command-driven replay reproduces; a replay "
        "driven by the encoders (drive 'ticks') tests the body's effects without it"
        if differs
        else f"the drive train's {what} is the same in every log within its errors "
        f"({g.min():.3f} … {g.max():.3f}, p = {p:.2g})"
    )
    return {
        "logs": [r["log"] for r in use],
        "mean": mean,
        "min": float(g.min()),
        "max": float(g.max()),
        "q": q,
        "p": p,
        "differs": differs,
        "message": message,
    }


def wheel_tracking(
    travel_of: TravelOf,
    prepared: Sequence[PreparedLog],
    *,
    v_max: float | None = None,
    margin: float = 0.1,
    min_speed: float = 0.02,
    min_windows: int = 3,
    min_departure: float = 0.05,
    sigmas: float = 3.0,
) -> dict[str, Any] | None:
    """Whether each wheel still follows the commands where held-out runs ask it for more
    speed than the training ever did (see the module docstring).

    Parameters
    ----------
    travel_of : callable
        ``travel_of(prepared)`` (the adapter's ``wheel_travel``): per window the logged and
        the nominal replay's wheel travel (M, 2), m, and the windows' durations, s
        (``None`` for a log without encoders or commands).
    prepared : sequence of PreparedLog
        Training windows are those of training logs not scored as held out.
    v_max : float or None
        The robot's speed limit (m/s): the message's suggested test speed stays within it.
    margin : float
        A held-out window lies beyond the training when the nominal drive train's speed
        of a wheel there exceeds the training's fastest by more than this share.
    min_speed : float
        Windows whose wheel is asked for less (m/s) say nothing of its gain.
    min_windows : int
        Fewest windows of a wheel for a gain.
    min_departure : float
        Smallest change of gain that counts, also when its errors are smaller.
    sigmas : float
        Standard errors (of the difference of the two gains) a change must exceed.

    Returns
    -------
    dict or None
        ``wheels``: per wheel ``wheel``, ``train_top_speed`` (m/s), ``train_gain``,
        ``train_gain_se``, ``n_beyond`` and, with enough windows beyond,
        ``beyond_gain``, ``beyond_gain_se``, ``asked_max`` and ``reached_max`` (m/s),
        ``n_capped`` and ``capped_logs`` (windows beyond that ask for more than
        ``1 + margin`` times the fastest the wheel reached there: a ceiling), ``logs``
        (held-out logs of the windows beyond, most first), ``by_log`` (per such log with
        ``min_windows``: ``log``, ``n``, ``gain``, ``gain_se``, ``asked_max``,
        ``reached_max``, ``departs``) and ``departs`` (the pooled gain, a ceiling or a log's
        gain departs);
        ``departs`` (any wheel), ``beyond`` (any wheel asked beyond the training) and
        ``message``. ``None`` when either split has no window with wheel travel.
    """
    for name, value, ok, expected in (
        ("margin", margin, margin >= 0, "a share >= 0 (default 0.1)"),
        ("min_speed", min_speed, min_speed >= 0, "a speed >= 0 m/s (default 0.02)"),
        ("min_windows", min_windows, min_windows >= 3, "a count >= 3 (default 3)"),
        ("min_departure", min_departure, min_departure >= 0, "a gain change >= 0 (default 0.05)"),
        ("sigmas", sigmas, sigmas > 0, "a number of standard errors > 0 (default 3)"),
    ):
        if not (ok and math.isfinite(value)):
            raise ValueError(f"wheel_tracking: {name} must be {expected}, got {value!r}")
    real, asked, dur, train, held, names = [], [], [], [], [], []
    for p in prepared:
        w = travel_of(p)
        if w is None:
            continue
        r, a, d = w
        ho = np.asarray(p.holdout_windows, dtype=bool)
        real.append(r)
        asked.append(a)
        dur.append(d)
        held.append(ho)
        train.append(~ho if p.split == "train" else np.zeros_like(ho))
        names += [p.name] * len(d)
    if not real:
        return None
    r_all, a_all, d_all = np.concatenate(real), np.concatenate(asked), np.concatenate(dur)
    is_train, is_held = np.concatenate(train), np.concatenate(held)
    if not (is_train.any() and is_held.any()):
        return None
    ok = d_all > 0
    speed_asked = np.abs(a_all) / np.where(ok, d_all, 1.0)[:, None]
    speed_real = np.abs(r_all) / np.where(ok, d_all, 1.0)[:, None]
    names_arr = np.asarray(names, dtype=object)
    rows: list[dict[str, Any]] = []
    for j, wheel in enumerate(WHEELS):
        moving = ok & (speed_asked[:, j] >= min_speed)
        tr = is_train & moving
        if int(tr.sum()) < min_windows:
            continue
        top = float(speed_asked[tr, j].max())
        g_t, se_t = gain_through_origin(r_all[tr, j], a_all[tr, j])
        beyond = is_held & moving & (speed_asked[:, j] > top * (1.0 + margin))
        row: dict[str, Any] = {
            "wheel": wheel,
            "train_top_speed": top,
            "train_gain": g_t,
            "train_gain_se": se_t,
            "n_beyond": int(beyond.sum()),
            "departs": False,
        }
        rows.append(row)
        if row["n_beyond"] < min_windows:
            continue
        against = (g_t, se_t, min_departure, sigmas)
        g_b, se_b, off = _gain_against(r_all[beyond, j], a_all[beyond, j], *against)
        logs, counts = np.unique(names_arr[beyond], return_counts=True)
        ordered = [str(x) for x in logs[np.argsort(-counts, kind="stable")]]
        reached = float(speed_real[beyond, j].max())
        # a ceiling: windows asking clearly more than the wheel ever reached beyond
        capped = beyond & (speed_asked[:, j] > reached * (1.0 + margin))
        n_capped = int(capped.sum())
        by_log = []
        for name in ordered:
            sel = beyond & (names_arr == name)
            if int(sel.sum()) >= min_windows:
                g, se, off_log = _gain_against(r_all[sel, j], a_all[sel, j], *against)
                by_log.append(
                    {
                        "log": name,
                        "n": int(sel.sum()),
                        "gain": g,
                        "gain_se": se,
                        "asked_max": float(speed_asked[sel, j].max()),
                        "reached_max": float(speed_real[sel, j].max()),
                        "departs": off_log,
                    }
                )
        row.update(
            beyond_gain=g_b,
            beyond_gain_se=se_b,
            asked_max=float(speed_asked[beyond, j].max()),
            reached_max=reached,
            n_capped=n_capped,
            capped_logs=sorted({str(x) for x in names_arr[capped]}),
            logs=ordered,
            by_log=by_log,
            departs=off or n_capped >= min_windows or any(b["departs"] for b in by_log),
        )
    if not rows:
        return None
    return {
        "wheels": rows,
        "departs": any(r["departs"] for r in rows),
        "beyond": any("beyond_gain" in r for r in rows),
        "message": _tracking_message(rows, v_max),
    }


def _gain_against(
    real: FloatArray,
    asked: FloatArray,
    g_train: float,
    se_train: float,
    min_departure: float,
    sigmas: float,
) -> tuple[float, float, bool]:
    """Gain of ``real`` on ``asked`` travel, its error, and whether it departs from the
    training gain ``g_train ± se_train`` (by ``min_departure`` and ``sigmas`` errors of the
    difference)."""
    g, se = gain_through_origin(real, asked)
    err = math.hypot(*(x if math.isfinite(x) else 0.0 for x in (se_train, se)))
    return g, se, bool(abs(g - g_train) > max(min_departure, sigmas * err))


def _tracking_message(rows: Sequence[dict[str, Any]], v_max: float | None) -> str:
    """The words of :func:`wheel_tracking`."""
    beyond = [r for r in rows if "beyond_gain" in r]
    if not beyond:
        tops = ", ".join(f"{r['wheel']} up to {r['train_top_speed']:.3g} m/s" for r in rows)
        return f"no held-out run asks a wheel for more speed than the training did ({tops})"
    parts = []
    for r in beyond:
        head = (
            f"the {r['wheel']} wheel, asked for up to {r['asked_max']:.2f} m/s in "
            f"{r['n_beyond']} held-out windows (the training asked at most "
            f"{r['train_top_speed']:.2f} m/s)"
        )
        if not r["departs"]:
            parts.append(
                f"{head}, followed as in training ({r['beyond_gain']:.2f} of the nominal "
                f"travel against {r['train_gain']:.2f})"
            )
            continue
        says = [
            f"turned {r['beyond_gain']:.2f} of the nominal drive train's travel there against "
            f"{r['train_gain']:.2f} in training"
        ]
        if r["n_capped"]:
            says.append(
                f"never faster than {r['reached_max']:.2f} m/s although {r['n_capped']} windows "
                f"asked for more (in {', '.join(r['capped_logs'][:3])})"
            )
        off = [b for b in r["by_log"] if b["departs"]]
        if off:
            says.append(
                "; ".join(
                    f"{b['gain']:.2f} in {b['log']} (up to {b['reached_max']:.2f} of "
                    f"{b['asked_max']:.2f} m/s)"
                    for b in off[:3]
                )
            )
        parts.append(f"{head}, " + ", ".join(says))
    departed = [r for r in beyond if r["departs"]]
    if not departed:
        return (
            "beyond the training's wheel speeds the encoders show the wheels following the "
            "commands as in training: " + "; ".join(parts)
        )
    top = max(r["asked_max"] for r in departed)
    within = ""
    if v_max is not None and math.isfinite(v_max):
        top = min(top, float(v_max))
        within = f", within the robot's {v_max:.2f} m/s"
    return (
        "beyond the training's wheel speeds the encoders show the drive train answering the "
        "commands otherwise: " + "; ".join(parts) + ". An effect that acts only there (a "
        "top speed or a torque limit of that wheel, or one that changes from run to run) "
        f"cannot be fitted from this training; drive straight legs at up to {top:.2f} m/s"
        f"{within}, to test it"
    )
