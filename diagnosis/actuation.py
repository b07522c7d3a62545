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
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.stats import chi2

from realitygap.diagnosis.adapters import PreparedLog

__all__ = ["actuation_spread", "command_wheel_gains"]


def command_wheel_gains(adapter: Any, prepared: Sequence[PreparedLog]) -> list[dict[str, Any]]:
    """Per log of a command-driven diagnosis, the adapter's ``command_wheel_gains`` with
    the log's name and split; empty when the adapter has none or no log qualifies."""
    if not hasattr(adapter, "command_wheel_gains"):
        return []
    rows = []
    for p in prepared:
        g = adapter.command_wheel_gains(p)
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
