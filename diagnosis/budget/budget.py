"""The gap budget: how much of the held-out gap each effect explains, and what remains.

:func:`gap_budget` runs the one selection rule
(:func:`~realitygap.diagnosis.budget.select.forward_select`) on the training folds, then
measures on the held-out data, at both scales, the gap of the calibrated baseline and of
each cumulative model (baseline + effect 1, + effect 2, …):

* an entry's **share** is the drop of the held-out RMS it brings, as a fraction of the
  baseline's RMS; its **interval** is the 2.5–97.5 % percentile range of that share over a
  bootstrap of the held-out units (runs, or segments of a single held-out log), 1000
  draws from a seeded generator;
* the **remainder** is the final model's RMS as a fraction of the baseline's, split into
  the sensors' **noise floor** (the share of the remaining squared residual that the noise
  levels account for: the noise the sensors' own samples show where the adapter measures
  it, else its stated levels, else each group's window-to-window level) and a
  **structured** part.

One rule sets the kind (:func:`kind_of`): effects are *named* when they entered and hold one
value across sessions; with named effects the kind is ``"effects"`` when the structured
remainder is under half the gap at both scales, else ``"partial"``; with none it is
``"unexplained"`` when the baseline's held-out residual exceeds what the sensors' noise
gives (:math:`Σ z^2/σ^2` against :math:`χ^2_n` at either scale, :func:`beyond_noise`) and
its structured part is larger than its noise part at some scale, else ``"none"``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.stats import chi2

from realitygap.core.parallel import Backend
from realitygap.diagnosis.budget.folds import Folds, RunCells, make_folds
from realitygap.diagnosis.budget.select import (
    ALPHA,
    as_arrays,
    forward_select,
    values_of,
)
from realitygap.diagnosis.fit.model import ModelFit
from realitygap.diagnosis.problem.parameters import param_spec
from realitygap.diagnosis.problem.problem import Problem
from realitygap.diagnosis.problem.residual import white_level

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "SCHEMA",
    "Budget",
    "BudgetEntry",
    "beyond_noise",
    "gap_budget",
    "kind_of",
    "noise_variance",
]

SCHEMA = "realitygap.budget/1"
"""Version of :meth:`Budget.to_json`'s layout (documented in ``docs/budget.md``)."""
UNEXPLAINED_LIMIT = 50.0
"""A named budget leaves the kind ``"partial"`` when its structured remainder is at least
this share (%) of the gap at either scale."""
_DRAWS = 1000


@dataclass(frozen=True)
class BudgetEntry:
    """One effect of the budget."""

    effect: str
    scale: str
    values: dict[str, float]
    stderr: dict[str, float]
    share: dict[str, float]
    interval: dict[str, tuple[float, float]]
    cv_gain: float
    p_value: float
    folds: int
    aliases: tuple[str, ...]
    stability: dict[str, Any]

    @property
    def constant(self) -> bool:
        return bool(self.stability.get("constant", True))

    @property
    def carries(self) -> bool:
        """Whether the entry helps the held-out data at some scale: an entry whose held-out
        share lies wholly below zero at every scale (its 95 % interval included) made the
        held-out runs worse — fitted on the training runs, it does not carry over."""
        if not self.interval:
            return True
        return any(iv[1] > 0.0 for iv in self.interval.values())

    @property
    def named(self) -> bool:
        """Named as a finding: one value across sessions (:attr:`constant`) that carries over
        to the held-out runs (:attr:`carries`)."""
        return self.constant and self.carries

    def to_json(self) -> dict[str, Any]:
        return {
            "effect": self.effect,
            "scale": self.scale,
            "parameters": {
                k: {
                    "value": v,
                    "stderr": self.stderr.get(k, math.nan),
                    "unit": param_spec(k).unit,
                    "nominal": param_spec(k).nominal,
                }
                for k, v in self.values.items()
            },
            "share_pct": dict(self.share),
            "interval_pct": {s: list(iv) for s, iv in self.interval.items()},
            "cv_gain": self.cv_gain,
            "p_value": self.p_value,
            "aliases": list(self.aliases),
            "stability": self.stability,
            "named": self.named,
            "carries_over": self.carries,
        }


