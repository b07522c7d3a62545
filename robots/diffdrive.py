"""A Kobuki-like differential-drive robot with a Kinect-V2-like RGB-D camera.

The body is generated as URDF from :class:`DiffDriveParams`, so a robot with
another wheel radius or wheelbase really is another body in the simulation.
Frames: ``base`` at the midpoint of the wheel axle on the floor, x forward,
y left, z up; the camera's optical frame is x right, y down, z forward.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from enum import Enum
from functools import partial
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt
import pybullet as p

from realitygap.core.geometry import check_finite
from realitygap.core.jit import KERNELS, compiled, use_compiled
from realitygap.estimators.base import CameraIntrinsics, WheelTicks
from realitygap.robots.world import World

if TYPE_CHECKING:
    from realitygap.robots.effects import Reality, WheelHook

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class RGBDCameraParams:
    """Kinect-V2-like time-of-flight RGB-D camera.

    Mounting ``mount_xyz`` (m) and ``mount_yaw`` / ``mount_pitch`` (rad) of the
    optical centre in the base frame; 70.6° × 60° field of view; depth valid in
    ``[range_min, range_max]`` with noise ``σ(z) = depth_noise_a + depth_noise_b·z²``
    (≈ 2 cm at 3 m).
    """

    width: int = 320
    height: int = 240
    hfov_deg: float = 70.6
    vfov_deg: float = 60.0
    range_min: float = 0.5
    range_max: float = 8.0
    depth_noise_a: float = 0.001
    depth_noise_b: float = 0.002
    mount_xyz: tuple[float, float, float] = (0.0, 0.0, 0.30)
    mount_yaw: float = 0.0
    mount_pitch: float = 0.0
    rate_hz: float = 20.0

    def intrinsics(self) -> CameraIntrinsics:
        """Pinhole intrinsics that give the stated field of view at this resolution."""
        fx = (self.width / 2.0) / math.tan(math.radians(self.hfov_deg) / 2.0)
        fy = (self.height / 2.0) / math.tan(math.radians(self.vfov_deg) / 2.0)
        return CameraIntrinsics(
            self.width, self.height, fx, fy, self.width / 2.0, self.height / 2.0
        )

    def T_base_camera(self) -> FloatArray:
        """4×4 pose of the optical frame in the base frame."""
        cy, sy = math.cos(self.mount_yaw), math.sin(self.mount_yaw)
        cp, sp = math.cos(self.mount_pitch), math.sin(self.mount_pitch)
        R_yaw = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1.0]])
        R_pitch = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
        # optical axes expressed in a forward-looking body frame: z fwd, x right, y down
        R_opt = np.array([[0, 0, 1.0], [-1.0, 0, 0], [0, -1.0, 0]])
        T = np.eye(4)
        T[:3, :3] = R_yaw @ R_pitch @ R_opt
        T[:3, 3] = self.mount_xyz
        return T


PARAM_RANGES: dict[str, tuple[float, float, str]] = {
    "wheel_radius_left": (1e-3, 2.0, "m"),
    "wheel_radius_right": (1e-3, 2.0, "m"),
    "wheelbase": (1e-2, 10.0, "m"),
    "wheel_width": (1e-4, 1.0, "m"),
    "body_radius": (5e-3, 10.0, "m"),
    "body_height": (5e-3, 10.0, "m"),
    "body_mass": (1e-2, 1e4, "kg"),
    "wheel_mass": (1e-3, 1e3, "kg"),
    "caster_radius": (5e-4, 1.0, "m"),
    "caster_offset": (5e-4, 10.0, "m"),
    "wheel_friction": (1e-3, 10.0, "1"),
    "motor_max_torque": (1e-4, 1e4, "N·m"),
    "ticks_per_rev": (1.0, 1e8, "ticks"),
    "v_max": (1e-3, 100.0, "m/s"),
    "w_max": (1e-3, 100.0, "rad/s"),
    "a_max": (1e-3, 1e3, "m/s²"),
    "alpha_max": (1e-3, 1e4, "rad/s²"),
}
"""Physical range and unit of each number of :class:`DiffDriveParams`: wide enough for any
wheeled base from a toy to a truck, narrow enough to catch a wrong unit (a radius in mm given
as m is 1000× too large)."""


def check_param(name: str, value: object, prefix: str = "") -> float:
    """``value`` of the :class:`DiffDriveParams` field ``name`` as a float, or a
    ``ValueError`` naming it, its unit and physical range, what came and the fix.

    A bool, text or ``None`` is no number; NaN, infinity and values outside
    :data:`PARAM_RANGES` are refused.
    """
    low, high, unit = PARAM_RANGES[name]
    number = isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )
    x = float(value) if number else math.nan  # type: ignore[arg-type]
    if not (number and low <= x <= high):
        got = f"{value!r}" if number else f"{value!r} ({type(value).__name__})"
        hint = (
            " (a length in mm given as m is 1000× too large)"
            if unit == "m" and number and x > high
            else ""
        )
        raise ValueError(
            f"{prefix}{name} must be a number in [{low:g}, {high:g}] {unit} (SI units), got "
            f"{got}{hint}. Fix: give {name} in {unit}"
        )
    return x


@dataclass(frozen=True)
class DiffDriveParams:
    """Physical parameters of a Kobuki-like base, SI units.

    Defaults follow the Yujin Kobuki: wheel radius 35 mm, wheelbase 230 mm,
    0.70 m/s and 180 °/s, ≈ 2578 encoder ticks per wheel revolution.
    """

    wheel_radius_left: float = 0.035
    wheel_radius_right: float = 0.035
    wheelbase: float = 0.230
    wheel_width: float = 0.021
    body_radius: float = 0.176
    body_height: float = 0.09
    body_mass: float = 2.35
    wheel_mass: float = 0.10
    caster_radius: float = 0.012
    caster_offset: float = 0.115
    wheel_friction: float = 1.2
    motor_max_torque: float = 0.35
    ticks_per_rev: float = 2578.33
    v_max: float = 0.70
    w_max: float = math.pi
    a_max: float = 1.0
    alpha_max: float = 4.0
    camera: RGBDCameraParams = field(default_factory=RGBDCameraParams)

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name in PARAM_RANGES:
                check_param(f.name, getattr(self, f.name), "DiffDriveParams.")
        if self.wheelbase <= self.wheel_width:
            raise ValueError(
                f"wheelbase ({self.wheelbase} m) must exceed the wheel width ({self.wheel_width} m)"
            )

    def replace(self, **changes: object) -> DiffDriveParams:
        """A copy with ``changes`` applied (validated)."""
        return replace(self, **changes)  # type: ignore[arg-type]

    @property
    def max_wheel_speed(self) -> float:
        """Largest wheel angular speed in rad/s needed by the velocity limits."""
        r = min(self.wheel_radius_left, self.wheel_radius_right)
        return (self.v_max + self.w_max * self.wheelbase / 2.0) / r


class Ramp(str, Enum):
    """What a firmware's rate limiter ramps."""

    BODY = "body"
    """The body twist ``(v, ω)`` (ros2 ``diff_drive_controller``'s speed limiter,
    ``yocs_velocity_smoother``)."""
    WHEELS = "wheels"
    """Each wheel's speed set-point (many motor-driver firmwares)."""


