"""Sim-to-real diagnosis experiments: ``diagnose-suite``, ``diagnose-real``,
``diagnose-arm-real``, ``diagnose-bench``."""

from __future__ import annotations

import math
import os
import time
from collections import Counter
from typing import Any

import numpy as np

from realitygap.experiments import RunContext, experiment

GOALS = {
    "top1_accuracy": 0.95,
    "open_set_unexplained_rate": 0.90,
    "heldout_shrink_pct_median": 80.0,
}


@experiment(
    "diagnose-suite",
    "blind cases: hidden effects realised in PyBullet, diagnosed without the truth "
    "(--robot diffdrive|arm|climber)",
    robots=("diffdrive", "arm", "climber"),
)
def diagnose_suite(ctx: RunContext) -> dict[str, Any]:
    from realitygap.core.parallel import make_backend
    from realitygap.core.progress import Progress
    from realitygap.diagnosis.validation.suite import (
        SuiteSettings,
        draw_cases,
        run_suite,
        summarise,
    )

    n = int(ctx.options.get("cases", 12 if ctx.quick else 48))
    robot = str(ctx.options.get("robot", "diffdrive"))
    settings = SuiteSettings(robot=robot)
    cases = draw_cases(n, ctx.seed, settings)
    backend = make_backend(
        str(ctx.options.get("backend", "process")),
        workers=ctx.options.get("workers"),
        address=ctx.options.get("address"),
    )
    workers = int(getattr(backend, "workers", 0) or os.cpu_count() or 1)
    chunk = max(1, 2 * workers)
    outcomes: list[dict[str, Any]] = []
    with Progress(n, f"{robot} blind cases", enabled=ctx.verbose) as bar:
        for a in range(0, n, chunk):
            part = run_suite(cases[a : a + chunk], settings, backend)
            outcomes += part
            ok = sum(o["correct"] for o in outcomes)
            bar.write(
                f"cases {a}–{a + len(part) - 1}: {', '.join(str(o['verdict']) for o in part)}"
            )
            bar.update(len(part), note=f"{ok} correct")
    figures, tables = summarise(outcomes)
    figures["seconds_per_case_median"] = float(
        np.median([o["seconds_record"] + o["seconds_diagnose"] for o in outcomes])
    )
    notes = []
    for key, goal in GOALS.items():
        value = figures.get(key, math.nan)
        met = value >= goal if math.isfinite(value) else False
        notes.append(f"goal {key} >= {goal}: {'met' if met else 'NOT met'} ({value:.3g})")
    missed = [o for o in outcomes if not o["correct"]]
    for o in missed:
        notes.append(
            f"case {o['index']}: truth {'+'.join(o['truth_names'])}"
            f"{' (withheld ' + o['withheld'][0] + ')' if o['open_set'] else ''} → {o['verdict']}: "
            f"{o['reason']}"
        )
    return {
        "figures": figures,
        "tables": tables,
        "notes": notes,
        "config": {
            "robot": robot,
            "cases": n,
            "open_set_every": settings.open_set_every,
            "pair_probability": settings.pair_probability,
            "backend": backend.name,
            "workers": workers,
        },
    }


def _optiodom_groups(ctx: RunContext) -> dict[str, list[Any]]:
    from realitygap.diagnosis.logs.read import logs_from_optiodom

    root = ctx.data_subdir("optiodom_diffdrive")
    logs = logs_from_optiodom(root)
    groups: dict[str, list[Any]] = {}
    for lg in logs:
        groups.setdefault(str(lg.meta.get("path_type", "unknown")), []).append(lg)
    return groups


def _pick(
    logs: list[Any], per_session: int, max_sessions: int | None, skip_sessions: int = 0
) -> list[Any]:
    """Up to ``per_session`` runs (cw and ccw alternating) of each session, sessions in
    name order, skipping the first ``skip_sessions`` and taking at most ``max_sessions``."""
    by_session: dict[str, list[Any]] = {}
    for lg in logs:
        by_session.setdefault(str(lg.meta.get("session")), []).append(lg)
    out = []
    for i, (_, runs) in enumerate(sorted(by_session.items())[skip_sessions:]):
        if max_sessions is not None and i >= max_sessions:
            break
        # balance directions: alternate cw / ccw runs where both exist
        cw = [r for r in runs if r.meta.get("direction") == "cw"]
        ccw = [r for r in runs if r.meta.get("direction") == "ccw"]
        rest = [r for r in runs if r.meta.get("direction") not in ("cw", "ccw")]
        mixed = [x for pair in zip(cw, ccw) for x in pair] + cw[len(ccw) :] + ccw[len(cw) :] + rest
        out += mixed[:per_session]
    return out


