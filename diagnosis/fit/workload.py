"""How long the rest of a diagnosis will take, from the work measured in this run.

A diagnosis spends its time in two kinds of work: PyBullet replays (seconds per
second of log) and surrogate evaluations (seconds per *row*: one parameter set
simulated over every training log). Both rates depend on the machine and on its
load at the moment, so neither is a constant here. :class:`Workload` takes the
replay rate the nominal replays just measured and the row rate
:func:`row_seconds` measures on the problem at hand (a fraction of a second),
multiplies them by the work each stage will do — the replays and the rows it
evaluates, which depend on the algorithm, not the machine (:data:`ROWS`) — and
divides the parallel stages by the backend's workers.

As stages finish, the ratio of the time they took to the time predicted for them
corrects what is left of the same kind of work (a loaded machine, a slower parallel
speed-up, a fit that needs more steps): surrogate stages correct surrogate stages,
replay stages replay stages, so one stage that ran long for its own reasons (a choice
among many actuator conventions) does not inflate the rest.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from realitygap.diagnosis.problem.parameters import model_keys, param_spec
from realitygap.diagnosis.problem.problem import Problem

__all__ = ["ROWS", "Stage", "Workload", "row_seconds"]

ROWS = {
    "baseline": 1300.0,  # the nuisances' fit (a few parameters, several starts)
    "convention": 730.0,  # the nuisances' fit over their physical ranges, per convention
    "screen_single": 220.0,  # grid, fine scan and three refinements, nuisances held
    "screen_pair": 340.0,  # a grid over both effects, then refinements
    "budget_try": 80.0,  # a candidate tried at one step of the budget's selection
    "verify_refit": 40.0,  # the defect-corrected refit of a verified model
    "rest": 100.0,  # judgement, whole-run figures, advice and discovery
}
"""Surrogate rows each kind of work evaluates on average (counted on the 90 s benchmark log
and on the OptiOdom sessions, all effects); the rates that turn them into seconds are
measured in the run."""

LIMITS_REPLAYS = 0.1
"""Fitting one actuator convention's limits to the encoders costs about this share of a
replay of the logs (counted on the OptiOdom sessions)."""

PARALLEL_EFFICIENCY = 0.8
"""Assumed share of the ideal speed-up of a parallel stage before one has been measured."""


def row_seconds(
    problem: Problem, effects: Sequence[str], batch: int = 16, repeats: int = 2
) -> float:
    """Seconds one surrogate row takes on ``problem``'s training windows, measured now
    (the best of ``repeats`` batches of ``batch`` rows, each its own parameter set of the
    first of ``effects`` near nominal, as the fits evaluate them)."""
    best = math.inf
    keys = model_keys(tuple(effects[:1]))
    values = {
        k: param_spec(k).nominal
        + np.linspace(0.0, 1e-3, batch) * (param_spec(k).high - param_spec(k).nominal)
        for k in keys
    }
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        problem.surrogate_residuals(problem.train, values, batch)
        best = min(best, time.perf_counter() - t0)
    return best / batch


@dataclass
class Stage:
    """One stage of the plan: its kind of work (``"rows"``: surrogate evaluations,
    ``"replays"``: PyBullet, ``"mixed"``: both, corrected by its own measurement only),
    its predicted seconds and, once finished, the measured ones."""

    name: str
    predicted_s: float
    kind: str = "rows"
    measured_s: float | None = None


@dataclass
class Workload:
    """The remaining stages of a diagnosis and their predicted durations.

    Parameters
    ----------
    row_s : float
        Measured seconds per surrogate row (:func:`row_seconds`).
    replay_s : float
        Measured seconds of one PyBullet replay of all logs on one core.
    workers : int
        Parallel workers of the backend.
    """

    row_s: float
    replay_s: float
    workers: int = 1
    stages: list[Stage] = field(default_factory=list)

    @classmethod
    def plan(
        cls,
        problem: Problem,
        candidates: int,
        *,
        row_s: float,
        replay_s: float,
        workers: int,
        calibrate: bool = True,
        conventions: int = 0,
    ) -> Workload:
        """The plan of a diagnosis of ``candidates`` single effects on ``problem``, whose
        baseline chooses among ``conventions`` actuator conventions (0: none)."""
        s = problem.settings
        w = cls(row_s=row_s, replay_s=replay_s, workers=max(1, int(workers)))
        k = min(s.pair_candidates, candidates)
        pairs = max(candidates - 1, 0) + max(k - 1, 0) * max(k - 2, 0) // 2 if k else 0
        logs = len(problem.logs)
        if calibrate:
            # the nuisances' fit, and per actuator convention a fit of its limits and a
            # screening fit on the surrogate, then a replay of the one chosen
            w.add(
                "baseline",
                ROWS["baseline"] * row_s
                + conventions * ROWS["convention"] * row_s
                + w.parallel(conventions * LIMITS_REPLAYS * replay_s, conventions)
                + (w.parallel(replay_s, logs) if conventions else 0.0),
                kind="mixed",
            )
        w.add("screen singles", w.parallel(candidates * ROWS["screen_single"] * row_s, candidates))
        w.add("screen pairs", w.parallel(pairs * ROWS["screen_pair"] * row_s, pairs))
        # a verified model: its training logs replayed per defect iteration, then all logs
        train_share = sum(bool((~p.holdout_windows).any()) for p in problem.logs) / max(logs, 1)
        replays = s.verify_top * (1 + s.defect_iterations * train_share)
        w.add("verify", w.parallel(replays * replay_s, logs), kind="replays")
        # the budget's selection: every candidate tried at each of its (typically two) steps
        tries = 2 * candidates
        w.add("budget", w.parallel(tries * ROWS["budget_try"] * row_s, tries))
        w.add("rest", (ROWS["rest"] + s.verify_top * ROWS["verify_refit"]) * row_s)
        return w

    def add_reach(self, problem: Problem, candidates: int) -> None:
        """Plan the two-fold reach of ``candidates`` single effects on the held-out windows
        (:func:`~realitygap.diagnosis.stages.reach.library_reach`)."""
        share = problem.holdout.n / max(problem.train.n, 1) / 2.0
        fits = 2 * candidates
        self.add("reach", self.parallel(fits * ROWS["screen_single"] * self.row_s * share, fits))

    def parallel(self, serial_s: float, items: int) -> float:
        """``serial_s`` of ``items`` independent tasks spread over the workers."""
        if items <= 1 or self.workers == 1:
            return serial_s
        share = math.ceil(items / self.workers) / items
        return serial_s * share / PARALLEL_EFFICIENCY

    def add(self, name: str, predicted_s: float, kind: str = "rows") -> None:
        if kind not in ("rows", "replays", "mixed"):
            raise ValueError(f"Workload.add: kind must be rows, replays or mixed, got {kind!r}")
        self.stages.append(Stage(name, float(predicted_s), kind))

    def finish(self, name: str, measured_s: float) -> None:
        """Record that stage ``name`` took ``measured_s``; a stage not planned is ignored."""
        for st in self.stages:
            if st.name == name and st.measured_s is None:
                st.measured_s = float(measured_s)
                return

    def correction(self, kind: str = "rows") -> float:
        """Measured over predicted seconds of the finished stages of ``kind`` (1 before any;
        a ``"mixed"`` stage corrects nothing but itself)."""
        done = [st for st in self.stages if st.measured_s is not None and st.kind == kind]
        predicted = sum(st.predicted_s for st in done)
        if kind == "mixed" or predicted <= 0:
            return 1.0
        return sum(st.measured_s or 0.0 for st in done) / predicted

    def remaining_s(self) -> float:
        """Predicted seconds of the stages not finished, each corrected by its kind's
        :meth:`correction`."""
        return sum(
            st.predicted_s * self.correction(st.kind) for st in self.stages if st.measured_s is None
        )
