r"""What the diagnosis compares: per-window features of a log, motion regimes, pipeline stages.

Real and simulated episodes are compared over short, non-overlapping windows
(1 s by default) rather than sample by sample, so that an early heading error
does not masquerade as a gap everywhere after it. For a differential drive,
per window ``[t_a, t_b]``:

==========  ===============  =========  ===========================================================
group       columns          units      value
==========  ===============  =========  ===========================================================
pose_gt     dx, dy, dtheta   m, m, rad  motion of the ground truth, in the frame of its pose at t_a
ticks       left, right      m, m       wheel travel counted by the encoders (nominal m per tick)
pose_cam    ex, ey, etheta   m, m, rad  camera pose seen from the ground-truth base pose (mean)
==========  ===============  =========  ===========================================================

The *regime* of a window comes from the commands applied during it (or, when
the replay is driven by encoder ticks, from the wheel motion): ``standing``,
``straight``, ``turning_ccw``, ``turning_cw`` or ``accelerating``.

An arm is measured at rest, pose after pose; a window is four consecutive
poses and its feature the six distances between their tool points
(``tool_dist``, m), which no registration of the measuring instrument to the
robot base can change. Its regime says how far the arm reaches out
(``folded``, ``mid_reach``, ``outstretched``), i.e. how hard gravity loads
the shoulder and elbow (see :mod:`realitygap.diagnosis.adapters.arm.adapter`).

A climber's windows compare the mean tether reading (``tether``, m) and the
mean ride height above the CAD surface (``surface``, m); its regimes are
``standing``, ``climbing``, ``descending`` and ``traversing``
(:mod:`realitygap.diagnosis.adapters.climber.adapter`).

Each robot adapter declares its groups (columns, units, default scales) and
its regimes as a :class:`FeatureSchema`; the generic diagnosis iterates over
that schema.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.problem.schemas import (
    DIFFDRIVE_REGIMES,
    FeatureGroup,
    FeatureSchema,
    feature_group,
)

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "DIFFDRIVE_REGIMES",
    "FeatureGroup",
    "FeatureSchema",
    "FeatureSettings",
    "classify_regimes",
    "features",
    "relative_motion",
    "window_bounds",
]


@dataclass(frozen=True)
class FeatureSettings:
    """How logs are cut into windows and how feature residuals are weighted.

    Attributes
    ----------
    window_s : float
        Window length, s.
    scales : mapping of group to tuple of float
        Residual size that counts as one unit per column (SI units per
        window): the weights of the fit and of the statistics. A group not
        given here takes the default scales its robot adapter declares
        (:class:`FeatureGroup`): ground truth 2 mm, 2 mm, 2 mrad; encoder
        travel 2 mm per wheel; camera 2 mm, 2 mm, 3 mrad; arm tool-point
        distances 0.1 mm; climber tether and ride height 1 mm.
    standing_speed, standing_rate : float
        Below these commanded speeds (m/s, rad/s) a window is ``standing``.
    turning_rate : float
        Mean commanded turn rate (rad/s) above which a window is turning.
    accel_speed, accel_rate : float
        A window whose commanded speed (turn rate) varies by more than this
        (m/s, rad/s), or by more than 20 % of its mean magnitude, is
        ``accelerating``.
    """

    window_s: float = 1.0
    scales: Mapping[str, tuple[float, ...]] = field(default_factory=dict)
    standing_speed: float = 0.005
    standing_rate: float = 0.02
    turning_rate: float = 0.05
    accel_speed: float = 0.03
    accel_rate: float = 0.15

    def __post_init__(self) -> None:
        if not (self.window_s > 0 and math.isfinite(self.window_s)):
            raise ValueError(f"window_s must be a positive number of seconds, got {self.window_s}")
        for g, given in self.scales.items():
            cols = feature_group(g).columns
            sc = tuple(given)
            if len(sc) != len(cols) or not all(v > 0 for v in sc):
                raise ValueError(
                    f"scales[{g!r}] must hold {len(cols)} positive numbers ({cols}), got {sc}"
                )

    def scale(self, group: str) -> FloatArray:
        """Residual scale of each column of ``group`` (given, else the group's default)."""
        given = self.scales.get(group)
        if given is None:
            return np.asarray(feature_group(group).scales, dtype=float)
        return np.asarray(given, dtype=float)


def window_bounds(n: int, dt: float, window_s: float) -> npt.NDArray[np.int64]:
    """Start and end rows ``[a, b]`` of the complete windows of a log of ``n`` rows, (M, 2)."""
    w = max(1, int(round(window_s / dt)))
    m = (n - 1) // w
    a = np.arange(m) * w
    return np.stack([a, a + w], axis=1).astype(np.int64)


def relative_motion(pose_a: FloatArray, pose_b: FloatArray) -> FloatArray:
    """``⊖a ⊕ b`` with a continuous heading difference; (..., 3) → (..., 3)."""
    c, s = np.cos(pose_a[..., 2]), np.sin(pose_a[..., 2])
    dx = pose_b[..., 0] - pose_a[..., 0]
    dy = pose_b[..., 1] - pose_a[..., 1]
    return np.stack([c * dx + s * dy, -s * dx + c * dy, pose_b[..., 2] - pose_a[..., 2]], axis=-1)


def features(
    channels: Mapping[str, FloatArray],
    bounds: npt.NDArray[np.int64],
    meters_per_tick: tuple[float, float],
) -> dict[str, FloatArray]:
    """Window features of one episode or a batch of episodes.

    Parameters
    ----------
    channels : mapping
        ``pose_gt`` (…, N, 3), ``ticks`` (…, N, 2), ``pose_cam`` (…, N, 3);
        any may be absent (its group is then absent). Leading batch axes are
        kept.
    bounds : ndarray, shape (M, 2)
        From :func:`window_bounds`.
    meters_per_tick : (float, float)
        Nominal wheel travel per tick, left and right, m.

    Returns
    -------
    dict of group to ndarray, shape (…, M, k)
    """
    a, b = bounds[:, 0], bounds[:, 1]
    out: dict[str, FloatArray] = {}
    gt = channels.get("pose_gt")
    if gt is not None:
        out["pose_gt"] = relative_motion(gt[..., a, :], gt[..., b, :])
    ticks = channels.get("ticks")
    if ticks is not None:
        d = ticks[..., b, :] - ticks[..., a, :]
        out["ticks"] = d * np.asarray(meters_per_tick, dtype=float)
    cam = channels.get("pose_cam")
    if gt is not None and cam is not None:
        rel = relative_motion(gt, cam)
        csum = np.cumsum(rel, axis=-2)
        zero = np.zeros_like(rel[..., :1, :])
        csum = np.concatenate([zero, csum], axis=-2)
        # mean over rows a .. b-1
        out["pose_cam"] = (csum[..., b, :] - csum[..., a, :]) / (b - a)[:, None]
    return out


def classify_regimes(
    twist: FloatArray, bounds: npt.NDArray[np.int64], settings: FeatureSettings | None = None
) -> list[str]:
    """Motion regime of each window from the applied twist (N, 2) [m/s, rad/s].

    Precedence: ``standing`` (all commands near zero) < ``accelerating``
    (speed or turn rate changes within the window, including the step into
    it) < ``turning_ccw`` / ``turning_cw`` (mean turn rate) < ``straight``.
    """
    s = settings if settings is not None else FeatureSettings()
    out = []
    for a, b in bounds:
        seg = twist[max(a - 1, 0) : b]
        v, w = seg[:, 0], seg[:, 1]
        if np.max(np.abs(v)) < s.standing_speed and np.max(np.abs(w)) < s.standing_rate:
            out.append("standing")
            continue
        v_rng, w_rng = float(np.ptp(v)), float(np.ptp(w))
        if v_rng > max(s.accel_speed, 0.2 * float(np.mean(np.abs(v)))) or w_rng > max(
            s.accel_rate, 0.2 * float(np.mean(np.abs(w)))
        ):
            out.append("accelerating")
            continue
        w_mean = float(np.mean(w))
        if w_mean > s.turning_rate:
            out.append("turning_ccw")
        elif w_mean < -s.turning_rate:
            out.append("turning_cw")
        else:
            out.append("straight")
    return out
