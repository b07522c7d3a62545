"""Kinematic identification of MDH parameters from distance, displacement or position data.

Observations are joint readings with measured positions of a tool point (the
optical centre of a flange camera, a laser-tracker probe). The unknowns
:math:`u` are a selection of MDH parameters (:mod:`.mdh`), the tool point in the
flange frame and, depending on the residual mode, the pose of the measurement
frame (board or tracker) relative to the arm's base:

``distance``
    For pose pairs :math:`(i, j)`: :math:`\\gamma_{ij} = \\|p_j(u) - p_i(u)\\| -
    \\|\\delta_{ij}\\|` — distance accuracy, free of the whole measurement-frame pose.
``displacement``
    :math:`\\gamma_{ij} = R_{mb}(\\omega)\\,(p_j(u) - p_i(u)) - \\delta_{ij}` with the
    measured displacement :math:`\\delta_{ij}` in the measurement frame and the
    frame rotation :math:`R_{mb} = R_0 \\operatorname{Exp}(\\omega)` estimated (three
    parameters); free of the translation.
``position``
    :math:`\\gamma_k = R_{mb}(\\omega)\\, p_k(u) + t_{mb} - m_k`, the rigid registration
    :math:`(R_{mb}, t_{mb})` estimated jointly (laser-tracker data).

Solvers: Gauss–Newton with the pseudo-inverse,

.. math::

    u_{n+1} = u_n - J^{+}(u_n)\\, e(u_n),

with step halving when the cost would rise, or ``scipy.optimize.least_squares``
(``"lm"`` or ``"trf"``). The Jacobian is analytic (:func:`.mdh.jacobian_params`
and the right Jacobian of SO(3) for the frame rotation).

Identifiability: before solving, the Jacobian at the start point is scaled to
unit columns and parameters are admitted one by one in a fixed order of
preference (frame, tool, then per joint ``a, alpha, theta, d, beta`` with ``d`` of
parallel rows and ``beta`` of non-parallel rows last); one that adds less than
``rank_tol`` of a new direction is fixed at its start value and reported by
name. This fixes, e.g., ``d2, d3`` of a UR arm (parallel axes), ``theta1, d1``
when a registration is estimated, and the last joint's parameters that the tool
point absorbs.

Optionally (``prior_std_length`` / ``prior_std_angle``) a Gaussian prior about
the start values turns the fit into a maximum-a-posteriori estimate; it helps
when the test poses lie outside the region the training poses cover.
"""

from __future__ import annotations

import difflib
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import Protocol

import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from realitygap.core.geometry import check_finite

from .handeye import solve_ax_xb
from .mdh import (
    TOOL_PARAM_NAMES,
    MDHTable,
    ParamSet,
    check_joint_angles,
    check_param_set,
    forward_kinematics,
    jacobian_params,
    tool_positions,
)

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "FRAME_PARAM_NAMES",
    "ArmCalibrationReport",
    "ErrorStats",
    "EyeInHandData",
    "Identifiability",
    "IdentificationResult",
    "IdentificationSettings",
    "LaserTrackerData",
    "PairObservations",
    "PositionObservations",
    "ResidualMode",
    "Solver",
    "analyse_identifiability",
    "calibrate_fr3",
    "calibrate_ur10",
    "identify",
    "kabsch",
    "pair_distance_errors",
    "registered_position_errors",
]

#: Names of the measurement-frame parameters: rotation vector (rad), translation (m).
FRAME_PARAM_NAMES: tuple[str, ...] = (
    "frame_rx",
    "frame_ry",
    "frame_rz",
    "frame_x",
    "frame_y",
    "frame_z",
)


class ResidualMode(str, Enum):
    """What is compared (see the module docstring)."""

    DISTANCE = "distance"
    DISPLACEMENT = "displacement"
    POSITION = "position"


class Solver(str, Enum):
    """Nonlinear least-squares solver."""

    GAUSS_NEWTON = "gauss_newton"  #: own Gauss–Newton, u <- u - J^+ e, step halving
    LM = "lm"  #: scipy.optimize.least_squares, Levenberg–Marquardt (MINPACK)
    TRF = "trf"  #: scipy.optimize.least_squares, trust-region reflective


@dataclass(frozen=True)
class IdentificationSettings:
    r"""Settings of :func:`identify`.

    Attributes
    ----------
    mode : ResidualMode
        Residual type; must match the observations (pairs for distance and
        displacement, positions for position).
    solver : Solver
    param_set : ParamSet
        ``MDH`` (five per joint) or ``DH`` (β held at its start value).
    estimate_tool : bool
        Estimate the tool point in the last joint frame.
    estimate_frame : bool
        Estimate the measurement-frame rotation (displacement) or registration
        (position); ignored in distance mode.
    fixed : tuple of str
        Parameters held at their start values in any case.
    rank_tol : float
        Admission threshold of the identifiability analysis: the fraction of a
        unit-scaled Jacobian column that must lie outside the span of the
        columns admitted before it.
    max_iterations : int
    xtol : float
        Stop when the step is below ``xtol * (|u| + xtol)``.
    ftol : float
        Stop when the cost falls by less than this fraction.
    prior_std_length, prior_std_angle : float or None
        Optional Gaussian prior on the kinematic parameters about their start
        values, std in m and rad (maximum a posteriori instead of least squares):
        rows :math:`(\sigma_e / \sigma_u)(u - u_0)` are appended to the residuals.
        ``None`` (default): no prior.
    measurement_std : float
        :math:`\sigma_e`, the std of one residual component (m), weighting the prior.
    """

    mode: ResidualMode = ResidualMode.DISPLACEMENT
    solver: Solver = Solver.GAUSS_NEWTON
    param_set: ParamSet = ParamSet.MDH
    estimate_tool: bool = True
    estimate_frame: bool = True
    fixed: tuple[str, ...] = ()
    rank_tol: float = 1e-6
    max_iterations: int = 100
    xtol: float = 1e-13
    ftol: float = 1e-15
    prior_std_length: float | None = None
    prior_std_angle: float | None = None
    measurement_std: float = 1e-4

    def __post_init__(self) -> None:
        object.__setattr__(self, "mode", _enum(ResidualMode, self.mode, "mode"))
        object.__setattr__(self, "solver", _enum(Solver, self.solver, "solver"))
        object.__setattr__(self, "param_set", check_param_set(self.param_set))
        object.__setattr__(self, "fixed", tuple(self.fixed))
        if not 0.0 < self.rank_tol < 1.0:
            raise ValueError(f"rank_tol must be in (0, 1), got {self.rank_tol!r}")
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations!r}")
        for nm in ("prior_std_length", "prior_std_angle"):
            v = getattr(self, nm)
            if v is not None and not (np.isfinite(v) and v > 0):
                raise ValueError(f"{nm} must be a positive number or None, got {v!r}")
        if not (np.isfinite(self.measurement_std) and self.measurement_std > 0):
            raise ValueError(f"measurement_std must be positive, got {self.measurement_std!r}")


