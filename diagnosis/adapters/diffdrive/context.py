"""What the differential drive keeps about a prepared log, and the geometry all logs share.

:class:`DiffDriveContext` holds a prepared log's nominal robot, the surrogate and its
inputs, and the applied twist; :func:`values_for_log` re-expresses effect values relative
to the reference geometry of the diagnosis (:meth:`DiffDriveAdapter.link_logs
<realitygap.diagnosis.adapters.diffdrive.adapter.DiffDriveAdapter.link_logs>`) for one
log's nominal. The constants are the conventions the adapter's baseline and drive-train
figures use.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.adapters.contract import LogContext, WheelGeometry
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.diffdrive_surrogate import DiffDriveSurrogate, SurrogateInputs

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "DRIVE_RESPONSE_FLOOR",
    "TRUTH_FRAME_RANGE",
    "TRUTH_LATENCY_FLOOR",
    "TRUTH_YAW_RANGE",
    "TURN_WINDOW_RAD",
    "DiffDriveContext",
    "declared_truth_frame",
    "geometry",
    "geometry_report",
    "meters_per_tick",
    "twist_from_ticks",
    "values_for_log",
]

TURN_WINDOW_RAD = 0.05
"""A window turns when what the commands asked of it turns by more than this (rad): the
windows :meth:`DiffDriveAdapter.command_wheel_gains
<realitygap.diagnosis.adapters.diffdrive.adapter.DiffDriveAdapter.command_wheel_gains>`
compares turn rates on."""

TRUTH_FRAME_RANGE = 0.02
"""m: how far from the axle centre a hand-defined ground-truth body origin is a convention."""
TRUTH_YAW_RANGE = 0.035
"""rad (2°): how far from the rolling direction a hand-defined ground-truth heading is a convention."""
TRUTH_LATENCY_FLOOR = 0.02
"""s: how far the ground truth's stamps may trail or lead the rows as a convention, however
short the row period: a capture system stamps a pose its latency and sample hold after the
motion (some to twenty milliseconds), and the rows hold the latest sample."""
DRIVE_RESPONSE_FLOOR = 0.05
"""s: the time constant of a DC wheel drive's speed loop that is its own response, not a
finding, however fast the commands come (a speed loop settles in some tens of
milliseconds; the command period bounds it only where it is longer)."""


def declared_truth_frame(
    prepared: Any,
) -> tuple[dict[str, float], dict[str, float]]:
    """Where the logs say the ground truth's tracked point sits, and how far it may be off.

    ``meta["truth_frame"]`` of a log (from a robot file: ``x``, ``y`` (m), ``yaw``
    (rad) and their uncertainties ``sigma_xy`` (m), ``sigma_yaw`` (rad)) gives the
    centre and half-width of the baseline's frame range; logs that declare
    nothing give the convention: the axle centre within :data:`TRUTH_FRAME_RANGE`
    and :data:`TRUTH_YAW_RANGE`.

    Raises
    ------
    ValueError
        Logs of one diagnosis that declare different tracked points (one robot, one
        marker), naming two of them.
    """
    centre = {"x": 0.0, "y": 0.0, "yaw": 0.0}
    half = {"x": TRUTH_FRAME_RANGE, "y": TRUTH_FRAME_RANGE, "yaw": TRUTH_YAW_RANGE}
    seen: tuple[str, Mapping[str, Any]] | None = None
    for p in prepared:
        tf = p.log.meta.get("truth_frame")
        if not isinstance(tf, Mapping):
            continue
        if seen is not None and dict(seen[1]) != dict(tf):
            raise ValueError(
                f"{seen[0]} and {p.log.name} declare different ground-truth tracked points "
                f"({dict(seen[1])} and {dict(tf)}); the logs of one diagnosis come from one "
                "robot and one marker. Fix: diagnose them separately, or declare one point"
            )
        seen = (p.log.name, tf)
    if seen is not None:
        tf = seen[1]
        centre = {k: float(tf.get(k, 0.0)) for k in centre}
        sxy = float(tf.get("sigma_xy", TRUTH_FRAME_RANGE))
        half = {"x": sxy, "y": sxy, "yaw": float(tf.get("sigma_yaw", TRUTH_YAW_RANGE))}
    return centre, half


def twist_from_ticks(ticks: npt.ArrayLike, params: DiffDriveParams, dt: float) -> FloatArray:
    """The body twist (N, 2) [m/s, rad/s] the nominal geometry makes of cumulative encoder
    counts (N, 2), each row the rate until the next (the last repeats none: zero)."""
    t = np.asarray(ticks, dtype=float)
    d = np.diff(t, axis=0, append=t[-1:]) * (2.0 * math.pi / params.ticks_per_rev)
    sl = d[:, 0] * params.wheel_radius_left / dt
    sr = d[:, 1] * params.wheel_radius_right / dt
    return np.column_stack([(sl + sr) / 2.0, (sr - sl) / params.wheelbase])


def meters_per_tick(params: DiffDriveParams) -> tuple[float, float]:
    """Nominal wheel travel per encoder count, left and right, m."""
    return (
        2.0 * math.pi * params.wheel_radius_left / params.ticks_per_rev,
        2.0 * math.pi * params.wheel_radius_right / params.ticks_per_rev,
    )


@dataclass
class DiffDriveContext(LogContext):
    """What the differential drive keeps about a prepared log.

    Attributes
    ----------
    params : DiffDriveParams
        The nominal robot of the log.
    inputs : SurrogateInputs
        Start pose and the commands or ticks that drive the surrogate.
    twist : ndarray, shape (N, 2)
        Applied body twist (m/s, rad/s): the commands, or the wheel motion.
    surrogate : DiffDriveSurrogate
    reference : DiffDriveParams or None
        The nominal geometry every log of the diagnosis shares when the logs
        declare different ones (:meth:`DiffDriveAdapter.link_logs
        <realitygap.diagnosis.adapters.diffdrive.adapter.DiffDriveAdapter.link_logs>`);
        ``None`` while the log is judged against its own.
    """

    params: DiffDriveParams
    inputs: SurrogateInputs
    twist: FloatArray
    surrogate: DiffDriveSurrogate
    reference: DiffDriveParams | None = None

    def window_motion(self, bounds: npt.NDArray[np.int64]) -> FloatArray | None:
        """Mean speed and turn rate, their change over the window and ranges, (M, 6)."""
        twist = self.twist
        motion = np.zeros((bounds.shape[0], 6))
        for m, (a, b) in enumerate(bounds):
            seg = twist[a:b]
            before = twist[max(a - 1, 0)]
            motion[m] = (
                seg[:, 0].mean(),
                seg[:, 1].mean(),
                twist[b - 1, 0] - before[0],
                twist[b - 1, 1] - before[1],
                np.ptp(twist[max(a - 1, 0) : b, 0]),
                np.ptp(twist[max(a - 1, 0) : b, 1]),
            )
        return motion

    def wheels(self) -> WheelGeometry:
        """The wheels the log declares (its own nominal, not the reference)."""
        p = self.params
        return WheelGeometry(
            wheel_radius_left=p.wheel_radius_left,
            wheel_radius_right=p.wheel_radius_right,
            wheelbase=p.wheelbase,
            ticks_per_rev=p.ticks_per_rev,
        )

    def applied_twist(self) -> FloatArray:
        """The applied body twist (:attr:`twist`)."""
        return self.twist

    def reference_wheelbase(self) -> float | None:
        """The wheelbase of the reference geometry, else of the log's own nominal."""
        params = self.reference or self.params
        return None if params.wheelbase is None else float(params.wheelbase)


