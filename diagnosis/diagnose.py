"""The sim-to-real gap diagnosis, end to end: localise → attribute → verify → shrink.

:func:`diagnose` takes real logs (training and, optionally, held-out ones) and
returns a :class:`Diagnosis`. It is a pipeline of named stages, each a small
function of this module or of the module it names:

1. every log is checked and replayed in the nominal PyBullet simulation
   (same commands or wheel rotation, same start);
2. windows disturbed by stalls, bumps or lost markers are listed and set aside
   (:mod:`realitygap.diagnosis.stages.transients`), and the nuisances of every real log
   (time alignment, response of the replayed commands) are fitted first as the
   calibrated baseline every effect is scored against
   (:mod:`realitygap.diagnosis.stages.baseline`);
3. :func:`~realitygap.diagnosis.stages.localise.localise` tabulates where replay and
   reality part (per channel, regime, pipeline stage);
4. each candidate effect, then pairs of the best, is fitted on the training
   windows and scored on the held-out ones
   (:mod:`realitygap.diagnosis.fit.model`), fits running in parallel through a
   backend (:mod:`realitygap.core.parallel`);
5. the best models are verified in PyBullet, and the verdict is drawn — an
   effect (or pair) only if it closes enough of the held-out gap and leaves
   unstructured residuals, else ``"unexplained"``; confounded explanations
   are flagged with a manoeuvre that would separate them;
6. :mod:`realitygap.diagnosis.problem.shrink` reports the held-out gap before and
   after, per channel and regime.

================  ==============================================  ==========================
stage             function                                        result
================  ==============================================  ==========================
library           :func:`candidate_library`                       effect names to consider
prepare           :func:`prepare_logs`                            checked, replayed logs
transients        :func:`~realitygap.diagnosis.stages.transients.detect_transients`  windows set aside
observability     :func:`observable_candidates`                   candidates, and why not
baseline          :func:`~realitygap.diagnosis.stages.baseline.calibrate_baseline`  calibrated reference
localise          :func:`~realitygap.diagnosis.stages.localise.localise`  where the gap lies
attribute         :func:`fit_candidates`                          fitted singles and pairs
verify            :func:`~realitygap.diagnosis.fit.verify.verify_ranking`  verified ranking
verdict           :func:`~realitygap.diagnosis.verdict.judge.judge`     the draft verdict
identifiability   :func:`~realitygap.diagnosis.verdict.advice.advise`  confounded alternatives
rules             :func:`~realitygap.diagnosis.verdict.rules.decide`  the decision
conclude          :func:`~realitygap.diagnosis.verdict.conclude.conclude`  the verdict
shrink            :func:`gap_report`                              held-out gap before/after
================  ==============================================  ==========================
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.parallel import Backend, SerialBackend
from realitygap.core.progress import duration_words
from realitygap.diagnosis.adapters.contract import Drive, PreparedLog, RobotAdapter
from realitygap.diagnosis.adapters.registry import get_adapter
from realitygap.diagnosis.budget import Budget, gap_budget
from realitygap.diagnosis.fit.candidates import fit_candidates
from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.fit.status import parameter_status
from realitygap.diagnosis.fit.verify import Verification, verify_ranking
from realitygap.diagnosis.fit.workload import Workload, row_seconds
from realitygap.diagnosis.logs.log import Log, LogError
from realitygap.diagnosis.logs.pieces import drop_short_pieces
from realitygap.diagnosis.problem.parameters import split_key
from realitygap.diagnosis.problem.problem import Problem
from realitygap.diagnosis.problem.shrink import (
    overall_shrink,
    shrink_table,
)
from realitygap.diagnosis.settings import DiagnosisSettings
from realitygap.diagnosis.stages.baseline import Baseline, calibrate_baseline
from realitygap.diagnosis.stages.coverage import (
    Coverage,
    CoverageSettings,
    layout_windows,
    motion_variables,
    planar_motion,
    training_coverage,
    wheel_speeds,
)
from realitygap.diagnosis.stages.localise import localise
from realitygap.diagnosis.stages.reach import library_reach
from realitygap.diagnosis.stages.transients import (
    TransientReport,
    detect_transients,
)
from realitygap.diagnosis.verdict.conclude import conclude
from realitygap.diagnosis.verdict.judge import (
    budget_replays,
    describe_fit_residual,
    gap_report,
    gap_words,
    heldout_view,
)
from realitygap.diagnosis.verdict.notes import alias_notes, regime_consistency, run_discovery
from realitygap.diagnosis.verdict.types import CoverageNote, Judgement, Verdict, VerdictKind
from realitygap.robots.effects import EFFECTS, Twin

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "Diagnosis",
    "DiagnosisSettings",
    "candidate_library",
    "diagnose",
    "fit_candidates",
    "gap_report",
    "observable_candidates",
    "prepare_logs",
]


def _check_arguments(
    logs: Sequence[Log], holdout: Sequence[Log] | None, settings: object, backend: object
) -> None:
    """:func:`diagnose`'s arguments of the right kinds, and no log both trained on and held
    out (a held-out score on training data is no test)."""
    for name, group in (("logs", logs), ("holdout", holdout or [])):
        if isinstance(group, str | Log) or not isinstance(group, Sequence):
            raise TypeError(f"diagnose: {name} must be a list of Log, got {type(group).__name__}")
        for i, lg in enumerate(group):
            if not isinstance(lg, Log):
                hint = (
                    " (a path? read it first: read_logs(path) or Log.load(path))"
                    if isinstance(lg, str | bytes) or hasattr(lg, "__fspath__")
                    else ""
                )
                raise TypeError(
                    f"diagnose: {name}[{i}] must be a Log, got {type(lg).__name__}{hint}"
                )
    if settings is not None and not isinstance(settings, DiagnosisSettings):
        raise TypeError(
            f"diagnose: settings must be a DiagnosisSettings (e.g. DiagnosisSettings(robot="
            f"'diffdrive')), got {type(settings).__name__}"
        )
    if backend is not None and not callable(getattr(backend, "map", None)):
        raise TypeError(
            f"diagnose: backend must be a Backend (make_backend('process')), got "
            f"{type(backend).__name__}"
        )
    both = [
        lg.name
        for lg in holdout or []
        if any(
            lg is t
            or (
                lg.n == t.n
                and np.array_equal(lg.t, t.t)
                and lg.channels.keys() == t.channels.keys()
                and all(np.array_equal(lg.channels[c], t.channels[c]) for c in lg.channels)
            )
            for t in logs
        )
    ]
    if both:
        raise ValueError(
            f"diagnose: {', '.join(both)} given both as training and as held-out log(s); a "
            "held-out score needs logs not used for fitting. Fix: remove them from one set"
        )


@dataclass
class Diagnosis:
    """Result of :func:`diagnose` (see :meth:`to_json` for the exported form)."""

    settings: DiagnosisSettings
    prepared: list[PreparedLog]
    candidates: list[str]
    not_observable: dict[str, str]
    localisation: dict[str, Any]
    ranking: list[ModelFit]
    verdict: Verdict
    identifiability: list[dict[str, Any]]
    shrink: list[dict[str, Any]]
    gap: dict[str, Any]
    agreement: list[dict[str, Any]]
    corrected_replays: dict[int, Log]
    timing: dict[str, float]
    nominal_heldout: FloatArray
    problem: Problem
    gap_mask: npt.NDArray[np.bool_] | None = None
    shrink_best: list[dict[str, Any]] = field(default_factory=list)
    baseline: Baseline = field(default_factory=Baseline)
    transients: TransientReport = field(default_factory=TransientReport)
    nominal_reference: dict[str, Any] = field(default_factory=dict)
    coverage: Coverage | None = None
    actuation: dict[str, Any] = field(default_factory=dict)
    """How the actuators answered the commands, where the logs show it
    (:meth:`~realitygap.diagnosis.adapters.contract.RobotAdapter.actuation`; for a
    command-driven replay of a differential drive's logs with encoders ``gains``, ``spread``
    and ``tracking``, :mod:`~realitygap.diagnosis.adapters.diffdrive.actuation`); else empty."""

    budget: Budget | None = None
    """The gap budget (:mod:`~realitygap.diagnosis.budget`): the answer."""

    budget_model: ModelFit | None = None
    """The budget's model (all its entries on the calibrated baseline) with its held-out
    residual; ``None`` when the budget is empty."""

    @property
    def chosen(self) -> ModelFit | None:
        """The model of the named effects (the budget's), if the verdict names any."""
        if self.verdict.kind not in (VerdictKind.EFFECTS, VerdictKind.PARTIAL):
            return None
        return self.budget_model

    def to_reality(self, name: str = "") -> Twin:
        """The robot the logs came from as a reality file's content: the effects found, their
        fitted values and uncertainties (:mod:`~realitygap.diagnosis.export`); ``.save(path)``
        writes it, ``gym.make(id, reality=path)`` simulates it."""
        from realitygap.diagnosis.export import twin_of

        return twin_of(self, name)

    def ranking_rows(self) -> list[dict[str, Any]]:
        """The ranking as JSON-able rows (fitted values with units and uncertainty)."""
        rows = []
        mask = self.gap_mask
        if mask is None or not mask.any():
            mask = np.ones(self.nominal_heldout.shape, dtype=bool)
        nominal_rms = (
            float(np.sqrt(np.mean(self.nominal_heldout[mask] ** 2))) if mask.any() else 0.0
        )
        for rank, fit in enumerate(self.ranking, start=1):
            params = {}
            for k in (*fit.keys, *fit.held):
                effect, pname = split_key(k)
                spec = EFFECTS[effect]().spec(pname)
                params[k] = {
                    "value": fit.values[k],
                    "stderr": fit.stderr.get(k, math.nan),
                    "unit": spec.unit,
                    "nominal": spec.nominal,
                }
                if k in fit.held:
                    params[k]["held_at_nominal"] = fit.held[k]
            nxt = next((f for f in self.ranking[rank:] if f.effects != fit.effects), None)
            rows.append(
                {
                    "rank": rank,
                    "name": fit.name,
                    "effects": list(fit.effects),
                    "params": params,
                    "heldout_shrink_pct": overall_shrink(
                        self.nominal_heldout[mask], fit.z_heldout[mask]
                    )
                    if nominal_rms > 0 and fit.z_heldout.size == mask.size
                    else 0.0,
                    "heldout_rms": fit.heldout_rms,
                    "heldout_score": fit.heldout_score,
                    "rank_score": fit.rank_score,
                    "bic_train": fit.bic,
                    "margin_to_next": (nxt.rank_score - fit.rank_score) if nxt else math.inf,
                    "verified_in_pybullet": fit.verified,
                    "screened": fit.screened,
                }
            )
        return rows

    def to_json(self) -> dict[str, Any]:
        """The JSON form: ``ranking`` (each candidate with fitted values and held-out shrink),
        ``verdict`` (effect names or ``"unexplained"`` / ``"none"``) and the details."""
        v = self.verdict
        return {
            "robot": self.settings.robot,
            "drive": self.settings.drive,
            "logs": {
                "train": [p.name for p in self.prepared if p.split == "train"],
                "holdout": [p.name for p in self.prepared if p.split == "holdout"],
                "window_split": any(
                    p.split == "train" and p.holdout_windows.any() for p in self.prepared
                ),
            },
            "nominal_reference": self.nominal_reference,
            "baseline_calibration": self.baseline.to_json(),
            "transients": self.transients.to_json(),
            "verdict": v.label,
            "budget": self.budget.to_json() if self.budget is not None else None,
            **v.notes.to_json(),
            "verdict_detail": {
                "kind": v.kind.value,
                "effects": list(v.effects),
                "reason": v.reason,
                "confidence": v.confidence.value,
                "margin": v.margin,
                "ambiguous_with": list(v.ambiguous_with),
                "remaining_residual": v.residual,
            },
            "coverage": self.coverage.to_json() if self.coverage is not None else None,
            "actuation": self.actuation or None,
            "ranking": self.ranking_rows(),
            "candidates": self.candidates,
            "not_observable": self.not_observable,
            "identifiability": self.identifiability,
            "localisation": self.localisation,
            "shrink": self.shrink,
            "shrink_best_candidate": self.shrink_best,
            "gap": self.gap,
            "surrogate_agreement": self.agreement,
            "timing_s": self.timing,
        }


# --------------------------------------------------------------------------- worker tasks
def _prepare_task(shared: tuple[Any, ...], item: tuple[Log, str]) -> PreparedLog:
    robot, drive, feats, sim = shared
    log, split = item
    return get_adapter(robot).prepare(
        log, split=split, drive=Drive(drive), features_settings=feats, sim=sim
    )


# --------------------------------------------------------------------------- stages
def candidate_library(adapter: RobotAdapter, settings: DiagnosisSettings) -> tuple[str, ...]:
    """The effects to consider: ``settings.effects`` (checked against the robot's), else all."""
    library = adapter.effect_names()
    _refuse_duplicates(library, f"the {settings.robot!r} effect library")
    if settings.effects is not None:
        _refuse_duplicates(settings.effects, "DiagnosisSettings.effects")
    for name in settings.effects if settings.effects is not None else library:
        cls = EFFECTS.get(name)
        for spec in getattr(cls, "specs", ()):
            if not spec.low < spec.high:
                raise ValueError(
                    f"effect {name!r}: parameter {spec.name!r} has bounds low={spec.low:g} ≥ "
                    f"high={spec.high:g}; fix: give the ParamSpec physical bounds with low < high"
                )
            if not spec.low <= spec.nominal <= spec.high:
                raise ValueError(
                    f"effect {name!r}: parameter {spec.name!r} has its nominal value "
                    f"{spec.nominal:g} outside its bounds {spec.low:g} … {spec.high:g}"
                )
    if settings.effects is None:
        return library
    # asked for by name, every registered effect of the robot is a candidate, in the default
    # library or not (an effect outside it is a baseline nuisance unless asked for)
    known = tuple(n for n, cls in EFFECTS.items() if cls.robot == settings.robot)
    unknown = [e for e in settings.effects if e not in known]
    if unknown:
        import difflib

        hints = [difflib.get_close_matches(u, known, n=1) for u in unknown]
        hint = "; ".join(
            f"{u!r} (did you mean {h[0]!r}?)" if h else repr(u) for u, h in zip(unknown, hints)
        )
        raise ValueError(
            f"unknown effect(s) {hint} for robot {settings.robot!r}; known: {', '.join(known)}"
        )
    return tuple(settings.effects)


def _refuse_duplicates(names: Sequence[str], what: str) -> None:
    seen: set[str] = set()
    dup = [n for n in names if n in seen or seen.add(n)]  # type: ignore[func-returns-value]
    if dup:
        raise ValueError(
            f"{what} names effect(s) {', '.join(repr(d) for d in dict.fromkeys(dup))} more than "
            "once; fix: list each effect once"
        )


def _split(
    logs: Sequence[Log], holdout: Sequence[Log] | None, settings: DiagnosisSettings
) -> list[tuple[Log, str]]:
    if holdout:
        return [(lg, "train") for lg in logs] + [(lg, "holdout") for lg in holdout]
    if len(logs) >= 2:
        n_ho = max(1, math.ceil(settings.holdout_fraction * len(logs)))
        n_ho = min(n_ho, len(logs) - 1)
        return [(lg, "train") for lg in logs[:-n_ho]] + [(lg, "holdout") for lg in logs[-n_ho:]]
    return [(logs[0], "train")]


def _window_split(prepared: list[PreparedLog], block: int) -> None:
    """Single-log diagnosis: alternate blocks of windows are held out."""
    p = prepared[0]
    m = p.bounds.shape[0]
    block = max(1, min(block, m // 2))
    p.holdout_windows = (np.arange(m) // block) % 2 == 1


def prepare_logs(
    adapter: RobotAdapter,
    logs: Sequence[Log],
    holdout: Sequence[Log] | None,
    settings: DiagnosisSettings,
    backend: Backend,
    say: Callable[[str], None],
) -> list[PreparedLog]:
    """Check every log, split training from held-out data and replay each nominally."""
    drive = Drive(settings.drive)
    for lg in list(logs) + list(holdout or []):
        adapter.check(lg, drive)
    items = _split(list(logs), list(holdout) if holdout else None, settings)
    say(f"replaying {len(items)} log(s) in the nominal simulation")
    prepared: list[PreparedLog] = backend.map(
        _prepare_task, items, (settings.robot, drive.value, settings.features, settings.sim)
    )
    if not any(p.split == "holdout" for p in prepared):
        _window_split(prepared, settings.block_windows)
    return prepared


def observable_candidates(
    adapter: RobotAdapter, library: Sequence[str], prepared: Sequence[PreparedLog], drive: Drive
) -> tuple[list[str], dict[str, str]]:
    """The effects the logs can show, and for the others why not."""
    not_observable = {}
    candidates = []
    for e in library:
        why = adapter.observable(e, prepared, drive)
        if why:
            not_observable[e] = why
        else:
            candidates.append(e)
    return candidates, not_observable


def coverage_report(
    problem: Problem, judgement: Judgement, settings: CoverageSettings | None
) -> Coverage | None:
    """Whether the held-out motions lie within the training's
    (:func:`~realitygap.diagnosis.stages.coverage.training_coverage`), for the best model of
    ``judgement``. :func:`~realitygap.diagnosis.verdict.rules.decide` puts it in the verdict's
    words when no effect is named and what remains gathers beyond the training
    (:attr:`Coverage.beyond_training`)."""
    if settings is None or problem.holdout.n == 0 or problem.train.n == 0:
        return None
    best = judgement.best
    used = sorted(set(problem.train.log.tolist()) | set(problem.holdout.log.tolist()))
    # the motion the robot made: a planar ground truth where the log has one, with each
    # wheel's speed where every log also states its wheelbase
    planar: dict[int, FloatArray] = {}
    wheelbase: dict[int, float] = {}
    for i in used:
        p = problem.logs[i]
        if p.log.has("pose_gt") and np.shape(p.log["pose_gt"])[-1] == 3:
            planar[i] = planar_motion(p.log.t, p.log["pose_gt"], p.bounds)
        b = p.context.reference_wheelbase()
        if b is not None:
            wheelbase[i] = b
    wheels = all(i in planar and i in wheelbase for i in used)
    motions: dict[int, FloatArray] = {}
    for i in used:
        if i in planar:
            m = planar[i]
            motions[i] = np.hstack([m, wheel_speeds(m, wheelbase[i])]) if wheels else m
        else:
            bounds = problem.logs[i].bounds
            m_ctx = problem.logs[i].context.window_motion(bounds)
            motions[i] = np.zeros((bounds.shape[0], 6)) if m_ctx is None else m_ctx
    motion_of = motions.__getitem__

    _, m_train = layout_windows(problem.train, motion_of)
    which, m_ho = layout_windows(problem.holdout, motion_of)
    cov = training_coverage(
        m_train,
        m_ho,
        which,
        judgement.nominal_heldout,
        best.z_heldout,
        judgement.gap_mask,
        variables=motion_variables(problem.adapter.motion_labels, wheels),
        best=best.name,
        settings=settings,
    )
    return cov


def _replay_seconds(
    adapter: RobotAdapter, prepared: Sequence[PreparedLog], measured_s: float, workers: int
) -> float:
    """Seconds a replay of every log costs in this run, on one core: what the nominal
    replays just took (on ``workers`` workers), or the adapter's probe of an uncached
    replay if that is less (the nominal replays included one-time work); when the
    nominal replays were read from the cache, they are what replays cost here."""
    probe = adapter.replay_seconds(prepared)
    taken = measured_s * min(workers, max(len(prepared), 1))
    return taken if probe is None else min(probe, taken)


# --------------------------------------------------------------------------- main entry
def check_request(
    logs: Sequence[Log],
    holdout: Sequence[Log] | None,
    settings: DiagnosisSettings,
    say: Callable[[str], None] | None = None,
) -> tuple[RobotAdapter, list[str], list[Log], list[Log] | None]:
    """Everything about a diagnosis request that can be checked before its work: the robot
    has an adapter, the candidate effects exist for it, the drive is known, every log is of
    that robot and long enough for at least two windows of at least two samples each.
    :func:`diagnose` calls it first; a command line calls it before saying what it will do.

    Returns
    -------
    adapter, library, logs, holdout
        The robot's adapter, the candidate effects, and the logs without the importer's
        pieces too short to read (:func:`~realitygap.diagnosis.logs.pieces.drop_short_pieces`).

    Raises
    ------
    ValueError
        An unknown robot, effect or drive; :class:`LogError` a log that does not fit.
    """
    if not logs:
        raise ValueError("diagnose needs at least one log")
    adapter: RobotAdapter = get_adapter(settings.robot)
    drive = Drive(settings.drive)
    library = candidate_library(adapter, settings)
    quiet = say if say is not None else (lambda msg: None)
    logs, holdout = drop_short_pieces(logs, holdout, 2.0 * settings.features.window_s, quiet)
    adapter.check_request([*logs, *(holdout or [])], settings.features, drive)
    return adapter, list(library), list(logs), holdout


def diagnose(
    logs: Sequence[Log],
    holdout: Sequence[Log] | None = None,
    *,
    settings: DiagnosisSettings | None = None,
    backend: Backend | None = None,
    progress: Callable[[str], None] | None = None,
    on_estimate: Callable[[float], None] | None = None,
) -> Diagnosis:
    """Diagnose the gap between real ``logs`` and the nominal simulation.

    Parameters
    ----------
    logs : sequence of Log
        Training logs (regular time stamps; for a differential drive ``cmd``
        and ``pose_gt``, or ``ticks`` and ``pose_gt`` with ``drive="ticks"``).
    holdout : sequence of Log, optional
        Held-out logs for scoring (other trajectories). Without them, the last
        third of several logs is held out, or alternate blocks of windows of a
        single log.
    settings : DiagnosisSettings, optional
    backend : Backend, optional
        Where replays and fits run (default: this process).
    progress : callable, optional
        Receives short progress messages.
    on_estimate : callable, optional
        Receives the estimated seconds left (:class:`~realitygap.diagnosis.fit.workload.Workload`:
        from the replay and surrogate rates measured in this run, corrected as stages
        finish), first once the nominal replays are done, then after every stage.

    Returns
    -------
    Diagnosis

    Raises
    ------
    LogError
        A log is unusable (missing channels, irregular time, …); the message
        names the file, the channel and the fix.
    ValueError
        Unknown robot or effect names.
    """
    _check_arguments(logs, holdout, settings, backend)
    s = settings if settings is not None else DiagnosisSettings()
    be = backend if backend is not None else SerialBackend()
    say = progress if progress is not None else (lambda msg: None)
    timing: dict[str, float] = {}
    t0 = time.perf_counter()
    adapter, library, logs, holdout = check_request(logs, holdout, s, say)
    drive = Drive(s.drive)
    split = _split(list(logs), list(holdout) if holdout else None, s)
    train_in = [lg for lg, part in split if part == "train"]
    other_in = [lg for lg, part in split if part != "train"]
    train_in, other_in, completed = adapter.complete_nominal(train_in, other_in)
    if completed:
        say(completed["summary"])
        logs, holdout = train_in, (other_in or None)
    prepared = prepare_logs(adapter, logs, holdout, s, be, say)
    reference = dict(adapter.link_logs(prepared, drive))
    if reference:
        say(reference["summary"])
    if completed:
        reference["effective_track"] = completed
        reference["summary"] = "; ".join(
            x for x in (reference.get("summary"), completed["summary"]) if x
        )
    timing["prepare"] = time.perf_counter() - t0

    problem = Problem(adapter, prepared, drive, s.features, s.sim, s.attribution)
    transients = TransientReport()
    if s.transients is not None and adapter.transient_detection:
        transients = detect_transients(problem, s.transients)
        problem.exclude(transients.masks)
        say(transients.summary())
        for ev in transients.events[:8]:
            say(
                f"  {ev.run} {ev.start_s:.1f}–{ev.end_s:.1f} s {ev.kind} "
                f"({'excluded' if ev.excluded else 'kept'}): {ev.channel} {ev.size:.3g} {ev.unit}; "
                f"{ev.signals}"
            )
    if problem.holdout.n == 0 or problem.train.n == 0:
        raise LogError(
            "the logs give no training or no held-out windows"
            + (" once transient events are set aside" if transients.n_excluded else "")
            + "; record longer episodes"
        )
    candidates, not_observable = observable_candidates(adapter, library, prepared, drive)
    workers = int(getattr(be, "workers", 1) or 1)
    workload = Workload.plan(
        problem,
        len(candidates),
        row_s=row_seconds(problem, candidates),
        replay_s=_replay_seconds(adapter, prepared, timing["prepare"], workers),
        workers=workers,
        calibrate=s.calibrate,
        conventions=len(adapter.actuator_conventions(prepared, drive)),
    )
    estimate_said = [math.inf]

    def stage_done(stage: str, seconds: float) -> None:
        workload.finish(stage, seconds)
        left = workload.remaining_s()
        if on_estimate is not None:
            on_estimate(left)
        # say it again when it moved by more than a quarter
        if abs(left - estimate_said[0]) > 0.25 * max(estimate_said[0], 1.0) and left >= 1.0:
            estimate_said[0] = left
            say(f"estimate: about {duration_words(left).removeprefix('about ')} left")

    first = workload.remaining_s()
    estimate_said[0] = first
    if on_estimate is not None:
        on_estimate(first)
    say(
        f"measured: a PyBullet replay of the logs {workload.replay_s:.1f} s, a surrogate "
        f"evaluation {1e3 * workload.row_s:.2f} ms; estimate: about "
        f"{duration_words(first).removeprefix('about ')} left"
    )
    baseline = Baseline()
    if s.calibrate:
        t_b = time.perf_counter()
        baseline = calibrate_baseline(problem, candidates, be, say, clock=s.clock, frames=s.frames)
        timing["baseline"] = time.perf_counter() - t_b
        stage_done("baseline", timing["baseline"])
        if baseline.values:
            say(baseline.summary())
    loc = localise(prepared, adapter, s.features)

    t1 = time.perf_counter()
    singles, pairs, nominal_fit = fit_candidates(problem, candidates, be, say, stage_done)
    timing["fit"] = time.perf_counter() - t1

    t2 = time.perf_counter()
    verification: Verification = verify_ranking(problem, [*singles, *pairs], nominal_fit, be, say)
    timing["verify"] = time.perf_counter() - t2
    stage_done("verify", timing["verify"])

    noise = adapter.noise_levels(prepared, s.features)
    t_bud = time.perf_counter()
    budget = gap_budget(
        problem,
        candidates,
        verification.ranking,
        be,
        say,
        noise,
        seed=s.attribution.seed,
        sample_noise=adapter.sample_noise_levels(prepared, s.features),
    )
    timing["budget"] = time.perf_counter() - t_bud
    stage_done("budget", timing["budget"])
    say(budget.sentence())
    judgement = heldout_view(problem, budget, nominal_fit, noise)
    best = judgement.best
    named = judgement.kind in (VerdictKind.EFFECTS, VerdictKind.PARTIAL)
    coverage = coverage_report(problem, judgement, s.coverage)
    residual = describe_fit_residual(problem, best, noise)
    structured = any(
        r["structured_pct"] > 0.5 * r["remaining_pct"] for r in budget.remainder.values()
    )
    discovery = run_discovery(problem, judgement, structured)
    robot = None
    if named:
        robot = adapter.fitted_robot(prepared, budget.named, budget.values)
        if robot is not None:
            say(f"fitted robot: {robot['message']}")
    actuation_note: dict[str, Any] | None = None
    tracking_note: dict[str, Any] | None = None
    actuation = adapter.actuation(prepared, drive)
    spread = actuation.get("spread")
    if spread is not None and spread["differs"]:
        actuation_note = spread
        say(f"drive train: {spread['message']}")
    tracking = actuation.get("tracking")
    if tracking is not None and tracking["beyond"]:
        tracking_note = tracking
        say(f"wheels: {tracking['message']}")
    reach = None
    if s.reach and not named and judgement.kind is VerdictKind.UNEXPLAINED:
        workload.add_reach(problem, len(candidates))
        stage_done("rest", time.perf_counter() - t2 - timing["verify"] - timing["budget"])
        t_r = time.perf_counter()
        reach = library_reach(
            problem,
            candidates,
            judgement.nominal_heldout,
            judgement.gap_mask,
            judgement.shrink_pct_best,
            be,
            say,
            block=s.block_windows,
        )
        timing["reach"] = time.perf_counter() - t_r
        stage_done("reach", timing["reach"])
        if reach is not None:
            say(f"reach: {reach.message}")
    replays = dict(verification.replays)
    if budget.entries and best.effects not in replays:
        replays[best.effects] = budget_replays(problem, budget, be)
    rows, gap = gap_report(problem, judgement, replays, baseline)
    status: dict[str, dict[str, str]] = {}
    for f in verification.ranking[:8]:
        st_f = parameter_status(problem, f)
        for k in st_f:
            f.stderr[k] = math.nan
        if st_f:
            status[f.name] = st_f
    z_nom = judgement.nominal_heldout
    consistency = [
        regime_consistency(problem, f, z_nom, judgement.gap_mask)
        for f in [best, *verification.ranking[:4]]
        if f.effects and f.z_heldout.shape == z_nom.shape
    ]
    verdict = conclude(
        budget,
        judgement,
        residual=residual,
        aliases=alias_notes(problem, budget, verification.ranking),
        regime_consistency=consistency,
        parameter_status=status,
        discovery=discovery.to_json() if discovery is not None else None,
        coverage=(
            CoverageNote(coverage.summary(), coverage.suggestion())
            if coverage is not None and coverage.beyond_training and not named
            else None
        ),
        robot=robot,
        actuation=actuation_note,
        tracking=tracking_note,
        reach=reach.to_json() if reach is not None else None,
        gap_words=gap_words(gap),
    )

    if coverage is not None:
        say(f"coverage: {coverage.summary()}")
    timing["total"] = time.perf_counter() - t0
    say(f"verdict: {verdict.label}")
    return Diagnosis(
        settings=s,
        prepared=prepared,
        candidates=candidates,
        not_observable=not_observable,
        localisation=loc,
        ranking=verification.ranking,
        verdict=verdict,
        identifiability=[
            a["identifiability"] for a in verdict.notes.aliases if "identifiability" in a
        ],
        shrink=rows,
        gap=gap,
        agreement=verification.agreement,
        corrected_replays=replays.get(best.effects) or {},
        timing=timing,
        nominal_heldout=z_nom,
        problem=problem,
        gap_mask=judgement.gap_mask,
        shrink_best=shrink_table(z_nom, best.z_heldout, problem.holdout, s.features),
        baseline=baseline,
        transients=transients,
        nominal_reference=reference,
        coverage=coverage,
        actuation=actuation,
        budget=budget,
        budget_model=best if budget.entries else None,
    )
