r"""Per-log clock alignment: each recording's own time offset between its channels.

Every recording synchronises its clocks once (a motion-capture system and a
robot's encoders, each with its own clock): the offset between the ground truth
and the robot's channels is therefore one value per log, and it differs from
log to log by the accuracy of that synchronisation — tens of milliseconds on
real set-ups. A window of length :math:`T` then carries a heading error

.. math::  e_θ \approx δ_i \, Δω

(the change of turn rate over the window times the log's offset), which at a
1-s window scale can be larger than the signature of a wheelbase error of
a per cent. A single common alignment (the baseline's nuisance, or a
``timestamp_offset`` effect) cannot remove it.

:func:`align_clocks` fits, before any effect, each log's total offset
:math:`o_i` of the timing parameter the adapter names as a nuisance (for the
differential drive ``timestamp_offset.offset``, the ground truth's stamp minus
true time) on the log's own windows with the reference model, robustly (the
same loss and scale as the attribution). A common geometric error of the
robot barely biases these offsets — it scales the motion of a window, a clock
offset follows its *change* — and what bias it leaves is common to the logs.
The common part

.. math::  c = \operatorname{median}_i o_i

is *not* removed — it belongs to the calibrated baseline's nuisance or, when
larger, to a ``timestamp_offset`` / latency effect the diagnosis may name —
only the deviations :math:`δ_i = o_i - c` are, and only where

* :math:`|δ_i| \le` :attr:`ClockSettings.bound` (a synchronisation error, not
  a finding; a log beyond it keeps the common offset and is listed), and
* the deviation lowers the log's robust cost by more than a BIC penalty,
  :math:`Δχ^2 > \log n_i` (:math:`n_i` residual entries of the log, in units
  of the noise level), so that noise does not move a log's clock.

A deviation is applied by re-stamping the log's channel
(:func:`restamp`: the channel evaluated at :math:`t + δ_i`, linear, angles
unwrapped), after which every stage — the baseline's nuisances, the
attribution, the verdict and the whole-run trajectory gaps — sees a recording
whose clocks agree with the common offset. Held-out logs are aligned too,
from their own windows and the reference model only (as their start pose is
taken from their own ground truth): their clock is a property of the
recording, not of any effect.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.fit.model import _rho
from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.parameters import param_spec, split_key
from realitygap.diagnosis.problem.problem import Problem
from realitygap.robots.effects import make_effect

FloatArray = npt.NDArray[np.float64]

__all__ = ["ClockAlignment", "ClockSettings", "align_clocks", "restamp", "timing_channel"]


@dataclass(frozen=True)
class ClockSettings:
    """Settings of the per-log clock alignment.

    Attributes
    ----------
    bound : float
        Largest deviation of one log's offset from the common one that counts as
        a synchronisation error, s (physical: tens of milliseconds).
    step : float
        Grid step of the search over the timing parameter's physical range, s;
        the minimum is refined by a parabola through its neighbours.
    """

    bound: float = 0.05
    step: float = 0.002

    def __post_init__(self) -> None:
        for name in ("bound", "step"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(
                    f"ClockSettings.{name}: expected a positive number of seconds, got {v!r}"
                )
        if self.step >= self.bound:
            raise ValueError(
                f"ClockSettings.step ({self.step:g} s) must be below bound ({self.bound:g} s); "
                "fix: use a step of a few milliseconds"
            )


@dataclass
class ClockAlignment:
    """Result of :func:`align_clocks`.

    Attributes
    ----------
    parameter : str
        The timing parameter (``"effect.param"``) whose per-log value was fitted.
    channel : str
        The channel that was re-stamped.
    common : float
        Median of the logs' fitted offsets, s (left to the baseline or an effect).
    rows : list of dict
        Per log: ``log``, ``split``, ``offset_s`` (fitted total offset),
        ``deviation_s`` (from ``common``), ``applied``, ``chi2_drop`` (cost
        reduction in noise units) and ``why`` when not applied.
    bound : float
    """

    parameter: str = ""
    channel: str = ""
    common: float = 0.0
    rows: list[dict[str, Any]] = field(default_factory=list)
    bound: float = 0.0

    @property
    def applied(self) -> list[float]:
        """Deviations of the logs that were re-stamped, s (in log order)."""
        return [r["deviation_s"] for r in self.rows if r["applied"]]

    def to_json(self) -> dict[str, Any]:
        return {
            "parameter": self.parameter,
            "channel": self.channel,
            "common_offset_s": self.common,
            "bound_s": self.bound,
            "logs": [dict(r) for r in self.rows],
        }

    def summary(self) -> str:
        """One line: how many logs were re-stamped and the range of their deviations."""
        if not self.rows:
            return ""
        dev = self.applied
        head = f"per-log clock alignment of {self.channel}: "
        if not dev:
            return head + f"none of {len(self.rows)} logs re-stamped"
        return head + (
            f"{len(dev)} of {len(self.rows)} logs re-stamped by {1e3 * min(dev):+.1f} … "
            f"{1e3 * max(dev):+.1f} ms from the common offset {1e3 * self.common:+.1f} ms "
            f"(bound ±{1e3 * self.bound:.0f} ms)"
        )


def timing_channel(key: str) -> str | None:
    """The channel a timing parameter ``"effect.param"`` shifts, or ``None``.

    Read from the effect itself (:meth:`~realitygap.robots.effects.Effect.channel_time_offsets`
    at a non-zero value): an effect that shifts exactly one channel's stamps.
    """
    effect, pname = split_key(key)
    try:
        spec = param_spec(key)
        probe = make_effect(effect, **{pname: 0.5 * (spec.high if spec.high else spec.low)})
    except (KeyError, TypeError, ValueError):
        return None
    shifted = probe.channel_time_offsets()
    return next(iter(shifted)) if len(shifted) == 1 else None


def restamp(log: Log, channel: str, shift: float) -> Log:
    """``log`` with ``channel`` evaluated at ``t + shift`` (s); other channels unchanged.

    A channel stamped ``shift`` seconds late holds at stamp ``t`` what happened at
    ``t - shift``; its value at ``t + shift`` is what happened at ``t``. Linear
    interpolation, angle columns unwrapped and kept in the log's own convention
    (wrapped or continuous); times beyond the log are clamped to its first / last
    sample.
    """
    if not math.isfinite(shift):
        raise ValueError(f"restamp: the shift must be a finite number of seconds, got {shift!r}")
    if not log.has(channel):
        raise ValueError(f"restamp: {log.source} has no channel {channel!r}")
    if shift == 0.0:
        return log
    original = np.asarray(log[channel], dtype=float)
    moved = log.interpolated(log.t + shift)[channel].copy()
    for j in log.spec(channel).angle_columns:
        # keep the log's own angle convention (wrapped or continuous): add the wrapped change
        step = moved[:, j] - np.unwrap(original[:, j])
        moved[:, j] = original[:, j] + np.angle(np.exp(1j * step))
    return log.with_channels(**{channel: moved})


def _log_costs(problem: Problem, i: int, key: str, offsets: FloatArray) -> tuple[FloatArray, int]:
    """Robust cost of log ``i`` (every window not set aside) at each total offset."""
    p = problem.logs[i]
    use = ~problem.excluded.get(i, np.zeros(p.bounds.shape[0], dtype=bool))
    n_b = offsets.size
    values = problem.with_baseline({key: offsets}, n_b)
    sur = problem.adapter.surrogate_features(p, values, problem.drive)
    cost = np.zeros(n_b)
    n = 0
    st = problem.settings
    for g in p.groups:
        pred = sur[g][:, use] + p.bias[g][use][None]
        z = (p.real[g][use][None] - pred) / problem.features.scale(g)
        cost += np.sum(_rho(z**2, st.loss, problem.f_scale), axis=(1, 2))
        n += int(z[0].size)
    return cost, n


def _refine(grid: FloatArray, cost: FloatArray) -> float:
    """Minimum of ``cost`` on ``grid`` refined by a parabola through its neighbours."""
    j = int(np.argmin(cost))
    if 0 < j < grid.size - 1:
        c0, c1, c2 = cost[j - 1], cost[j], cost[j + 1]
        den = c0 - 2.0 * c1 + c2
        if den > 0:
            return float(grid[j] + 0.5 * (grid[1] - grid[0]) * (c0 - c2) / den)
    return float(grid[j])


def align_clocks(
    problem: Problem,
    key: str,
    settings: ClockSettings,
    say: Callable[[str], None] = lambda msg: None,
) -> ClockAlignment:
    """Fit each log's clock offset and re-stamp the logs whose deviation is a sync error.

    Parameters
    ----------
    problem : Problem
        Its logs are modified in place: ``log`` re-stamped and ``real`` features
        recomputed for every log whose deviation is applied; the layouts are rebuilt.
    key : str
        The timing parameter (``"timestamp_offset.offset"``); it must shift one
        channel's stamps (:func:`timing_channel`).
    settings : ClockSettings
    say : callable

    Returns
    -------
    ClockAlignment
        Empty when fewer than two logs are given or ``key`` shifts no single channel.
    """
    channel = timing_channel(key)
    logs: Sequence[Any] = problem.logs
    if channel is None or len(logs) < 2:
        return ClockAlignment()
    spec = param_spec(key)
    n_grid = int(math.floor((spec.high - spec.low) / settings.step + 1e-9)) + 1
    grid = spec.low + settings.step * np.arange(n_grid)
    noise = problem.f_scale / problem.settings.robust_scale
    fitted: list[float] = []
    sizes: list[int] = []
    for i in range(len(logs)):
        cost, n = _log_costs(problem, i, key, grid)
        fitted.append(_refine(grid, cost))
        sizes.append(n)
    common = float(np.median(fitted))
    out = ClockAlignment(parameter=key, channel=channel, common=common, bound=settings.bound)
    for i, p in enumerate(logs):
        dev = fitted[i] - common
        row: dict[str, Any] = {
            "log": p.name,
            "split": p.split,
            "offset_s": fitted[i],
            "deviation_s": dev,
            "applied": False,
            "chi2_drop": 0.0,
            "why": "",
        }
        pair, _ = _log_costs(problem, i, key, np.array([common, fitted[i]]))
        drop = float(pair[0] - pair[1]) / noise**2
        row["chi2_drop"] = drop
        if abs(dev) > settings.bound:
            row["why"] = (
                f"deviation {1e3 * dev:+.1f} ms beyond ±{1e3 * settings.bound:.0f} ms: "
                "not a synchronisation error; the log keeps the common offset"
            )
        elif not drop > math.log(max(sizes[i], 2)):
            row["why"] = "the deviation does not lower the log's cost beyond noise"
        else:
            row["applied"] = True
            # the model shifts the simulated channel by the common offset; the rest is the log's
            p.log = restamp(p.log, channel, dev)
            feats = problem.adapter.log_features(p, p.log)
            p.real = {g: feats[g] for g in p.real}
        out.rows.append(row)
    if out.applied:
        problem.exclude(problem.excluded)
    say(out.summary())
    return out