@dataclass(frozen=True)
class Budget:
    """The gap budget (module docstring). Scales are ``"run"`` and ``"window"``; a robot whose
    motion does not integrate has only ``"window"``."""

    entries: tuple[BudgetEntry, ...]
    gap: dict[str, float]
    remainder: dict[str, dict[str, float]]
    kind: str
    rule: str
    folds: dict[str, Any]
    structured_baseline: bool
    values: dict[str, float] = field(default_factory=dict)

    @property
    def named(self) -> tuple[str, ...]:
        return tuple(e.effect for e in self.entries if e.named)

    @property
    def unexplained_share(self) -> float:
        """The largest structured remainder over the scales, % of the gap."""
        return max((r["structured_pct"] for r in self.remainder.values()), default=math.nan)

    @property
    def scales(self) -> tuple[str, ...]:
        return tuple(self.gap)

    def to_json(self) -> dict[str, Any]:
        return {
            "schema": SCHEMA,
            "kind": self.kind,
            "rule": self.rule,
            "named": list(self.named),
            "unexplained_share_pct": self.unexplained_share,
            "gap_rms": dict(self.gap),
            "entries": [e.to_json() for e in self.entries],
            "remainder": {s: dict(r) for s, r in self.remainder.items()},
            "folds": self.folds,
            "sentence": self.sentence(),
        }

    def sentence(self, gap_words: Mapping[str, str] | None = None) -> str:
        """The budget in one sentence per scale (``gap_words`` may name a scale's gap in
        physical units, e.g. ``{"run": "3.5 cm RMS trajectory gap"}``)."""
        words = []
        for s in self.scales:
            what = (gap_words or {}).get(s) or f"{self.gap[s]:.3g} noise units RMS"
            label = "whole-run drift" if s == "run" else "windows"
            parts = []
            for e in self.entries:
                lo, hi = self.interval_of(e, s)
                vals = ", ".join(
                    f"{k.split('.', 1)[1]} = {v:.5g}"
                    + (f" ± {e.stderr[k]:.2g}" if math.isfinite(e.stderr.get(k, math.nan)) else "")
                    for k, v in e.values.items()
                )
                alias = f" (or {' or '.join(e.aliases)}: alike on these data)" if e.aliases else ""
                vary = (
                    ""
                    if e.constant
                    else " — its value varies between " + e.stability.get("unit", "fold") + "s"
                )
                parts.append(
                    f"{e.effect.replace('_', ' ')} ({vals}){alias}{vary} explains "
                    f"{e.share[s]:.0f} % [{lo:.0f}, {hi:.0f}]"
                )
            r = self.remainder[s]
            rest = (
                f"{r['remaining_pct']:.0f} % remains: {r['noise_pct']:.0f} points sensor noise, "
                f"{r['structured_pct']:.0f} points structured"
            )
            body = (
                "; ".join(parts) + "; " + rest if parts else "no effect explains a share; " + rest
            )
            words.append(f"Of the held-out {label} ({what}), {body}.")
        return " ".join(words)

    def interval_of(self, entry: BudgetEntry, scale: str) -> tuple[float, float]:
        return entry.interval.get(scale, (math.nan, math.nan))


