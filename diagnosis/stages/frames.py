r"""Per-log frame alignment: the body frame each recording's ground truth tracks.

A motion-capture system tracks a rigid body that someone defined by hand on
the robot — its origin a few millimetres off the axle centre, its heading a few
milliradians off the direction the wheels roll. A rigid body is defined again
whenever markers are moved or a session is set up anew, so the frame is a
property of the *recording*, like its clock synchronisation
(:mod:`~realitygap.diagnosis.stages.clock`), and differs from session to session. A
frame :math:`F = (x, y, ψ)` shows in every window as

.. math::  e_y \approx ψ\,Δs + x\,Δθ

(sideways motion along each metre driven, and the origin circling the axle in
each turn): a common frame is the calibrated baseline's nuisance
(``truth_frame_offset``), but sessions that differ by a few millimetres leave a
sideways residual that no robot effect explains and that adds up along a run.

:func:`align_frames` fits, before any effect, each log's own frame
:math:`F_i` on its own windows with the reference model, robustly (the same
loss and scale as the attribution), within the nuisance's stated range. A
robot effect barely biases the fit — geometric and drive-train errors change
how far and how much a window turns, a frame changes where sideways the
tracked origin goes — and what bias it leaves is common to the logs. The common
part, the per-component median :math:`F_c`, is *not* removed (it belongs to the
baseline), only each log's deviation from it, and only where

* the fitted frame lies inside the nuisance range (a frame at its edge is a
  gap the frame cannot close, not a convention; the log keeps the common one), and
* the deviation lowers the log's robust cost by more than a BIC penalty,
  :math:`Δχ^2 > k_i \log n_i` (:math:`k_i` components the log's motion tests,
  :math:`n_i` residual entries, in units of the noise level), so that noise does
  not move a log's frame. A component the log's motion does not test (the
  heading of the frame in a turn on the spot) keeps the common value.

A deviation is applied by re-framing the log's channel: the recorded track
:math:`R_k` is taken back to the body poses it implies under :math:`F_i`
and recorded again under :math:`F_c` (:func:`~realitygap.core.geometry.reframe_recorded`; headings
are unchanged). Held-out logs are aligned too, from their own windows and the
reference model only, as their clocks are.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares

from realitygap.core.geometry import reframe_recorded
from realitygap.diagnosis.fit.model import _rho
from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.parameters import model_keys, param_spec, split_key
from realitygap.diagnosis.problem.problem import Problem
from realitygap.robots.effects import make_effect

FloatArray = npt.NDArray[np.float64]

__all__ = ["TESTED", "FrameAlignment", "align_frames", "frame_channel"]

TESTED = 0.05
"""A frame component moves a log's residuals over its whole range by less than this
fraction of what the most telling component does: the log's motion does not test it."""


@dataclass
class FrameAlignment:
    """Result of :func:`align_frames`.

    Attributes
    ----------
    keys : tuple of str
        The frame parameters (``"effect.x"``, ``"effect.y"``, ``"effect.yaw"``).
    channel : str
        The channel that was re-framed.
    common : tuple of float
        Per-component median of the logs' fitted frames (m, m, rad), left to the baseline.
    rows : list of dict
        Per log: ``log``, ``split``, ``frame`` (fitted x, y, yaw), ``deviation``
        (from ``common``), ``applied``, ``chi2_drop`` (cost reduction in noise
        units) and ``why`` when not applied.
    """

    keys: tuple[str, ...] = ()
    channel: str = ""
    common: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rows: list[dict[str, Any]] = field(default_factory=list)

    @property
    def applied(self) -> list[tuple[float, float, float]]:
        """Deviations (x m, y m, yaw rad) of the logs that were re-framed, in log order."""
        return [tuple(r["deviation"]) for r in self.rows if r["applied"]]

    def to_json(self) -> dict[str, Any]:
        return {
            "parameters": list(self.keys),
            "channel": self.channel,
            "common_frame": list(self.common),
            "logs": [dict(r) for r in self.rows],
        }

    def summary(self) -> str:
        """One line: how many logs were re-framed and by how much at most."""
        if not self.rows:
            return ""
        dev = np.array(self.applied).reshape(-1, 3)
        head = f"per-log frame alignment of {self.channel}: "
        if dev.shape[0] == 0:
            return head + f"none of {len(self.rows)} logs re-framed"
        xy = 1e3 * float(np.max(np.hypot(dev[:, 0], dev[:, 1])))
        yaw = 1e3 * float(np.max(np.abs(dev[:, 2])))
        cx, cy, cyaw = self.common
        return head + (
            f"{dev.shape[0]} of {len(self.rows)} logs re-framed by up to {xy:.1f} mm and "
            f"{yaw:.1f} mrad from the common frame ({1e3 * cx:+.1f} mm, {1e3 * cy:+.1f} mm, "
            f"{1e3 * cyaw:+.1f} mrad)"
        )