def _log_geometry(log: Any) -> dict[str, float]:
    p = log.meta["params"]
    return {k: float(p[k]) for k in ("wheel_radius_left", "wheel_radius_right", "wheelbase")}


def _ranking_table(js: dict[str, Any], n: int) -> list[dict[str, Any]]:
    """The first ``n`` models of a diagnosis (its JSON form) as table rows."""
    return [
        {
            "rank": r["rank"],
            "model": r["name"],
            "params": {k: round(p["value"], 6) for k, p in r["params"].items()},
            "heldout_shrink_pct": round(r["heldout_shrink_pct"], 2),
            "verified": r["verified_in_pybullet"],
        }
        for r in js["ranking"][:n]
    ]


def _umbmark_on_logs(logs: list[Any], reference: dict[str, float]) -> dict[str, float]:
    """UMBmark (closed form on the squares' end poses) on exactly these square runs.

    Per session, Borenstein & Feng's ``E_d`` and ``E_b`` from the picked runs
    (:func:`~realitygap.estimators.umbmark.umbmark_from_runs`) and from all its
    runs (:func:`~realitygap.calibrate.calibrate_session`); pooled as
    ``umbmark-real`` pools (means of ``E_d`` and of the dimensionless ``b / D̄``,
    the quantity UMBmark observes) and expressed as ``E_b`` relative to
    ``reference`` (wheel radii and wheelbase, m).
    """
    from pathlib import Path

    from realitygap.calibrate import calibrate_session
    from realitygap.diagnosis.logs.importers.optiodom import read_session
    from realitygap.estimators.umbmark import UMBmarkRun, umbmark_from_runs

    d_ref = reference["wheel_radius_left"] + reference["wheel_radius_right"]
    b_ref = reference["wheelbase"]
    picked: dict[str, set[int]] = {}
    folders: dict[str, Path] = {}
    for lg in logs:
        sid = str(lg.meta.get("session"))
        picked.setdefault(sid, set()).add(int(lg.meta.get("run", -1)))
        folders[sid] = Path(str(lg.meta.get("source"))).parent
    same_runs: list[tuple[float, float]] = []
    all_runs: list[tuple[float, float]] = []
    for sid, folder in sorted(folders.items()):
        session = read_session(folder)
        kin = session.kinematics()
        d_mean = kin.wheel_radius_left + kin.wheel_radius_right
        side = session.metadata.side_length
        runs = [
            UMBmarkRun(
                r.gt_pose, r.ticks_left.astype(float), r.ticks_right.astype(float), r.direction
            )
            for r in session.runs
            if r.index in picked[sid] and r.direction is not None
        ]
        if side and {r.direction for r in runs} == {"cw", "ccw"}:
            res = umbmark_from_runs(runs, kin, float(side))
            same_runs.append((res.E_d, res.E_b * kin.wheelbase / d_mean))
        cal = calibrate_session(folder)
        all_runs.append((cal.E_d, cal.b_over_D))
    out: dict[str, float] = {}
    for label, rows in (("same_runs", same_runs), ("same_sessions", all_runs)):
        if rows:
            arr = np.asarray(rows)
            out[f"umbmark_{label}_E_d"] = float(arr[:, 0].mean())
            out[f"umbmark_{label}_E_b"] = float(arr[:, 1].mean() * d_ref / b_ref)
    return out


def _umbmark_heldout(d: Any, e_b: float, e_d: float) -> dict[str, float]:
    """The held-out trajectory gap of a diagnosis ``d`` (either drive) when the replay
    carries UMBmark's ``E_b`` and ``E_d`` instead of the diagnosis's best model: the same
    calibrated baseline (clocks, frames; with the command drive also the actuator
    response), the same PyBullet replays, the classical
    calibration's two factors (``wheelbase_error.E_b``, ``wheel_diameter_ratio.E_d``;
    UMBmark keeps the mean wheel diameter, as the diameter ratio does)."""
    from realitygap.diagnosis.problem.shrink import trajectory_gap

    problem = d.problem
    values = {
        **d.baseline.values,
        "wheelbase_error.E_b": float(e_b),
        "wheel_diameter_ratio.E_d": float(e_d),
    }
    held = [i for i, p in enumerate(problem.logs) if p.holdout_windows.any()]
    gap = trajectory_gap(
        [problem.logs[i].log for i in held], [problem.replay(i, values)[1] for i in held]
    )
    nominal = d.gap["heldout_trajectory_gap_m_nominal"]
    return {
        "umbmark_heldout_gap_cm": 100.0 * gap,
        "umbmark_trajectory_shrink_pct": 100.0 * (1.0 - gap / nominal) if nominal > 0 else 0.0,
    }


