"""Does a residual still have structure, and what does it look like?

:func:`describe_residual` is the structured-residual test of the verdict: a
group's residual is structured when it is much larger than its noise level,
concentrates in one column or motion regime, or follows the commanded motion
(:data:`~realitygap.diagnosis.problem.problem.MOTION_COLUMNS`). The noise level is
the robust (MAD-based) window-to-window level :func:`white_level` of each
column — combined over a group's columns by :func:`mixture_level`, and each
column's own for the standard error of its mean — or the measurement noise an
adapter states; a regime's concentration is judged
against the larger of the column's level and the regime's own
window-to-window level, so a regime that only scatters more is not taken for
structure, while a residual that stays put from window to window is.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from realitygap.diagnosis.problem.features import FeatureSettings
    from realitygap.diagnosis.problem.problem import AttributionSettings, Layout

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "column_levels",
    "describe_residual",
    "mixture_level",
    "robust_spread",
    "shrink_above_noise",
    "white_level",
]

_MAD_TO_SD = 1.4826
"""Ratio of a normal distribution's standard deviation to its median absolute deviation."""


def robust_spread(x: FloatArray, axis: int | None = None) -> tuple[Any, Any]:
    """Median of ``x`` and its normal-consistent spread ``1.4826 · MAD``, ignoring NaNs.

    Over all of ``x`` (floats) or along ``axis`` (arrays).
    """
    med = np.nanmedian(x, axis=axis)
    return med, _MAD_TO_SD * np.nanmedian(np.abs(x - med), axis=axis)


def white_level(z: FloatArray, layout: Layout, sel: npt.NDArray[np.bool_]) -> float:
    """Noise level of a residual group: robust spread of its window-to-window differences.

    ``1.4826 · MAD(Δz) / √2`` over consecutive windows of each log and column,
    so that a few large structured windows (starts, stops, slow legs) do not
    pass for noise.
    """
    diffs = []
    for col in np.unique(layout.column[sel]):
        for lg in np.unique(layout.log[sel]):
            m = sel & (layout.column == col) & (layout.log == lg)
            v = z[m]
            if v.size >= 2:
                diffs.append(np.diff(v))
    if not diffs:
        return 0.0
    _, spread = robust_spread(np.concatenate(diffs))
    return float(spread) / math.sqrt(2.0)


def column_levels(z: FloatArray, layout: Layout, sel: npt.NDArray[np.bool_]) -> dict[Any, float]:
    """:func:`white_level` of each column of ``sel`` on its own."""
    return {
        c: white_level(z, layout, sel & (layout.column == c)) for c in np.unique(layout.column[sel])
    }


def mixture_level(layout: Layout, sel: npt.NDArray[np.bool_], levels: Mapping[Any, float]) -> float:
    r"""Noise level of a selection that spans columns, to compare with its RMS.

    Each column keeps its own noise level :math:`σ_c` (``levels``, e.g.
    :func:`column_levels`), combined as pure noise would combine in an RMS over
    the selection's :math:`n_c` entries per column:

    .. math::  σ = \sqrt{\textstyle\sum_c n_c σ_c^2 / \sum_c n_c}.

    The columns of one group come from different sensors or axes (a motion-capture
    heading is several times noisier, in feature-scale units, than its position);
    one robust level pooled over them (:func:`white_level` of the whole selection)
    sits near the quieter columns', and the noisier column's noise would pass for
    structure.
    """
    num, den = 0.0, 0
    for c in np.unique(layout.column[sel]):
        n = int(np.count_nonzero(sel & (layout.column == c)))
        num += n * float(levels[c]) ** 2
        den += n
    return math.sqrt(num / den) if den else 0.0


SAMPLE_NOISE_TOLERANCE = 1.25
"""How far (as a factor) the noise a sensor's samples show may miss the noise of a window
feature: samples not quite independent, motion left in the differences."""


