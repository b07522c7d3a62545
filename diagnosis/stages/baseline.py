r"""The calibrated baseline: nuisances present in every real log, fitted before any effect.

A real log and its nominal replay never agree on everything that is a matter of
convention rather than of physics: when within a sample period a command takes
effect (the zero-order hold of the replayed commands and the response of the
nominal's actuators to them), and when within a sample period a channel was
stamped (time alignment between the commands, the encoders and the ground
truth). Left alone, these small differences are picked up by whichever effect
can absorb them — a time offset of some ten milliseconds came out beside the
true effect on every robot the diagnosis did not simulate itself.

Beside these continuous nuisances an adapter may offer discrete conventions
of the nominal's actuator response (:meth:`actuator_conventions` of the
adapter; for the differential drive, whether the firmware's rate limit ramps
the body twist, as ros2 ``diff_drive_controller`` does, or each wheel, as many
motor firmwares do, and whether it limits deceleration too or brakes at once);
:func:`choose_convention` replays each, fits the nuisances under it and keeps
the one that fits best, with each nuisance free over its effect's physical
range so that a larger latency or lag cannot decide the choice. It is reported
with the nuisances as baseline calibration.

Each adapter states its nuisances (:meth:`baseline_nuisances` of the adapter):
``{"effect.param": (low, high, what)}`` — an existing effect's parameter with a
*narrow* range around its nominal value that is a convention, not a finding.
For the differential drive these are the ground truth's time alignment
(``timestamp_offset.offset``, within half a sample period) and the response
time of the replayed commands (``command_latency.delay``, with a
command-driven replay, within half a sample period, or one period when the
logged commands are requests to the robot's firmware):

.. math::  |δ_{align}| \le \tfrac{1}{2} Δt, \qquad 0 \le τ_{resp} \le \tfrac{1}{2} Δt
           \ (\text{requests: } Δt),

because stamps are quantised to the sample period :math:`Δt`, and whether a
firmware takes a request in the period it is issued or the next one (or
through a velocity loop that settles within a period) is the robot's actuator
response. Larger
values are findings and remain candidates of the effect library.

:func:`calibrate_baseline` fits the nuisances together on the training windows
(robust loss, :func:`~realitygap.diagnosis.fit.model.fit_model`), replays every
log in PyBullet at the fitted values and makes that replay the reference of the
whole diagnosis: the surrogate's bias is re-anchored there
(PyBullet − surrogate at the baseline), :meth:`Problem.nominal_residuals`
returns the baseline's residual, and every model carries the baseline values
for the parameters it does not fit itself. Ranking, shrink, the open-set
verdict and the structured-residual test are therefore all scored against the
calibrated baseline, and an effect that duplicates a nuisance (a time offset
within the nuisance range) gains nothing over it and cannot be a finding.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.parallel import Backend
from realitygap.diagnosis.adapters.contract import ActuatorLimits, Drive, PreparedLog, RobotAdapter
from realitygap.diagnosis.fit.model import _rho, fit_model, replay_task
from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.parameters import model_keys, param_spec, split_key
from realitygap.diagnosis.problem.problem import Problem
from realitygap.diagnosis.problem.shrink import overall_shrink
from realitygap.diagnosis.stages.clock import (
    ClockAlignment,
    ClockSettings,
    align_clocks,
    timing_channel,
)
from realitygap.diagnosis.stages.frames import FrameAlignment, align_frames, frame_channel

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "Baseline",
    "NuisanceRange",
    "calibrate_baseline",
    "check_nuisances",
    "choose_convention",
]

NuisanceRange = tuple[float, float, str]
"""``(low, high, what)``: a nuisance parameter's range (natural units) and what it stands for."""