def _geometry_found(d: Any) -> dict[str, Any]:
    """Wheelbase and diameter factors the diagnosis found, as UMBmark defines them.

    From the best-ranked model holding ``wheelbase_error`` (resp.
    ``wheel_diameter_ratio``): UMBmark observes the wheelbase relative to the mean
    wheel diameter, so its ``E_b`` is the wheelbase factor over the radius scale.
    """
    out: dict[str, Any] = {}
    vals = d.budget.values if d.budget is not None else {}
    if "wheelbase_error.E_b" in vals:
        out["E_b"] = vals["wheelbase_error.E_b"] / vals.get("wheel_radius_scale.scale", 1.0)
        out["E_b_model"] = "gap budget"
    if "wheel_diameter_ratio.E_d" in vals:
        out["E_d"] = vals["wheel_diameter_ratio.E_d"]
        out["E_d_model"] = "gap budget"
    for fit in d.ranking:
        if "wheelbase_error" in fit.effects and "E_b" not in out:
            out["E_b"] = fit.values["wheelbase_error.E_b"] / fit.values.get(
                "wheel_radius_scale.scale", 1.0
            )
            out["E_b_model"] = fit.name
        if "wheel_diameter_ratio" in fit.effects and "E_d" not in out:
            out["E_d"] = fit.values["wheel_diameter_ratio.E_d"]
            out["E_d_model"] = fit.name
    return out


def _verdict_figure(d: Any) -> str:
    """The verdict of diagnosis ``d`` as a figure: its effects joined by "+", or its kind."""
    from realitygap.diagnosis.verdict.types import VerdictKind

    v = d.verdict
    if v.kind is VerdictKind.PARTIAL:
        return "partly " + "+".join(v.effects)
    return "+".join(v.effects) if v.kind is VerdictKind.EFFECTS else v.kind.value


def _reach_figures(d: Any, prefix: str) -> dict[str, Any]:
    """The library reach of an unexplained verdict (:mod:`realitygap.diagnosis.stages.reach`): the
    single effect that closes most of the held-out gap fitted on the held-out windows
    themselves, and how much."""
    reach = d.verdict.notes.reach
    if not reach or not reach.get("rows"):
        return {}
    top = reach["rows"][0]
    return {
        prefix + "reach_top_model": top["model"],
        prefix + "reach_top_shrink_pct": top["shrink_pct"],
        prefix + "reach_expressible": float(reach["expressible"]),
    }


def _real_split(ctx: RunContext, extend_training: bool) -> tuple[list[Any], list[Any]]:
    """Training and held-out OptiOdom runs of ``diagnose-real``.

    Training: a cw and a ccw run of each UMBmark square session. Held out: two runs
    of the first two sessions of every other path type (one session with ``--quick``).
    With ``extend_training`` the training also takes two runs of the next two
    sessions of each held-out path type (one with ``--quick``), so that it
    exercises the speeds and turn rates of the held-out runs; the held-out runs
    stay the same.
    """
    groups = _optiodom_groups(ctx)
    if "square" not in groups:
        raise FileNotFoundError(
            "diagnose-real trains on the UMBmark square runs: no session under "
            "'<data>/optiodom_diffdrive/square/' was found"
        )
    n_ho = 1 if ctx.quick else 2
    train = _pick(groups["square"], per_session=2, max_sessions=2 if ctx.quick else None)
    holdout: list[Any] = []
    for kind in ("ivanjko", "circular", "free"):
        if kind in groups:
            holdout += _pick(groups[kind], per_session=2, max_sessions=n_ho)
            if extend_training:
                train += _pick(groups[kind], per_session=2, max_sessions=n_ho, skip_sessions=n_ho)
    if not holdout:
        raise FileNotFoundError("diagnose-real needs held-out runs of another path type")
    return train, holdout


