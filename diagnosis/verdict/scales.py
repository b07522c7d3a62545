"""The two-scale test: a model the 1-s windows fail only on their shrink, named on whole runs.

The method is that of :mod:`realitygap.diagnosis.stages.scales`, which measures the figures
(:func:`~realitygap.diagnosis.stages.scales.whole_run_figures`). Here the draft is revisited:
:func:`revisits_on_whole_runs` says whether a judgement qualifies (an ``"unexplained"`` draft
whose only failed test was the window shrink), :func:`judge_scales` applies the three
tests to the figures and returns a judgement whose draft names the model on whole runs,
with both figures in its reason — or the judgement as it was, with the tests that failed.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from realitygap.diagnosis.adapters.contract import Drive
from realitygap.diagnosis.fit.status import pinned_parameters
from realitygap.diagnosis.problem.problem import Problem
from realitygap.diagnosis.stages.scales import ScaleFigures, ScaleSettings
from realitygap.diagnosis.verdict.judge import confidence_of
from realitygap.diagnosis.verdict.types import Draft, Judgement, VerdictKind, WholeRuns

__all__ = ["judge_scales", "revisits_on_whole_runs"]


def revisits_on_whole_runs(problem: Problem, judgement: Judgement) -> bool:
    """Whether ``judgement`` failed only on the window shrink: an ``"unexplained"`` draft
    whose best model is not the reference, closes less than
    :attr:`AttributionSettings.min_shrink` of the held-out windows' gap and sits at no
    edge of its range (the held-out tests run in that order)."""
    best = judgement.best
    return (
        judgement.kind is VerdictKind.UNEXPLAINED
        and bool(best.effects)
        and judgement.shrink_pct_best < 100.0 * problem.settings.min_shrink
        and not pinned_parameters(problem, best)
    )


def judge_scales(
    problem: Problem,
    judgement: Judgement,
    figures: ScaleFigures,
    settings: ScaleSettings,
) -> tuple[Judgement, dict[str, Any]]:
    """Revisit a judgement that failed only on the window shrink
    (:func:`revisits_on_whole_runs`) with its best model's whole-run ``figures``.

    Returns
    -------
    judgement : Judgement
        The same judgement, or one whose draft names ``best.effects`` on whole runs (reason
        with both figures, :class:`~realitygap.diagnosis.verdict.types.WholeRuns` noted).
    figures : dict
        What was measured (``verdict_scales`` of the diagnosis JSON): the figures, the
        ``remainder`` the model leaves in the windows, ``named`` and, when not named,
        ``why_not`` (the tests that failed).
    """
    st = problem.settings
    best, draft = judgement.best, judgement.draft
    # what the best model leaves on the held-out windows: the draft already described it
    rest_desc = draft.residual
    out: dict[str, Any] = {
        **figures.to_json(),
        "remainder": rest_desc["reasons"],
        "named": False,
    }
    worst = figures.run_bias_worst
    gain, run_shrink = figures.window_gain, figures.run_shrink_pct
    better, n_runs = figures.runs_improved, len(figures.runs)
    p_family = figures.run_bias_p_family
    drift_msg = (
        f"what it leaves still adds up along held-out run "
        f"{worst['log']} ({worst['group']} {worst['column']}: mean window "
        f"residual {figures.run_bias_max_se:.1f} standard errors from zero over "
        f"{worst['windows']} windows, p = {p_family:.2g} over {figures.run_bias_tests} runs "
        f"and columns, against {settings.run_bias_alpha:g}): a second mechanism that drifts"
        if worst is not None
        else ""
    )
    checks = [
        (
            f"the windows do not improve beyond the margin ({gain:.1f} < {st.margin_strong:g})",
            gain >= st.margin_strong,
        ),
        (
            f"the whole-run gap shrinks only {run_shrink:.0f} % "
            f"(needs {100 * st.min_shrink:.0f} %)",
            run_shrink >= 100.0 * st.min_shrink,
        ),
        (f"only {better} of {n_runs} held-out runs improve", figures.consistent),
        (drift_msg, p_family >= settings.run_bias_alpha),
    ]
    failed = [msg for msg, ok in checks if not ok]
    if failed:
        out["why_not"] = failed
        return judgement, out
    out["named"] = True
    share, null = figures.timing_share_pct, figures.timing_share_pct_permuted_max
    if figures.clock_like:
        p5, p95 = figures.window_offsets_ms_p5_p95
        timing_words = (
            f"one clock offset per window (5–95 %: {p5:+.0f} … {p95:+.0f} ms) explains "
            f"{share:.0f} % of it (permuted signatures: at most {null:.0f} %), as a clock "
            "wandering between the channels would"
        )
        if problem.drive is Drive.COMMANDS:
            timing_words += (
                " (or the drive train's response to the commands, which moves windows in time "
                "alike)"
            )
    else:
        timing_words = (
            f"one clock offset per window explains only {share:.0f} % of it (permuted "
            f"signatures: up to {null:.0f} %), so it is not a clock's alone"
        )
    rest_words = (
        "is not explained: " + "; ".join(rest_desc["reasons"][:3])
        if rest_desc["structured"]
        else "looks like noise at that scale"
    )
    nom, aft = figures.run_gap_m_nominal, figures.run_gap_m_best
    reason = (
        f"{best.name} closes {run_shrink:.0f} % of the held-out whole-run trajectory gap "
        f"({100 * nom:.2f} → {100 * aft:.2f} cm, {better} of {n_runs} runs better) but only "
        f"{figures.window_shrink_pct:.0f} % at the 1-s window scale; what it leaves there does "
        f"not add up along the runs (no run's mean window residual is away from zero: p = "
        f"{p_family:.2g} over {figures.run_bias_tests} runs and columns) and {rest_words}; "
        f"{timing_words}"
    )
    named = Draft(
        VerdictKind.EFFECTS,
        best.effects,
        reason,
        draft.margin,
        confidence_of(draft.margin, st),
        rest_desc,
        training_only=draft.training_only,
        whole_runs=WholeRuns(
            run_shrink_pct=run_shrink,
            window_shrink_pct=figures.window_shrink_pct,
            remainder=tuple(rest_desc["reasons"]) if rest_desc["structured"] else (),
            clock_like=figures.clock_like,
            timing_share_pct=share,
        ),
    )
    return replace(judgement, draft=named), out
