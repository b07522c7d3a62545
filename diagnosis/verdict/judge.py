"""The held-out figures of the gap budget's model: its residuals, the gap report (window
and whole-run figures, PyBullet replays of the held-out runs) and the gap in words.

:func:`heldout_view` turns the budget (:mod:`~realitygap.diagnosis.budget`) into the
:class:`~realitygap.diagnosis.verdict.types.Judgement` the later stages read: the budget's
model as a :class:`~realitygap.diagnosis.fit.model.ModelFit` (its held-out residual on the
surrogate), the reference replay's held-out residual, the channels where the gap lives and
the shrink there. It decides nothing: the budget's one rule has set the kind.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.parallel import Backend
from realitygap.diagnosis.budget import Budget
from realitygap.diagnosis.fit.model import ModelFit, replay_task
from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.problem import Layout, Problem, profile_score
from realitygap.diagnosis.problem.residual import describe_residual, shrink_above_noise
from realitygap.diagnosis.problem.shrink import (
    overall_shrink,
    shrink_table,
    trajectory_gap,
    trajectory_runs,
)
from realitygap.diagnosis.stages.baseline import Baseline
from realitygap.diagnosis.verdict.types import Judgement, VerdictKind

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "budget_fit",
    "budget_replays",
    "describe_fit_residual",
    "gap_channels",
    "gap_report",
    "gap_words",
    "heldout_view",
]


def gap_channels(
    z_nom: FloatArray, problem: Problem, layout: Layout | None = None
) -> npt.NDArray[np.bool_]:
    """Entries of the held-out groups (of ``layout``'s, e.g. the training windows) whose
    nominal residual exceeds twice the floor (all entries if none does): channels the
    effects do not touch would only add their noise to both sides of the shrink."""
    lay = problem.holdout if layout is None else layout
    gap_mask = np.zeros(z_nom.shape, dtype=bool)
    for g in np.unique(lay.group):
        sel = lay.group == g
        if float(np.sqrt(np.mean(z_nom[sel] ** 2))) > 2.0 * problem.settings.floor:
            gap_mask |= sel
    if not gap_mask.any():
        gap_mask[:] = True
    return gap_mask


def describe_fit_residual(
    problem: Problem, fit: ModelFit, noise: Mapping[str, float] | None
) -> dict[str, Any]:
    """What ``fit`` leaves on the held-out windows
    (:func:`~realitygap.diagnosis.problem.residual.describe_residual`), with the adapter's own
    structure test (``residual_structure``; the nominal's at ``{}``)."""
    desc = describe_residual(
        fit.z_heldout, problem.holdout, problem.settings, problem.features, noise
    )
    return problem.adapter.residual_structure(problem, fit.values if fit.effects else {}, desc)


def budget_fit(problem: Problem, budget: Budget, nominal_fit: ModelFit) -> ModelFit:
    """The budget's model (every entry, the baseline beneath) as a ModelFit: its values and
    errors, and its residuals on the surrogate; ``nominal_fit`` when the budget is empty."""
    if not budget.entries:
        return nominal_fit
    point = {k: np.array([v]) for k, v in budget.values.items()}
    z_tr = problem.surrogate_residuals(problem.train, point, 1)[0]
    z_ho = (
        problem.surrogate_residuals(problem.holdout, point, 1)[0]
        if problem.holdout.n
        else np.zeros(0)
    )
    st = problem.settings
    p = len(budget.values)
    train = float(profile_score(z_tr, problem.train, st.score_floor))
    held = float(profile_score(z_ho, problem.holdout, st.score_floor)) if z_ho.size else 0.0
    n_tr = max(problem.train.n, 1)
    stderr = {k: v for e in budget.entries for k, v in e.stderr.items()}
    return ModelFit(
        effects=tuple(e.effect for e in budget.entries),
        keys=tuple(budget.values),
        values=dict(budget.values),
        stderr=stderr,
        corr=np.full((p, p), np.nan),
        train_score=train,
        bic=train + p * math.log(n_tr),
        heldout_score=held,
        rank_score=held + p * math.log(n_tr),
        heldout_rms=float(np.sqrt(np.mean(z_ho**2))) if z_ho.size else 0.0,
        z_heldout=z_ho,
        verified=False,
        message="the gap budget's model",
        n_train=problem.train.n,
    )


def heldout_view(
    problem: Problem,
    budget: Budget,
    nominal_fit: ModelFit,
    noise: Mapping[str, float] | None,
) -> Judgement:
    """The held-out figures of the budget's model (module docstring)."""
    z_nom = problem.nominal_residuals(problem.holdout)
    best = budget_fit(problem, budget, nominal_fit)
    gap_mask = gap_channels(z_nom, problem)
    return Judgement(
        kind=VerdictKind(budget.kind),
        best=best,
        nominal_heldout=z_nom,
        gap_mask=gap_mask,
        shrink_pct_best=overall_shrink(z_nom[gap_mask], best.z_heldout[gap_mask]),
        shrink_pct_above_noise=shrink_above_noise(
            z_nom, best.z_heldout, problem.holdout, gap_mask, noise
        ),
    )


def gap_report(
    problem: Problem,
    judgement: Judgement,
    replays: Mapping[tuple[str, ...], dict[int, Log]],
    baseline: Baseline | None = None,
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The held-out shrink table of the verdict's model and the gap figures.

    Window figures are measured against the reference (the calibrated baseline
    when there is one) on the windows left after transient events are set
    aside; trajectory gaps are whole replays (nominal, baseline, best model), pooled
    and run by run (``heldout_trajectory_runs``).
    """
    best = judgement.best
    z_nom, gap_mask = judgement.nominal_heldout, judgement.gap_mask
    prepared = problem.logs
    scales = problem.features
    chosen = best if best.effects else None
    z_after = chosen.z_heldout if chosen is not None else z_nom
    rows = shrink_table(z_nom, z_after, problem.holdout, scales)
    ho_idx = [i for i, p in enumerate(prepared) if p.holdout_windows.any()]
    real_ho = [prepared[i].log for i in ho_idx]
    nominal_ho = [prepared[i].replay_log for i in ho_idx]
    gap = {
        "heldout_rms_nominal": float(np.sqrt(np.mean(z_nom**2))),
        "heldout_rms_best": float(best.heldout_rms),
        "heldout_shrink_pct_best": judgement.shrink_pct_best,
        "heldout_shrink_pct": overall_shrink(z_nom[gap_mask], z_after[gap_mask]),
        "heldout_shrink_pct_all_channels": overall_shrink(z_nom, z_after),
        "heldout_shrink_pct_best_all_channels": overall_shrink(z_nom, best.z_heldout),
        "gap_channels": sorted({str(g) for g in problem.holdout.group[gap_mask]}),
        "reference": "calibrated baseline"
        if baseline is not None and baseline.values
        else "nominal replay",
    }
    if math.isfinite(trajectory_gap(real_ho, nominal_ho)):  # a planar ground truth
        runs = {"nominal": nominal_ho}
        if baseline is not None and baseline.replays:
            runs["baseline"] = [baseline.replays[i] for i in ho_idx]
        reps_best = replays.get(best.effects)
        if reps_best is not None:
            runs["best"] = [reps_best[i] for i in ho_idx]
        elif not best.effects and "baseline" in runs:
            # an empty budget: its model is the calibrated baseline
            runs["best"] = runs["baseline"]
        for name, sims in runs.items():
            gap[f"heldout_trajectory_gap_m_{name}"] = trajectory_gap(real_ho, sims)
        nom = gap["heldout_trajectory_gap_m_nominal"]
        if "best" in runs and nom > 0:
            # whole replays: what a drift-type effect integrates into, next to the window figures
            gap["heldout_trajectory_shrink_pct_best"] = 100.0 * (
                1.0 - gap["heldout_trajectory_gap_m_best"] / nom
            )
        gap["heldout_trajectory_runs"] = trajectory_runs(real_ho, runs)
    gt_sel = problem.holdout.group == "pose_gt"
    if gt_sel.any():
        scale = scales.scale("pose_gt")[0]
        xy = gt_sel & np.isin(problem.holdout.column, ["dx", "dy"])
        gap["heldout_window_gap_m_nominal"] = float(np.sqrt(np.mean(z_nom[xy] ** 2)) * scale)
        gap["heldout_window_gap_m_best"] = float(np.sqrt(np.mean(best.z_heldout[xy] ** 2)) * scale)
    return rows, gap


def budget_replays(problem: Problem, budget: Budget, backend: Backend) -> dict[int, Log]:
    """PyBullet replays of the held-out logs with the budget's effects on the calibrated
    baseline: what its whole-run figures rest on."""
    values = {**problem.baseline_values, **budget.values}
    idx = [i for i, p in enumerate(problem.logs) if p.holdout_windows.any()]
    reps = backend.map(replay_task, [(i, values) for i in idx], problem)
    return {i: lg for i, (_, lg) in zip(idx, reps)}


def gap_words(gap: Mapping[str, Any]) -> dict[str, str]:
    """The held-out gap of each budget scale in physical units, where the logs give them
    (a planar ground truth: the whole-run trajectory gap and the 1-s window position gap)."""
    out = {}
    run = gap.get("heldout_trajectory_gap_m_baseline", gap.get("heldout_trajectory_gap_m_nominal"))
    if run is not None and math.isfinite(run):
        out["run"] = f"{100 * run:.2f} cm RMS trajectory gap of the calibrated replay"
    win = gap.get("heldout_window_gap_m_nominal")
    if win is not None and math.isfinite(win):
        out["window"] = f"{1000 * win:.1f} mm RMS per window"
    return out
