r"""Two scales of the held-out gap: 1-s windows and whole held-out runs.

A drift-type effect (a wheelbase or wheel-diameter error) adds a small error to
every window — a wheelbase error of 0.8 % turns a 1-s quarter turn by about
4 mrad less — and its errors integrate along a run. A clock that wanders
between the channels of a recording adds, per window, an error that does *not*
integrate,

.. math::  e_w \approx δ_w \, \frac{∂ f_w}{∂ t}

(the window's offset times the sensitivity of its features to a time shift:
the change of motion within the window), and at the window scale it can hide
the drift effect: the window shrink of the right effect is then a few per cent
while it closes most of the whole-run gap.

:func:`whole_run_figures` measures both scales for the best model of an
``"unexplained"`` draft whose only reason was the window shrink;
:func:`~realitygap.diagnosis.verdict.scales.judge_scales` then names the model, with both
figures stated, when

1. it improves the held-out windows beyond :attr:`AttributionSettings.margin_strong`
   (rank score against the reference) — it helps at the window scale, it is
   only small there;
2. its whole-run held-out trajectory gap (PyBullet replays) shrinks by at least
   :attr:`AttributionSettings.min_shrink`, consistently across runs (every
   held-out run improves, or a one-sided sign test over runs at 5 %);
3. what it leaves at the window scale does not add up along the runs: no
   held-out run and feature column has a mean window residual away from zero
   at the family-wise level :attr:`ScaleSettings.run_bias_alpha` (Student's t
   on the run's windows, standard errors and degrees of freedom corrected for
   lag-1 autocorrelation, Bonferroni over runs and columns: :func:`run_bias`).
   A drift the model
   leaves — a second mechanism that integrates — keeps a mean, run after run;
   a residual that only moves windows about (a clock wandering between the
   channels, the body lagging the wheels in a turn, a bump) does not.

The window residual the model leaves is then named for what it is: left
unexplained, with its description (:func:`~realitygap.diagnosis.problem.residual.describe_residual`)
and the share of it that one clock offset per window along the timing
signature :math:`∂f_w/∂t` would explain, against the same fit with the
signatures of other windows of the log (:func:`window_timing`). The verdict
says both: "X (on whole runs; the 1-s window residual it leaves is
unexplained)".

Both replays qualify. In one driven by the measured wheel motion what a window
keeps is what happens between the wheels and the ground and between the
channels' clocks; in a command-driven one it also holds the part of the drive
train's response to the commands (lags, ramps) that the calibrated baseline
does not reproduce, which moves windows about as a clock does and is stated
with the remainder — the clock share is then only a description (a per-window
time shift is confounded with the drive train's response), never a test.
Otherwise the verdict stays as it was. A pure-noise log fails (1) and (2); an
effect outside the library that a library effect partly compensates leaves a
residual that keeps a mean along the runs (3).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.stats import binomtest
from scipy.stats import t as student_t

from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.problem import Layout, Problem
from realitygap.diagnosis.problem.residual import describe_residual
from realitygap.diagnosis.problem.shrink import trajectory_runs
from realitygap.diagnosis.stages.clock import timing_channel

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "ScaleFigures",
    "ScaleSettings",
    "gain_through_origin",
    "run_bias",
    "timing_signature",
    "whole_run_figures",
    "window_timing",
]


@dataclass(frozen=True)
class ScaleSettings:
    """Settings of the two-scale verdict.

    Attributes
    ----------
    bound : float
        Largest clock offset of one window, s.
    min_timing_share : float
        Share of the remaining window residual above which the per-window
        offsets (beating every permuted signature) call it a clock's.
    permutations : int
        Fits with permuted signatures the true fit is compared with.
    step : float
        Finite-difference step of the timing signature, s.
    run_bias_alpha : float
        Family-wise significance level (over held-out runs and feature columns)
        at which a mean window residual left along a run counts as a drift.
    """

    bound: float = 0.05
    min_timing_share: float = 0.5
    permutations: int = 20
    step: float = 0.005
    run_bias_alpha: float = 0.01

    def __post_init__(self) -> None:
        for name in ("bound", "step"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(
                    f"ScaleSettings.{name}: expected a positive number of seconds, got {v!r}"
                )
        if not 0.0 < self.min_timing_share < 1.0:
            raise ValueError(
                f"ScaleSettings.min_timing_share: expected a share in (0, 1), got {self.min_timing_share!r}"
            )
        if not 0.0 < self.run_bias_alpha < 1.0:
            raise ValueError(
                "ScaleSettings.run_bias_alpha: expected a significance level in (0, 1), "
                f"got {self.run_bias_alpha!r}"
            )
        if self.permutations < 1:
            raise ValueError(f"ScaleSettings.permutations: expected ≥ 1, got {self.permutations!r}")


def timing_signature(
    problem: Problem, layout: Layout, values: Mapping[str, float], key: str, step: float
) -> FloatArray:
    """Change of the normalised residual (n,) per second of the timing parameter ``key``.

    Central difference of the surrogate's features at ``values`` (plus the
    baseline), stacked as the residuals of ``layout`` are.
    """
    at = float(values.get(key, problem.baseline_values.get(key, 0.0)))
    point = {k: np.full(2, v) for k, v in values.items()}
    point[key] = np.array([at - step, at + step])
    full = problem.with_baseline(point, 2)
    out = np.empty(layout.n)
    pos = 0
    cache: dict[int, dict[str, FloatArray]] = {}
    for i, g, wins in layout.blocks:
        p = problem.logs[i]
        if i not in cache:
            cache[i] = problem.adapter.surrogate_features(p, full, problem.drive)
        f = cache[i][g][:, wins]
        d = -(f[1] - f[0]) / (2.0 * step) / problem.features.scale(g)
        out[pos : pos + d.size] = d.ravel()
        pos += d.size
    return out


def window_timing(
    z: FloatArray, signature: FloatArray, layout: Layout, bound: float
) -> tuple[FloatArray, FloatArray]:
    """One clock offset per window along ``signature``: the residual left and the offsets.

    Returns
    -------
    z_left : ndarray, shape (n,)
    offsets : ndarray, shape (W,)
        Per (log, window) in the order of first appearance, s, within ``±bound``.
    """
    key = layout.log.astype(np.int64) * 1_000_000 + layout.window
    _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    sr = np.bincount(inverse, weights=signature * z)
    ss = np.bincount(inverse, weights=signature**2)
    off = np.where(ss > 1e-12, sr / np.maximum(ss, 1e-12), 0.0)
    off = np.clip(off, -bound, bound)
    return z - off[inverse] * signature, off[np.argsort(first)]


def autocorrelation_widening(
    d: FloatArray, max_autocorrelation: float = 0.9
) -> tuple[float, float]:
    r"""Lag-1 autocorrelation :math:`ρ` of deviations ``d`` (in order, clipped to
    ``[0, max_autocorrelation]``) and the factor :math:`\sqrt{(1+ρ)/(1-ρ)}` by which it
    widens the standard error of a mean or a slope over them."""
    d = np.asarray(d, dtype=float)
    den = float(d @ d)
    rho = float(d[1:] @ d[:-1]) / den if den > 0 else 0.0
    rho = min(max(rho, 0.0), max_autocorrelation)
    return rho, math.sqrt((1.0 + rho) / (1.0 - rho))


def gain_through_origin(real: FloatArray, asked: FloatArray) -> tuple[float, float]:
    r"""Least-squares slope :math:`g = r·a / a·a` of ``real`` on ``asked`` through the
    origin, and its standard error from the scatter about it, widened for the scatter's
    lag-1 autocorrelation (:func:`autocorrelation_widening`); NaN error with fewer than
    three points, NaN slope when nothing was asked."""
    r, a = np.asarray(real, dtype=float), np.asarray(asked, dtype=float)
    aa = float(a @ a)
    if aa <= 0.0:
        return math.nan, math.nan
    g = float(r @ a) / aa
    if a.size < 3:
        return g, math.nan
    res = r - g * a
    _, widen = autocorrelation_widening(res)
    return g, math.sqrt(float(res @ res) / (a.size - 1) / aa) * widen


def run_bias(
    z: FloatArray, layout: Layout, max_autocorrelation: float = 0.9
) -> list[dict[str, Any]]:
    r"""Mean window residual of each run and feature column, in standard errors.

    The standard error of a mean of ``n`` windows with spread ``s`` and lag-1
    autocorrelation ``ρ`` (clipped to ``[0, max_autocorrelation]``) is
    :math:`s/\sqrt n \cdot \sqrt{(1+ρ)/(1-ρ)}`, and the two-sided p-value of
    ``t = mean / se`` is Student's with :math:`n(1-ρ)/(1+ρ) - 1` degrees of
    freedom (at least 1). Runs with fewer than four windows in a column are
    left out.

    Returns
    -------
    list of dict
        ``log`` (index), ``group``, ``column``, ``windows``, ``mean``, ``se``,
        ``t`` (mean / se), ``df`` and ``p``, smallest ``p`` first.
    """
    if z.shape != (layout.n,):
        raise ValueError(f"run_bias: z has shape {z.shape}, the layout {layout.n} entries")
    out: list[dict[str, Any]] = []
    keys = np.char.add(np.char.add(layout.group, "/"), layout.column)
    for i in np.unique(layout.log):
        in_log = layout.log == i
        for key in np.unique(keys[in_log]):
            sel = np.flatnonzero(in_log & (keys == key))
            x = z[sel[np.argsort(layout.window[sel], kind="stable")]]
            if x.size < 4:
                continue
            spread = float(np.std(x, ddof=1))
            rho, widen = autocorrelation_widening(x - x.mean(), max_autocorrelation)
            se = spread / math.sqrt(x.size) * widen
            df = max(x.size * (1.0 - rho) / (1.0 + rho) - 1.0, 1.0)
            mean = float(x.mean())
            t = mean / se if se > 0 else (0.0 if mean == 0 else math.inf)
            group, column = str(key).split("/", 1)
            out.append(
                {
                    "log": int(i),
                    "group": group,
                    "column": column,
                    "windows": int(x.size),
                    "mean": mean,
                    "se": se,
                    "t": t,
                    "df": df,
                    "p": float(2.0 * student_t.sf(abs(t), df)),
                }
            )
    out.sort(key=lambda r: (r["p"], -abs(r["t"])))
    return out


def _share(z: FloatArray, z_left: FloatArray) -> float:
    total = float(np.sum(z**2))
    return 1.0 - float(np.sum(z_left**2)) / total if total > 0 else 0.0


def _permuted(signature: FloatArray, layout: Layout, rng: np.random.Generator) -> FloatArray:
    """The signature with windows permuted within each log (same groups and columns)."""
    out = signature.copy()
    for i in np.unique(layout.log):
        sel = np.flatnonzero(layout.log == i)
        wins = layout.window[sel]
        uniq = np.unique(wins)
        order = rng.permutation(uniq)
        per = sel.size // uniq.size
        if per * uniq.size != sel.size:
            continue
        # entries of one window are contiguous per group block; rebuild by window
        for g in np.unique(layout.group[sel]):
            gs = sel[layout.group[sel] == g]
            k = gs.size // uniq.size
            block = signature[gs].reshape(uniq.size, k)
            pos = {w: j for j, w in enumerate(np.unique(layout.window[gs]))}
            out[gs] = block[[pos[w] for w in order]].ravel()
    return out


@dataclass(frozen=True)
class ScaleFigures:
    """What the best model does on whole held-out runs, and what it leaves in the windows
    (:func:`whole_run_figures`).

    Attributes
    ----------
    window_shrink_pct : float
        Its held-out shrink at the window scale, %.
    run_gap_m_nominal, run_gap_m_best : float
        RMS over held-out runs of each run's whole-replay position error, nominal and best, m.
    run_shrink_pct : float
        The whole-run gap it closes, %.
    runs_improved : int
        Held-out runs whose whole-replay error it lowers.
    runs : list of dict
        Per run: ``log``, ``gap_m_nominal``, ``gap_m_best``.
    consistent : bool
        Every run improves, or a one-sided sign test over runs at 5 %.
    window_gain : float
        Its rank-score gain over the reference on the held-out windows.
    run_bias_max_se, run_bias_p_family : float
        The largest mean window residual of a run and column in standard errors, and its
        family-wise p-value (Bonferroni over the ``run_bias_tests`` runs and columns).
    run_bias_worst : dict or None
        That run and column (:func:`run_bias`, ``log`` by name).
    run_bias_tests : int
    timing_parameter : str
        The clock parameter whose signature the per-window offsets follow.
    timing_share_pct, timing_share_pct_permuted_max : float
        The share of the window residual one clock offset per window explains, and the
        most permuted signatures explain, %.
    window_offsets_ms_p5_p95 : list of float
    residual_after_timing_structured : bool
    clock_like : bool
        The offsets explain at least :attr:`ScaleSettings.min_timing_share` of it, more
        than any permuted signature.
    """

    window_shrink_pct: float
    run_gap_m_nominal: float
    run_gap_m_best: float
    run_shrink_pct: float
    runs_improved: int
    runs: list[dict[str, Any]]
    consistent: bool
    window_gain: float
    run_bias_max_se: float
    run_bias_p_family: float
    run_bias_worst: dict[str, Any] | None
    run_bias_tests: int
    timing_parameter: str
    timing_share_pct: float
    timing_share_pct_permuted_max: float
    window_offsets_ms_p5_p95: list[float]
    residual_after_timing_structured: bool
    clock_like: bool

    def to_json(self) -> dict[str, Any]:
        """The figures as ``verdict_scales`` of the diagnosis JSON holds them."""
        return {
            "window_shrink_pct": self.window_shrink_pct,
            "run_gap_m_nominal": self.run_gap_m_nominal,
            "run_gap_m_best": self.run_gap_m_best,
            "run_shrink_pct": self.run_shrink_pct,
            "runs_improved": self.runs_improved,
            "runs": self.runs,
            "window_gain": self.window_gain,
            "run_bias_max_se": self.run_bias_max_se,
            "run_bias_p_family": self.run_bias_p_family,
            "run_bias_worst": self.run_bias_worst,
            "timing_parameter": self.timing_parameter,
            "timing_share_pct": self.timing_share_pct,
            "timing_share_pct_permuted_max": self.timing_share_pct_permuted_max,
            "window_offsets_ms_p5_p95": self.window_offsets_ms_p5_p95,
            "residual_after_timing_structured": self.residual_after_timing_structured,
        }


def whole_run_figures(
    problem: Problem,
    best: ModelFit,
    nominal_fit: ModelFit,
    shrink_pct_best: float,
    replays: Mapping[tuple[str, ...], Mapping[int, Log]],
    noise: Mapping[str, float] | None,
    settings: ScaleSettings,
) -> ScaleFigures | None:
    """Measure ``best`` on whole held-out runs and its window residual along the runs.

    Returns
    -------
    ScaleFigures or None
        ``None`` when no timing parameter (of the baseline or the model) gives a signature
        or ``best`` has no PyBullet replays.
    """
    st = problem.settings
    key = next(
        (k for k in (*problem.baseline_values, *best.values) if timing_channel(k) is not None),
        None,
    )
    reps = replays.get(best.effects)
    if key is None or reps is None:
        return None
    ho = [i for i, p in enumerate(problem.logs) if p.holdout_windows.any() and i in reps]
    rows = trajectory_runs(
        [problem.logs[i].log for i in ho],
        {"nominal": [problem.logs[i].replay_log for i in ho], "best": [reps[i] for i in ho]},
    )
    runs = [(r["log"], r["nominal_m"], r["best_m"]) for r in rows]
    nom = math.sqrt(sum(r[1] ** 2 for r in runs) / len(runs)) if runs else 0.0
    aft = math.sqrt(sum(r[2] ** 2 for r in runs) / len(runs)) if runs else 0.0
    run_shrink = 100.0 * (1.0 - aft / nom) if nom > 0 else 0.0
    better = sum(r[2] < r[1] for r in runs)
    consistent = bool(runs) and (
        better == len(runs)
        or binomtest(better, len(runs), 0.5, alternative="greater").pvalue < 0.05
    )
    gain = nominal_fit.rank_score - best.rank_score
    sig = timing_signature(problem, problem.holdout, best.values, key, settings.step)
    z = best.z_heldout
    z_left, offsets = window_timing(z, sig, problem.holdout, settings.bound)
    share = _share(z, z_left)
    rng = np.random.default_rng(st.seed)
    null = max(
        _share(
            z,
            window_timing(z, _permuted(sig, problem.holdout, rng), problem.holdout, settings.bound)[
                0
            ],
        )
        for _ in range(settings.permutations)
    )
    left_desc = describe_residual(z_left, problem.holdout, st, problem.features, noise)
    bias = run_bias(z, problem.holdout)
    worst = bias[0] if bias else None
    return ScaleFigures(
        window_shrink_pct=shrink_pct_best,
        run_gap_m_nominal=nom,
        run_gap_m_best=aft,
        run_shrink_pct=run_shrink,
        runs_improved=better,
        runs=[{"log": n, "gap_m_nominal": a, "gap_m_best": b} for n, a, b in runs],
        consistent=consistent,
        window_gain=gain,
        run_bias_max_se=abs(float(worst["t"])) if worst is not None else 0.0,
        run_bias_p_family=min(1.0, len(bias) * float(worst["p"])) if worst is not None else 1.0,
        run_bias_worst=(
            {**worst, "log": problem.logs[int(worst["log"])].name} if worst is not None else None
        ),
        run_bias_tests=len(bias),
        timing_parameter=key,
        timing_share_pct=100.0 * share,
        timing_share_pct_permuted_max=100.0 * null,
        window_offsets_ms_p5_p95=[float(1e3 * np.percentile(offsets, q)) for q in (5, 95)]
        if offsets.size
        else [],
        residual_after_timing_structured=bool(left_desc["structured"]),
        clock_like=share >= settings.min_timing_share and share > null,
    )
