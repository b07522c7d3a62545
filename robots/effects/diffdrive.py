r"""Effects of the differential drive (``realitygap/WheeledNav-v0``).

Each effect is realised on :class:`~realitygap.robots.diffdrive.DiffDriveParams`
(a body with other radii, wheelbase, friction or camera mount), by a command or
encoder hook, or by a clock error; and each has a term in the fast kinematic
surrogate (:class:`~realitygap.diagnosis.surrogate.DiffDriveSurrogate`), which
composes the terms at the :class:`SurrogateSlot` they declare.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, replace
from enum import Enum
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
    TicksHook,
    WheelHook,
    register_effect,
)

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "AccelerationLimits",
    "CameraMountOffset",
    "CommandLatency",
    "EncoderRatio",
    "EncoderScale",
    "LongitudinalSlip",
    "MotorDeadband",
    "SurrogateContext",
    "SurrogateSlot",
    "TimestampOffset",
    "TorqueSpeedSaturation",
    "TractionSlip",
    "VelocitySaturation",
    "WheelDeadZone",
    "WheelDiameterRatio",
    "WheelRadiusScale",
    "WheelVelocityLag",
    "WheelbaseError",
    "speed_limiter_step",
    "torque_speed_step",
]


class SurrogateSlot(str, Enum):
    """Where a term enters the differential-drive surrogate, in the model's order.

    Each slot fixes the layout of the quantity its terms transform.
    """

    COMMAND_TWIST = "command_twist"
    """Applied body twist ``u``, shape (N, 2) or (B, N, 2) (m/s, rad/s)."""
    WHEEL_SPEED = "wheel_speed"
    """Firmware wheel-surface-speed commands ``(s_L, s_R)``, each (B, N), m/s."""
    ENCODER_GAIN = "encoder_gain"
    """Counted / true wheel angle ``(c_L, c_R)``, each (B,)."""
    GROUND_SPEED = "ground_speed"
    """Ground speeds of the wheels' contact points ``(g_L, g_R)`` from their surface speeds, each (B, N), m/s."""
    WHEEL_RADII = "wheel_radii"
    """True wheel radii ``(r_L, r_R)``, each (B,) or scalar, m."""
    TRACTION = "traction"
    """Tyre–floor friction coefficient ``μ``, (B,)."""
    WHEELBASE = "wheelbase"
    """True wheelbase ``b``, (B,) or scalar, m."""
    CAMERA_MOUNT = "camera_mount"
    """Camera mount ``(x, y, yaw)`` in the base frame, each (B,) or scalar (m, m, rad)."""
    STAMPS = "stamps"
    """Base pose as stamped in the ground-truth channel, (B, N, 3)."""


@dataclass(frozen=True)
class SurrogateContext:
    """What a surrogate term may need besides its input and parameters.

    Attributes
    ----------
    dt : float
        Control period, s.
    params : DiffDriveParams
        Nominal parameters (what the firmware believes).
    """

    dt: float
    params: DiffDriveParams


def _half_wheelbase(nominal: DiffDriveParams | None) -> float:
    params = nominal if nominal is not None else DiffDriveParams()
    return float(params.wheelbase) / 2.0


def _shift(u: FloatArray, steps: FloatArray) -> FloatArray:
    """Delay series ``u`` (N, k) by fractional ``steps`` (B,) → (B, N, k), zeros before the start."""
    n = u.shape[0]
    K = np.floor(steps).astype(int)
    f = (steps - K)[:, None, None]
    idx = np.arange(n)[None, :] - K[:, None]
    pad = np.concatenate([np.zeros((1, u.shape[1])), u], axis=0)  # index 0 = "before start"
    a = pad[np.clip(idx + 1, 0, n)]
    b = pad[np.clip(idx, 0, n)]
    return (1.0 - f) * a + f * b


def _shift_back(t_idx_shift: FloatArray, series: FloatArray) -> FloatArray:
    """Evaluate ``series`` (B, N, k) at fractional row ``k − shift`` (B,), clamped at both ends."""
    B, n, _ = series.shape
    pos = np.arange(n)[None, :] - t_idx_shift[:, None]
    pos = np.clip(pos, 0.0, n - 1.0)
    i0 = np.floor(pos).astype(int)
    i1 = np.minimum(i0 + 1, n - 1)
    f = (pos - i0)[..., None]
    rows = np.arange(B)[:, None]
    return (1.0 - f) * series[rows, i0] + f * series[rows, i1]


