"""Effects: named, parameterised ways in which a real robot differs from its model.

An :class:`Effect` knows its parameters (units, nominal value, plausible
bounds, a physical description) and realises itself in the simulation in one
or both of two ways:

* by changing the robot's physical parameters before the body is built
  (:meth:`Effect.apply_params`) — a different wheel radius really is a
  different URDF, a moved camera really is mounted elsewhere;
* by a runtime hook between the controller and the body
  (:meth:`Effect.make_command_hook`) — a command queue for latency, a motor
  dead-band, velocity saturation — or between a sensor and its reader
  (:meth:`Effect.make_ticks_hook`);
* by a clock error of a recorded channel (:meth:`Effect.channel_time_offsets`):
  the recorder stamps that channel's samples late or early.

Every effect also says where it can be seen (:attr:`Effect.observed_in`, the
log channels it changes) and at which stage of the pipeline it acts
(:attr:`Effect.stage`: ``"body"``, ``"drive"``, ``"command"``, ``"sensor"``,
``"camera"``, ``"timing"``), which the diagnosis uses to drop candidates a log
cannot show and to explain its findings.

A :class:`Reality` is the nominal parameters plus a set of effects with values;
``gym.make(id, reality=...)`` builds the "real" robot from it.
"""

from __future__ import annotations

import difflib
import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

from realitygap.robots.diffdrive import DiffDriveParams


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of an effect: ``nominal`` means "no effect"; ``low``/``high`` plausible bounds."""

    name: str
    unit: str
    nominal: float
    low: float
    high: float
    description: str


CommandHook = Callable[[float, float, float], tuple[float, float]]
"""``hook(v, w, dt) -> (v, w)``: transforms the commanded body twist each control step."""

TicksHook = Callable[[float, float], tuple[float, float]]
"""``hook(angle_left, angle_right) -> (angle_left, angle_right)``: what the encoders see (rad)."""


class Effect:
    """Base class of all effects. Subclasses set ``name``, ``robot``, ``description``, ``specs``."""

    name: ClassVar[str] = ""
    robot: ClassVar[str] = ""
    description: ClassVar[str] = ""
    specs: ClassVar[tuple[ParamSpec, ...]] = ()
    stage: ClassVar[str] = "body"
    observed_in: ClassVar[tuple[str, ...]] = ("pose_gt",)

    def __init__(self, **values: float):
        known = {s.name: s for s in self.specs}
        unknown = set(values) - set(known)
        if unknown:
            bad = sorted(unknown)[0]
            close = difflib.get_close_matches(bad, list(known), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise TypeError(
                f"effect {self.name!r} has no parameter {bad!r}{hint} (parameters: {', '.join(known)})"
            )
        self.values: dict[str, float] = {}
        for spec in self.specs:
            value = float(values.get(spec.name, spec.nominal))
            if not math.isfinite(value):
                raise ValueError(f"effect {self.name!r}: {spec.name} must be finite, got {value!r}")
            self.values[spec.name] = value
        self._nominal: Any = None

    # realisations (identity by default) ---------------------------------------
    def apply_params(self, params: Any) -> Any:
        """Return the physical parameters of the robot with this effect built in."""
        return params

    def make_command_hook(self, dt: float) -> CommandHook | None:
        """A fresh, stateful command hook for one episode, or ``None``."""
        return None

    def make_ticks_hook(self) -> TicksHook | None:
        """A fresh encoder hook for one episode, or ``None``."""
        return None

    def make_ticks_inverse_hook(self) -> TicksHook | None:
        """The inverse of :meth:`make_ticks_hook` (encoder reading → true wheel angle), or ``None``.

        Needed to drive a simulation by logged encoder ticks; an effect with a
        ticks hook but no inverse cannot be replayed that way.
        """
        return None

    def channel_time_offsets(self) -> dict[str, float]:
        """Clock errors of recorded channels, s: ``{channel: offset}``.

        A channel with offset ``Δ`` is stamped ``Δ`` late: its logged sample at
        time ``t`` is the true value at ``t − Δ``.
        """
        return {}

    def bind_nominal(self, params: Any) -> None:
        """Remember the robot's nominal parameters (what its firmware believes).

        :class:`Reality` calls this before :meth:`apply_params`, so hooks that
        act on the firmware's wheel-speed commands use the nominal geometry
        whatever other effects change in the body.
        """
        self._nominal = params

    # helpers ------------------------------------------------------------------
    def __getitem__(self, key: str) -> float:
        return self.values[key]

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v:.6g}" for k, v in self.values.items())
        return f"{type(self).__name__}({args})"

    def to_dict(self) -> dict[str, Any]:
        """``{"name": ..., "values": {param: value}}`` (JSON-able)."""
        return {"name": self.name, "values": dict(self.values)}

    def spec(self, param: str) -> ParamSpec:
        """The :class:`ParamSpec` of parameter ``param``."""
        for s in self.specs:
            if s.name == param:
                return s
        raise KeyError(f"effect {self.name!r} has no parameter {param!r}")

    def is_nominal(self) -> bool:
        """True when every parameter sits at its nominal value (the effect does nothing)."""
        return all(self.values[s.name] == s.nominal for s in self.specs)

    def _nominal_half_wheelbase(self) -> float:
        params = self._nominal if self._nominal is not None else DiffDriveParams()
        return float(params.wheelbase) / 2.0


EFFECTS: dict[str, type[Effect]] = {}


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Class decorator adding an effect to the library."""
    if not cls.name:
        raise ValueError(f"{cls.__name__} needs a name")
    EFFECTS[cls.name] = cls
    return cls


