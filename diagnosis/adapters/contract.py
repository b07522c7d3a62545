"""Robot adapters: what the generic diagnosis needs to know about one kind of robot.

An adapter bundles

* the **effect library** it may attribute a gap to (effects of
  :mod:`realitygap.robots.effects` registered for the robot),
* the **replay** of a log in PyBullet with the nominal robot plus effects,
* the **channels** it reads and the window **features** compared between real
  and simulated episodes (:class:`~realitygap.diagnosis.problem.features.FeatureSchema`:
  feature groups with columns, units and scales, and the motion **regimes**),
* the **probe manoeuvres** its identifiability advice may suggest,
* a fast **surrogate** of the replay for the fit, and
* the **blind-log recorder** and noise model of the validation suite.

The diagnosis (:mod:`realitygap.diagnosis.diagnose`) only talks to this
interface. :data:`ADAPTER_CLASSES` is the one place that maps robot names to
adapters. A new robot is

1. one effects module (its :class:`~realitygap.robots.effects.Effect` classes),
2. one adapter module: a subclass of :class:`AdapterBase` that sets ``robot``,
   ``channels``, ``schema`` and ``surrogate_effects``, keeps what it needs about
   a prepared log in a :class:`LogContext` subclass and implements ``check``,
   ``prepare``, ``replay_features``, ``log_features``, ``surrogate_features``,
   ``probe_manoeuvres``, ``probe_features`` and ``record_blind_logs`` (the
   blind-test ranges come from the effect classes themselves),
3. one line in :data:`ADAPTER_CLASSES`.

The adapters are :class:`~realitygap.diagnosis.adapters.diffdrive.adapter.DiffDriveAdapter`,
:class:`~realitygap.diagnosis.adapters.arm.adapter.ArmAdapter` and
:class:`~realitygap.diagnosis.adapters.climber.adapter.ClimberAdapter`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.logs.log import ChannelSpec, Log, LogError
from realitygap.diagnosis.problem.features import (
    FeatureSchema,
    FeatureSettings,
    window_bounds,
)
from realitygap.robots.effects import (
    EFFECTS,
    BlindRange,
    Reality,
    Stage,
    blind_ranges,
    library,
)
from realitygap.robots.simulation import SimSettings

if TYPE_CHECKING:
    from realitygap.diagnosis.validation.suite import SuiteSettings

FloatArray = npt.NDArray[np.float64]
Features = dict[str, FloatArray]

__all__ = [
    "AdapterBase",
    "Drive",
    "HiddenTable",
    "LogContext",
    "PreparedLog",
    "RobotAdapter",
    "WheelDrivenAdapter",
]

HiddenTable = dict[str, tuple[BlindRange, ...]]
"""Blind-test magnitudes per effect: ``(param, low, high, symmetric)`` per parameter."""


class Drive(str, Enum):
    """What drives a replay: the logged commands, or the logged actuator readings (a wheeled
    robot's encoder ticks; an adapter without such readings replays ``COMMANDS`` only)."""

    COMMANDS = "commands"
    TICKS = "ticks"


@dataclass
class LogContext:
    """What an adapter keeps about one prepared log besides its features.

    Each adapter subclasses this with its own inputs (parameters, surrogate
    inputs, poses, …).

    Attributes
    ----------
    sim : SimSettings
        Replay fidelity of this log.
    """

    sim: SimSettings

    def window_motion(self, bounds: npt.NDArray[np.int64]) -> FloatArray | None:
        """The motion of each window in the six columns of
        :data:`~realitygap.diagnosis.problem.problem.MOTION_COLUMNS`, (M, 6), or ``None``."""
        return None


@dataclass
class PreparedLog:
    """One log made ready for the diagnosis.

    Attributes
    ----------
    log : Log
        The (resampled, checked) real log.
    split : {"train", "holdout"}
        Role of the whole log; with ``window_split`` some windows of a train
        log may be held out instead (single-log diagnoses).
    bounds : ndarray, shape (M, 2)
        Window start / end rows.
    regimes : list of str, length M
    real : dict of group to ndarray, shape (M, k)
        Features of the real log.
    nominal : dict of group to ndarray, shape (M, k)
        Features of the nominal PyBullet replay.
    replay_log : Log
        The nominal replay itself.
    holdout_windows : ndarray of bool, shape (M,)
        Windows scored as held-out data.
    schema : FeatureSchema
        The adapter's feature groups and regimes.
    context : LogContext
        Adapter-specific inputs (surrogate inputs, parameters, twist).
    bias : dict of group to ndarray, shape (M, k)
        PyBullet nominal minus surrogate nominal (the surrogate's own error).
    """

    log: Log
    split: str
    bounds: npt.NDArray[np.int64]
    regimes: list[str]
    real: Features
    nominal: Features
    replay_log: Log
    holdout_windows: npt.NDArray[np.bool_]
    schema: FeatureSchema
    context: LogContext
    bias: Features = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.log.name

    @property
    def groups(self) -> list[str]:
        """Feature groups present in both the real log and its replay, in schema order."""
        return [g for g in self.schema.names if g in self.real and g in self.nominal]


class RobotAdapter(Protocol):
    """What the diagnosis needs from a robot (see the module docstring)."""

    robot: str
    channels: tuple[ChannelSpec, ...]
    schema: FeatureSchema
    stage_group: str
    drive_stages: tuple[str, str] | None
    transient_detection: bool

    def effect_names(self) -> tuple[str, ...]: ...

    def check(self, log: Log, drive: Drive) -> Log: ...

    def prepare(
        self,
        log: Log,
        *,
        split: str,
        drive: Drive,
        features_settings: FeatureSettings,
        sim: SimSettings | None,
    ) -> PreparedLog: ...

    def observable(self, effect: str, prepared: Sequence[PreparedLog], drive: Drive) -> str: ...

    def probe_manoeuvres(self) -> dict[str, str]: ...

    def log_features(self, prepared: PreparedLog, log: Log) -> Features: ...

    def replay_features(
        self, prepared: PreparedLog, values: Mapping[str, float], drive: Drive, sim: SimSettings
    ) -> tuple[Features, Log]: ...

    def surrogate_features(
        self, prepared: PreparedLog, values: Mapping[str, npt.ArrayLike], drive: Drive
    ) -> Features: ...

    def probe_features(
        self, manoeuvre: str, params_like: PreparedLog, values: Mapping[str, npt.ArrayLike]
    ) -> tuple[Features, list[str]]: ...

    def stage_residuals(self, prepared: PreparedLog) -> dict[str, FloatArray]: ...

    def noise_levels(
        self, prepared: Sequence[PreparedLog], settings: FeatureSettings
    ) -> dict[str, float] | None: ...

    def sample_noise_levels(
        self, prepared: Sequence[PreparedLog], settings: FeatureSettings
    ) -> dict[str, dict[str, float]] | None: ...

    def hidden_effects(self) -> HiddenTable: ...

    def fitted_robot(
        self, prepared: Sequence[PreparedLog], effects: Sequence[str], values: Mapping[str, float]
    ) -> dict[str, Any] | None: ...

    def baseline_nuisances(
        self, prepared: Sequence[PreparedLog], drive: Drive
    ) -> dict[str, tuple[float, float, str]]: ...

    def link_logs(self, prepared: Sequence[PreparedLog], drive: Drive) -> dict[str, Any]: ...
    def actuator_conventions(
        self, prepared: Sequence[PreparedLog], drive: Drive
    ) -> dict[str, str]: ...

    def actuator_convention(self, log: Log) -> str: ...

    def with_actuator_convention(self, log: Log, name: str) -> Log: ...

    def fit_actuator_limits(self, logs: Sequence[Log], name: str) -> Any: ...

    def with_actuator_limits(self, log: Log, fit: Any) -> Log: ...

    def alias_groups(
        self,
        prepared: Sequence[PreparedLog],
        threshold: float = 0.95,
        effects: Sequence[str] | None = None,
    ) -> list[dict[str, Any]]: ...

    def record_blind_logs(
        self, reality: Reality, rng: np.random.Generator, settings: SuiteSettings
    ) -> tuple[list[Log], list[Log]]: ...

    def close(self) -> None: ...


class AdapterBase:
    """What every adapter shares: its effect library, the robot check, observability.

    Subclasses set :attr:`robot`, :attr:`channels` (the log channels it
    reads), :attr:`schema` (feature groups and regimes), :attr:`surrogate_effects`
    (effects the fast surrogate models) and may give :attr:`unobservable`
    (effect → why these channels cannot show it, whatever the log) and
    :attr:`stage_group` (the feature group whose columns its
    :meth:`stage_residuals` use) and :attr:`drive_stages` (the two of those stages
    a command-driven gap splits into: up to the actuators, and after them).
    """

    robot: str = ""
    channels: tuple[ChannelSpec, ...] = ()
    schema: FeatureSchema = FeatureSchema((), ())
    surrogate_effects: tuple[str, ...] = ()
    unobservable: Mapping[str, str] = {}
    stage_group: str = ""
    drive_stages: tuple[str, str] | None = None

    def stage_residuals(self, prepared: PreparedLog) -> dict[str, FloatArray]:
        """Residuals of the pipeline stages inside the real log, per window, in the columns of
        the feature group :attr:`stage_group` (none by default)."""
        return {}

    def residual_structure(
        self, problem: Any, values: Mapping[str, float], desc: dict[str, Any]
    ) -> dict[str, Any]:
        """The verdict's description of a held-out residual (``desc``, of
        :func:`~realitygap.diagnosis.problem.residual.describe_residual`) with this robot's own
        structure test added, for the model at ``values`` (``{}``: the nominal); ``desc``
        unchanged by default."""
        return desc

    def noise_levels(
        self, prepared: Sequence[PreparedLog], settings: FeatureSettings
    ) -> dict[str, float] | None:
        """Measurement noise per group in feature-scale units, or ``None``: then the
        window-to-window spread of the residual stands for the noise."""
        return None

    def sample_noise_levels(
        self, prepared: Sequence[PreparedLog], settings: FeatureSettings
    ) -> dict[str, dict[str, float]] | None:
        """Noise of window features that a sensor's own samples show, per group and column
        in feature-scale units, or ``None`` (no such measurement): what the verdict asks
        before it calls a residual that passes for white "noise"
        (:func:`~realitygap.diagnosis.problem.residual.above_sample_noise`)."""
        return None

    def fitted_robot(
        self, prepared: Sequence[PreparedLog], effects: Sequence[str], values: Mapping[str, float]
    ) -> dict[str, Any] | None:
        """The robot a verdict's ``effects`` at ``values`` describe, in the robot's own
        quantities (per wheel, per joint), or ``None`` where the adapter reads none."""
        return None

    def hidden_effects(self) -> HiddenTable:
        """Blind-test magnitudes of the effects the validation suite hides in this robot
        (each effect's :attr:`~realitygap.robots.effects.Effect.blind` ranges)."""
        return blind_ranges(self.robot)

    def record_blind_logs(
        self, reality: Reality, rng: np.random.Generator, settings: SuiteSettings
    ) -> tuple[list[Log], list[Log]]:
        """Training and held-out logs of the robot ``reality`` for one blind case."""
        raise NotImplementedError(f"the blind suite cannot record {self.robot!r} logs")

    transient_detection: bool = False
    """Whether the logs are time series in which disturbed windows (stalls, bumps, lost
    markers) are detected and set aside (:mod:`~realitygap.diagnosis.stages.transients`)."""

    def baseline_nuisances(
        self, prepared: Sequence[PreparedLog], drive: Drive
    ) -> dict[str, tuple[float, float, str]]:
        """Nuisances fitted first as the calibrated baseline
        (:mod:`~realitygap.diagnosis.stages.baseline`): ``"effect.param"`` → (low, high, what it is);
        none by default."""
        return {}

    def link_logs(self, prepared: Sequence[PreparedLog], drive: Drive) -> dict[str, Any]:
        """Relate prepared logs of one robot to each other once all are prepared.

        An adapter whose logs may declare different nominal parameters for the same
        physical robot puts their effects on one reference here; returns a JSON-able
        description of what it did (empty: nothing to relate, the default).
        """
        return {}

    def actuator_conventions(self, prepared: Sequence[PreparedLog], drive: Drive) -> dict[str, str]:
        """Discrete conventions of the nominal's actuator response the baseline chooses among
        (name → what it is; :mod:`~realitygap.diagnosis.stages.baseline`); none by default."""
        return {}

    def actuator_convention(self, log: Log) -> str:
        """The actuator convention ``log`` is replayed with (``""``: the adapter has none)."""
        return ""

    def with_actuator_convention(self, log: Log, name: str) -> Log:
        """``log`` replayed with the actuator convention ``name`` (itself by default)."""
        return log

    def fit_actuator_limits(self, logs: Sequence[Log], name: str) -> Any:
        """Continuous limits of the actuator convention ``name`` fitted to ``logs`` (the
        training logs), or ``None`` when the adapter fits none (default)."""
        return None

    def with_actuator_limits(self, log: Log, fit: Any) -> Log:
        """``log`` replayed with the limits ``fit`` of :meth:`fit_actuator_limits` (itself by
        default)."""
        return log

    def alias_groups(
        self,
        prepared: Sequence[PreparedLog],
        threshold: float = 0.95,
        effects: Sequence[str] | None = None,
    ) -> list[dict[str, Any]]:
        """Groups of effects this robot's physics makes alike, each with the pairs that are
        aliases on ``prepared`` (``{"effects", "why", "separate_by", "pairs", "aliases"}``);
        none by default. ``effects`` keeps only the groups containing one of them."""
        return []

    def close(self) -> None:
        """Release what the adapter holds open (simulator scenes); it can be used again."""

    def __enter__(self) -> AdapterBase:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def effect_names(self) -> tuple[str, ...]:
        return library(self.robot)

    def check_robot(self, log: Log, drive: Drive, replayed_from: str | None = None) -> None:
        """The log names this robot; ``replayed_from`` (e.g. "its joint readings"): only the
        default command drive is meaningful."""
        robot = log.meta.get("robot", self.robot)
        if robot != self.robot:
            raise LogError(
                f"{log.source}: the log is for robot {robot!r}, not {self.robot!r}; pass --robot"
            )
        if replayed_from is not None and drive is not Drive.COMMANDS:
            raise LogError(
                f"{log.source}: a {self.robot} log is replayed from {replayed_from}; use the "
                f"default drive ('commands'), not {drive.value!r}"
            )

    @staticmethod
    def time_windows(log: Log, settings: FeatureSettings) -> npt.NDArray[np.int64]:
        """Window bounds of a time series; at least two windows or a :class:`LogError`."""
        bounds = window_bounds(log.n, log.dt, settings.window_s)
        if bounds.shape[0] < 2:
            raise LogError(
                f"{log.source}: the log is {log.duration:.2f} s long; the diagnosis needs at least "
                f"two {settings.window_s:g}-s windows. Fix: record longer episodes"
            )
        return bounds

    def observable(self, effect: str, prepared: Sequence[PreparedLog], drive: Drive) -> str:
        """``""`` if the logs can show ``effect``, else why not."""
        cls = EFFECTS.get(effect)
        if cls is None or cls.robot != self.robot:
            return f"not a {self.robot} effect"
        if effect in self.unobservable:
            return self.unobservable[effect]
        groups = set().union(*(p.groups for p in prepared)) if prepared else set()
        if not [c for c in cls.observed_in if c in groups]:
            return f"shows only in {', '.join(cls.observed_in)}, which the logs do not compare"
        if effect not in self.surrogate_effects:
            return "no analytic surrogate"
        return ""


class WheelDrivenAdapter(AdapterBase):
    """An adapter whose replay can be driven by the logged commands or by the measured wheel
    rotation (:class:`~realitygap.diagnosis.adapters.diffdrive.replay.Drive`)."""

    # ------------------------------------------------------------------ observability
    def observable(self, effect: str, prepared: Sequence[PreparedLog], drive: Drive) -> str:
        """``""`` if the logs can show ``effect``, else why not."""
        # effects acting before the wheels cannot be seen when the replay is driven by the wheels
        cls = EFFECTS.get(effect)
        if drive is Drive.TICKS and cls is not None and cls.stage is Stage.COMMAND:
            return "acts on the commands, which a tick-driven replay does not use"
        why = super().observable(effect, prepared, drive)
        if why.startswith("shows only in") and drive is Drive.TICKS:
            why += " (ticks drive the replay)"
        return why