def _real_diagnoses(
    ctx: RunContext, train: list[Any], holdout: list[Any], drives: tuple[str, ...]
) -> dict[str, Any]:
    """Diagnose ``train`` against ``holdout`` once per replay drive; figures, tables, notes."""
    from realitygap.core.parallel import ProcessBackend
    from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
    from realitygap.diagnosis.problem.shrink import concentrated_gap
    from realitygap.diagnosis.report.summary import stage_split
    from realitygap.diagnosis.report.words import explain

    backend = ProcessBackend(ctx.options.get("workers"))
    figures: dict[str, Any] = {}
    tables: dict[str, Any] = {}
    notes: list[str] = []
    for drive in drives:
        tr = [lg for lg in train if drive == "ticks" or lg.has("cmd")]
        ho = [lg for lg in holdout if drive == "ticks" or lg.has("cmd")]
        ctx.progress(f"{drive}-driven replay: {len(tr)} training runs, {len(ho)} held-out runs")
        estimates: list[tuple[float, float]] = []  # (when, seconds left)
        d = diagnose(
            tr,
            ho,
            settings=DiagnosisSettings(drive=drive),
            backend=backend,
            progress=ctx.progress,
            on_estimate=lambda left, e=estimates: e.append((time.perf_counter(), left)),
        )
        end = time.perf_counter()
        ctx.add_diagnosis(f"{drive}-driven replay", d)
        best = next(f for f in d.ranking)
        prefix = "" if drive == "commands" else "ticks_"
        if estimates:  # the first estimate of the time left against the time it took
            figures[prefix + "estimate_seconds_left_first"] = estimates[0][1]
            figures[prefix + "actual_seconds_left_then"] = end - estimates[0][0]
        g = d.gap
        figures[prefix + "heldout_gap_cm_nominal"] = 100.0 * g["heldout_trajectory_gap_m_nominal"]
        figures[prefix + "heldout_gap_cm_corrected"] = 100.0 * g.get(
            "heldout_trajectory_gap_m_best", g["heldout_trajectory_gap_m_nominal"]
        )
        figures[prefix + "heldout_window_gap_mm_nominal"] = 1e3 * g.get(
            "heldout_window_gap_m_nominal", math.nan
        )
        figures[prefix + "heldout_window_gap_mm_corrected"] = 1e3 * g.get(
            "heldout_window_gap_m_best", math.nan
        )
        figures[prefix + "shrink_pct"] = g["heldout_shrink_pct_best"]
        if "heldout_trajectory_gap_m_best" in g and g["heldout_trajectory_gap_m_nominal"] > 0:
            figures[prefix + "trajectory_shrink_pct"] = 100.0 * (
                1.0 - g["heldout_trajectory_gap_m_best"] / g["heldout_trajectory_gap_m_nominal"]
            )
        runs = g.get("heldout_trajectory_runs", [])
        if runs:
            tables[f"{drive}_heldout_runs"] = [
                {k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()}
                for r in runs
            ]
        conc = concentrated_gap(runs)
        if conc is not None:
            figures[prefix + "top_run_share_pct"] = conc["share_pct"]
            figures[prefix + "heldout_gap_cm_other_runs_nominal"] = 100.0 * conc["rest_before_m"]
            if "rest_after_m" in conc:
                figures[prefix + "heldout_gap_cm_other_runs_corrected"] = (
                    100.0 * conc["rest_after_m"]
                )
        split = stage_split(d)
        if split is not None:
            figures[prefix + "stage_command_to_wheels_pct"] = split[0]
            figures[prefix + "stage_wheels_to_body_pct"] = split[1]
        gains = d.actuation.get("gains", [])
        if gains:
            tables[f"{drive}_command_wheel_gains"] = gains
            for split_name in ("train", "holdout"):
                turn = [g["turn_gain"] for g in gains if g["split"] == split_name]
                turn = [x for x in turn if math.isfinite(x)]
                if turn:
                    figures[f"{prefix}{split_name}_turn_gain_min"] = min(turn)
                    figures[f"{prefix}{split_name}_turn_gain_max"] = max(turn)
        frames = d.baseline.frames
        if frames.rows:
            moved = [r for r in frames.rows if r["applied"]]
            figures[prefix + "frame_logs_reframed"] = float(len(moved))
            figures[prefix + "frame_common_yaw_mrad"] = 1e3 * frames.common[2]
            tables[f"{drive}_frame_alignment"] = [
                {
                    "log": r["log"],
                    "split": r["split"],
                    "x_mm": round(1e3 * r["frame"][0], 2),
                    "y_mm": round(1e3 * r["frame"][1], 2),
                    "yaw_mrad": round(1e3 * r["frame"][2], 2),
                    "tested": "".join("xyψ"[j] for j, t in enumerate(r["tested"]) if t),
                    "applied": r["applied"],
                    "chi2_drop": round(r["chi2_drop"], 1),
                }
                for r in frames.rows
            ]
        clock = d.baseline.clock
        if clock.rows:
            devs = [1e3 * r["deviation_s"] for r in clock.rows if r["applied"]]
            figures[prefix + "clock_common_offset_ms"] = 1e3 * clock.common
            figures[prefix + "clock_logs_restamped"] = float(len(devs))
            if devs:
                figures[prefix + "clock_deviation_ms_min"] = min(devs)
                figures[prefix + "clock_deviation_ms_max"] = max(devs)
            tables[f"{drive}_clock_alignment"] = [
                {
                    "log": r["log"],
                    "split": r["split"],
                    "offset_ms": round(1e3 * r["offset_s"], 2),
                    "deviation_ms": round(1e3 * r["deviation_s"], 2),
                    "applied": r["applied"],
                    "chi2_drop": round(r["chi2_drop"], 1),
                }
                for r in clock.rows
            ]
        if d.budget is not None:
            bj = d.budget.to_json()
            figures[prefix + "budget_kind"] = bj["kind"]
            figures[prefix + "budget_unexplained_share_pct"] = bj["unexplained_share_pct"]
            for j, e in enumerate(bj["entries"], start=1):
                figures[f"{prefix}budget_{j}_effect"] = e["effect"]
                for sc, share in e["share_pct"].items():
                    lo, hi = e["interval_pct"][sc]
                    figures[f"{prefix}budget_{j}_{sc}_share_pct"] = share
                    figures[f"{prefix}budget_{j}_{sc}_interval_pct"] = f"{lo:.0f} … {hi:.0f}"
            notes.append(f"{drive}: {bj['sentence']}")
        cov = d.coverage
        if cov is not None:
            figures[prefix + "heldout_windows_beyond_training"] = float(cov.n_outside)
            figures[prefix + "gap_share_beyond_training_pct"] = 100.0 * cov.gap_share_outside
            figures[prefix + "shrink_within_training_pct"] = cov.shrink_inside_pct
            figures[prefix + "shrink_beyond_training_pct"] = cov.shrink_outside_pct
            tables[f"{drive}_coverage"] = cov.rows
            if d.verdict.notes.coverage is None:  # else the verdict's own lines state it
                notes.append(f"{drive}: coverage: {cov.summary()}")
        track = d.actuation.get("tracking")
        if track is not None:
            tables[f"{drive}_wheel_tracking"] = track["wheels"]
            for r in track["wheels"]:
                w = f"{prefix}{r['wheel']}_wheel_"
                figures[w + "train_gain"] = r["train_gain"]
                figures[w + "train_top_speed"] = r["train_top_speed"]
                if "beyond_gain" in r:
                    figures[w + "beyond_training_gain"] = r["beyond_gain"]
                    figures[w + "beyond_training_reached_max"] = r["reached_max"]
                    figures[w + "beyond_training_capped_windows"] = float(r["n_capped"])
        tr_rep = d.transients
        figures[prefix + "transient_windows_set_aside"] = float(tr_rep.n_excluded)
        figures[prefix + "transient_share_pct"] = 100.0 * tr_rep.share_excluded
        figures[prefix + "top_effect"] = best.name
        figures[prefix + "verdict"] = _verdict_figure(d)
        figures[prefix + "verdict_text"] = d.verdict.notes.verdict_text
        figures[prefix + "diagnose_seconds"] = d.timing["total"]
        figures.update(_reach_figures(d, prefix))
        js = d.to_json()
        tables[f"{drive}_ranking"] = _ranking_table(js, 10)
        tables[f"{drive}_where"] = [
            {
                k: r[k]
                for k in (
                    "kind",
                    "where",
                    "column",
                    "regime",
                    "n_windows",
                    "rms",
                    "mean",
                    "unit",
                    "share",
                )
            }
            for r in js["localisation"]["table"][:12]
        ]
        tables[f"{drive}_shrink_best_candidate"] = [
            r for r in js["shrink_best_candidate"] if r["regime"] == "all"
        ]
        top = [f.name for f in d.ranking[:1]]  # the ranking table marks the others
        notes += [f"{drive}: {line}" for line in explain(d.verdict, top)]
        if d.nominal_reference:
            notes.append(f"{drive}: {d.nominal_reference['summary']}")
        ref = d.nominal_reference.get("reference") or _log_geometry(train[0])
        umb = _umbmark_on_logs(tr, ref)
        if drive == "commands" and {"umbmark_same_runs_E_b", "umbmark_same_runs_E_d"} <= set(umb):
            ctx.progress("replaying the held-out commands with UMBmark's factors")
            classical = _umbmark_heldout(
                d, umb["umbmark_same_runs_E_b"], umb["umbmark_same_runs_E_d"]
            )
            figures.update(
                {k.replace("umbmark_", "umbmark_commands_"): v for k, v in classical.items()}
            )
            notes.append(
                "commands: umbmark_commands_*: the held-out runs' commands replayed with "
                "UMBmark's same-run E_b and E_d on the command replay's calibrated baseline "
                "(clocks, frames, actuator response), for the comparison with "
                "heldout_gap_cm_corrected: what the classical calibration does where the "
                "diagnosis is scored"
            )
        if drive == "ticks":
            found = _geometry_found(d)
            for k in ("E_b", "E_d"):
                if k in found:
                    figures[f"ticks_{k}"] = found[k]
                for label in ("same_runs", "same_sessions"):
                    if f"umbmark_{label}_{k}" in umb:
                        figures[f"umbmark_{label}_{k}"] = umb[f"umbmark_{label}_{k}"]
            if "E_b" in found and "umbmark_same_runs_E_b" in umb:
                figures["ticks_E_b_minus_umbmark"] = found["E_b"] - umb["umbmark_same_runs_E_b"]
            if "umbmark_same_runs_E_b" in umb and "umbmark_same_runs_E_d" in umb:
                ctx.progress("replaying the held-out runs with UMBmark's factors")
                figures.update(
                    _umbmark_heldout(d, umb["umbmark_same_runs_E_b"], umb["umbmark_same_runs_E_d"])
                )
            notes.append(
                "ticks: E_b (b / D̄ over the reference's, as UMBmark defines it) from "
                f"{found.get('E_b_model', 'no model with wheelbase_error')}, E_d from "
                f"{found.get('E_d_model', 'no model with wheel_diameter_ratio')}; umbmark_same_runs_*: "
                "UMBmark on exactly the training square runs, umbmark_same_sessions_*: on all runs "
                "of their sessions (both pooled as umbmark-real pools); umbmark_heldout_gap_cm: "
                "the held-out runs replayed with UMBmark's same-run E_b and E_d on the same "
                "calibrated baseline, for the comparison with ticks_heldout_gap_cm_corrected"
            )
        for info in d.identifiability:
            if not info.get("separable"):
                notes.append(f"{drive}: {info['message']}")
    figures["n_train_runs"] = float(len(train))
    figures["n_holdout_runs"] = float(len(holdout))
    kinds = Counter(str(lg.meta.get("path_type")) for lg in holdout)
    return {
        "figures": figures,
        "tables": tables,
        "notes": notes,
        "config": {
            "train": [lg.name for lg in train],
            "holdout": [lg.name for lg in holdout],
            "holdout_path_types": dict(kinds),
        },
    }