def make_effect(name: str, **values: float) -> Effect:
    """Instantiate library effect ``name``; suggests close names on a typo."""
    if name not in EFFECTS:
        close = difflib.get_close_matches(name, list(EFFECTS), n=3)
        hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
        raise KeyError(f"unknown effect {name!r}.{hint} Known: {', '.join(sorted(EFFECTS))}")
    return EFFECTS[name](**values)


# --------------------------------------------------------------------------- diff drive
GRAVITY = 9.81
"""Standard gravity, m/s²."""


@register_effect
class WheelRadiusScale(Effect):
    name = "wheel_radius_scale"
    robot = "diffdrive"
    stage = "body"
    observed_in = ("pose_gt", "pose_cam")
    description = (
        "Both wheels larger or smaller than nominal (tyre wear, inflation): scales distance "
        "and rotation per wheel revolution. Realised as a body with other wheel radii."
    )
    specs = (ParamSpec("scale", "1", 1.0, 0.9, 1.1, "true radius / nominal radius, both wheels"),)

    def apply_params(self, params: DiffDriveParams) -> DiffDriveParams:
        s = self["scale"]
        return params.replace(
            wheel_radius_left=params.wheel_radius_left * s,
            wheel_radius_right=params.wheel_radius_right * s,
        )


@register_effect
class WheelDiameterRatio(Effect):
    name = "wheel_diameter_ratio"
    robot = "diffdrive"
    stage = "body"
    observed_in = ("pose_gt", "pose_cam")
    description = (
        "Unequal wheel diameters, E_d = D_R / D_L (Borenstein): the robot curves when driving straight. "
        "The mean diameter is kept. Realised as a body with other wheel radii."
    )
    specs = (ParamSpec("E_d", "1", 1.0, 0.95, 1.05, "right / left wheel diameter"),)

    def apply_params(self, params: DiffDriveParams) -> DiffDriveParams:
        e = self["E_d"]
        mean = (params.wheel_radius_left + params.wheel_radius_right) / 2.0
        return params.replace(
            wheel_radius_left=2.0 * mean / (e + 1.0), wheel_radius_right=2.0 * mean * e / (e + 1.0)
        )


