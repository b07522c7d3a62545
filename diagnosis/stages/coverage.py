"""Does the training exercise the motions the held-out data are scored on?

A model fitted on one set of motions says nothing about motions it never saw:
a wheel's top speed cannot be learnt from runs that never drive fast, an arm's
compliance at full reach not from poses that stay folded. When held-out runs
go beyond the training, a large held-out gap may be an effect the training
could not test rather than one outside the library — and the useful answer is
the experiment that would test it.

:func:`training_coverage` compares, variable by variable, the motion of every
held-out window (:data:`~realitygap.diagnosis.problem.problem.MOTION_COLUMNS`: for a
wheeled robot its speed and turn rate, their change over the window and
their ranges; an arm's reach and holding torques; a climber's speed and
vertical speed) with the span the training windows cover. What counts is the
motion the robot *made*: a wheeled robot's comes from its planar ground truth
(:func:`planar_motion`), not from its commands, which a firmware ramp may
never let it reach. A held-out window
lies *outside the training envelope* when any variable leaves that span by
more than a margin (``margin`` of the span, at least ``atol``). The report
gives:

* per variable, the training span, the held-out span and how many held-out
  windows leave it;
* the share of the held-out gap (the reference residual's sum of squares, in
  the channels where the gap lives) that lies outside the envelope;
* the best model's held-out shrink inside and outside the envelope, and how much
  denser what it leaves unexplained is beyond the training than within it;
* the training run that would cover the held-out motions.

When no effect is named and the unexplained rest gathers beyond the training
(:attr:`Coverage.beyond_training`), the verdict says so: the gap may well be an
effect the training could not test. When the rest spreads evenly — the best model
transfers to the new motions as well as it fits the old ones — the coverage is
reported but the verdict does not blame it.

The envelope is a box, one interval per variable: it flags the motions the
training never reached, not every combination it never drove (a speed and a
turn rate each seen alone may still be new together).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.problem.problem import MOTION_COLUMNS, Layout
from realitygap.diagnosis.problem.shrink import overall_shrink

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "DEFAULT_MOTION_LABELS",
    "WHEEL_SPEED_VARIABLES",
    "Coverage",
    "CoverageSettings",
    "layout_windows",
    "motion_variables",
    "planar_motion",
    "training_coverage",
    "wheel_speeds",
]

DEFAULT_MOTION_LABELS: tuple[tuple[str, str], ...] = (
    ("speed", "m/s"),
    ("turn rate", "rad/s"),
    ("change of speed over a window", "m/s"),
    ("change of turn rate over a window", "rad/s"),
    ("range of speed within a window", "m/s"),
    ("range of turn rate within a window", "rad/s"),
)
"""What the six :data:`~realitygap.diagnosis.problem.problem.MOTION_COLUMNS` mean for a wheeled
robot (name, SI unit); an adapter with other meanings declares ``motion_labels``."""

WHEEL_SPEED_VARIABLES: tuple[tuple[str, str, str], ...] = (
    ("v_left", "left wheel speed", "m/s"),
    ("v_right", "right wheel speed", "m/s"),
)
"""Extra variables of a differential drive: the mean ground speed of each wheel over a
window (``v ∓ ω b / 2``), what a motor's top speed or torque limit acts on."""


def motion_variables(
    labels: Sequence[tuple[str, str]] | None = None, wheels: bool = False
) -> tuple[tuple[str, str, str], ...]:
    """``(variable, label, unit)`` of the motion columns, then the wheel speeds if asked."""
    lab = tuple(labels) if labels is not None else DEFAULT_MOTION_LABELS
    if len(lab) != len(MOTION_COLUMNS):
        raise ValueError(
            f"labels must name the {len(MOTION_COLUMNS)} motion columns {MOTION_COLUMNS}, "
            f"got {len(lab)}"
        )
    out = tuple((c, label, unit) for c, (label, unit) in zip(MOTION_COLUMNS, lab, strict=True))
    return out + (WHEEL_SPEED_VARIABLES if wheels else ())