def kind_of(
    entries: Sequence[BudgetEntry], remainder: Mapping[str, Mapping[str, float]], structured: bool
) -> tuple[str, str]:
    """The budget's kind and the rule that set it (module docstring)."""
    named = [e.effect for e in entries if e.named]
    if not named:
        if any(e.constant and not e.carries for e in entries):
            return "unexplained", (
                "the effects fitted on the training runs make the held-out runs worse: they do "
                "not carry over"
            )
        if entries:
            return "unexplained", (
                "effects explain part of the gap but none holds one value across "
                f"{entries[0].stability.get('unit', 'fold')}s"
            )
        # a gap: beyond the sensors' noise (significant) and more of it than the noise
        if structured and any(r["structured_pct"] > r["noise_pct"] for r in remainder.values()):
            return "unexplained", (
                "no effect's cross-validated gain is significant and the held-out residual is "
                "structured beyond the sensors' noise"
            )
        return "none", (
            "no effect's gain is significant and the held-out residual is mostly the sensors' noise"
        )
    worst = max(r["structured_pct"] for r in remainder.values())
    if worst < UNEXPLAINED_LIMIT:
        return "effects", (
            f"named effects leave a structured remainder of {worst:.0f} % (< "
            f"{UNEXPLAINED_LIMIT:.0f} %) of the held-out gap at every scale"
        )
    return "partial", (
        f"named effects leave a structured remainder of {worst:.0f} % (≥ "
        f"{UNEXPLAINED_LIMIT:.0f} %) of the held-out gap at some scale"
    )


def _unit_sums(
    z: FloatArray, unit: npt.NDArray[np.int64], cells: RunCells | None, n_units: int
) -> dict[str, tuple[FloatArray, FloatArray]]:
    """Per held-out unit: squared sum and count of the run cells (first: whole-run drift is
    what a user reads first) and of the window entries."""
    out: dict[str, tuple[FloatArray, FloatArray]] = {}
    if cells is not None:
        v = cells(z)
        out["run"] = (
            np.bincount(cells.unit, v**2, minlength=n_units).astype(float),
            np.bincount(cells.unit, minlength=n_units).astype(float),
        )
    out["window"] = (
        np.bincount(unit, z**2, minlength=n_units).astype(float),
        np.bincount(unit, minlength=n_units).astype(float),
    )
    return out


def noise_variance(
    problem: Problem,
    z: FloatArray,
    cells: RunCells | None,
    noise: Mapping[str, float] | None,
    sample_noise: Mapping[str, Mapping[str, float]] | None = None,
) -> dict[str, FloatArray]:
    """The variance sensor noise alone gives each held-out entry and each run cell: the
    noise the sensors' own samples show (the adapter's ``sample_noise_levels``, per group and
    column), else the adapter's stated level of the group, else the group's window-to-window
    level in ``z`` (:func:`~realitygap.diagnosis.problem.residual.white_level`); a cell, a
    sum over √n entries, keeps their mean variance."""
    layout = problem.holdout
    level = np.zeros(layout.n)
    for g in np.unique(layout.group):
        sel = layout.group == g
        lv = noise.get(str(g)) if noise else None
        if lv is None or not math.isfinite(lv):
            lv = white_level(z, layout, sel)
        level[sel] = lv
        own = (sample_noise or {}).get(str(g)) or {}
        for col, v in own.items():
            if v is not None and math.isfinite(v) and v > 0:
                level[sel & (layout.column == col)] = v
    level = np.maximum(level, 1e-12)
    out: dict[str, FloatArray] = {}
    if cells is not None:
        out["run"] = np.asarray(cells.matrix.T.multiply(cells.matrix.T).dot(level**2)).ravel()
    out["window"] = level**2
    return out


def beyond_noise(z: FloatArray, cells: RunCells | None, var: Mapping[str, FloatArray]) -> bool:
    """Whether a held-out residual exceeds what sensor noise gives at some scale:
    :math:`Σ z_i^2/σ_i^2` against :math:`χ^2_n` at :data:`ALPHA`, Bonferroni over the scales."""
    values = {"window": z}
    if cells is not None:
        values["run"] = cells(z)
    for s, v in values.items():
        q = float(np.sum(v**2 / var[s]))
        if chi2.sf(q, max(v.size, 1)) < ALPHA / len(values):
            return True
    return False