def _enum(cls: type[Enum], value: object, name: str) -> Enum:
    try:
        return cls(value)
    except ValueError:
        raise ValueError(f"{name} must be one of {[m.value for m in cls]}, got {value!r}") from None


# =========================================================================== observations
@dataclass(frozen=True)
class PairObservations:
    """Measured displacements of the tool point between pose pairs.

    Attributes
    ----------
    q_from, q_to : ndarray, shape (P, n)
        Joint readings of the two poses of each pair (rad).
    displacement : ndarray, shape (P, 3)
        Measured :math:`p_{\\mathrm{to}} - p_{\\mathrm{from}}` in the measurement frame (m),
        e.g. hierarchical displacements :math:`\\delta'` in the board frame.
    """

    q_from: FloatArray
    q_to: FloatArray
    displacement: FloatArray

    def __post_init__(self) -> None:
        qf = np.asarray(self.q_from, dtype=float)
        qt = np.asarray(self.q_to, dtype=float)
        dp = np.asarray(self.displacement, dtype=float)
        if qf.ndim != 2 or qt.shape != qf.shape:
            raise ValueError(
                f"q_from and q_to must both have shape (P, n), got {qf.shape} and {qt.shape}"
            )
        if dp.shape != (qf.shape[0], 3):
            raise ValueError(f"displacement must have shape ({qf.shape[0]}, 3), got {dp.shape}")
        for nm, arr in (("q_from", qf), ("q_to", qt), ("displacement", dp)):
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{nm} must be finite")
        object.__setattr__(self, "q_from", qf)
        object.__setattr__(self, "q_to", qt)
        object.__setattr__(self, "displacement", dp)

    @property
    def n(self) -> int:
        """Number of pairs ``P``."""
        return int(self.q_from.shape[0])

    @property
    def distance(self) -> FloatArray:
        """Measured distances (P,) (m)."""
        return np.linalg.norm(self.displacement, axis=1)

    @classmethod
    def from_positions(
        cls,
        q: npt.ArrayLike,
        positions: npt.ArrayLike,
        pairs: npt.ArrayLike | None = None,
    ) -> PairObservations:
        """Pairs from absolute positions in one measurement frame.

        Parameters
        ----------
        q : array_like, shape (N, n)
            Joint readings (rad).
        positions : array_like, shape (N, 3)
            Measured tool-point positions in the measurement frame (m).
        pairs : array_like of int, shape (P, 2), optional
            Index pairs ``(from, to)``; all ``i < j`` when omitted.
        """
        qa = np.asarray(q, dtype=float)
        pa = np.asarray(positions, dtype=float)
        if qa.ndim != 2 or pa.shape != (qa.shape[0], 3):
            raise ValueError(
                f"q must have shape (N, n) and positions (N, 3), got {qa.shape} and {pa.shape}"
            )
        if pairs is None:
            i, j = np.triu_indices(qa.shape[0], k=1)
        else:
            pr = np.asarray(pairs)
            if pr.ndim != 2 or pr.shape[1] != 2 or not np.issubdtype(pr.dtype, np.integer):
                raise ValueError(f"pairs must be an int array of shape (P, 2), got {pr.shape}")
            if pr.size and (pr.min() < 0 or pr.max() >= qa.shape[0]):
                raise ValueError(f"pairs index out of range 0..{qa.shape[0] - 1}")
            i, j = pr[:, 0], pr[:, 1]
        return cls(qa[i], qa[j], pa[j] - pa[i])


@dataclass(frozen=True)
class PositionObservations:
    """Measured tool-point positions in an external measurement frame.

    Attributes
    ----------
    q : ndarray, shape (N, n)
        Joint readings (rad).
    positions : ndarray, shape (N, 3)
        Measured positions in the measurement frame (m).
    """

    q: FloatArray
    positions: FloatArray

    def __post_init__(self) -> None:
        qa = np.asarray(self.q, dtype=float)
        pa = np.asarray(self.positions, dtype=float)
        if qa.ndim != 2 or pa.shape != (qa.shape[0], 3):
            raise ValueError(
                f"q must have shape (N, n) and positions (N, 3), got {qa.shape} and {pa.shape}"
            )
        if not (np.all(np.isfinite(qa)) and np.all(np.isfinite(pa))):
            raise ValueError("q and positions must be finite")
        object.__setattr__(self, "q", qa)
        object.__setattr__(self, "positions", pa)

    @property
    def n(self) -> int:
        """Number of poses ``N``."""
        return int(self.q.shape[0])


