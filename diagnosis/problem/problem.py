"""The diagnosis problem: prepared logs laid out as one residual vector."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.adapters.contract import Drive, PreparedLog, RobotAdapter
from realitygap.diagnosis.logs.log import Log
from realitygap.diagnosis.problem.features import FeatureSchema, FeatureSettings
from realitygap.diagnosis.problem.parameters import (
    model_keys,
)
from realitygap.diagnosis.problem.residual import white_level
from realitygap.robots.simulation import SimSettings

FloatArray = npt.NDArray[np.float64]

__all__ = ["MOTION_COLUMNS", "AttributionSettings", "Layout", "Problem", "profile_score"]


@dataclass(frozen=True)
class AttributionSettings:
    """Settings of the fits, the ranking and the residual tests the budget reads.

    Attributes
    ----------
    pair_candidates : int
        The best this many single effects are also fitted in pairs for the ranking (a
        detail of the report); 0 by default: the gap budget combines effects itself, by
        forward selection (:mod:`~realitygap.diagnosis.budget.select`).
    verify_top : int
        Models verified with PyBullet (defect-corrected refit and PyBullet
        held-out residual); the rest keep surrogate scores.
    defect_iterations : int
        PyBullet bias updates per verified model.
    min_shrink : float
        Fraction of the held-out RMS gap a model must close to count as reaching it (the
        library's reach, :mod:`~realitygap.diagnosis.stages.reach`).
    excess_ratio : float
        A group's residual is structured if its RMS exceeds this many times
        its white, window-to-window level.
    regime_t : float
        … or if a regime's mean residual exceeds this many standard errors.
    trend_r2 : float
        … or if the commanded motion explains this fraction of its variance.
    floor : float
        Residual level (in feature-scale units) below which nothing counts as
        structured: effects that small are below what the logs resolve.
    score_floor : float
        ``ε`` of the profile score (feature-scale units).
    confound_corr : float
        |correlation| of jointly fitted parameters above which two effects are
        reported as not separable by the logged motions.
    margin_strong : float
        Score difference within which actuator conventions screened on the surrogate are
        all replayed in PyBullet (:func:`~realitygap.diagnosis.stages.baseline.choose_convention`).
    parsimony_margin : float
        A model with one effect fewer whose score is within this of a larger
        model's is preferred (Occam's razor on held-out scores).
    grid_points : int
        Grid points per parameter of single-parameter fits.
    loss : {"soft_l1", "cauchy", "huber", "linear"}
        Loss of :func:`scipy.optimize.least_squares` (``"linear"``: plain least squares).
    robust_scale : float
        ``f_scale`` of the robust loss in noise levels of the baseline residual.
    seed : int
        Seed of the random starts of models with more than two parameters.
    fit_tolerance : float
        ``xtol`` and ``ftol`` of the local refinement: it stops once a step moves the
        parameters by less than this fraction of their physical ranges, or the robust
        cost by less than this fraction of itself (SciPy's default).
    """

    pair_candidates: int = 0
    verify_top: int = 2
    defect_iterations: int = 1
    min_shrink: float = 0.5
    excess_ratio: float = 2.5
    regime_t: float = 6.0
    trend_r2: float = 0.5
    floor: float = 0.3
    score_floor: float = 0.3
    confound_corr: float = 0.95
    margin_strong: float = 10.0
    parsimony_margin: float = 6.0
    grid_points: int = 41
    loss: str = "soft_l1"
    robust_scale: float = 3.0
    seed: int = 0
    fit_tolerance: float = 1e-8

    def __post_init__(self) -> None:
        if not (0.0 < self.min_shrink <= 1.0):
            raise ValueError(
                f"AttributionSettings.min_shrink: expected a fraction in (0, 1], got "
                f"{self.min_shrink!r}; fix: pass e.g. min_shrink=0.5"
            )
        allowed = ("soft_l1", "cauchy", "huber", "linear", "arctan")
        if self.loss not in allowed:
            raise ValueError(
                f"AttributionSettings.loss: expected one of {', '.join(allowed)}, got "
                f"{self.loss!r}; fix: pass e.g. loss='soft_l1'"
            )
        if not (0.0 < self.fit_tolerance < 0.1):
            raise ValueError(
                "AttributionSettings.fit_tolerance: expected a fraction in (0, 0.1), got "
                f"{self.fit_tolerance!r}; fix: pass e.g. fit_tolerance=1e-8"
            )
        if not (self.robust_scale > 0 and math.isfinite(self.robust_scale)):
            raise ValueError(
                "AttributionSettings.robust_scale: expected a positive finite number of noise "
                f"levels, got {self.robust_scale!r}"
            )


# --------------------------------------------------------------------------- layout
MOTION_COLUMNS = ("v_mean", "w_mean", "dv", "dw", "v_range", "w_range")
"""Commanded motion of a window: mean speed and turn rate, their signed change over the
window (m/s, rad/s) and their ranges. Each adapter's log context describes its windows in
these six columns (:meth:`~realitygap.diagnosis.adapters.contract.LogContext.window_motion`: a
differential drive's commanded motion, an arm's reach and holding torques, a climber's
speed and vertical speed); the trend test regresses the residual on it."""


@dataclass
class Layout:
    """Where each entry of a stacked residual vector comes from.

    ``blocks`` lists ``(log index, group, window indices)``; the per-entry
    arrays (length n) give group, column, regime, log, window and the
    commanded motion of the window (:data:`MOTION_COLUMNS`); ``schema`` is
    the robot's feature groups and regimes.
    """

    blocks: list[tuple[int, str, npt.NDArray[np.int64]]]
    # entries below have one value per residual entry
    group: npt.NDArray[np.str_]
    column: npt.NDArray[np.str_]
    regime: npt.NDArray[np.str_]
    log: npt.NDArray[np.int64]
    window: npt.NDArray[np.int64]
    motion: FloatArray
    schema: FeatureSchema

    @property
    def n(self) -> int:
        return int(self.group.shape[0])

    def alternate(self, block: int, parity: int) -> tuple[Layout, npt.NDArray[np.int64]]:
        """Every other block of ``block`` consecutive windows of each log (``parity`` 0: the
        first block, 1: the second), and the positions of their entries in this layout.

        Two calls with parities 0 and 1 split the layout into halves that share no window
        and interleave in time (a two-fold split that keeps each log's motions in both).
        """
        if block < 1 or parity not in (0, 1):
            raise ValueError(
                f"Layout.alternate: block must be >= 1 and parity 0 or 1, got {block!r}, {parity!r}"
            )
        keep = (self.window // block) % 2 == parity
        blocks = []
        for i, g, wins in self.blocks:
            w = wins[(wins // block) % 2 == parity]
            if w.size:
                blocks.append((i, g, w))
        part = Layout(
            blocks=blocks,
            group=self.group[keep],
            column=self.column[keep],
            regime=self.regime[keep],
            log=self.log[keep],
            window=self.window[keep],
            motion=self.motion[keep],
            schema=self.schema,
        )
        return part, np.flatnonzero(keep)

    @classmethod
    def build(
        cls,
        logs: Sequence[PreparedLog],
        split: str,
        schema: FeatureSchema,
        excluded: Mapping[int, npt.NDArray[np.bool_]] | None = None,
    ) -> Layout:
        """The layout of the ``split`` windows of ``logs``, without the ``excluded`` ones
        (per log index, a boolean mask over its windows: transient events)."""
        blocks = []
        g_all, c_all, r_all, l_all, w_all, m_all = [], [], [], [], [], []
        for i, p in enumerate(logs):
            use = ~p.holdout_windows if split == "train" else p.holdout_windows.copy()
            if excluded is not None and i in excluded:
                use = use & ~excluded[i]
            wins = np.flatnonzero(use)
            if wins.size == 0:
                continue
            motion = np.zeros((p.bounds.shape[0], len(MOTION_COLUMNS)))
            described = p.context.window_motion(p.bounds)
            if described is not None:
                motion[:] = described
            for g in p.groups:
                cols = schema.columns(g)
                blocks.append((i, g, wins))
                for w in wins:
                    for c in cols:
                        g_all.append(g)
                        c_all.append(c)
                        r_all.append(p.regimes[w])
                        l_all.append(i)
                        w_all.append(w)
                        m_all.append(motion[w])
        return cls(
            blocks=blocks,
            group=np.asarray(g_all, dtype=str),
            column=np.asarray(c_all, dtype=str),
            regime=np.asarray(r_all, dtype=str),
            log=np.asarray(l_all, dtype=np.int64),
            window=np.asarray(w_all, dtype=np.int64),
            motion=np.asarray(m_all, dtype=float).reshape(-1, len(MOTION_COLUMNS)),
            schema=schema,
        )


def profile_score(z: FloatArray, layout: Layout, floor: float) -> FloatArray:
    """``Σ_g n_g log(mean(z_g²) + floor²)`` for residual vectors z (..., n)."""
    z = np.asarray(z, dtype=float)
    total = np.zeros(z.shape[:-1])
    for g in np.unique(layout.group):
        sel = layout.group == g
        ms = np.mean(z[..., sel] ** 2, axis=-1)
        total = total + sel.sum() * np.log(ms + floor**2)
    return total


# --------------------------------------------------------------------------- problem
@dataclass
class Problem:
    """Everything a fit needs: adapter, prepared logs, drive, settings (picklable).

    Attributes
    ----------
    excluded : dict of int to ndarray of bool
        Windows set aside as transient events, per log index
        (:mod:`realitygap.diagnosis.stages.transients`); :meth:`exclude` sets them.
    baseline_values : dict of str to float
        The calibrated baseline (``{"effect.param": value}``,
        :mod:`realitygap.diagnosis.stages.baseline`): added to every model unless the
        model fits that parameter itself.
    baseline_features : dict of int to features
        PyBullet features of each log at the calibrated baseline (the reference
        every effect is scored against); empty before calibration.
    baseline_ranges : dict of str to (float, float)
        The nuisance range of each baseline parameter: a model re-fits the
        nuisances inside these ranges together with its own parameters (so that
        a nuisance value biased by an effect missing from the baseline does not
        stay biased), without naming them as findings.
    f_scale : float
        Scale of the robust loss, feature-scale units (:meth:`noise_scale`).
    """

    adapter: RobotAdapter
    logs: list[PreparedLog]
    drive: Drive
    features: FeatureSettings
    sim: SimSettings | None
    settings: AttributionSettings
    train: Layout = field(init=False)
    holdout: Layout = field(init=False)
    excluded: dict[int, npt.NDArray[np.bool_]] = field(default_factory=dict)
    baseline_values: dict[str, float] = field(default_factory=dict)
    baseline_features: dict[int, dict[str, FloatArray]] = field(default_factory=dict)
    baseline_ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    f_scale: float = 1.0

    def __post_init__(self) -> None:
        self._build()

    def _build(self) -> None:
        schema = self.adapter.schema
        self.__dict__.pop("_held_cache", None)
        self.train = Layout.build(self.logs, "train", schema, self.excluded)
        self.holdout = Layout.build(self.logs, "holdout", schema, self.excluded)
        self.f_scale = self.noise_scale()

    def exclude(self, windows: Mapping[int, npt.NDArray[np.bool_]]) -> None:
        """Set aside windows (per log index, boolean mask over its windows) and rebuild."""
        for i, mask in windows.items():
            m = np.asarray(mask, dtype=bool)
            if m.shape != (self.logs[i].bounds.shape[0],):
                raise ValueError(
                    f"Problem.exclude: log {i} has {self.logs[i].bounds.shape[0]} windows, the "
                    f"mask has shape {m.shape}"
                )
            self.excluded[i] = m
        self._build()

    def noise_scale(self) -> float:
        """``f_scale`` of the robust loss: :attr:`AttributionSettings.robust_scale` times the
        noise level of the reference residual on the training windows.

        The noise level of each group is its robust white (window-to-window,
        MAD-based) level (:func:`white_level`); the median over groups is
        used, never less than the structure floor.
        """
        st = self.settings
        if self.train.n == 0:
            return st.robust_scale * st.floor
        z = self.nominal_residuals(self.train)
        levels = [
            white_level(z, self.train, self.train.group == g) for g in np.unique(self.train.group)
        ]
        level = max(float(np.median(levels)) if levels else 0.0, st.floor)
        return st.robust_scale * level

    def held_parameters(self, effects: Sequence[str]) -> dict[str, str]:
        """Parameters of a model that the training windows cannot identify, with the reason.

        Asked of the adapter (``adapter.held_parameters(problem, keys)``; none by default,
        the arm's geometry: its tool-distance features are linear in small parameter
        errors, so a rank test of their Jacobian decides); such parameters are held at
        nominal and reported as not testable rather than fitted into a direction the data
        cannot see. Cached per model.
        """
        keys = model_keys(effects)
        if not keys or self.train.n == 0:
            return {}
        cache = self.__dict__.setdefault("_held_cache", {})
        if keys not in cache:
            cache[keys] = dict(self.adapter.held_parameters(self, keys))
        return dict(cache[keys])

    def replay(self, i: int, values: Mapping[str, float]) -> tuple[Any, Log]:
        """PyBullet replay of log ``i`` with the effect ``values``: its features and its log
        (the problem's replay fidelity, else the log's own)."""
        p = self.logs[i]
        sim = self.sim if self.sim is not None else p.context.sim
        return self.adapter.replay_features(p, values, self.drive, sim)

    def with_baseline(self, values: Mapping[str, FloatArray], batch: int) -> dict[str, FloatArray]:
        """``values`` plus the calibrated baseline for every parameter they do not set."""
        out = dict(values)
        for k, v in self.baseline_values.items():
            if k not in out:
                out[k] = np.full(batch, v)
        return out

    def real_minus(
        self,
        layout: Layout,
        predict: Callable[[PreparedLog, int], dict[str, FloatArray]],
        batch: int,
    ) -> FloatArray:
        """Normalised residuals (B, n): real features minus ``predict(log, i)`` (B, M, k)."""
        out = np.empty((batch, layout.n))
        pos = 0
        cache: dict[int, dict[str, FloatArray]] = {}
        for i, g, wins in layout.blocks:
            p = self.logs[i]
            if i not in cache:
                cache[i] = predict(p, i)
            pred = cache[i][g][..., wins, :]
            res = (p.real[g][wins] - pred) / self.features.scale(g)
            k = res.shape[-1] * res.shape[-2]
            out[:, pos : pos + k] = res.reshape(res.shape[0] if res.ndim == 3 else 1, -1)
            pos += k
        return out

    def surrogate_residuals(
        self,
        layout: Layout,
        values: Mapping[str, FloatArray],
        batch: int,
        bias: Mapping[int, dict[str, FloatArray]] | None = None,
    ) -> FloatArray:
        """Residuals (B, n) of a batch of effect values on the bias-corrected surrogate."""

        full = self.with_baseline(values, batch)

        def predict(p: PreparedLog, i: int) -> dict[str, FloatArray]:
            sur = self.adapter.surrogate_features(p, full, self.drive)
            b = bias[i] if bias is not None and i in bias else p.bias
            return {g: sur[g] + b[g][None] for g in p.groups}

        return self.real_minus(layout, predict, batch)

    def nominal_residuals(self, layout: Layout) -> FloatArray:
        """Residual (n,) of the reference PyBullet replays: the calibrated baseline once
        :mod:`~realitygap.diagnosis.stages.baseline` has set it, else the nominal robot."""

        def predict(p: PreparedLog, i: int) -> dict[str, FloatArray]:
            feats = self.baseline_features.get(i, p.nominal)
            return {g: feats[g][None] for g in p.groups}

        return self.real_minus(layout, predict, 1)[0]
