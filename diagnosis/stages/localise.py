"""Localise a gap: residuals per channel, per motion regime and per pipeline stage.

Residuals are window features of the real log minus those of the nominal
replay (see :mod:`realitygap.diagnosis.problem.features`), plus three stage residuals
computed inside the real log: *command → motion* (ground truth against the
replay of the commands), *motion → sensor* (encoder travel against the
ground-truth motion, through the nominal geometry) and *sensor → estimate*
(the robot's estimate against nominal odometry of its own ticks).

:func:`localise` returns a table ranked by each cell's share of the total
normalised squared residual: the first rows say where the gap is.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.adapters.contract import PreparedLog, RobotAdapter
from realitygap.diagnosis.problem.features import FeatureSettings

FloatArray = npt.NDArray[np.float64]

__all__ = ["localise"]


def _rows_for(
    where: str,
    kind: str,
    values: list[FloatArray],
    regimes: list[list[str]],
    columns: Sequence[str],
    units: Sequence[str],
    scale: FloatArray,
    regime_names: Sequence[str],
) -> list[dict[str, Any]]:
    rows = []
    stacked = np.concatenate(values, axis=0) if values else np.zeros((0, len(columns)))
    labels = np.concatenate([np.asarray(r, dtype=str) for r in regimes]) if regimes else np.zeros(0)
    for regime in ("all", *regime_names):
        sel = np.ones(stacked.shape[0], bool) if regime == "all" else labels == regime
        if sel.sum() == 0:
            continue
        block = stacked[sel]
        for j, c in enumerate(columns):
            v = block[:, j]
            rows.append(
                {
                    "kind": kind,
                    "where": where,
                    "column": c,
                    "regime": regime,
                    "n_windows": int(sel.sum()),
                    "rms": float(np.sqrt(np.mean(v**2))),
                    "mean": float(np.mean(v)),
                    "unit": units[j],
                    "normalised_ss": float(np.sum((v / scale[j]) ** 2)),
                }
            )
    return rows


def localise(
    prepared: Sequence[PreparedLog], adapter: RobotAdapter, scales: FeatureSettings
) -> dict[str, Any]:
    """Where the nominal replay departs from the real logs.

    Parameters
    ----------
    prepared : sequence of PreparedLog
        All logs (training and held-out).
    adapter : RobotAdapter
    scales : FeatureSettings

    Returns
    -------
    dict
        ``table`` — rows ``{kind: "channel" | "stage", where, column, regime,
        n_windows, rms, mean, unit, share}`` for each regime, ranked by
        ``share`` of the normalised squared residual among the per-regime
        rows; ``overall`` — the ``regime == "all"`` rows; ``regime_counts``.
    """
    rows: list[dict[str, Any]] = []
    schema = adapter.schema
    for group in schema.groups:
        g = group.name
        vals, regs = [], []
        for p in prepared:
            if g in p.groups:
                vals.append(p.real[g] - p.nominal[g])
                regs.append(p.regimes)
        if vals:
            rows += _rows_for(
                g,
                "channel",
                vals,
                regs,
                group.columns,
                group.units,
                scales.scale(g),
                schema.regimes,
            )
    stages: dict[str, tuple[list[FloatArray], list[list[str]]]] = {}
    for p in prepared:
        for name, res in adapter.stage_residuals(p).items():
            stages.setdefault(name, ([], []))
            stages[name][0].append(res)
            stages[name][1].append(p.regimes)
    if stages:
        # stage residuals are in the columns and units of the adapter's stage group
        sg = schema.group(adapter.stage_group)
        for name, (vals, regs) in stages.items():
            rows += _rows_for(
                name,
                "stage",
                vals,
                regs,
                sg.columns,
                sg.units,
                scales.scale(sg.name),
                schema.regimes,
            )
    for kind in ("channel", "stage"):
        total = sum(r["normalised_ss"] for r in rows if r["kind"] == kind and r["regime"] != "all")
        for r in rows:
            if r["kind"] == kind:
                r["share"] = r["normalised_ss"] / total if total > 0 else 0.0
    per_regime = [r for r in rows if r["regime"] != "all"]
    per_regime.sort(key=lambda r: (r["kind"] != "channel", -r["share"]))
    counts: dict[str, int] = {}
    for p in prepared:
        for r in p.regimes:
            counts[r] = counts.get(r, 0) + 1
    return {
        "table": per_regime,
        "overall": [r for r in rows if r["regime"] == "all"],
        "regime_counts": counts,
    }
