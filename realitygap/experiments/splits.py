"""Real-data diagnoses over every split that holds out whole sessions (and days):
``diagnose-real-splits`` (OptiOdom differential drive) and ``diagnose-arm-splits``
(UR10 series both ways, FR3 poses in contiguous blocks).

A real-data figure is reported as a distribution over these splits, never from one
split. The splits are enumerated from the data found (:func:`session_splits`):

* **cross-day**: for every recording day D that has UMBmark square sessions, train on
  all runs of D's square sessions and hold out runs of every session recorded on
  another day (every path type; at most ``holdout_per_session`` runs per session,
  cw and ccw alternating, as :func:`~realitygap.experiments.diagnosis._pick` picks);
* **leave-one-session-out within a day**: for every day with at least two square
  sessions and each of its square sessions S, train on the day's other square
  sessions' runs and hold out all of S's runs.

An OptiOdom session id is ``DDMMYYYYhhmm``: its recording day is the first 8 digits.
"""

from __future__ import annotations

import math
import re
import time
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from realitygap.experiments import RunContext, experiment

CROSS_DAY = "cross-day"
LEAVE_ONE_SESSION_OUT = "leave-one-session-out"
SQUARE = "square"
_BUDGET_GAP_KEYS = (
    "heldout_trajectory_gap_m_nominal",
    "heldout_trajectory_gap_m_baseline",
    "heldout_trajectory_gap_m_best",
    "heldout_trajectory_shrink_pct_best",
)
"""The diagnosis's whole-run gap figures a split's row reads."""
_SESSION_ID = re.compile(r"^(\d{2})(\d{2})(\d{4})(\d{4})$")


# --------------------------------------------------------------------------- enumeration
def session_day(session: str) -> str:
    """The recording day ``DDMMYYYY`` of an OptiOdom session id ``DDMMYYYYhhmm``
    (``ValueError`` naming the id when it is not of that form)."""
    m = _SESSION_ID.match(str(session))
    if m is None:
        raise ValueError(
            f"session id {session!r} is not of the form DDMMYYYYhhmm (12 digits), so its "
            "recording day is unknown"
        )
    dd, mm = int(m.group(1)), int(m.group(2))
    if not (1 <= dd <= 31 and 1 <= mm <= 12):
        raise ValueError(f"session id {session!r}: day {dd} / month {mm} is not a date")
    return str(session)[:8]


def day_label(day: str) -> str:
    """``DDMMYYYY`` → ``DD.MM.YYYY``."""
    return f"{day[:2]}.{day[2:4]}.{day[4:8]}"


def _day_order(day: str) -> tuple[int, int, int]:
    """Chronological sort key of a ``DDMMYYYY`` day."""
    return int(day[4:8]), int(day[2:4]), int(day[:2])


@dataclass(frozen=True)
class SessionSplit:
    """One split: training and held-out runs (logs with ``meta["session"]``)."""

    name: str
    kind: str
    """:data:`CROSS_DAY` or :data:`LEAVE_ONE_SESSION_OUT`."""
    day: str
    """The training day, ``DDMMYYYY``."""
    train: tuple[Any, ...]
    holdout: tuple[Any, ...]

    @property
    def train_sessions(self) -> tuple[str, ...]:
        return tuple(sorted({str(lg.meta["session"]) for lg in self.train}))

    @property
    def holdout_sessions(self) -> tuple[str, ...]:
        return tuple(sorted({str(lg.meta["session"]) for lg in self.holdout}))

    def describe(self) -> dict[str, Any]:
        """The split as a JSON-ready row (no logs)."""
        return {
            "split": self.name,
            "kind": self.kind,
            "train_day": day_label(self.day),
            "n_train": len(self.train),
            "n_holdout": len(self.holdout),
            "train_sessions": list(self.train_sessions),
            "holdout_sessions": list(self.holdout_sessions),
            "holdout_path_types": dict(
                sorted(Counter(str(lg.meta.get("path_type")) for lg in self.holdout).items())
            ),
        }