@register_effect
class WheelbaseError(Effect):
    name = "wheelbase_error"
    robot = "diffdrive"
    stage = "body"
    observed_in = ("pose_gt", "pose_cam")
    description = (
        "Effective wheelbase differs from nominal, E_b = b_actual / b_nominal: turns are "
        "over/under-rotated. Realised as a body with the wheels further apart or closer."
    )
    specs = (ParamSpec("E_b", "1", 1.0, 0.9, 1.1, "actual / nominal wheelbase"),)

    def apply_params(self, params: DiffDriveParams) -> DiffDriveParams:
        return params.replace(wheelbase=params.wheelbase * self["E_b"])


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
    the wheels after a start and runs on after a stop.

    A *constant* creep ratio is not part of this effect on purpose: it changes
    metres per wheel revolution exactly as a wheel-radius scale does, so no log
    could tell the two apart; it is reported as ``wheel_radius_scale``.
    """

    name = "longitudinal_slip"
    robot = "diffdrive"
    stage = "drive"
    observed_in = ("pose_gt", "pose_cam")
    description = (
        "Reduced tyre-floor traction (dust, polished or wet floor): on hard speed changes the "
        "wheels spin or skid, so the ground moves less than the wheel rotation on a start and "
        "more on a stop. Realised as the wheels' friction coefficient."
    )
    specs = (ParamSpec("mu", "1", 1.2, 0.05, 1.2, "tyre-floor friction coefficient (nominal 1.2)"),)

    def apply_params(self, params: DiffDriveParams) -> DiffDriveParams:
        return params.replace(wheel_friction=self["mu"])


@register_effect
class CameraMountOffset(Effect):
    name = "camera_mount_offset"
    robot = "diffdrive"
    stage = "camera"
    observed_in = ("pose_cam",)
    description = (
        "The camera is mounted off its nominal place: offset in x, y (m) and yaw (rad) in the "
        "base frame. Realised by moving the camera link of the body."
    )
    specs = (
        ParamSpec("dx", "m", 0.0, -0.03, 0.03, "forward offset"),
        ParamSpec("dy", "m", 0.0, -0.03, 0.03, "leftward offset"),
        ParamSpec("dyaw", "rad", 0.0, -0.1, 0.1, "yaw offset"),
    )

    def apply_params(self, params: DiffDriveParams) -> DiffDriveParams:
        cam = params.camera
        x, y, z = cam.mount_xyz
        new_cam = replace(
            cam,
            mount_xyz=(x + self["dx"], y + self["dy"], z),
            mount_yaw=cam.mount_yaw + self["dyaw"],
        )
        return params.replace(camera=new_cam)


@register_effect
class CommandLatency(Effect):
    name = "command_latency"
    robot = "diffdrive"
    stage = "command"
    observed_in = ("pose_gt", "ticks", "pose_cam")
    description = (
        "Commands reach the motors late (bus, firmware queue): a pure delay of the commanded "
        "twist. Realised as a command queue (fractional delays interpolate between steps)."
    )
    specs = (ParamSpec("delay", "s", 0.0, 0.0, 0.3, "command delay"),)

    def make_command_hook(self, dt: float) -> CommandHook | None:
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


@register_effect
class MotorDeadband(Effect):
    name = "motor_deadband"
    robot = "diffdrive"
    stage = "command"
    observed_in = ("pose_gt", "ticks", "pose_cam")
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

    def make_command_hook(self, dt: float) -> CommandHook | None:
        thr = self["threshold"]
        if thr <= 0:
            return None
        hb = self._nominal_half_wheelbase()

        def hook(v: float, w: float, dt_: float) -> tuple[float, float]:
            vl, vr = v - w * hb, v + w * hb
            vl = 0.0 if abs(vl) < thr else vl
            vr = 0.0 if abs(vr) < thr else vr
            return (vl + vr) / 2.0, (vr - vl) / (2.0 * hb)

        return hook


@register_effect
class VelocitySaturation(Effect):
    name = "velocity_saturation"
    robot = "diffdrive"
    stage = "command"
    observed_in = ("pose_gt", "ticks", "pose_cam")
    description = (
        "The drive reaches a lower top speed than specified (weak battery, motor limit). "
        "Realised by clipping the firmware's wheel-speed commands (nominal geometry)."
    )
    specs = (
        ParamSpec(
            "v_limit", "m/s", 10.0, 0.2, 10.0, "largest wheel surface speed actually reached"
        ),
    )

    def make_command_hook(self, dt: float) -> CommandHook | None:
        lim = self["v_limit"]
        if lim >= self.spec("v_limit").nominal:
            return None
        hb = self._nominal_half_wheelbase()

        def hook(v: float, w: float, dt_: float) -> tuple[float, float]:
            vl, vr = v - w * hb, v + w * hb
            vl, vr = max(-lim, min(lim, vl)), max(-lim, min(lim, vr))
            return (vl + vr) / 2.0, (vr - vl) / (2.0 * hb)

        return hook


@register_effect
class EncoderScale(Effect):
    name = "encoder_scale"
    robot = "diffdrive"
    stage = "sensor"
    observed_in = ("ticks",)
    description = (
        "Encoders count more or fewer ticks per revolution than specified (wrong gear ratio in "
        "firmware). Realised between the wheel joints and the encoder reading."
    )
    specs = (ParamSpec("scale", "1", 1.0, 0.9, 1.1, "counted / specified ticks per revolution"),)

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


@register_effect
class TimestampOffset(Effect):
    name = "timestamp_offset"
    robot = "diffdrive"
    stage = "timing"
    observed_in = ("pose_gt",)
    description = (
        "The ground-truth (motion-capture) clock is offset from the robot's clock: each "
        "ground-truth sample is stamped `offset` seconds late. Realised by the recorder."
    )
    specs = (ParamSpec("offset", "s", 0.0, -0.3, 0.3, "ground-truth stamp minus true time"),)

    def channel_time_offsets(self) -> dict[str, float]:
        return {"pose_gt": self["offset"]} if self["offset"] != 0.0 else {}


@dataclass
class Reality:
    """Nominal parameters plus effects: the description of a "real" robot.

    ``Reality()`` is the nominal robot. Effects apply in order; hooks that act
    on the firmware's commands see the *nominal* geometry (see
    :meth:`Effect.bind_nominal`).
    """

    effects: tuple[Effect, ...] = ()
    name: str = "nominal"
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.effects = tuple(self.effects)
        for e in self.effects:
            if not isinstance(e, Effect):
                raise TypeError(f"Reality.effects must hold Effect objects, got {type(e).__name__}")

    def apply_params(self, params: Any) -> Any:
        """The physical parameters of the real robot, built from the nominal ``params``."""
        for effect in self.effects:
            effect.bind_nominal(params)
        for effect in self.effects:
            params = effect.apply_params(params)
        return params

    def command_hooks(self, dt: float) -> list[CommandHook]:
        """Fresh command hooks for one episode, in effect order."""
        return [h for e in self.effects if (h := e.make_command_hook(dt)) is not None]

    def ticks_hooks(self) -> list[TicksHook]:
        """Fresh encoder hooks for one episode, in effect order."""
        return [h for e in self.effects if (h := e.make_ticks_hook()) is not None]

    def ticks_inverse_hooks(self) -> list[TicksHook]:
        """Inverse encoder hooks in reverse effect order (reading → true wheel angle).

        Raises
        ------
        ValueError
            If an effect changes the encoder reading but cannot be inverted.
        """
        out: list[TicksHook] = []
        for e in reversed(self.effects):
            inv = e.make_ticks_inverse_hook()
            if inv is None and e.make_ticks_hook() is not None:
                raise ValueError(
                    f"effect {e.name!r} changes the encoder reading but has no inverse; "
                    "a simulation driven by logged ticks cannot include it"
                )
            if inv is not None:
                out.append(inv)
        return out

    def channel_time_offsets(self) -> dict[str, float]:
        """Total clock error per recorded channel, s (see :meth:`Effect.channel_time_offsets`)."""
        out: dict[str, float] = {}
        for e in self.effects:
            for channel, offset in e.channel_time_offsets().items():
                out[channel] = out.get(channel, 0.0) + float(offset)
        return out

    @property
    def effect_names(self) -> tuple[str, ...]:
        """Names of the effects, in order."""
        return tuple(e.name for e in self.effects)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description; :meth:`from_dict` rebuilds it."""
        return {"name": self.name, "effects": [e.to_dict() for e in self.effects]}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Reality:
        """Rebuild a :class:`Reality` from :meth:`to_dict` output."""
        effects = tuple(
            make_effect(e["name"], **e.get("values", {})) for e in data.get("effects", ())
        )
        return cls(effects=effects, name=str(data.get("name", "custom")))