def shrink_above_noise(
    before: FloatArray,
    after: FloatArray,
    layout: Layout,
    mask: npt.NDArray[np.bool_],
    noise: Mapping[str, float] | None = None,
) -> float:
    """Share of the held-out gap *above the noise floor* that a model closes, %.

    The raw shrink ``1 − RMS(after) / RMS(before)`` counts the measurement
    noise as part of the gap, and no effect can close it: a small true effect
    whose gap is comparable with the noise can never close half of it. Here
    each channel's mean square is reduced by its noise variance first::

        gap² = Σ_c n_c · max(mean(z_c²) − σ_c², 0)
        shrink = 100 · (1 − gap_after / gap_before)

    with σ_c the noise the adapter states for the channel's group, else the
    smaller of the two residuals' window-to-window levels (:func:`white_level`)
    in that column, which is the noise wherever an effect drifts slowly from
    window to window. The level is taken per column, not per group: the columns
    of one group come from different sensors or axes (a motion-capture heading
    is noisier, in feature-scale units, than its position), and a pooled level
    would count the noisier column's noise as gap. Entries outside ``mask`` are
    ignored. When the nominal residual is itself at the noise level (no gap
    above it), the raw shrink is returned.

    Parameters
    ----------
    before, after : ndarray, shape (n,)
        Normalised held-out residuals of the nominal replay and of the model.
    layout : Layout
        Where each entry comes from.
    mask : ndarray of bool, shape (n,)
        Entries of the channels where the gap lives.
    noise : mapping of group to float, optional
        Measurement noise the adapter states (feature-scale units).

    Returns
    -------
    float
        Shrink of the gap above noise, % (may be negative when the model is worse).
    """
    before = np.asarray(before, dtype=float)
    after = np.asarray(after, dtype=float)
    if before.shape != after.shape or before.shape != mask.shape:
        raise ValueError(
            f"shrink_above_noise: residuals and mask must have one shape, got {before.shape}, "
            f"{after.shape} and {mask.shape}; pass residuals laid out by the same layout"
        )
    gap_b = gap_a = 0.0
    for g in np.unique(layout.group[mask]):
        in_group = mask & (layout.group == g)
        stated = float(noise[g]) if noise is not None and g in noise else None
        for col in np.unique(layout.column[in_group]):
            sel = in_group & (layout.column == col)
            sigma = (
                stated
                if stated is not None
                else min(white_level(before, layout, sel), white_level(after, layout, sel))
            )
            n = int(sel.sum())
            gap_b += n * max(float(np.mean(before[sel] ** 2)) - sigma**2, 0.0)
            gap_a += n * max(float(np.mean(after[sel] ** 2)) - sigma**2, 0.0)
    if gap_b <= 0.0:
        rb = float(np.sqrt(np.mean(before[mask] ** 2))) if mask.any() else 0.0
        ra = float(np.sqrt(np.mean(after[mask] ** 2))) if mask.any() else 0.0
        return 100.0 * (1.0 - ra / rb) if rb > 0 else 0.0
    return 100.0 * (1.0 - math.sqrt(gap_a / gap_b))


_BLOCK = 4
"""Consecutive windows summed by the boundary-error test of :func:`describe_residual`."""

_ANTI_LAG1 = -0.3
"""Lag-1 autocorrelation at or below which adjacent windows are taken to cancel."""


def _lag1(z: FloatArray, layout: Layout, sel: npt.NDArray[np.bool_]) -> float:
    """Lag-1 autocorrelation of ``z[sel]`` within logs and columns (uncentred)."""
    num = den = 0.0
    for c in np.unique(layout.column[sel]):
        for lg in np.unique(layout.log[sel]):
            v = z[sel & (layout.column == c) & (layout.log == lg)]
            if v.size >= 3:
                num += float(np.sum(v[1:] * v[:-1]))
                den += float(np.sum(v * v))
    return num / den if den > 0 else 0.0


def _boundary_error(
    z: FloatArray, layout: Layout, sel: npt.NDArray[np.bool_], level: float, limit: float
) -> float | None:
    """The block ratio (:func:`_block_excess`) when the residual of ``sel`` is an error at
    the window boundaries — adjacent windows cancel (lag-1 autocorrelation at most
    ``_ANTI_LAG1``) and sums over a few windows stay within ``limit`` noise levels — else
    None."""
    if _lag1(z, layout, sel) > _ANTI_LAG1:
        return None
    block = _block_excess(z, layout, sel, level)
    return block if block <= limit else None