class Deceleration(str, Enum):
    """How a firmware's rate limiter treats slowing down."""

    LIMITED = "limited"
    """Slowing down is rate-limited too, at ``decel_factor`` times the acceleration limit."""
    FREE = "free"
    """Only speeding up is limited; a move towards standstill passes at once."""
    STOP = "stop"
    """Rate-limited both ways, but a request of exactly zero (``v = ω = 0``) is a stop
    command: the set-points drop to zero at once, as firmwares that take a zero twist
    for a brake do (``yocs_velocity_smoother`` tests for the zero twist by name)."""


@dataclass(frozen=True)
class FirmwareLimits:
    """Speed and acceleration limits the base's firmware applies to a commanded twist.

    Each control period the twist request ``(v, ω)`` is clipped to
    ``|v| ≤ v_max``, ``|ω| ≤ w_max`` and then moved from the previously applied
    twist by at most ``a_max·dt`` and ``alpha_max·dt`` (:meth:`step` applies the
    convention ``ramp`` / ``deceleration``; :meth:`limit` and
    :meth:`limit_wheels` are its body and wheel ramps). An infinite limit is no
    limit.

    Parameters
    ----------
    v_max : float
        Largest forward speed, m/s.
    w_max : float
        Largest turn rate, rad/s.
    a_max : float
        Largest forward acceleration, m/s² (with the wheel ramp: a wheel's surface
        acceleration).
    alpha_max : float
        Largest angular acceleration, rad/s² (not used by the wheel ramp).
    ramp : Ramp
        What is ramped: the body twist (default) or each wheel's set-point.
    deceleration : Deceleration
        Slowing down limited (default), free, or limited with a zero request
        stopping at once.
    decel_factor : float
        Deceleration limit over acceleration limit (``yocs_velocity_smoother``'s
        ``decel_factor``; ros2 ``diff_drive_controller`` states ``max_deceleration``
        apart), used when slowing down is limited; 1 by default.
    """

    v_max: float = math.inf
    w_max: float = math.inf
    a_max: float = math.inf
    alpha_max: float = math.inf
    ramp: Ramp = Ramp.BODY
    deceleration: Deceleration = Deceleration.LIMITED
    decel_factor: float = 1.0

    def __post_init__(self) -> None:
        for name in ("v_max", "w_max", "a_max", "alpha_max", "decel_factor"):
            value = getattr(self, name)
            if not value > 0.0:
                raise ValueError(
                    f"FirmwareLimits.{name} must be positive (inf: no limit), got {value!r}"
                )
        try:
            object.__setattr__(self, "ramp", Ramp(self.ramp))
            object.__setattr__(self, "deceleration", Deceleration(self.deceleration))
        except ValueError:
            raise ValueError(
                f"FirmwareLimits: ramp must be one of {[r.value for r in Ramp]} and deceleration "
                f"one of {[d.value for d in Deceleration]}, got ramp {self.ramp!r}, "
                f"deceleration {self.deceleration!r}"
            ) from None

    @classmethod
    def from_mapping(cls, values: Mapping[str, object], name: str = "firmware") -> FirmwareLimits:
        """The limits a user states (``--firmware``, a robot file): known keys only, each limit
        a positive number (``inf``: none); a ``ValueError`` naming ``name`` and the key
        otherwise."""
        if not isinstance(values, Mapping):
            raise ValueError(
                f"{name} must be a mapping of limits (e.g. {{'a_max': 1.0}}), got "
                f"{type(values).__name__}"
            )
        known = [f.name for f in fields(cls)]
        unknown = sorted(set(map(str, values)) - set(known))
        if unknown:
            raise ValueError(
                f"{name}: unknown key(s) {unknown}; known: {', '.join(known)}. Fix: use those names"
            )
        kwargs: dict[str, object] = {}
        for key, value in values.items():
            if key in ("ramp", "deceleration"):
                kwargs[key] = value
                continue
            ok = isinstance(value, int | float | np.integer | np.floating) and not isinstance(
                value, bool | np.bool_
            )
            if not ok or not float(value) > 0.0:  # type: ignore[arg-type]
                raise ValueError(
                    f"{name}: {key} must be a positive number (inf: no limit), got {value!r}. "
                    f"Fix: give {key} in SI units, e.g. {key}=1.0"
                )
            kwargs[key] = float(value)  # type: ignore[arg-type]
        try:
            return cls(**kwargs)  # type: ignore[arg-type]
        except ValueError as exc:
            raise ValueError(f"{name}: {exc}") from None

    @property
    def convention(self) -> str:
        """``"<ramp>/<deceleration>"``, e.g. ``"body/stop"``."""
        return f"{self.ramp.value}/{self.deceleration.value}"

    def step(
        self, v: float, w: float, v_prev: float, w_prev: float, dt: float, wheelbase: float
    ) -> tuple[float, float]:
        r"""The twist (m/s, rad/s) applied for request ``(v, w)`` under this firmware's convention.

        With ``deceleration`` :attr:`Deceleration.STOP` a request of exactly
        ``(0, 0)`` gives ``(0, 0)`` at once; otherwise :meth:`limit` (body ramp)
        or :meth:`limit_wheels` (wheel ramp, ``wheelbase`` in m) with free
        deceleration when ``deceleration`` is :attr:`Deceleration.FREE`.
        ``dt`` is the control period in s.
        """
        # module constants: cheaper than the Enum classes' attribute lookups, once per step
        deceleration = self.deceleration
        if deceleration is _STOP and v == 0.0 and w == 0.0:
            return 0.0, 0.0
        free = deceleration is _FREE
        if self.ramp is _WHEELS:
            return self.limit_wheels(v, w, v_prev, w_prev, dt, wheelbase, free_deceleration=free)
        return self.limit(v, w, v_prev, w_prev, dt, free_deceleration=free)

    def bound(
        self, dt: float, wheelbase: float
    ) -> Callable[[float, float, float, float], tuple[float, float]]:
        """:meth:`step` for the control period ``dt`` (s) and nominal ``wheelbase`` (m) of an
        episode, as a function of ``(v, w, v_prev, w_prev)``: the body ramp's steps are
        computed once, the same values as :meth:`limit` computes at every call."""
        if self.ramp is _WHEELS or self.deceleration is _STOP:
            step = self.step
            return lambda v, w, v_prev, w_prev: step(v, w, v_prev, w_prev, dt, wheelbase)
        free = self.deceleration is _FREE
        v_max, w_max, f = self.v_max, self.w_max, self.decel_factor
        dv, dv_slow = self.a_max * dt, f * self.a_max * dt
        dw, dw_slow = self.alpha_max * dt, f * self.alpha_max * dt
        # the episode's constants bound in front (a C-level partial: no Python frame of its
        # own), to the compiled twin where the compiled kernels are in use (the same bits)
        ramp = (
            _body_ramp_compiled
            if _body_ramp_compiled is not None and use_compiled()
            else _body_ramp
        )
        return partial(ramp, v_max, w_max, dv, dv_slow, dw, dw_slow, free)

    @classmethod
    def from_params(cls, params: DiffDriveParams) -> FirmwareLimits:
        """The limits stated in ``params`` (``v_max``, ``w_max``, ``a_max``, ``alpha_max``)."""
        return cls(params.v_max, params.w_max, params.a_max, params.alpha_max)

    def applied(self, requests: npt.ArrayLike, dt: float, wheelbase: float) -> FloatArray:
        """The twists applied for a sequence of requests (N, 2) [m/s, rad/s], from rest.

        :meth:`step` row by row, each row's result the previous twist of the next;
        ``dt`` is the control period (s), ``wheelbase`` the nominal one (m).
        """
        req = np.asarray(requests, dtype=float)
        if req.ndim != 2 or req.shape[-1] != 2:
            raise ValueError(f"FirmwareLimits.applied: requests must be (N, 2), got {req.shape}")
        if _applied_rows_compiled is not None and use_compiled():
            return _applied_rows_compiled(
                np.ascontiguousarray(req),
                float(dt),
                float(wheelbase),
                self.v_max,
                self.w_max,
                self.a_max,
                self.alpha_max,
                self.decel_factor,
                self.ramp is _WHEELS,
                self.deceleration is _STOP,
                self.deceleration is _FREE,
            )
        out = np.empty_like(req)
        v = w = 0.0
        for k in range(req.shape[0]):
            v, w = self.step(float(req[k, 0]), float(req[k, 1]), v, w, dt, wheelbase)
            out[k, 0], out[k, 1] = v, w
        return out

    def limit(
        self,
        v: float,
        w: float,
        v_prev: float,
        w_prev: float,
        dt: float,
        *,
        free_deceleration: bool = False,
    ) -> tuple[float, float]:
        r"""The twist (m/s, rad/s) applied for request ``(v, w)`` after ``(v_prev, w_prev)``.

        .. math::

            v_k = v_{k-1} + \operatorname{clip}(\operatorname{clip}(v, \pm v_{max})
                  - v_{k-1}, \pm a_{max}\,\Delta t)

        and likewise for ω with ``w_max`` and ``alpha_max``; ``dt`` is the
        control period in s. Slowing down is limited by ``decel_factor`` times
        the acceleration limit. With ``free_deceleration`` only speeding up is
        limited (:func:`ramp_step`): slowing down, and a reversal through
        standstill, pass at once, as in a firmware that brakes without a ramp.
        """
        f = self.decel_factor
        return _body_ramp(
            self.v_max,
            self.w_max,
            self.a_max * dt,
            f * self.a_max * dt,
            self.alpha_max * dt,
            f * self.alpha_max * dt,
            free_deceleration,
            v,
            w,
            v_prev,
            w_prev,
        )

    def limit_wheels(
        self,
        v: float,
        w: float,
        v_prev: float,
        w_prev: float,
        dt: float,
        wheelbase: float,
        *,
        free_deceleration: bool = False,
    ) -> tuple[float, float]:
        r"""As :meth:`limit`, with the rate limit acting on each wheel instead of the body.

        Many motor firmwares ramp each wheel's speed set-point rather than the
        body twist. After the speed limits, the wheel surface speeds
        :math:`s_{l,r} = v \mp ω b / 2` each move from their previous values by
        at most ``a_max·dt`` (``a_max`` is then a wheel's surface acceleration,
        m/s²; ``alpha_max`` is not used: a turn in place ramps at
        :math:`2 a_{max} / b`):

        .. math::

            s_k = s_{k-1} + \operatorname{clip}(s^{req} - s_{k-1}, \pm a_{max}\,Δt),
            \qquad v_k = \tfrac12 (s_{r,k} + s_{l,k}), \quad ω_k = (s_{r,k} - s_{l,k}) / b .

        ``wheelbase`` is the nominal wheelbase ``b`` in m. On an arc the wheel
        that must change more saturates first, so the curvature during a ramp
        differs from that of a body-twist ramp. ``free_deceleration`` as in
        :meth:`limit`, per wheel.
        """
        v = min(self.v_max, max(-self.v_max, v))
        w = min(self.w_max, max(-self.w_max, w))
        half = 0.5 * wheelbase
        ds = self.a_max * dt
        dd = self.decel_factor * ds
        sl = ramp_step(v_prev - w_prev * half, v - w * half, ds, free_deceleration, dd)
        sr = ramp_step(v_prev + w_prev * half, v + w * half, ds, free_deceleration, dd)
        return float(0.5 * (sl + sr)), float((sr - sl) / wheelbase)


