"""The settings of a diagnosis (:class:`DiagnosisSettings`), checked where they are made."""

from __future__ import annotations

from dataclasses import dataclass, field

from realitygap.diagnosis.adapters.contract import Drive
from realitygap.diagnosis.problem.features import FeatureSettings
from realitygap.diagnosis.problem.problem import AttributionSettings
from realitygap.diagnosis.stages.clock import ClockSettings
from realitygap.diagnosis.stages.coverage import CoverageSettings
from realitygap.diagnosis.stages.transients import TransientSettings
from realitygap.robots.simulation import SimSettings

__all__ = ["DiagnosisSettings"]


@dataclass(frozen=True)
class DiagnosisSettings:
    """Settings of :func:`diagnose`.

    Attributes
    ----------
    robot : str
        Adapter name (``"diffdrive"``).
    drive : {"commands", "ticks"}
        What drives the replay: the logged commands, or the logged wheel
        rotation (then only effects after the wheels can be attributed).
    effects : tuple of str or None
        Candidate library; ``None`` means every effect of the robot.
    features : FeatureSettings
    attribution : AttributionSettings
    sim : SimSettings or None
        Replay fidelity (default: a simulated log's own settings, else
        :class:`SimSettings` ()).
    holdout_fraction : float
        Without explicit held-out logs and with several logs, the last
        ``ceil(fraction · n)`` logs are held out.
    block_windows : int
        With a single log, alternate blocks of this many windows are held out; the library
        reach splits the held-out windows two-fold in blocks of this many.
    transients : TransientSettings or None
        Thresholds of the transient-event detector; ``None`` switches it off.
    calibrate : bool
        Fit the adapter's baseline nuisances first (the calibrated baseline).
    clock : ClockSettings or None
        With ``calibrate``: fit each log's own clock offset first and re-stamp the
        logs whose deviation from the common offset is a synchronisation error
        (:mod:`realitygap.diagnosis.stages.clock`); ``None`` leaves every log's clock alone.
    frames : bool
        With ``calibrate`` and a tick-driven replay: fit each log's own ground-truth
        frame (where the adapter states one as a nuisance) and re-frame the logs
        whose deviation from the common frame is their own
        (:mod:`realitygap.diagnosis.stages.frames`).
    coverage : CoverageSettings or None
        How the held-out motions are compared with the training envelope
        (:mod:`realitygap.diagnosis.stages.coverage`); ``None`` skips the comparison.
    reach : bool
        For an unexplained verdict, fit every single candidate on the held-out windows
        themselves and say how far the library could reach there
        (:mod:`realitygap.diagnosis.stages.reach`): whether the training or the library falls
        short. Never changes the verdict.
    """

    robot: str = "diffdrive"
    drive: str = "commands"
    effects: tuple[str, ...] | None = None
    features: FeatureSettings = field(default_factory=FeatureSettings)
    attribution: AttributionSettings = field(default_factory=AttributionSettings)
    sim: SimSettings | None = None
    holdout_fraction: float = 1.0 / 3.0
    block_windows: int = 10
    transients: TransientSettings | None = field(default_factory=TransientSettings)
    calibrate: bool = True
    clock: ClockSettings | None = field(default_factory=ClockSettings)
    frames: bool = True
    coverage: CoverageSettings | None = field(default_factory=CoverageSettings)
    reach: bool = True

    def __post_init__(self) -> None:
        """Every field checked where it is written: its type, its choices, its range."""
        kinds: dict[str, tuple[type, ...]] = {
            "robot": (str,),
            "drive": (str,),
            "features": (FeatureSettings,),
            "attribution": (AttributionSettings,),
            "sim": (SimSettings, type(None)),
            "transients": (TransientSettings, type(None)),
            "clock": (ClockSettings, type(None)),
            "coverage": (CoverageSettings, type(None)),
            "calibrate": (bool,),
            "frames": (bool,),
            "reach": (bool,),
        }
        for name, allowed in kinds.items():
            value = getattr(self, name)
            if not isinstance(value, allowed):
                want = " or ".join("None" if k is type(None) else k.__name__ for k in allowed)
                raise TypeError(
                    f"DiagnosisSettings.{name} must be {want}, got {type(value).__name__} "
                    f"{value!r:.60}"
                )
        choices = [d.value for d in Drive]
        if self.drive not in choices:
            raise ValueError(
                f"DiagnosisSettings.drive must be one of {', '.join(choices)}, got {self.drive!r}"
            )
        if self.effects is not None:
            if isinstance(self.effects, str) or not all(isinstance(e, str) for e in self.effects):
                raise TypeError(
                    "DiagnosisSettings.effects must be a tuple of effect names, e.g. "
                    f"('wheel_diameter_ratio',), or None for the robot's library; got "
                    f"{self.effects!r:.80}"
                )
            names = tuple(self.effects)
            if not names:
                raise ValueError(
                    "DiagnosisSettings.effects is empty: a diagnosis needs at least one "
                    "candidate effect. Fix: name some, or None for the robot's library"
                )
            twice = sorted({n for n in names if names.count(n) > 1})
            if twice:
                raise ValueError(
                    f"DiagnosisSettings.effects names {', '.join(map(repr, twice))} more than once"
                )
            object.__setattr__(self, "effects", names)
        if isinstance(self.holdout_fraction, bool) or not (
            isinstance(self.holdout_fraction, int | float) and 0.0 < self.holdout_fraction < 1.0
        ):
            raise ValueError(
                "DiagnosisSettings.holdout_fraction must be a share of the logs in (0, 1), got "
                f"{self.holdout_fraction!r}"
            )
        if isinstance(self.block_windows, bool) or not (
            isinstance(self.block_windows, int) and self.block_windows >= 1
        ):
            raise ValueError(
                f"DiagnosisSettings.block_windows must be a whole number ≥ 1, got "
                f"{self.block_windows!r}"
            )