def _block_excess(z: FloatArray, layout: Layout, sel: npt.NDArray[np.bool_], level: float) -> float:
    """RMS of sums of ``_BLOCK`` consecutive windows, over ``√_BLOCK · level``.

    White noise keeps its ratio; an effect that drifts slowly from window to
    window grows by up to ``√_BLOCK``; an error made at the window boundaries
    (a mis-stamped sample moves displacement from one window into the next:
    ``e_k = b_{k+1} − b_k``) telescopes, and its sums stay at the size of one
    boundary error.
    """
    sums = []
    for col in np.unique(layout.column[sel]):
        for lg in np.unique(layout.log[sel]):
            m = sel & (layout.column == col) & (layout.log == lg)
            v, w = z[m], np.asarray(layout.window)[m]
            # runs of consecutive windows only: a held-out split need not be contiguous
            breaks = np.flatnonzero(np.diff(w) != 1) + 1
            for run in np.split(v, breaks):
                k = run.size // _BLOCK
                if k:
                    sums.append(run[: k * _BLOCK].reshape(k, _BLOCK).sum(axis=1))
    if not sums or level <= 0.0:
        return math.inf
    s = np.concatenate(sums)
    return float(np.sqrt(np.mean(s**2)) / (math.sqrt(_BLOCK) * level))