def _run_order(lg: Any) -> tuple[str, int]:
    return str(lg.meta["session"]), int(lg.meta.get("run", 0))


def session_splits(logs: Iterable[Any], holdout_per_session: int = 2) -> list[SessionSplit]:
    """Every cross-day and leave-one-session-out split of ``logs`` (module docstring).

    ``logs`` carry ``meta["session"]`` (``DDMMYYYYhhmm``), ``meta["path_type"]``
    (``"square"`` for UMBmark squares), ``meta["run"]`` and ``meta["direction"]``.
    Deterministic: days in calendar order, cross-day splits first, then each day's
    leave-one-session-out splits in session order; runs in (session, run) order.
    Splits with no training or no held-out run are not made.
    """
    from realitygap.experiments.diagnosis import _pick

    logs = sorted(logs, key=_run_order)
    by_day: dict[str, list[Any]] = {}
    for lg in logs:
        by_day.setdefault(session_day(str(lg.meta["session"])), []).append(lg)
    days = sorted(by_day, key=_day_order)
    squares = {
        day: [lg for lg in by_day[day] if str(lg.meta.get("path_type")) == SQUARE] for day in days
    }
    out: list[SessionSplit] = []
    for day in days:
        train = squares[day]
        if not train:
            continue
        others = [lg for d in days if d != day for lg in by_day[d]]
        holdout = _pick(others, per_session=holdout_per_session, max_sessions=None)
        if holdout:
            out.append(
                SessionSplit(
                    f"{CROSS_DAY} {day_label(day)}→others",
                    CROSS_DAY,
                    day,
                    tuple(train),
                    tuple(sorted(holdout, key=_run_order)),
                )
            )
    for day in days:
        sessions = sorted({str(lg.meta["session"]) for lg in squares[day]})
        if len(sessions) < 2:
            continue
        for s in sessions:
            train = [lg for lg in squares[day] if str(lg.meta["session"]) != s]
            holdout = [lg for lg in squares[day] if str(lg.meta["session"]) == s]
            out.append(
                SessionSplit(
                    f"day {day_label(day)} without {s}",
                    LEAVE_ONE_SESSION_OUT,
                    day,
                    tuple(train),
                    tuple(holdout),
                )
            )
    return out


def spread_subset(splits: Sequence[SessionSplit], n: int) -> list[SessionSplit]:
    """At most ``n`` of ``splits``, taken in turn from each kind (first of each kind, then
    the second, …), kept in enumeration order: a quick run sees both kinds."""
    kinds: dict[str, list[int]] = {}
    for i, sp in enumerate(splits):
        kinds.setdefault(sp.kind, []).append(i)
    chosen: list[int] = []
    depth = 0
    while len(chosen) < min(n, len(splits)):
        for idx in kinds.values():
            if depth < len(idx) and len(chosen) < n:
                chosen.append(idx[depth])
        depth += 1
    return [splits[i] for i in sorted(chosen)]


# --------------------------------------------------------------------------- helpers
def _finite(values: Iterable[Any]) -> list[float]:
    out = []
    for v in values:
        try:
            x = float(v)
        except (TypeError, ValueError):
            continue
        if math.isfinite(x):
            out.append(x)
    return out


def _spread(figures: dict[str, Any], key: str, values: Sequence[Any]) -> int:
    """``key_median``, ``key_min``, ``key_max`` over the finite ``values`` (NaN when none);
    returns how many were finite."""
    xs = _finite(values)
    figures[key + "_median"] = float(np.median(xs)) if xs else math.nan
    figures[key + "_min"] = min(xs) if xs else math.nan
    figures[key + "_max"] = max(xs) if xs else math.nan
    return len(xs)


def _budget_rows(budget: Any) -> list[dict[str, Any]]:
    """The budget's entries, compact: effect, parameter values, shares and intervals."""
    rows = []
    for e in budget.entries:
        row: dict[str, Any] = {
            "effect": e.effect,
            "scale": e.scale,
            "named": e.constant,
            "parameters": {k: float(v) for k, v in e.values.items()},
            "stderr": {k: float(v) for k, v in e.stderr.items()},
            "aliases": list(e.aliases),
        }
        for s in budget.scales:
            row[f"share_{s}_pct"] = float(e.share.get(s, math.nan))
            row[f"interval_{s}_pct"] = [float(x) for x in budget.interval_of(e, s)]
        rows.append(row)
    return rows


