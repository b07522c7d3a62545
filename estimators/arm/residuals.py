"""Observations of the tool point and the residuals the kinematic identification minimises.

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

The Jacobian is analytic (:func:`.mdh.jacobian_params` and the right Jacobian of
SO(3) for the frame rotation).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from realitygap.core.geometry import hat, hat_batch

from .mdh import TOOL_PARAM_NAMES, MDHTable, jacobian_params, tool_positions

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "FRAME_PARAM_NAMES",
    "PairObservations",
    "ParameterLayout",
    "PositionObservations",
    "ResidualMode",
    "ResidualModel",
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
    """What is compared (see the module docstring of :mod:`.residuals`)."""

    DISTANCE = "distance"
    DISPLACEMENT = "displacement"
    POSITION = "position"


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


# =========================================================================== frame rotation
def _right_jacobian(w: FloatArray) -> FloatArray:
    """Right Jacobian of SO(3): :math:`\\operatorname{Exp}(w + \\delta) \\approx
    \\operatorname{Exp}(w) \\operatorname{Exp}(J_r \\delta)`.

    The same map as :func:`realitygap.core.geometry.right_jacobian`, evaluated in
    another order (norm by ``np.linalg.norm``, series below 1e-8 rad, ``c * (W @ W)``),
    which rounds differently in the last bit; the identification's figures rest on
    this one.
    """
    th = float(np.linalg.norm(w))
    W = hat(w)
    if th < 1e-8:
        return np.eye(3) - 0.5 * W + W @ W / 6.0
    return np.eye(3) - (1.0 - np.cos(th)) / th**2 * W + (th - np.sin(th)) / th**3 * (W @ W)


# =========================================================================== model
@dataclass(frozen=True)
class ParameterLayout:
    """Where the parts of the parameter vector live."""

    kin_names: tuple[str, ...]
    tool_names: tuple[str, ...]
    frame_names: tuple[str, ...]

    @property
    def names(self) -> tuple[str, ...]:
        return self.kin_names + self.tool_names + self.frame_names


class ResidualModel:
    """Residuals and their Jacobian for one mode and one set of free parameters."""

    def __init__(
        self,
        table: MDHTable,
        tool: FloatArray,
        R0: FloatArray,
        t0: FloatArray,
        obs: PairObservations | PositionObservations,
        mode: ResidualMode,
        layout: ParameterLayout,
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
        """Residuals (prior rows appended when set) and their Jacobian at ``u``."""
        r, J = self.data_residual(u, with_jac)
        if self.prior_w is None or self.prior_u0 is None:
            return r, J
        rp = self.prior_w * (u - self.prior_u0)
        Jp = None if J is None else np.vstack([J, np.diag(self.prior_w)])
        return np.concatenate([r, rp]), Jp

    def start(self) -> FloatArray:
        """Parameter vector of the start values, in the order of :attr:`layout`."""
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
        """Table, tool point, frame rotation, frame translation and rotation vector at ``u``."""
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

    def data_residual(
        self, u: FloatArray, with_jac: bool = True
    ) -> tuple[FloatArray, FloatArray | None]:
        """Residuals of the observations (no prior rows) and their Jacobian at ``u``."""
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
                    Jf[:, :, c] = -(R @ (hat_batch(p) @ Jr[:, k]).T).T
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
            Jf[:, :, c] = -(R @ (hat_batch(d) @ Jr[:, k]).T).T
        J = np.concatenate([Jk, Jf], axis=2)
        return r.reshape(-1), J.reshape(-1, J.shape[2])