def frame_channel(effect: str) -> str | None:
    """The channel whose recorded frame the effect ``effect`` moves, or ``None``.

    Read from the effect itself (:meth:`~realitygap.robots.effects.Effect.channel_frames`
    at a non-zero frame): an effect with parameters ``x``, ``y``, ``yaw`` that
    re-frames exactly one channel.
    """
    try:
        probe = make_effect(effect, x=0.01, y=0.01, yaw=0.01)
    except (KeyError, TypeError, ValueError):
        return None
    frames = probe.channel_frames()
    return next(iter(frames)) if len(frames) == 1 else None


def _residuals(problem: Problem, i: int, keys: Sequence[str], points: FloatArray) -> FloatArray:
    """Normalised residuals (B, n) of log ``i`` (windows not set aside) at each point (B, K)
    of the parameters ``keys``."""
    p = problem.logs[i]
    use = ~problem.excluded.get(i, np.zeros(p.bounds.shape[0], dtype=bool))
    values = problem.with_baseline({k: points[:, j] for j, k in enumerate(keys)}, points.shape[0])
    sur = problem.adapter.surrogate_features(p, values, problem.drive)
    parts = []
    for g in p.groups:
        pred = sur[g][:, use] + p.bias[g][use][None]
        z = (p.real[g][use][None] - pred) / problem.features.scale(g)
        parts.append(z.reshape(points.shape[0], -1))
    return np.concatenate(parts, axis=1)


@dataclass(frozen=True)
class _LogFit:
    """One log's frame fit: the space it searches and what it found."""

    keys: tuple[str, ...]  # the three frame parameters, then the robot's own
    low: FloatArray
    high: FloatArray
    start: FloatArray  # frame zero, the robot's parameters at nominal
    free: FloatArray  # which parameters the fit moves
    tested: FloatArray  # which frame components the log's motion tests
    n: int  # residual entries


def _jacobian(
    problem: Problem,
    i: int,
    keys: Sequence[str],
    low: FloatArray,
    high: FloatArray,
    x: FloatArray,
) -> FloatArray:
    """Forward-difference Jacobian (n, K) of log ``i``'s residuals in the parameters
    ``keys`` (ranges ``[low, high]``) at ``x``, one batch."""
    h = 1e-4 * (high - low)
    step = np.where(x + h <= high, h, -h)
    pts = np.repeat(x[None], x.size + 1, axis=0)
    pts[1:] += np.diag(step)
    z = _residuals(problem, i, keys, pts)
    return ((z[1:] - z[0]) / step[:, None]).T