@register_effect
class WheelRadiusScale(Effect):
    """Both wheels larger or smaller than nominal; surrogate: :math:`r_{L,R} \\mathrel{*}= s`."""

    name = "wheel_radius_scale"
    robot = "diffdrive"
    stage = Stage.BODY
    observed_in = (Channel.POSE_GT, Channel.POSE_CAM)
    description = (
        "Both wheels larger or smaller than nominal (tyre wear, inflation): scales distance "
        "and rotation per wheel revolution. Realised as a body with other wheel radii."
    )
    specs = (ParamSpec("scale", "1", 1.0, 0.9, 1.1, "true radius / nominal radius, both wheels"),)
    blind = (BlindRange("scale", 0.01, 0.04, True),)
    surrogate_slot = SurrogateSlot.WHEEL_RADII
    surrogate_order = 1  # a common factor on the radii the per-wheel terms give
    surrogate_example = (("scale", 1.03),)

    def apply_params(self, params: DiffDriveParams) -> DiffDriveParams:
        s = self["scale"]
        return params.replace(
            wheel_radius_left=params.wheel_radius_left * s,
            wheel_radius_right=params.wheel_radius_right * s,
        )

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        rl, rr = x
        return rl * p["scale"], rr * p["scale"]


@register_effect
class WheelDiameterRatio(Effect):
    r"""Unequal wheel diameters at a kept mean; surrogate:
    :math:`r_L = \frac{2\bar r}{E_d + 1}\frac{r_L}{\bar r}`, :math:`r_R = \frac{2\bar r E_d}{E_d + 1}\frac{r_R}{\bar r}`."""

    name = "wheel_diameter_ratio"
    robot = "diffdrive"
    stage = Stage.BODY
    observed_in = (Channel.POSE_GT, Channel.POSE_CAM)
    description = (
        "Unequal wheel diameters, E_d = D_R / D_L (Borenstein): the robot curves when driving straight. "
        "The mean diameter is kept. Realised as a body with other wheel radii."
    )
    specs = (ParamSpec("E_d", "1", 1.0, 0.95, 1.05, "right / left wheel diameter"),)
    blind = (BlindRange("E_d", 0.004, 0.015, True),)
    surrogate_slot = SurrogateSlot.WHEEL_RADII
    surrogate_example = (("E_d", 1.01),)

    def apply_params(self, params: DiffDriveParams) -> DiffDriveParams:
        e = self["E_d"]
        mean = (params.wheel_radius_left + params.wheel_radius_right) / 2.0
        return params.replace(
            wheel_radius_left=2.0 * mean / (e + 1.0), wheel_radius_right=2.0 * mean * e / (e + 1.0)
        )

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        rl, rr = x
        e_d = p["E_d"]
        mean_r = (rl + rr) / 2.0
        return (
            2.0 * mean_r / (e_d + 1.0) * (rl / mean_r),
            2.0 * mean_r * e_d / (e_d + 1.0) * (rr / mean_r),
        )


@register_effect
class WheelbaseError(Effect):
    """Effective wheelbase off nominal; surrogate: :math:`b \\mathrel{*}= E_b`."""

    name = "wheelbase_error"
    robot = "diffdrive"
    stage = Stage.BODY
    observed_in = (Channel.POSE_GT, Channel.POSE_CAM)
    description = (
        "Effective wheelbase differs from nominal, E_b = b_actual / b_nominal: turns are "
        "over/under-rotated. Realised as a body with the wheels further apart or closer."
    )
    specs = (ParamSpec("E_b", "1", 1.0, 0.9, 1.1, "actual / nominal wheelbase"),)
    blind = (BlindRange("E_b", 0.015, 0.06, True),)
    surrogate_slot = SurrogateSlot.WHEELBASE
    surrogate_example = (("E_b", 1.04),)

    def apply_params(self, params: DiffDriveParams) -> DiffDriveParams:
        return params.replace(wheelbase=params.wheelbase * self["E_b"])

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        return x * p["E_b"]