def gap_budget(
    problem: Problem,
    candidates: Sequence[str],
    ranking: Sequence[ModelFit],
    backend: Backend,
    say: Callable[[str], None] = lambda m: None,
    noise: Mapping[str, float] | None = None,
    seed: int = 0,
    sample_noise: Mapping[str, Mapping[str, float]] | None = None,
) -> Budget:
    """The gap budget of ``problem`` (module docstring). ``noise`` and ``sample_noise`` are
    the adapter's stated noise levels and those its sensors' own samples show."""
    folds: Folds = make_folds(problem)
    integrates = bool(problem.adapter.integrates)
    chosen, _, _ = forward_select(problem, candidates, ranking, folds, integrates, backend, say)
    ho = problem.holdout
    n_units = len(folds.holdout_labels)
    cells = RunCells.of(ho, folds.holdout) if integrates else None
    models = [values_of(chosen, j) for j in range(len(chosen) + 1)]
    Z = np.vstack([problem.surrogate_residuals(ho, as_arrays(v), 1)[0] for v in models])
    sums = [_unit_sums(z, folds.holdout, cells, n_units) for z in Z]
    scales = list(sums[0])
    var_final = noise_variance(problem, Z[-1], cells, noise, sample_noise)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, n_units, size=(_DRAWS, n_units))
    gap: dict[str, float] = {}
    shares: dict[str, FloatArray] = {}
    boot: dict[str, FloatArray] = {}
    remainder: dict[str, dict[str, float]] = {}
    for s in scales:
        ss = np.stack([sm[s][0] for sm in sums])  # (J+1, units)
        cnt = sums[0][s][1]
        rms = np.sqrt(ss.sum(axis=1) / max(cnt.sum(), 1.0))
        gap[s] = float(rms[0])
        shares[s] = 100.0 * (rms[:-1] - rms[1:]) / rms[0] if rms[0] > 0 else np.zeros(len(chosen))
        # bootstrap over held-out units: (draws, J+1)
        ss_b = ss[:, draws].sum(axis=2).T
        cnt_b = cnt[draws].sum(axis=1)[:, None]
        rms_b = np.sqrt(ss_b / np.maximum(cnt_b, 1.0))
        boot[s] = 100.0 * (rms_b[:, :-1] - rms_b[:, 1:]) / np.maximum(rms_b[:, :1], 1e-300)
        left = float(rms[-1] / rms[0]) if rms[0] > 0 else 1.0
        noise_frac = min(1.0, float(var_final[s].sum() / max(ss[-1].sum(), 1e-300)))
        remainder[s] = {
            "remaining_pct": 100.0 * left,
            "noise_pct": 100.0 * left * noise_frac,
            "structured_pct": 100.0 * left * (1.0 - noise_frac),
            "rms": float(rms[-1]),
        }
    entries = []
    for j, sel in enumerate(chosen):
        tri = sel.trial
        entries.append(
            BudgetEntry(
                effect=tri.effect,
                scale=tri.scale,
                values=dict(tri.values),
                stderr=dict(tri.stderr),
                share={s: float(shares[s][j]) for s in scales},
                interval={
                    s: (
                        float(np.percentile(boot[s][:, j], 2.5)),
                        float(np.percentile(boot[s][:, j], 97.5)),
                    )
                    for s in scales
                },
                cv_gain=tri.mean_gain,
                p_value=tri.p,
                folds=folds.k,
                aliases=sel.aliases,
                stability=sel.stability,
            )
        )
    structured = beyond_noise(
        Z[0], cells, noise_variance(problem, Z[0], cells, noise, sample_noise)
    )
    kind, rule = kind_of(entries, remainder, structured)
    return Budget(
        entries=tuple(entries),
        gap=gap,
        remainder=remainder,
        kind=kind,
        rule=rule,
        folds={
            "unit": folds.unit,
            "k": folds.k,
            "labels": list(folds.labels),
            "holdout_unit": folds.holdout_unit,
            "stability_unit": folds.groups_unit,
            "holdout_labels": list(folds.holdout_labels),
            "test": f"paired one-sided t over folds at {ALPHA:g}/candidates (Bonferroni); "
            "aliases: paired one-sided t at the same level; stability: Cochran's Q at 0.01; "
            "intervals: bootstrap of held-out units (1000 draws)",
        },
        structured_baseline=structured,
        values=values_of(chosen),
    )