@dataclass
class Baseline:
    """The calibrated baseline of a diagnosis.

    Attributes
    ----------
    values : dict of str to float
        Fitted nuisance values ``{"effect.param": value}`` (natural units).
    ranges : dict of str to NuisanceRange
        The range each nuisance was allowed.
    units : dict of str to str
    train_shrink_pct : float
        How much of the nominal replay's training residual the baseline removes, %.
        A baseline whose PyBullet replay does not lower the robust training cost
        is not applied (``values`` empty).
    replays : dict of int to Log
        PyBullet replays of each log at the baseline.
    convention : str
        The actuator convention of the nominal chosen by the calibration
        (``""``: the adapter offers none), e.g. ``"wheels/free"`` for a
        firmware that ramps each wheel up and brakes at once.
    convention_what : str
        What the chosen convention means.
    convention_costs : dict of str to float
        Robust cost of each convention over every window, its nuisances fitted
        on the training windows (lower is better; the same loss scale for all).
    clock : ClockAlignment
        Each log's own clock offset, fitted before the nuisances: the deviations
        from the common offset that were applied by re-stamping the log
        (:mod:`~realitygap.diagnosis.stages.clock`).
    frames : FrameAlignment
        Each log's own ground-truth frame, fitted after the clocks: the deviations
        from the common frame that were applied by re-framing the log
        (:mod:`~realitygap.diagnosis.stages.frames`).
    convention_limits : dict
        The chosen convention's continuous limits fitted on the training logs
        (the adapter's :meth:`fit_actuator_limits`, JSON form; empty when the
        adapter fits none), e.g. the firmware's acceleration limits over the
        stated ones and its deceleration factor.
    """

    values: dict[str, float] = field(default_factory=dict)
    ranges: dict[str, NuisanceRange] = field(default_factory=dict)
    units: dict[str, str] = field(default_factory=dict)
    train_shrink_pct: float = 0.0
    replays: dict[int, Log] = field(default_factory=dict)
    convention: str = ""
    convention_what: str = ""
    convention_costs: dict[str, float] = field(default_factory=dict)
    clock: ClockAlignment = field(default_factory=ClockAlignment)
    convention_limits: dict[str, Any] = field(default_factory=dict)
    frames: FrameAlignment = field(default_factory=FrameAlignment)

    def to_json(self) -> dict[str, Any]:
        """JSON form: one row per nuisance and the training shrink of the baseline."""
        return {
            "nuisances": [
                {
                    "parameter": k,
                    "value": v,
                    "unit": self.units.get(k, ""),
                    "range": [self.ranges[k][0], self.ranges[k][1]],
                    "what": self.ranges[k][2],
                }
                for k, v in self.values.items()
            ],
            "train_shrink_pct": self.train_shrink_pct,
            "actuator_convention": {
                "chosen": self.convention,
                "what": self.convention_what,
                "cost": dict(self.convention_costs),
                "limits": dict(self.convention_limits),
            }
            if self.convention
            else None,
            "clock_alignment": self.clock.to_json() if self.clock.rows else None,
            "frame_alignment": self.frames.to_json() if self.frames.rows else None,
        }

    def summary(self) -> str:
        """One line for the terminal and the report."""
        conv = f"actuator response: {self.convention_what}" if self.convention else ""
        clock = "; ".join(x for x in (self.clock.summary(), self.frames.summary()) if x)
        lim = self.convention_limits
        if conv and "accel_scale" in lim:
            conv += (
                f" (limits fitted to the encoders: acceleration ×{lim['accel_scale']:.2f} "
                f"the stated, deceleration ×{lim['decel_factor']:.2f} the acceleration)"
            )
        if not self.values:
            head = "; ".join(x for x in (conv, clock) if x)
            return "baseline calibration: " + (head or "none (the adapter states no nuisances)")
        parts = [x for x in (conv, clock) if x]
        for k, v in self.values.items():
            unit = self.units.get(k, "")
            scale, shown = {"s": (1e3, "ms"), "m": (1e3, "mm"), "rad": (1e3, "mrad")}.get(
                unit, (1.0, unit)
            )
            parts.append(f"{self.ranges[k][2]} {scale * v:+.1f} {shown}".rstrip())
        return (
            "baseline calibration: "
            + "; ".join(parts)
            + f" (removes {self.train_shrink_pct:.1f} % of the nominal training residual)"
        )


def check_nuisances(ranges: Mapping[str, NuisanceRange]) -> None:
    """Refuse a nuisance range that is empty or outside its parameter's physical bounds."""
    for key, (low, high, _) in ranges.items():
        spec = param_spec(key)
        if not low < high:
            raise ValueError(
                f"baseline nuisance {key!r}: low ({low:g}) must be below high ({high:g})"
            )
        if low < spec.low or high > spec.high:
            raise ValueError(
                f"baseline nuisance {key!r}: range {low:g} … {high:g} leaves the physical bounds "
                f"{spec.low:g} … {spec.high:g} of the parameter"
            )


def _prepare_task(problem: Problem, item: tuple[int, Log]) -> PreparedLog:
    i, log = item
    old = problem.logs[i]
    p = problem.adapter.prepare(
        log,
        split=old.split,
        drive=problem.drive,
        features_settings=problem.features,
        sim=problem.sim,
    )
    p.holdout_windows = old.holdout_windows.copy()
    return p