@register_effect
class LongitudinalSlip(Effect):
    r"""Reduced traction: the wheels spin or skid when the drive asks for more force than the floor gives.

    Realised by the tyre–floor friction coefficient of the body's wheels
    (PyBullet multiplies it with the floor's 1.0). While the wheels grip,
    nothing changes; when a speed change needs more than the friction force,
    the wheel keeps turning at its commanded speed (the encoder counts it) while
    the ground speed follows at the traction limit

    .. math::

        |\dot u| \le a_{\max} = \frac{\mu g}{1 + \mu h / l},

    with ``h`` the height of the centre of mass and ``l`` the caster offset
    (load moves onto a caster under hard acceleration). The ground then lags
    the wheels after a start and runs on after a stop. In the surrogate the
    term sets the friction coefficient from which the rate limits follow.

    A *constant* creep ratio is not part of this effect on purpose: it changes
    metres per wheel revolution exactly as a wheel-radius scale does, so no log
    could tell the two apart; it is reported as ``wheel_radius_scale``.
    """

    name = "longitudinal_slip"
    robot = "diffdrive"
    stage = Stage.DRIVE
    observed_in = (Channel.POSE_GT, Channel.POSE_CAM)
    description = (
        "Reduced tyre-floor traction (dust, polished or wet floor): on hard speed changes the "
        "wheels spin or skid, so the ground moves less than the wheel rotation on a start and "
        "more on a stop. Realised as the wheels' friction coefficient."
    )
    specs = (ParamSpec("mu", "1", 1.2, 0.05, 1.2, "tyre-floor friction coefficient (nominal 1.2)"),)
    blind = (BlindRange("mu", 0.15, 0.5, False, absolute=True),)
    surrogate_slot = SurrogateSlot.TRACTION
    surrogate_example = (("mu", 0.3),)
    surrogate_tolerance = 0.35

    def apply_params(self, params: DiffDriveParams) -> DiffDriveParams:
        return params.replace(wheel_friction=self["mu"])

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        return p["mu"]


@register_effect
class CameraMountOffset(Effect):
    """Camera off its nominal mount; surrogate: the mount ``(x, y, yaw)`` plus the offsets."""

    name = "camera_mount_offset"
    robot = "diffdrive"
    stage = Stage.CAMERA
    observed_in = (Channel.POSE_CAM,)
    description = (
        "The camera is mounted off its nominal place: offset in x, y (m) and yaw (rad) in the "
        "base frame. Realised by moving the camera link of the body."
    )
    specs = (
        ParamSpec("dx", "m", 0.0, -0.03, 0.03, "forward offset"),
        ParamSpec("dy", "m", 0.0, -0.03, 0.03, "leftward offset"),
        ParamSpec("dyaw", "rad", 0.0, -0.1, 0.1, "yaw offset"),
    )
    blind = (
        BlindRange("dx", 0.005, 0.025, True),
        BlindRange("dy", 0.005, 0.025, True),
        BlindRange("dyaw", 0.01, 0.05, True),
    )
    surrogate_slot = SurrogateSlot.CAMERA_MOUNT
    surrogate_example = (("dx", 0.02), ("dy", -0.01), ("dyaw", 0.03))

    def apply_params(self, params: DiffDriveParams) -> DiffDriveParams:
        cam = params.camera
        x, y, z = cam.mount_xyz
        new_cam = replace(
            cam,
            mount_xyz=(x + self["dx"], y + self["dy"], z),
            mount_yaw=cam.mount_yaw + self["dyaw"],
        )
        return params.replace(camera=new_cam)

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        mx, my, myaw = x
        return mx + p["dx"], my + p["dy"], myaw + p["dyaw"]