_STOP, _FREE, _WHEELS = Deceleration.STOP, Deceleration.FREE, Ramp.WHEELS
_VELOCITY_CONTROL = p.VELOCITY_CONTROL


def ramp_step(
    prev: float,
    target: float,
    step: float,
    free_deceleration: bool = False,
    decel_step: float | None = None,
) -> float:
    """One period of a rate limiter: ``prev`` moves towards ``target`` by at most ``step``.

    A move towards standstill (judged by the sign of ``prev``, as ros2
    ``diff_drive_controller``'s speed limiter judges acceleration and
    deceleration) is limited by ``decel_step`` instead (default: ``step``), and
    not at all with ``free_deceleration``; from standstill the acceleration
    limit applies both ways. An infinite step does not limit.
    """
    d = target - prev
    slowing = (prev > 0.0 and d < 0.0) or (prev < 0.0 and d > 0.0)
    if slowing:
        if free_deceleration:
            return float(target)
        if decel_step is not None:
            step = decel_step
    return float(prev + min(step, max(-step, d)))


_ramp_step = compiled(ramp_step) or ramp_step
"""The compiled twin of :func:`ramp_step` that :func:`_body_ramp` calls (a compiled kernel
calls only compiled functions); :func:`ramp_step` itself without Numba."""


def _body_ramp(
    v_max: float,
    w_max: float,
    dv: float,
    dv_slow: float,
    dw: float,
    dw_slow: float,
    free: bool,
    v: float,
    w: float,
    v_prev: float,
    w_prev: float,
) -> tuple[float, float]:
    """The body-twist ramp of :meth:`FirmwareLimits.limit` with its per-period steps given:
    the request ``(v, w)`` after ``(v_prev, w_prev)`` clipped to ``±v_max``, ``±w_max``, then
    :func:`ramp_step` of each part (speeding up by at most ``dv`` / ``dw``, slowing down by
    ``dv_slow`` / ``dw_slow``). The constants come first, so that
    :meth:`FirmwareLimits.bound` binds them."""
    v = min(v_max, max(-v_max, v))
    w = min(w_max, max(-w_max, w))
    return _ramp_step(v_prev, v, dv, free, dv_slow), _ramp_step(w_prev, w, dw, free, dw_slow)