def describe_residual(
    z: FloatArray,
    layout: Layout,
    settings: AttributionSettings,
    scales: FeatureSettings,
    noise: Mapping[str, float] | None = None,
) -> dict[str, Any]:
    """Whether a held-out residual (n,) still has structure, and what it looks like.

    The noise level a group's residual is compared with is, by default, its
    white, window-to-window level (:func:`white_level`: right for time series,
    where an effect drifts slowly from window to window). Where windows are
    independent — an arm measured at random poses, so any effect looks
    different in every window — the adapter states the measurement noise
    instead: ``noise[group]`` in feature-scale units.

    Returns
    -------
    dict
        ``structured`` (bool), ``reasons`` (list of str) and per group
        ``groups[g]``: RMS (scale units and SI units per column), white level,
        excess ratio, lag-1 autocorrelation, mean per regime (SI units per
        column), the regime t statistics and the fraction of variance
        explained by the commanded motion.
    """
    out: dict[str, Any] = {"structured": False, "reasons": [], "groups": {}}
    regimes = layout.schema.regimes
    for g in layout.schema.names:
        sel = layout.group == g
        if sel.sum() < 6:
            continue
        zg = z[sel]
        rms = float(np.sqrt(np.mean(zg**2)))
        stated = noise is not None and g in noise
        col_white = {} if stated else column_levels(z, layout, sel)
        white = noise[g] if stated else mixture_level(layout, sel, col_white)
        level = max(white, settings.floor)
        excess = rms / level
        cols = layout.schema.columns(g)
        scale = scales.scale(g)
        per_col_rms = {}
        for j, c in enumerate(cols):
            m = sel & (layout.column == c)
            per_col_rms[c] = float(np.sqrt(np.mean(z[m] ** 2)) * scale[j]) if m.any() else 0.0
        # lag-1 autocorrelation within logs and columns
        lag1 = _lag1(z, layout, sel)
        # residual concentrated in one column or one regime (heteroscedastic structure)
        worst_ratio, worst_ratio_where = 0.0, ""
        for c in cols:
            mc = sel & (layout.column == c)
            if mc.sum() < 6:
                continue
            # noise reference: the column's white level, or its quietest regime if lower
            quiet = [
                float(np.sqrt(np.mean(z[mc & (layout.regime == r)] ** 2)))
                for r in regimes
                if (mc & (layout.regime == r)).sum() >= 10
            ]
            if stated:
                lvl_c = max(noise[g], settings.floor)
            else:
                lvl_c = max(min([col_white[c], *quiet]), settings.floor)
            for r in ("all", *regimes):
                m = mc if r == "all" else mc & (layout.regime == r)
                if m.sum() < 5:
                    continue
                r_rms = float(np.sqrt(np.mean(z[m] ** 2)))
                # the noise floor of this regime itself: a regime whose windows scatter more
                # (starts and stops replay less exactly) is not structured for that; a
                # residual that stays put from window to window is
                lvl_r = lvl_c
                if r != "all" and not stated:
                    lvl_r = max(lvl_c, white_level(z, layout, m))
                if r_rms > settings.floor and r_rms / lvl_r > worst_ratio:
                    worst_ratio = r_rms / lvl_r
                    worst_ratio_where = c if r == "all" else f"{c} while {r}"
        regime_means: dict[str, dict[str, float]] = {}
        worst_t, worst_where = 0.0, ""
        for r in regimes:
            for j, c in enumerate(cols):
                m = sel & (layout.regime == r) & (layout.column == c)
                if m.sum() < 3:
                    continue
                mean = float(np.mean(z[m]))
                regime_means.setdefault(r, {})[c] = mean * float(scale[j])
                # the standard error of a column's mean is its own noise's
                lvl_t = level if stated else max(col_white.get(c, 0.0), settings.floor)
                t = abs(mean) / (lvl_t / math.sqrt(m.sum()))
                if t > worst_t and abs(mean) > settings.floor:
                    worst_t, worst_where = t, f"{c} while {r}"
        # dependence on the commanded motion (per column, least squares)
        r2_best, r2_where = 0.0, ""
        for c in cols:
            m = sel & (layout.column == c)
            if m.sum() < 8:
                continue
            y = z[m]
            mot = layout.motion[m]
            X = np.column_stack(
                [
                    np.ones(m.sum()),
                    mot[:, 0],
                    mot[:, 1],
                    np.abs(mot[:, 0]),
                    np.abs(mot[:, 1]),
                    mot[:, 2],
                    mot[:, 3],
                    mot[:, 4],
                    mot[:, 5],
                ]
            )
            n_m = int(m.sum())
            if n_m < 3 * X.shape[1]:
                continue
            beta, *_ = np.linalg.lstsq(X, y, rcond=None)
            fit = X @ beta
            ss_tot = float(np.sum(y**2))
            ss_res = float(np.sum((y - fit) ** 2))
            explained_rms = math.sqrt(max(ss_tot - ss_res, 0.0) / n_m)
            # share of the (uncentred) residual energy explained, adjusted for the regressors
            r2 = 1.0 - (ss_res / ss_tot) * n_m / (n_m - X.shape[1]) if ss_tot > 0 else 0.0
            if r2 > r2_best and explained_rms > settings.floor:
                r2_best, r2_where = r2, c
        info = {
            "rms": rms,
            "rms_units": per_col_rms,
            "units": dict(zip(cols, layout.schema.units(g))),
            "white_level": white,
            "excess_ratio": excess,
            "lag1_autocorrelation": lag1,
            "regime_means": regime_means,
            "worst_regime_t": worst_t,
            "worst_regime": worst_where,
            "motion_r2": r2_best,
            "motion_r2_column": r2_where,
            "worst_concentration": worst_ratio,
            "worst_concentration_where": worst_ratio_where,
        }
        out["groups"][g] = info
        if rms <= settings.floor:
            continue
        block = (
            _boundary_error(z, layout, sel, level, settings.excess_ratio)
            if excess > settings.excess_ratio
            else None
        )
        info["block_excess_ratio"] = block
        if block is not None:
            # adjacent windows cancel: an error at the window boundaries (a mis-stamped
            # sample), which no drive effect causes and sums over a few windows remove
            out.setdefault("notes", []).append(
                f"{g}: residual RMS is {excess:.1f}× its noise level, but adjacent windows "
                f"cancel (lag-1 autocorrelation {lag1:.2f}; summed over {_BLOCK} windows "
                f"{block:.1f}×): errors at the window boundaries, not a missing effect"
            )
        elif excess > settings.excess_ratio:
            out["reasons"].append(
                f"{g}: residual RMS is {excess:.1f}× its noise level ("
                f"{'stated by the logs' if noise is not None and g in noise else 'window to window'}"
                f"; lag-1 autocorrelation {lag1:.2f})"
            )
        if worst_ratio > settings.excess_ratio:
            out["reasons"].append(
                f"{g}: the residual of {worst_ratio_where} is {worst_ratio:.1f}× the noise level"
            )
        if worst_t > settings.regime_t:
            out["reasons"].append(
                f"{g}: mean residual of {worst_where} is {worst_t:.1f} standard errors from zero"
            )
        if r2_best > settings.trend_r2:
            out["reasons"].append(
                f"{g}: the commanded motion (speed, turn rate, acceleration; an arm's reach "
                "and load) explains "
                f"{100 * r2_best:.0f} % of the {r2_where} residual"
            )
    out["structured"] = bool(out["reasons"])
    return out
