"""How far a gap shrinks: held-out residuals before and after adding the chosen effects.

Both residuals come from PyBullet replays of the held-out logs — the nominal
robot before, the nominal robot plus the fitted effects after — compared
window by window with the real logs. :func:`shrink_table` reports them per
channel, column and motion regime, in SI units and in per cent;
:func:`trajectory_gap` the absolute position error of whole replays (cm), and
:func:`trajectory_runs` the same per run, with the run's share of the whole.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.features import FeatureSettings
from realitygap.diagnosis.problem.problem import Layout

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "concentrated_gap",
    "overall_shrink",
    "shrink_table",
    "trajectory_gap",
    "trajectory_runs",
]


def overall_shrink(before: FloatArray, after: FloatArray) -> float:
    """``100 (1 − RMS(after) / RMS(before))`` of normalised residuals, %."""
    rb = float(np.sqrt(np.mean(np.asarray(before) ** 2))) if np.size(before) else 0.0
    ra = float(np.sqrt(np.mean(np.asarray(after) ** 2))) if np.size(after) else 0.0
    return 100.0 * (1.0 - ra / rb) if rb > 0 else 0.0


def shrink_table(
    before: FloatArray, after: FloatArray, layout: Layout, scales: FeatureSettings
) -> list[dict[str, Any]]:
    """Rows ``{group, column, regime, unit, n, rms_before, rms_after, shrink_pct}`` (SI units).

    ``before`` and ``after`` are normalised held-out residual vectors laid out
    by ``layout``; ``regime == "all"`` rows summarise each column and
    ``column == "all"`` rows each group (normalised RMS, unit ``"1"``).
    """
    rows: list[dict[str, Any]] = []
    schema = layout.schema
    for group in schema.groups:
        g, cols = group.name, group.columns
        gsel = layout.group == g
        if not gsel.any():
            continue
        scale = scales.scale(g)
        for regime in ("all", *schema.regimes):
            rsel = gsel if regime == "all" else gsel & (layout.regime == regime)
            if not rsel.any():
                continue
            for j, c in enumerate(cols):
                sel = rsel & (layout.column == c)
                if not sel.any():
                    continue
                rb = float(np.sqrt(np.mean(before[sel] ** 2)) * scale[j])
                ra = float(np.sqrt(np.mean(after[sel] ** 2)) * scale[j])
                rows.append(
                    {
                        "group": g,
                        "column": c,
                        "regime": regime,
                        "unit": group.units[j],
                        "n": int(sel.sum()),
                        "rms_before": rb,
                        "rms_after": ra,
                        "shrink_pct": 100.0 * (1.0 - ra / rb) if rb > 0 else 0.0,
                    }
                )
        rows.append(
            {
                "group": g,
                "column": "all",
                "regime": "all",
                "unit": "1",
                "n": int(gsel.sum()),
                "rms_before": float(np.sqrt(np.mean(before[gsel] ** 2))),
                "rms_after": float(np.sqrt(np.mean(after[gsel] ** 2))),
                "shrink_pct": overall_shrink(before[gsel], after[gsel]),
            }
        )
    return rows


def _squared_gaps(real: Sequence[Log], simulated: Sequence[Log]) -> list[tuple[float, int]]:
    """Per pair of logs, the summed squared position error (m²) and its sample count
    (``(0, 0)`` where either lacks a ground truth)."""
    out = []
    for r, s in zip(real, simulated):
        if not (r.has("pose_gt") and s.has("pose_gt")):
            out.append((0.0, 0))
            continue
        d = r["pose_gt"][:, :2] - s["pose_gt"][:, :2]
        out.append((float(np.sum(d**2)), int(d.shape[0])))
    return out


def trajectory_gap(real: Sequence[Log], simulated: Sequence[Log]) -> float:
    """RMS distance (m) between real and simulated ground-truth positions over all samples."""
    parts = _squared_gaps(real, simulated)
    sq, n = sum(p[0] for p in parts), sum(p[1] for p in parts)
    return float(np.sqrt(sq / n)) if n else float("nan")


def trajectory_runs(real: Sequence[Log], replays: dict[str, Sequence[Log]]) -> list[dict[str, Any]]:
    """The trajectory gap run by run.

    Parameters
    ----------
    real : sequence of Log
        The real runs.
    replays : dict of str to sequence of Log
        Replays of the same runs, by what drove them (e.g. ``"nominal"``, ``"best"``);
        the first entry is the one the shares are taken of.

    Returns
    -------
    list of dict
        Per run with a ground truth: ``log``, ``samples``, ``<name>_m`` (its RMS
        position error, m, per replay) and ``share_pct``, the run's part of the summed
        squared error of the first replay — what it weighs in :func:`trajectory_gap`.
    """
    if not replays:
        raise ValueError("trajectory_runs: replays must name at least one replay of the runs")
    names = list(replays)
    parts = {k: _squared_gaps(real, v) for k, v in replays.items()}
    total = sum(sq for sq, _ in parts[names[0]])
    rows = []
    for i, r in enumerate(real):
        n = parts[names[0]][i][1]
        if n == 0:
            continue
        row: dict[str, Any] = {"log": r.name, "samples": n}
        for k in names:
            sq, m = parts[k][i]
            row[f"{k}_m"] = float(np.sqrt(sq / m)) if m else float("nan")
        row["share_pct"] = 100.0 * parts[names[0]][i][0] / total if total > 0 else 0.0
        rows.append(row)
    return rows


def concentrated_gap(
    rows: Sequence[dict[str, Any]],
    share_pct: float = 50.0,
    before: str = "nominal",
    after: str = "best",
) -> dict[str, Any] | None:
    """Whether one run carries most of a pooled trajectory gap, and the gap without it.

    A whole-run RMS pools squared errors, so one long run that drifts far
    (an open-loop replay of a fast run, say) can outweigh every other; the
    pooled figure is then that run's. Returns ``None`` with fewer than three runs
    or when no run's share (of :func:`trajectory_runs`) reaches ``share_pct``;
    else ``log``, ``share_pct``, its own ``before_m`` / ``after_m``, and the
    other runs' pooled ``rest_before_m`` / ``rest_after_m`` and ``runs``.
    """
    if not 0.0 < share_pct < 100.0:
        raise ValueError(f"concentrated_gap: share_pct must lie in (0, 100), got {share_pct!r}")
    if len(rows) < 3:
        return None
    top = max(rows, key=lambda r: r["share_pct"])
    if top["share_pct"] < share_pct:
        return None
    rest = [r for r in rows if r is not top]

    def pooled(key: str) -> float:
        n = sum(r["samples"] for r in rest)
        return float(np.sqrt(sum(r["samples"] * r[key] ** 2 for r in rest) / n))

    out = {
        "log": top["log"],
        "share_pct": float(top["share_pct"]),
        "before_m": float(top[f"{before}_m"]),
        "rest_before_m": pooled(f"{before}_m"),
        "runs": len(rest),
    }
    if f"{after}_m" in top:
        out["after_m"] = float(top[f"{after}_m"])
        out["rest_after_m"] = pooled(f"{after}_m")
    return out