def _setup(
    problem: Problem,
    i: int,
    keys: Sequence[str],
    low: FloatArray,
    high: FloatArray,
    effects: Sequence[str],
) -> _LogFit:
    r"""The parameters of log ``i``'s fit and the frame components its motion tests.

    A frame component is tested when it moves the residuals, over its range, by
    :data:`TESTED` of what the most telling component does, and the part of its
    signature the robot's own effects (``effects``' parameters) cannot make is at
    least :math:`\sqrt{1 - ρ_c^2}` of it (:math:`ρ_c` the attribution's
    ``confound_corr``: a correlation beyond it with the effects' best combination
    is an alias). A turn on the spot moves no distance and so cannot test the
    heading of the frame; on a circle, a sideways origin changes the tracked radius
    exactly as a wheel-radius error changes the distance, and is left to the effect.
    """
    robot = [k for k in model_keys(effects) if k not in keys]
    all_keys = (*keys, *robot)
    lo = np.concatenate([low, [param_spec(k).low for k in robot]])
    hi = np.concatenate([high, [param_spec(k).high for k in robot]])
    x0 = np.concatenate([np.clip(np.zeros(3), low, high), [param_spec(k).nominal for k in robot]])
    cols = _jacobian(problem, i, all_keys, lo, hi, x0) * (hi - lo)[None]  # over each range
    moves = np.linalg.norm(cols, axis=0)
    free = moves > 1e-9 * max(float(moves.max()), 1e-300)
    effect_cols = cols[:, [c for c in np.flatnonzero(free) if c >= 3]]
    reach = np.zeros(3)
    for j in range(3):
        col = cols[:, j]
        if effect_cols.shape[1]:
            coef, *_ = np.linalg.lstsq(effect_cols, col, rcond=None)
            col = col - effect_cols @ coef
        reach[j] = float(np.linalg.norm(col))
    # its own part: what is left once the effects have made what they can (a correlation
    # with their best combination beyond the attribution's confound level leaves too little)
    own = math.sqrt(1.0 - problem.settings.confound_corr**2)
    tested = (moves[:3] > TESTED * max(float(moves[:3].max()), 1e-300)) & (reach > own * moves[:3])
    free[:3] = tested
    return _LogFit(all_keys, lo, hi, x0, free, tested, int(cols.shape[0]))


def _fit(
    problem: Problem, i: int, fit: _LogFit, frame: FloatArray | None = None
) -> tuple[FloatArray, float]:
    """Robust fit of log ``i``: the robot's parameters, and the tested frame components
    unless ``frame`` fixes them. Returns the parameter vector and its robust cost."""
    st = problem.settings
    free = fit.free.copy()
    x0 = fit.start.copy()
    if frame is not None:
        x0[:3] = frame
        free[:3] = False
    if not free.any() or fit.n < 6:
        z = _residuals(problem, i, fit.keys, x0[None])
        return x0, float(np.sum(_rho(z**2, st.loss, problem.f_scale)))

    def full(y: FloatArray) -> FloatArray:
        x = x0.copy()
        x[free] = y
        return x

    res = least_squares(
        lambda y: _residuals(problem, i, fit.keys, full(y)[None])[0],
        np.clip(x0[free], fit.low[free], fit.high[free]),
        jac=lambda y: _jacobian(problem, i, fit.keys, fit.low, fit.high, full(y))[:, free],
        bounds=(fit.low[free], fit.high[free]),
        loss=st.loss,
        f_scale=problem.f_scale,
        x_scale=(fit.high - fit.low)[free],
        max_nfev=50,
    )
    x = full(np.asarray(res.x, dtype=float))
    z = _residuals(problem, i, fit.keys, x[None])
    return x, float(np.sum(_rho(z**2, st.loss, problem.f_scale)))


