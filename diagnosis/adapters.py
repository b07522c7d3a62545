"""Robot adapters: what the generic diagnosis needs to know about one kind of robot.

An adapter bundles

* the **effect library** it may attribute a gap to (effects of
  :mod:`realitygap.robots.effects` registered for the robot),
* the **replay** of a log in PyBullet with the nominal robot plus effects,
* the **channels** and window **features** compared between real and
  simulated episodes, the motion **regimes**, and
* a fast **surrogate** of the replay for the fit.

The diagnosis (:mod:`realitygap.diagnosis.attribute`) only talks to this
interface, so other robots plug in their own adapter and effects.
:class:`DiffDriveAdapter` is the differential drive's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.features import (
    FEATURE_COLUMNS,
    FeatureSettings,
    classify_regimes,
    features,
    window_bounds,
)
from realitygap.diagnosis.log import Log, LogError
from realitygap.diagnosis.manoeuvres import MANOEUVRES
from realitygap.diagnosis.replay import (
    Drive,
    SimSettings,
    applied_commands,
    nominal_odometry,
    params_from_meta,
    replay,
)
from realitygap.diagnosis.surrogate import (
    SURROGATE_EFFECTS,
    DiffDriveSurrogate,
    SurrogateInputs,
    calibrate,
)
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.effects import EFFECTS, Reality, Stage, library, make_effect

FloatArray = npt.NDArray[np.float64]
Features = dict[str, FloatArray]

__all__ = [
    "ADAPTERS",
    "AdapterBase",
    "DiffDriveAdapter",
    "PreparedLog",
    "RobotAdapter",
    "get_adapter",
    "known_robots",
    "reality_from_values",
    "split_key",
]


def split_key(key: str) -> tuple[str, str]:
    """``"effect.param"`` → ``("effect", "param")``."""
    effect, _, param = key.partition(".")
    return effect, param


def reality_from_values(values: Mapping[str, float]) -> Reality:
    """A :class:`Reality` from ``{"effect.param": value}`` (effects in first-seen order)."""
    grouped: dict[str, dict[str, float]] = {}
    for key, v in values.items():
        effect, param = split_key(key)
        grouped.setdefault(effect, {})[param] = float(v)
    return Reality(tuple(make_effect(name, **vals) for name, vals in grouped.items()))


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
    context : dict
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
    context: dict[str, Any] = field(default_factory=dict)
    bias: Features = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.log.name

    @property
    def groups(self) -> list[str]:
        """Feature groups present in both the real log and its replay."""
        return [g for g in FEATURE_COLUMNS if g in self.real and g in self.nominal]


class RobotAdapter(Protocol):
    """What the diagnosis needs from a robot (see the module docstring)."""

    robot: str

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


class AdapterBase:
    """What every adapter shares: its effect library, the robot check, observability.

    Subclasses set :attr:`robot`, :attr:`surrogate_effects` (effects the fast
    surrogate models) and may give :attr:`unobservable` (effect → why these
    channels cannot show it, whatever the log).
    """

    robot: str = ""
    surrogate_effects: tuple[str, ...] = ()
    unobservable: Mapping[str, str] = {}

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


class DiffDriveAdapter(AdapterBase):
    """Differential drive: effects, PyBullet replay, channels, features and surrogate."""

    robot = "diffdrive"
    surrogate_effects = tuple(SURROGATE_EFFECTS)

    # ------------------------------------------------------------------ checks
    def check(self, log: Log, drive: Drive) -> Log:
        """Validate a log for this robot; returns it (raises :class:`LogError` with the fix)."""
        self.check_robot(log, drive)
        params_from_meta(log)
        log.check_uniform()
        if drive is Drive.COMMANDS:
            log.require(["cmd", "pose_gt"], "a command-driven diagnosis")
        else:
            log.require(["ticks", "pose_gt"], "a tick-driven diagnosis")
        if log.n < 3:
            raise LogError(f"{log.source}: the log is too short ({log.n} rows)")
        return log

    # ------------------------------------------------------------------ preparation
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
        params = params_from_meta(log)
        dt = log.dt
        bounds = self.time_windows(log, features_settings)
        if drive is Drive.COMMANDS:
            twist = applied_commands(log)
        else:
            twist = self._twist_from_ticks(log["ticks"], params, dt)
        regimes = classify_regimes(twist, bounds, features_settings)
        settings = sim if sim is not None else SimSettings.for_log(log)
        start = np.asarray(log["pose_gt"][0], dtype=float)
        inputs = SurrogateInputs(
            dt=dt,
            start=start,
            commands=twist if drive is Drive.COMMANDS else None,
            ticks=np.asarray(log["ticks"], dtype=float) if drive is Drive.TICKS else None,
        )
        mpt = self.meters_per_tick(params)
        real = features(log.channels, bounds, mpt)
        if drive is Drive.TICKS:
            real.pop("ticks", None)
        context = {
            "params": params,
            "inputs": inputs,
            "twist": twist,
            "sim": settings,
            "surrogate": DiffDriveSurrogate(params, calibrate(params, settings.solver_iterations)),
        }
        prepared = PreparedLog(
            log=log,
            split=split,
            bounds=bounds,
            regimes=regimes,
            real=real,
            nominal={},
            replay_log=log,
            holdout_windows=np.full(bounds.shape[0], split == "holdout"),
            context=context,
        )
        nominal, replay_log = self.replay_features(prepared, {}, drive, settings)
        prepared.nominal = {g: v for g, v in nominal.items() if g in real}
        prepared.replay_log = replay_log
        sur = self.surrogate_features(prepared, {}, drive)
        prepared.bias = {g: prepared.nominal[g] - sur[g][0] for g in prepared.groups}
        return prepared

    @staticmethod
    def meters_per_tick(params: DiffDriveParams) -> tuple[float, float]:
        return (
            2.0 * math.pi * params.wheel_radius_left / params.ticks_per_rev,
            2.0 * math.pi * params.wheel_radius_right / params.ticks_per_rev,
        )

    @staticmethod
    def _twist_from_ticks(ticks: FloatArray, params: DiffDriveParams, dt: float) -> FloatArray:
        d = np.diff(ticks, axis=0, append=ticks[-1:]) * (2.0 * math.pi / params.ticks_per_rev)
        sl = d[:, 0] * params.wheel_radius_left / dt
        sr = d[:, 1] * params.wheel_radius_right / dt
        return np.column_stack([(sl + sr) / 2.0, (sr - sl) / params.wheelbase])

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

    # ------------------------------------------------------------------ models
    def replay_features(
        self, prepared: PreparedLog, values: Mapping[str, float], drive: Drive, sim: SimSettings
    ) -> tuple[Features, Log]:
        """PyBullet replay with effect values ``{"effect.param": v}``; its features and log."""
        reality = reality_from_values(values) if values else None
        rep = replay(
            prepared.log,
            reality,
            drive=drive,
            settings=sim,
            params=prepared.context["params"],
        )
        feats = features(
            rep.channels, prepared.bounds, self.meters_per_tick(prepared.context["params"])
        )
        if drive is Drive.TICKS:
            feats.pop("ticks", None)
        return feats, rep

    def log_features(self, prepared: PreparedLog, log: Log) -> Features:
        """Window features of another log of the same episode (e.g. a replay)."""
        mpt = self.meters_per_tick(prepared.context["params"])
        return features(log.channels, prepared.bounds, mpt)

    def surrogate_features(
        self, prepared: PreparedLog, values: Mapping[str, npt.ArrayLike], drive: Drive
    ) -> Features:
        """Surrogate features for a batch of effect values, (B, M, k) per group."""
        sur: DiffDriveSurrogate = prepared.context["surrogate"]
        out = sur.simulate(prepared.context["inputs"], values)
        feats = features(out, prepared.bounds, self.meters_per_tick(prepared.context["params"]))
        return {g: v for g, v in feats.items() if g in prepared.real}

    def probe_manoeuvres(self) -> dict[str, str]:
        """Manoeuvres the identifiability advice may suggest, with descriptions."""
        from realitygap.diagnosis.manoeuvres import PROBE_MANOEUVRES

        return {name: MANOEUVRES[name].description for name in PROBE_MANOEUVRES}

    def probe_features(
        self, manoeuvre: str, params_like: PreparedLog, values: Mapping[str, npt.ArrayLike]
    ) -> tuple[Features, list[str]]:
        """Surrogate features of a library manoeuvre (for identifiability advice)."""
        params: DiffDriveParams = params_like.context["params"]
        man = MANOEUVRES[manoeuvre]
        dt = params_like.log.dt
        t, cmd = man.applied(dt, params)
        sur: DiffDriveSurrogate = params_like.context["surrogate"]
        out = sur.simulate(SurrogateInputs(dt, np.zeros(3), commands=cmd), values)
        bounds = window_bounds(t.shape[0], dt, 1.0)
        feats = features(out, bounds, self.meters_per_tick(params))
        groups = [g for g in params_like.real if g in feats]
        return {g: feats[g] for g in groups}, groups

    # ------------------------------------------------------------------ stages
    def stage_residuals(self, prepared: PreparedLog) -> dict[str, FloatArray]:
        """Residuals of the pipeline stages inside the real log, per window.

        ``command → motion``: real ground truth minus the nominal replay's;
        ``motion → sensor``: encoder travel minus the travel the nominal
        geometry predicts from the ground-truth motion; ``sensor → estimate``:
        the logged estimate's motion minus nominal odometry of the logged ticks.
        """
        params: DiffDriveParams = prepared.context["params"]
        log = prepared.log
        out: dict[str, FloatArray] = {}
        if "pose_gt" in prepared.real and "pose_gt" in prepared.nominal:
            out["command → motion"] = prepared.real["pose_gt"] - prepared.nominal["pose_gt"]
        if log.has("ticks") and log.has("pose_gt"):
            mpt = self.meters_per_tick(params)
            odo = nominal_odometry(np.asarray(log["ticks"]), params, log["pose_gt"][0])
            f_odo = features({"pose_gt": odo}, prepared.bounds, mpt)["pose_gt"]
            out["motion → sensor"] = f_odo - prepared.real["pose_gt"]
            if log.has("pose_est"):
                f_est = features({"pose_gt": log["pose_est"]}, prepared.bounds, mpt)["pose_gt"]
                out["sensor → estimate"] = f_est - f_odo
        return out


ADAPTERS: dict[str, RobotAdapter] = {"diffdrive": DiffDriveAdapter()}
"""Robot adapters by robot name (the others are loaded on first use, see :data:`LAZY_ADAPTERS`)."""

LAZY_ADAPTERS: dict[str, str] = {
    "arm": "realitygap.diagnosis.arm_adapter:ArmAdapter",
    "climber": "realitygap.diagnosis.climb_adapter:ClimberAdapter",
}
"""``robot`` → ``"module:Class"`` of adapters built when first asked for."""


def known_robots() -> tuple[str, ...]:
    """Names of every robot with a diagnosis adapter."""
    return tuple(sorted(set(ADAPTERS) | set(LAZY_ADAPTERS)))


def get_adapter(robot: str) -> RobotAdapter:
    """The adapter of ``robot``; a ``ValueError`` listing the known robots otherwise."""
    if robot not in ADAPTERS and robot in LAZY_ADAPTERS:
        import importlib

        module, _, cls = LAZY_ADAPTERS[robot].partition(":")
        ADAPTERS[robot] = getattr(importlib.import_module(module), cls)()
    if robot not in ADAPTERS:
        raise ValueError(
            f"no diagnosis adapter for robot {robot!r}; known: {', '.join(known_robots())}"
        )
    return ADAPTERS[robot]