def _fitted_cost(
    problem: Problem, effects: tuple[str, ...], box: Mapping[str, tuple[float, float]], c: float
) -> tuple[float, dict[str, float]]:
    """Robust cost (loss scale ``c``) over every window of ``problem`` with the nuisances
    fitted on the training windows."""
    values: dict[str, float] = {}
    if effects:
        values = dict(fit_model(problem, effects, box=box).values)
    point = {k: np.array([v]) for k, v in values.items()}
    cost = 0.0
    for layout in (problem.train, problem.holdout):
        if layout.n:
            z = problem.surrogate_residuals(layout, point, 1)[0]
            cost += float(np.sum(_rho(z**2, problem.settings.loss, c)))
    return cost, values


def _fit_limits_task(shared: tuple[RobotAdapter, list[Log]], name: str) -> ActuatorLimits | None:
    adapter, logs = shared
    return adapter.fit_actuator_limits(logs, name)


def _trivial_limits(fit: ActuatorLimits | None) -> bool:
    """Whether fitted limits leave the stated ones as they are (no fit, or the stated)."""
    return fit is None or fit.leaves_stated()


def choose_convention(
    problem: Problem,
    effects: tuple[str, ...],
    box: Mapping[str, tuple[float, float]],
    backend: Backend,
    say: Callable[[str], None] = lambda msg: None,
) -> tuple[str, str, dict[str, float], dict[str, Any]]:
    """Choose the nominal's actuator convention that fits the logs best.

    Each convention the adapter offers (:meth:`actuator_conventions`, e.g. a
    firmware that ramps the body twist or each wheel, that limits slowing down
    or not, that stops at once on a zero request) first gets its continuous
    limits fitted on the training logs (:meth:`fit_actuator_limits`: for the
    differential drive the firmware's acceleration and deceleration limits,
    fitted to the encoders within physical bounds of the stated ones), is
    screened on the surrogate (:meth:`prepare_on_surrogate`: the nominal replays'
    PyBullet defect carried over) and, unless its screened cost exceeds the best by
    more than ``margin_strong``, replayed in PyBullet with them; the nuisances
    ``effects`` are fitted inside ``box`` on the training windows, and the robust cost over every window
    (training and held-out, transient events set aside) is compared at one loss
    scale; ``problem`` is switched in place to the convention of least cost.
    :func:`calibrate_baseline` passes a ``box`` that frees each nuisance over its
    effect's physical range, not its narrow nuisance range: the choice is then
    made with the effects a nuisance stands for (a command latency of a few
    periods, a slow velocity loop, a late clock) profiled out. Judged with the
    narrow ranges, a robot whose commands act 200 ms late was given the ramp
    convention that best imitates a delay (each wheel ramped), and the latency,
    scored against that reference, no longer explained its own gap.

    The convention is a property of the robot's firmware, the same in every
    log, and the motions that tell conventions apart (arcs while the speed
    changes) may lie only in the held-out logs — a training set of straight
    runs and turns in place ramps identically under both. The choice is one
    discrete bit made on the reference replay without any effect, so it
    cannot favour an effect; it only makes the reference every effect is
    scored against the better one. The continuous limits use the training
    logs only.

    Returns
    -------
    name, what, costs, limits : str, str, dict of str to float, dict
        ``limits`` is the chosen convention's fit in JSON form (empty when the
        adapter fits none); ``("", "", {}, {})`` when the adapter offers fewer
        than two conventions.
    """
    offered = problem.adapter.actuator_conventions(problem.logs, problem.drive)
    if len(offered) < 2 or problem.train.n == 0:
        return "", "", {}, {}
    c = problem.f_scale
    adapter = problem.adapter
    current = adapter.actuator_convention(problem.logs[0].log)
    train_logs = [p.log for p in problem.logs if p.split == "train"]
    say(f"fitting the limits of {len(offered)} actuator conventions to the training logs")
    fitted = backend.map(_fit_limits_task, list(offered), (adapter, train_logs))
    fits = dict(zip(offered, fitted, strict=True))
    own = {
        name: name == current and _trivial_limits(fits[name]) for name in offered
    }  # the logs as prepared: nothing to replay

    def relogged(name: str) -> list[tuple[int, Log]]:
        return [
            (
                i,
                adapter.with_actuator_limits(
                    adapter.with_actuator_convention(p.log, name), fits[name]
                ),
            )
            for i, p in enumerate(problem.logs)
        ]

    def candidate(logs: list[PreparedLog], replayed: bool = True) -> Problem:
        # logs that declare different geometries stay on the one reference (a screened
        # log keeps the reference its replayed original was linked to)
        if replayed:
            adapter.link_logs(logs, problem.drive)
        cand = Problem(
            adapter, list(logs), problem.drive, problem.features, problem.sim, problem.settings
        )
        cand.exclude(problem.excluded)
        return cand

    # screen every convention on the surrogate (the nominal replays' PyBullet defect
    # carried over), then replay in PyBullet only those whose screened cost lies within
    # ``margin_strong`` of the best: a larger difference is decisive on its own
    screened: dict[str, float] = {}
    for name in offered:
        if own[name]:
            continue
        preps = [adapter.prepare_on_surrogate(problem.logs[i], lg) for i, lg in relogged(name)]
        if any(p is None for p in preps):
            screened = {}
            break
        screened[name], _ = _fitted_cost(candidate(list(preps), False), effects, box, c)  # type: ignore[arg-type]
    costs: dict[str, float] = {}
    options: dict[str, Problem] = {}
    for name in offered:
        if own[name]:
            costs[name], _ = _fitted_cost(problem, effects, box, c)
            options[name] = problem
    if screened:
        bar = min([*screened.values(), *costs.values()]) + problem.settings.margin_strong
        left_out = [n for n, v in screened.items() if v > bar]
        if left_out:
            say(
                f"screened {len(screened)} actuator conventions on the surrogate; "
                f"{', '.join(repr(n) for n in left_out)} fit the logs clearly worse and are not "
                "replayed"
            )
    for name in offered:
        if own[name] or (screened and screened[name] > bar):
            continue
        say(f"replaying with the actuator convention {name!r}")
        logs = list(backend.map(_prepare_task, relogged(name), problem))
        cand = candidate(logs)
        costs[name], _ = _fitted_cost(cand, effects, box, c)
        options[name] = cand
    best = min(costs, key=lambda k: costs[k])
    if options[best] is not problem:
        problem.logs[:] = options[best].logs
        problem.exclude(problem.excluded)
    fit = fits[best]
    limits = fit.to_json() if fit is not None else {}
    # the costs reported: PyBullet's where replayed, the screening's otherwise
    costs = {name: costs.get(name, screened.get(name, math.nan)) for name in offered}
    return best, offered[best], costs, limits


