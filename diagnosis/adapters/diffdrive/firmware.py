"""The firmware a log states: rate limits and the convention by which they act.

A log whose ``cmd`` channel holds *requests* to the robot's firmware says so in
``meta["firmware"]``; the firmware's
:class:`~realitygap.robots.diffdrive.FirmwareLimits` turn the requests into the
twist the drive received (:func:`~realitygap.diagnosis.adapters.diffdrive.replay.applied_commands`),
the same realisation the PyBullet robot's
:meth:`~realitygap.robots.diffdrive.DiffDriveRobot.command_twist` uses, so the
PyBullet replay and the surrogate (both driven by the applied twist) follow one
definition.

Keys of ``meta["firmware"]``
    ``a_max`` (m/s²), ``alpha_max`` (rad/s²), ``v_max`` (m/s), ``w_max`` (rad/s),
    each optional (absent: no limit); ``ramp`` — ``"body"`` (default) or
    ``"wheels"``; ``deceleration`` — ``"limited"`` (default), ``"free"`` or
    ``"stop"`` (:class:`~realitygap.robots.diffdrive.Deceleration`);
    ``decel_factor`` — deceleration limit over acceleration limit (default 1).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.optimize import minimize_scalar

from realitygap.diagnosis.adapters.contract import ActuatorLimits
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.robots.diffdrive import FirmwareLimits

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "ACCEL_SCALE_BOUNDS",
    "DECEL_FACTOR_BOUNDS",
    "FIRMWARE_CONVENTIONS",
    "MIN_GAIN",
    "FirmwareFit",
    "firmware_from_meta",
    "fit_firmware_limits",
]


FIRMWARE_CONVENTIONS: dict[str, str] = {
    "body/limited": "the firmware ramps the body twist up and down (a_max on v, alpha_max on ω)",
    "body/free": "the firmware ramps the body twist up only (a_max on v, alpha_max on ω); "
    "it slows down at once",
    "wheels/limited": "the firmware ramps each wheel's speed set-point up and down "
    "(a_max per wheel)",
    "wheels/free": "the firmware ramps each wheel's speed set-point up only (a_max per "
    "wheel); it slows down at once",
    "body/stop": "the firmware ramps the body twist up and down (a_max on v, alpha_max on "
    "ω); a zero request stops at once",
    "wheels/stop": "the firmware ramps each wheel's speed set-point up and down (a_max per "
    "wheel); a zero request stops at once",
}
"""The conventions by which a firmware's rate limits act, ``"<ramp>/<deceleration>"`` →
what it does (the nominal's actuator conventions the calibrated baseline chooses among)."""


def firmware_from_meta(log: Log) -> FirmwareLimits | None:
    """The firmware of ``log.meta["firmware"]``; ``None`` when the log states none.

    Raises
    ------
    LogError
        If a key holds a value of the wrong kind, naming the log, what was
        expected, what came and the fix.
    """
    fw = log.meta.get("firmware")
    if not isinstance(fw, Mapping) or not fw:
        return None
    try:
        return FirmwareLimits(
            v_max=float(fw.get("v_max", math.inf)),
            w_max=float(fw.get("w_max", math.inf)),
            a_max=float(fw.get("a_max", math.inf)),
            alpha_max=float(fw.get("alpha_max", math.inf)),
            ramp=fw.get("ramp", "body"),
            deceleration=fw.get("deceleration", "limited"),
            decel_factor=float(fw.get("decel_factor", 1.0)),
        )
    except (TypeError, ValueError) as exc:
        raise LogError(
            f"{log.source}: meta['firmware'] must have ramp 'body' or 'wheels', deceleration "
            "'limited', 'free' or 'stop', and positive limits and decel_factor; "
            f"{exc}. Fix the importer's firmware settings"
        ) from None


@dataclass(frozen=True)
class FirmwareFit(ActuatorLimits):
    """Rate limits of a firmware convention fitted to the encoders of request-driven logs.

    Attributes
    ----------
    convention : str
        ``"<ramp>/<deceleration>"`` the limits were fitted under.
    accel_scale : float
        Fitted acceleration limits over the stated ones (``a_max`` and
        ``alpha_max`` scale together: one firmware clock, one set of units).
    decel_factor : float
        Fitted deceleration limit over the acceleration limit (1 when the
        convention does not limit slowing down).
    delay_periods : float
        Control periods (fractional) between a set-point and the wheel speed it
        shows in: the encoders' average over a period and the motors' response (a
        nuisance of the fit).
    cost, cost_stated : float
        Robust cost of the wheel-speed residual at the fit and at the stated limits.
    n_rows : int
        Wheel-speed samples the fit used.
    """

    convention: str
    accel_scale: float = 1.0
    decel_factor: float = 1.0
    delay_periods: float = 0.0
    cost: float = math.nan
    cost_stated: float = math.nan
    n_rows: int = 0

    def meta(self, stated: Mapping[str, Any]) -> dict[str, Any]:
        """``meta["firmware"]`` with the fitted limits applied to the ``stated`` one."""
        out = dict(stated)
        for key in ("a_max", "alpha_max"):
            if key in out and math.isfinite(float(out[key])):
                out[key] = float(out[key]) * self.accel_scale
        out["decel_factor"] = float(stated.get("decel_factor", 1.0)) * self.decel_factor
        return out

    def leaves_stated(self) -> bool:
        """Whether the fitted limits are the stated ones (both factors one)."""
        return bool(self.accel_scale == 1.0 and self.decel_factor == 1.0)

    def to_json(self) -> dict[str, Any]:
        """JSON form."""
        return {
            "convention": self.convention,
            "accel_scale": self.accel_scale,
            "decel_factor": self.decel_factor,
            "delay_periods": self.delay_periods,
            "cost": self.cost,
            "cost_stated": self.cost_stated,
            "n_rows": self.n_rows,
        }


ACCEL_SCALE_BOUNDS = (0.5, 2.0)
"""Fitted acceleration limits stay within a factor of two of the stated ones."""
DECEL_FACTOR_BOUNDS = (0.25, 4.0)
"""A firmware's deceleration limit lies within a factor of four of its acceleration limit
(``yocs_velocity_smoother`` ships ``decel_factor`` 1; ros2 ``diff_drive_controller``'s
``max_deceleration`` is usually set between the acceleration and a few times it)."""


def _at_bound(x: float, bounds: tuple[float, float], tol: float = 0.05) -> bool:
    """Whether ``x`` lies within ``tol`` (in logarithm: 5 %) of either end of ``bounds``."""
    return min(abs(math.log(x / bounds[0])), abs(math.log(x / bounds[1]))) < tol


DELAY_STEP_PERIODS = 0.5
"""Spacing (control periods) of the grid the set-point delay is first searched on."""


def max_delay_seconds() -> float:
    """The longest delay (s) between a set-point and the wheel speed it shows in that the
    limit fit allows: the longest command latency of the effect library
    (``command_latency.delay``'s physical bound). A bound in seconds, not in periods: a
    latency the fit could not reach would be taken for a slower ramp."""
    from realitygap.diagnosis.problem.parameters import param_spec

    return float(param_spec("command_latency.delay").high)


MIN_GAIN = 0.005
"""Fitted limits replace the stated ones only when they lower the robust cost by more than
this share (and by more than two per fitted parameter, the Akaike penalty): wheel speeds
one period apart are correlated, so a smaller gain is within what noise buys."""


def _wheel_data(log: Log) -> tuple[FloatArray, FloatArray, float, float] | None:
    """Requests (N, 2), measured wheel surface speeds (N−1, 2) in m/s, dt and wheelbase."""
    from realitygap.robots.diffdrive_replay import MetaError, params_from_meta

    if not (log.has("cmd") and log.has("ticks")) or log.n < 4:
        return None
    try:
        params = params_from_meta(log.meta, log.source)
    except MetaError as exc:
        raise LogError(str(exc)) from None
    ticks = np.asarray(log["ticks"], dtype=float)
    k = 2.0 * math.pi / params.ticks_per_rev
    rates = np.diff(ticks, axis=0) * k / log.dt
    rates[:, 0] *= params.wheel_radius_left
    rates[:, 1] *= params.wheel_radius_right
    return np.asarray(log["cmd"], dtype=float), rates, log.dt, params.wheelbase


def fit_firmware_limits(
    logs: Sequence[Log], convention: str, max_delay_periods: float | None = None
) -> FirmwareFit:
    r"""Fit the rate limits of ``convention`` to the wheel speeds the encoders saw.

    For each log with requests (``cmd``), encoder counts and a stated firmware,
    the requests pass through the firmware
    (:meth:`~realitygap.robots.diffdrive.FirmwareLimits.applied`) with
    acceleration limits :math:`s\,a_{max}`, :math:`s\,α_{max}` and deceleration
    limit :math:`f` times those; the wheel set-points :math:`v ∓ ω b/2` are
    compared with the wheel surface speeds from the encoders (nominal radii), a
    set-point showing :math:`d` periods later (fractional, linear interpolation;
    :math:`0 ≤ d ≤` ``max_delay_periods``: half a period of the encoders'
    average over the period, the velocity loop's response and any command
    latency — by default one period plus :func:`max_delay_seconds` over the
    shortest log period, a bound in time, not in periods), :math:`d` searched
    on a grid of :data:`DELAY_STEP_PERIODS` and refined by bounded Brent steps
    at the stated limits. The loss is robust (soft-L1, scale from the
    median absolute residual at the stated limits), so stalls and encoder
    quantisation do not steer it. ``s`` and ``f`` are searched on a logarithmic
    grid and refined by bounded Brent steps, one coordinate at a time, inside
    :data:`ACCEL_SCALE_BOUNDS` and :data:`DECEL_FACTOR_BOUNDS`; ``f`` only when
    the convention limits slowing down. The stated limits stay unless the fit
    lowers the cost by more than :data:`MIN_GAIN`, and they stay when a fitted
    factor ends at either end of its range: the encoders then show a drive train
    that no rescaling of the stated firmware describes (a speed loop slower than
    the firmware's ramps, other ramps altogether), which is for the effect library
    (``wheel_velocity_lag``, ``acceleration_limits``) to answer, not for the
    nominal's convention.

    The encoders see the wheels' rotation, so an encoder scale error biases
    ``s`` in proportion; the limits are a convention of the nominal robot and
    the encoder scale a candidate effect of the diagnosis, which is scored
    against it.

    Returns
    -------
    FirmwareFit
        ``accel_scale = decel_factor = 1`` and ``n_rows = 0`` when no log has
        requests, encoder counts and a stated firmware.
    """
    data = []
    for log in logs:
        stated = firmware_from_meta(log)
        wd = _wheel_data(log)
        if stated is None or wd is None:
            continue
        ramp, _, decel = convention.partition("/")
        data.append((replace(stated, ramp=ramp, deceleration=decel), *wd))
    if not data:
        return FirmwareFit(convention)
    limited = convention.partition("/")[2] != "free"

    cache: dict[tuple[float, float], list[FloatArray]] = {}

    def set_points(s: float, f: float) -> list[FloatArray]:
        if (s, f) not in cache:
            cache.clear()
            out = []
            for fw, req, _, dt, b in data:
                lim = replace(fw, a_max=fw.a_max * s, alpha_max=fw.alpha_max * s, decel_factor=f)
                tw = lim.applied(req, dt, b)
                half = 0.5 * b
                out.append(
                    np.column_stack([tw[:, 0] - half * tw[:, 1], tw[:, 0] + half * tw[:, 1]])
                )
            cache[(s, f)] = out
        return cache[(s, f)]

    def residuals(s: float, f: float, d: float) -> FloatArray:
        i, w = int(math.floor(d)), d - math.floor(d)
        out = []
        for pred, (_, _, rates, _, _) in zip(set_points(s, f), data, strict=True):
            # the set-point of row k shows in the wheel speed d periods later
            padded = np.vstack([np.zeros((i + 1, 2)), pred])
            n = rates.shape[0]
            at = np.arange(n) + 1  # row k of pred sits at padded[k + i + 1]
            shifted = (1.0 - w) * padded[at] + w * padded[at - 1]
            out.append((rates - shifted).ravel())
        return np.concatenate(out)

    def cost(z: FloatArray, c: float) -> float:
        return float(np.sum(2.0 * (np.sqrt(1.0 + (z / c) ** 2) - 1.0)))

    z0 = residuals(1.0, 1.0, 0.5)
    c = max(1.4826 * float(np.median(np.abs(z0))), 1e-6)

    d_max = (
        float(max_delay_periods)
        if max_delay_periods is not None
        else 1.0 + max_delay_seconds() / min(dt for _, _, _, dt, _ in data)
    )

    def fit_delay(s: float, f: float) -> tuple[float, float]:
        # a grid first: over a long bound the cost can have more than one dip (periodic
        # manoeuvres), which a bounded Brent search over the whole range could miss
        grid = np.arange(0.0, d_max + 1e-9, DELAY_STEP_PERIODS)
        costs = [cost(residuals(s, f, float(d)), c) for d in grid]
        i0 = int(np.argmin(costs))
        d0, c0 = float(grid[i0]), float(costs[i0])
        res = minimize_scalar(
            lambda d: cost(residuals(s, f, d), c),
            bounds=(max(d0 - DELAY_STEP_PERIODS, 0.0), min(d0 + DELAY_STEP_PERIODS, d_max)),
            method="bounded",
            options={"xatol": 0.01},
        )
        if float(res.fun) <= c0:
            return float(res.x), float(res.fun)
        return d0, c0

    d_best, cost_stated = fit_delay(1.0, 1.0)
    best = (cost_stated, 1.0, 1.0)

    def refine(which: int, step: float, bounds: tuple[float, float]) -> None:
        nonlocal best
        x0 = best[1 + which]
        a = math.log(max(x0 / step, bounds[0]))
        b = math.log(min(x0 * step, bounds[1]))

        def objective(u: float) -> float:
            s, f = (math.exp(u), best[2]) if which == 0 else (best[1], math.exp(u))
            return cost(residuals(s, f, d_best), c)

        res = minimize_scalar(objective, bounds=(a, b), method="bounded", options={"xatol": 0.004})
        if float(res.fun) < best[0]:
            x = math.exp(float(res.x))
            best = (float(res.fun), x, best[2]) if which == 0 else (float(res.fun), best[1], x)

    lo, hi = ACCEL_SCALE_BOUNDS
    flo, fhi = DECEL_FACTOR_BOUNDS
    s_grid = np.geomspace(lo, hi, 7)
    f_grid = np.geomspace(flo, fhi, 7) if limited else np.ones(1)
    for f in f_grid:
        for s in s_grid:
            val = cost(residuals(float(s), float(f), d_best), c)
            if val < best[0]:
                best = (val, float(s), float(f))
    # refine each coordinate within one coarse step (bounded Brent on the logarithm)
    refine(0, (hi / lo) ** (1.0 / 6.0), ACCEL_SCALE_BOUNDS)
    if limited:
        refine(1, (fhi / flo) ** (1.0 / 6.0), DECEL_FACTOR_BOUNDS)
        refine(0, (hi / lo) ** (1.0 / 12.0), ACCEL_SCALE_BOUNDS)
    n_rows = sum(r.shape[0] for _, _, r, _, _ in data)
    k = 2 if limited else 1
    if not cost_stated - best[0] > max(2.0 * k, MIN_GAIN * cost_stated):
        best = (cost_stated, 1.0, 1.0)  # the data do not ask for other limits than the stated
    elif _at_bound(best[1], ACCEL_SCALE_BOUNDS) or (
        limited and _at_bound(best[2], DECEL_FACTOR_BOUNDS)
    ):
        # limits stretched to the end of their range: the encoders show a drive train the
        # stated firmware, rescaled, does not describe (a slow speed loop, other ramps);
        # that is for the effect library to answer, not for the nominal's convention
        best = (cost_stated, 1.0, 1.0)
    return FirmwareFit(
        convention,
        accel_scale=float(best[1]),
        decel_factor=float(best[2]),
        delay_periods=d_best,
        cost=float(best[0]),
        cost_stated=cost_stated,
        n_rows=n_rows,
    )