def _budget_summary(budget: Any) -> dict[str, Any]:
    """Kind, named effects, unexplained share and remainder of a budget (``None``: absent)."""
    if budget is None:
        return {"budget_kind": None, "budget_named": [], "budget_entries": []}
    out: dict[str, Any] = {
        "budget_kind": budget.kind,
        "budget_named": list(budget.named),
        "budget_unexplained_share_pct": float(budget.unexplained_share),
        "budget_entries": _budget_rows(budget),
    }
    for s, r in budget.remainder.items():
        out[f"budget_remaining_{s}_pct"] = float(r["remaining_pct"])
        out[f"budget_structured_{s}_pct"] = float(r["structured_pct"])
    return out


def budget_wheelbase_factor(budget: Any) -> float:
    """The budget's wheelbase factor as UMBmark observes it: the wheelbase over the mean
    wheel diameter (the distance per count), relative to nominal —
    ``wheelbase_error.E_b · encoder_scale.scale / wheel_radius_scale.scale``, each factor 1
    when the budget does not hold it (a budget that scales the wheels instead of the
    wheelbase still states the ratio UMBmark measures); NaN when the budget holds none of
    them."""
    if budget is None:
        return math.nan
    values: dict[str, float] = {}
    for e in budget.entries:
        values.update({k: float(v) for k, v in e.values.items()})
    keys = ("wheelbase_error.E_b", "wheel_radius_scale.scale", "encoder_scale.scale")
    if not any(k in values for k in keys):
        return math.nan
    return (
        values.get("wheelbase_error.E_b", 1.0)
        * values.get("encoder_scale.scale", 1.0)
        / values.get("wheel_radius_scale.scale", 1.0)
    )


# --------------------------------------------------------------------------- diffdrive
def _diagnose_diffdrive_split(
    ctx: RunContext,
    split: SessionSplit,
    drive: str,
    backend: Any,
    umbmark_cache: dict[tuple[str, ...], dict[str, float]],
) -> dict[str, Any] | None:
    """One split & drive: the diagnosis's budget and trajectory gaps, UMBmark on the same
    training square runs and on the same held-out runs; a table row (``None``: no runs)."""
    from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
    from realitygap.experiments.diagnosis import (
        _log_geometry,
        _umbmark_heldout,
        _umbmark_on_logs,
        _verdict_figure,
    )

    tr = [lg for lg in split.train if drive == "ticks" or lg.has("cmd")]
    ho = [lg for lg in split.holdout if drive == "ticks" or lg.has("cmd")]
    if not tr or not ho:
        return None
    t0 = time.perf_counter()
    d = diagnose(
        tr,
        ho,
        settings=DiagnosisSettings(robot="diffdrive", drive=drive),
        backend=backend,
        progress=ctx.progress,
    )
    ctx.add_diagnosis(f"{split.name} ({drive})", d)
    g = d.gap
    row: dict[str, Any] = {**split.describe(), "drive": drive, "n_train": len(tr)}
    row["n_holdout"] = len(ho)
    row.update(_budget_summary(d.budget))
    row["verdict"] = _verdict_figure(d)
    nominal = g.get("heldout_trajectory_gap_m_nominal", math.nan)
    # the gap report's "best" replay is the budget's model
    for name, key in (("nominal", "nominal"), ("baseline", "baseline"), ("budget", "best")):
        row[f"heldout_gap_cm_{name}"] = 100.0 * g.get(f"heldout_trajectory_gap_m_{key}", math.nan)
    row["budget_trajectory_shrink_pct"] = g.get("heldout_trajectory_shrink_pct_best", math.nan)
    row["gap_keys_missing"] = [k for k in _BUDGET_GAP_KEYS if k not in g]
    e_b = budget_wheelbase_factor(d.budget)
    row["wheelbase_in_budget"] = math.isfinite(e_b)
    row["budget_E_b"] = e_b
    # UMBmark on exactly the training square runs (reference: as diagnose-real takes it)
    key = tuple(lg.name for lg in tr)
    if key not in umbmark_cache:
        ref = (d.nominal_reference or {}).get("reference") or _log_geometry(tr[0])
        umbmark_cache[key] = _umbmark_on_logs(tr, ref)
    umb = umbmark_cache[key]
    for k, v in umb.items():
        row[k] = v
    row["umbmark_trajectory_shrink_pct"] = math.nan
    if {"umbmark_same_runs_E_b", "umbmark_same_runs_E_d"} <= set(umb) and math.isfinite(nominal):
        ctx.progress(f"{split.name} ({drive}): replaying the held-out runs with UMBmark's factors")
        row.update(_umbmark_heldout(d, umb["umbmark_same_runs_E_b"], umb["umbmark_same_runs_E_d"]))
    row["tool_minus_umbmark_shrink_points"] = (
        row["budget_trajectory_shrink_pct"] - row["umbmark_trajectory_shrink_pct"]
    )
    row["E_b_minus_umbmark"] = e_b - umb.get("umbmark_same_runs_E_b", math.nan)
    row["diagnose_seconds"] = float(d.timing.get("total", math.nan))
    row["seconds"] = time.perf_counter() - t0
    row["_budget_json"] = d.budget.to_json() if d.budget is not None else None
    return row