_body_ramp_compiled = compiled(_body_ramp)
""":func:`_body_ramp` compiled by Numba (the same bits: IEEE arithmetic, the same
comparisons); ``None`` without Numba."""


def _applied_rows(
    req: FloatArray,
    dt: float,
    wheelbase: float,
    v_max: float,
    w_max: float,
    a_max: float,
    alpha_max: float,
    f: float,
    wheels: bool,
    stop: bool,
    free: bool,
) -> FloatArray:
    """:meth:`FirmwareLimits.applied` as one loop over the rows with the firmware's numbers
    given: :meth:`FirmwareLimits.step` (:meth:`~FirmwareLimits.limit` or
    :meth:`~FirmwareLimits.limit_wheels`) with the same operations in the same order, so
    that its compiled twin gives the same bits (a day of logs is millions of rows, and the
    actuator-limit fit replays them hundreds of times)."""
    n = req.shape[0]
    out = np.empty((n, 2))
    v = 0.0
    w = 0.0
    dv = a_max * dt
    dv_slow = f * a_max * dt
    dw = alpha_max * dt
    dw_slow = f * alpha_max * dt
    half = 0.5 * wheelbase
    ds = a_max * dt
    dd = f * ds
    for k in range(n):
        rv = req[k, 0]
        rw = req[k, 1]
        if stop and rv == 0.0 and rw == 0.0:
            v = 0.0
            w = 0.0
        else:
            cv = min(v_max, max(-v_max, rv))
            cw = min(w_max, max(-w_max, rw))
            if wheels:
                sl = _ramp_step(v - w * half, cv - cw * half, ds, free, dd)
                sr = _ramp_step(v + w * half, cv + cw * half, ds, free, dd)
                v = 0.5 * (sl + sr)
                w = (sr - sl) / wheelbase
            else:
                v, w = _ramp_step(v, cv, dv, free, dv_slow), _ramp_step(w, cw, dw, free, dw_slow)
        out[k, 0] = v
        out[k, 1] = w
    return out