@register_effect
class CommandLatency(Effect):
    r"""Commands reach the motors late; surrogate:
    :math:`u'_k = (1-f)\,u_{k-K} + f\,u_{k-K-1}` with :math:`K + f = d / dt`."""

    name = "command_latency"
    robot = "diffdrive"
    stage = Stage.COMMAND
    observed_in = (Channel.POSE_GT, Channel.TICKS, Channel.POSE_CAM)
    description = (
        "Commands reach the motors late (bus, firmware queue): a pure delay of the commanded "
        "twist. Realised as a command queue (fractional delays interpolate between steps)."
    )
    specs = (ParamSpec("delay", "s", 0.0, 0.0, 0.3, "command delay"),)
    blind = (BlindRange("delay", 0.05, 0.2, False),)
    surrogate_slot = SurrogateSlot.COMMAND_TWIST
    surrogate_example = (("delay", 0.12),)

    def make_command_hook(
        self, dt: float, nominal: DiffDriveParams | None = None
    ) -> CommandHook | None:
        delay = self["delay"]
        if delay <= 0:
            return None
        n = delay / dt
        k = int(math.floor(n))
        frac = n - k
        queue: deque[tuple[float, float]] = deque([(0.0, 0.0)] * (k + 1), maxlen=k + 2)

        def hook(v: float, w: float, dt_: float) -> tuple[float, float]:
            queue.append((v, w))
            # queue[-1] is now, queue[-1-k] is k steps ago; interpolate the fraction
            a = queue[-1 - k]
            b = queue[-2 - k] if len(queue) >= k + 2 else a
            return (1 - frac) * a[0] + frac * b[0], (1 - frac) * a[1] + frac * b[1]

        return hook

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        delay = p["delay"]
        return _shift(x, delay / ctx.dt) if np.any(delay > 0) else x


@register_effect
class MotorDeadband(Effect):
    r"""Motors stand still below a wheel-speed command; surrogate: :math:`s = 0` if :math:`|s| < δ`."""

    name = "motor_deadband"
    robot = "diffdrive"
    stage = Stage.COMMAND
    observed_in = (Channel.POSE_GT, Channel.TICKS, Channel.POSE_CAM)
    description = (
        "Motors do not turn below a minimum wheel-speed command (static friction, PWM dead zone). "
        "Realised on the firmware's wheel-speed commands (nominal geometry)."
    )
    specs = (
        ParamSpec(
            "threshold",
            "m/s",
            0.0,
            0.0,
            0.08,
            "wheel surface speed below which the wheel stays still",
        ),
    )
    blind = (BlindRange("threshold", 0.02, 0.06, False),)
    surrogate_slot = SurrogateSlot.WHEEL_SPEED
    surrogate_example = (("threshold", 0.05),)

    def make_command_hook(
        self, dt: float, nominal: DiffDriveParams | None = None
    ) -> CommandHook | None:
        thr = self["threshold"]
        if thr <= 0:
            return None
        hb = _half_wheelbase(nominal)

        def hook(v: float, w: float, dt_: float) -> tuple[float, float]:
            vl, vr = v - w * hb, v + w * hb
            vl = 0.0 if abs(vl) < thr else vl
            vr = 0.0 if abs(vr) < thr else vr
            return (vl + vr) / 2.0, (vr - vl) / (2.0 * hb)

        return hook

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        sl, sr = x
        thr = p["threshold"][:, None]
        if np.any(thr > 0):
            sl = np.where(np.abs(sl) < thr, 0.0, sl)
            sr = np.where(np.abs(sr) < thr, 0.0, sr)
        return sl, sr


@register_effect
class VelocitySaturation(Effect):
    r"""The drive tops out below its rating; surrogate: :math:`s \in [-s_{max}, s_{max}]`.

    The physical range reaches down to a crawl (0.05 m/s): a top speed far below
    anything the logs command (a tired battery, a firmware cap) is a value the fit
    can reach, not one outside its range.
    """

    name = "velocity_saturation"
    robot = "diffdrive"
    stage = Stage.COMMAND
    observed_in = (Channel.POSE_GT, Channel.TICKS, Channel.POSE_CAM)
    description = (
        "The drive reaches a lower top speed than specified (weak battery, motor limit). "
        "Realised by clipping the firmware's wheel-speed commands (nominal geometry)."
    )
    specs = (
        ParamSpec(
            "v_limit", "m/s", 10.0, 0.05, 10.0, "largest wheel surface speed actually reached"
        ),
    )
    blind = (BlindRange("v_limit", 0.35, 0.55, False, absolute=True),)
    surrogate_slot = SurrogateSlot.WHEEL_SPEED
    surrogate_example = (("v_limit", 0.45),)

    def make_command_hook(
        self, dt: float, nominal: DiffDriveParams | None = None
    ) -> CommandHook | None:
        lim = self["v_limit"]
        if lim >= self.spec("v_limit").nominal:
            return None
        hb = _half_wheelbase(nominal)

        def hook(v: float, w: float, dt_: float) -> tuple[float, float]:
            vl, vr = v - w * hb, v + w * hb
            vl, vr = max(-lim, min(lim, vl)), max(-lim, min(lim, vr))
            return (vl + vr) / 2.0, (vr - vl) / (2.0 * hb)

        return hook

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        sl, sr = x
        v_lim = p["v_limit"][:, None]
        if np.any(v_lim < 9.99):
            sl = np.clip(sl, -v_lim, v_lim)
            sr = np.clip(sr, -v_lim, v_lim)
        return sl, sr


