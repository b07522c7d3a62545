"""How the data split for the budget: folds of the training, units of the held-out data,
and the two scales a residual is read at.

Real data comes in sessions and runs, and a figure that is to hold on the next session
must be scored on data held out whole. :func:`make_folds` therefore groups the training
windows by **session** (the logs' ``meta["session"]``) when there are enough sessions, else
by **run** (log), else by contiguous **segments** of the runs; the held-out windows are
grouped the same way into units (runs, or segments of a single held-out log), over which
the budget's intervals are bootstrapped.

A residual is read at two scales:

* **windows** — every 1-s window feature (:class:`~realitygap.diagnosis.problem.problem.Layout`),
  where the dynamics show (a latency, a lag, a limit);
* **runs** — per fold unit, log, feature column and motion regime, the sum of the window
  residuals over the unit divided by the square root of their number
  (:class:`RunCells`). A window error that does not add up along a run (a clock that
  moves windows about) averages out; one that does (a wheelbase or wheel-size error) grows
  with the run, as it does in the trajectory. White noise keeps unit variance, so both
  scales are in the same units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
from scipy import sparse

from realitygap.diagnosis.problem.problem import Layout, Problem

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

__all__ = ["Folds", "RunCells", "make_folds"]

MIN_FOLDS = 16
"""The fewest folds the budget's tests run on: with fewer sessions or runs than this, the
runs are cut into contiguous segments (a paired test over 2 or 3 folds has almost no
power)."""


@dataclass(frozen=True)
class Folds:
    """The training folds and held-out units.

    Attributes
    ----------
    unit : {"session", "run", "segment"}
        What a training fold holds out.
    labels : tuple of str
        One label per fold (a session id, a run name, ``"run 3 part 2"``).
    train : ndarray of int, shape (n_train,)
        The fold of every entry of ``problem.train``.
    holdout_unit : {"run", "segment"}
        What a held-out unit is.
    holdout_labels : tuple of str
    holdout : ndarray of int, shape (n_holdout,)
        The unit of every entry of ``problem.holdout``.
    groups_unit : {"session", "run", "segment"}
        What the stability test compares: sessions when the training holds two or more
        (a constant of the robot has one value in each; a single run of a UMBmark square
        need not identify it alone), else runs, else segments.
    group_labels : tuple of str
    groups : ndarray of int, shape (n_train,)
        The stability group of every entry of ``problem.train``.
    """

    unit: str
    labels: tuple[str, ...]
    train: IntArray
    holdout_unit: str
    holdout_labels: tuple[str, ...]
    holdout: IntArray
    groups_unit: str = "segment"
    group_labels: tuple[str, ...] = ()
    groups: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    sub: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """Per training entry, its part of a stability group: its run when the groups are
    sessions, one of :data:`SUB_PARTS` contiguous segments of its run when they are runs.
    The spread of the parts' estimates within a group is that group's error."""
    sub_group: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    """The stability group of every part."""

    @property
    def k(self) -> int:
        return len(self.labels)


SUB_PARTS = 4
"""Contiguous parts of a run whose spread gives a run's error in the stability test."""


def _segments(layout: Layout, per_log: int) -> IntArray:
    """A segment index per entry: each log's windows cut into ``per_log`` contiguous parts
    (numbered log by log)."""
    out = np.zeros(layout.n, dtype=np.int64)
    base = 0
    for lg in np.unique(layout.log):
        sel = layout.log == lg
        wins = np.unique(layout.window[sel])
        parts = max(1, min(per_log, wins.size))
        edges = np.array_split(wins, parts)
        part_of = {int(w): j for j, chunk in enumerate(edges) for w in chunk}
        out[sel] = base + np.array([part_of[int(w)] for w in layout.window[sel]], dtype=np.int64)
        base += parts
    return out