_applied_rows_compiled = compiled(_applied_rows)
""":func:`_applied_rows` compiled by Numba (the same bits); ``None`` without Numba."""


_FLOAT64 = np.dtype(np.float64)

_NOT_SCENERY = frozenset({"robot", "floor", "floor_surface"})
"""World bodies that have no scenery footprint: this robot and the floor."""

CONTACT_QUERY_MARGIN = 0.2
"""Distance (m) added to :func:`collision_reach` beyond which
:meth:`DiffDriveRobot.in_contact_with_scenery` does not ask the engine: well above the
engine's collision margins (0.04 m per convex shape) and its contact breaking threshold
(0.02 m) together."""


def collision_reach(params: DiffDriveParams) -> float:
    """Radius (m) of a sphere about the base link's origin (the body cylinder's centre, see
    :func:`urdf_from_params`) that holds every collision shape of the robot: the body
    cylinder, the two caster spheres and the two wheel spheres."""
    P = params
    r_max = max(P.wheel_radius_left, P.wheel_radius_right)
    body_z = r_max + 0.01 + P.body_height / 2.0
    body = math.hypot(P.body_radius, P.body_height / 2.0)
    wheels = math.hypot(P.wheelbase / 2.0, r_max - body_z) + r_max
    casters = math.hypot(P.caster_offset, P.caster_radius - body_z) + P.caster_radius
    return max(body, wheels, casters)


def _inertia_cylinder(m: float, r: float, h: float) -> tuple[float, float, float]:
    ixx = m * (3 * r * r + h * h) / 12.0
    return ixx, ixx, m * r * r / 2.0


def urdf_from_params(params: DiffDriveParams) -> str:
    """URDF text of the robot described by ``params``.

    The wheels collide as spheres of the wheel radius: a single contact point
    on the floor, so the effective wheel radius and track are exactly the
    parameters (a cylinder's edge contacts make both wander with load).

    Links: ``base_link`` (body cylinder and two casters), ``wheel_left``,
    ``wheel_right`` (continuous joints about the axle), ``camera_link`` (fixed, at
    the camera mount). The base frame sits on the floor below the axle midpoint.
    """
    P = params
    r_max = max(P.wheel_radius_left, P.wheel_radius_right)
    body_z = r_max + 0.01 + P.body_height / 2.0  # body centre above the floor
    ixx, iyy, izz = _inertia_cylinder(P.body_mass, P.body_radius, P.body_height)

    def wheel(side: str, y: float, r: float) -> str:
        wi = _inertia_cylinder(P.wheel_mass, r, P.wheel_width)
        return f"""
  <link name="wheel_{side}">
    <inertial><mass value="{P.wheel_mass}"/><inertia ixx="{wi[0]:.6g}" iyy="{wi[1]:.6g}" izz="{wi[2]:.6g}" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><cylinder radius="{r}" length="{P.wheel_width}"/></geometry><material name="black"><color rgba="0.1 0.1 0.1 1"/></material></visual>
    <collision><geometry><sphere radius="{r}"/></geometry></collision>
  </link>
  <joint name="wheel_{side}_joint" type="continuous">
    <parent link="base_link"/><child link="wheel_{side}"/>
    <origin xyz="0 {y:.6f} {r - body_z:.6f}" rpy="-1.5707963267948966 0 0"/>
    <axis xyz="0 0 1"/>
  </joint>"""

    cam = P.camera
    cx, cy_, cz = cam.mount_xyz
    caster_z = P.caster_radius - body_z
    return f"""<?xml version="1.0"?>
<robot name="kobuki_like">
  <link name="base_link">
    <inertial><origin xyz="0 0 0"/><mass value="{P.body_mass}"/><inertia ixx="{ixx:.6g}" iyy="{iyy:.6g}" izz="{izz:.6g}" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><cylinder radius="{P.body_radius}" length="{P.body_height}"/></geometry><material name="grey"><color rgba="0.25 0.25 0.28 1"/></material></visual>
    <collision><geometry><cylinder radius="{P.body_radius}" length="{P.body_height}"/></geometry></collision>
    <collision><origin xyz="{P.caster_offset} 0 {caster_z:.6f}"/><geometry><sphere radius="{P.caster_radius}"/></geometry></collision>
    <collision><origin xyz="{-P.caster_offset} 0 {caster_z:.6f}"/><geometry><sphere radius="{P.caster_radius}"/></geometry></collision>
  </link>{wheel("left", P.wheelbase / 2.0, P.wheel_radius_left)}{wheel("right", -P.wheelbase / 2.0, P.wheel_radius_right)}
  <link name="camera_link">
    <inertial><mass value="0.01"/><inertia ixx="1e-6" iyy="1e-6" izz="1e-6" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><geometry><box size="0.066 0.249 0.066"/></geometry><material name="dark"><color rgba="0.05 0.05 0.05 1"/></material></visual>
  </link>
  <joint name="camera_joint" type="fixed">
    <parent link="base_link"/><child link="camera_link"/>
    <origin xyz="{cx} {cy_} {cz - body_z:.6f}" rpy="0 {cam.mount_pitch} {cam.mount_yaw}"/>
  </joint>
</robot>
"""