@experiment(
    "diagnose-real",
    "OptiOdom robot: where the real gap lies, which effects explain it, held-out shrink",
    data_subdir="optiodom_diffdrive",
)
def diagnose_real(ctx: RunContext) -> dict[str, Any]:
    """UMBmark squares train; circular, Ivanjko and free-driving runs are held out; both
    replays (driven by the commands and by the encoder ticks)."""
    train, holdout = _real_split(ctx, extend_training=False)
    return _real_diagnoses(ctx, train, holdout, ("commands", "ticks"))


@experiment(
    "diagnose-real-covered",
    "OptiOdom robot, command replay: the same held-out runs, with training that also drives "
    "at their speeds",
    data_subdir="optiodom_diffdrive",
)
def diagnose_real_covered(ctx: RunContext) -> dict[str, Any]:
    """The experiment ``diagnose-real`` asks for when its held-out runs go beyond the
    squares' motions: the same held-out runs, with runs of other sessions of each held-out
    path type added to the training (:func:`_real_split`), command replay only."""
    train, holdout = _real_split(ctx, extend_training=True)
    return _real_diagnoses(ctx, train, holdout, ("commands",))


@experiment(
    "diagnose-arm-real",
    "UR10 laser-tracker series: which arm effects explain the real error, held-out shrink",
    data_subdir="ipa_ur10_lasertracker",
)
def diagnose_arm_real(ctx: RunContext) -> dict[str, Any]:
    """Diagnose the UR10 with one series for training and the other held out, both ways.

    The logs are what ``realitygap diagnose <data>/ipa_ur10_lasertracker`` reads; the
    first direction (train on the first series, hold out the last) gives the headline
    figures ``ur10_top_effects`` and ``ur10_shrink_pct``.
    """
    from realitygap.core.parallel import ProcessBackend
    from realitygap.diagnosis.adapters.arm.adapter import ArmAdapter
    from realitygap.diagnosis.adapters.arm.aliases import identify_window_geometry
    from realitygap.diagnosis.adapters.registry import ADAPTERS
    from realitygap.diagnosis.diagnose import DiagnosisSettings, diagnose
    from realitygap.diagnosis.logs.read import logs_from_ur10
    from realitygap.diagnosis.report.words import explain

    logs = logs_from_ur10(ctx.data_subdir("ipa_ur10_lasertracker"))
    if len(logs) < 2:
        raise FileNotFoundError(
            "diagnose-arm-real needs two measurement series (one to train on, one held out); "
            f"found {len(logs)}"
        )
    # windows per log (the thinning is evenly spread and keeps each pose's direction of motion)
    ADAPTERS["arm"] = ArmAdapter(max_windows=200 if ctx.quick else 600)
    backend = ProcessBackend(ctx.options.get("workers"))
    figures: dict[str, Any] = {}
    tables: dict[str, Any] = {}
    notes: list[str] = []
    try:
        splits = [("", logs[:-1], logs[-1:]), ("reverse_", logs[1:], logs[:1])]
        for prefix, train, holdout in splits:
            names = f"{'+'.join(lg.name for lg in train)} → {'+'.join(lg.name for lg in holdout)}"
            ctx.progress(f"training on / holding out: {names}")
            d = diagnose(
                train,
                holdout,
                settings=DiagnosisSettings(robot="arm"),
                backend=backend,
                progress=ctx.progress,
            )
            ctx.add_diagnosis(names, d)
            best = d.ranking[0]
            scale = 1e-4  # tool_dist feature scale, m
            figures[f"ur10_{prefix}top_effects"] = list(best.effects)
            figures[f"ur10_{prefix}shrink_pct"] = d.gap["heldout_shrink_pct_best"]
            figures[f"ur10_{prefix}verdict"] = _verdict_figure(d)
            figures[f"ur10_{prefix}heldout_dist_err_mm_nominal"] = (
                1e3 * scale * d.gap["heldout_rms_nominal"]
            )
            figures[f"ur10_{prefix}heldout_dist_err_mm_best"] = (
                1e3 * scale * d.gap["heldout_rms_best"]
            )
            figures[f"ur10_{prefix}diagnose_seconds"] = d.timing["total"]
            figures.update(_reach_figures(d, f"ur10_{prefix}"))
            # the verdict's held-out evidence: residual against the noise floor (stated noise
            # raised by the fitted parameters' own noise), and what discovery finds in it
            floor = d.verdict.residual.get("noise_floor") if d.verdict.residual else None
            if floor is not None:
                figures[f"ur10_{prefix}residual_over_noise_floor"] = floor["ratio"]
                figures[f"ur10_{prefix}noise_floor_inflation"] = floor["inflation"]
            geo = next((f for f in d.ranking if f.effects == ("arm_geometric_tolerances",)), None)
            if geo is not None:
                z_nom = d.nominal_heldout
                figures[f"ur10_{prefix}geometric_tolerances_shrink_pct"] = 100.0 * (
                    1.0 - float(np.sqrt(np.mean(geo.z_heldout**2) / np.mean(z_nom**2)))
                )
                figures[f"ur10_{prefix}geometric_tolerances_rank"] = d.ranking.index(geo) + 1
            disc = d.verdict.notes.discovery or (
                (d.verdict.residual or {}).get("held_out_structure")
            )
            if disc is not None:
                figures[f"ur10_{prefix}discovered_terms"] = [
                    f"{t['term']}: {t['coef']:.3g} {t['unit']}"
                    for f in disc["fits"][:1]
                    if f["found"]
                    for t in f["terms"]
                ]
                figures[f"ur10_{prefix}discovery_heldout_shrink_pct"] = (
                    disc["fits"][0]["heldout_shrink_pct"] if disc["fits"] else 0.0
                )
            js = d.to_json()
            tables[f"{prefix or 'forward_'}ranking"] = _ranking_table(js, 8)
            tables[f"{prefix or 'forward_'}where"] = [
                {k: r[k] for k in ("where", "column", "regime", "n_windows", "rms", "share")}
                for r in js["localisation"]["table"][:8]
            ]
            top = [f.name for f in d.ranking[:1]]  # the ranking table marks the others
            notes += [f"{names}: {line}" for line in explain(d.verdict, top)]
            for e, why in d.not_observable.items():
                if prefix == "":
                    notes.append(f"not observable: {e}: {why}")
            # the project's kinematic identification on the same training poses
            for pairs in ("windows", "all"):
                ident = identify_window_geometry(
                    d.prepared, pairs=pairs, max_poses=300 if ctx.quick else 800
                )
                figures[f"ur10_{prefix}identified_{pairs}_shrink_pct"] = ident["heldout_shrink_pct"]
            aliases = ADAPTERS["arm"].alias_groups(d.prepared)
            tables[f"{prefix or 'forward_'}aliases"] = [
                {"effects": " / ".join(p["effects"]), "correlation": p["correlation"]}
                for g in aliases
                for p in g["pairs"]
            ]
            for g in aliases:
                for a, b in g["aliases"]:
                    notes.append(f"{names}: {a} or {b} (aliases on this data): {g['why']}")
    finally:
        ADAPTERS.pop("arm", None)
    notes.append(
        "distance error: RMS over held-out windows of the six tool-point distances between four "
        "poses a quarter of the series apart (registration-free); shrink = 1 - best/nominal"
    )
    notes.append(
        "identified_*: distance-mode MDH identification (estimators.arm.identify) on the training "
        "windows' pairs (windows) or on all pairs of the training poses (all), scored on the "
        "same held-out windows"
    )
    return {
        "figures": figures,
        "tables": tables,
        "notes": notes,
        "config": {
            "series": [lg.name for lg in logs],
            "max_windows": 200 if ctx.quick else 600,
            "identification_max_poses": 300 if ctx.quick else 800,
        },
    }


