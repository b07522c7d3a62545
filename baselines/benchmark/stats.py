"""Benchmark metrics, confidence intervals and the per-cell summary."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.baselines.benchmark.policies import POLICY_KINDS
from realitygap.baselines.rl import (
    env_slug,
)
from realitygap.cards import ENV_CARDS

METRICS: tuple[str, ...] = (
    "success",
    "reached_10cm",
    "final_pos_error_cm",
    "final_heading_deg",
    "path_length_m",
    "time_to_goal_s",
    "collision",
    "effort",
    "jerk",
    "compute_ms",
    "steps",
    "return",
)
RATE_METRICS = frozenset({"success", "reached_10cm", "collision"})
REACHED_RADIUS = 0.10
"""Radius (m) of the looser "reached" figure."""


# --------------------------------------------------------------------------- statistics
def t_interval(
    values: npt.ArrayLike, confidence: float = 0.95
) -> tuple[float, float, float, float]:
    r"""Mean, sample standard deviation and Student-t confidence interval of the mean.

    .. math:: \bar x \pm t_{1-\alpha/2,\,n-1}\, s / \sqrt{n}

    Returns ``(mean, std, low, high)``; NaN where undefined (no values, or ``n = 1`` for
    the spread). NaN values are ignored.
    """
    from scipy import stats

    x = np.asarray(values, dtype=float).reshape(-1)
    x = x[np.isfinite(x)]
    n = len(x)
    if n == 0:
        return (math.nan, math.nan, math.nan, math.nan)
    mean = float(np.mean(x))
    if n == 1:
        return (mean, math.nan, math.nan, math.nan)
    std = float(np.std(x, ddof=1))
    half = float(stats.t.ppf(0.5 + confidence / 2.0, n - 1)) * std / math.sqrt(n)
    return (mean, std, mean - half, mean + half)


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    r"""Wilson score interval of a rate ``successes / n``.

    .. math::

        \frac{\hat p + z^2/2n \pm z\sqrt{\hat p(1-\hat p)/n + z^2/4n^2}}{1 + z^2/n}
    """
    from scipy import stats

    if n <= 0:
        return (math.nan, math.nan)
    if not 0 <= successes <= n:
        raise ValueError(f"successes must be in [0, n={n}], got {successes}")
    z = float(stats.norm.ppf(0.5 + confidence / 2.0))
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    low = 0.0 if successes == 0 else max(0.0, centre - half)
    high = 1.0 if successes == n else min(1.0, centre + half)
    return (low, high)


def difference_interval(
    k1: int, n1: int, k2: int, n2: int, confidence: float = 0.95
) -> tuple[float, float]:
    r"""Interval of the difference of two rates ``k1/n1 − k2/n2`` (Newcombe's hybrid score
    interval, his method 10, from the two :func:`wilson_interval`\ s ``(l_i, u_i)``):

    .. math::

        \hat d - \sqrt{(\hat p_1 - l_1)^2 + (u_2 - \hat p_2)^2}, \qquad
        \hat d + \sqrt{(u_1 - \hat p_1)^2 + (\hat p_2 - l_2)^2}.

    It keeps its coverage near rates of 0 and 1, where the normal approximation's collapses.
    """
    if n1 <= 0 or n2 <= 0:
        return (math.nan, math.nan)
    p1, p2 = k1 / n1, k2 / n2
    l1, u1 = wilson_interval(k1, n1, confidence)
    l2, u2 = wilson_interval(k2, n2, confidence)
    d = p1 - p2
    return (
        d - math.sqrt((p1 - l1) ** 2 + (u2 - p2) ** 2),
        d + math.sqrt((u1 - p1) ** 2 + (p2 - l2) ** 2),
    )


def extra_metrics(env_id: str) -> tuple[str, ...]:
    """The env's own metrics (:attr:`~realitygap.cards.EnvCard.metrics`); none for an unknown id."""
    card = ENV_CARDS.get(env_id)
    return card.metrics if card is not None else ()


def record_key(rec: Mapping[str, Any]) -> tuple[str, str, str, str, int]:
    return (rec["env_id"], rec["policy"], rec["reality"], rec["sensor_mode"], int(rec["seed"]))