class DiffDriveRobot:
    """The simulated body and its firmware: wheel motors, ground-truth state, encoders.

    The firmware (see :meth:`attach_firmware`) turns a commanded body twist into
    wheel speeds: its :class:`FirmwareLimits`, then the command-stage effects of
    a :class:`~realitygap.robots.effects.Reality`, then the inverse kinematics
    with the geometry the firmware believes (the nominal parameters). The
    encoders report the wheel angles through the effects' encoder hooks.

    Parameters
    ----------
    world : the :class:`World` to live in.
    params : physical parameters; the URDF is generated from them.
    """

    LEFT, RIGHT = 0, 1

    def __init__(self, world: World, params: DiffDriveParams):
        self.world = world
        self.params = params
        self.nominal = params
        self.firmware_limits: FirmwareLimits | None = None
        self.control_dt = world.dt
        self.command = np.zeros(2)
        # FirmwareLimits.bound for the attached limits, control period and nominal wheelbase
        self._bound_to: tuple[object, ...] = ()  # (limits, control period, nominal, compiled) bound
        self._limit_twist: Callable[[float, float, float, float], tuple[float, float]] | None = None
        self._reality: Reality | None = None
        self._command_hooks: list[Callable[[float, float, float], tuple[float, float]]] = []
        self._ticks_hooks: list[Callable[[float, float], tuple[float, float]]] = []
        self._wheel_hooks: list[WheelHook] = []
        self._body_z = (
            max(params.wheel_radius_left, params.wheel_radius_right) + 0.01 + params.body_height / 2
        )
        self.body = world.load_urdf(
            "robot", urdf_from_params(params), [0, 0, self._body_z], [0, 0, 0, 1]
        )
        c = world.bullet
        self.joint_index = {
            c.getJointInfo(self.body, j)[1].decode(): j for j in range(c.getNumJoints(self.body))
        }
        self.wheel_joints = [
            self.joint_index["wheel_left_joint"],
            self.joint_index["wheel_right_joint"],
        ]
        for j in self.wheel_joints:
            c.changeDynamics(
                self.body,
                j,
                lateralFriction=params.wheel_friction,
                rollingFriction=0.0,
                spinningFriction=0.0,
            )
        # casters are part of the base: a frictionless base contact models free-swivelling casters
        c.changeDynamics(
            self.body, -1, lateralFriction=0.0, rollingFriction=0.0, spinningFriction=0.0
        )
        # soft caster contacts model their springs (as on the Kobuki): the weight rests on the
        # driven wheels and the body does not lean on a caster, which would load the wheel
        # motors. (PyBullet ignores contact stiffness given together with friction: own call.)
        c.changeDynamics(self.body, -1, contactStiffness=3000.0, contactDamping=60.0)
        # a robot that creeps slowly must not be put to sleep by the engine (its motors would stop)
        c.changeDynamics(self.body, -1, activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING)
        # make sure no default motor fights the wheel velocity motors
        c.setJointMotorControlArray(
            self.body, self.wheel_joints, p.VELOCITY_CONTROL, forces=[0.0, 0.0]
        )
        self._body_from_base = np.array([0.0, 0.0, self._body_z])
        # bound client functions, looked up once (BulletClient rebinds on every attribute access);
        # the two reads of every step call pybullet with the client id positional, which
        # costs ~0.15 µs a call less than the keyword BulletClient's partial passes
        self._cid = world.client_id
        self._get_base_pose = p.getBasePositionAndOrientation
        self._get_joint_states = p.getJointStates
        self._get_contacts = c.getContactPoints
        self._set_motors = c.setJointMotorControlArray
        # the torque bound as the engine needs it commanded (World.motor_force: a world that
        # runs a control period in one engine call turns it into an impulse with that period)
        tau = world.motor_force(params.motor_max_torque)
        self._motor_forces = [tau, tau]  # each wheel's
        # the contact query is skipped where no scenery is near (in_contact_with_scenery)
        self._reach = collision_reach(params) + CONTACT_QUERY_MARGIN
        self._clearance_ref: tuple[object, float, float, float] | None = None
        # whether every body but this robot and the floor has a scenery footprint, and the
        # change counts of the world's bodies and primitives it was worked out at
        self._footprints_seen: tuple[int, int] = (-1, -1)
        self._all_have_footprints = False

    # ------------------------------------------------------------- control
    def set_wheel_speeds(self, w_left: float, w_right: float) -> None:
        """Command wheel angular speeds in rad/s (velocity motors with bounded torque)."""
        self._set_motors(
            self.body,
            self.wheel_joints,
            _VELOCITY_CONTROL,
            targetVelocities=[w_left, w_right],
            forces=self._motor_forces,  # read by the engine, not kept
        )

    def attach_firmware(
        self,
        dt: float,
        *,
        nominal: DiffDriveParams | None = None,
        limits: FirmwareLimits | None = None,
        reality: Reality | None = None,
    ) -> None:
        """Start the firmware for an episode: applied twist at rest, fresh effect hooks.

        Parameters
        ----------
        dt : float
            Control period, s (the rate limits and the effect hooks use it).
        nominal : DiffDriveParams, optional
            The geometry the firmware believes (default: the body's own).
        limits : FirmwareLimits, optional
            Limits applied by :meth:`command_twist` (default: none, the twist
            is applied as given).
        reality : Reality, optional
            Effects whose command, per-wheel and encoder hooks act on this robot.
        """
        self.control_dt = float(dt)
        self.nominal = nominal if nominal is not None else self.params
        self.firmware_limits = limits
        self._bound_to, self._limit_twist = (), None  # bound afresh at the first command
        self.command = np.zeros(2)
        self._reality = reality
        self._command_hooks = reality.command_hooks(dt, self.nominal) if reality is not None else []
        self._ticks_hooks = reality.ticks_hooks() if reality is not None else []
        self._wheel_hooks = reality.wheel_hooks(dt, self.nominal) if reality is not None else []

    def wheel_speeds_from_twist(self, v: float, w: float) -> tuple[float, float]:
        r"""Firmware inverse kinematics: body twist (m/s, rad/s) → wheel speeds (rad/s).

        .. math::

            \omega_{l} = (v - \omega\,b/2) / r_l, \qquad \omega_{r} = (v + \omega\,b/2) / r_r

        with the wheelbase ``b`` and radii ``r_l``, ``r_r`` the firmware believes
        (:attr:`nominal`), as a real robot converts with its nominal geometry.
        """
        P = self.nominal
        half_b = P.wheelbase / 2.0
        return (v - w * half_b) / P.wheel_radius_left, (v + w * half_b) / P.wheel_radius_right

    def command_twist(self, v: float, omega: float) -> tuple[float, float]:
        """Command a body twist ``(v, ω)`` (m/s, rad/s) for the next control period.

        The firmware limits (if any) give the applied twist, stored in
        :attr:`command` and returned; the command-stage effect hooks then act on
        it, the inverse kinematics gives the wheel speeds, the per-wheel hooks
        act on those and the wheel motors take them. The world is not stepped.
        """
        limits, command = self.firmware_limits, self.command
        if limits is not None:
            bound_to = (limits, self.control_dt, self.nominal, KERNELS.on)
            if bound_to != self._bound_to:  # attached, or any of the four changed since
                self._bound_to = bound_to
                self._limit_twist = limits.bound(self.control_dt, self.nominal.wheelbase)
            v_prev, w_prev = command.tolist()  # plain floats: cheaper scalar arithmetic
            v, omega = self._limit_twist(v, omega, v_prev, w_prev)
        command[0], command[1] = v, omega
        applied = (v, omega)
        for hook in self._command_hooks:
            v, omega = hook(v, omega, self.control_dt)
        w_left, w_right = self.wheel_speeds_from_twist(v, omega)
        for wheel_hook in self._wheel_hooks:
            w_left, w_right = wheel_hook.command(w_left, w_right)
        self.set_wheel_speeds(float(w_left), float(w_right))
        return applied

    def encoder_angles(self) -> tuple[float, float]:
        """Wheel angles (rad) as the encoders report them: :meth:`wheel_angles` (the rolling
        angles) through the effects' per-wheel hooks (wheels that turned more than they
        rolled) and encoder hooks."""
        angles = self.wheel_angles()
        for wheel_hook in self._wheel_hooks:
            angles = wheel_hook.encoder(*angles)
        for hook in self._ticks_hooks:
            angles = hook(*angles)
        return angles

    def wheel_angles_from_encoder(self, angles: npt.ArrayLike) -> FloatArray:
        """Rolling wheel angles (N, 2) (rad) for encoder readings ``angles`` (N, 2) (rad).

        Inverts the effects' encoder hooks, in reverse effect order, then their
        per-wheel hooks (the readings one control period apart).

        Raises
        ------
        ValueError
            If an attached effect changes the encoder reading but cannot be inverted.
        """
        ang = np.asarray(angles, dtype=float)
        inverse = self._reality.ticks_inverse_hooks() if self._reality is not None else []
        if inverse:
            al, ar = ang[:, 0].copy(), ang[:, 1].copy()
            for h in inverse:
                res = [h(a, b) for a, b in zip(al, ar, strict=True)]
                al = np.array([r[0] for r in res])
                ar = np.array([r[1] for r in res])
            ang = np.column_stack([al, ar])
        if self._reality is not None:
            for wheel_hook in reversed(self._reality.wheel_hooks(self.control_dt, self.nominal)):
                ang = np.asarray(wheel_hook.rolling_from_encoder(ang), dtype=float)
        return ang

    # --------------------------------------------------------------- state
    def reset(self, pose: npt.ArrayLike) -> None:
        """Place the robot at planar pose ``[x, y, theta]`` at rest."""
        x, y, th = check_finite("pose", pose, (3,))
        c = self.world.bullet
        quat = c.getQuaternionFromEuler([0.0, 0.0, th])
        c.resetBasePositionAndOrientation(self.body, [x, y, self._body_z], quat)
        c.resetBaseVelocity(self.body, [0, 0, 0], [0, 0, 0])
        for j in self.wheel_joints:
            c.resetJointState(self.body, j, 0.0, 0.0)
        self.set_wheel_speeds(0.0, 0.0)

    def pose2d(self) -> FloatArray:
        """Ground-truth planar pose ``[x, y, theta]`` of the base frame (m, m, rad)."""
        pos, (qx, qy, qz, qw) = self._get_base_pose(self.body, self._cid)
        yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        return np.array([pos[0], pos[1], yaw])

    def pose3d(self) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
        """Ground-truth position (m) and orientation (quat_xyzw) of the body link."""
        return self.world.bullet.getBasePositionAndOrientation(self.body)

    def twist(self) -> FloatArray:
        """Ground-truth body-frame velocity ``[v, w]`` (m/s, rad/s)."""
        lin, ang = self.world.bullet.getBaseVelocity(self.body)
        th = self.pose2d()[2]
        return np.array([math.cos(th) * lin[0] + math.sin(th) * lin[1], ang[2]])

    def in_contact_with_scenery(self, pose: FloatArray | None = None) -> bool:
        """Whether the body touches anything but the floor (a collision).

        ``pose``: the current :meth:`pose2d` when the caller has read it. Then the engine is
        asked only when some scenery is near: if the distance in the plane from the base
        link's origin to every scenery footprint exceeds the robot's :func:`collision_reach`
        plus :data:`CONTACT_QUERY_MARGIN`, no contact point can exist, whatever the robot's
        attitude. The distance is computed when needed and bounded in between by the
        distance moved since (it changes by at most that).
        """
        if pose is not None:
            if type(pose) is np.ndarray and pose.dtype is _FLOAT64:
                x, y = pose.tolist()[:2]  # Python floats already
            else:
                x, y = float(pose[0]), float(pose[1])
            if self._clear_of_scenery(x, y):
                return False
        floor = self.world.bodies.get("floor", -1)
        for contact in self._get_contacts(bodyA=self.body):
            if contact[2] != floor:
                return True
        return False

    def _clear_of_scenery(self, x: float, y: float) -> bool:
        """Whether the base link's origin at ``(x, y)`` (m) is farther than :attr:`_reach`
        from every scenery footprint (a lower bound from the last computed distance), and the
        world holds no other body the robot could touch."""
        world = self.world
        bodies, primitives = world.bodies, world.primitives
        seen = (bodies.version, primitives.version)
        if seen != self._footprints_seen:  # the bodies changed since the last look
            self._footprints_seen = seen
            self._all_have_footprints = bodies.keys() - primitives.keys() <= _NOT_SCENERY
        if not self._all_have_footprints:
            return False  # a body without a footprint: ask the engine
        arrays = world.scenery_arrays
        ref = self._clearance_ref
        if ref is not None and ref[0] is arrays:
            _, rx, ry, dist = ref
            if dist - math.hypot(x - rx, y - ry) > self._reach:
                return True
        dist = arrays.clearance(x, y)
        self._clearance_ref = (arrays, x, y, dist)
        return dist > self._reach

    def wheel_angles(self) -> tuple[float, float]:
        """Wheel rotation angles (rad) since reset, positive driving forward."""
        states = self._get_joint_states(self.body, self.wheel_joints, self._cid)
        return states[0][0], states[1][0]

    def T_world_camera(self) -> FloatArray:
        """4×4 pose of the camera's optical frame in the world (ground truth)."""
        pos, quat = self.pose3d()
        R = np.array(self.world.bullet.getMatrixFromQuaternion(quat)).reshape(3, 3)
        T_world_body = np.eye(4)
        T_world_body[:3, :3] = R
        T_world_body[:3, 3] = pos
        T_body_base = np.eye(4)
        T_body_base[:3, 3] = -self._body_from_base
        return T_world_body @ T_body_base @ self.params.camera.T_base_camera()


def encoder_ticks(t: float, angles: tuple[float, float], ticks_per_rev: float) -> WheelTicks:
    """Quantise wheel angles (rad) to cumulative encoder counts."""
    k = ticks_per_rev / (2.0 * math.pi)
    # positional (t, left, right, ticks_per_rev): cheaper than keywords, once per step
    return WheelTicks(t, math.floor(angles[0] * k), math.floor(angles[1] * k), ticks_per_rev)
