r"""Drive-train effects of the differential drive: what happens between the firmware's
wheel-speed commands, the wheels and the floor.

Per-wheel velocity-loop lag, acceleration / deceleration limits (the speed
limiter of ros2 ``diff_drive_controller``), per-wheel dead zones, DC-motor
torque–speed saturation, and traction slip. Each acts with state carried
from one control period to the next; one vectorised step function per effect
serves the PyBullet hook (a batch of one) and the surrogate term (a batch of
parameter sets), so both realise the same law.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects.base import (
    BlindRange,
    Channel,
    CommandHook,
    Effect,
    ParamSpec,
    Stage,
    WheelHook,
    register_effect,
)
from realitygap.robots.effects.diffdrive import (
    SurrogateContext,
    SurrogateSlot,
    _wheel_command_hook,
)

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "AccelerationLimits",
    "MotorResponse",
    "TorqueSpeedSaturation",
    "TractionSlip",
    "WheelDeadZone",
    "WheelVelocityLag",
    "speed_limiter_step",
    "torque_speed_step",
]


def _lag_gain(tau: Any, dt: float) -> Any:
    r"""Share of the remaining error a first-order lag closes in one period, :math:`1 - e^{-dt/τ}`."""
    tau = np.asarray(tau, dtype=float)
    with np.errstate(divide="ignore", over="ignore"):
        return np.where(tau > 0.0, -np.expm1(-dt / np.where(tau > 0.0, tau, 1.0)), 1.0)


def _inverse_rate(t_per_unit: Any) -> Any:
    """Rate limit from its inverse (time per unit change): ``1 / t``, infinite at ``t = 0``."""
    t = np.asarray(t_per_unit, dtype=float)
    with np.errstate(divide="ignore", over="ignore"):  # a subnormal t: an infinite rate, as t = 0
        return np.where(t > 0.0, 1.0 / np.where(t > 0.0, t, 1.0), np.inf)


def speed_limiter_step(y0: Any, x: Any, up: Any, down: Any) -> Any:
    r"""One step of an acceleration / deceleration limiter (ros2 ``diff_drive_controller``).

    The change from the previous output ``y0`` towards the request ``x`` is
    clipped to

    .. math::

        Δ \in \begin{cases}
        [-d, a] & y_0 > 0 \\ [-a, d] & y_0 < 0 \\ [-a, a] & y_0 = 0
        \end{cases}

    with ``a = up`` (largest speed-up per period) and ``d = down`` (largest
    slow-down per period): moving away from standstill is acceleration,
    towards it deceleration, judged by the sign of the previous output, as the
    speed limiter of ``diff_drive_controller`` does with ``max_acceleration``
    and ``max_deceleration``. Arrays broadcast; infinite limits do not limit.
    """
    y0 = np.asarray(y0, dtype=float)
    x = np.asarray(x, dtype=float)
    lo = np.where(y0 > 0.0, -down, -up)
    hi = np.where(y0 < 0.0, down, up)
    d = x - y0
    # a request within the limits passes exactly (the recursion skips such stretches)
    return np.where((d >= lo) & (d <= hi), x, y0 + np.clip(d, lo, hi))


def torque_speed_step(s0: Any, target: Any, v_top: Any, k: Any) -> Any:
    r"""One period of a DC-motor wheel whose drive saturates on its torque–speed line.

    With the drive at full voltage the wheel-surface speed approaches the
    loaded top speed :math:`v_{top}` along the motor's mechanical time
    constant :math:`t_m`; over one period it can gain at most

    .. math::

        Δ|s| \le (v_{top} - |s_0|)\,(1 - e^{-dt/t_m}) = (v_{top} - |s_0|)\,k .

    A request within reach is met; slowing down is not limited (the motor
    brakes); a reversal starts from standstill. Arrays broadcast.
    """
    s0 = np.asarray(s0, dtype=float)
    target = np.asarray(target, dtype=float)
    mag0, mag = np.abs(s0), np.abs(target)
    room = np.maximum(v_top - mag0, 0.0) * k
    reverse = s0 * target < 0.0
    speeding_up = (~reverse) & (mag > mag0)
    new_mag = np.where(
        reverse,
        np.minimum(mag, np.minimum(v_top, 1e300) * k),
        np.where(speeding_up & (mag - mag0 > room), mag0 + room, mag),
    )
    return np.sign(target) * new_mag


def _recurse(x: FloatArray, step: Any) -> FloatArray:
    """Run ``y_k = step(y_{k-1}, x_k)`` along axis 1 of ``x`` (B, N), ``y_{-1} = 0``.

    ``step`` acts elementwise on (B, m) arrays (its parameters shaped (B, 1)) and
    returns ``x_k`` itself, exactly, where it does not act (a limit not reached).
    Where the output follows the input the recursion is not stepped: the
    periods in which ``step(x_{k-1}, x_k) != x_k`` for some row are found at
    once, and only from there on is the recursion run, until every row has
    caught up with its input again.
    """
    x = np.asarray(x, dtype=float)
    B, n = x.shape
    prev = np.concatenate([np.zeros((B, 1)), x[:, :-1]], axis=1)
    starts = np.flatnonzero(np.any(step(prev, x) != x, axis=0))
    y = x.copy()
    if starts.size == 0:
        return y
    k = int(starts[0])
    y0 = prev[:, k : k + 1]
    while k < n:
        yk = step(y0, x[:, k : k + 1])
        y[:, k : k + 1] = yk
        if np.all(yk == x[:, k : k + 1]):
            later = starts[starts > k]
            if later.size == 0:
                break
            k = int(later[0])
            y0 = y[:, k - 1 : k]
            continue
        y0 = yk
        k += 1
    return y


def _lag(x: FloatArray, k: FloatArray) -> FloatArray:
    r"""First-order lag :math:`y_k = y_{k-1} + k\,(x_k - y_{k-1})`, ``y_{-1} = 0``, per row of (B, N)."""
    from scipy.signal import lfilter

    x = np.asarray(x, dtype=float)
    kk = np.broadcast_to(np.asarray(k, dtype=float), (x.shape[0],))
    y = np.empty_like(x)
    # one filter call per distinct gain: a batch that shares its lag (a baseline value
    # every parameter set carries) is filtered at once
    for gain in np.unique(kk):
        rows = kk == gain
        y[rows] = x[rows] if gain >= 1.0 else lfilter([gain], [1.0, gain - 1.0], x[rows], axis=1)
    return y


def _lag_hook(
    nominal: DiffDriveParams | None, dt: float, tau_l: float, tau_r: float
) -> CommandHook:
    """The PyBullet command hook of first-order lags with time constants ``tau_l``,
    ``tau_r`` (s) on the left and right wheel-speed commands, from rest."""
    kl, kr = float(_lag_gain(tau_l, dt)), float(_lag_gain(tau_r, dt))
    state = [0.0, 0.0]

    def step(sl: float, sr: float, dt_: float) -> tuple[float, float]:
        state[0] += kl * (sl - state[0])
        state[1] += kr * (sr - state[1])
        return state[0], state[1]

    return _wheel_command_hook(nominal, step)


def _lag_term(x: Any, tau_l: FloatArray, tau_r: FloatArray, dt: float) -> Any:
    """The surrogate's term of the same lags: wheel speeds ``x = (s_L, s_R)`` (N,) or
    (B, N) and time constants (B,) → lagged wheel speeds (B, N) each."""
    sl, sr = x
    if not (np.any(tau_l > 0) or np.any(tau_r > 0)):
        return sl, sr
    out = []
    for s, tau in ((sl, tau_l), (sr, tau_r)):
        kk = _lag_gain(tau, dt)
        out.append(_lag(np.broadcast_to(s, (kk.shape[0], np.shape(s)[-1])), kk))
    return out[0], out[1]


@register_effect
class WheelVelocityLag(Effect):
    r"""Each wheel's velocity loop follows its command as a first-order lag.

    A wheel's speed controller (PI loop, motor and gear inertia) does not
    reach a new wheel-speed command at once: with time constant
    :math:`τ` per wheel the speed applied over period ``k`` is

    .. math::

        s_k = s_{k-1} + (1 - e^{-dt/τ})\,(s^{cmd}_k - s_{k-1}).

    Unequal time constants (one motor or gearbox stiffer than the other) make
    the robot yaw on every start and stop. Realised on the firmware's
    wheel-speed commands; the surrogate runs the same recursion.
    """

    name = "wheel_velocity_lag"
    robot = "diffdrive"
    stage = Stage.COMMAND
    observed_in = (Channel.POSE_GT, Channel.TICKS, Channel.POSE_CAM)
    description = (
        "Each wheel's velocity loop follows its speed command as a first-order lag with its own "
        "time constant (s); unequal constants yaw the robot on starts and stops. Realised on the "
        "firmware's wheel-speed commands (nominal geometry)."
    )
    specs = (
        ParamSpec("tau_left", "s", 0.0, 0.0, 0.5, "left wheel velocity-loop time constant"),
        ParamSpec("tau_right", "s", 0.0, 0.0, 0.5, "right wheel velocity-loop time constant"),
    )
    blind = (
        BlindRange("tau_left", 0.05, 0.25, False),
        BlindRange("tau_right", 0.05, 0.25, False),
    )
    since = 2
    surrogate_slot = SurrogateSlot.WHEEL_SPEED
    surrogate_order = 3  # after the static dead zones, gains and limits
    surrogate_example = (("tau_left", 0.08), ("tau_right", 0.2))

    def make_command_hook(
        self, dt: float, nominal: DiffDriveParams | None = None
    ) -> CommandHook | None:
        if self.is_nominal():
            return None
        return _lag_hook(nominal, dt, self["tau_left"], self["tau_right"])

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        return _lag_term(x, p["tau_left"], p["tau_right"], ctx.dt)


@register_effect
class MotorResponse(Effect):
    r"""Both wheels' velocity loops follow their commands as one first-order lag.

    The drive's speed controller, motor and gearbox take some time to reach a
    new wheel-speed command; the nominal robot does not know how long. With one
    time constant :math:`τ` for both wheels,

    .. math::

        s_k = s_{k-1} + (1 - e^{-dt/τ})\,(s^{cmd}_k - s_{k-1})

    per wheel: every start and stop is softened alike and the robot does not
    yaw. It is the actuator response of the nominal that every real drive has,
    so it stays outside the default library: the calibrated baseline fits it as
    a convention of the drive (:meth:`~realitygap.diagnosis.adapters.diffdrive.adapter.DiffDriveAdapter.baseline_nuisances`).
    Wheels that answer with *different* time constants are the effect
    ``wheel_velocity_lag``. The same law as that effect (one recursion).
    """

    name = "motor_response"
    robot = "diffdrive"
    stage = Stage.COMMAND
    observed_in = (Channel.POSE_GT, Channel.TICKS, Channel.POSE_CAM)
    description = (
        "Both wheels' velocity loops follow their speed commands as one first-order lag (s): "
        "the drive's response, which the nominal robot does not know. Realised on the "
        "firmware's wheel-speed commands (nominal geometry)."
    )
    specs = (ParamSpec("tau", "s", 0.0, 0.0, 0.5, "time constant of both wheels' velocity loops"),)
    since = 4
    surrogate_slot = SurrogateSlot.WHEEL_SPEED
    surrogate_order = 3  # with the per-wheel lags: linear lags commute
    surrogate_example = (("tau", 0.12),)

    def make_command_hook(
        self, dt: float, nominal: DiffDriveParams | None = None
    ) -> CommandHook | None:
        if self.is_nominal():
            return None
        return _lag_hook(nominal, dt, self["tau"], self["tau"])

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        return _lag_term(x, p["tau"], p["tau"], ctx.dt)


@register_effect
class AccelerationLimits(Effect):
    r"""Separate acceleration and deceleration limits on the body twist.

    The speed limiter of ros2 ``diff_drive_controller`` (``max_acceleration``,
    ``max_deceleration`` of ``linear.x`` and ``angular.z``) or a motor
    driver's ramp: each period the applied ``v`` and ``ω`` move from their
    previous values by at most :func:`speed_limiter_step`, with acceleration
    (away from standstill) and deceleration (towards it) limits

    .. math::

        a_{acc} = 1 / t_{acc}, \quad a_{dec} = 1 / t_{dec}, \quad
        α_{acc} = 1 / t_{α,acc}, \quad α_{dec} = 1 / t_{α,dec}.

    The parameters are the inverse limits (seconds per m/s or per rad/s of
    speed change): zero is "no limit", so the nominal sits inside the range
    and the fit's scale is even. Realised after the robot's own firmware
    limits, on the applied twist; the surrogate runs the same limiter.
    """

    name = "acceleration_limits"
    robot = "diffdrive"
    stage = Stage.COMMAND
    observed_in = (Channel.POSE_GT, Channel.TICKS, Channel.POSE_CAM)
    description = (
        "A speed limiter with separate acceleration and deceleration limits on v and ω "
        "(diff_drive_controller's max_acceleration / max_deceleration, a motor driver's ramp), "
        "given as inverse limits: seconds per m/s (rad/s) of speed change. Realised on the "
        "applied twist."
    )
    specs = (
        ParamSpec("t_acc", "s²/m", 0.0, 0.0, 10.0, "1 / max. forward acceleration (≥ 0.1 m/s²)"),
        ParamSpec("t_dec", "s²/m", 0.0, 0.0, 10.0, "1 / max. forward deceleration (≥ 0.1 m/s²)"),
        ParamSpec(
            "t_alpha_acc", "s²/rad", 0.0, 0.0, 5.0, "1 / max. angular acceleration (≥ 0.2 rad/s²)"
        ),
        ParamSpec(
            "t_alpha_dec", "s²/rad", 0.0, 0.0, 5.0, "1 / max. angular deceleration (≥ 0.2 rad/s²)"
        ),
    )
    blind = (
        BlindRange("t_acc", 1.5, 4.0, False),
        BlindRange("t_dec", 1.5, 4.0, False),
        BlindRange("t_alpha_acc", 0.4, 1.5, False),
        BlindRange("t_alpha_dec", 0.4, 1.5, False),
    )
    since = 2
    surrogate_slot = SurrogateSlot.COMMAND_TWIST
    surrogate_order = 1  # after the latency (a causal limiter and a delay commute)
    surrogate_example = (("t_acc", 2.5), ("t_dec", 1.2), ("t_alpha_acc", 0.8), ("t_alpha_dec", 0.3))

    def make_command_hook(
        self, dt: float, nominal: DiffDriveParams | None = None
    ) -> CommandHook | None:
        if self.is_nominal():
            return None
        up_v, down_v = _inverse_rate(self["t_acc"]) * dt, _inverse_rate(self["t_dec"]) * dt
        up_w, down_w = (
            _inverse_rate(self["t_alpha_acc"]) * dt,
            _inverse_rate(self["t_alpha_dec"]) * dt,
        )
        state = [0.0, 0.0]

        def hook(v: float, w: float, dt_: float) -> tuple[float, float]:
            state[0] = float(speed_limiter_step(state[0], v, up_v, down_v))
            state[1] = float(speed_limiter_step(state[1], w, up_w, down_w))
            return state[0], state[1]

        return hook

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        if not any(np.any(p[s.name] > 0) for s in cls.specs):
            return x
        B = p["t_acc"].shape[0]
        u = np.broadcast_to(np.asarray(x, dtype=float), (B, *np.shape(x)[-2:]))
        out = np.empty_like(u)
        for col, (ka, kd) in enumerate((("t_acc", "t_dec"), ("t_alpha_acc", "t_alpha_dec"))):
            up = _inverse_rate(p[ka])[:, None] * ctx.dt
            down = _inverse_rate(p[kd])[:, None] * ctx.dt
            out[..., col] = _recurse(
                u[..., col], lambda y0, xk, up=up, down=down: speed_limiter_step(y0, xk, up, down)
            )
        return out


@register_effect
class WheelDeadZone(Effect):
    r"""Per-wheel dead zones of the two motor drives.

    Each wheel stands still while its commanded surface speed is below its
    own threshold (static friction, a PWM dead zone differing between the two
    drivers):

    .. math::

        s'_L = s_L\,[|s_L| \ge δ_L], \qquad s'_R = s_R\,[|s_R| \ge δ_R].

    Unlike ``motor_deadband`` (one threshold for both wheels) the wheels
    differ: a slow turn pivots on the wheel whose threshold is not reached.
    A drive-gain asymmetry (the right wheel turning ``G`` times as fast for
    the same command) is not a parameter here: it is exactly
    ``wheel_diameter_ratio`` with ``E_d = G`` together with ``encoder_ratio``
    with ``E_c = G`` (the same ground and count ratios). Realised on the
    firmware's wheel-speed commands.
    """

    name = "wheel_dead_zone"
    robot = "diffdrive"
    stage = Stage.COMMAND
    observed_in = (Channel.POSE_GT, Channel.TICKS, Channel.POSE_CAM)
    description = (
        "Per-wheel dead zones (m/s): a wheel commanded below its threshold does not turn, so "
        "slow turns pivot on it. Realised on the firmware's wheel-speed commands (nominal "
        "geometry)."
    )
    specs = (
        ParamSpec("dz_left", "m/s", 0.0, 0.0, 0.08, "left wheel dead zone (surface speed)"),
        ParamSpec("dz_right", "m/s", 0.0, 0.0, 0.08, "right wheel dead zone (surface speed)"),
    )
    blind = (
        BlindRange("dz_left", 0.0, 0.06, False),
        BlindRange("dz_right", 0.0, 0.06, False),
    )
    since = 2
    surrogate_slot = SurrogateSlot.WHEEL_SPEED
    surrogate_order = 1
    surrogate_example = (("dz_left", 0.06), ("dz_right", 0.01))

    @staticmethod
    def _apply(sl: Any, sr: Any, dzl: Any, dzr: Any) -> tuple[Any, Any]:
        sl = np.where(np.abs(sl) < dzl, 0.0, sl)
        sr = np.where(np.abs(sr) < dzr, 0.0, sr)
        return sl, sr

    def make_command_hook(
        self, dt: float, nominal: DiffDriveParams | None = None
    ) -> CommandHook | None:
        if self.is_nominal():
            return None
        dzl, dzr = self["dz_left"], self["dz_right"]
        return _wheel_command_hook(nominal, lambda sl, sr, dt_: self._apply(sl, sr, dzl, dzr))

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        sl, sr = x
        dzl, dzr = p["dz_left"], p["dz_right"]
        if not (np.any(dzl > 0) or np.any(dzr > 0)):
            return sl, sr
        return cls._apply(sl, sr, dzl[:, None], dzr[:, None])


@register_effect
class TorqueSpeedSaturation(Effect):
    r"""DC-motor drives on their torque–speed line: the top speed falls with load and battery.

    A DC motor's torque falls linearly with speed, :math:`τ = τ_s (1 - ω/ω_0)`,
    and :math:`ω_0` scales with the battery voltage. Against a load torque
    :math:`τ_L` (rolling resistance, a payload, a slope) the wheel tops out at

    .. math::

        v_{top} = ω_0 r \frac{V}{V_{nom}} \Bigl(1 - \frac{τ_L}{τ_s}\Bigr),

    and at full voltage approaches it with the mechanical time constant
    :math:`t_m` (:func:`torque_speed_step`): the closer to the top speed, the
    slower the wheel speeds up. A robot whose speed saturates *below* the
    commanded speed is therefore inside the range — from a crawling 0.05 m/s
    up to the nominal drive's top wheel speed. Realised per wheel on the
    firmware's wheel-speed commands; the surrogate runs the same law.
    """

    name = "torque_speed_saturation"
    robot = "diffdrive"
    stage = Stage.COMMAND
    observed_in = (Channel.POSE_GT, Channel.TICKS, Channel.POSE_CAM)
    description = (
        "The wheel motors run on their torque-speed line: the loaded top wheel speed v_top (m/s) "
        "falls with load and battery voltage, and the wheels approach it with the motors' "
        "mechanical time constant t_m (s). Realised on the firmware's wheel-speed commands."
    )
    specs = (
        ParamSpec(
            "v_top", "m/s", 1.2, 0.05, 1.2, "loaded top wheel surface speed (nominal: not reached)"
        ),
        ParamSpec("t_m", "s", 0.0, 0.0, 0.5, "mechanical time constant at full voltage"),
    )
    blind = (
        BlindRange("v_top", 0.3, 0.6, False, absolute=True),
        BlindRange("t_m", 0.05, 0.3, False),
    )
    since = 2
    surrogate_slot = SurrogateSlot.WHEEL_SPEED
    surrogate_order = 2
    surrogate_example = (("v_top", 0.45), ("t_m", 0.15))

    def make_command_hook(
        self, dt: float, nominal: DiffDriveParams | None = None
    ) -> CommandHook | None:
        if self.is_nominal():
            return None
        v_top, k = self["v_top"], float(_lag_gain(self["t_m"], dt))
        state = [0.0, 0.0]

        def step(sl: float, sr: float, dt_: float) -> tuple[float, float]:
            state[0] = float(torque_speed_step(state[0], sl, v_top, k))
            state[1] = float(torque_speed_step(state[1], sr, v_top, k))
            return state[0], state[1]

        return _wheel_command_hook(nominal, step)

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        sl, sr = x
        v_top, t_m = p["v_top"], p["t_m"]
        if not (np.any(v_top < cls.spec("v_top").nominal) or np.any(t_m > 0)):
            return sl, sr
        k = _lag_gain(t_m, ctx.dt)[:, None]
        vt = v_top[:, None]
        out = []
        for s in (sl, sr):
            s = np.broadcast_to(s, (k.shape[0], np.shape(s)[-1]))
            out.append(_recurse(s, lambda y0, xk: torque_speed_step(y0, xk, vt, k)))
        return out[0], out[1]


class _SlipHook:
    """Per-wheel hook of :class:`TractionSlip`: the motors roll at the ground speed, the
    encoders count the turned wheel."""

    def __init__(self, k: float, dt: float):
        self.k, self.dt = k, dt
        self.ground_left = self.ground_right = 0.0  # rolling speeds, rad/s
        self.slip_left = self.slip_right = 0.0  # turned minus rolled angles, rad

    def command(self, w_left: float, w_right: float) -> tuple[float, float]:
        k, dt = self.k, self.dt
        tl, tr = float(w_left), float(w_right)
        gl = self.ground_left = self.ground_left + k * (tl - self.ground_left)
        gr = self.ground_right = self.ground_right + k * (tr - self.ground_right)
        self.slip_left += (tl - gl) * dt
        self.slip_right += (tr - gr) * dt
        return gl, gr

    def encoder(self, a_left: float, a_right: float) -> tuple[float, float]:
        return a_left + self.slip_left, a_right + self.slip_right

    def rolling_from_encoder(self, angles: Any) -> FloatArray:
        ang = np.asarray(angles, dtype=float)
        rate = np.diff(ang, axis=0) / self.dt
        ground = _lag(rate.T, np.full(2, self.k)).T
        return np.concatenate([ang[:1], ang[:1] + np.cumsum(ground * self.dt, axis=0)])


@register_effect
class TractionSlip(Effect):
    r"""Traction slip: the wheels spin up faster than the body accelerates.

    A tyre passes force to the floor through slip: the traction force grows
    with the slip speed, :math:`F = c\,(s - g)` per wheel (wheel surface speed
    ``s``, ground speed ``g``). The body's inertia ``m`` then makes the ground
    speed a first-order lag of the wheel speed,

    .. math::

        \dot g = \frac{s - g}{t_{slip}}, \qquad t_{slip} = \frac{m}{2c}, \qquad
        s - g = t_{slip}\,\dot g,

    so the slip grows with the acceleration and vanishes at constant speed:
    the encoders count the wheels' turning while the body lags behind on a
    start and runs on after a stop. Unlike ``longitudinal_slip`` (no slip
    until the friction limit) it slips at every acceleration; unlike a
    velocity-loop lag the encoders see the wheels turn at once. Realised by a
    per-wheel hook: the motors roll at the ground speed, the encoders add the
    slipped angle (and a replay driven by encoder ticks recovers the rolling
    angles by the same lag); the surrogate lags the ground speeds.
    """

    name = "traction_slip"
    robot = "diffdrive"
    stage = Stage.DRIVE
    observed_in = (Channel.POSE_GT, Channel.POSE_CAM)
    description = (
        "Tyre slip proportional to the traction force: the ground speed lags the wheel speed "
        "with time constant t_slip (s), so the wheels spin up faster than the body accelerates "
        "and the slip vanishes at constant speed. Realised between the wheel motors and encoders."
    )
    specs = (ParamSpec("t_slip", "s", 0.0, 0.0, 0.5, "tyre slip time constant m / (2 c)"),)
    blind = (BlindRange("t_slip", 0.05, 0.2, False),)
    since = 2
    surrogate_slot = SurrogateSlot.GROUND_SPEED
    surrogate_example = (("t_slip", 0.12),)

    def make_wheel_hook(
        self, dt: float, nominal: DiffDriveParams | None = None
    ) -> WheelHook | None:
        if self.is_nominal():
            return None
        return _SlipHook(float(_lag_gain(self["t_slip"], dt)), float(dt))

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        gl, gr = x
        t = p["t_slip"]
        if not np.any(t > 0):
            return gl, gr
        k = _lag_gain(t, ctx.dt)
        return tuple(_lag(np.broadcast_to(g, (k.shape[0], np.shape(g)[-1])), k) for g in (gl, gr))
