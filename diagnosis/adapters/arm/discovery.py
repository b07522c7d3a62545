r"""Discovery on the arm: which joint-angle terms an unexplained tool-distance residual follows.

The arm's features are distances between tool points, so a term of the
residual is not a signal of the window but an error *generator*: a small
displacement :math:`\delta p_k = g(q_k)` of the tool point at every pose
:math:`k` (in the base frame, m per unit coefficient), which changes the
distance of a pair :math:`(i, j)` to first order by

.. math:: \delta d_{ij} = u_{ij}^\top \big(g(q_j) - g(q_i)\big),
    \qquad u_{ij} = \frac{p_j - p_i}{\lVert p_j - p_i \rVert} .

The library (one column per generator, one row per residual entry):

* a joint angle error that follows the joint's own angle,
  :math:`\delta q_k = c\,f(q_k)` with :math:`f \in \{\sin q_k, \cos q_k,
  \sin 2q_k, \cos 2q_k\}` (gear eccentricity, a transmission error twice per
  turn), :math:`g = c\,f(q_k)\,\partial p / \partial q_k` (coefficient in rad);
* a joint angle error that follows the joint's nominal gravity torque
  (:math:`\delta q_k = c\,\tau_k`, rad/(N·m): a compliance);
* a uniform length scale that grows with time, :math:`g = c\,(t - \bar t)\,p`
  (1/s: thermal growth or an instrument drifting during the series), and one
  that follows the reach ratio (1 per unit reach).

The sparse regression, its threshold chosen by cross-validation on the training
windows and its score on the held-out windows are those of
:func:`~realitygap.diagnosis.stages.discovery.fit_terms` (STLSQ). The residual is that of
the verdict's best model; discovery only describes it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.adapters.arm.kinematics import TOOL_DIST_PAIRS, reach_ratio
from realitygap.diagnosis.problem.parameters import split_key
from realitygap.diagnosis.problem.schemas import TOOL_DIST_COLUMNS
from realitygap.diagnosis.stages.discovery import Discovery, DiscoverySettings, fit_terms

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "STATED_NOISE_TOLERANCE",
    "arm_discovery_generators",
    "discover_arm",
    "held_out_structure",
    "pair_terms",
]

STATED_NOISE_TOLERANCE = 1.5
"""A held-out residual RMS above this multiple of the noise floor is structured: more than
the stated noise figure's own uncertainty (a data-sheet repeatability, a tracker's
specification) allows. On hundreds of distances pure noise stays within a few per cent of
the floor, so the tolerance is for the figure, not for chance."""

_STEP = 1e-6
"""Step (rad) of the central differences of the tool point by a joint angle."""


def arm_discovery_generators(ctx: Any, t: FloatArray) -> tuple[list[str], list[str], FloatArray]:
    """Names, coefficient units and displacements (N, p, 3) of every generator, m per unit.

    ``ctx`` is a prepared log's :class:`~realitygap.diagnosis.adapters.arm.adapter.ArmContext`
    (readings ``q``, holding torques ``tau``, nominal table and tool), ``t`` the
    time of each kept pose (s).
    """
    from realitygap.estimators.arm.mdh import tool_positions

    table, q, tool = ctx.params.mdh, np.asarray(ctx.q, dtype=float), np.asarray(ctx.tool)
    p0 = tool_positions(table, q, tool)
    names: list[str] = []
    units: list[str] = []
    cols: list[FloatArray] = []
    for k in range(q.shape[1]):
        dq = np.zeros_like(q)
        dq[:, k] = _STEP
        dp = (tool_positions(table, q + dq, tool) - tool_positions(table, q - dq, tool)) / (
            2 * _STEP
        )
        j = k + 1
        for label, f in (
            (f"sin q{j}", np.sin(q[:, k])),
            (f"cos q{j}", np.cos(q[:, k])),
            (f"sin 2q{j}", np.sin(2 * q[:, k])),
            (f"cos 2q{j}", np.cos(2 * q[:, k])),
        ):
            names.append(f"δq{j} ∝ {label}")
            units.append("rad")
            cols.append(f[:, None] * dp)
        names.append(f"δq{j} ∝ τ{j} (gravity)")
        units.append("rad/(N·m)")
        cols.append(np.asarray(ctx.tau, dtype=float)[:, k : k + 1] * dp)
    tc = np.asarray(t, dtype=float) - float(np.mean(t))
    names.append("length scale ∝ time")
    units.append("1/s")
    cols.append(tc[:, None] * p0)
    names.append("length scale ∝ reach")
    units.append("1")
    cols.append(reach_ratio(table, q)[:, None] * p0)
    return names, units, np.stack(cols, axis=1)


def pair_terms(
    points: FloatArray, gen: FloatArray, first: npt.ArrayLike, second: npt.ArrayLike
) -> FloatArray:
    """Distance changes (n, p) of the pairs ``(first, second)`` under each generator.

    ``points`` (N, 3) are the nominal tool points, ``gen`` (N, p, 3) the
    displacements per unit coefficient.
    """
    i, j = np.asarray(first, dtype=np.int64), np.asarray(second, dtype=np.int64)
    d = points[j] - points[i]
    u = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    return np.einsum("nc,npc->np", u, gen[j] - gen[i])


def _entry_terms(problem: Any, layout: Any, sel: npt.NDArray[np.bool_]) -> FloatArray:
    from realitygap.estimators.arm.mdh import tool_positions

    idx = np.flatnonzero(sel)
    rows: FloatArray | None = None
    for i in np.unique(layout.log[idx]):
        p = problem.logs[int(i)]
        ctx = p.context
        t = np.asarray(p.log.t, dtype=float)[ctx.rows]
        _, _, gen = arm_discovery_generators(ctx, t)
        pts = tool_positions(ctx.params.mdh, ctx.q, ctx.tool)
        m = idx[layout.log[idx] == i]
        pair = np.array(
            [TOOL_DIST_PAIRS[TOOL_DIST_COLUMNS.index(str(c))] for c in layout.column[m]]
        )
        start = p.bounds[layout.window[m], 0]
        X = pair_terms(pts, gen, start + pair[:, 0], start + pair[:, 1])
        if rows is None:
            rows = np.zeros((idx.size, X.shape[1]))
        rows[np.searchsorted(idx, m)] = X
    return rows if rows is not None else np.zeros((0, 0))


def discover_arm(
    problem: Any,
    z_train: FloatArray,
    z_holdout: FloatArray,
    mask: npt.NDArray[np.bool_] | None = None,
    settings: DiscoverySettings | None = None,
) -> Discovery:
    """The arm's discovery: the tool-distance residual regressed on the generators.

    Parameters
    ----------
    problem : Problem
        The diagnosis problem of arm logs (tool-distance group).
    z_train, z_holdout : ndarray
        Normalised residuals of the model to describe, in layout order.
    mask : ndarray of bool, optional
        Held-out entries to consider.
    settings : DiscoverySettings, optional

    Returns
    -------
    Discovery
        ``found`` when terms chosen on the training windows shrink the held-out
        residual by at least ``settings.min_shrink``; the message names them
        with their coefficients ("δq2 = +0.00061 rad·sin 2q2").
    """
    st = settings if settings is not None else DiscoverySettings()
    tr, ho = problem.train, problem.holdout
    if z_train.shape != (tr.n,) or z_holdout.shape != (ho.n,):
        raise ValueError(
            f"discover_arm: residuals must follow the layouts, ({tr.n},) and ({ho.n},); got "
            f"{z_train.shape} and {z_holdout.shape}"
        )
    a = tr.group == "tool_dist"
    b = (ho.group == "tool_dist") & (np.ones(ho.n, bool) if mask is None else np.asarray(mask))
    first = problem.logs[0].context
    names, units, _ = arm_discovery_generators(first, np.zeros(first.q.shape[0]))
    if a.sum() < st.min_windows or b.sum() < max(5, st.min_windows // 4):
        return Discovery(False, "too few windows to describe the residual", [], names)
    scale = float(np.min(problem.features.scale("tool_dist")))
    fit = fit_terms(
        _entry_terms(problem, tr, a),
        z_train[a] * scale,
        _entry_terms(problem, ho, b),
        z_holdout[b] * scale,
        names,
        units,
        groups=_blocks(tr, a),
        target="tool_dist",
        unit="m",
        settings=st,
    )
    if fit.found:
        words = "; ".join(_term_words(t) for t in fit.terms)
        message = (
            f"not in the library; the tool-point distances behave like {words} "
            f"(held-out shrink {fit.heldout_shrink_pct:.0f} %)"
        )
    else:
        message = (
            f"no term of the {len(names)}-term library describes the remaining residual on "
            f"held-out data (best held-out shrink {max(fit.heldout_shrink_pct, 0.0):.0f} %)"
        )
    return Discovery(fit.found, message, [fit], names)


def _blocks(layout: Any, sel: npt.NDArray[np.bool_]) -> npt.NDArray[np.int64]:
    """Cross-validation groups: the log, then contiguous blocks of windows within it."""
    log, win = layout.log[sel], layout.window[sel]
    out = np.empty(log.size, dtype=np.int64)
    for i in np.unique(log):
        m = log == i
        w = win[m]
        lo, hi = int(w.min()), int(w.max()) + 1
        out[m] = 5 * int(i) + np.minimum((w - lo) * 5 // max(hi - lo, 1), 4)
    return out


def _term_words(term: dict[str, Any]) -> str:
    name, coef, unit = str(term["term"]), float(term["coef"]), str(term["unit"])
    lhs, _, rhs = name.partition(" ∝ ")
    return f"{lhs} = {coef:+.3g} {unit}·{rhs}" if rhs else f"{coef:+.3g} {unit}·{name}"


def held_out_structure(
    problem: Any, values: Mapping[str, float], desc: dict[str, Any]
) -> dict[str, Any]:
    """``desc`` (:func:`~realitygap.diagnosis.problem.residual.describe_residual`) with two held-out
    tests added: is the residual of the model ``values`` structured?

    Its held-out RMS is compared with the noise floor: the noise the logs state,
    raised by the noise the fitted parameters carry onto the held-out windows
    (:func:`~realitygap.diagnosis.adapters.arm.aliases.fit_noise_inflation`); above
    :data:`STATED_NOISE_TOLERANCE` times that floor it is structured.

    A residual is structured when terms of the arm's library chosen on the
    *training* windows' residual (:func:`discover_arm`) predict the *held-out*
    residual (held-out shrink of at least
    :attr:`~realitygap.diagnosis.stages.discovery.DiscoverySettings.min_shrink`): a
    systematic part that is not noise, whatever noise level the logs state. With
    the stated noise alone a model that compensates a missing effect passes as
    soon as what it leaves is within a few times a conservative noise figure (a
    data-sheet repeatability); on noise the one-standard-error rule of the
    regression selects nothing, so a correct model is not touched. ``values``
    empty: the reference replay's residual.
    """
    if values:
        point = {k: np.array([v]) for k, v in values.items()}
        z_tr = problem.surrogate_residuals(problem.train, point, 1)[0]
        z_ho = problem.surrogate_residuals(problem.holdout, point, 1)[0]
    else:
        z_tr = problem.nominal_residuals(problem.train)
        z_ho = problem.nominal_residuals(problem.holdout)
    from realitygap.diagnosis.adapters.arm.aliases import fit_noise_inflation

    disc = discover_arm(problem, z_tr, z_ho)
    out = {**desc, "reasons": list(desc.get("reasons", ())), "held_out_structure": disc.to_json()}
    group = desc.get("groups", {}).get("tool_dist")
    if group is not None and group["white_level"] > 0.0:
        effects = sorted({split_key(k)[0] for k in values})
        inflation = fit_noise_inflation(problem.adapter, problem.logs, effects)
        ratio = group["rms"] / (group["white_level"] * inflation)
        out["noise_floor"] = {"inflation": inflation, "ratio": ratio}
        if ratio > STATED_NOISE_TOLERANCE:
            out["reasons"].append(
                f"tool_dist: held-out residual RMS is {ratio:.2f}× the noise floor (the noise "
                f"the logs state, × {inflation:.3f} for the fitted parameters' own noise)"
            )
    if disc.found:
        fit = disc.fits[0]
        out["reasons"].append(
            "tool_dist: terms fitted on the training residual predict the held-out residual "
            f"({fit.heldout_shrink_pct:.0f} % of its RMS): "
            + "; ".join(_term_words(t) for t in fit.terms)
        )
    out["structured"] = bool(out["reasons"])
    return out
