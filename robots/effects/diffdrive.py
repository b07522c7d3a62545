r"""Effects of the differential drive (``realitygap/WheeledNav-v0``).

Each effect is realised on :class:`~realitygap.robots.diffdrive.DiffDriveParams`
(a body with other radii, wheelbase, friction or camera mount), by a command or
encoder hook, or by a clock error; and each has a term in the fast kinematic
surrogate (:class:`~realitygap.robots.diffdrive_surrogate.DiffDriveSurrogate`), which
composes the terms at the :class:`SurrogateSlot` they declare. The drive-train
family (wheel lags, acceleration limits, per-wheel dead zones, torque–speed
saturation, traction slip) lives in
:mod:`~realitygap.robots.effects.diffdrive_drivetrain`.
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

from realitygap.core.geometry import reframe_track
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects.base import (
    BlindRange,
    Channel,
    CommandHook,
    Effect,
    ParamSpec,
    Stage,
    TicksHook,
    register_effect,
    register_robot,
)

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "CameraMountOffset",
    "CommandLatency",
    "EncoderRatio",
    "EncoderScale",
    "LongitudinalSlip",
    "MotorDeadband",
    "SurrogateContext",
    "SurrogateSlot",
    "TimestampOffset",
    "TruthFrameOffset",
    "VelocitySaturation",
    "WheelDiameterRatio",
    "WheelRadiusScale",
    "WheelbaseError",
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


def _wheel_gains(ratio: Any) -> tuple[Any, Any]:
    """Left and right gains with right / left ``ratio`` and their mean 1."""
    return 2.0 / (ratio + 1.0), 2.0 * ratio / (ratio + 1.0)


def _shift(u: FloatArray, steps: FloatArray) -> FloatArray:
    """Delay series ``u`` (N, k) by fractional ``steps`` (B,) → (B, N, k), zeros before the start.

    One delay shared by the whole batch is computed once, (1, N, k), and broadcasts.
    """
    steps = np.asarray(steps, dtype=float)
    if steps.size > 1 and np.all(steps == steps[0]):
        steps = steps[:1]
    n = u.shape[0]
    K = np.floor(steps).astype(int)
    f = (steps - K)[:, None, None]
    idx = np.arange(n)[None, :] - K[:, None]
    pad = np.concatenate([np.zeros((1, u.shape[1])), u], axis=0)  # index 0 = "before start"
    a = pad[np.clip(idx + 1, 0, n)]
    b = pad[np.clip(idx, 0, n)]
    return (1.0 - f) * a + f * b


def _shift_back(t_idx_shift: FloatArray, series: FloatArray) -> FloatArray:
    """Evaluate ``series`` (B, N, k) at fractional row ``k − shift`` (B,), clamped at both ends.

    One shift shared by the whole batch gathers the same rows of every entry (a plain
    take along the time axis instead of a per-entry gather): the same values, faster.
    """
    B, n, _ = series.shape
    shift = np.asarray(t_idx_shift, dtype=float)
    if shift.size > 1 and np.all(shift == shift[0]):
        pos = np.clip(np.arange(n) - shift[0], 0.0, n - 1.0)
        i0 = np.floor(pos).astype(int)
        i1 = np.minimum(i0 + 1, n - 1)
        f = (pos - i0)[None, :, None]
        return (1.0 - f) * series[:, i0] + f * series[:, i1]
    pos = np.arange(n)[None, :] - shift[:, None]
    pos = np.clip(pos, 0.0, n - 1.0)
    i0 = np.floor(pos).astype(int)
    i1 = np.minimum(i0 + 1, n - 1)
    f = (pos - i0)[..., None]
    rows = np.arange(B)[:, None]
    return (1.0 - f) * series[rows, i0] + f * series[rows, i1]


register_robot("diffdrive", "realitygap.robots.diffdrive.DiffDriveParams")


@register_effect
class WheelRadiusScale(Effect):
    """Both wheels larger or smaller than nominal; surrogate: :math:`r_{L,R} \\mathrel{*}= s`."""

    name = "wheel_radius_scale"
    scale = "run"
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
    scale = "run"
    robot = "diffdrive"
    stage = Stage.BODY
    observed_in = (Channel.POSE_GT, Channel.POSE_CAM)
    description = (
        "Unequal wheel diameters, E_d = D_R / D_L (Borenstein): the robot curves when driving straight. "
        "The mean diameter is kept. Realised as a body with other wheel radii."
    )
    specs = (ParamSpec("E_d", "1", 1.0, 0.9, 1.1, "right / left wheel diameter"),)
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
    scale = "run"
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
        return _wheel_command_hook(
            nominal,
            lambda vl, vr, dt_: (0.0 if abs(vl) < thr else vl, 0.0 if abs(vr) < thr else vr),
        )

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
            "v_limit",
            "m/s",
            10.0,
            0.05,
            10.0,
            "largest wheel surface speed actually reached",
            log_scale=True,
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
        return _wheel_command_hook(
            nominal,
            lambda vl, vr, dt_: (max(-lim, min(lim, vl)), max(-lim, min(lim, vr))),
        )

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
    scale = "run"
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
    """Ground-truth clock offset; surrogate: the pose sampled ``offset`` earlier.

    The range stops at ±0.3 s. No physics bounds an offset between two clocks, but a wider
    range lets the offset compensate: on the independent generator's out-of-round encoder
    disc (``diagnose-independent --variant large``), a 0.31 s offset beside a traction
    lag closed the held-out gap above noise, a false attribution that ±0.3 s refuses. A
    larger offset is pinned at the edge and the verdict says so ("unexplained").
    """

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
    scale = "run"
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

    def make_ticks_hook(self) -> TicksHook | None:
        if self["E_c"] == 1.0:
            return None
        gl, gr = _wheel_gains(self["E_c"])
        return lambda left, right: (left * gl, right * gr)

    def make_ticks_inverse_hook(self) -> TicksHook | None:
        if self["E_c"] == 1.0:
            return None
        gl, gr = _wheel_gains(self["E_c"])
        return lambda left, right: (left / gl, right / gr)

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        cl, cr = x
        e = p["E_c"]
        if not np.any(e != 1.0):
            return cl, cr
        gl, gr = _wheel_gains(e)
        return cl * gl, cr * gr


@register_effect
class TruthFrameOffset(Effect):
    r"""The ground truth tracks a frame a little off the axle centre and the forward axis.

    A motion-capture rigid body is defined by hand on the robot: its origin
    lands some millimetres from the centre of the axle and its heading some
    milliradians from the direction the wheels roll. The channel then records
    :math:`A_k ⊕ F` for the axle poses :math:`A_k` and :math:`F = (x, y, ψ)`:
    on every straight leg the recorded motion crabs sideways by :math:`ψ` per
    metre, and on every turn in place the recorded origin circles the axle.
    Realised by the recorder; the surrogate transforms its stamped track the
    same way (:func:`~realitygap.core.geometry.reframe_track`, one definition).
    The calibrated baseline fits it within the setup's convention (a few
    centimetres of the axle centre) or within the uncertainty of a declared
    tracked point; a tracked point further off — a marker on a mast, a camera at
    the back of a large platform, up to half a metre — is this effect of the
    library, named with its offset.
    """

    name = "truth_frame_offset"
    robot = "diffdrive"
    stage = Stage.SENSOR
    observed_in = (Channel.POSE_GT,)
    description = (
        "The ground-truth channel tracks a body frame offset from the axle centre by (x, y) "
        "and turned by yaw from the forward axis (a motion-capture rigid body defined by hand). "
        "Realised by the recorder."
    )
    specs = (
        ParamSpec("x", "m", 0.0, -0.5, 0.5, "tracked origin ahead of the axle centre"),
        ParamSpec("y", "m", 0.0, -0.5, 0.5, "tracked origin left of the axle centre"),
        ParamSpec("yaw", "rad", 0.0, -0.2, 0.2, "tracked heading minus the rolling direction"),
    )
    since = 3
    surrogate_slot = SurrogateSlot.STAMPS
    surrogate_order = -1
    surrogate_example = (("x", 0.03), ("y", -0.02), ("yaw", 0.05))

    def channel_frames(self) -> dict[str, tuple[float, float, float]]:
        frame = (self["x"], self["y"], self["yaw"])
        return {Channel.POSE_GT.value: frame} if any(frame) else {}

    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, FloatArray], ctx: SurrogateContext) -> Any:
        frame = np.stack(np.broadcast_arrays(p["x"], p["y"], p["yaw"]), axis=-1)
        if not np.any(frame):
            return x
        return reframe_track(x, frame)