# =============================================================================
# arm (realitygap/ArmCalib-v0): realised on :class:`realitygap.robots.arm.ArmParams`
# =============================================================================
def _arm_mdh_delta(params: Any, deltas: Mapping[str, float]) -> Any:
    """``params`` with MDH parameters shifted by ``{name: delta}`` (m or rad)."""
    table = params.mdh
    cur = table.param_dict()
    names = [n for n, v in deltas.items() if v != 0.0]
    if not names:
        return params
    return params.replace(mdh=table.with_params([cur[n] + deltas[n] for n in names], names))


@register_effect
class ArmJointOffset(Effect):
    name = "arm_joint_offset"
    robot = "arm"
    stage = "body"
    observed_in = ("camera_pose", "tool_dist")
    description = (
        "Joint zero offsets: the encoder's zero is not where the kinematic model puts it "
        "(mastering error). Realised as the MDH offsets theta_i of the arm's body."
    )
    specs = tuple(
        ParamSpec(f"dtheta{k}", "rad", 0.0, -0.01, 0.01, f"zero offset of joint {k}")
        for k in range(1, 7)
    )

    def apply_params(self, params: Any) -> Any:
        return _arm_mdh_delta(params, {f"theta{k}": self[f"dtheta{k}"] for k in range(1, 7)})