# =========================================================================== small maths
def _skew(v: FloatArray) -> FloatArray:
    """Skew matrices (..., 3, 3) of vectors (..., 3)."""
    S = np.zeros((*v.shape[:-1], 3, 3))
    S[..., 0, 1] = -v[..., 2]
    S[..., 0, 2] = v[..., 1]
    S[..., 1, 0] = v[..., 2]
    S[..., 1, 2] = -v[..., 0]
    S[..., 2, 0] = -v[..., 1]
    S[..., 2, 1] = v[..., 0]
    return S


def _right_jacobian(w: FloatArray) -> FloatArray:
    """Right Jacobian of SO(3): :math:`\\operatorname{Exp}(w + \\delta) \\approx
    \\operatorname{Exp}(w) \\operatorname{Exp}(J_r \\delta)`."""
    th = float(np.linalg.norm(w))
    W = _skew(w)
    if th < 1e-8:
        return np.eye(3) - 0.5 * W + W @ W / 6.0
    return np.eye(3) - (1.0 - np.cos(th)) / th**2 * W + (th - np.sin(th)) / th**3 * (W @ W)


def kabsch(source: npt.ArrayLike, target: npt.ArrayLike) -> FloatArray:
    """Rigid transform (4, 4) minimising :math:`\\sum_k \\|R s_k + t - m_k\\|^2`.

    Parameters
    ----------
    source, target : array_like, shape (N, 3), N >= 3
        Corresponding points; ``source`` is moved onto ``target``.
    """
    S = np.asarray(source, dtype=float)
    M = np.asarray(target, dtype=float)
    if S.ndim != 2 or S.shape[1] != 3 or S.shape != M.shape or S.shape[0] < 3:
        raise ValueError(
            f"source and target must have the same shape (N >= 3, 3), got {S.shape}, {M.shape}"
        )
    cs, cm = S.mean(axis=0), M.mean(axis=0)
    U, _, Vt = np.linalg.svd(np.einsum("ni,nj->ij", S - cs, M - cm))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = cm - R @ cs
    return T


def _wahba(source: FloatArray, target: FloatArray) -> FloatArray:
    """Rotation (3, 3) minimising :math:`\\sum_k \\|R s_k - m_k\\|^2`."""
    U, _, Vt = np.linalg.svd(np.einsum("ni,nj->ij", source, target))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    return Vt.T @ D @ U.T