def align_frames(
    problem: Problem,
    keys: Sequence[str],
    ranges: Sequence[tuple[float, float]],
    say: Callable[[str], None] = lambda msg: None,
    effects: Sequence[str] = (),
) -> FrameAlignment:
    """Fit each log's ground-truth frame and re-frame the logs whose deviation is their own.

    Parameters
    ----------
    problem : Problem
        Its logs are modified in place: ``log`` re-framed and ``real`` features
        recomputed for every log whose deviation is applied; the layouts are rebuilt.
    keys : sequence of str
        The frame parameters ``("effect.x", "effect.y", "effect.yaw")`` of one
        effect that re-frames one channel (:func:`frame_channel`).
    ranges : sequence of (low, high)
        The nuisance range of each parameter (natural units).
    say : callable
    effects : sequence of str
        The robot's own candidate effects: fitted per log beside the frame (and
        discarded), so that a frame does not take up what an effect does, and a
        frame component only they could equally explain is left untested.

    Returns
    -------
    FrameAlignment
        Empty when fewer than two logs are given or the keys re-frame no single channel.
    """
    order = {"x": 0, "y": 1, "yaw": 2}
    pairs = sorted(zip(keys, ranges), key=lambda kr: order.get(split_key(kr[0])[1], 3))
    keys = tuple(k for k, _ in pairs)
    ranges = [r for _, r in pairs]
    owners = {split_key(k)[0] for k in keys}
    suffixes = [split_key(k)[1] for k in keys]
    if suffixes != ["x", "y", "yaw"] or len(owners) != 1 or len(ranges) != 3:
        raise ValueError(
            f"align_frames: expected the x, y and yaw parameters of one effect with a range "
            f"each, got {keys} and {len(ranges)} range(s)"
        )
    channel = frame_channel(next(iter(owners)))
    logs: Sequence[Any] = problem.logs
    if channel is None or len(logs) < 2:
        return FrameAlignment()
    for k in keys:
        param_spec(k)  # a clear error for an unknown parameter
    low = np.array([float(r[0]) for r in ranges])
    high = np.array([float(r[1]) for r in ranges])
    noise = problem.f_scale / problem.settings.robust_scale
    fits = [_setup(problem, i, keys, low, high, effects) for i in range(len(logs))]
    solved = [_fit(problem, i, f) for i, f in enumerate(fits)]
    fitted = [x[:3] for x, _ in solved]
    tested = [f.tested for f in fits]
    sizes = [f.n for f in fits]
    # the common frame: per component, the median over the logs whose motion tests it
    fx, ok_all = np.array(fitted), np.array(tested)
    common = np.array(
        [float(np.median(fx[ok_all[:, j], j])) if ok_all[:, j].any() else 0.0 for j in range(3)]
    )
    out = FrameAlignment(
        keys=keys, channel=channel, common=(float(common[0]), float(common[1]), float(common[2]))
    )
    edge = 1e-3 * (high - low)
    for i, p in enumerate(logs):
        # an untested component keeps the common value: the log says nothing about it
        x = np.where(tested[i], fitted[i], common)
        dev = x - common
        row: dict[str, Any] = {
            "log": p.name,
            "split": p.split,
            "frame": [float(v) for v in x],
            "tested": [bool(v) for v in tested[i]],
            "deviation": [float(v) for v in dev],
            "applied": False,
            "chi2_drop": 0.0,
            "why": "",
        }
        # both sides with the robot's own parameters fitted: only the frame's part counts
        cost_own = solved[i][1] if np.array_equal(x, fitted[i]) else _fit(problem, i, fits[i], x)[1]
        cost_common = _fit(problem, i, fits[i], common)[1]
        drop = (cost_common - cost_own) / noise**2
        row["chi2_drop"] = drop
        at_edge = (x <= low + edge) | (x >= high - edge)
        if np.any(at_edge & tested[i]):
            row["why"] = (
                "the fitted frame ends at the edge of its range: a gap the frame cannot "
                "close, not the recording's convention; the log keeps the common frame"
            )
        elif not drop > int(tested[i].sum()) * math.log(max(sizes[i], 2)):
            row["why"] = "the deviation does not lower the log's cost beyond noise"
        else:
            row["applied"] = True
            p.log = _reframe_log(p.log, channel, x, common)
            feats = problem.adapter.log_features(p, p.log)
            p.real = {g: feats[g] for g in p.real}
        out.rows.append(row)
    if out.applied:
        problem.exclude(problem.excluded)
    say(out.summary())
    return out


def _reframe_log(log: Log, channel: str, frame_from: FloatArray, frame_to: FloatArray) -> Log:
    """``log`` with ``channel`` recorded under ``frame_to`` instead of ``frame_from``."""
    return log.with_channels(**{channel: reframe_recorded(log[channel], frame_from, frame_to)})
