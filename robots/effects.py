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
  (:meth:`Effect.make_ticks_hook`).

A :class:`Reality` is the nominal parameters plus a set of effects with values;
``gym.make(id, reality=...)`` builds the "real" robot from it.
"""

from __future__ import annotations

import difflib
import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
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

    # helpers ------------------------------------------------------------------
    def __getitem__(self, key: str) -> float:
        return self.values[key]

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v:.6g}" for k, v in self.values.items())
        return f"{type(self).__name__}({args})"

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "values": dict(self.values)}


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
@register_effect
class WheelRadiusScale(Effect):
    name = "wheel_radius_scale"
    robot = "diffdrive"
    description = (
        "Both wheels larger or smaller than nominal (tyre wear, inflation): scales distance."
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
    description = (
        "Unequal wheel diameters, E_d = D_R / D_L (Borenstein): the robot curves when driving straight. "
        "The mean diameter is kept."
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
    description = "Effective wheelbase differs from nominal, E_b = b_actual / b_nominal: turns are over/under-rotated."
    specs = (ParamSpec("E_b", "1", 1.0, 0.9, 1.1, "actual / nominal wheelbase"),)

    def apply_params(self, params: DiffDriveParams) -> DiffDriveParams:
        return params.replace(wheelbase=params.wheelbase * self["E_b"])


@register_effect
class CameraMountOffset(Effect):
    name = "camera_mount_offset"
    robot = "diffdrive"
    description = "The camera is mounted off its nominal place: offset in x, y (m) and yaw (rad) in the base frame."
    specs = (
        ParamSpec("dx", "m", 0.0, -0.03, 0.03, "forward offset"),
        ParamSpec("dy", "m", 0.0, -0.03, 0.03, "leftward offset"),
        ParamSpec("dyaw", "rad", 0.0, -0.05, 0.05, "yaw offset"),
    )

    def apply_params(self, params: DiffDriveParams) -> DiffDriveParams:
        cam = params.camera
        x, y, z = cam.mount_xyz
        from dataclasses import replace

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
    description = (
        "Commands reach the motors late (bus, firmware queue): a pure delay of the commanded twist."
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
    description = (
        "Motors do not turn below a minimum wheel-speed command (static friction, PWM dead zone)."
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

    def __init__(self, **values: float):
        super().__init__(**values)
        self._half_b = DiffDriveParams().wheelbase / 2.0

    def apply_params(self, params: DiffDriveParams) -> DiffDriveParams:
        self._half_b = params.wheelbase / 2.0
        return params

    def make_command_hook(self, dt: float) -> CommandHook | None:
        thr = self["threshold"]
        if thr <= 0:
            return None
        hb = self._half_b

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
    description = "The drive reaches a lower top speed than specified (weak battery, motor limit)."
    specs = (
        ParamSpec(
            "v_limit", "m/s", 10.0, 0.2, 10.0, "largest wheel surface speed actually reached"
        ),
    )

    def apply_params(self, params: DiffDriveParams) -> DiffDriveParams:
        self._half_b = params.wheelbase / 2.0
        return params

    def make_command_hook(self, dt: float) -> CommandHook | None:
        lim = self["v_limit"]
        hb = getattr(self, "_half_b", DiffDriveParams().wheelbase / 2.0)

        def hook(v: float, w: float, dt_: float) -> tuple[float, float]:
            vl, vr = v - w * hb, v + w * hb
            vl, vr = max(-lim, min(lim, vl)), max(-lim, min(lim, vr))
            return (vl + vr) / 2.0, (vr - vl) / (2.0 * hb)

        return hook


@register_effect
class EncoderScale(Effect):
    name = "encoder_scale"
    robot = "diffdrive"
    description = "Encoders count more or fewer ticks per revolution than specified (wrong gear ratio in firmware)."
    specs = (ParamSpec("scale", "1", 1.0, 0.9, 1.1, "counted / specified ticks per revolution"),)

    def make_ticks_hook(self) -> TicksHook | None:
        s = self["scale"]
        return lambda left, right: (left * s, right * s)


@dataclass
class Reality:
    """Nominal parameters plus effects: the description of a "real" robot.

    ``Reality()`` is the nominal robot. Effects apply in order.
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
        for effect in self.effects:
            params = effect.apply_params(params)
        return params

    def command_hooks(self, dt: float) -> list[CommandHook]:
        return [h for e in self.effects if (h := e.make_command_hook(dt)) is not None]

    def ticks_hooks(self) -> list[TicksHook]:
        return [h for e in self.effects if (h := e.make_ticks_hook()) is not None]

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "effects": [e.to_dict() for e in self.effects]}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Reality:
        effects = tuple(
            make_effect(e["name"], **e.get("values", {})) for e in data.get("effects", ())
        )
        return cls(effects=effects, name=str(data.get("name", "custom")))
