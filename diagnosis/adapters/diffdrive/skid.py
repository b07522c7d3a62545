r"""A skid-steer's effective track, fitted from its training logs before the diagnosis.

A skid-steer (four or six wheels, two per side, no steering) turns by
scrubbing its wheels sideways: it turns as a differential drive would whose
track :math:`B_{eff}` is wider than its wheel track :math:`T` (typically
1.2–2 ×, depending on the floor, the load and the wheel base). The robot file
says ``robot: skid_steer`` with the wheel track; unless it also declares the
effective track, the diagnosis fits it from the training logs' encoders and
ground-truth headings and uses it as the nominal wheelbase of every log:

.. math:: \Delta\theta_k = \frac{r_R\,\Delta\varphi_{R,k} - r_L\,\Delta\varphi_{L,k}}{B_{eff}}

over chords of :data:`CHORD_S` seconds (least squares through the origin in
:math:`1/B_{eff}`, which is what the heading depends on linearly). The headings
alone give :math:`r/B_{eff}`: a wheel radius off its declared value would move
into the track. So the straight chords (turning less than
:data:`STRAIGHT_CHORD_RAD`) give the wheels' true scale :math:`k_r` (the
ground truth's distance over the wheels' declared travel; a tracked point off
the axle moves with it on a straight chord), and :math:`B_{eff} = k_r \cdot
r_{declared} / (r/B_{eff})`. The radii stay as declared: a wheel-scale error is
the diagnosis's finding, and with the physical track it shows as one effect. The
fit reads only the training logs, so the held-out score stays honest.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from realitygap.diagnosis.logs.log import Log, LogError

__all__ = ["CHORD_S", "complete_skid_steer", "fit_effective_track"]

CHORD_S = 0.5
"""s: the chords the headings and wheel rotations are compared over."""

STRAIGHT_CHORD_RAD = 0.01
"""rad: a chord turning less than this is straight (its distance measures the wheel scale)."""

MIN_STRAIGHT_M = 1.0
"""m: straight travel below which the wheel scale is taken as declared (and said so)."""

MIN_TURN_RAD = 0.5
"""rad: total turning the training logs must hold for the effective track to be fitted."""


def _is_skid(log: Log) -> bool:
    return str(log.meta.get("drive_kind", "")) == "skid_steer"


def fit_effective_track(logs: Sequence[Log]) -> tuple[float, float, int, float]:
    """The effective track (m), its standard error (m), the chords used and the wheel scale
    :math:`k_r` of the straight chords (1 when they are too short), from ``logs`` (each with
    ``ticks``, ``pose_gt`` and ``meta["params"]`` wheel radii and ticks per rev).

    Raises
    ------
    LogError
        A log without encoders or ground truth, or logs that turn too little.
    """
    num = den = 0.0
    xs: list[np.ndarray] = []
    ys: list[np.ndarray] = []
    wheel_dist = true_dist = 0.0
    for lg in logs:
        for ch in ("ticks", "pose_gt"):
            if not lg.has(ch):
                raise LogError(
                    f"{lg.source or lg.name}: a skid-steer's effective track is fitted from the "
                    f"encoders and the ground-truth heading, and the log has no {ch!r}. Fix: map "
                    "both channels, or declare wheels.effective_track in the robot file"
                )
        p = lg.meta.get("params", {})
        tpr = float(p.get("ticks_per_rev", 0.0))
        rl, rr = float(p.get("wheel_radius_left", 0.0)), float(p.get("wheel_radius_right", 0.0))
        if not (tpr > 0 and rl > 0 and rr > 0):
            raise LogError(
                f"{lg.source or lg.name}: the nominal wheel radii and ticks_per_rev are needed to "
                "fit a skid-steer's effective track; give them in the robot file"
            )
        stride = max(1, int(round(CHORD_S / lg.dt)))
        idx = np.arange(0, lg.n, stride)
        ticks = lg["ticks"][idx]
        th = np.unwrap(lg["pose_gt"][idx, 2])
        dphi = np.diff(ticks, axis=0) * (2.0 * math.pi / tpr)
        d = rr * dphi[:, 1] - rl * dphi[:, 0]
        xs.append(d)
        ys.append(np.diff(th))
        straight = np.abs(np.diff(th)) < STRAIGHT_CHORD_RAD
        travel = 0.5 * (rr * dphi[:, 1] + rl * dphi[:, 0])
        xy = lg["pose_gt"][idx, :2]
        wheel_dist += float(np.sum(np.abs(travel[straight])))
        true_dist += float(np.sum(np.hypot(*np.diff(xy, axis=0).T)[straight]))
    x, y = np.concatenate(xs), np.concatenate(ys)
    turn = float(np.sum(np.abs(y)))
    if x.size < 3 or turn < MIN_TURN_RAD:
        raise LogError(
            f"the training logs turn {turn:.3g} rad in all; at least {MIN_TURN_RAD:g} rad of "
            "turning is needed to fit a skid-steer's effective track. Fix: add logs with turns, "
            "or declare wheels.effective_track in the robot file"
        )
    num, den = float(x @ y), float(x @ x)
    if not num > 0:
        raise LogError(
            "the ground-truth heading turns against the wheels (left faster than right gives a "
            "right turn): a mirrored encoder or a clockwise heading? Fix the signs in the column "
            "map (e.g. ticks.left=-COL or pose_gt.theta=-COL)"
        )
    k = num / den  # heading per declared differential wheel travel: (true r / declared r) / B_eff
    res = y - k * x
    dof = max(x.size - 1, 1)
    se_k = math.sqrt(float(res @ res) / dof / den)
    scale = true_dist / wheel_dist if wheel_dist >= MIN_STRAIGHT_M else 1.0
    track = scale / k
    return track, track * se_k / k, int(x.size), scale


def complete_skid_steer(
    train: Sequence[Log], others: Sequence[Log]
) -> tuple[list[Log], list[Log], dict[str, Any]]:
    """``train`` and ``others`` with a fitted effective track as their nominal wheelbase.

    Only logs that declare ``meta["drive_kind"] == "skid_steer"`` without
    ``meta["effective_track_declared"]`` change; the fit reads the training ones.
    Returns the logs and a report (empty when nothing was fitted): ``value``,
    ``stderr`` (m), ``wheel_track`` (m), ``ratio`` and ``summary``.
    """
    fit_on = [lg for lg in train if _is_skid(lg) and not lg.meta.get("effective_track_declared")]
    if not fit_on:
        return list(train), list(others), {}
    track, se, n, scale = fit_effective_track(fit_on)
    wheel_track = float(fit_on[0].meta.get("wheel_track", fit_on[0].meta["params"]["wheelbase"]))
    report = {
        "value": track,
        "stderr": se,
        "wheel_track": wheel_track,
        "ratio": track / wheel_track,
        "chords": n,
        "wheel_scale": scale,
        "summary": (
            f"skid-steer: effective track {track:.4f} ± {se:.4f} m fitted on {len(fit_on)} "
            f"training log(s) ({track / wheel_track:.3f} × the wheel track {wheel_track:.4g} m, "
            f"with the wheels rolling {scale:.4f} × their declared travel on straight chords); "
            "it is the nominal wheelbase of every log"
        ),
    }

    def fix(lg: Log) -> Log:
        if not _is_skid(lg) or lg.meta.get("effective_track_declared"):
            return lg
        params: Mapping[str, Any] = lg.meta.get("params", {})
        meta = {
            **lg.meta,
            "params": {**params, "wheelbase": track},
            "effective_track": {k: v for k, v in report.items() if k != "summary"},
        }
        return lg.replace(meta=meta)

    return [fix(lg) for lg in train], [fix(lg) for lg in others], report