@register_effect
class EncoderScale(Effect):
    """Both encoders count off by a factor; surrogate: :math:`c_{L,R} \\mathrel{*}= s`."""

    name = "encoder_scale"
    robot = "diffdrive"
    stage = Stage.SENSOR
    observed_in = (Channel.TICKS,)
    description = (
        "Encoders count more or fewer ticks per revolution than specified (wrong gear ratio in "
        "firmware). Realised between the wheel joints and the encoder reading."
    )
    specs = (ParamSpec("scale", "1", 1.0, 0.9, 1.1, "counted / specified ticks per revolution"),)
    blind = (BlindRange("scale", 0.01, 0.04, True),)
    surrogate_slot = SurrogateSlot.ENCODER_GAIN
    surrogate_example = (("scale", 0.97),)

    def make_ticks_hook(self) -> TicksHook | None:
        s = self["scale"]
        if s == 1.0:
            return None
        return lambda left, right: (left * s, right * s)

    def make_ticks_inverse_hook(self) -> TicksHook | None:
        s = self["scale"]
        if s == 1.0:
            return None
        return lambda left, right: (left / s, right / s)

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        cl, cr = x
        return cl * p["scale"], cr * p["scale"]


@register_effect
class TimestampOffset(Effect):
    """Ground-truth clock offset; surrogate: the pose sampled ``offset`` earlier."""

    name = "timestamp_offset"
    robot = "diffdrive"
    stage = Stage.TIMING
    observed_in = (Channel.POSE_GT,)
    description = (
        "The ground-truth (motion-capture) clock is offset from the robot's clock: each "
        "ground-truth sample is stamped `offset` seconds late. Realised by the recorder."
    )
    specs = (ParamSpec("offset", "s", 0.0, -0.3, 0.3, "ground-truth stamp minus true time"),)
    blind = (BlindRange("offset", 0.04, 0.2, True),)
    surrogate_slot = SurrogateSlot.STAMPS
    surrogate_example = (("offset", 0.08),)

    def channel_time_offsets(self) -> dict[str, float]:
        return {Channel.POSE_GT.value: self["offset"]} if self["offset"] != 0.0 else {}

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        off = p["offset"]
        return _shift_back(off / ctx.dt, x) if np.any(off != 0) else x


