"""Which kinematic parameters a set of observations can identify.

Before solving, the Jacobian at the start point is scaled to unit columns and
parameters are admitted one by one in a fixed order of preference (frame, tool,
then per joint ``a, alpha, theta, d, beta`` with ``d`` of parallel rows and
``beta`` of non-parallel rows last); one that adds less than ``rank_tol`` of a
new direction is fixed at its start value and reported by name. This fixes,
e.g., ``d2, d3`` of a UR arm (parallel axes), ``theta1, d1`` when a registration
is estimated, and the last joint's parameters that the tool point absorbs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .least_squares import column_norms, thin_qr
from .mdh import MDHTable

FloatArray = npt.NDArray[np.float64]

__all__ = ["Identifiability", "analyse_identifiability", "preference_order"]


@dataclass(frozen=True)
class Identifiability:
    """Identifiability of candidate parameters at one linearisation point.

    Attributes
    ----------
    names : tuple of str
        Candidate parameters, in the order of preference.
    free : tuple of str
        Admitted (identifiable) parameters.
    fixed : tuple of str
        Parameters fixed because they have no effect or are (numerically) linear
        combinations of parameters admitted before them.
    reasons : dict of str to str
        Why each fixed parameter was fixed.
    singular_values : ndarray
        Singular values of the unit-column-scaled Jacobian of all candidates,
        descending.
    combinations : tuple of str
        The near-null directions of that Jacobian as readable combinations.
    rank : int
    """

    names: tuple[str, ...]
    free: tuple[str, ...]
    fixed: tuple[str, ...]
    reasons: dict[str, str]
    singular_values: FloatArray
    combinations: tuple[str, ...]
    rank: int


def analyse_identifiability(
    J: npt.ArrayLike, names: Sequence[str], rank_tol: float = 1e-6
) -> Identifiability:
    """Greedy identifiable subset and near-null combinations of a Jacobian.

    Columns are scaled to unit norm (lengths and angles become comparable). In
    the given order, a column is admitted when the component orthogonal to the
    span of the admitted ones has norm ``> rank_tol``; otherwise the parameter
    is fixed.

    Parameters
    ----------
    J : array_like, shape (m, p)
        Residual Jacobian.
    names : sequence of str, length p
        Parameter names, most wanted first.
    rank_tol : float

    Returns
    -------
    Identifiability
    """
    Jm = np.asarray(J, dtype=float)
    names = tuple(names)
    if Jm.ndim != 2 or Jm.shape[1] != len(names):
        raise ValueError(f"J must have shape (m, {len(names)}), got {Jm.shape}")
    norms = column_norms(Jm)
    scale_ref = float(norms.max()) if norms.size else 0.0
    free: list[str] = []
    fixed: list[str] = []
    reasons: dict[str, str] = {}
    basis: list[FloatArray] = []
    for k, nm in enumerate(names):
        if norms[k] <= 1e-12 * max(scale_ref, 1e-300):
            fixed.append(nm)
            reasons[nm] = "no effect on the residuals"
            continue
        v = Jm[:, k] / norms[k]
        if basis:
            B = np.column_stack(basis)
            for _ in range(2):
                v = v - np.einsum("ij,j->i", B, np.einsum("ij,i->j", B, v))
        rest = float(np.sqrt(np.einsum("i,i->", v, v)))
        if rest > rank_tol:
            basis.append(v / rest)
            free.append(nm)
        else:
            fixed.append(nm)
            reasons[nm] = (
                f"linearly dependent on the parameters before it (residual direction {rest:.1e})"
            )
    ok = norms > 1e-12 * max(scale_ref, 1e-300)
    Js = Jm[:, ok] / norms[ok]
    nm_ok = [n for n, o in zip(names, ok) if o]
    if Js.size:
        _, R = thin_qr(Js)
        _, s, Vt = np.linalg.svd(R)
    else:
        s, Vt = np.zeros(0), np.zeros((0, 0))
    combos = []
    for sv, v in zip(s, Vt):
        if sv <= rank_tol * max(float(s[0]) if s.size else 1.0, 1e-300):
            top = np.argsort(-np.abs(v))[:4]
            terms = [f"{v[i]:+.2f}*{nm_ok[i]}" for i in top if abs(v[i]) > 0.05]
            combos.append(" ".join(terms))
    return Identifiability(
        names, tuple(free), tuple(fixed), reasons, s, tuple(combos), int(len(free))
    )


def preference_order(table: MDHTable, kin_names: Sequence[str]) -> list[str]:
    """Kinematic parameter names in the order they are admitted: per joint
    ``a, alpha, theta, d, beta``, with ``d`` of parallel rows and ``beta`` of
    non-parallel rows moved to the end."""
    par = table.parallel_rows
    first: list[str] = []
    last: list[str] = []
    for i in range(table.n_joints):
        tag = str(i + 1)
        for kind in ("a", "alpha", "theta", "d", "beta"):
            nm = kind + tag
            if nm not in kin_names:
                continue
            demote = (kind == "d" and par[i]) or (kind == "beta" and not par[i])
            (last if demote else first).append(nm)
    return first + last