@register_effect
class ArmLinkLength(Effect):
    name = "arm_link_length"
    robot = "arm"
    stage = "body"
    observed_in = ("camera_pose", "tool_dist")
    description = (
        "Link lengths and offsets differ from the data sheet (machining, assembly): the "
        "non-zero MDH lengths d1, a2, a3, d4, d5, d6. Realised as a body with other links."
    )
    specs = tuple(
        ParamSpec(f"d{nm}", "m", 0.0, -0.005, 0.005, f"error of MDH length {nm}")
        for nm in ("d1", "a2", "a3", "d4", "d5", "d6")
    )

    def apply_params(self, params: Any) -> Any:
        return _arm_mdh_delta(
            params, {nm: self[f"d{nm}"] for nm in ("d1", "a2", "a3", "d4", "d5", "d6")}
        )


@register_effect
class ArmParallelTwist(Effect):
    name = "arm_parallel_twist"
    robot = "arm"
    stage = "body"
    observed_in = ("camera_pose", "tool_dist")
    description = (
        "The nominally parallel axes of joints 2, 3 and 4 are tilted against each other: about "
        "the common normal's y axis (Hayati twist beta, the case classical DH cannot describe) "
        "and about the common normal itself (twist alpha). Realised as a body whose joint 3 and "
        "4 axes are tilted."
    )
    specs = (
        ParamSpec("beta2", "rad", 0.0, -0.005, 0.005, "tilt of axis 3 against axis 2 about y"),
        ParamSpec("beta3", "rad", 0.0, -0.005, 0.005, "tilt of axis 4 against axis 3 about y"),
        ParamSpec("dalpha2", "rad", 0.0, -0.005, 0.005, "tilt of axis 3 against axis 2 about x"),
        ParamSpec("dalpha3", "rad", 0.0, -0.005, 0.005, "tilt of axis 4 against axis 3 about x"),
    )

    def apply_params(self, params: Any) -> Any:
        return _arm_mdh_delta(
            params,
            {
                "beta2": self["beta2"],
                "beta3": self["beta3"],
                "alpha2": self["dalpha2"],
                "alpha3": self["dalpha3"],
            },
        )