@register_effect
class EncoderRatio(Effect):
    r"""The two encoders count differently per wheel revolution, the mean kept.

    A real drive gets there with encoders of different resolution on the two
    sides, a gearbox of another ratio on one side, or a code disc slipping on
    its shaft: the body moves as commanded, only the counts disagree. With
    :math:`E_c = c_R / c_L` (right over left counts per revolution),

    .. math::

        c_L = \frac{2}{E_c + 1}, \qquad c_R = \frac{2 E_c}{E_c + 1}.

    Realised between the wheel joints and the encoder reading (invertible, so
    a tick-driven replay can include it); the surrogate multiplies the encoder
    gains by the same factors.
    """

    name = "encoder_ratio"
    robot = "diffdrive"
    stage = Stage.SENSOR
    observed_in = (Channel.TICKS,)
    description = (
        "The right encoder counts E_c times as many ticks per wheel revolution as the left one "
        "(mixed encoder resolutions or gear ratios, a slipping code disc); the mean count is kept. "
        "Realised between the wheel joints and the encoder reading."
    )
    specs = (ParamSpec("E_c", "1", 1.0, 0.9, 1.1, "right / left counts per wheel revolution"),)
    blind = (BlindRange("E_c", 0.01, 0.04, True),)
    since = 2
    surrogate_slot = SurrogateSlot.ENCODER_GAIN
    surrogate_example = (("E_c", 1.03),)

    def _gains(self) -> tuple[float, float]:
        e = self["E_c"]
        return 2.0 / (e + 1.0), 2.0 * e / (e + 1.0)

    def make_ticks_hook(self) -> TicksHook | None:
        if self["E_c"] == 1.0:
            return None
        gl, gr = self._gains()
        return lambda left, right: (left * gl, right * gr)

    def make_ticks_inverse_hook(self) -> TicksHook | None:
        if self["E_c"] == 1.0:
            return None
        gl, gr = self._gains()
        return lambda left, right: (left / gl, right / gr)

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        cl, cr = x
        e = p["E_c"]
        if not np.any(e != 1.0):
            return cl, cr
        return cl * (2.0 / (e + 1.0)), cr * (2.0 * e / (e + 1.0))


# --------------------------------------------------------------------------- drive train
# The drive-train family acts on the firmware's wheel-surface-speed commands
# (or on its body twist) with state carried from one control period to the next.
# One vectorised step function per effect serves the PyBullet hook (a batch of
# one) and the surrogate term (a batch of parameter sets), so both realise the
# same law.


def _wheel_command_hook(
    nominal: DiffDriveParams | None,
    step: Any,
) -> CommandHook:
    """A twist hook that applies ``step(s_L, s_R, dt) -> (s_L, s_R)`` to the wheel-speed commands.

    The firmware's inverse kinematics (nominal half wheelbase ``b/2``) is linear
    and invertible, so the hook returns the twist that the firmware turns into
    the changed wheel-surface speeds (m/s).
    """
    hb = _half_wheelbase(nominal)

    def hook(v: float, w: float, dt_: float) -> tuple[float, float]:
        sl, sr = step(v - w * hb, v + w * hb, dt_)
        sl, sr = float(sl), float(sr)
        return (sl + sr) / 2.0, (sr - sl) / (2.0 * hb)

    return hook


def _lag_gain(tau: Any, dt: float) -> Any:
    r"""Share of the remaining error a first-order lag closes in one period, :math:`1 - e^{-dt/τ}`."""
    tau = np.asarray(tau, dtype=float)
    with np.errstate(divide="ignore", over="ignore"):
        return np.where(tau > 0.0, -np.expm1(-dt / np.where(tau > 0.0, tau, 1.0)), 1.0)


def _inverse_rate(t_per_unit: Any) -> Any:
    """Rate limit from its inverse (time per unit change): ``1 / t``, infinite at ``t = 0``."""
    t = np.asarray(t_per_unit, dtype=float)
    with np.errstate(divide="ignore"):
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