def _group(
    problem: Problem, layout: Layout, min_units: int, allow_sessions: bool
) -> tuple[str, tuple[str, ...], IntArray]:
    logs = np.unique(layout.log)
    names = [problem.logs[int(i)].name for i in logs]
    if allow_sessions:
        sessions = [problem.logs[int(i)].log.meta.get("session") for i in logs]
        if all(s is not None for s in sessions) and len(set(map(str, sessions))) >= min_units:
            order = sorted(set(map(str, sessions)))
            of_log = {int(i): order.index(str(s)) for i, s in zip(logs, sessions)}
            return "session", tuple(order), np.array([of_log[int(i)] for i in layout.log])
    if logs.size >= min_units:
        of_log = {int(i): j for j, i in enumerate(logs)}
        return "run", tuple(names), np.array([of_log[int(i)] for i in layout.log])
    per_log = math.ceil(min_units / max(logs.size, 1))
    seg = _segments(layout, per_log)
    labels = []
    for lg, name in zip(logs, names):
        parts = np.unique(seg[layout.log == lg])
        labels += [f"{name} part {j + 1}" for j in range(parts.size)]
    return "segment", tuple(labels), seg


def make_folds(problem: Problem, min_folds: int = MIN_FOLDS) -> Folds:
    """The training folds (sessions, else runs, else segments: at least ``min_folds``) and
    the held-out units (runs when there are at least two, else segments)."""
    if min_folds < 2:
        raise ValueError(f"make_folds: min_folds must be at least 2, got {min_folds}")
    unit, labels, train = _group(problem, problem.train, min_folds, allow_sessions=True)
    h_unit, h_labels, holdout = _group(problem, problem.holdout, 2, allow_sessions=False)
    g_unit, g_labels, groups = _group(problem, problem.train, 2, allow_sessions=True)
    lay = problem.train
    if g_unit == "session":
        logs = np.unique(lay.log)
        sub = np.searchsorted(logs, lay.log).astype(np.int64)
    else:
        sub = _segments(lay, SUB_PARTS)
    sub_group = np.zeros(int(sub.max()) + 1 if sub.size else 0, dtype=np.int64)
    sub_group[sub] = groups
    return Folds(
        unit, labels, train, h_unit, h_labels, holdout, g_unit, g_labels, groups, sub, sub_group
    )


@dataclass(frozen=True)
class RunCells:
    """The run scale of a layout: entries summed per (unit, log, group, column, regime),
    divided by the square root of their number.

    Attributes
    ----------
    matrix : scipy.sparse.csr_matrix, shape (n, cells)
        ``z @ matrix`` gives the cell values of residuals ``z`` (..., n).
    unit : ndarray of int, shape (cells,)
        The fold (or held-out unit) of every cell.
    regime : ndarray of str, shape (cells,)
    group : ndarray of str, shape (cells,)
    """

    matrix: sparse.csr_matrix
    unit: IntArray
    regime: npt.NDArray[np.str_]
    group: npt.NDArray[np.str_]
    first: IntArray
    """An entry of each cell (all of a cell's entries share its unit, log and regime)."""

    @classmethod
    def of(cls, layout: Layout, unit: IntArray) -> RunCells:
        keys = np.stack(
            [
                unit.astype(str),
                layout.log.astype(str),
                layout.group.astype(str),
                layout.column.astype(str),
                layout.regime.astype(str),
            ],
            axis=1,
        )
        _, first, cell = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        cell = np.asarray(cell).ravel()
        count = np.bincount(cell, minlength=first.size).astype(float)
        weight = 1.0 / np.sqrt(count[cell])
        m = sparse.csr_matrix((weight, (np.arange(layout.n), cell)), shape=(layout.n, first.size))
        return cls(m, unit[first], layout.regime[first], layout.group[first], first)

    def __call__(self, z: FloatArray) -> FloatArray:
        """Cell values of residuals ``z`` (n,) or (B, n)."""
        return np.asarray(sparse.csr_matrix.transpose(self.matrix) @ np.asarray(z).T).T

    @property
    def n(self) -> int:
        return int(self.unit.shape[0])