@experiment(
    "diagnose-real-splits",
    "OptiOdom robot: the diagnosis and UMBmark over every split holding out whole sessions "
    "and days (cross-day, leave-one-session-out), as distributions",
    data_subdir="optiodom_diffdrive",
)
def diagnose_real_splits(ctx: RunContext) -> dict[str, Any]:
    """Every cross-day and within-day leave-one-session-out split of the OptiOdom sessions
    (:func:`session_splits`), each diagnosed with the tick- and the command-driven replay
    (``--quick``: ticks only, at most 3 splits of both kinds); per split the gap budget, the
    whole-run trajectory gaps and UMBmark on the same runs, and their spread over splits."""
    from realitygap.core.parallel import ProcessBackend
    from realitygap.experiments.diagnosis import _optiodom_groups

    groups = _optiodom_groups(ctx)
    if SQUARE not in groups:
        raise FileNotFoundError(
            "diagnose-real-splits trains on the UMBmark square runs: no session under "
            "'<data>/optiodom_diffdrive/square/' was found"
        )
    logs = [lg for runs in groups.values() for lg in runs]
    every = session_splits(logs)
    if not every:
        raise FileNotFoundError(
            "diagnose-real-splits found no split: it needs square sessions and sessions of "
            "another day, or two square sessions of one day"
        )
    splits = spread_subset(every, 3) if ctx.quick else every
    drives = ("ticks",) if ctx.quick else ("ticks", "commands")
    ctx.progress(
        f"{len(every)} splits found ({', '.join(sp.name for sp in every)}); diagnosing "
        f"{len(splits)} with the {' and '.join(drives)} replay"
    )
    backend = ProcessBackend(ctx.options.get("workers"))
    rows: list[dict[str, Any]] = []
    budgets: list[dict[str, Any]] = []
    notes: list[str] = []
    umbmark_cache: dict[tuple[str, ...], dict[str, float]] = {}
    n_jobs = len(splits) * len(drives)
    job = 0
    for i, sp in enumerate(splits, 1):
        for drive in drives:
            job += 1
            ctx.progress(
                f"split {i} of {len(splits)} ({job}/{n_jobs} diagnoses): {sp.name}, {drive}: "
                f"{len(sp.train)} training runs ({', '.join(sp.train_sessions)}), "
                f"{len(sp.holdout)} held-out runs of {len(sp.holdout_sessions)} session(s)"
            )
            t0 = time.perf_counter()
            row = _diagnose_diffdrive_split(ctx, sp, drive, backend, umbmark_cache)
            if row is None:
                notes.append(f"{sp.name}, {drive}: no runs with this drive's channels; skipped")
                continue
            budgets.append({"split": sp.name, "drive": drive, "budget": row.pop("_budget_json")})
            rows.append(row)
            ctx.progress(
                f"split {i} of {len(splits)}: {sp.name}, {drive}: done in "
                f"{time.perf_counter() - t0:.0f} s: budget {row['budget_kind']} "
                f"({'+'.join(row['budget_named']) or 'nothing named'}), trajectory shrink "
                f"{row['budget_trajectory_shrink_pct']:.1f} % vs UMBmark "
                f"{row['umbmark_trajectory_shrink_pct']:.1f} %"
            )
    figures: dict[str, Any] = {
        "n_splits": float(len(splits)),
        "n_splits_found": float(len(every)),
        "n_splits_cross_day": float(sum(sp.kind == CROSS_DAY for sp in splits)),
        "n_splits_leave_one_session_out": float(
            sum(sp.kind == LEAVE_ONE_SESSION_OUT for sp in splits)
        ),
    }
    for drive in drives:
        mine = [r for r in rows if r["drive"] == drive]
        p = f"{drive}_"
        figures[p + "splits"] = float(len(mine))
        for key in (
            "budget_trajectory_shrink_pct",
            "umbmark_trajectory_shrink_pct",
            "tool_minus_umbmark_shrink_points",
        ):
            n_ok = _spread(figures, p + key, [r[key] for r in mine])
            if n_ok < len(mine):
                notes.append(
                    f"{drive}: {key} is not a number on {len(mine) - n_ok} of {len(mine)} "
                    "splits; the median/min/max are over the others"
                )
        diffs = _finite(abs(r["E_b_minus_umbmark"]) for r in mine)
        figures[p + "E_b_minus_umbmark_abs_max"] = max(diffs) if diffs else math.nan
        figures[p + "splits_with_wheelbase_error"] = float(
            sum(bool(r["wheelbase_in_budget"]) for r in mine)
        )
        kinds = Counter(str(r["budget_kind"]) for r in mine)
        figures[p + "budget_kinds"] = ", ".join(f"{k}: {n}" for k, n in sorted(kinds.items()))
    missing = sorted({k for r in rows for k in r["gap_keys_missing"]})
    if missing:
        notes.append(
            f"the diagnosis's gap lacks {', '.join(missing)} on some splits: the figures "
            "made from them are NaN there"
        )
    notes += [
        "splits: cross-day = train on all runs of one day's square sessions, hold out at most "
        "2 runs (cw/ccw alternating) of every session of the other days; leave-one-session-out "
        "= within a day with >= 2 square sessions, train on the others, hold out all runs of one",
        "budget_trajectory_shrink_pct: the budget's model replayed in PyBullet on the held-out "
        "runs, 1 - gap/nominal (the diagnosis's heldout_trajectory_shrink_pct_best: the budget's model); "
        "umbmark_trajectory_shrink_pct: the same held-out runs replayed with UMBmark's same-run "
        "E_b and E_d on the same calibrated baseline; tool_minus_umbmark_shrink_points = the "
        "difference, percentage points",
        "budget_E_b: wheelbase_error.E_b of the budget entries over wheel_radius_scale.scale "
        "when that is an entry (UMBmark's b / D̄ factor); E_b_minus_umbmark = budget_E_b - "
        "UMBmark's same-run E_b on exactly the training square runs",
    ]
    if ctx.quick:
        notes.append(
            f"--quick: ticks only and {len(splits)} of the {len(every)} splits (first of each "
            "kind in turn); figures over these only"
        )
    return {
        "figures": figures,
        "tables": {
            "splits": [sp.describe() for sp in every],
            "rows": rows,
            "budgets": budgets,
        },
        "notes": notes,
        "config": {
            "drives": list(drives),
            "splits": [sp.name for sp in splits],
            "holdout_per_session_cross_day": 2,
        },
    }


