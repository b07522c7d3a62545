"""Discovery: what an unexplained residual looks like.

When no candidate effect explains the held-out gap, or the residual after the
best one is still structured, :func:`discover` regresses that residual, one
feature column at a time, on a library of candidate terms built from the
logged signals. Each robot adapter states its library through
``discovery_terms(prepared)``: a mapping from term name to its per-window
values and SI unit (wheeled: v, ω, their rates, sign and magnitude terms,
v·ω, per-wheel speeds, time; arm: sin, cos of each joint angle and of twice
it, joint gravity torques, reach, time; climber: height, surface normal
angle, tether length, time), or ``None`` (no library: nothing is discovered).
An adapter whose features are not signals of a window describes a residual its
own way instead (``discover_residual``: the arm's joint-angle error generators).

The sparse regression is sequentially thresholded least squares
(:class:`pysindy.STLSQ`) on columns scaled to unit RMS:

.. math::

    \\xi = \\arg\\min_\\xi \\lVert y - X \\xi \\rVert^2 + \\alpha \\lVert \\xi \\rVert^2,
    \\quad \\xi_j \\leftarrow 0 \\text{ where } |\\xi_j| < \\lambda \\,\\mathrm{rms}(y)

The threshold :math:`\\lambda` is chosen by cross-validation over training
logs (or blocks of windows): the sparsest threshold whose cross-validated
error is within one standard error of the best, so that noise yields no term.
The selected terms are then scored on the held-out logs; a finding needs a
held-out shrink of at least :attr:`DiscoverySettings.min_shrink`. Discovery
only describes the residual: it never changes the verdict.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.adapters.contract import RobotAdapter

FloatArray = npt.NDArray[np.float64]

__all__ = ["Discovery", "DiscoverySettings", "TermFit", "discover", "fit_terms"]


@dataclass(frozen=True)
class DiscoverySettings:
    """Settings of the sparse regression.

    Attributes
    ----------
    thresholds : tuple of float
        STLSQ thresholds to try, as fractions of the target's RMS (coefficients
        are those of unit-RMS columns).
    ridge : float
        Ridge weight ``α`` of each STLSQ least-squares step.
    folds : int
        Cross-validation folds (over training logs when there are enough,
        else over contiguous blocks of windows).
    max_terms : int
        At most this many terms are reported.
    min_shrink : float
        Held-out RMS shrink (fraction) a finding needs.
    min_windows : int
        Targets with fewer training or held-out entries are skipped.
    """

    thresholds: tuple[float, ...] = (0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3, 0.45, 0.7, 1.0)
    ridge: float = 1e-6
    folds: int = 5
    max_terms: int = 3
    min_shrink: float = 0.2
    min_windows: int = 12

    def __post_init__(self) -> None:
        if not self.thresholds or any(t <= 0 for t in self.thresholds):
            raise ValueError(
                f"thresholds: expected positive fractions, got {self.thresholds!r}; "
                "pass e.g. (0.05, 0.1, 0.2)"
            )
        if self.folds < 2:
            raise ValueError(f"folds: expected at least 2, got {self.folds}; pass folds=5")
        if not 0.0 < self.min_shrink < 1.0:
            raise ValueError(
                f"min_shrink: expected a fraction in (0, 1), got {self.min_shrink}; pass 0.2"
            )


@dataclass
class TermFit:
    """A sparse model of one residual column.

    Attributes
    ----------
    target : str
        ``"group.column"`` of the residual.
    unit : str
        SI unit of the residual (per window).
    terms : list of dict
        ``{"term", "coef", "unit"}``: coefficient in residual units per term unit.
    heldout_shrink_pct : float
        Held-out RMS shrink of the residual by the terms, %.
    cv_shrink_pct : float
        Cross-validated RMS shrink on the training data, %.
    threshold : float
        The chosen STLSQ threshold.
    found : bool
        Terms were selected and they shrink the held-out residual enough.
    """

    target: str
    unit: str
    terms: list[dict[str, Any]]
    heldout_shrink_pct: float
    cv_shrink_pct: float
    threshold: float
    found: bool

    def phrase(self) -> str:
        """The model in words: ``"dθ behaves like 0.012 (rad per rad/s²)·ω̇"``."""
        parts = [
            f"{t['coef']:+.3g} ({self.unit} per {t['unit']})·{t['term']}"
            if t["unit"]
            else f"{t['coef']:+.3g} {self.unit}·{t['term']}"
            for t in self.terms
        ]
        return f"the residual of {self.target} behaves like " + " ".join(parts).lstrip("+")


@dataclass
class Discovery:
    """Outcome of :func:`discover`.

    Attributes
    ----------
    found : bool
    message : str
        One line in words (then numbers) for the verdict.
    fits : list of TermFit
        Findings first (best held-out shrink first), then the rest.
    library : list of str
        The term names tried.
    """

    found: bool
    message: str
    fits: list[TermFit] = field(default_factory=list)
    library: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {
            "found": self.found,
            "message": self.message,
            "library": self.library,
            "fits": [
                {
                    "target": f.target,
                    "unit": f.unit,
                    "terms": f.terms,
                    "heldout_shrink_pct": f.heldout_shrink_pct,
                    "cv_shrink_pct": f.cv_shrink_pct,
                    "threshold": f.threshold,
                    "found": f.found,
                }
                for f in self.fits
            ],
        }


def _stlsq(X: FloatArray, y: FloatArray, threshold: float, ridge: float) -> FloatArray:
    from pysindy import STLSQ

    if X.shape[1] == 0:
        return np.zeros(0)
    opt = STLSQ(threshold=threshold, alpha=ridge, max_iter=20, normalize_columns=False)
    with warnings.catch_warnings():
        # "eliminated all coefficients" is an answer here (the null model), not a problem
        warnings.simplefilter("ignore", UserWarning)
        opt.fit(X, y)
    return np.asarray(opt.coef_, dtype=float).reshape(-1)


def _independent(X: FloatArray, rms: FloatArray, tol: float = 0.02) -> npt.NDArray[np.bool_]:
    """Columns kept in library order: each must not be (nearly) a combination of those
    kept before it (Gram–Schmidt residual RMS above ``tol`` of its own RMS), so that a
    wheel speed does not compete with the ``v``, ``ω`` it is made of."""
    keep = np.zeros(X.shape[1], dtype=bool)
    basis: list[FloatArray] = []
    for j in range(X.shape[1]):
        if rms[j] <= 1e-12:
            continue
        r = X[:, j] / rms[j]
        for q in basis:
            r = r - (q @ r) * q
        norm = float(np.sqrt(np.mean(r**2)))
        if norm > tol:
            keep[j] = True
            basis.append(r / np.linalg.norm(r))
    return keep


def _folds(groups: npt.NDArray[Any], n_folds: int) -> npt.NDArray[np.int64]:
    """Fold of each entry: by group (log) when there are enough, else contiguous blocks."""
    uniq = np.unique(groups)
    if uniq.size >= n_folds:
        lookup = {g: i % n_folds for i, g in enumerate(uniq)}
        return np.array([lookup[g] for g in groups], dtype=np.int64)
    n = groups.size
    return np.minimum((np.arange(n) * n_folds) // max(n, 1), n_folds - 1).astype(np.int64)


def fit_terms(
    X: FloatArray,
    y: FloatArray,
    X_ho: FloatArray,
    y_ho: FloatArray,
    names: Sequence[str],
    units: Sequence[str],
    groups: npt.ArrayLike | None = None,
    *,
    target: str = "residual",
    unit: str = "",
    settings: DiscoverySettings | None = None,
) -> TermFit:
    """Sparse model of a residual ``y`` on candidate terms ``X``, chosen by held-out error.

    Parameters
    ----------
    X, y : ndarray, shapes (n, p) and (n,)
        Training terms and residual.
    X_ho, y_ho : ndarray, shapes (m, p) and (m,)
        Held-out terms and residual (only scored, never fitted).
    names, units : sequence of str, length p
        Term names and SI units.
    groups : array-like, shape (n,), optional
        Cross-validation groups (e.g. log index); default contiguous blocks.
    target, unit : str
        Name and SI unit of the residual.
    settings : DiscoverySettings, optional

    Returns
    -------
    TermFit

    Raises
    ------
    ValueError
        Shapes that do not agree, or non-finite values.
    """
    st = settings if settings is not None else DiscoverySettings()
    X, y = np.asarray(X, dtype=float), np.asarray(y, dtype=float).reshape(-1)
    X_ho, y_ho = np.asarray(X_ho, dtype=float), np.asarray(y_ho, dtype=float).reshape(-1)
    p = len(names)
    if X.ndim != 2 or X.shape != (y.size, p) or X_ho.shape != (y_ho.size, p) or len(units) != p:
        raise ValueError(
            f"fit_terms: expected X (n, {p}), y (n,), X_ho (m, {p}), y_ho (m,) and {p} units; "
            f"got X {X.shape}, y {y.shape}, X_ho {X_ho.shape}, y_ho {y_ho.shape}, "
            f"{len(units)} units; build X from the same term list as names"
        )
    if not (np.isfinite(X).all() and np.isfinite(y).all() and np.isfinite(X_ho).all()):
        raise ValueError("fit_terms: X, y and X_ho must be finite; drop windows with gaps first")
    g = np.zeros(y.size, dtype=np.int64) if groups is None else np.asarray(groups)
    # unit-RMS columns; columns that do not vary in the training data are dropped
    rms = np.sqrt(np.mean(X**2, axis=0)) if y.size else np.zeros(p)
    keep = _independent(X, rms)
    Xs, Xhs = X[:, keep] / rms[keep], X_ho[:, keep] / rms[keep]
    y_rms = float(np.sqrt(np.mean(y**2))) if y.size else 0.0
    empty = TermFit(target, unit, [], 0.0, 0.0, math.nan, False)
    if y_rms == 0.0 or not keep.any():
        return empty
    folds = _folds(g, st.folds) if groups is not None else _folds(np.zeros(y.size), st.folds)
    k = int(folds.max()) + 1
    # cross-validated squared error per fold: the null model (no term) and each threshold
    null = np.array([float(np.sum(y[folds == f] ** 2)) for f in range(k)])
    cv = np.empty((len(st.thresholds), k))
    for i, lam in enumerate(st.thresholds):
        for f in range(k):
            tr, te = folds != f, folds == f
            xi = _stlsq(Xs[tr], y[tr], lam * y_rms, st.ridge)
            cv[i, f] = float(np.sum((y[te] - Xs[te] @ xi) ** 2))
    totals = np.concatenate([cv.sum(axis=1), [null.sum()]])
    per_fold = np.vstack([cv, null[None]])
    best = int(np.argmin(totals))
    se = float(np.std(per_fold[best] - per_fold[-1]) * math.sqrt(k))
    # one-standard-error rule towards sparsity (larger thresholds, then the null model)
    ok = [i for i in range(len(totals)) if totals[i] <= totals[best] + se]
    chosen = max(ok)
    cv_shrink = 100.0 * (1.0 - math.sqrt(totals[chosen] / null.sum()))
    if chosen == len(st.thresholds):
        return TermFit(target, unit, [], 0.0, cv_shrink, math.inf, False)
    lam = st.thresholds[chosen]
    xi = _stlsq(Xs, y, lam * y_rms, st.ridge)
    if np.count_nonzero(xi) > st.max_terms:
        # keep the largest terms and refit them alone
        top = np.argsort(-np.abs(xi))[: st.max_terms]
        xi = np.zeros_like(xi)
        xi[top] = np.linalg.lstsq(Xs[:, top], y, rcond=None)[0]
    if not np.any(xi):
        return TermFit(target, unit, [], 0.0, cv_shrink, lam, False)
    ho_rms = float(np.sqrt(np.mean(y_ho**2))) if y_ho.size else 0.0
    after = float(np.sqrt(np.mean((y_ho - Xhs @ xi) ** 2))) if y_ho.size else 0.0
    shrink = 100.0 * (1.0 - after / ho_rms) if ho_rms > 0 else 0.0
    kept_names = [n for n, kp in zip(names, keep) if kp]
    kept_units = [u for u, kp in zip(units, keep) if kp]
    coef = xi / rms[keep]
    order = np.argsort(-np.abs(xi))
    terms = [
        {"term": kept_names[j], "coef": float(coef[j]), "unit": kept_units[j]}
        for j in order
        if xi[j] != 0.0
    ]
    found = shrink >= 100.0 * st.min_shrink
    return TermFit(target, unit, terms, shrink, cv_shrink, lam, found)


def _term_matrix(
    adapter: RobotAdapter, logs: Sequence[Any]
) -> tuple[list[str], list[str], dict[int, FloatArray]] | None:
    """Term names, units and each log's (M, p) term matrix from the adapter; ``None`` when the
    adapter states no term library."""
    names: list[str] | None = None
    units: list[str] = []
    mats: dict[int, FloatArray] = {}
    for i, p in enumerate(logs):
        given: Mapping[str, tuple[FloatArray, str]] | None = adapter.discovery_terms(p)
        if given is None:
            return None
        terms = given
        if names is None:
            names = list(terms)
            units = [terms[n][1] for n in names]
        if list(terms) != names:
            raise ValueError(
                f"discovery_terms of {type(adapter).__name__}: every log must give the same "
                f"terms; log {i} gave {list(terms)}, log 0 gave {names}"
            )
        m = p.bounds.shape[0]
        cols = [np.asarray(terms[n][0], dtype=float).reshape(-1) for n in names]
        if any(c.size != m for c in cols):
            raise ValueError(
                f"discovery_terms of {type(adapter).__name__}: each term needs one value per "
                f"window ({m} in log {i})"
            )
        mats[i] = np.nan_to_num(np.column_stack(cols)) if cols else np.zeros((m, 0))
    return names or [], units, mats


def discover(
    problem: Any,
    z_train: FloatArray,
    z_holdout: FloatArray,
    mask: npt.NDArray[np.bool_] | None = None,
    settings: DiscoverySettings | None = None,
) -> Discovery | None:
    """Describe a residual by the adapter's term library, column by column.

    Parameters
    ----------
    problem : Problem
        The diagnosis problem (adapter, prepared logs, train / held-out layouts).
    z_train, z_holdout : ndarray, shapes (n_train,) and (n_holdout,)
        Normalised residuals of the model to describe, in layout order.
    mask : ndarray of bool, shape (n_holdout,), optional
        Held-out entries to consider (the gap channels); default all.
    settings : DiscoverySettings, optional

    Returns
    -------
    Discovery or None
        ``None`` when the adapter states no term library.
    """
    st = settings if settings is not None else DiscoverySettings()
    adapter = problem.adapter
    own = adapter.discover_residual(problem, z_train, z_holdout, mask, st)
    if own is not None:  # an adapter whose terms are not per window
        return cast(Discovery, own)
    matrix = _term_matrix(adapter, problem.logs)
    if matrix is None:  # the adapter states no term library
        return None
    tr, ho = problem.train, problem.holdout
    if z_train.shape != (tr.n,) or z_holdout.shape != (ho.n,):
        raise ValueError(
            f"discover: residuals must follow the layouts, ({tr.n},) and ({ho.n},); got "
            f"{z_train.shape} and {z_holdout.shape}"
        )
    names, units, mats = matrix
    sel_ho = np.ones(ho.n, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
    fits: list[TermFit] = []
    targets = sorted({(str(gr), str(c)) for gr, c in zip(ho.group[sel_ho], ho.column[sel_ho])})
    for group, column in targets:
        a = (tr.group == group) & (tr.column == column)
        b = (ho.group == group) & (ho.column == column) & sel_ho
        if a.sum() < st.min_windows or b.sum() < max(5, st.min_windows // 4):
            continue
        fg = problem.adapter.schema.group(group)
        j = fg.columns.index(column)
        scale = float(np.atleast_1d(problem.features.scale(group))[j])
        X = np.vstack([mats[i][w] for i, w in zip(tr.log[a], tr.window[a])])
        Xh = np.vstack([mats[i][w] for i, w in zip(ho.log[b], ho.window[b])])
        fits.append(
            fit_terms(
                X,
                z_train[a] * scale,
                Xh,
                z_holdout[b] * scale,
                names,
                units,
                groups=tr.log[a],
                target=f"{group}.{column}",
                unit=fg.units[j],
                settings=st,
            )
        )
    fits.sort(key=lambda f: (not f.found, -f.heldout_shrink_pct))
    found = [f for f in fits if f.found]
    if found:
        message = "not in the library; " + "; ".join(
            f"{f.phrase()} (held-out shrink {f.heldout_shrink_pct:.0f} %)" for f in found[:3]
        )
    else:
        best = max((f.heldout_shrink_pct for f in fits), default=0.0)
        message = (
            f"no term of the {len(names)}-term library describes the remaining residual on "
            f"held-out data (best held-out shrink {max(best, 0.0):.0f} %)"
        )
    return Discovery(bool(found), message, fits, names)