@experiment(
    "diagnose-bench",
    "time to diagnose one 90 s log against the full effect library (process pool)",
)
def diagnose_bench(ctx: RunContext) -> dict[str, Any]:
    from realitygap.core.parallel import ProcessBackend, SerialBackend
    from realitygap.diagnosis.adapters.diffdrive.replay import params_from_meta
    from realitygap.diagnosis.diagnose import diagnose
    from realitygap.experiments.scaling import bench_log, fresh_replay_cache
    from realitygap.robots.diffdrive_surrogate import calibrate
    from realitygap.robots.simulation import SimSettings

    log = bench_log(np.random.default_rng(ctx.seed))
    backend = ProcessBackend(ctx.options.get("workers"))
    ctx.progress(f"diagnosing a {log.duration:.0f} s log with {backend.workers} worker(s)")
    estimates: list[tuple[float, float]] = []  # (when, seconds left)
    with fresh_replay_cache():
        # the robot's surrogate calibration is made once per robot, not per log: made
        # here, before the timed runs (the workers inherit it)
        calibrate(params_from_meta(log), SimSettings.for_log(log).solver_iterations)
        t0 = time.perf_counter()
        d = diagnose(
            [log],
            backend=backend,
            progress=ctx.progress,
            on_estimate=lambda left: estimates.append((time.perf_counter(), left)),
        )
        end = time.perf_counter()
        seconds = end - t0
        # the same log again: its replays come from the cache
        t1 = time.perf_counter()
        diagnose([log], backend=backend)
        warm = time.perf_counter() - t1
    ctx.add_diagnosis("", d)
    figures: dict[str, Any] = {
        "diagnose_seconds": seconds,
        "diagnose_seconds_cached_replays": warm,
        "log_seconds": log.duration,
        "workers": float(backend.workers),
        "verdict": _verdict_figure(d),
    }
    if estimates:
        # the first estimate, made once the nominal replays are done, against the truth
        when, left = estimates[0]
        figures["estimate_seconds_left_first"] = left
        figures["actual_seconds_left_then"] = end - when
    if not ctx.quick:
        with fresh_replay_cache():
            t2 = time.perf_counter()
            diagnose([log], backend=SerialBackend())
            figures["diagnose_seconds_serial"] = time.perf_counter() - t2
    return {
        "figures": figures,
        "config": {"library": "all diffdrive effects", "window_s": 1.0, "hidden": "E_d = 1.008"},
        "notes": [
            f"goal diagnose_seconds <= 3: {'met' if seconds <= 3 else 'NOT met'}",
            "diagnose_seconds: a first diagnosis of the log (replays not cached); "
            "diagnose_seconds_cached_replays: the same log again",
        ],
    }