# --------------------------------------------------------------------------- arms
def _fr3_block_splits(ctx: RunContext, k: int) -> tuple[list[dict[str, Any]], list[str]]:
    """FR3 eye-in-hand poses held out in ``k`` contiguous blocks, each calibrated on the rest
    with ``arm-real``'s MDH calibration (:func:`~realitygap.estimators.arm.calibration.calibrate_fr3`)."""
    from pathlib import Path

    from realitygap.diagnosis.logs.importers.franka import read_franka_npz
    from realitygap.estimators.arm.calibration import calibrate_fr3

    notes: list[str] = []
    try:
        root = ctx.data_subdir("franka_fr3_eyeinhand")
    except FileNotFoundError as exc:
        return [], [f"FR3 skipped: {exc}"]
    files = sorted(Path(root).glob("*.npz"))
    if not files:
        return [], [f"FR3 skipped: no *.npz eye-in-hand file under {root}"]
    rows: list[dict[str, Any]] = []
    for f in files:
        data = read_franka_npz(f)
        idx = np.arange(data.n)
        if data.n < 4 * k:
            notes.append(f"FR3 {f.name}: {data.n} poses are too few for {k} blocks; skipped")
            continue
        for j, block in enumerate(np.array_split(idx, k), 1):
            t0 = time.perf_counter()
            name = f"{f.stem} block {j}/{k} (poses {block[0]}–{block[-1]})"
            ctx.progress(f"FR3 split {j} of {k}: {name}")
            rep = calibrate_fr3(data, np.setdiff1d(idx, block), block)
            nom, cal = rep.nominal.rms, rep.calibrated.rms
            rows.append(
                {
                    "split": name,
                    "n_train": rep.n_train,
                    "n_holdout": rep.n_test,
                    "heldout_dist_err_mm_nominal": 1e3 * nom,
                    "heldout_dist_err_mm_calibrated": 1e3 * cal,
                    "heldout_shrink_pct": 100.0 * (1.0 - cal / nom) if nom > 0 else math.nan,
                    "seconds": time.perf_counter() - t0,
                }
            )
    notes.append(
        "FR3: no diagnosis log reader exists for the eye-in-hand poses, so its splits reuse "
        "arm-real's MDH calibration (calibrate_fr3): held-out shrink = 1 - calibrated/nominal "
        "RMS distance-accuracy error over pairs of held-out poses; no gap budget"
    )
    return rows, notes