@register_effect
class ArmTwistError(Effect):
    name = "arm_twist_error"
    robot = "arm"
    stage = "body"
    observed_in = ("camera_pose", "tool_dist")
    description = (
        "The right angles between the non-parallel axes are not exact (twists alpha1, alpha4, "
        "alpha5). Realised as a body with tilted joint axes."
    )
    specs = tuple(
        ParamSpec(f"dalpha{k}", "rad", 0.0, -0.005, 0.005, f"twist error of row {k}")
        for k in (1, 4, 5)
    )

    def apply_params(self, params: Any) -> Any:
        return _arm_mdh_delta(params, {f"alpha{k}": self[f"dalpha{k}"] for k in (1, 4, 5)})


@register_effect
class ArmJointCompliance(Effect):
    name = "arm_joint_compliance"
    robot = "arm"
    stage = "drive"
    observed_in = ("camera_pose", "tool_dist")
    description = (
        "Elastic gearboxes: the links of the gravity-loaded joints 2, 3, 4 sag by compliance x "
        "gravity torque while the motor-side encoders read the command. Realised by the servo: "
        "the link settles at command - c * tau_g(q), tau_g the holding torque (PyBullet inverse "
        "dynamics of the body)."
    )
    specs = tuple(
        ParamSpec(f"c{k}", "rad/(N*m)", 0.0, 0.0, 5e-5, f"compliance of joint {k}")
        for k in (2, 3, 4)
    )

    def apply_params(self, params: Any) -> Any:
        c = list(params.joint_compliance)
        for k in (2, 3, 4):
            c[k - 1] = self[f"c{k}"]
        return params.replace(joint_compliance=tuple(c))


@register_effect
class ArmBacklash(Effect):
    name = "arm_backlash"
    robot = "arm"
    stage = "drive"
    observed_in = ("camera_pose", "tool_dist")
    description = (
        "Gear play: the link trails the motor by half the play in the direction of the last "
        "move, so the same reading gives two link angles. Realised by the servo model."
    )
    specs = tuple(
        ParamSpec(f"b{k}", "rad", 0.0, 0.0, 2e-3, f"full play of joint {k}") for k in range(1, 7)
    )

    def apply_params(self, params: Any) -> Any:
        return params.replace(backlash=tuple(self[f"b{k}"] for k in range(1, 7)))


@register_effect
class ArmEncoderScale(Effect):
    name = "arm_encoder_scale"
    robot = "arm"
    stage = "sensor"
    observed_in = ("camera_pose", "tool_dist")
    description = (
        "Joint encoders (or the gear ratios the controller assumes) are off by a factor: the "
        "reading is s times the motor angle. Realised between the joints and their readings."
    )
    specs = tuple(
        ParamSpec(f"s{k}", "1", 1.0, 0.998, 1.002, f"reading / motor angle of joint {k}")
        for k in range(1, 7)
    )

    def apply_params(self, params: Any) -> Any:
        return params.replace(encoder_scale=tuple(self[f"s{k}"] for k in range(1, 7)))


@register_effect
class ArmToolOffset(Effect):
    name = "arm_tool_offset"
    robot = "arm"
    stage = "tool"
    observed_in = ("tool_dist",)
    description = (
        "The measured tool point (a tracker probe, a TCP) is not where its nominal definition "
        "puts it on the flange: a mounting or tool-length error. Realised by moving the point "
        "the instrument measures, in the flange frame."
    )
    specs = (
        ParamSpec("dx", "m", 0.0, -0.02, 0.02, "offset along flange x"),
        ParamSpec("dy", "m", 0.0, -0.02, 0.02, "offset along flange y"),
        ParamSpec("dz", "m", 0.0, -0.02, 0.02, "offset along flange z (tool length)"),
    )

    def tool_offset(self) -> tuple[float, float, float]:
        """The offset of the measured point in the flange frame (m)."""
        return (self["dx"], self["dy"], self["dz"])


def arm_tool_offset(reality: Reality | None) -> tuple[float, float, float]:
    """Total tool-point offset (flange frame, m) of the :class:`ArmToolOffset` effects in
    ``reality`` (zero without)."""
    total = [0.0, 0.0, 0.0]
    for e in reality.effects if reality is not None else ():
        if isinstance(e, ArmToolOffset):
            total = [a + b for a, b in zip(total, e.tool_offset())]
    return (total[0], total[1], total[2])