def _wheel_gains(ratio: Any) -> tuple[Any, Any]:
    """Left and right gains with right / left ``ratio`` and their mean 1."""
    return 2.0 / (ratio + 1.0), 2.0 * ratio / (ratio + 1.0)


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
    for row, gain in enumerate(kk):
        y[row] = x[row] if gain >= 1.0 else lfilter([gain], [1.0, gain - 1.0], x[row])
    return y


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
        kl, kr = _lag_gain(self["tau_left"], dt), _lag_gain(self["tau_right"], dt)
        state = [0.0, 0.0]

        def step(sl: float, sr: float, dt_: float) -> tuple[float, float]:
            state[0] += float(kl) * (sl - state[0])
            state[1] += float(kr) * (sr - state[1])
            return state[0], state[1]

        return _wheel_command_hook(nominal, step)

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        sl, sr = x
        tl, tr = p["tau_left"], p["tau_right"]
        if not (np.any(tl > 0) or np.any(tr > 0)):
            return sl, sr
        out = []
        for s, tau in ((sl, tl), (sr, tr)):
            kk = _lag_gain(tau, ctx.dt)
            out.append(_lag(np.broadcast_to(s, (kk.shape[0], np.shape(s)[-1])), kk))
        return out[0], out[1]


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
    r"""Per-wheel dead zones and a gain asymmetry of the two motor drives.

    Each wheel stands still while its commanded surface speed is below its
    own threshold (static friction, a PWM dead zone differing between the two
    drivers), and the right drive turns ``G`` times as fast as the left one
    for the same command (mean gain kept):

    .. math::

        s'_L = \frac{2}{G+1}\,s_L\,[|s_L| \ge δ_L], \qquad
        s'_R = \frac{2G}{G+1}\,s_R\,[|s_R| \ge δ_R].

    Unlike ``motor_deadband`` (one threshold for both wheels) the wheels
    differ: a slow turn pivots on the wheel whose threshold is not reached,
    and the gain asymmetry turns the encoder rates as well as the body (a
    wheel-diameter ratio leaves the rates alone). The gain ratio alone is an
    alias of ``wheel_diameter_ratio`` with ``E_d = G`` together with
    ``encoder_ratio`` with ``E_c = G`` (the same ground and count ratios); only
    the dead zones tell this effect from that pair. Realised on the firmware's
    wheel-speed commands.
    """

    name = "wheel_dead_zone"
    robot = "diffdrive"
    stage = Stage.COMMAND
    observed_in = (Channel.POSE_GT, Channel.TICKS, Channel.POSE_CAM)
    description = (
        "Per-wheel dead zones (m/s: a wheel commanded below its threshold does not turn) and a "
        "right / left drive-gain ratio G (mean gain kept). Realised on the firmware's wheel-speed "
        "commands (nominal geometry)."
    )
    specs = (
        ParamSpec("dz_left", "m/s", 0.0, 0.0, 0.08, "left wheel dead zone (surface speed)"),
        ParamSpec("dz_right", "m/s", 0.0, 0.0, 0.08, "right wheel dead zone (surface speed)"),
        ParamSpec("gain_ratio", "1", 1.0, 0.9, 1.1, "right / left wheel speed per command"),
    )
    blind = (
        BlindRange("dz_left", 0.0, 0.06, False),
        BlindRange("dz_right", 0.0, 0.06, False),
        BlindRange("gain_ratio", 0.01, 0.04, True),
    )
    since = 2
    surrogate_slot = SurrogateSlot.WHEEL_SPEED
    surrogate_order = 1
    surrogate_example = (("dz_left", 0.06), ("dz_right", 0.01), ("gain_ratio", 1.03))

    @staticmethod
    def _apply(sl: Any, sr: Any, dzl: Any, dzr: Any, ratio: Any) -> tuple[Any, Any]:
        gl, gr = _wheel_gains(ratio)
        sl = np.where(np.abs(sl) < dzl, 0.0, sl * gl)
        sr = np.where(np.abs(sr) < dzr, 0.0, sr * gr)
        return sl, sr

    def make_command_hook(
        self, dt: float, nominal: DiffDriveParams | None = None
    ) -> CommandHook | None:
        if self.is_nominal():
            return None
        dzl, dzr, g = self["dz_left"], self["dz_right"], self["gain_ratio"]
        return _wheel_command_hook(nominal, lambda sl, sr, dt_: self._apply(sl, sr, dzl, dzr, g))

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        sl, sr = x
        dzl, dzr, g = p["dz_left"], p["dz_right"], p["gain_ratio"]
        if not (np.any(dzl > 0) or np.any(dzr > 0) or np.any(g != 1.0)):
            return sl, sr
        return cls._apply(sl, sr, dzl[:, None], dzr[:, None], g[:, None])


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
        self.ground = np.zeros(2)
        self.slip = np.zeros(2)

    def command(self, w_left: float, w_right: float) -> tuple[float, float]:
        turned = np.array([w_left, w_right], dtype=float)
        self.ground = self.ground + self.k * (turned - self.ground)
        self.slip = self.slip + (turned - self.ground) * self.dt
        return float(self.ground[0]), float(self.ground[1])

    def encoder(self, a_left: float, a_right: float) -> tuple[float, float]:
        return a_left + float(self.slip[0]), a_right + float(self.slip[1])

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
