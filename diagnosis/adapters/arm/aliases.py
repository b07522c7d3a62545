r"""Arm effects that the same tool-point distances cannot tell apart, and the identification
of the full geometry on the diagnosis' own windows.

Aliases
    On tool-to-tool distances some effects change the features along the same
    directions. For two effects with feature Jacobians :math:`J_A` (n × p_A) and
    :math:`J_B` (n × p_B) — derivatives of the normalised training features by
    the parameters, at nominal, from the arm's surrogate — the measured
    correlation is the first canonical correlation of their column spaces,

    .. math:: \rho_{AB} = \cos \angle_{min}\big(\mathrm{span}\,J_A, \mathrm{span}\,J_B\big),

    the largest correlation a parameter combination of A can have with one of
    B in a joint least-squares fit. :math:`\rho > 0.95` means the data cannot
    separate them: "A or B (aliases on this data)". Each member is also
    compared with the rest of its group together (a uniform length scale is
    link lengths *and* tool length at once).

Geometry by identification
    :func:`identify_window_geometry` runs the project's kinematic identification
    (:func:`~realitygap.estimators.arm.identification.identify`, distance mode:
    its identifiability analysis selects the parameters) on the pairs of poses
    inside the training windows, and scores the identified table on the held-out
    windows: the classical calibration on exactly the data the diagnosis ranks
    its candidates on.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.linalg import subspace_angles

from realitygap.diagnosis.adapters.arm.kinematics import TOOL_DIST_PAIRS
from realitygap.diagnosis.adapters.contract import PreparedLog, RobotAdapter
from realitygap.robots.effects import EFFECTS

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "ARM_ALIAS_GROUPS",
    "AliasGroup",
    "effect_jacobian",
    "fit_noise_inflation",
    "identify_window_geometry",
    "measure_aliases",
]


@dataclass(frozen=True)
class AliasGroup:
    """Effects that a kind of data may not tell apart, and why.

    Attributes
    ----------
    effects : tuple of str
        Effect names (registered arm effects).
    why : str
        The physical reason they can look alike.
    separate_by : str
        What measurement would separate them.
    """

    effects: tuple[str, ...]
    why: str
    separate_by: str


ARM_ALIAS_GROUPS: tuple[AliasGroup, ...] = (
    AliasGroup(
        ("arm_tool_offset", "arm_link_length", "arm_measurement_scale"),
        "on tool-to-tool distances a uniform length scale s is the link-length errors s*l plus "
        "a tool-length error s*t, and the tool length along the flange axis is the last link "
        "offset d6",
        "a length reference: the tracker on a calibrated scale bar, or the arm's temperature",
    ),
    AliasGroup(
        ("arm_base_compliance", "arm_joint_compliance"),
        "a base that tilts under the overturning moment turns the whole arm about an axis "
        "parallel to joint 2, as joint-2 compliance turns it about the shoulder",
        "an inclinometer on the base, or poses of equal shoulder torque at different shoulder "
        "heights",
    ),
)
"""The alias groups the arm adapter knows (see :meth:`ArmAdapter.alias_groups`)."""


def effect_jacobian(
    adapter: RobotAdapter, prepared: Sequence[PreparedLog], effect: str, held: bool = False
) -> FloatArray:
    """Derivatives (n, p) of the training features by ``effect``'s parameters.

    Central differences of the adapter's surrogate at the nominal values, a step
    of 1e-3 of each parameter's physical range; rows are the training windows'
    features of every log (the held-out windows' with ``held``; m: one unit, so
    no scale enters the correlations), columns the parameters
    (a column of zeros: a parameter the features do not see).
    """
    if effect not in EFFECTS:
        raise ValueError(f"effect must be a registered effect name, got {effect!r}")
    specs = EFFECTS[effect].specs
    blocks = []
    for p in prepared:
        wins = np.flatnonzero(p.holdout_windows == held)
        if wins.size == 0:
            continue
        batch: dict[str, FloatArray] = {}
        steps = np.array([1e-3 * (s.high - s.low) for s in specs])
        for j, s in enumerate(specs):
            v = np.full(2 * len(specs), s.nominal)
            v[2 * j] += steps[j]
            v[2 * j + 1] -= steps[j]
            batch[f"{effect}.{s.name}"] = v
        feats = adapter.surrogate_features(p, batch, None)
        F = np.concatenate(
            [feats[g][:, wins, :].reshape(2 * len(specs), -1) for g in p.groups], axis=1
        )
        blocks.append(((F[0::2] - F[1::2]) / (2.0 * steps[:, None])).T)
    if not blocks:
        raise ValueError(f"the prepared logs have no {'held-out' if held else 'training'} windows")
    return np.concatenate(blocks, axis=0)


def fit_noise_inflation(
    adapter: RobotAdapter, prepared: Sequence[PreparedLog], effects: Sequence[str]
) -> float:
    r"""Factor by which fitting ``effects`` on the training windows raises the held-out
    residual of pure noise.

    Fitting their :math:`p` parameters on training features with independent
    noise :math:`\sigma` leaves a parameter error of covariance
    :math:`\sigma^2 (J_{tr}^\top J_{tr})^{-1}`, which the held-out windows see
    on top of their own noise:

    .. math:: \frac{\sigma_{ho}}{\sigma} = \sqrt{1 + \tfrac{1}{n_{ho}}
        \mathrm{tr}\big(J_{ho} (J_{tr}^\top J_{tr})^{+} J_{ho}^\top\big)},

    with the Jacobians of :func:`effect_jacobian` stacked over the effects
    (pseudo-inverse: directions the training windows do not see add nothing).
    1 without effects.
    """
    if not effects:
        return 1.0
    J_tr = np.hstack([effect_jacobian(adapter, prepared, e) for e in effects])
    J_ho = np.hstack([effect_jacobian(adapter, prepared, e, held=True) for e in effects])
    cov = np.linalg.pinv(J_tr.T @ J_tr, rcond=1e-10, hermitian=True)
    extra = float(np.einsum("ij,jk,ik->", J_ho, cov, J_ho)) / max(J_ho.shape[0], 1)
    return float(np.sqrt(1.0 + extra))


def _span(J: FloatArray) -> FloatArray:
    norms = np.linalg.norm(J, axis=0)
    keep = norms > 1e-12 * max(float(norms.max(initial=0.0)), 1e-300)
    return J[:, keep] / norms[keep] if keep.any() else np.zeros((J.shape[0], 0))


def _correlation(A: FloatArray, B: FloatArray) -> float:
    if A.shape[1] == 0 or B.shape[1] == 0:
        return 0.0
    return float(np.cos(np.min(subspace_angles(A, B))))


def measure_aliases(
    adapter: RobotAdapter,
    prepared: Sequence[PreparedLog],
    groups: Sequence[AliasGroup] = ARM_ALIAS_GROUPS,
    threshold: float = 0.95,
    effects: Sequence[str] | None = None,
) -> list[dict[str, Any]]:
    """The first canonical correlation of every pair in every alias group, on these logs.

    Parameters
    ----------
    adapter : ArmAdapter
    prepared : sequence of PreparedLog
        Logs the diagnosis prepared (their training windows are used).
    groups : sequence of AliasGroup
    threshold : float
        Correlation above which two effects are aliases on this data.
    effects : sequence of str, optional
        Only pairs with at least one of these effects (e.g. the verdict's).

    Returns
    -------
    list of dict
        Per group: ``effects``, ``why``, ``separate_by``, ``threshold``,
        ``pairs`` (each ``{"effects": [a, b], "correlation": ρ, "aliases": bool}``),
        ``member_vs_rest`` (``{effect: ρ}`` against the other members together)
        and ``aliases`` (the pairs' effect names with ρ above the threshold).
    """
    if not 0.0 < threshold < 1.0:
        raise ValueError(f"threshold must be in (0, 1), got {threshold!r}")
    out: list[dict[str, Any]] = []
    cache: dict[str, FloatArray] = {}
    for grp in groups:
        if effects is not None and not set(effects) & set(grp.effects):
            continue
        for e in grp.effects:
            if e not in cache:
                cache[e] = _span(effect_jacobian(adapter, prepared, e))
        pairs = []
        for i, a in enumerate(grp.effects):
            for b in grp.effects[i + 1 :]:
                rho = _correlation(cache[a], cache[b])
                pairs.append({"effects": [a, b], "correlation": rho, "aliases": rho > threshold})
        rest = {}
        for e in grp.effects:
            others = [cache[o] for o in grp.effects if o != e]
            rest[e] = _correlation(cache[e], np.concatenate(others, axis=1))
        out.append(
            {
                "effects": list(grp.effects),
                "why": grp.why,
                "separate_by": grp.separate_by,
                "threshold": threshold,
                "pairs": pairs,
                "member_vs_rest": rest,
                "aliases": [p["effects"] for p in pairs if p["aliases"]],
            }
        )
    return out


def identify_window_geometry(
    prepared: Sequence[PreparedLog], pairs: str = "windows", max_poses: int = 800
) -> dict[str, Any]:
    """Identify the geometry on the training poses; score the held-out windows.

    Distance-mode :func:`~realitygap.estimators.arm.identification.identify`
    (tool point estimated, the identifiable set chosen by its own analysis), from
    the logs' nominal table and tool, on the six pairs of every training window
    (``pairs="windows"``: the diagnosis' own features) or on every pair of the
    training poses of each log (``pairs="all"``: the classical distance
    calibration, with long distances across the workspace; at most ``max_poses``
    poses per log, evenly spread, to bound memory). Returns the free
    parameters, their deltas and standard deviations, and the RMS distance
    error (m) of the held-out windows' pairs before and after.
    """
    if pairs not in ("windows", "all"):
        raise ValueError(f"pairs must be 'windows' or 'all', got {pairs!r}")
    if max_poses < 8:
        raise ValueError(f"max_poses must be at least 8, got {max_poses}")
    from realitygap.estimators.arm.identification import IdentificationSettings, identify
    from realitygap.estimators.arm.mdh import tool_positions
    from realitygap.estimators.arm.residuals import PairObservations, ResidualMode

    ctxs = [p.context for p in prepared]
    if not ctxs:
        raise ValueError("identify_window_geometry needs prepared arm logs")
    base = ctxs[0]
    for c in ctxs[1:]:
        if not c.params.mdh.isclose(base.params.mdh) or not np.allclose(c.tool, base.tool):
            raise ValueError("the logs describe different nominal arms or tools")

    def select(p: PreparedLog, held: bool, every: bool) -> tuple[FloatArray, ...]:
        wins = np.flatnonzero(p.holdout_windows == held)
        pts = np.asarray(p.log["tool_pos"], dtype=float)[p.context.rows]
        if every:
            poses = np.concatenate([np.arange(a, b) for a, b in p.bounds[wins]] or [[]])
            if poses.size > max_poses:
                poses = poses[np.linspace(0, poses.size - 1, max_poses).round().astype(int)]
            i, j = np.triu_indices(poses.size, k=1)
            ij = np.stack([poses[i], poses[j]], axis=1).astype(np.int64)
        else:
            idx = [(a + i, a + j) for a in p.bounds[wins, 0] for i, j in TOOL_DIST_PAIRS]
            ij = np.asarray(idx, dtype=np.int64).reshape(-1, 2)
        q = p.context.q
        return q[ij[:, 0]], q[ij[:, 1]], pts[ij[:, 1]] - pts[ij[:, 0]]

    def stack(held: bool, every: bool) -> PairObservations:
        parts = [select(p, held, every) for p in prepared]
        return PairObservations(*(np.concatenate([x[k] for x in parts]) for k in range(3)))

    train, test = stack(False, pairs == "all"), stack(True, False)
    res = identify(
        base.params.mdh,
        train,
        tool=base.tool,
        settings=IdentificationSettings(mode=ResidualMode.DISTANCE),
    )

    def err(table: Any, tool: FloatArray, obs: PairObservations) -> float:
        d = tool_positions(table, obs.q_to, tool) - tool_positions(table, obs.q_from, tool)
        return float(np.sqrt(np.mean((np.linalg.norm(d, axis=1) - obs.distance) ** 2)))

    before = err(base.params.mdh, base.tool, test)
    after = err(res.table, res.tool, test)
    return {
        "free_params": list(res.free_params),
        "deltas": dict(res.deltas),
        "std": dict(res.std),
        "heldout_rms_m_nominal": before,
        "heldout_rms_m_identified": after,
        "heldout_shrink_pct": 100.0 * (1.0 - after / before) if before > 0 else 0.0,
        "n_train_pairs": train.n,
        "n_heldout_pairs": test.n,
    }