@register_effect
class ArmHandEyeError(Effect):
    name = "arm_handeye_error"
    robot = "arm"
    stage = "camera"
    observed_in = ("camera_pose",)
    description = (
        "The flange camera is mounted off its nominal place: translation (flange frame) and a "
        "small rotation (rotation vector in the camera frame). Realised by moving the camera "
        "link of the body."
    )
    specs = (
        ParamSpec("dx", "m", 0.0, -0.01, 0.01, "offset along flange x"),
        ParamSpec("dy", "m", 0.0, -0.01, 0.01, "offset along flange y"),
        ParamSpec("dz", "m", 0.0, -0.01, 0.01, "offset along flange z"),
        ParamSpec("drx", "rad", 0.0, -0.05, 0.05, "rotation about the camera x axis"),
        ParamSpec("dry", "rad", 0.0, -0.05, 0.05, "rotation about the camera y axis"),
        ParamSpec("drz", "rad", 0.0, -0.05, 0.05, "rotation about the optical axis"),
    )

    def apply_params(self, params: Any) -> Any:
        from scipy.spatial.transform import Rotation

        cam = params.camera
        R = Rotation.from_euler("xyz", cam.mount_rpy) * Rotation.from_rotvec(
            [self["drx"], self["dry"], self["drz"]]
        )
        xyz = tuple(v + d for v, d in zip(cam.mount_xyz, (self["dx"], self["dy"], self["dz"])))
        rpy = tuple(float(v) for v in R.as_euler("xyz"))
        return params.replace(camera=cam.replace(mount_xyz=xyz, mount_rpy=rpy))


@register_effect
class ArmCameraIntrinsics(Effect):
    name = "arm_camera_intrinsics"
    robot = "arm"
    stage = "camera"
    observed_in = ("camera_pose",)
    description = (
        "The flange camera's intrinsics differ from the ones the measurement uses: focal "
        "length scale, principal point and radial distortion. Realised in the image formation."
    )
    specs = (
        ParamSpec("f_scale", "1", 1.0, 0.97, 1.03, "true / nominal focal length"),
        ParamSpec("dcx", "px", 0.0, -10.0, 10.0, "principal point offset, x"),
        ParamSpec("dcy", "px", 0.0, -10.0, 10.0, "principal point offset, y"),
        ParamSpec("k1", "1", 0.0, -0.3, 0.3, "added radial distortion k1"),
        ParamSpec("k2", "1", 0.0, -0.2, 0.2, "added radial distortion k2"),
    )

    def apply_params(self, params: Any) -> Any:
        cam = params.camera
        dist = list(cam.dist) + [0.0] * (5 - len(cam.dist))
        dist[0] += self["k1"]
        dist[1] += self["k2"]
        return params.replace(
            camera=cam.replace(
                fx=cam.fx * self["f_scale"],
                fy=cam.fy * self["f_scale"],
                cx=cam.cx + self["dcx"],
                cy=cam.cy + self["dcy"],
                dist=tuple(dist),
            )
        )


# =============================================================================
# climber (realitygap/WallClimb-v0): realised on :class:`realitygap.robots.climber.ClimberParams`
# =============================================================================
@register_effect
class ClimberTetherSag(Effect):
    name = "climber_tether_sag"
    robot = "climber"
    stage = "sensor"
    observed_in = ("tether",)
    description = (
        "The tether sags under its weight: the paid-out length exceeds the straight line by "
        "k·d². Realised in the tether sensor model."
    )
    specs = (ParamSpec("k", "1/m", 0.0, 0.0, 0.005, "extra length per squared distance"),)

    def apply_params(self, params: Any) -> Any:
        return params.replace(tether_sag=self["k"])