@experiment(
    "diagnose-arm-splits",
    "UR10 series each way and FR3 poses in contiguous blocks: gap budgets and held-out "
    "shrink over every split, as distributions",
    data_subdir="ipa_ur10_lasertracker",
)
def diagnose_arm_splits(ctx: RunContext) -> dict[str, Any]:
    """Each UR10 series held out in turn with the others training (two series: A→B and
    B→A), as ``diagnose-arm-real`` does; per split the gap budget (kind, named effects with
    parameters, shares with intervals, unexplained share) and the held-out shrink. The FR3
    poses held out in ``k`` = 4 contiguous blocks (:func:`_fr3_block_splits`)."""
    from realitygap.core.parallel import ProcessBackend
    from realitygap.diagnosis.adapters.arm.adapter import ArmAdapter
    from realitygap.diagnosis.adapters.registry import ADAPTERS
    from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
    from realitygap.diagnosis.logs.read import logs_from_ur10
    from realitygap.experiments.diagnosis import _verdict_figure

    logs = logs_from_ur10(ctx.data_subdir("ipa_ur10_lasertracker"))
    if len(logs) < 2:
        raise FileNotFoundError(
            "diagnose-arm-splits needs two measurement series (one to train on, one held out); "
            f"found {len(logs)}"
        )
    max_windows = 200 if ctx.quick else 600
    ADAPTERS["arm"] = ArmAdapter(max_windows=max_windows)
    backend = ProcessBackend(ctx.options.get("workers"))
    scale = 1e-4  # tool_dist feature scale, m (as diagnose-arm-real)
    rows: list[dict[str, Any]] = []
    budgets: list[dict[str, Any]] = []
    notes: list[str] = []
    try:
        for i, held in enumerate(logs, 1):
            train = [lg for lg in logs if lg is not held]
            name = f"{'+'.join(lg.name for lg in train)} → {held.name}"
            ctx.progress(f"UR10 split {i} of {len(logs)}: {name}")
            t0 = time.perf_counter()
            d = diagnose(
                train,
                [held],
                settings=DiagnosisSettings(robot="arm"),
                backend=backend,
                progress=ctx.progress,
            )
            ctx.add_diagnosis(name, d)
            g = d.gap
            row: dict[str, Any] = {
                "split": name,
                "train": [lg.name for lg in train],
                "holdout": held.name,
                **_budget_summary(d.budget),
                "verdict": _verdict_figure(d),
                "heldout_shrink_pct_best": g.get("heldout_shrink_pct_best", math.nan),
                "heldout_shrink_pct_budget": (
                    100.0 - d.budget.remainder["window"]["remaining_pct"]
                    if d.budget is not None and "window" in d.budget.remainder
                    else math.nan
                ),
                "heldout_dist_err_mm_nominal": 1e3 * scale * g.get("heldout_rms_nominal", math.nan),
                "heldout_dist_err_mm_best": 1e3 * scale * g.get("heldout_rms_best", math.nan),
                "diagnose_seconds": float(d.timing.get("total", math.nan)),
                "seconds": time.perf_counter() - t0,
            }
            budgets.append(
                {"split": name, "budget": d.budget.to_json() if d.budget is not None else None}
            )
            rows.append(row)
            ctx.progress(
                f"UR10 split {i} of {len(logs)}: {name}: done in {row['seconds']:.0f} s: budget "
                f"{row['budget_kind']} ({'+'.join(row['budget_named']) or 'nothing named'}), "
                f"held-out shrink {row['heldout_shrink_pct_budget']:.1f} % (budget), "
                f"{row['heldout_shrink_pct_best']:.1f} % (best-ranked model)"
            )
    finally:
        ADAPTERS.pop("arm", None)
    fr3_rows, fr3_notes = _fr3_block_splits(ctx, k=4)
    notes += fr3_notes
    figures: dict[str, Any] = {"ur10_splits": float(len(rows))}
    _spread(
        figures, "ur10_heldout_shrink_pct_budget", [r["heldout_shrink_pct_budget"] for r in rows]
    )
    _spread(figures, "ur10_heldout_shrink_pct_best", [r["heldout_shrink_pct_best"] for r in rows])
    _spread(
        figures,
        "ur10_budget_unexplained_share_pct",
        [r.get("budget_unexplained_share_pct", math.nan) for r in rows],
    )
    kinds = Counter(str(r["budget_kind"]) for r in rows)
    figures["ur10_budget_kinds"] = ", ".join(f"{k}: {n}" for k, n in sorted(kinds.items()))
    named = Counter(e for r in rows for e in r["budget_named"])
    figures["ur10_named_effects"] = ", ".join(
        f"{e}: {n}/{len(rows)}" for e, n in sorted(named.items())
    )
    if fr3_rows:
        figures["fr3_splits"] = float(len(fr3_rows))
        _spread(figures, "fr3_heldout_shrink_pct", [r["heldout_shrink_pct"] for r in fr3_rows])
        _spread(
            figures,
            "fr3_heldout_dist_err_mm_calibrated",
            [r["heldout_dist_err_mm_calibrated"] for r in fr3_rows],
        )
    notes += [
        "UR10: each series held out in turn, the others training (diagnose-arm-real's two "
        "directions); heldout_shrink_pct_budget = 100 - the budget's remaining window share; "
        "heldout_shrink_pct_best: the best-ranked model's window shrink",
        "distance error: RMS over held-out windows of the six tool-point distances between four "
        "poses a quarter of the series apart (registration-free)",
    ]
    return {
        "figures": figures,
        "tables": {"ur10": rows, "ur10_budgets": budgets, "fr3": fr3_rows},
        "notes": notes,
        "config": {
            "series": [lg.name for lg in logs],
            "max_windows": max_windows,
            "fr3_blocks": 4,
        },
    }