def _thin_qr(A: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Thin QR of a tall matrix (m, p) by classical Gram–Schmidt with
    re-orthogonalisation. Uses only ``einsum`` (no multithreaded BLAS), which keeps
    it fast and deterministic on busy machines; dependent columns give zero columns
    of Q and zero diagonal entries of R."""
    m, p = A.shape
    Q = np.zeros((m, p))
    R = np.zeros((p, p))
    for k in range(p):
        v = A[:, k].copy()
        for _ in range(2):
            c = np.einsum("ij,i->j", Q[:, :k], v)
            v -= np.einsum("ij,j->i", Q[:, :k], c)
            R[:k, k] += c
        nv = float(np.sqrt(np.einsum("i,i->", v, v)))
        scale = float(np.sqrt(np.einsum("i,i->", A[:, k], A[:, k])))
        if nv > 1e-14 * max(scale, 1e-300):
            Q[:, k] = v / nv
            R[k, k] = nv
    return Q, R


def _column_norms(J: FloatArray) -> FloatArray:
    return np.sqrt(np.einsum("ij,ij->j", J, J))


def _lstsq(J: FloatArray, r: FloatArray, rcond: float = 1e-12) -> FloatArray:
    """Minimum-norm least-squares solution :math:`x = J^{+} r` (columns scaled first)."""
    norms = _column_norms(J)
    norms[norms == 0] = 1.0
    Q, R = _thin_qr(J / norms)
    U, sv, Vt = np.linalg.svd(R)
    inv = np.where(sv > rcond * max(float(sv[0]), 1e-300), 1.0 / np.maximum(sv, 1e-300), 0.0)
    y = np.einsum("ij,i->j", Q, r)
    return (Vt.T @ (inv * (U.T @ y))) / norms


def _singular_values(J: FloatArray) -> FloatArray:
    """Singular values of a tall matrix (descending) through its R factor."""
    if J.shape[1] == 0:
        return np.zeros(0)
    _, R = _thin_qr(J)
    return np.asarray(np.linalg.svd(R, compute_uv=False), dtype=np.float64)


# =========================================================================== model
@dataclass(frozen=True)
class _Layout:
    """Where the parts of the parameter vector live."""

    kin_names: tuple[str, ...]
    tool_names: tuple[str, ...]
    frame_names: tuple[str, ...]

    @property
    def names(self) -> tuple[str, ...]:
        return self.kin_names + self.tool_names + self.frame_names


class _Model:
    """Residuals and their Jacobian for one mode and one set of free parameters."""

    def __init__(
        self,
        table: MDHTable,
        tool: FloatArray,
        R0: FloatArray,
        t0: FloatArray,
        obs: PairObservations | PositionObservations,
        mode: ResidualMode,
        layout: _Layout,
    ) -> None:
        self.table0 = table
        self.tool0 = tool
        self.R0 = R0
        self.t0 = t0
        self.obs = obs
        self.mode = mode
        self.layout = layout
        self.prior_w: FloatArray | None = None
        self.prior_u0: FloatArray | None = None

    def set_prior(self, weights: FloatArray) -> None:
        """Append rows ``weights * (u - u_start)`` (zero weight: no prior)."""
        self.prior_w = weights
        self.prior_u0 = self.start()

    def residual(
        self, u: FloatArray, with_jac: bool = True
    ) -> tuple[FloatArray, FloatArray | None]:
        r, J = self._residual(u, with_jac)
        if self.prior_w is None or self.prior_u0 is None:
            return r, J
        rp = self.prior_w * (u - self.prior_u0)
        Jp = None if J is None else np.vstack([J, np.diag(self.prior_w)])
        return np.concatenate([r, rp]), Jp

    def start(self) -> FloatArray:
        kin = self.table0.param_dict()
        vals = [kin[n] for n in self.layout.kin_names]
        vals += [self.tool0[TOOL_PARAM_NAMES.index(n)] for n in self.layout.tool_names]
        vals += [
            self.t0[FRAME_PARAM_NAMES.index(n) - 3] if n in FRAME_PARAM_NAMES[3:] else 0.0
            for n in self.layout.frame_names
        ]
        return np.asarray(vals, dtype=float)

    def unpack(
        self, u: FloatArray
    ) -> tuple[MDHTable, FloatArray, FloatArray, FloatArray, FloatArray]:
        lk = len(self.layout.kin_names)
        lt = len(self.layout.tool_names)
        table = self.table0.with_params(u[:lk], self.layout.kin_names) if lk else self.table0
        tool = self.tool0.copy()
        for n, v in zip(self.layout.tool_names, u[lk : lk + lt]):
            tool[TOOL_PARAM_NAMES.index(n)] = v
        w = np.zeros(3)
        t = self.t0.copy()
        for n, v in zip(self.layout.frame_names, u[lk + lt :]):
            k = FRAME_PARAM_NAMES.index(n)
            if k < 3:
                w[k] = v
            else:
                t[k - 3] = v
        R = self.R0 @ Rotation.from_rotvec(w).as_matrix()
        return table, tool, R, t, w

    def _residual(
        self, u: FloatArray, with_jac: bool = True
    ) -> tuple[FloatArray, FloatArray | None]:
        table, tool, R, t, w = self.unpack(u)
        names_p = self.layout.kin_names + self.layout.tool_names
        nf = len(self.layout.frame_names)
        if isinstance(self.obs, PositionObservations):
            q = self.obs.q
            p = tool_positions(table, q, tool)
            r = np.einsum("ij,nj->ni", R, p) + t - self.obs.positions
            if not with_jac:
                return r.reshape(-1), None
            Jp = (
                jacobian_params(table, q, names_p, tool=tool)
                if names_p
                else np.zeros((len(q), 3, 0))
            )
            Jk = np.einsum("ij,njk->nik", R, Jp)
            Jf = np.zeros((len(q), 3, nf))
            Jr = _right_jacobian(w)
            for c, n in enumerate(self.layout.frame_names):
                k = FRAME_PARAM_NAMES.index(n)
                if k < 3:
                    Jf[:, :, c] = -(R @ (_skew(p) @ Jr[:, k]).T).T
                else:
                    Jf[:, k - 3, c] = 1.0
            J = np.concatenate([Jk, Jf], axis=2)
            return r.reshape(-1), J.reshape(-1, J.shape[2])
        qf, qt = self.obs.q_from, self.obs.q_to
        d = tool_positions(table, qt, tool) - tool_positions(table, qf, tool)
        if self.mode is ResidualMode.DISTANCE:
            dist = np.linalg.norm(d, axis=1)
            r = dist - self.obs.distance
            if not with_jac:
                return r, None
            if not names_p:
                return r, np.zeros((len(r), 0))
            Jd = jacobian_params(table, qt, names_p, tool=tool) - jacobian_params(
                table, qf, names_p, tool=tool
            )
            unit = d / np.maximum(dist, 1e-12)[:, None]
            return r, np.einsum("ni,nik->nk", unit, Jd)
        r = np.einsum("ij,nj->ni", R, d) - self.obs.displacement
        if not with_jac:
            return r.reshape(-1), None
        if names_p:
            Jd = jacobian_params(table, qt, names_p, tool=tool) - jacobian_params(
                table, qf, names_p, tool=tool
            )
        else:
            Jd = np.zeros((len(d), 3, 0))
        Jk = np.einsum("ij,njk->nik", R, Jd)
        Jf = np.zeros((len(d), 3, nf))
        Jr = _right_jacobian(w)
        for c, n in enumerate(self.layout.frame_names):
            k = FRAME_PARAM_NAMES.index(n)
            Jf[:, :, c] = -(R @ (_skew(d) @ Jr[:, k]).T).T
        J = np.concatenate([Jk, Jf], axis=2)
        return r.reshape(-1), J.reshape(-1, J.shape[2])


# =========================================================================== identifiability
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
    norms = _column_norms(Jm)
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
        _, R = _thin_qr(Js)
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


def _preference_order(table: MDHTable, kin_names: Sequence[str]) -> list[str]:
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


# =========================================================================== result
@dataclass(frozen=True)
class IdentificationResult:
    """Outcome of :func:`identify`.

    Attributes
    ----------
    table : MDHTable
        Fitted geometry (fixed parameters at their start values).
    tool : ndarray, shape (3,)
        Fitted tool point in the last joint frame (m).
    T_meas_base : ndarray, shape (4, 4) or None
        Fitted pose of the base in the measurement frame (position mode: full;
        displacement mode: rotation only, zero translation; distance mode: None).
    free_params, fixed_params : tuple of str
        Estimated and fixed parameter names.
    fixed_reasons : dict of str to str
    deltas : dict of str to float
        Fitted minus start value of every free parameter (m or rad).
    std : dict of str to float
        Standard deviations from :math:`\\hat\\sigma^2 (J^\\top J)^{-1}`,
        :math:`\\hat\\sigma^2 = \\|e\\|^2 / (m - p)`.
    singular_values : ndarray
        Of the unit-column-scaled Jacobian of the free parameters at the solution.
    condition_number : float
        Their ratio max/min.
    unidentifiable : tuple of str
        Near-null parameter combinations found before fixing.
    rms_before, rms_after : float
        Root mean square of the per-observation residual norms (m) at the start
        and at the solution.
    iterations : int
    converged : bool
    mode : ResidualMode
    solver : Solver
    """

    table: MDHTable
    tool: FloatArray
    T_meas_base: FloatArray | None
    free_params: tuple[str, ...]
    fixed_params: tuple[str, ...]
    fixed_reasons: dict[str, str]
    deltas: dict[str, float]
    std: dict[str, float]
    singular_values: FloatArray
    condition_number: float
    unidentifiable: tuple[str, ...]
    rms_before: float
    rms_after: float
    iterations: int
    converged: bool
    mode: ResidualMode
    solver: Solver
    residuals: FloatArray = field(repr=False, default_factory=lambda: np.zeros(0))

    def tool_positions(self, q: npt.ArrayLike) -> FloatArray:
        """Fitted tool-point positions (N, 3) in the base frame (m)."""
        return tool_positions(self.table, q, self.tool)


def _rms(r: FloatArray, n_obs: int) -> float:
    return float(np.sqrt(np.sum(r**2) / max(n_obs, 1)))


def identify(
    table: MDHTable,
    observations: PairObservations | PositionObservations,
    *,
    tool: npt.ArrayLike | None = None,
    T_meas_base: npt.ArrayLike | None = None,
    settings: IdentificationSettings | None = None,
) -> IdentificationResult:
    """Identify kinematic parameters, tool point and measurement frame.

    Parameters
    ----------
    table : MDHTable
        Start (nominal) geometry.
    observations : PairObservations or PositionObservations
        Pairs for ``distance``/``displacement`` mode, positions for ``position`` mode.
    tool : array_like, shape (3,), optional
        Start tool point in the last joint frame (m), e.g. from hand–eye; zero if omitted.
    T_meas_base : array_like, shape (4, 4), optional
        Start pose of the base in the measurement frame; when omitted it is
        fitted to the start model (Kabsch on positions, Wahba on displacements).
    settings : IdentificationSettings, optional

    Returns
    -------
    IdentificationResult

    Raises
    ------
    ValueError
        On mismatched observations, unknown fixed names, or too few observations.
    """
    s = settings or IdentificationSettings()
    mode = ResidualMode(s.mode)
    is_pos = isinstance(observations, PositionObservations)
    if is_pos != (mode is ResidualMode.POSITION):
        raise ValueError(
            f"mode {mode.value!r} needs "
            f"{'PositionObservations' if mode is ResidualMode.POSITION else 'PairObservations'},"
            f" got {type(observations).__name__}"
        )
    n = table.n_joints
    tool0 = np.zeros(3) if tool is None else check_finite("tool", tool, (3,))
    all_names = set(table.param_names()) | set(TOOL_PARAM_NAMES) | set(FRAME_PARAM_NAMES)
    for nm in s.fixed:
        if nm not in all_names:
            close = difflib.get_close_matches(nm, sorted(all_names), n=3)
            raise ValueError(f"unknown parameter {nm!r} in fixed; did you mean {close}?")

    # ---- start frame
    if isinstance(observations, PositionObservations):
        check_joint_angles(observations.q, n)
        p_start = tool_positions(table, observations.q, tool0)
        T0 = kabsch(p_start, observations.positions)
    else:
        check_joint_angles(observations.q_from, n)
        d_start = tool_positions(table, observations.q_to, tool0) - tool_positions(
            table, observations.q_from, tool0
        )
        T0 = np.eye(4)
        if mode is ResidualMode.DISPLACEMENT:
            T0[:3, :3] = _wahba(d_start, observations.displacement)
    if T_meas_base is not None:
        T0 = check_finite("T_meas_base", T_meas_base, (4, 4))
    R0, t0 = T0[:3, :3].copy(), T0[:3, 3].copy()

    # ---- candidate parameters in order of preference
    kin_all = [nm for nm in table.param_names(s.param_set) if nm not in s.fixed]
    kin_pref = _preference_order(table, kin_all)
    tool_c = [nm for nm in TOOL_PARAM_NAMES if s.estimate_tool and nm not in s.fixed]
    if mode is ResidualMode.POSITION and s.estimate_frame:
        frame_c = [nm for nm in FRAME_PARAM_NAMES if nm not in s.fixed]
    elif mode is ResidualMode.DISPLACEMENT and s.estimate_frame:
        frame_c = [nm for nm in FRAME_PARAM_NAMES[:3] if nm not in s.fixed]
    else:
        frame_c = []
    cand = _Layout(tuple(kin_pref), tuple(tool_c), tuple(frame_c))
    model_c = _Model(table, tool0, R0, t0, observations, mode, cand)
    r0, J0 = model_c.residual(model_c.start())
    assert J0 is not None
    order = list(cand.frame_names) + list(cand.tool_names) + list(cand.kin_names)
    col = {nm: k for k, nm in enumerate(cand.names)}
    ana = analyse_identifiability(J0[:, [col[nm] for nm in order]], order, s.rank_tol)
    free = set(ana.free)
    layout = _Layout(
        tuple(nm for nm in table.param_names() if nm in free and nm in cand.kin_names),
        tuple(nm for nm in TOOL_PARAM_NAMES if nm in free),
        tuple(nm for nm in FRAME_PARAM_NAMES if nm in free),
    )
    p = len(layout.names)
    n_obs = observations.n
    if r0.size <= p:
        raise ValueError(
            f"{r0.size} residuals cannot determine {p} identifiable parameters with any "
            "redundancy; add observations"
        )
    model = _Model(table, tool0, R0, t0, observations, mode, layout)
    u0 = model.start()
    if s.prior_std_length is not None or s.prior_std_angle is not None:
        wts = np.zeros(p)
        for k, nm in enumerate(layout.kin_names):
            kind = nm.rstrip("0123456789")
            std_k = s.prior_std_length if kind in ("d", "a") else s.prior_std_angle
            if std_k is not None:
                wts[k] = s.measurement_std / std_k
        model.set_prior(wts)

    # ---- solve
    if s.solver is Solver.GAUSS_NEWTON:
        u, iterations, converged = _gauss_newton(model, u0, s)
    else:
        sol = least_squares(
            lambda x: model.residual(x, with_jac=False)[0],
            u0,
            jac=lambda x: model.residual(x)[1],
            method=s.solver.value,
            xtol=max(s.xtol, 1e-15),
            ftol=max(s.ftol, 1e-15),
            gtol=1e-15,
            x_scale="jac",
            max_nfev=s.max_iterations * 10,
        )
        u, iterations, converged = sol.x, int(sol.nfev), bool(sol.success)
    r, J = model._residual(u)  # data rows only (no prior)
    assert J is not None
    table_f, tool_f, R_f, t_f, _ = model.unpack(u)

    # ---- statistics
    norms = _column_norms(J)
    norms[norms == 0] = 1.0
    sv = _singular_values(J / norms)
    cond = float(sv[0] / sv[-1]) if p and sv[-1] > 0 else float("inf")
    dof = max(r.size - p, 1)
    sigma2 = float(np.einsum("i,i->", r, r)) / dof
    if p:
        _, Rj = _thin_qr(J / norms)
        _, sj, Vt = np.linalg.svd(Rj)
        inv = np.where(sj > sj[0] * 1e-14, 1.0 / np.maximum(sj, 1e-300) ** 2, 0.0)
        var = sigma2 * np.einsum("ki,k,ki->i", Vt, inv, Vt) / norms**2
    else:
        var = np.zeros(0)
    names = layout.names
    deltas = {nm: float(u[k] - u0[k]) for k, nm in enumerate(names)}
    std = {nm: float(np.sqrt(max(var[k], 0.0))) for k, nm in enumerate(names)}
    if mode is ResidualMode.DISTANCE:
        T_out = None
    else:
        T_out = np.eye(4)
        T_out[:3, :3] = R_f
        T_out[:3, 3] = t_f if mode is ResidualMode.POSITION else 0.0
    fixed_reasons = dict(ana.reasons)
    for nm in s.fixed:
        fixed_reasons[nm] = "fixed by the settings"
    fixed_all = tuple(nm for nm in ana.fixed) + tuple(s.fixed)
    return IdentificationResult(
        table=table_f,
        tool=tool_f,
        T_meas_base=T_out,
        free_params=names,
        fixed_params=fixed_all,
        fixed_reasons=fixed_reasons,
        deltas=deltas,
        std=std,
        singular_values=sv,
        condition_number=cond,
        unidentifiable=ana.combinations,
        rms_before=_rms(r0, n_obs),
        rms_after=_rms(r, n_obs),
        iterations=iterations,
        converged=converged,
        mode=mode,
        solver=s.solver,
        residuals=r,
    )


def _gauss_newton(
    model: _Model, u0: FloatArray, s: IdentificationSettings
) -> tuple[FloatArray, int, bool]:
    u = u0.copy()
    r, J = model.residual(u)
    cost = float(np.einsum("i,i->", r, r))
    for it in range(1, s.max_iterations + 1):
        assert J is not None
        step = -_lstsq(J, r)  # u <- u - J^+ e
        lam = 1.0
        while True:
            u_new = u + lam * step
            r_new, _ = model.residual(u_new, with_jac=False)
            cost_new = float(np.einsum("i,i->", r_new, r_new))
            if cost_new <= cost or lam < 1e-6:
                break
            lam *= 0.5
        small_step = np.linalg.norm(lam * step) <= s.xtol * (np.linalg.norm(u) + s.xtol)
        small_gain = cost - cost_new <= s.ftol * cost
        if cost_new <= cost:
            u = u_new
            r, J = model.residual(u)
            cost = float(np.einsum("i,i->", r, r))
        if small_step or small_gain or cost == 0.0:
            return u, it, True
    return u, s.max_iterations, False


# =========================================================================== evaluation helpers
@dataclass(frozen=True)
class ErrorStats:
    """Summary of error magnitudes (m)."""

    median: float
    rms: float
    p95: float
    max: float
    n: int

    @classmethod
    def of(cls, errors: npt.ArrayLike) -> ErrorStats:
        """Statistics of absolute errors (m)."""
        e = np.abs(np.asarray(errors, dtype=float).reshape(-1))
        if e.size == 0:
            raise ValueError("no errors to summarise")
        return cls(
            float(np.median(e)),
            float(np.sqrt(np.mean(e**2))),
            float(np.percentile(e, 95)),
            float(e.max()),
            int(e.size),
        )


def registered_position_errors(
    model_positions: npt.ArrayLike,
    measured_positions: npt.ArrayLike,
    T_meas_base: npt.ArrayLike | None = None,
) -> FloatArray:
    """3-D errors (N,) (m) after the rigid registration the model allows.

    With ``T_meas_base`` that registration is used; without, it is fitted to these
    points (:func:`kabsch`).
    """
    P = np.asarray(model_positions, dtype=float)
    M = np.asarray(measured_positions, dtype=float)
    T = kabsch(P, M) if T_meas_base is None else np.asarray(T_meas_base, dtype=float)
    return np.linalg.norm(np.einsum("ij,nj->ni", T[:3, :3], P) + T[:3, 3] - M, axis=1)


def pair_distance_errors(
    model_positions: npt.ArrayLike,
    measured_positions: npt.ArrayLike,
    pairs: npt.ArrayLike | None = None,
) -> FloatArray:
    """Distance-accuracy errors (P,) (m): :math:`\\|p_j - p_i\\| - \\|m_j - m_i\\|` over pairs
    (all ``i < j`` when omitted)."""
    P = np.asarray(model_positions, dtype=float)
    M = np.asarray(measured_positions, dtype=float)
    if pairs is None:
        i, j = np.triu_indices(len(P), k=1)
    else:
        pr = np.asarray(pairs)
        i, j = pr[:, 0], pr[:, 1]
    return np.linalg.norm(P[j] - P[i], axis=1) - np.linalg.norm(M[j] - M[i], axis=1)


# =========================================================================== end-to-end
class LaserTrackerData(Protocol):
    """What :func:`calibrate_ur10` needs (e.g. a UR10 laser-tracker series)."""

    @property
    def joint_angles(self) -> FloatArray:  # (N, n) rad
        ...

    @property
    def probe_positions(self) -> FloatArray:  # (N, 3) m, tracker frame
        ...

    @property
    def probe_in_flange(self) -> FloatArray:  # (3,) m, nominal probe point in the flange frame
        ...


class EyeInHandData(Protocol):
    """What :func:`calibrate_fr3` needs (an eye-in-hand camera over a fixed board)."""

    @property
    def joint_positions(self) -> FloatArray:  # (N, n) rad
        ...

    @property
    def T_board_camera(self) -> FloatArray:  # (N, 4, 4) m
        ...


@dataclass(frozen=True)
class ArmCalibrationReport:
    """Held-out accuracy of a nominal and a calibrated kinematic model.

    Attributes
    ----------
    metric : str
        What the errors are.
    nominal, calibrated : ErrorStats
        Held-out errors of the nominal and the identified model (m).
    improvement : float
        ``nominal.rms / calibrated.rms``.
    identification : IdentificationResult
        The fit on the training part.
    n_train, n_test : int
        Poses used.
    secondary : dict of str to ErrorStats
        Further held-out figures (e.g. with the training registration).
    """

    metric: str
    nominal: ErrorStats
    calibrated: ErrorStats
    improvement: float
    identification: IdentificationResult
    n_train: int
    n_test: int
    secondary: dict[str, ErrorStats]


def _check_split(
    train_idx: npt.ArrayLike, test_idx: npt.ArrayLike, n: int
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    tr = np.asarray(train_idx)
    te = np.asarray(test_idx)
    for name, a in (("train_idx", tr), ("test_idx", te)):
        if a.ndim != 1 or a.size == 0 or not np.issubdtype(a.dtype, np.integer):
            raise ValueError(f"{name} must be a non-empty 1-D int array, got shape {a.shape}")
        if a.min() < 0 or a.max() >= n:
            raise ValueError(f"{name} indexes outside 0..{n - 1}")
    if np.intersect1d(tr, te).size:
        raise ValueError("train_idx and test_idx overlap; held-out poses must not be trained on")
    return tr.astype(np.int64), te.astype(np.int64)


def calibrate_ur10(
    dataset: LaserTrackerData,
    train_idx: npt.ArrayLike,
    test_idx: npt.ArrayLike,
    *,
    table: MDHTable | None = None,
    settings: IdentificationSettings | None = None,
) -> ArmCalibrationReport:
    """Identify MDH + registration + probe offset on laser-tracker data, test held out.

    Parameters
    ----------
    dataset : LaserTrackerData
        Joint angles (N, 6), probe positions (N, 3) in the tracker frame and the
        nominal probe point in the flange frame.
    train_idx, test_idx : array_like of int
        Disjoint pose indices.
    table : MDHTable, optional
        Nominal geometry (:meth:`MDHTable.ur10` by default).
    settings : IdentificationSettings, optional
        Default: position mode, Gauss–Newton, MDH, tool and registration estimated.

    Returns
    -------
    ArmCalibrationReport
        ``nominal``/``calibrated``: 3-D position errors of the held-out poses after
        the rigid registration refitted on them (what a rigid fit of model to
        tracker allows); ``secondary["*_train_registration"]``: with the
        registration of the training fit instead.
    """
    q = np.asarray(dataset.joint_angles, dtype=float)
    m = np.asarray(dataset.probe_positions, dtype=float)
    tool0 = np.asarray(dataset.probe_in_flange, dtype=float).reshape(3)
    tr, te = _check_split(train_idx, test_idx, len(q))
    tab = table or MDHTable.ur10()
    s = settings or IdentificationSettings(mode=ResidualMode.POSITION)
    if s.mode is not ResidualMode.POSITION:
        raise ValueError("calibrate_ur10 needs settings.mode = 'position'")
    res = identify(tab, PositionObservations(q[tr], m[tr]), tool=tool0, settings=s)
    p_nom_tr = tool_positions(tab, q[tr], tool0)
    T_nom = kabsch(p_nom_tr, m[tr])
    p_nom = tool_positions(tab, q[te], tool0)
    p_cal = res.tool_positions(q[te])
    nominal = ErrorStats.of(registered_position_errors(p_nom, m[te]))
    calibrated = ErrorStats.of(registered_position_errors(p_cal, m[te]))
    secondary = {
        "nominal_train_registration": ErrorStats.of(
            registered_position_errors(p_nom, m[te], T_nom)
        ),
        "calibrated_train_registration": ErrorStats.of(
            registered_position_errors(p_cal, m[te], res.T_meas_base)
        ),
        "nominal_train_fit": ErrorStats.of(registered_position_errors(p_nom_tr, m[tr])),
        "calibrated_train_fit": ErrorStats.of(
            registered_position_errors(res.tool_positions(q[tr]), m[tr])
        ),
    }
    return ArmCalibrationReport(
        metric="3-D probe position error after rigid registration (m)",
        nominal=nominal,
        calibrated=calibrated,
        improvement=nominal.rms / max(calibrated.rms, 1e-300),
        identification=res,
        n_train=int(tr.size),
        n_test=int(te.size),
        secondary=secondary,
    )


def calibrate_fr3(
    dataset: EyeInHandData,
    train_idx: npt.ArrayLike,
    test_idx: npt.ArrayLike,
    *,
    table: MDHTable | None = None,
    settings: IdentificationSettings | None = None,
) -> ArmCalibrationReport:
    """Identify MDH + camera point + board rotation from eye-in-hand board poses.

    The tool point is the camera's optical centre. Its start value and the
    board's start rotation come from an :math:`AX = XB` hand–eye calibration
    (:func:`~.handeye.solve_ax_xb`) on the training poses with the nominal model;
    the identification then fits displacement residuals between all training
    pose pairs.

    Parameters
    ----------
    dataset : EyeInHandData
        Joint positions (N, n) and camera poses in the board frame (N, 4, 4).
    train_idx, test_idx : array_like of int
        Disjoint pose indices.
    table : MDHTable, optional
        Nominal geometry (:meth:`MDHTable.franka_fr3` by default).
    settings : IdentificationSettings, optional
        Default: displacement mode, Gauss–Newton, MDH, tool and board rotation estimated.

    Returns
    -------
    ArmCalibrationReport
        ``nominal``/``calibrated``: distance-accuracy errors
        :math:`\\|p_j - p_i\\|_{\\mathrm{model}} - \\|c_j - c_i\\|_{\\mathrm{camera}}`
        over all pairs of held-out poses; ``secondary["*_displacement"]``: 3-D
        displacement errors with the board rotation of the respective model.
    """
    q = np.asarray(dataset.joint_positions, dtype=float)
    C = np.asarray(dataset.T_board_camera, dtype=float)
    if C.ndim != 3 or C.shape[1:] != (4, 4) or C.shape[0] != q.shape[0]:
        raise ValueError(f"T_board_camera must have shape ({q.shape[0]}, 4, 4), got {C.shape}")
    tr, te = _check_split(train_idx, test_idx, len(q))
    tab = table or MDHTable.franka_fr3()
    s = settings or IdentificationSettings(mode=ResidualMode.DISPLACEMENT)
    if s.mode is ResidualMode.POSITION:
        raise ValueError("calibrate_fr3 needs settings.mode = 'distance' or 'displacement'")
    he = solve_ax_xb(forward_kinematics(tab, q[tr]), C[tr])
    tool0 = he.T_flange_camera[:3, 3].copy()
    assert he.T_base_board is not None
    T0 = np.eye(4)
    T0[:3, :3] = he.T_base_board[:3, :3].T  # rotation of the base seen from the board
    cam = C[:, :3, 3]
    res = identify(
        tab,
        PairObservations.from_positions(q[tr], cam[tr]),
        tool=tool0,
        T_meas_base=T0,
        settings=s,
    )
    p_nom = tool_positions(tab, q[te], tool0)
    p_cal = res.tool_positions(q[te])
    nominal = ErrorStats.of(pair_distance_errors(p_nom, cam[te]))
    calibrated = ErrorStats.of(pair_distance_errors(p_cal, cam[te]))
    i, j = np.triu_indices(te.size, k=1)
    R_nom = T0[:3, :3]
    R_cal = res.T_meas_base[:3, :3] if res.T_meas_base is not None else R_nom
    d_meas = cam[te][j] - cam[te][i]
    secondary = {
        "nominal_displacement": ErrorStats.of(
            np.linalg.norm(np.einsum("ab,nb->na", R_nom, p_nom[j] - p_nom[i]) - d_meas, axis=1)
        ),
        "calibrated_displacement": ErrorStats.of(
            np.linalg.norm(np.einsum("ab,nb->na", R_cal, p_cal[j] - p_cal[i]) - d_meas, axis=1)
        ),
        "nominal_train_distance": ErrorStats.of(
            pair_distance_errors(tool_positions(tab, q[tr], tool0), cam[tr])
        ),
        "calibrated_train_distance": ErrorStats.of(
            pair_distance_errors(res.tool_positions(q[tr]), cam[tr])
        ),
    }
    return ArmCalibrationReport(
        metric="distance-accuracy error between held-out pose pairs (m)",
        nominal=nominal,
        calibrated=calibrated,
        improvement=nominal.rms / max(calibrated.rms, 1e-300),
        identification=res,
        n_train=int(tr.size),
        n_test=int(te.size),
        secondary=secondary,
    )