@register_effect
class ClimberTetherStretch(Effect):
    name = "climber_tether_stretch"
    robot = "climber"
    stage = "sensor"
    observed_in = ("tether",)
    description = "The tether stretches under tension: reading grows by strain·d."
    specs = (ParamSpec("strain", "1", 0.0, -0.01, 0.01, "elastic strain of the tether"),)

    def apply_params(self, params: Any) -> Any:
        return params.replace(tether_stretch=self["strain"])


@register_effect
class ClimberAnchorError(Effect):
    name = "climber_anchor_error"
    robot = "climber"
    stage = "sensor"
    observed_in = ("tether",)
    description = "The tether anchor is not where the model puts it (world-frame offset)."
    specs = (
        ParamSpec("dx", "m", 0.0, -0.05, 0.05, "anchor offset along world x"),
        ParamSpec("dy", "m", 0.0, -0.05, 0.05, "anchor offset along world y"),
        ParamSpec("dz", "m", 0.0, -0.05, 0.05, "anchor offset along world z"),
    )

    def apply_params(self, params: Any) -> Any:
        return params.replace(anchor_offset=(self["dx"], self["dy"], self["dz"]))


@register_effect
class ClimberSpoolScale(Effect):
    name = "climber_spool_scale"
    robot = "climber"
    stage = "sensor"
    observed_in = ("tether",)
    description = "The spool encoder's length per count is off: reading = s · paid-out length."
    specs = (ParamSpec("s", "1", 1.0, 0.98, 1.02, "reading / paid-out length"),)

    def apply_params(self, params: Any) -> Any:
        return params.replace(spool_scale=self["s"])


@register_effect
class ClimberGyroBias(Effect):
    name = "climber_gyro_bias"
    robot = "climber"
    stage = "sensor"
    observed_in = ("imu",)
    description = "Constant gyroscope bias (body frame) on top of the random turn-on bias."
    specs = tuple(
        ParamSpec(f"b{a}", "rad/s", 0.0, -0.05, 0.05, f"gyro bias about body {a}") for a in "xyz"
    )

    def apply_params(self, params: Any) -> Any:
        return params.replace(gyro_bias=(self["bx"], self["by"], self["bz"]))


@register_effect
class ClimberAccelBias(Effect):
    name = "climber_accel_bias"
    robot = "climber"
    stage = "sensor"
    observed_in = ("imu",)
    description = "Constant accelerometer bias (body frame) on top of the random turn-on bias."
    specs = tuple(
        ParamSpec(f"b{a}", "m/s^2", 0.0, -0.3, 0.3, f"accelerometer bias along body {a}")
        for a in "xyz"
    )

    def apply_params(self, params: Any) -> Any:
        return params.replace(accel_bias=(self["bx"], self["by"], self["bz"]))


@register_effect
class ClimberSurfaceDeviation(Effect):
    name = "climber_surface_deviation"
    robot = "climber"
    stage = "body"
    observed_in = ("surface", "pose_gt", "tether")
    description = (
        "The real blade deviates from its CAD model by a smooth normal displacement (largest "
        "value d, shape from seed). Realised by building the simulated blade from the deformed "
        "surface while the estimator keeps the nominal CAD cloud."
    )
    specs = (
        ParamSpec("d", "m", 0.0, 0.0, 0.02, "largest normal deviation"),
        ParamSpec("seed", "1", 0.0, 0.0, 1000.0, "seed of the deviation's shape"),
    )

    def apply_params(self, params: Any) -> Any:
        return params.replace(surface_deviation=self["d"], surface_seed=int(self["seed"]))


@register_effect
class ClimberAdsorptionGap(Effect):
    name = "climber_adsorption_gap"
    robot = "climber"
    stage = "body"
    observed_in = ("surface", "pose_gt", "imu")
    description = (
        "The adsorption unit rides higher than designed (worn skirt, larger wheels): the body "
        "sits gap m higher than the estimator's h and the suction force drops by exp(-gap/λ). "
        "Realised in the body (wheel radius) and in the adsorption force."
    )
    specs = (ParamSpec("gap", "m", 0.0, -0.005, 0.01, "extra ride height"),)

    def apply_params(self, params: Any) -> Any:
        return params.replace(gap_offset=self["gap"])