# --------------------------------------------------------------------------- common geometry
def geometry(params: DiffDriveParams) -> tuple[float, float, float]:
    """Declared wheel radii and wheelbase (m), the geometry the geometric effects scale."""
    return (
        float(params.wheel_radius_left),
        float(params.wheel_radius_right),
        float(params.wheelbase),
    )


def geometry_report(
    counts: Mapping[tuple[float, float, float], int],
    reference: tuple[float, float, float],
    relinked: list[str],
) -> dict[str, Any]:
    """What linking logs of different declared geometries did, as JSON (the reference,
    each declared geometry with its number of logs, the logs replayed on the reference)
    and a one-line ``summary``."""
    rl, rr, b = reference
    return {
        "reference": {"wheel_radius_left": rl, "wheel_radius_right": rr, "wheelbase": b},
        "declared": [
            {"wheel_radius_left": g[0], "wheel_radius_right": g[1], "wheelbase": g[2], "logs": n}
            for g, n in counts.items()
        ],
        "relinked": relinked,
        "summary": (
            f"the logs declare {len(counts)} nominal geometries; geometric factors are "
            f"relative to the most common one (wheel radii {1e3 * rl:.2f} / {1e3 * rr:.2f} mm, "
            f"wheelbase {1e3 * b:.1f} mm); {len(relinked)} log(s) replayed on it"
        ),
    }


def values_for_log(ctx: DiffDriveContext, values: Mapping[str, Any]) -> dict[str, Any]:
    r"""Effect values relative to the reference geometry, re-expressed for one log's nominal.

    With a reference (:meth:`DiffDriveAdapter.link_logs
    <realitygap.diagnosis.adapters.diffdrive.adapter.DiffDriveAdapter.link_logs>`) of radii
    :math:`r^*_{L,R}` and wheelbase :math:`b^*`, a log that declares :math:`r_{L,R}`,
    :math:`b` gets

    .. math::

        E_b' = E_b \frac{b^*}{b}, \quad
        s' = s \frac{\bar r^*}{\bar r}, \quad
        E_d' = E_d \frac{r^*_R / r^*_L}{r_R / r_L},

    so that every log's physical wheelbase and wheel radii are the same
    (``wheelbase_error``, ``wheel_radius_scale``, ``wheel_diameter_ratio``;
    values may be arrays over a batch). Without a reference, or for a log that
    declares the reference geometry, ``values`` is returned unchanged.
    """
    ref = ctx.reference
    if ref is None:
        return dict(values)
    rl0, rr0, b0 = geometry(ref)
    rl, rr, b = geometry(ctx.params)
    if (rl, rr, b) == (rl0, rr0, b0):
        return dict(values)
    out = dict(values)
    factors = {
        "wheelbase_error.E_b": b0 / b,
        "wheel_radius_scale.scale": (rl0 + rr0) / (rl + rr),
        "wheel_diameter_ratio.E_d": (rr0 / rl0) / (rr / rl),
    }
    for key, f in factors.items():
        if f != 1.0:
            out[key] = np.asarray(values.get(key, 1.0), dtype=float) * f
            if out[key].ndim == 0:
                out[key] = float(out[key])
    return out
