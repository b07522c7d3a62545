"""The benchmark's Markdown table and success plot."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from realitygap.baselines.benchmark.stats import extra_metrics
from realitygap.core.io import atomic_write


def _fmt(x: Any, digits: int = 2) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    return f"{x:.{digits}f}"


def _rate_cell(row: Mapping[str, Any], m: str) -> str:
    return f"{_fmt(row[f'{m}_mean'])} [{_fmt(row[f'{m}_ci_low'])}, {_fmt(row[f'{m}_ci_high'])}]"


def _pm(row: Mapping[str, Any], m: str, digits: int = 1) -> str:
    return f"{_fmt(row[f'{m}_mean'], digits)} ± {_fmt(row[f'{m}_std'], digits)}"


def markdown_report(
    summary: Sequence[Mapping[str, Any]],
    transfer: Sequence[Mapping[str, Any]],
    notes: Sequence[str] = (),
    surrogate: Sequence[Mapping[str, Any]] = (),
    mode_gap: Sequence[Mapping[str, Any]] = (),
) -> str:
    """The benchmark tables in Markdown (``surrogate``: the surrogate → PyBullet rows;
    ``mode_gap``: fast next to image mode, :func:`~realitygap.baselines.benchmark.stats.
    mode_gap_rows`)."""
    lines = [
        "# Benchmark",
        "",
        "Success: the env's default criterion (WheeledNav: within 3 cm and 5° of the goal pose, at "
        "rest). Reached: the true position came within 10 cm before any collision. Rates: mean "
        "[95 % Wilson CI]; other metrics: mean ± std over episodes (time to goal over successes).",
        "",
        "| env | mode | policy | reality | n | success | reached ≤10 cm | collision | final pos err (cm) | "
        "heading err (°) | path (m) | time to goal (s) | effort | jerk (1/s²) | compute (ms) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in summary:
        lines.append(
            f"| {r['env']} | {r['sensor_mode']} | {r['policy']} | {r['reality']} | {r['n']} | "
            f"{_rate_cell(r, 'success')} | {_rate_cell(r, 'reached_10cm')} | "
            f"{_rate_cell(r, 'collision')} | {_pm(r, 'final_pos_error_cm')} | "
            f"{_pm(r, 'final_heading_deg')} | {_pm(r, 'path_length_m', 2)} | "
            f"{_pm(r, 'time_to_goal_s')} | {_pm(r, 'effort', 3)} | {_pm(r, 'jerk', 0)} | "
            f"{_pm(r, 'compute_ms', 3)} |"
        )
    if mode_gap:
        lines += [
            "",
            "## Fast vs image mode (success; gap = fast − image, 95 % Newcombe interval)",
            "",
            "| env | policy | reality | n fast | n image | success fast | success image | "
            "gap (pp) | gap 95 % (pp) |",
            "|---|---|---|---|---|---|---|---|---|",
        ]
        for g in mode_gap:
            lines.append(
                f"| {g['env']} | {g['policy']} | {g['reality']} | {g['n_fast']} | "
                f"{g['n_image']} | {_fmt(g['success_fast'])} | {_fmt(g['success_image'])} | "
                f"{_fmt(g['gap_pp'], 1)} | [{_fmt(g['gap_ci_low_pp'], 1)}, "
                f"{_fmt(g['gap_ci_high_pp'], 1)}] |"
            )
    if transfer:
        lines += [
            "",
            "## Sim-to-real transfer (success, nominal → reality profile)",
            "",
            "| env | mode | policy | reality | n | success nominal | success reality | drop (pp) | "
            "reached nominal | reached reality | final err nominal (cm) | final err reality (cm) |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for t in transfer:
            lines.append(
                f"| {t['env']} | {t['sensor_mode']} | {t['policy']} | {t['reality']} | {t['n']} | "
                f"{_fmt(t['success_nominal'])} | {_fmt(t['success_reality'])} | "
                f"{_fmt(t['success_drop_pp'], 0)} | {_fmt(t['reached_10cm_nominal'])} | "
                f"{_fmt(t['reached_10cm_reality'])} | {_fmt(t['final_pos_error_cm_nominal'], 1)} | "
                f"{_fmt(t['final_pos_error_cm_reality'], 1)} |"
            )
    if surrogate:
        lines += [
            "",
            "## Sim-to-sim transfer (success, vectorised surrogate → PyBullet, same episodes)",
            "",
            "| env | policy | trained on | reality | n | success surrogate | success PyBullet | "
            "drop (pp) | reached surrogate | reached PyBullet | collision surrogate | "
            "collision PyBullet |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|",
        ]
        for t in surrogate:
            lines.append(
                f"| {t['env']} | {t['policy']} | {t['trained_on']} | {t['reality']} | {t['n']} | "
                f"{_fmt(t['success_surrogate'])} | {_fmt(t['success_pybullet'])} | "
                f"{_fmt(t['success_drop_pp'], 0)} | {_fmt(t['reached_10cm_surrogate'])} | "
                f"{_fmt(t['reached_10cm_pybullet'])} | {_fmt(t['collision_surrogate'])} | "
                f"{_fmt(t['collision_pybullet'])} |"
            )
    extra_rows = [
        (r, extra_metrics(r["env_id"])) for r in summary if extra_metrics(r.get("env_id", ""))
    ]
    if extra_rows:
        lines += ["", "## Env-specific metrics (final info, mean ± std)", ""]
        lines += ["| env | mode | policy | reality | n | metrics |", "|---|---|---|---|---|---|"]
        for r, keys in extra_rows:
            cells = ", ".join(f"{k} {_pm(r, k, 3)}" for k in keys)
            lines.append(
                f"| {r['env']} | {r['sensor_mode']} | {r['policy']} | {r['reality']} | {r['n']} "
                f"| {cells} |"
            )
    if notes:
        lines += ["", "## Notes", ""] + [f"- {n}" for n in notes]
    return "\n".join(lines) + "\n"


def plot_success(summary: Sequence[Mapping[str, Any]], out: str | os.PathLike[str]) -> Path | None:
    """Bar charts of strict success and reached-within-10-cm per policy, nominal vs reality,
    with 95 % CI whiskers; ``None`` when matplotlib is missing."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None

    panels = sorted(
        {(r["env"], r["sensor_mode"]) for r in summary}, key=lambda k: (k[0], k[1] != "fast")
    )
    if not panels:
        return None
    fig, axes = plt.subplots(len(panels), 2, figsize=(11, 3.2 * len(panels)), squeeze=False)
    for row_i, (env, mode) in enumerate(panels):
        rows = [r for r in summary if r["env"] == env and r["sensor_mode"] == mode]
        policies = list(dict.fromkeys(r["policy"] for r in rows))
        realities = list(dict.fromkeys(r["reality"] for r in rows))
        width = 0.8 / max(len(realities), 1)
        for col, metric in enumerate(("success", "reached_10cm")):
            ax = axes[row_i][col]
            for j, reality in enumerate(realities):
                vals, lo, hi = [], [], []
                for p in policies:
                    match = [r for r in rows if r["policy"] == p and r["reality"] == reality]
                    r = match[0] if match else None
                    v = r[f"{metric}_mean"] if r else math.nan
                    vals.append(v)
                    lo.append(v - r[f"{metric}_ci_low"] if r else 0.0)
                    hi.append(r[f"{metric}_ci_high"] - v if r else 0.0)
                x = np.arange(len(policies)) + (j - (len(realities) - 1) / 2) * width
                ax.bar(x, vals, width, yerr=[lo, hi], capsize=3, label=reality)
            ax.set_xticks(np.arange(len(policies)), policies)
            ax.set_ylim(0, 1.05)
            title = "strict success" if metric == "success" else "reached ≤ 10 cm"
            ax.set_title(f"{env} ({mode} sensors): {title}", fontsize=9)
            ax.legend(fontsize=7)
    fig.tight_layout()
    try:
        return atomic_write(out, lambda fh: fig.savefig(fh, dpi=110, format="png"))
    finally:
        plt.close(fig)
