"""``diagnose-independent``: the diagnosis on worlds written by an independent simulator.

For each case of :mod:`realitygap.independent.cases` the independent simulator
(:mod:`realitygap.independent`) writes training and held-out sessions in the
recorded-data formats (OptiOdom folders for the differential drive, UR10
laser-tracker series for the arm) into a temporary folder; they are read back
with the package's importers (:func:`~realitygap.diagnosis.logs.read.read_logs`) and
diagnosed as ``realitygap diagnose`` does, without the truth.

Scoring
-------
top-1 (in-library cases)
    The verdict names effects, every named effect is one the case accepts
    (:attr:`~realitygap.independent.cases.Case.accepted`), and the gap budget's first
    entry is one of them. A verdict that adds an effect the case does not accept is wrong.
open set (out-of-library cases)
    *strict*: the verdict is ``"unexplained"``, or the budget leaves a structured
    unexplained share of at least 50 % of the held-out gap; *lenient*: that, or effects
    named with ``"weak"`` confidence (the tool does not vouch for them).
false attribution
    The verdict names an effect the case does not accept (out-of-library cases: any named
    effect with an unexplained share under 50 %), over every scored diagnosis.
top-1, alias-aware (in-library cases)
    As strict top-1, or the verdict is "X or Y (aliases on this data)" and one
    of its alternatives names only accepted effects
    (:func:`~realitygap.diagnosis.verdict.notes.verdict_alternatives`); a separate
    column, so that an alias verdict is never counted as a strict hit.
held-out shrink
    ``gap["heldout_shrink_pct_best"]`` of the diagnosis, median over in-library cases.

In a tick-driven replay the accepted set adds the case's exact equivalents
(:attr:`~realitygap.independent.cases.Case.ticks_aliases`). A verdict ``"none"``
(no significant gap) is neither correct for an in-library case nor an
"unexplained" for an out-of-library one.

A differential-drive case is diagnosed once per replay drive in which its effect
shows (:attr:`~realitygap.independent.cases.Case.drives`): ``commands`` (the logged
requests drive the nominal robot, so the independent firmware ramp and motor
response are part of what the diagnosis sees) and ``ticks`` (the logged wheel
rotation drives it). Figures are given overall (every scored diagnosis counts
once) and per group: ``diffdrive_commands_``, ``diffdrive_ticks_``, ``arm_``.

Training data: two UMBmark squares (cw, ccw) for the drive, 90 random poses for
the arm; held out: a circle and a free path, and a 90-pose grid series.

Variants
--------
``--variant NAME`` (default ``default``) writes every case on one named robot and
set of conventions of :mod:`realitygap.independent.variants` — another robot's
size, encoder, control cycle, firmware ramp, motion-capture rate, latency and
noise; another tracker pose, noise and probe — with the square and circle sized
to that robot and the cases' speed values scaled to its cruise
(:func:`~realitygap.independent.variants.hidden_values`). The variant is in the
result's ``config`` and in every row of the ``cases`` table.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from realitygap.experiments import RunContext, experiment
from realitygap.independent.variants import VARIANTS

__all__ = ["diagnose_case", "generate_case", "score"]


def generate_case(
    case: Any, folder: Path, seed: int, variant: str = "default"
) -> tuple[list[Path], list[Path]]:
    """Write the training and held-out data of ``case`` on ``variant`` below ``folder``;
    return their paths."""
    from realitygap.independent import diffdrive as dd
    from realitygap.independent import ur10
    from realitygap.independent.variants import hidden_values, variant_by_name

    world = variant_by_name(variant)
    rng = np.random.default_rng(seed)
    values = hidden_values(case.values, world)
    if case.robot == "diffdrive":
        robot = world.drive
        hidden = dd.Hidden(**values)
        side = world.square_side
        plans = [
            ("square", [dd.square_path(robot, side, "cw"), dd.square_path(robot, side, "ccw")]),
            ("circular", [dd.circle_path(robot, world.circle_radius, "ccw")]),
            ("free", [dd.free_path(robot, rng, 8)]),
        ]
        clock = 0.0
        paths: dict[str, Path] = {}
        for k, (kind, segs) in enumerate(plans):
            runs = []
            for seg in segs:
                run = dd.simulate_run(
                    seg, robot, hidden, rng, session_t0=clock, session_length=400.0
                )
                clock += float(run.time[-1]) + 10.0
                runs.append(run)
            sid = f"0103202409{10 + k:02d}"
            paths[kind] = dd.write_session(
                folder, sid, runs, robot, kind, side=side if kind == "square" else None, rng=rng
            )
        return [paths["square"]], [paths["circular"], paths["free"]]
    if case.robot == "arm":
        hidden_arm = ur10.ArmHidden(**values)
        tr = world.tracker
        probe = world.probe
        q_a = ur10.random_poses(90, rng)
        q_b = ur10.grid_poses(90, rng)
        s_a = ur10.measure_series(q_a, hidden_arm, tr, rng, probe=probe)
        tr_b = replace(tr, temperature_start=tr.temperature_start + tr.temperature_rise)
        s_b = ur10.measure_series(q_b, hidden_arm, tr_b, rng, probe=probe)
        a = ur10.write_series(folder, "A", s_a, file_stem="random", probe=probe)
        b = ur10.write_series(folder, "B", s_b, file_stem="grid", start_hour=14, probe=probe)
        return [a], [b]
    raise ValueError(f"case {case.name}: robot must be 'diffdrive' or 'arm', got {case.robot!r}")


def diagnose_case(
    case: Any,
    seed: int,
    backend: Any,
    progress: Any = None,
    drives: tuple[str, ...] | None = None,
    variant: str = "default",
    keep_miss: Callable[[str, Any], None] | None = None,
) -> list[dict[str, Any]]:
    """Generate on ``variant``, read back, diagnose and score one case: one row per replay drive.

    ``drives`` defaults to the case's own (:attr:`~realitygap.independent.cases.Case.drives`);
    ``keep_miss(label, diagnosis)`` receives each diagnosis scored wrong (an in-library case
    not named, an out-of-library case not called unexplained).
    """
    from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose

    drives = case.drives if drives is None else drives
    rows = []
    t0 = time.perf_counter()
    refused: list[str] = []
    with tempfile.TemporaryDirectory(prefix="rg-indep-") as tmp:
        train_p, hold_p = generate_case(case, Path(tmp), seed, variant)
        t_gen = time.perf_counter() - t0
        train = [lg for p in train_p for lg in _read(p, refused)]
        hold = [lg for p in hold_p for lg in _read(p, refused)]
        for drive in drives:
            t1 = time.perf_counter()
            d = diagnose(
                train,
                hold,
                settings=DiagnosisSettings(robot=case.robot, drive=drive),
                backend=backend,
                progress=progress,
            )
            row = score(
                case, d, drive=drive, seconds=time.perf_counter() - t1, seconds_generate=t_gen
            )
            row["plausibility_refused"] = [m.replace(str(tmp), "<data>") for m in refused]
            row["runners_up"] = [
                {"model": "+".join(m.effects), "params": {k: float(x) for k, x in m.values.items()}}
                for m in d.ranking[1:3]
            ]
            row["verdict_notes"] = {
                k: x
                for k, x in d.verdict.notes.to_json().items()
                if isinstance(x, (str, int, float))
            }
            if keep_miss is not None and _missed(row):
                keep_miss(f"{case.name} ({drive}, {variant})", d)
            rows.append(
                {
                    "drive": drive if case.robot == "diffdrive" else "joints",
                    "variant": variant,
                    **row,
                }
            )
    return rows


def _missed(row: dict[str, Any]) -> bool:
    """True when a scored row is wrong: not named (in library) or not unexplained (outside)."""
    if row["in_library"]:
        return not row["correct"]
    return not row["open_set_strict"]


def _read(path: Path, refused: list[str]) -> list[Any]:
    """The logs of ``path``, read as ``realitygap diagnose`` reads them.

    The importer's plausibility check (:func:`~realitygap.diagnosis.logs.read.check_plausible`) is
    run on each log; a log it refuses is kept (the files are written in their declared
    units) and the refusal is appended to ``refused`` — what a user would read before
    passing ``--no-plausibility-check``.
    """
    from realitygap.diagnosis.logs.log import LogError
    from realitygap.diagnosis.logs.read import ReadOptions, check_plausible, read_logs

    logs = read_logs(path, ReadOptions(check_plausible=False))
    for lg in logs:
        try:
            check_plausible(lg)
        except LogError as exc:
            refused.append(str(exc))
    return logs


def score(case: Any, d: Any, drive: str = "commands", **extra: float) -> dict[str, Any]:
    """Score a diagnosis ``d`` of ``case`` replayed with ``drive`` (see the module notes)."""
    from realitygap.diagnosis.verdict.notes import verdict_alternatives
    from realitygap.diagnosis.verdict.types import Confidence, VerdictKind

    v = d.verdict
    budget = d.budget
    named = list(v.effects) if v.kind in (VerdictKind.EFFECTS, VerdictKind.PARTIAL) else []
    # the budget's first entry is its answer's head
    top = [budget.entries[0].effect] if budget is not None and budget.entries else []
    share = budget.unexplained_share if budget is not None else math.nan
    accepted = set(case.accepted_for(drive))
    alternatives = verdict_alternatives(v)
    if case.in_library:
        correct = bool(named) and set(named) <= accepted and bool(set(top) & accepted)
        alias_aware = correct or any(set(a) <= accepted for a in alternatives)
        strict = lenient = math.nan
    else:
        correct = alias_aware = False
        strict = float(v.kind is VerdictKind.UNEXPLAINED or share >= 50.0)
        lenient = float(bool(strict) or v.confidence is Confidence.WEAK)
    # the budget's model when it names effects, else the ranking's first candidate
    top_values = (
        dict(budget.values)
        if budget is not None and budget.entries
        else (dict(d.ranking[0].values) if d.ranking else {})
    )
    reach = v.notes.reach or {}
    reach_top = reach.get("rows", [{}])[0] if reach.get("rows") else {}
    return {
        "case": case.name,
        "robot": case.robot,
        "in_library": case.in_library,
        "accepted": sorted(accepted),
        "verdict": v.label,
        "confidence": v.confidence.value,
        "top_model": "+".join(top),
        "top_params": {k: float(v) for k, v in top_values.items()},
        "correct": correct,
        "correct_alias_aware": bool(alias_aware),
        "verdict_alternatives": [list(a) for a in alternatives],
        "open_set_strict": strict,
        "open_set_lenient": lenient,
        # an out-of-library case whose named effects leave half the gap or more is seen
        "false_attribution": bool(named)
        and not set(named) <= accepted
        and not (not case.in_library and strict == 1.0),
        "unexplained_share_pct": share,
        "budget_kind": budget.kind if budget is not None else None,
        "heldout_shrink_pct": float(d.gap.get("heldout_shrink_pct_best", math.nan)),
        "reason": v.reason,
        "reach_top_model": reach_top.get("model", ""),
        "reach_top_shrink_pct": float(reach_top.get("shrink_pct", math.nan)),
        "reach_expressible": reach.get("expressible"),
        **extra,
    }


def _median(xs: list[float]) -> float:
    xs = [x for x in xs if math.isfinite(x)]
    return float(np.median(xs)) if xs else math.nan


@experiment(
    "diagnose-independent",
    "the diagnosis on OptiOdom and UR10 data written by an independent simulator "
    "(its own kinematics, actuators, timing and noise; cases in and out of the library; "
    "--robot diffdrive|arm runs one robot's cases; --variant NAME another robot and conventions: "
    + ", ".join(VARIANTS)
    + ")",
    robots=("diffdrive", "arm"),
    variants=tuple(VARIANTS),
)
def diagnose_independent(ctx: RunContext) -> dict[str, Any]:
    from realitygap.core.parallel import ProcessBackend
    from realitygap.diagnosis.adapters.registry import close_adapters
    from realitygap.independent.cases import CASES, QUICK, case_by_name
    from realitygap.independent.variants import variant_by_name

    variant = variant_by_name(ctx.options.get("variant", "default")).name
    only = ctx.options.get("cases")
    if only:
        cases = [case_by_name(n.strip()) for n in str(only).split(",") if n.strip()]
    elif ctx.quick:
        cases = [case_by_name(n) for n in QUICK]
    else:
        cases = list(CASES)
    robot = ctx.options.get("robot")
    if robot is not None:
        cases = [c for c in cases if c.robot == robot]
    backend = ProcessBackend(ctx.options.get("workers"))
    rows: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    try:
        for i, case in enumerate(cases):
            for row in diagnose_case(
                case, ctx.seed + 1000 * i, backend, variant=variant, keep_miss=ctx.add_diagnosis
            ):
                rows.append(row)
                mark = (
                    ("right" if row["correct"] else "WRONG")
                    if case.in_library
                    else ("named effects" if row["false_attribution"] else str(row["verdict"]))
                )
                ctx.progress(
                    f"{variant}: {i + 1}/{len(cases)} {case.name} ({row['drive']}): verdict "
                    f"{row['verdict']} ({row['confidence']}), top {row['top_model']}, shrink "
                    f"{row['heldout_shrink_pct']:.1f} % → {mark} [{time.perf_counter() - t0:.0f} s]"
                )
    finally:
        close_adapters()
    figures: dict[str, Any] = {"n_cases": float(len(cases)), "n_diagnoses": float(len(rows))}
    groups = {
        "": rows,
        "diffdrive_commands_": [r for r in rows if r["drive"] == "commands"],
        "diffdrive_ticks_": [r for r in rows if r["drive"] == "ticks"],
        "arm_": [r for r in rows if r["robot"] == "arm"],
    }
    for p, sel in groups.items():
        if not sel:
            continue
        closed = [r for r in sel if r["in_library"]]
        opened = [r for r in sel if not r["in_library"]]
        figures[f"{p}top1_correct"] = f"{sum(r['correct'] for r in closed)}/{len(closed)}"
        figures[f"{p}top1_accuracy"] = (
            float(np.mean([r["correct"] for r in closed])) if closed else math.nan
        )
        figures[f"{p}top1_alias_aware_correct"] = (
            f"{sum(r['correct_alias_aware'] for r in closed)}/{len(closed)}"
        )
        figures[f"{p}top1_alias_aware_accuracy"] = (
            float(np.mean([r["correct_alias_aware"] for r in closed])) if closed else math.nan
        )
        figures[f"{p}open_set_unexplained_rate"] = (
            float(np.mean([r["open_set_strict"] for r in opened])) if opened else math.nan
        )
        figures[f"{p}open_set_lenient_rate"] = (
            float(np.mean([r["open_set_lenient"] for r in opened])) if opened else math.nan
        )
        figures[f"{p}false_attribution_rate"] = float(
            np.mean([r["false_attribution"] for r in sel])
        )
        figures[f"{p}heldout_shrink_pct_median"] = _median(
            [r["heldout_shrink_pct"] for r in closed]
        )
        # library reach of the unexplained verdicts: outside the library for an open-set case;
        # an accepted effect, expressible, for an in-library case the training did not pin down
        reached = [r for r in opened if r.get("reach_expressible") is not None]
        figures[f"{p}open_set_reach_outside"] = (
            f"{sum(not r['reach_expressible'] for r in reached)}/{len(reached)}"
        )
        reached = [r for r in closed if r.get("reach_expressible") is not None]
        figures[f"{p}in_library_reach_accepted"] = (
            f"{sum(bool(r['reach_expressible']) and r['reach_top_model'] in r['accepted'] for r in reached)}"
            f"/{len(reached)}"
        )
    figures["seconds_per_diagnosis_median"] = _median([r["seconds"] for r in rows])
    notes = [
        "each scored diagnosis is one (case, drive) pair; top-1: verdict names only accepted effects and the top-ranked model is accepted; "
        "alias-aware top-1: or one of the verdict's aliases names only accepted effects; "
        "open set strict: verdict 'unexplained'; lenient: 'unexplained' or weak confidence; "
        "shrink: median held-out shrink of the best model over in-library cases; "
        "open_set_reach_outside: of the open-set diagnoses whose verdict is unexplained, those "
        "whose library reach (every single effect fitted on the held-out windows themselves) "
        "stays below the shrink threshold; in_library_reach_accepted: of the in-library "
        "diagnoses whose verdict is unexplained, those whose reach is an accepted effect above it"
    ]
    refused = [m for r in rows for m in r.get("plausibility_refused", [])]
    if refused:
        hit = sum(bool(r.get("plausibility_refused")) for r in rows)
        notes.append(
            f"the importer's plausibility check refused a log {len(refused)} time(s) over {hit} "
            f"of {len(rows)} diagnoses ({variant}); the logs were diagnosed as read, as after "
            f"--no-plausibility-check; first: {refused[0]}"
        )
    for r in rows:
        if _missed(r):
            notes.append(
                f"{r['case']} ({r['drive']}, {variant}): verdict {r['verdict']} "
                f"({r['confidence']}), top {r['top_model']} — {r['reason']}"
            )
    return {
        "figures": figures,
        "tables": {"cases": rows},
        "notes": notes,
        "config": {
            "variant": variant,
            "cases": [c.name for c in cases],
            "workers": backend.workers,
        },
    }
