"""Blind validation of the diagnosis: hidden effects realised in PyBullet, then diagnosed.

Each :class:`BlindCase` draws one hidden effect (sometimes two) with a
realistic magnitude from a seeded generator (the robot adapter's
:meth:`~realitygap.diagnosis.adapters.contract.RobotAdapter.hidden_effects`), realises it
in the PyBullet robot, records a training and a held-out set of logs with the
adapter's blind-log recorder
(:meth:`~realitygap.diagnosis.adapters.contract.RobotAdapter.record_blind_logs`: ordinary
manoeuvres of the differential drive with motion-capture and camera noise,
random poses of the arm under a simulated laser tracker, paths of the climber
on the blade) and runs :func:`~realitygap.diagnosis.diagnose.diagnose` without
telling it the truth. In a quarter of the cases a true effect is removed from
the candidate library (open set): the right answer is then ``"unexplained"``.

:func:`summarise` turns case outcomes into the suite's figures (top-1 / top-2
accuracy, parameter error, held-out shrink, open-set and false-attribution
rates) and a confusion matrix. Top-1 is strict (the verdict's own model is
the truth); ``top1_alias_aware_accuracy`` also counts a verdict "X or Y
(aliases on this data)" whose alternatives include the truth, reported beside
the strict figure, never instead of it.
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
from realitygap.diagnosis.adapters.contract import BlindLogSettings, HiddenTable
from realitygap.diagnosis.adapters.registry import get_adapter, known_robots
from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.parameters import split_key
from realitygap.diagnosis.verdict.notes import verdict_alternatives
from realitygap.diagnosis.verdict.types import VerdictKind
from realitygap.robots.effects import EFFECTS, Reality, make_effect
from realitygap.robots.simulation import MeasurementNoise

__all__ = [
    "BlindCase",
    "SuiteSettings",
    "draw_cases",
    "run_case",
    "summarise",
    "withheld_exercised",
]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class SuiteSettings:
    """Settings of the blind suite.

    Attributes
    ----------
    noise : MeasurementNoise or None
        Motion-capture and camera noise of a differential drive's recorded logs
        (``None``: the adapter's ``blind_noise``).
    pair_probability : float
        Chance that a case hides two effects.
    open_set_every : int
        Every this-many-th case withholds a true effect from the library.
    diagnosis : DiagnosisSettings
    robot : str
        A robot with a diagnosis adapter (:func:`~realitygap.diagnosis.adapters.registry.known_robots`).
    arm_poses : int
        Arm: measured poses per log (one training and one held-out log).
    arm_tracker_noise : float
        Arm: laser-tracker noise per axis (m).
    """

    noise: MeasurementNoise | None = None
    pair_probability: float = 0.25
    open_set_every: int = 4
    diagnosis: DiagnosisSettings = field(default_factory=DiagnosisSettings)
    robot: str = "diffdrive"
    arm_poses: int = 96
    arm_tracker_noise: float = 2e-5

    def __post_init__(self) -> None:
        if self.robot not in known_robots():
            raise ValueError(
                f"the blind suite runs for {', '.join(known_robots())}; got robot {self.robot!r}"
            )

    @property
    def hidden_effects(self) -> HiddenTable:
        """The hidden-effect table of :attr:`robot` (its adapter's)."""
        return get_adapter(self.robot).hidden_effects()

    @property
    def blind_logs(self) -> BlindLogSettings:
        """What the adapter's blind-log recorder is told
        (:meth:`~realitygap.diagnosis.adapters.contract.RobotAdapter.record_blind_logs`)."""
        return BlindLogSettings(
            noise=self.noise, arm_poses=self.arm_poses, arm_tracker_noise=self.arm_tracker_noise
        )


@dataclass(frozen=True)
class BlindCase:
    """One blind case: the hidden truth and what the library lacks."""

    index: int
    truth: tuple[tuple[str, tuple[tuple[str, float], ...]], ...]
    withheld: tuple[str, ...]
    seed: int

    @property
    def truth_names(self) -> tuple[str, ...]:
        return tuple(sorted(name for name, _ in self.truth))

    @property
    def open_set(self) -> bool:
        return bool(self.withheld)

    def reality(self) -> Reality:
        return Reality(tuple(make_effect(n, **dict(v)) for n, v in self.truth))

    def truth_values(self) -> dict[str, float]:
        return {f"{n}.{k}": x for n, vals in self.truth for k, x in vals}


def _draw_values(
    name: str, rng: np.random.Generator, table: HiddenTable
) -> tuple[tuple[str, float], ...]:
    out = []
    for param, low, high, symmetric, absolute in table[name]:
        nominal = next(s.nominal for s in EFFECTS[name].specs if s.name == param)
        mag = float(rng.uniform(low, high))
        if absolute:
            value = mag
        elif symmetric:
            value = nominal + (mag if rng.random() < 0.5 else -mag)
        else:
            value = nominal + mag
        out.append((param, value))
    return tuple(out)


def draw_cases(n: int, seed: int, settings: SuiteSettings | None = None) -> list[BlindCase]:
    """``n`` blind cases from ``np.random.default_rng(seed)``.

    Effects cycle through the library in a shuffled order so every effect is
    hidden about equally often; a quarter of the cases (every
    ``open_set_every``-th) withhold one true effect from the library.
    """
    s = settings if settings is not None else SuiteSettings()
    rng = np.random.default_rng(seed)
    table = s.hidden_effects
    names = list(table)
    order: list[str] = []
    cases = []
    for i in range(n):
        if not order:
            order = list(rng.permutation(names))
        first = order.pop()
        chosen = [first]
        if rng.random() < s.pair_probability:
            others = [x for x in names if x != first]
            chosen.append(str(rng.choice(others)))
        truth = tuple((name, _draw_values(name, rng, table)) for name in chosen)
        withheld: tuple[str, ...] = ()
        if s.open_set_every > 0 and i % s.open_set_every == s.open_set_every - 1:
            withheld = (str(rng.choice(chosen)),)
        cases.append(
            BlindCase(index=i, truth=truth, withheld=withheld, seed=int(rng.integers(2**31)))
        )
    return cases


def _measurement_tolerance(settings: SuiteSettings) -> dict[str, FloatArray]:
    """Per channel and column, the measurement noise of the suite's recorded logs: the
    size below which a difference between two recordings is not a measurable one."""
    return get_adapter(settings.robot).blind_measurement_noise(settings.blind_logs)


def withheld_exercised(
    settings: SuiteSettings, case: BlindCase, train: Sequence[Log], holdout: Sequence[Log]
) -> bool:
    """Whether a case's withheld effect changes any recorded measurement beyond its noise.

    The case's logs are recorded again, with the same seed, without the withheld
    effect; where no ground-truth sample of any log moves by more than the
    measurement noise (:func:`_measurement_tolerance`), the withheld effect never
    acted on these motions (a slip limit the manoeuvres never reach), and the case
    is not an open-set case: the effects left in the library are the whole truth.
    Robots without a stated tolerance, recordings that differ in shape, and cases
    whose every effect is withheld count as exercised.
    """
    tol = _measurement_tolerance(settings)
    kept = tuple((n, v) for n, v in case.truth if n not in case.withheld)
    if not case.withheld or not kept or not tol:
        return True
    rng = np.random.default_rng(case.seed)
    reality = Reality(tuple(make_effect(n, **dict(v)) for n, v in kept))
    again = get_adapter(settings.robot).record_blind_logs(reality, rng, settings.blind_logs)
    if len(train) + len(holdout) != len(again[0]) + len(again[1]):
        return True
    for ours, theirs in zip((*train, *holdout), (*again[0], *again[1]), strict=True):
        for channel, limit in tol.items():
            if not (ours.has(channel) and theirs.has(channel)):
                return True
            a, b = np.asarray(ours[channel], float), np.asarray(theirs[channel], float)
            if a.shape != b.shape or a.shape[-1] != limit.size:
                return True
            if np.any(np.abs(a - b) > limit):
                return True
    return False


def run_case(settings: SuiteSettings, case: BlindCase) -> dict[str, Any]:
    """Record and diagnose one blind case; the outcome as a JSON-able dict.

    An open-set case whose withheld effect never acts on the recorded motions
    (:func:`withheld_exercised`) is scored as an in-library case of the effects
    left in the library (``withheld_exercised`` is ``False`` in the outcome).
    """
    t0 = time.perf_counter()
    rng = np.random.default_rng(case.seed)
    reality = case.reality()
    train, holdout = get_adapter(settings.robot).record_blind_logs(
        reality, rng, settings.blind_logs
    )
    exercised = withheld_exercised(settings, case, train, holdout) if case.open_set else True
    t_rec = time.perf_counter() - t0
    library = tuple(n for n in settings.hidden_effects if n not in case.withheld)
    dset = settings.diagnosis
    dset = DiagnosisSettings(
        robot=settings.robot,
        drive=dset.drive,
        effects=library,
        features=dset.features,
        attribution=dset.attribution,
        sim=dset.sim,
    )
    d = diagnose(train, holdout, settings=dset)
    rows = d.ranking_rows()
    verdict = d.verdict.label
    open_set = case.open_set and exercised
    truth = tuple(n for n in case.truth_names if open_set or n not in case.withheld)
    named = tuple(sorted(verdict)) if isinstance(verdict, list) else None
    budget = d.budget
    entries = list(budget.entries) if budget is not None else []
    # the budget's order: its first entry, then the cumulative models it adds up to
    top = [tuple(sorted(e.effect for e in entries[: j + 1])) for j in range(len(entries))]
    first = entries[0].effect if entries else None
    unexplained_share = budget.unexplained_share if budget is not None else math.nan
    alternatives = [tuple(sorted(a)) for a in verdict_alternatives(d.verdict)]
    if open_set:
        # right: nothing named, or what is named leaves half the gap or more unexplained
        correct = verdict == VerdictKind.UNEXPLAINED or unexplained_share >= 50.0
        alias_aware = correct
    else:
        correct = named == truth
        alias_aware = truth in alternatives
    first_right = (
        (not open_set)
        and first is not None
        and (first in truth or any(a in truth for a in (entries[0].aliases if entries else ())))
    )
    param_err: dict[str, float] = {}
    values = budget.values if budget is not None else {}
    if not open_set and named == truth:
        for key, x in case.truth_values().items():
            effect, pname = split_key(key)
            if effect not in truth or key not in values:
                continue
            nominal = EFFECTS[effect]().spec(pname).nominal
            dev = abs(x - nominal)
            param_err[key] = abs(values[key] - x) / dev if dev > 0 else math.nan
    best = rows[0]
    return {
        "index": case.index,
        "truth": {n: dict(v) for n, v in case.truth},
        "truth_names": list(truth),
        "withheld": list(case.withheld),
        "withheld_exercised": exercised,
        "open_set": open_set,
        "verdict": verdict,
        "reason": d.verdict.reason,
        "confidence": d.verdict.confidence.value,
        "correct": bool(correct),
        "correct_alias_aware": bool(alias_aware),
        "verdict_alternatives": [list(a) for a in alternatives],
        "top1": (not open_set) and bool(correct),
        "top2": (not open_set) and truth in top,
        "first_entry": first,
        "first_entry_right": bool(first_right),
        "unexplained_share_pct": unexplained_share,
        "budget_kind": budget.kind if budget is not None else None,
        "best": best["name"],
        "best_params": {k: v["value"] for k, v in best["params"].items()},
        "param_rel_err": param_err,
        "heldout_shrink_pct": float(d.gap["heldout_shrink_pct"]),
        "heldout_shrink_pct_best": float(d.gap["heldout_shrink_pct_best"]),
        "ambiguous_with": list(d.verdict.ambiguous_with),
        "seconds_record": t_rec,
        "seconds_diagnose": d.timing["total"],
    }


def _case_task(settings: SuiteSettings, case: BlindCase) -> dict[str, Any]:
    return run_case(settings, case)


def run_suite(
    cases: Sequence[BlindCase],
    settings: SuiteSettings | None = None,
    backend: Backend | None = None,
    progress: Callable[[str], None] | None = None,
) -> list[dict[str, Any]]:
    """Run cases (in parallel through ``backend``) and return their outcomes in order."""
    s = settings if settings is not None else SuiteSettings()
    be = backend if backend is not None else SerialBackend()
    say = progress if progress is not None else (lambda m: None)
    say(f"{len(cases)} blind cases on the {be.name} backend")
    out = be.map(_case_task, list(cases), s)
    for r in out:
        mark = "ok " if r["correct"] else "BAD"
        held = ""
        if r["withheld"]:
            held = f" (withheld {r['withheld'][0]}" + (
                ")" if r["open_set"] else ", which never acted on these motions)"
            )
        say(
            f"case {r['index']:2d} {mark} truth={'+'.join(r['truth_names'])}{held} → {r['verdict']}"
        )
    return out


def summarise(outcomes: Sequence[dict[str, Any]]) -> tuple[dict[str, float], dict[str, Any]]:
    """The suite's figures and tables (confusion matrix, per-case rows)."""
    closed = [o for o in outcomes if not o["open_set"]]
    opened = [o for o in outcomes if o["open_set"]]
    errs = [e for o in closed for e in o["param_rel_err"].values() if math.isfinite(e)]
    false_attr = [
        o
        for o in outcomes
        if isinstance(o["verdict"], list)
        and (
            (o["open_set"] and not o["correct"])
            or (not o["open_set"] and not set(o["verdict"]) <= set(o["truth_names"]))
        )
    ]
    figures = {
        "n_cases": float(len(outcomes)),
        "top1_accuracy": float(np.mean([o["top1"] and o["correct"] for o in closed]))
        if closed
        else math.nan,
        "first_entry_accuracy": float(np.mean([o.get("first_entry_right", False) for o in closed]))
        if closed
        else math.nan,
        "open_set_right_rate": float(np.mean([o["correct"] for o in opened]))
        if opened
        else math.nan,
        "top1_alias_aware_accuracy": float(
            np.mean([o.get("correct_alias_aware", o["correct"]) for o in closed])
        )
        if closed
        else math.nan,
        "top2_accuracy": float(np.mean([o["top2"] for o in closed])) if closed else math.nan,
        "param_rel_err_median": float(np.median(errs)) if errs else math.nan,
        "heldout_shrink_pct_median": float(np.median([o["heldout_shrink_pct"] for o in closed]))
        if closed
        else math.nan,
        "open_set_unexplained_rate": float(
            np.mean([o["verdict"] == VerdictKind.UNEXPLAINED for o in opened])
        )
        if opened
        else math.nan,
        "false_attribution_rate": len(false_attr) / len(outcomes) if outcomes else math.nan,
    }

    def label_truth(o: dict[str, Any]) -> str:
        name = "+".join(o["truth_names"])
        return f"{name} (withheld {o['withheld'][0]})" if o["open_set"] else name

    def label_verdict(o: dict[str, Any]) -> str:
        v = o["verdict"]
        return "+".join(sorted(v)) if isinstance(v, list) else str(v)

    confusion: dict[str, dict[str, int]] = {}
    for o in outcomes:
        row = confusion.setdefault(label_truth(o), {})
        col = label_verdict(o)
        row[col] = row.get(col, 0) + 1
    tables = {
        "confusion": [
            {"truth": t, **{f"→ {k}": v for k, v in sorted(cols.items())}}
            for t, cols in sorted(confusion.items())
        ],
        "cases": [
            {
                "index": o["index"],
                "truth": o["truth"],
                "withheld": o["withheld"],
                "verdict": o["verdict"],
                "correct": o["correct"],
                "correct_alias_aware": o.get("correct_alias_aware", o["correct"]),
                "best": o["best"],
                "best_params": o["best_params"],
                "param_rel_err": o["param_rel_err"],
                "heldout_shrink_pct": o["heldout_shrink_pct"],
                "first_entry": o.get("first_entry"),
                "unexplained_share_pct": o.get("unexplained_share_pct"),
                "reason": o["reason"],
            }
            for o in outcomes
        ],
    }
    return figures, tables
