"""How far a gap shrinks: held-out residuals before and after adding the chosen effects.

Both residuals come from PyBullet replays of the held-out logs — the nominal
robot before, the nominal robot plus the fitted effects after — compared
window by window with the real logs. :func:`shrink_table` reports them per
channel, column and motion regime, in SI units and in per cent;
:func:`trajectory_gap` the absolute position error of whole replays (cm).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.attribute import Layout
from realitygap.diagnosis.features import FeatureSettings
from realitygap.diagnosis.log import Log

FloatArray = npt.NDArray[np.float64]

__all__ = ["overall_shrink", "shrink_table", "trajectory_gap"]


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


def trajectory_gap(real: Sequence[Log], simulated: Sequence[Log]) -> float:
    """RMS distance (m) between real and simulated ground-truth positions over all samples."""
    sq, n = 0.0, 0
    for r, s in zip(real, simulated):
        if not (r.has("pose_gt") and s.has("pose_gt")):
            continue
        d = r["pose_gt"][:, :2] - s["pose_gt"][:, :2]
        sq += float(np.sum(d**2))
        n += d.shape[0]
    return float(np.sqrt(sq / n)) if n else float("nan")