def calibrate_baseline(
    problem: Problem,
    candidates: Sequence[str],
    backend: Backend,
    say: Callable[[str], None] = lambda msg: None,
    clock: ClockSettings | None = None,
    frames: bool = False,
) -> Baseline:
    """Fit the adapter's nuisances and make the baseline the reference of ``problem``.

    Parameters
    ----------
    problem : Problem
        Modified in place: ``baseline_values``, ``baseline_features`` and every
        log's surrogate ``bias`` are set to the baseline.
    candidates : sequence of str
        Observable effects; a nuisance whose effect is not among them is skipped.
    backend : Backend
        Where the PyBullet replays run.
    say : callable
    clock : ClockSettings, optional
        Fit each log's own clock offset first and re-stamp the logs whose
        deviation from the common offset is a synchronisation error
        (:func:`~realitygap.diagnosis.stages.clock.align_clocks`, on the nuisance that
        shifts a channel's stamps); ``None`` leaves every log's clock alone. Only
        a replay driven by the measured wheel motion (``Drive.TICKS``) is aligned:
        with a command-driven one, each log's manoeuvres meet the drive train's
        response differently, and a per-log time shift would absorb part of it.
    frames : bool
        Fit each log's own ground-truth frame after the clocks and re-frame the
        logs whose deviation from the common frame is their own
        (:func:`~realitygap.diagnosis.stages.frames.align_frames`, on the three parameters
        of a nuisance effect that re-frames one channel). Like the clocks, only with
        a replay driven by the measured wheel motion: a command-driven reference
        leaves the drive train's response in every window, and a per-log frame
        would absorb part of it.

    Returns
    -------
    Baseline
    """
    ranges: dict[str, NuisanceRange] = dict(
        problem.adapter.baseline_nuisances(problem.logs, problem.drive)
    )
    # a nuisance of a library effect counts only where that effect is a candidate; an effect
    # outside the default library is a nuisance only unless asked for; and the frame the
    # ground truth tracks is the measurement setup's convention, fitted whichever effects
    # are candidates
    default = set(problem.adapter.effect_names())
    ranges = {
        k: r
        for k, r in ranges.items()
        if split_key(k)[0] in candidates
        or split_key(k)[0] not in default
        or frame_channel(split_key(k)[0]) is not None
    }
    check_nuisances(ranges)
    if not ranges or problem.train.n == 0:
        return Baseline()
    aligned = ClockAlignment()
    timing = [k for k in ranges if timing_channel(k) is not None]
    # only a replay driven by the measured wheel motion isolates the clock: with a command-
    # driven replay each log's manoeuvres meet the drive train's response (lags, ramps,
    # limits) differently, and a per-log time shift would absorb part of it
    if clock is not None and timing and problem.drive is Drive.TICKS:
        say(f"aligning each log's clock ({timing[0]})")
        aligned = align_clocks(problem, timing[0], clock, say)
    framed = FrameAlignment()
    frame_keys = [k for k in ranges if frame_channel(split_key(k)[0]) is not None]
    if frames and len(frame_keys) == 3 and problem.drive is Drive.TICKS:
        say(f"aligning each log's ground-truth frame ({', '.join(frame_keys)})")
        own = [e for e in candidates if e in default and frame_channel(e) is None]
        framed = align_frames(
            problem, frame_keys, [ranges[k][:2] for k in frame_keys], say, effects=own
        )
    effects = tuple(dict.fromkeys(split_key(k)[0] for k in ranges))
    box = {k: (r[0], r[1]) for k, r in ranges.items()}
    # parameters of a nuisance effect that are not nuisances stay at nominal
    for k in model_keys(effects):
        if k not in box:
            nom = param_spec(k).nominal
            span = 1e-9 * (param_spec(k).high - param_spec(k).low)
            box[k] = (max(nom - span, param_spec(k).low), min(nom + span, param_spec(k).high))
    # the convention is judged with each nuisance free over its effect's physical range: a
    # long command latency or a slow speed loop (candidates of the library, larger than any
    # nuisance) would otherwise decide the one discrete choice every effect is scored against
    choice_box = {**box, **{k: (param_spec(k).low, param_spec(k).high) for k in ranges}}
    conv, conv_what, conv_costs, conv_limits = choose_convention(
        problem, effects, choice_box, backend, say
    )
    if conv:
        say(f"actuator response of the nominal: {conv_what}")
    say(f"calibrating the baseline: {', '.join(ranges)}")
    fit = fit_model(problem, effects, box=box)
    values = {k: fit.values[k] for k in ranges}
    idx = list(range(len(problem.logs)))
    reps = backend.map(replay_task, [(i, values) for i in idx], problem)
    z_before = problem.nominal_residuals(problem.train)
    features: dict[int, dict[str, FloatArray]] = {}
    replays: dict[int, Log] = {}
    point = {k: np.array([v]) for k, v in values.items()}
    for i, (feats, rep) in zip(idx, reps):
        p: PreparedLog = problem.logs[i]
        features[i] = {g: feats[g] for g in p.groups}
        replays[i] = rep
    old_bias = {i: p.bias for i, p in enumerate(problem.logs)}
    for i, p in enumerate(problem.logs):
        sur = problem.adapter.surrogate_features(p, point, problem.drive)
        p.bias = {g: features[i][g] - sur[g][0] for g in p.groups}
    problem.baseline_values = values
    problem.baseline_features = features
    problem.baseline_ranges = {k: (r[0], r[1]) for k, r in ranges.items()}
    z_after = problem.nominal_residuals(problem.train)
    st = problem.settings
    cost_before = float(np.sum(_rho(z_before**2, st.loss, problem.f_scale)))
    cost_after = float(np.sum(_rho(z_after**2, st.loss, problem.f_scale)))
    if not cost_after < cost_before:
        # the PyBullet replay at the surrogate's optimum is no better: keep the nominal robot
        for i, p in enumerate(problem.logs):
            p.bias = old_bias[i]
        problem.baseline_values, problem.baseline_features = {}, {}
        problem.baseline_ranges = {}
        say("baseline calibration: the nuisances do not improve the nominal replay; none applied")
        return Baseline(
            ranges=ranges,
            units={k: param_spec(k).unit for k in ranges},
            convention=conv,
            convention_what=conv_what,
            convention_costs=conv_costs,
            clock=aligned,
            convention_limits=conv_limits,
            frames=framed,
        )
    problem.f_scale = problem.noise_scale()
    return Baseline(
        values=values,
        ranges=ranges,
        units={k: param_spec(k).unit for k in ranges},
        train_shrink_pct=overall_shrink(z_before, z_after),
        replays=replays,
        convention=conv,
        convention_what=conv_what,
        convention_costs=conv_costs,
        clock=aligned,
        convention_limits=conv_limits,
        frames=framed,
    )