# --------------------------------------------------------------------------- aggregation
def summarise(
    records: Sequence[Mapping[str, Any]], confidence: float = 0.95
) -> list[dict[str, Any]]:
    """One row per (env, policy, reality, sensor mode): mean, std and CI of every metric."""
    groups: dict[tuple[str, str, str, str], list[Mapping[str, Any]]] = {}
    for rec in records:
        groups.setdefault(record_key(rec)[:4], []).append(rec)
    rows = []
    for (env_id, policy, reality, mode), recs in groups.items():
        recs = sorted(recs, key=lambda r: int(r["seed"]))
        row: dict[str, Any] = {
            "env": env_slug(env_id),
            "env_id": env_id,
            "policy": policy,
            "reality": reality,
            "sensor_mode": mode,
            "n": len(recs),
            "errors": sum(1 for r in recs if r.get("error")),
        }
        extra = extra_metrics(env_id)
        for m in (*METRICS, *extra):
            if m == "time_to_goal_s":
                vals = [float(r[m]) for r in recs if r.get("success")]
            else:
                vals = [float(r[m]) if r.get(m) is not None else math.nan for r in recs]
            mean, std, lo, hi = t_interval(vals, confidence)
            if m in RATE_METRICS:
                finite = [v for v in vals if math.isfinite(v)]
                k = int(sum(1 for v in finite if v > 0.5))
                lo, hi = wilson_interval(k, len(finite), confidence)
            row[f"{m}_mean"], row[f"{m}_std"] = mean, std
            row[f"{m}_ci_low"], row[f"{m}_ci_high"] = lo, hi
        rows.append(row)
    order = {p: i for i, p in enumerate(POLICY_KINDS)}
    rows.sort(
        key=lambda r: (
            r["env"],
            r["sensor_mode"] != "fast",
            order.get(r["policy"], 99),
            r["policy"],
            r["reality"] != "nominal",
            r["reality"],
        )
    )
    return rows


def transfer_rows(summary: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Success under each reality profile next to nominal, per env, policy and sensor mode."""
    nominal = {
        (r["env"], r["policy"], r["sensor_mode"]): r for r in summary if r["reality"] == "nominal"
    }
    out = []
    for r in summary:
        if r["reality"] == "nominal":
            continue
        base = nominal.get((r["env"], r["policy"], r["sensor_mode"]))
        if base is None:
            continue
        out.append(
            {
                "env": r["env"],
                "policy": r["policy"],
                "sensor_mode": r["sensor_mode"],
                "reality": r["reality"],
                "n": r["n"],
                "success_nominal": base["success_mean"],
                "success_reality": r["success_mean"],
                "success_drop_pp": 100.0 * (base["success_mean"] - r["success_mean"]),
                "reached_10cm_nominal": base["reached_10cm_mean"],
                "reached_10cm_reality": r["reached_10cm_mean"],
                "final_pos_error_cm_nominal": base["final_pos_error_cm_mean"],
                "final_pos_error_cm_reality": r["final_pos_error_cm_mean"],
            }
        )
    return out


def mode_gap_rows(
    summary: Sequence[Mapping[str, Any]], confidence: float = 0.95
) -> list[dict[str, Any]]:
    """Success in fast mode next to image mode, per env, policy and reality, with the
    gap's interval (:func:`difference_interval`): what rendering the sensors costs."""
    cells: dict[tuple[str, str, str], dict[str, Mapping[str, Any]]] = {}
    for r in summary:
        cells.setdefault((r["env"], r["policy"], r["reality"]), {})[r["sensor_mode"]] = r
    out = []
    for (env, policy, reality), modes in cells.items():
        if "fast" not in modes or "image" not in modes:
            continue
        fast, image = modes["fast"], modes["image"]
        kf = int(round(float(fast["success_mean"]) * int(fast["n"])))
        ki = int(round(float(image["success_mean"]) * int(image["n"])))
        lo, hi = difference_interval(kf, int(fast["n"]), ki, int(image["n"]), confidence)
        out.append(
            {
                "env": env,
                "policy": policy,
                "reality": reality,
                "n_fast": int(fast["n"]),
                "n_image": int(image["n"]),
                "success_fast": kf / int(fast["n"]),
                "success_image": ki / int(image["n"]),
                "gap_pp": 100.0 * (kf / int(fast["n"]) - ki / int(image["n"])),
                "gap_ci_low_pp": 100.0 * lo,
                "gap_ci_high_pp": 100.0 * hi,
            }
        )
    return out
