"""Robot adapters: what the generic diagnosis needs to know about one kind of robot.

An adapter bundles

* the **effect library** it may attribute a gap to (effects of
  :mod:`realitygap.robots.effects` registered for the robot),
* the **replay** of a log in PyBullet with the nominal robot plus effects,
* the **channels** it reads (declared in :mod:`~realitygap.diagnosis.logs.channels`) and the
  window **features** compared between real and simulated episodes
  (:class:`~realitygap.diagnosis.problem.schemas.FeatureSchema`, declared in
  :mod:`~realitygap.diagnosis.problem.schemas`: feature groups with columns, units and
  scales, and the motion **regimes**),
* the **probe manoeuvres** its identifiability advice may suggest,
* a fast **surrogate** of the replay for the fit, and
* the **blind-log recorder** and noise model of the validation suite.

The diagnosis (:mod:`realitygap.diagnosis.diagnose`) only talks to this interface,
:class:`RobotAdapter`: one abstract base class that declares every capability the
pipeline may call. The required ones are abstract; every optional one has a default
that says what an adapter without the capability means (no stage residuals, no
nuisances, no actuation figures, …). The pipeline never asks an adapter, nor the
:class:`LogContext` of a prepared log, whether it has an attribute.
:data:`~realitygap.diagnosis.adapters.registry.ADAPTER_CLASSES` is the one place that maps
robot names to adapters. A new robot is

1. one effects module (its :class:`~realitygap.robots.effects.Effect` classes),
2. its channels in :mod:`~realitygap.diagnosis.logs.channels` and its feature schema in
   :mod:`~realitygap.diagnosis.problem.schemas`,
3. one adapter module: a subclass of :class:`RobotAdapter` that sets ``robot``,
   ``channels``, ``schema`` and ``surrogate_effects``, keeps what it needs about
   a prepared log in a :class:`LogContext` subclass and implements ``check``,
   ``prepare``, ``replay_features``, ``log_features``, ``surrogate_features``,
   ``probe_manoeuvres`` and ``probe_features`` (and ``record_blind_logs`` for the blind
   suite; the blind-test ranges come from the effect classes themselves),
4. one line in :data:`~realitygap.diagnosis.adapters.registry.ADAPTER_CLASSES`.

The adapters are :class:`~realitygap.diagnosis.adapters.diffdrive.adapter.DiffDriveAdapter`,
:class:`~realitygap.diagnosis.adapters.arm.adapter.ArmAdapter` and
:class:`~realitygap.diagnosis.adapters.climber.adapter.ClimberAdapter`.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING, Any

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
from realitygap.robots.simulation import MeasurementNoise, SimSettings

if TYPE_CHECKING:
    from realitygap.diagnosis.problem.problem import Problem

FloatArray = npt.NDArray[np.float64]
Features = dict[str, FloatArray]
DiscoveryTerms = dict[str, tuple[FloatArray, str]]
"""Candidate terms of a residual: name → (one value per window, SI unit)."""

__all__ = [
    "ActuatorLimits",
    "BlindLogSettings",
    "DiscoveryTerms",
    "Drive",
    "HiddenTable",
    "LogContext",
    "PreparedLog",
    "RobotAdapter",
    "WheelDrivenAdapter",
    "WheelGeometry",
]

HiddenTable = dict[str, tuple[BlindRange, ...]]
"""Blind-test magnitudes per effect: ``(param, low, high, symmetric)`` per parameter."""


class Drive(str, Enum):
    """What drives a replay: the logged commands, or the logged actuator readings (a wheeled
    robot's encoder ticks; an adapter without such readings replays ``COMMANDS`` only)."""

    COMMANDS = "commands"
    TICKS = "ticks"


@dataclass(frozen=True)
class WheelGeometry:
    """The nominal wheels a wheeled robot's log declares (:meth:`LogContext.wheels`).

    Attributes
    ----------
    wheel_radius_left, wheel_radius_right : float
        m.
    wheelbase : float
        Distance between the wheels' contact points, m.
    ticks_per_rev : float
        Encoder counts per wheel revolution.
    """

    wheel_radius_left: float
    wheel_radius_right: float
    wheelbase: float
    ticks_per_rev: float


@dataclass
class LogContext:
    """What an adapter keeps about one prepared log besides its features.

    Each adapter subclasses this with its own inputs (parameters, surrogate
    inputs, poses, …) and answers the questions below that its robot can; the defaults
    say the robot has no such thing.

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

    def wheels(self) -> WheelGeometry | None:
        """The nominal wheels the log declares, whose travel the transient detector
        (:mod:`~realitygap.diagnosis.stages.transients`) compares with the body's motion;
        ``None`` (the default) for a robot without them."""
        return None

    def applied_twist(self) -> FloatArray | None:
        """The body twist (N, 2: m/s, rad/s) that drives the replay — the applied commands, or
        the wheel motion — or ``None`` (the default) for a robot not driven by one."""
        return None

    def reference_wheelbase(self) -> float | None:
        """The wheelbase (m) of the geometry every log of the diagnosis is judged on, from
        which the coverage (:mod:`~realitygap.diagnosis.stages.coverage`) turns a planar
        motion into wheel speeds; ``None`` (the default) for a robot without one."""
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


@dataclass(frozen=True)
class BlindLogSettings:
    """What an adapter's blind-log recorder (:meth:`RobotAdapter.record_blind_logs`) is told
    by the validation suite
    (:attr:`~realitygap.diagnosis.validation.suite.SuiteSettings.blind_logs`).

    Attributes
    ----------
    noise : MeasurementNoise or None
        Motion-capture and camera noise of a differential drive's recorded logs
        (``None``: the adapter's own).
    arm_poses : int
        Arm: measured poses per log.
    arm_tracker_noise : float
        Arm: laser-tracker noise per axis (m).
    """

    noise: MeasurementNoise | None
    arm_poses: int
    arm_tracker_noise: float


class ActuatorLimits(ABC):
    """Continuous limits of an actuator convention fitted to the training logs
    (:meth:`RobotAdapter.fit_actuator_limits`)."""

    @abstractmethod
    def leaves_stated(self) -> bool:
        """Whether the fit keeps the limits the logs state as they are."""

    @abstractmethod
    def to_json(self) -> dict[str, Any]:
        """JSON form (the calibrated baseline's ``actuator_limits``)."""


class RobotAdapter(ABC):
    """What the diagnosis needs from a robot (see the module docstring).

    Required: :attr:`robot`, :attr:`channels`, :attr:`schema` (class attributes of a
    subclass) and the abstract methods :meth:`check`, :meth:`prepare`,
    :meth:`replay_features`, :meth:`log_features`, :meth:`surrogate_features`,
    :meth:`probe_manoeuvres` and :meth:`probe_features`. Everything else has a default
    that stands for a robot without the capability.
    """

    # ------------------------------------------------------------------ required
    @property
    @abstractmethod
    def robot(self) -> str:
        """The robot's name (the registry's key, ``meta["robot"]`` of its logs)."""

    @property
    @abstractmethod
    def channels(self) -> tuple[ChannelSpec, ...]:
        """The log channels it reads (:mod:`~realitygap.diagnosis.logs.channels`)."""

    @property
    @abstractmethod
    def schema(self) -> FeatureSchema:
        """Its feature groups and regimes (:mod:`~realitygap.diagnosis.problem.schemas`)."""

    @abstractmethod
    def check(self, log: Log, drive: Drive) -> Log:
        """Validate a log for this robot; returns it (raises :class:`LogError` with the fix)."""

    @abstractmethod
    def prepare(
        self,
        log: Log,
        *,
        split: str,
        drive: Drive,
        features_settings: FeatureSettings,
        sim: SimSettings | None,
    ) -> PreparedLog:
        """Windows, regimes, real features, the nominal replay and the surrogate's bias."""

    @abstractmethod
    def replay_features(
        self, prepared: PreparedLog, values: Mapping[str, float], drive: Drive, sim: SimSettings
    ) -> tuple[Features, Log]:
        """PyBullet replay with effect values ``{"effect.param": v}``: its features and log."""

    @abstractmethod
    def log_features(self, prepared: PreparedLog, log: Log) -> Features:
        """Window features of another log of the same episode (e.g. a replay)."""

    @abstractmethod
    def surrogate_features(
        self, prepared: PreparedLog, values: Mapping[str, npt.ArrayLike], drive: Drive
    ) -> Features:
        """Surrogate features for a batch of effect values, (B, M, k) per group."""

    @abstractmethod
    def probe_manoeuvres(self) -> dict[str, str]:
        """Manoeuvres the identifiability advice may suggest, with descriptions."""

    @abstractmethod
    def probe_features(
        self, manoeuvre: str, params_like: PreparedLog, values: Mapping[str, npt.ArrayLike]
    ) -> tuple[Features, list[str]]:
        """Surrogate features of a probe manoeuvre on the robot of ``params_like`` (for the
        identifiability advice), and the groups they hold."""

    # ------------------------------------------------------------------ optional: attributes
    surrogate_effects: tuple[str, ...] = ()
    """Effects the fast surrogate models (none: every effect is "no analytic surrogate")."""

    unobservable: Mapping[str, str] = {}
    """Effect → why these channels cannot show it, whatever the log (none)."""

    stage_group: str = ""
    """The feature group whose columns :meth:`stage_residuals` use."""

    drive_stages: tuple[str, str] | None = None
    """The two stages of :meth:`stage_residuals` a command-driven gap splits into: up to the
    actuators, and after them (``None``: no such split)."""

    integrates: bool = False
    """Whether the robot's motion integrates along a run (a mobile base: a small constant
    error of a wheel or the wheelbase grows into a drift), so that the gap budget also reads
    residuals at run scale (:mod:`~realitygap.diagnosis.budget`)."""

    transient_detection: bool = False
    """Whether the logs are time series in which disturbed windows (stalls, bumps, lost
    markers) are detected and set aside (:mod:`~realitygap.diagnosis.stages.transients`)."""

    motion_labels: tuple[tuple[str, str], ...] | None = None
    """``(name, unit)`` of the six columns of :meth:`LogContext.window_motion`
    (:mod:`~realitygap.diagnosis.stages.coverage`); ``None``: a wheeled robot's speed and turn
    rate (:data:`~realitygap.diagnosis.stages.coverage.DEFAULT_MOTION_LABELS`)."""

    # ------------------------------------------------------------------ optional: the nominal
    def complete_nominal(
        self, train: Sequence[Log], others: Sequence[Log]
    ) -> tuple[list[Log], list[Log], dict[str, Any]]:
        """Nominal parameters the logs leave to be fitted, fitted on the training logs.

        A robot whose description leaves a nominal parameter open (a skid-steer's
        effective track) fits it here on ``train`` only and writes it into every
        log's ``meta["params"]``. Returns the logs and a report (``summary`` says
        what was fitted); unchanged logs and ``{}`` by default.
        """
        return list(train), list(others), {}

    # ------------------------------------------------------------------ optional: the library
    def effect_names(self) -> tuple[str, ...]:
        """The effect library of :attr:`robot`."""
        return library(self.robot)

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

    def probe_description(self, manoeuvre: str, params_like: PreparedLog) -> str:
        """The description of probe manoeuvre ``manoeuvre`` for the robot of ``params_like``
        (as its :meth:`probe_features` drive it); its :meth:`probe_manoeuvres` description by
        default."""
        return self.probe_manoeuvres()[manoeuvre]

    # ------------------------------------------------------------------ optional: stages
    def stage_residuals(self, prepared: PreparedLog) -> dict[str, FloatArray]:
        """Residuals of the pipeline stages inside the real log, per window, in the columns of
        the feature group :attr:`stage_group` (none by default)."""
        return {}

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

    def fit_actuator_limits(self, logs: Sequence[Log], name: str) -> ActuatorLimits | None:
        """Continuous limits of the actuator convention ``name`` fitted to ``logs`` (the
        training logs), or ``None`` when the adapter fits none (default)."""
        return None

    def with_actuator_limits(self, log: Log, fit: ActuatorLimits | None) -> Log:
        """``log`` replayed with the limits ``fit`` of :meth:`fit_actuator_limits` (itself by
        default)."""
        return log

    def replay_seconds(self, prepared: Sequence[PreparedLog]) -> float | None:
        """Seconds one PyBullet replay of every log of ``prepared`` takes on one core,
        measured now on a short probe (:class:`~realitygap.diagnosis.fit.workload.Workload`);
        ``None`` (default): unknown, the nominal replays' own time stands in."""
        return None

    def prepare_on_surrogate(self, prepared: PreparedLog, log: Log) -> PreparedLog | None:
        """``prepared`` for ``log`` — the same episode replayed otherwise (another actuator
        convention or limits) — without a PyBullet replay: the nominal predicted by the
        surrogate plus ``prepared``'s PyBullet defect (its ``bias``). For screening
        choices on the fast model before the chosen one is replayed; ``None`` (default)
        when the adapter cannot, and every option is then replayed."""
        return None

    def held_parameters(self, problem: Problem, keys: Sequence[str]) -> dict[str, str]:
        """Parameters ``"effect.param"`` of a model (``keys``) that the training windows of
        ``problem`` cannot identify, with the reason: held at nominal and reported as not
        testable (:meth:`~realitygap.diagnosis.problem.problem.Problem.held_parameters`);
        none by default."""
        return {}

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
        in feature-scale units, or ``None`` (no such measurement): the gap budget's noise
        floor where it exists (:mod:`~realitygap.diagnosis.budget`)."""
        return None

    # ------------------------------------------------------------------ optional: the verdict
    def residual_structure(
        self, problem: Problem, values: Mapping[str, float], desc: dict[str, Any]
    ) -> dict[str, Any]:
        """The verdict's description of a held-out residual (``desc``, of
        :func:`~realitygap.diagnosis.problem.residual.describe_residual`) with this robot's own
        structure test added, for the model at ``values`` (``{}``: the nominal); ``desc``
        unchanged by default."""
        return desc

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

    def fitted_robot(
        self, prepared: Sequence[PreparedLog], effects: Sequence[str], values: Mapping[str, float]
    ) -> dict[str, Any] | None:
        """The robot a verdict's ``effects`` at ``values`` describe, in the robot's own
        quantities (per wheel, per joint), or ``None`` where the adapter reads none."""
        return None

    def actuation(self, prepared: Sequence[PreparedLog], drive: Drive) -> dict[str, Any]:
        """How the actuators answered the commands, log by log, where the logs show it (a
        wheeled robot's encoders in a command-driven replay): ``gains`` (per log) and
        ``spread`` (whether the logs share one drive train), ``tracking`` (whether the
        actuators followed beyond the training's requests), each where present; empty by
        default (:attr:`~realitygap.diagnosis.diagnose.Diagnosis.actuation`)."""
        return {}

    def discovery_terms(self, prepared: PreparedLog) -> DiscoveryTerms | None:
        """Candidate terms of an unexplained residual, one value per window of ``prepared``,
        with SI units (:mod:`~realitygap.diagnosis.stages.discovery`); ``None`` (the default):
        the robot states no term library, and nothing is discovered."""
        return None

    def discover_residual(
        self,
        problem: Problem,
        z_train: FloatArray,
        z_holdout: FloatArray,
        mask: npt.NDArray[np.bool_] | None,
        settings: Any,
    ) -> Any:
        """The robot's own discovery of a residual whose terms are not signals of a window (a
        :class:`~realitygap.diagnosis.stages.discovery.Discovery`), or ``None`` (the default):
        :func:`~realitygap.diagnosis.stages.discovery.discover` then regresses the residual on
        the per-window :meth:`discovery_terms`."""
        return None

    # ------------------------------------------------------------------ optional: blind suite
    def hidden_effects(self) -> HiddenTable:
        """Blind-test magnitudes of the effects the validation suite hides in this robot
        (each effect's :attr:`~realitygap.robots.effects.Effect.blind` ranges)."""
        return blind_ranges(self.robot)

    def record_blind_logs(
        self, reality: Reality, rng: np.random.Generator, settings: BlindLogSettings
    ) -> tuple[list[Log], list[Log]]:
        """Training and held-out logs of the robot ``reality`` for one blind case (a robot
        without a recorder cannot be blind-tested: ``NotImplementedError``)."""
        raise NotImplementedError(f"the blind suite cannot record {self.robot!r} logs")

    def blind_measurement_noise(self, settings: BlindLogSettings) -> dict[str, FloatArray]:
        """Per channel, the noise of each column in the logs :meth:`record_blind_logs` records
        with ``settings`` (SI units): the size below which two recordings do not measurably
        differ; none by default."""
        return {}

    # ------------------------------------------------------------------ resources
    def close(self) -> None:  # noqa: B027 - an adapter without resources closes nothing
        """Release what the adapter holds open (simulator scenes); it can be used again."""

    def __enter__(self) -> RobotAdapter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ checks before work
    uses_time_windows: bool = True
    """Whether the features cut each log into time windows (:meth:`time_windows`); an
    adapter whose logs are poses at stations sets it ``False``."""

    def check_request(self, logs: Sequence[Log], settings: FeatureSettings, drive: Drive) -> None:
        """Refuse, before any work, logs this adapter cannot diagnose: what :meth:`check` finds
        (another robot, missing channels, irregular time, no nominal parameters) and, for
        time-series features, a log too short or too coarse for the window."""
        for log in logs:
            self.check(log, drive)
            if self.uses_time_windows:
                self.time_windows(log, settings)

    # ------------------------------------------------------------------ helpers of subclasses
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
        """Window bounds of a time series: at least two samples per window and at least two
        windows, or a :class:`LogError`."""
        if settings.window_s < 2.0 * log.dt:
            raise LogError(
                f"{log.source}: a {settings.window_s:g}-s window (--window) holds fewer than two "
                f"samples of this log (one every {log.dt:.4g} s); a window needs at least two. "
                f"Fix: --window {_round_up(2.0 * log.dt):g} or longer"
            )
        bounds = window_bounds(log.n, log.dt, settings.window_s)
        if bounds.shape[0] < 2:
            raise LogError(
                f"{log.source}: the log is {log.duration:.2f} s long; the diagnosis needs at least "
                f"two {settings.window_s:g}-s windows (--window). Fix: a shorter --window "
                f"(at most {log.duration / 2:.3g} s), or record longer episodes"
            )
        return bounds


def _round_up(x: float) -> float:
    """``x`` rounded up to two significant digits."""
    scale = 10.0 ** (math.floor(math.log10(x)) - 1)
    return math.ceil(x / scale - 1e-9) * scale


class WheelDrivenAdapter(RobotAdapter):
    """An adapter whose replay can be driven by the logged commands or by the measured wheel
    rotation (:class:`Drive`)."""

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
