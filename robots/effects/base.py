"""The effect vocabulary: :class:`Effect`, its parameters, stages, channels, and :class:`Reality`.

An :class:`Effect` is a named, parameterised way in which a real robot differs
from its model. One effect class holds, side by side:

* its parameters (:attr:`Effect.specs`): units, nominal value ("no effect") and
  physical bounds;
* its blind-test range (:attr:`Effect.blind`): the magnitudes the blind
  validation suite hides;
* where it acts (:attr:`Effect.stage`, a :class:`Stage`) and where it can be
  seen (:attr:`Effect.observed_in`, :class:`Channel` values);
* how it is realised in PyBullet — by changing the robot's physical parameters
  before the body is built (:meth:`Effect.apply_params`), by a runtime hook
  between the controller and the body (:meth:`Effect.make_command_hook`) or
  between a sensor and its reader (:meth:`Effect.make_ticks_hook`), or by a
  clock error of a recorded channel (:meth:`Effect.channel_time_offsets`), or by
  the body frame a recorded pose channel tracks (:meth:`Effect.channel_frames`);
* optionally its term in its robot's fast surrogate model
  (:attr:`Effect.surrogate_slot`, :meth:`Effect.surrogate_term`).

A :class:`Reality` is a set of effects with values; ``gym.make(id, reality=...)``
builds the "real" robot from it and the nominal parameters.
"""

from __future__ import annotations

import difflib
import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, ClassVar, NamedTuple, Protocol

from realitygap.core.checks import UnknownNameError

__all__ = [
    "EFFECTS",
    "LIBRARY_VERSION",
    "ROBOT_PARAMS",
    "BlindRange",
    "Channel",
    "CommandHook",
    "Effect",
    "EffectArgumentError",
    "ParamSpec",
    "Reality",
    "Stage",
    "TicksHook",
    "WheelHook",
    "make_effect",
    "pipeline_key",
    "pipeline_order",
    "register_effect",
    "register_robot",
    "robot_of_params",
]

LIBRARY_VERSION = 3
"""Version of the effect library the diagnosis and the blind suite use by default.

Every seeded figure of the diagnosis is stated against one library: an effect
with :attr:`Effect.since` above this version is fully usable (in a
:class:`Reality`, in the surrogate, as an explicit diagnosis candidate) but
joins the default candidate library and the blind suite only when the version
is raised.
"""


class _ValueEnum(str, Enum):
    """A string-valued enum that prints, formats and hashes as its value."""

    def __str__(self) -> str:
        return str(self.value)

    def __format__(self, format_spec: str) -> str:
        return format(str(self.value), format_spec)


class Stage(_ValueEnum):
    """Where in the robot's pipeline an effect acts."""

    COMMAND = "command"
    """Between the controller and the motors (queues, dead-bands, limits)."""
    DRIVE = "drive"
    """In the drive train or the contact with the ground (traction, gear play)."""
    BODY = "body"
    """In the body's geometry or mass (radii, wheelbase, link lengths)."""
    SENSOR = "sensor"
    """Between the physical quantity and its reading (encoders, tether, IMU)."""
    CAMERA = "camera"
    """In the camera's mounting or image formation."""
    TOOL = "tool"
    """In the definition of the measured tool point."""
    TIMING = "timing"
    """In the clocks that stamp recorded channels."""