def wheel_speeds(motion: FloatArray, wheelbase: float) -> FloatArray:
    """Mean left and right wheel ground speeds ``v ∓ ω b / 2`` of windows, (M, 2), m/s."""
    if not (np.isfinite(wheelbase) and wheelbase > 0):
        raise ValueError(f"wheelbase must be a positive length in m, got {wheelbase!r}")
    m = np.asarray(motion, dtype=float)
    half = 0.5 * wheelbase * m[:, 1]
    return np.stack([m[:, 0] - half, m[:, 0] + half], axis=1)


@dataclass(frozen=True)
class CoverageSettings:
    """How the training envelope is drawn and when it enters the verdict.

    Attributes
    ----------
    margin : float
        A held-out value lies outside a variable's training span when it leaves
        it by more than this fraction of the span.
    atol : float
        ... and by more than this much (SI units of the variable), so a
        variable the training held constant (a turn rate of exactly 0) does
        not flag held-out noise around it.
    min_gap_share : float
        The verdict states that what it leaves unexplained lies beyond the training
        when no effect was named, at least this share (0–1) of the best model's
        held-out residual lies there, ...
    min_concentration : float
        ... the residual's mean square per entry beyond the training is at least
        this many times its mean square within it (the unexplained part gathers
        where the training never looked, rather than spreading evenly over held-out
        windows that happen to lie beyond it) ...
    min_inside_windows : int
        ... and at least this many held-out windows lie within the training, so
        that the comparison means something.
    """

    margin: float = 0.1
    atol: float = 1e-3
    min_gap_share: float = 0.5
    min_concentration: float = 2.0
    min_inside_windows: int = 10

    def __post_init__(self) -> None:
        for name in ("margin", "atol"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise ValueError(f"CoverageSettings.{name} must be a finite number ≥ 0, got {v!r}")
        if not 0.0 < self.min_gap_share <= 1.0:
            raise ValueError(
                f"CoverageSettings.min_gap_share must lie in (0, 1], got {self.min_gap_share!r}"
            )
        if not (np.isfinite(self.min_concentration) and self.min_concentration >= 1.0):
            raise ValueError(
                "CoverageSettings.min_concentration must be a finite ratio ≥ 1, got "
                f"{self.min_concentration!r}"
            )
        if not (isinstance(self.min_inside_windows, int) and self.min_inside_windows >= 1):
            raise ValueError(
                "CoverageSettings.min_inside_windows must be an integer ≥ 1, got "
                f"{self.min_inside_windows!r}"
            )


@dataclass
class Coverage:
    """Where the held-out motions leave the training envelope (see the module docstring).

    Attributes
    ----------
    rows : list of dict
        Per variable: ``variable``, ``label``, ``unit``, ``train_min``,
        ``train_max``, ``heldout_min``, ``heldout_max``, ``n_outside``
        (held-out windows beyond the training span), ``n_above`` and ``n_below``
        (beyond its upper and its lower end).
    n_windows, n_outside : int
        Held-out windows, and those outside the envelope.
    gap_share_outside : float
        Share (0–1) of the held-out gap in windows outside the envelope.
    residual_share_outside : float
        Share (0–1) of the best model's held-out residual (what it leaves
        unexplained) in windows outside the envelope.
    concentration : float
        Mean square of that residual per entry outside the envelope over its mean
        square inside (NaN without entries on either side).
    shrink_inside_pct, shrink_outside_pct : float
        Held-out shrink of the best model inside / outside the envelope (NaN
        where there are no windows).
    best : str
        Name of the model the shrink figures are for.
    settings : CoverageSettings
    """

    rows: list[dict[str, Any]] = field(default_factory=list)
    n_windows: int = 0
    n_outside: int = 0
    gap_share_outside: float = 0.0
    residual_share_outside: float = 0.0
    concentration: float = float("nan")
    shrink_inside_pct: float = float("nan")
    shrink_outside_pct: float = float("nan")
    best: str = ""
    settings: CoverageSettings = field(default_factory=CoverageSettings)

    @property
    def beyond_training(self) -> bool:
        """Whether what the best model leaves unexplained gathers in motions the training
        never reached (see :class:`CoverageSettings` for the three conditions)."""
        s = self.settings
        return (
            self.n_outside > 0
            and self.n_windows - self.n_outside >= s.min_inside_windows
            and self.residual_share_outside >= s.min_gap_share
            and bool(self.concentration >= s.min_concentration)
        )

    def exceeded(self) -> list[dict[str, Any]]:
        """The variables some held-out window takes beyond the training span."""
        return [r for r in self.rows if r["n_outside"] > 0]

    def summary(self) -> str:
        """One sentence: how much of the held-out gap lies beyond the training, and where."""
        if self.n_windows == 0:
            return "no held-out windows to compare with the training"
        if self.n_outside == 0:
            return (
                f"every one of the {self.n_windows} held-out windows lies within the motions "
                "the training exercised"
            )
        parts = [
            f"{r['label']} {_span(r['heldout_min'], r['heldout_max'], r['unit'])} held out "
            f"against {_span(r['train_min'], r['train_max'], r['unit'])} in training"
            for r in self.exceeded()[:3]
        ]
        inside = (
            f"; inside the envelope {self.best or 'the best model'} closes "
            f"{self.shrink_inside_pct:.0f} % of the gap, outside {self.shrink_outside_pct:.0f} %"
            if np.isfinite(self.shrink_inside_pct) and np.isfinite(self.shrink_outside_pct)
            else ""
        )
        rest = (
            f"; what it leaves unexplained is {self.concentration:.1f}× denser (mean square per "
            "window) beyond the training than within it"
            if np.isfinite(self.concentration)
            else ""
        )
        return (
            f"{self.n_outside} of {self.n_windows} held-out windows "
            f"({100 * self.n_outside / self.n_windows:.0f} %), carrying "
            f"{100 * self.gap_share_outside:.0f} % of the held-out gap, go beyond the motions "
            f"the training exercised ({'; '.join(parts)}){inside}{rest}"
        )

    def suggestion(self) -> str:
        """The training run that would cover the held-out motions, or ``""``."""
        wanted = []
        for r in self.exceeded():
            ends = []
            if r["n_above"]:
                ends.append(f"up to {_value(r['heldout_max'], r['unit'])}")
            if r["n_below"]:
                ends.append(f"down to {_value(r['heldout_min'], r['unit'])}")
            wanted.append(
                f"{r['label']} {' and '.join(ends)} (training: "
                f"{_span(r['train_min'], r['train_max'], r['unit'])})"
            )
        if not wanted:
            return ""
        return (
            "record training runs that reach the held-out motions ("
            + "; ".join(wanted[:4])
            + "): effects that act only there (a top speed, a torque limit, slip at hard "
            "accelerations) cannot be tested from the present training"
        )

    def to_json(self) -> dict[str, Any]:
        return {
            "rows": self.rows,
            "n_windows": self.n_windows,
            "n_outside": self.n_outside,
            "gap_share_outside": self.gap_share_outside,
            "residual_share_outside": self.residual_share_outside,
            "concentration": self.concentration,
            "shrink_inside_pct": self.shrink_inside_pct,
            "shrink_outside_pct": self.shrink_outside_pct,
            "best": self.best,
            "beyond_training": self.beyond_training,
            "summary": self.summary(),
            "suggestion": self.suggestion(),
        }


def _value(x: float, unit: str) -> str:
    return f"{x:.3g}" + (f" {unit}" if unit != "1" else "")


def _span(lo: float, hi: float, unit: str) -> str:
    return f"{lo:.3g} … {_value(hi, unit)}"


def planar_motion(
    t: FloatArray, pose: FloatArray, bounds: npt.NDArray[np.int64], smooth_s: float = 0.25
) -> FloatArray:
    """Measured motion of each window of a planar pose track, in the six motion columns.

    Speed (signed along the heading) and turn rate come from a Savitzky–Golay
    derivative (quadratic, ``smooth_s`` long) of the pose, so that the
    differencing does not turn position noise into speed; per window ``[a, b]``:
    mean speed and turn rate, their change from the sample before the window to
    its last sample, and their ranges.

    Parameters
    ----------
    t : ndarray, shape (N,)
        Regular time stamps, s.
    pose : ndarray, shape (N, 3)
        x, y (m), heading (rad).
    bounds : ndarray, shape (M, 2)
        Window start / end rows.
    smooth_s : float
        Length of the derivative filter, s.

    Returns
    -------
    ndarray, shape (M, 6)
    """
    from scipy.signal import savgol_filter

    t = np.asarray(t, dtype=float)
    pose = np.asarray(pose, dtype=float)
    if pose.ndim != 2 or pose.shape[1] != 3 or pose.shape[0] != t.shape[0]:
        raise ValueError(f"pose must have shape ({t.shape[0]}, 3), got {pose.shape}")
    n = t.shape[0]
    dt = float(np.median(np.diff(t))) if n > 1 else 1.0
    out = np.zeros((bounds.shape[0], len(MOTION_COLUMNS)))
    if n < 3:
        return out
    win = max(3, int(round(smooth_s / dt)) | 1)
    win = min(win, n if n % 2 else n - 1)
    heading = np.unwrap(pose[:, 2])
    dx = savgol_filter(pose[:, 0], win, min(2, win - 1), deriv=1, delta=dt)
    dy = savgol_filter(pose[:, 1], win, min(2, win - 1), deriv=1, delta=dt)
    w = savgol_filter(heading, win, min(2, win - 1), deriv=1, delta=dt)
    v = dx * np.cos(heading) + dy * np.sin(heading)
    for m, (a, b) in enumerate(bounds):
        pre = max(a - 1, 0)
        out[m] = (
            v[a:b].mean(),
            w[a:b].mean(),
            v[b - 1] - v[pre],
            w[b - 1] - w[pre],
            np.ptp(v[pre:b]),
            np.ptp(w[pre:b]),
        )
    return out


def layout_windows(
    layout: Layout, motion_of: Callable[[int], FloatArray]
) -> tuple[npt.NDArray[np.int64], FloatArray]:
    """The distinct windows of a layout: for each residual entry the index of its window,
    and the (W, k) motion of those windows (``motion_of(log_index)`` gives a log's (M, k)
    window motions)."""
    keys = layout.log.astype(np.int64) * (1 + int(layout.window.max(initial=0))) + layout.window
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    cache: dict[int, FloatArray] = {}
    picked = []
    for e in first:
        i = int(layout.log[e])
        if i not in cache:
            cache[i] = np.asarray(motion_of(i), dtype=float)
        picked.append(cache[i][int(layout.window[e])])
    rows = np.asarray(picked, dtype=float).reshape(first.size, -1)
    return inverse.reshape(-1), rows


def training_coverage(
    train_motion: FloatArray,
    heldout_motion: FloatArray,
    heldout_window: npt.NDArray[np.int64],
    z_reference: FloatArray,
    z_best: FloatArray,
    gap_mask: npt.NDArray[np.bool_] | None = None,
    *,
    variables: Sequence[tuple[str, str, str]] | None = None,
    best: str = "",
    settings: CoverageSettings | None = None,
) -> Coverage:
    """Compare the held-out windows' motions with the training envelope.

    Parameters
    ----------
    train_motion : ndarray, shape (W_train, k)
        Motion of every training window, one column per variable.
    heldout_motion : ndarray, shape (W, k)
        Motion of every held-out window.
    heldout_window : ndarray of int, shape (n,)
        For each held-out residual entry, the row of its window in ``heldout_motion``
        (:func:`layout_windows`).
    z_reference, z_best : ndarray, shape (n,)
        Normalised held-out residuals of the reference (the calibrated baseline
        or the nominal replay) and of the best model.
    gap_mask : ndarray of bool, shape (n,), optional
        Entries of the channels where the gap lives (default: all).
    variables : sequence of (str, str, str), optional
        Key, name and SI unit of each column (default :func:`motion_variables` ():
        the six :data:`MOTION_COLUMNS` of a wheeled robot).
    best : str
        Name of the best model, for the words.
    settings : CoverageSettings, optional

    Returns
    -------
    Coverage
    """
    s = settings if settings is not None else CoverageSettings()
    var = tuple(variables) if variables is not None else motion_variables()
    k = len(var)
    m_train = np.asarray(train_motion, dtype=float)
    m_ho = np.asarray(heldout_motion, dtype=float)
    which = np.asarray(heldout_window, dtype=np.int64)
    for name, m in (("train_motion", m_train), ("heldout_motion", m_ho)):
        if m.ndim != 2 or m.shape[1] != k or not np.all(np.isfinite(m)):
            raise ValueError(
                f"{name} must be a finite (windows, {k}) array, one column per variable "
                f"{[v[0] for v in var]}, got shape {m.shape}"
            )
    n = which.shape[0]
    if which.ndim != 1 or (n and (which.min() < 0 or which.max() >= m_ho.shape[0])):
        raise ValueError(
            f"heldout_window must index the {m_ho.shape[0]} held-out windows, got values "
            f"{which.min() if n else '-'} … {which.max() if n else '-'}"
        )
    z_ref = np.asarray(z_reference, dtype=float)
    z_b = np.asarray(z_best, dtype=float)
    if z_ref.shape != (n,) or z_b.shape != (n,):
        raise ValueError(
            f"z_reference and z_best must have one entry per held-out residual ({n}), "
            f"got {z_ref.shape} and {z_b.shape}"
        )
    mask = np.ones(n, dtype=bool) if gap_mask is None else np.asarray(gap_mask, bool)
    if mask.shape != (n,):
        raise ValueError(f"gap_mask must have shape ({n},), got {mask.shape}")
    out = Coverage(best=best, settings=s)
    if n == 0 or m_train.shape[0] == 0 or m_ho.shape[0] == 0:
        return out
    lo, hi = m_train.min(axis=0), m_train.max(axis=0)
    tol = np.maximum(s.margin * (hi - lo), s.atol)
    above, below = m_ho > hi + tol, m_ho < lo - tol  # (W, k)
    beyond = above | below
    outside_w = beyond.any(axis=1)
    for j, (name, label, unit) in enumerate(var):
        out.rows.append(
            {
                "variable": name,
                "label": label,
                "unit": unit,
                "train_min": float(lo[j]),
                "train_max": float(hi[j]),
                "heldout_min": float(m_ho[:, j].min()),
                "heldout_max": float(m_ho[:, j].max()),
                "n_outside": int(beyond[:, j].sum()),
                "n_above": int(above[:, j].sum()),
                "n_below": int(below[:, j].sum()),
            }
        )
    out.n_windows = int(m_ho.shape[0])
    out.n_outside = int(outside_w.sum())
    outside = outside_w[which] & mask
    inside = ~outside_w[which] & mask
    total = float(np.sum(z_ref[mask] ** 2))
    out.gap_share_outside = float(np.sum(z_ref[outside] ** 2)) / total if total > 0 else 0.0
    rest = float(np.sum(z_b[mask] ** 2))
    out.residual_share_outside = float(np.sum(z_b[outside] ** 2)) / rest if rest > 0 else 0.0
    if inside.any() and outside.any():
        ms_in = float(np.mean(z_b[inside] ** 2))
        ms_out = float(np.mean(z_b[outside] ** 2))
        out.concentration = ms_out / ms_in if ms_in > 0 else float("inf")
    if inside.any():
        out.shrink_inside_pct = overall_shrink(z_ref[inside], z_b[inside])
    if outside.any():
        out.shrink_outside_pct = overall_shrink(z_ref[outside], z_b[outside])
    return out