class Channel(_ValueEnum):
    """A recorded log channel in which an effect can show."""

    POSE_GT = "pose_gt"
    """Ground-truth (motion-capture) pose of the base."""
    POSE_CAM = "pose_cam"
    """Pose of the camera."""
    TICKS = "ticks"
    """Cumulative wheel-encoder counts."""
    CAMERA_POSE = "camera_pose"
    """Arm: pose of the flange camera over the board."""
    TOOL_DIST = "tool_dist"
    """Arm: tool-point distances measured by a tracker."""
    TETHER = "tether"
    """Climber: paid-out tether length."""
    IMU = "imu"
    """Climber: gyroscope and accelerometer."""
    SURFACE = "surface"
    """Climber: ride height over the blade surface."""


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of an effect.

    Attributes
    ----------
    name, unit : str
        Parameter name and SI unit (``"1"`` for ratios).
    nominal : float
        The value at which the effect does nothing.
    low, high : float
        Physical bounds of the parameter.
    description : str
    log_scale : bool
        The parameter spans decades (a speed limit): fits search it in log units and
        difference it with a step relative to its value.
    """

    name: str
    unit: str
    nominal: float
    low: float
    high: float
    description: str
    log_scale: bool = False


class EffectArgumentError(ValueError, TypeError):
    """An effect parameter of the wrong kind: an unknown name, or a value that is no real number.

    A :class:`ValueError`, as every refused effect parameter is, and a :class:`TypeError`,
    as Python's own unexpected keyword argument and wrong-typed value are.
    """


_ROUND_OFF = 1e-9
"""Relative slack (of a parameter's range) within which a value past a bound is that bound:
a fit's transform to and from range positions may land an ulp outside."""


def _check_param(effect: str, spec: ParamSpec, value: Any) -> float:
    """``value`` of parameter ``spec`` of effect ``effect`` as a float within its bounds."""
    unit = "" if spec.unit == "1" else f" {spec.unit}"
    bounds = f"[{spec.low:g}, {spec.high:g}]{unit}"
    where = f"effect {effect!r}: parameter {spec.name!r} ({spec.description}; unit {spec.unit!r})"
    fix = f"Fix: pass a real number in {bounds}; {spec.nominal:g}{unit} is nominal (no effect)"
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        shown = repr(value) if len(repr(value)) <= 60 else repr(value)[:57] + "..."
        raise EffectArgumentError(
            f"{where} must be a real finite number in {bounds}, got {shown} "
            f"({type(value).__name__}). {fix}"
        )
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{where} must be a real finite number in {bounds}, got {v!r}. {fix}")
    slack = _ROUND_OFF * (spec.high - spec.low)
    if not spec.low - slack <= v <= spec.high + slack:
        raise ValueError(f"{where} = {v:g}{unit} is outside its physical bounds {bounds}. {fix}")
    return min(max(v, spec.low), spec.high)


class BlindRange(NamedTuple):
    """Magnitude of one parameter in the blind suite.

    The deviation from nominal is drawn as ``|Δ| ~ U(low, high)``, with a random
    sign when ``symmetric``. With ``absolute`` the draw is the parameter's value
    itself, not a deviation (a slip coefficient, a speed limit).
    """

    param: str
    low: float
    high: float
    symmetric: bool
    absolute: bool = False


CommandHook = Callable[[float, float, float], tuple[float, float]]
"""``hook(v, w, dt) -> (v, w)``: transforms the commanded body twist each control step."""

TicksHook = Callable[[float, float], tuple[float, float]]
"""``hook(angle_left, angle_right) -> (angle_left, angle_right)``: what the encoders see (rad)."""


class WheelHook(Protocol):
    """Per-wheel hook between the firmware's wheel-speed commands, the wheels and the encoders.

    For effects a body-twist hook cannot express: the wheels turn one way and
    the ground moves another (traction slip). One fresh, stateful hook per
    episode.
    """

    def command(self, w_left: float, w_right: float) -> tuple[float, float]:
        """Wheel speeds (rad/s) the firmware commands → the rolling speeds the motors get."""
        ...

    def encoder(self, a_left: float, a_right: float) -> tuple[float, float]:
        """Rolling angles (rad) of the wheels on the floor → the angles the wheels turned."""
        ...

    def rolling_from_encoder(self, angles: Any) -> Any:
        """Turned wheel angles (N, 2) (rad, one row per control period) → rolling angles (N, 2)."""
        ...


class Effect:
    """Base class of all effects.

    Subclasses set :attr:`name`, :attr:`robot`, :attr:`description`,
    :attr:`specs`, :attr:`stage`, :attr:`observed_in`, usually :attr:`blind`,
    and override the realisations they need.

    Parameters
    ----------
    **values : float
        Parameter values; absent parameters are nominal.

    Raises
    ------
    ValueError
        An unknown parameter name, or a value that is not a real finite number
        within the parameter's physical bounds (:meth:`checked_values`).
    """

    name: ClassVar[str] = ""
    robot: ClassVar[str] = ""
    description: ClassVar[str] = ""
    specs: ClassVar[tuple[ParamSpec, ...]] = ()
    stage: ClassVar[Stage] = Stage.BODY
    observed_in: ClassVar[tuple[Channel, ...]] = (Channel.POSE_GT,)
    blind: ClassVar[tuple[BlindRange, ...]] = ()
    """Magnitudes the blind suite hides; empty: the suite does not draw this effect."""
    since: ClassVar[int] = 1
    """Library version that introduced the effect (see :data:`LIBRARY_VERSION`)."""
    surrogate_slot: ClassVar[Enum | None] = None
    """Where the effect enters its robot's surrogate model; ``None``: no surrogate term."""
    surrogate_order: ClassVar[int] = 0
    """Order among the terms of one slot (lower first; ties in registration order)."""
    surrogate_example: ClassVar[tuple[tuple[str, float], ...]] = ()
    """A typical ``(param, value)`` set at which the surrogate term is checked against PyBullet."""
    surrogate_tolerance: ClassVar[float] = 0.08
    """Bound on the surrogate's relative error of the effect's change of the features."""
    scale: ClassVar[str] = "window"
    """Where the effect shows best: ``"run"`` for a constant factor on the distance travelled
    or the angle turned (a wheel size, a wheelbase, an encoder's scale), whose errors add
    up along a run; ``"window"`` for one that shapes the motion within seconds (a latency,
    a lag, a limit). The gap budget fits and scores an effect at its scale."""

    def __init__(self, **values: float):
        self.values: dict[str, float] = self.checked_values(values)

    @classmethod
    def checked_values(cls, values: Mapping[str, Any]) -> dict[str, float]:
        """Every parameter's value, checked against its :class:`ParamSpec`; absent ones nominal.

        The one check of an effect's parameters: the constructor (and so
        :func:`make_effect` and :meth:`Reality.from_dict`) calls it.

        Parameters
        ----------
        values : mapping of str to float
            Parameter name → value in the parameter's unit.

        Returns
        -------
        dict of str to float
            Every parameter of :attr:`specs`, in their order. A value within
            round-off (``1e-9`` of the range) outside a bound is the bound.

        Raises
        ------
        EffectArgumentError
            (a :class:`ValueError` and a :class:`TypeError`) An unknown parameter
            name (the message lists the known ones and suggests a close one), or a
            value that is not a real number (``bool``, ``str``, ``complex``).
        ValueError
            A NaN or infinite value, or one outside the parameter's physical bounds
            ``[low, high]``.
        """
        known = {s.name: s for s in cls.specs}
        unknown = [k for k in values if k not in known]
        if unknown:
            bad = unknown[0]
            close = difflib.get_close_matches(str(bad), list(known), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            listing = ", ".join(f"{s.name} ({s.unit}, {s.low:g} … {s.high:g})" for s in cls.specs)
            raise EffectArgumentError(
                f"effect {cls.name!r} has no parameter {bad!r}{hint} "
                f"(parameters: {listing or 'none'}). Fix: pass only these names"
            )
        return {s.name: _check_param(cls.name, s, values.get(s.name, s.nominal)) for s in cls.specs}

    # realisations (identity by default) ---------------------------------------
    def apply_params(self, params: Any) -> Any:
        """Return the physical parameters of the robot with this effect built in."""
        return params

    def make_command_hook(self, dt: float, nominal: Any = None) -> CommandHook | None:
        """A fresh, stateful command hook for one episode, or ``None``.

        Parameters
        ----------
        dt : float
            Control period, s.
        nominal : robot parameters, optional
            What the robot's firmware believes (its nominal geometry); hooks
            acting on the firmware's wheel-speed commands use it whatever other
            effects change in the body. ``None``: the robot's default parameters.
        """
        return None

    def make_ticks_hook(self) -> TicksHook | None:
        """A fresh encoder hook for one episode, or ``None``."""
        return None

    def make_wheel_hook(self, dt: float, nominal: Any = None) -> WheelHook | None:
        """A fresh per-wheel hook for one episode (see :class:`WheelHook`), or ``None``.

        Parameters
        ----------
        dt : float
            Control period, s.
        nominal : robot parameters, optional
            What the robot's firmware believes.
        """
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

    def channel_frames(self) -> dict[str, tuple[float, float, float]]:
        """Body frames that recorded pose channels track, ``{channel: (x, y, yaw)}``.

        A channel with frame ``F`` (m, m, rad, in the body frame) records the
        pose of that frame, not of the body origin
        (:func:`~realitygap.core.geometry.reframe_track`).
        """
        return {}

    # surrogate -----------------------------------------------------------------
    @classmethod
    def surrogate_term(cls, x: Any, p: Mapping[str, Any], ctx: Any) -> Any:
        """The effect's term in its robot's surrogate model.

        Parameters
        ----------
        x
            The quantity at :attr:`surrogate_slot` (its shape is fixed by the
            slot), before this term.
        p : mapping
            Parameter name → value array over the batch, shape (B,).
        ctx
            The surrogate's context (control period, nominal parameters, batch).

        Returns
        -------
        The quantity after this term, same layout as ``x``.
        """
        raise NotImplementedError(f"effect {cls.name!r} has no surrogate term")

    # helpers ------------------------------------------------------------------
    def __getitem__(self, key: str) -> float:
        return self.values[key]

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v:.6g}" for k, v in self.values.items())
        return f"{type(self).__name__}({args})"

    def to_dict(self) -> dict[str, Any]:
        """``{"name": ..., "values": {param: value}}`` (JSON-able)."""
        return {"name": self.name, "values": dict(self.values)}

    @classmethod
    def spec(cls, param: str) -> ParamSpec:
        """The :class:`ParamSpec` of parameter ``param``."""
        for s in cls.specs:
            if s.name == param:
                return s
        raise KeyError(f"effect {cls.name!r} has no parameter {param!r}")

    @classmethod
    def physical_bounds(cls) -> dict[str, tuple[float, float]]:
        """Physical bounds ``{param: (low, high)}`` in the parameters' units.

        These, not ranges derived from a log, are where a fit may look: a
        value the logged commands never reach (a top speed below the largest
        commanded speed) is still a physical value.
        """
        return {s.name: (s.low, s.high) for s in cls.specs}

    def is_nominal(self) -> bool:
        """True when every parameter sits at its nominal value (the effect does nothing)."""
        return all(self.values[s.name] == s.nominal for s in self.specs)


EFFECTS: dict[str, type[Effect]] = {}
"""Every registered effect class by name, in registration order."""


ROBOT_PARAMS: dict[str, str] = {}
"""Robot kind → qualified name of the physical-parameter class its effects act on
(``"diffdrive"`` → ``"realitygap.robots.diffdrive.DiffDriveParams"``); each robot's
effect module registers its robot (:func:`register_robot`)."""


def register_robot(robot: str, params_class: str) -> None:
    """Declare that ``robot``'s effects act on instances of ``params_class``.

    Parameters
    ----------
    robot : str
        The robot kind, as the effects' :attr:`Effect.robot` names it.
    params_class : str
        Qualified name ``"package.module.Class"`` of its physical parameters (a name,
        so that registering does not import the robot's simulation).
    """
    ROBOT_PARAMS[robot] = params_class


def robot_of_params(params: Any) -> str | None:
    """The robot kind whose physical parameters ``params`` are, or ``None`` if unregistered."""
    names = {f"{c.__module__}.{c.__qualname__}" for c in type(params).__mro__}
    return next((robot for robot, cls in ROBOT_PARAMS.items() if cls in names), None)


def _robot_effects(robot: str) -> str:
    return ", ".join(n for n, c in EFFECTS.items() if c.robot == robot) or "none"


def register_effect(cls: type[Effect]) -> type[Effect]:
    """Class decorator adding an effect to the library."""
    if not cls.name:
        raise ValueError(f"{cls.__name__} needs a name")
    if cls.name in EFFECTS and EFFECTS[cls.name] is not cls:
        raise ValueError(f"effect name {cls.name!r} is taken by {EFFECTS[cls.name].__name__}")
    for r in cls.blind:
        cls.spec(r.param)
    EFFECTS[cls.name] = cls
    return cls


def make_effect(name: str, **values: float) -> Effect:
    """Instantiate library effect ``name``; suggests close names on a typo.

    Raises
    ------
    KeyError
        An unknown effect name.
    TypeError
        A name that is not a string.
    ValueError
        A parameter the effect does not have, or a value outside its physical
        bounds (:meth:`Effect.checked_values`).
    """
    if not isinstance(name, str):
        raise TypeError(
            f"make_effect's effect name must be a str, got {name!r} ({type(name).__name__}). "
            f"Known effects: {', '.join(sorted(EFFECTS))}"
        )
    if name not in EFFECTS:
        close = difflib.get_close_matches(name, list(EFFECTS), n=3)
        hint = f" Did you mean {', '.join(map(repr, close))}?" if close else ""
        raise UnknownNameError(
            f"unknown effect {name!r}.{hint} Known: {', '.join(sorted(EFFECTS))}"
        )
    return EFFECTS[name](**values)


def pipeline_key(cls: type[Effect]) -> tuple[int, int]:
    """Where an effect class acts along its robot's pipeline: its
    :attr:`Effect.surrogate_slot` (in the order its enum lists the slots), then its
    :attr:`Effect.surrogate_order`; ``(-1, 0)`` for a class without a slot. The
    surrogate applies its terms in this order, and :func:`pipeline_order` puts a
    reality's effects in it."""
    slot = cls.surrogate_slot
    if slot is None:
        return (-1, 0)
    return (list(type(slot)).index(slot), cls.surrogate_order)


def pipeline_order(effects: Sequence[Effect]) -> tuple[Effect, ...]:
    """``effects`` in the order they act along the robot's pipeline (:func:`pipeline_key`).

    The sort is stable, so effects without a slot, and effects whose terms commute
    (equal keys), keep the order they were given in. The order matters where hooks do
    not commute: a dead zone or a speed limit before a lag is not the same drive as
    after it.
    """
    return tuple(sorted(effects, key=lambda e: pipeline_key(type(e))))


@dataclass
class Reality:
    """Nominal parameters plus effects: the description of a "real" robot.

    ``Reality()`` is the nominal robot. Effects act in the order of the robot's
    pipeline, whatever order they are given in (:func:`pipeline_order`): a motor's
    dead zone acts on the set-point before the motor's lag smooths it, as it does
    in the surrogate model. Hooks that act on the firmware's commands see the
    *nominal* geometry, handed to :meth:`command_hooks`.
    """

    effects: tuple[Effect, ...] = ()
    name: str = "nominal"
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        effects = tuple(self.effects)  # any iterable, read once
        for e in effects:
            if not isinstance(e, Effect):
                raise TypeError(f"Reality.effects must hold Effect objects, got {type(e).__name__}")
        seen: set[str] = set()
        for e in effects:
            if e.name in seen:
                values = [dict(x.values) for x in effects if x.name == e.name]
                raise ValueError(
                    f"a reality holds each effect once, but effect {e.name!r} comes "
                    f"{len(values)} times ({values}). Fix: keep one {e.name!r} with the "
                    "combined values"
                )
            seen.add(e.name)
        robots = {e.robot for e in effects}
        if len(robots) > 1:
            first = effects[0]
            other = next(e for e in effects if e.robot != first.robot)
            raise ValueError(
                f"a reality describes one robot, but effect {first.name!r} is for the "
                f"{first.robot} and effect {other.name!r} for the {other.robot}. Fix: build one "
                f"Reality per robot; effects for {first.robot}: {_robot_effects(first.robot)}"
            )
        self.effects = pipeline_order(effects)

    @property
    def robot(self) -> str | None:
        """The robot kind the effects are for; ``None`` for the nominal reality (no effects)."""
        return self.effects[0].robot if self.effects else None

    def check_robot(self, robot: str) -> None:
        """Refuse effects that are not for ``robot``.

        Parameters
        ----------
        robot : str
            The kind of the robot this reality is built onto (``"diffdrive"``, ``"arm"``,
            ``"climber"``).

        Raises
        ------
        ValueError
            An effect whose :attr:`Effect.robot` is another kind.
        """
        for e in self.effects:
            if e.robot != robot:
                raise ValueError(
                    f"effect {e.name!r} is for the {e.robot}; this reality is built onto a "
                    f"{robot} robot. Fix: use effects for {robot}: {_robot_effects(robot)}"
                )

    def _check_onto(self, params: Any) -> None:
        """:meth:`check_robot` against the robot whose parameters ``params`` are, if registered."""
        robot = robot_of_params(params)
        if robot is not None:
            self.check_robot(robot)

    def apply_params(self, params: Any) -> Any:
        """The physical parameters of the real robot, built from the nominal ``params``.

        Raises
        ------
        ValueError
            ``params`` are a registered robot's (:func:`register_robot`) and an effect is
            for another robot (:meth:`check_robot`).
        """
        self._check_onto(params)
        for effect in self.effects:
            params = effect.apply_params(params)
        return params

    def command_hooks(self, dt: float, nominal: Any) -> list[CommandHook]:
        """Fresh command hooks for one episode, in effect order.

        Parameters
        ----------
        dt : float
            Control period, s.
        nominal : robot parameters
            The nominal parameters the firmware believes (not the real body's).

        Raises
        ------
        ValueError
            An effect for another robot than ``nominal``'s (:meth:`check_robot`).
        """
        self._check_onto(nominal)
        return [h for e in self.effects if (h := e.make_command_hook(dt, nominal)) is not None]

    def wheel_hooks(self, dt: float, nominal: Any) -> list[WheelHook]:
        """Fresh per-wheel hooks for one episode, in effect order (checked as
        :meth:`command_hooks`)."""
        self._check_onto(nominal)
        return [h for e in self.effects if (h := e.make_wheel_hook(dt, nominal)) is not None]

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

    def channel_frames(self) -> dict[str, tuple[float, float, float]]:
        """Composed body frame per recorded pose channel (see :meth:`Effect.channel_frames`)."""
        from realitygap.core.geometry import se2_compose

        out: dict[str, tuple[float, float, float]] = {}
        for e in self.effects:
            for channel, frame in e.channel_frames().items():
                prev = out.get(channel, (0.0, 0.0, 0.0))
                x, y, _ = (float(v) for v in se2_compose(prev, frame))
                out[channel] = (x, y, float(prev[2]) + float(frame[2]))
        return out

    @property
    def effect_names(self) -> tuple[str, ...]:
        """Names of the effects, in the pipeline's order."""
        return tuple(e.name for e in self.effects)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description; :meth:`from_dict` rebuilds it."""
        return {"name": self.name, "effects": [e.to_dict() for e in self.effects]}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Reality:
        """A :class:`Reality` from its dict form: :meth:`to_dict` output
        (``{"name": ..., "effects": [{"name": ..., "values": {...}}, ...]}``) or a reality
        file's content (both read by :func:`reality_from_file_form`),
        or the short form ``{"effect_name": {"param": value, ...}, ...}``.

        Raises
        ------
        KeyError
            An unknown effect name in the short form (with close names).
        TypeError, ValueError
            Not a mapping, an entry of the wrong shape, an unknown key, or a parameter
            value the effect refuses (:func:`make_effect`).
        """
        if not isinstance(data, Mapping):
            raise TypeError(f"a Reality's dict form must be a mapping, got {type(data).__name__}")
        if "effects" in data:  # to_dict() form, or a reality file's (one reader for both)
            return reality_from_file_form(data, "reality")
        effects = []
        for effect_name, values in data.items():  # short form: effect name -> values
            if not isinstance(values, Mapping):
                raise TypeError(
                    f"effect {effect_name!r}: its values must be a mapping "
                    f"{{'param': value}}, got {values!r} ({type(values).__name__})"
                )
            effects.append(make_effect(effect_name, **dict(values)))
        return cls(effects=tuple(effects), name="custom")


REALITY_SCHEMA = "realitygap.reality/2"
"""Version of a reality file's layout (:mod:`~realitygap.robots.effects.twin`)."""
REALITY_EXAMPLE = (
    '{"schema": "realitygap.reality/2", "name": "mine", "effects": [{"name": '
    '"command_latency", "values": {"delay": 0.06}}]}'
)
_FILE_KEYS = {"written_by", "schema", "name", "robot", "effects", "nominal", "source", "meta"}
_ENTRY_KEYS = {"name", "values", "parameters", "origin"}


def reality_from_file_form(data: Any, where: str = "reality") -> Reality:
    """The :class:`Reality` (fitted values) of a reality file's content: :meth:`Reality.to_dict`'s
    form or schema :data:`REALITY_SCHEMA` (whose uncertainty
    :meth:`~realitygap.robots.effects.twin.Twin.from_dict` reads beside it). The one reader of
    the layout: its keys, its schema, each entry's shape and every value
    (:func:`make_effect`) are checked, each error naming ``where`` and the entry.

    Raises
    ------
    ValueError
        Anything the layout does not allow.
    """
    if not isinstance(data, Mapping):
        raise ValueError(
            f"{where}: a reality file holds an object, got {type(data).__name__}. "
            f"Fix: write it as {REALITY_EXAMPLE}"
        )
    unknown = sorted(set(map(str, data)) - _FILE_KEYS)
    if unknown:
        raise ValueError(
            f"{where}: unknown key(s) {unknown}; a reality file has "
            f"{sorted(_FILE_KEYS - {'written_by'})}, e.g. {REALITY_EXAMPLE}. Fix: remove or "
            "rename them"
        )
    schema = data.get("schema", REALITY_SCHEMA)
    if schema not in (REALITY_SCHEMA, "realitygap.reality/1"):
        raise ValueError(
            f"{where}: schema {schema!r} is not one this version reads ({REALITY_SCHEMA!r}). "
            "Fix: export the file again with this version"
        )
    entries = data.get("effects", [])
    if not isinstance(entries, list):
        raise ValueError(
            f'{where}: \'effects\' must be a list of {{"name": ..., "values": {{...}}}} '
            f"objects, got {type(entries).__name__}. Fix: write it as in {REALITY_EXAMPLE}"
        )
    effects = []
    for i, item in enumerate(entries):
        at = f"{where}: effects[{i}]"
        if not isinstance(item, Mapping) or not isinstance(item.get("name"), str):
            raise ValueError(
                f"{at} must be an object with a 'name' (str) and 'values', got "
                f"{item!r:.60}. Fix: write it as in {REALITY_EXAMPLE}"
            )
        extra = sorted(set(map(str, item)) - _ENTRY_KEYS)
        if extra:
            raise ValueError(f"{at} ({item['name']!r}): unknown key(s) {extra}")
        values = item.get("values", {})
        if not isinstance(values, Mapping):
            raise ValueError(
                f"{at} ({item['name']!r}): 'values' must be an object of parameter: "
                f"number, got {values!r:.60}"
            )
        try:
            effects.append(make_effect(item["name"], **{str(k): v for k, v in values.items()}))
        except KeyError as exc:
            raise ValueError(f"{at}: {exc.args[0]}") from None
        except (ValueError, TypeError) as exc:
            raise ValueError(f"{at}: {exc}") from None
    try:
        reality = Reality(effects=tuple(effects), name=str(data.get("name", "custom")))
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{where}: {exc}") from None
    robot = data.get("robot")
    if robot is not None and reality.robot is not None and robot != reality.robot:
        raise ValueError(
            f"{where}: 'robot' is {robot!r} but the effects are for the {reality.robot}. "
            "Fix: correct 'robot' or the effects"
        )
    return reality
