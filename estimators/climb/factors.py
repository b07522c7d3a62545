"""Factors of the sliding-window VIO: keyframe states, residuals and the window problem.

:class:`WindowState` is one keyframe state :math:`(R, p, v, b_g, b_a)`,
:class:`WindowPrior` the Gaussian prior left by marginalisation,
:class:`ImuFactor` and :class:`VisualFactor` the whitened factors between
consecutive states; :func:`prior_residual`, :func:`imu_residual` and
:func:`visual_residual` evaluate one factor with its analytic Jacobians, and
:class:`WindowProblem` evaluates all of them at once over a :class:`StateStack`
and accumulates the block-tridiagonal normal equations.

Frames: ``world`` is the VIO frame, gravity along :math:`-z`, its origin and yaw
those of the body at initialisation; ``body`` = IMU frame (x forward, z away from
the surface); ``camera`` is OpenCV's optical frame (z along the optical axis).
Rotations are matrices :math:`R_{wb}` (body → world); quaternions are xyzw.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import (
    hat,
    hat_batch,
    right_jacobian,
    right_jacobian_batch,
    right_jacobian_inv,
    right_jacobian_inv_batch,
    so3_exp,
    so3_exp_batch,
    so3_log,
    so3_log_batch,
)
from realitygap.estimators.climb.preintegration import Preintegration

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "ImuFactor",
    "StateStack",
    "VisualFactor",
    "WindowPrior",
    "WindowProblem",
    "WindowState",
    "imu_residual",
    "prior_residual",
    "visual_residual",
    "whitener",
]


@dataclass
class WindowState:
    t: float
    R: FloatArray
    p: FloatArray
    v: FloatArray
    bg: FloatArray
    ba: FloatArray

    def copy(self) -> WindowState:
        return WindowState(
            self.t, self.R.copy(), self.p.copy(), self.v.copy(), self.bg.copy(), self.ba.copy()
        )

    def retract(self, d: FloatArray) -> WindowState:
        return WindowState(
            self.t,
            self.R @ so3_exp(d[0:3]),
            self.p + d[3:6],
            self.v + d[6:9],
            self.bg + d[9:12],
            self.ba + d[12:15],
        )


@dataclass
class WindowPrior:
    mean: WindowState
    W: FloatArray  # (15, 15) whitening: r = W [Log(R_m^T R), p - p_m, ...]


@dataclass
class ImuFactor:
    pre: Preintegration
    W: FloatArray  # (9, 9)
    W_bias: FloatArray  # (6, 6)


@dataclass
class VisualFactor:
    dR: FloatArray
    dp: FloatArray
    W: FloatArray  # (6, 6)


def whitener(cov: FloatArray) -> FloatArray:
    """:math:`W` with :math:`W^\\top W = \\Sigma^{-1}` (inverse Cholesky factor)."""
    cov = 0.5 * (cov + cov.T) + 1e-15 * np.eye(len(cov))
    return np.linalg.inv(np.linalg.cholesky(cov))


def imu_residual(
    si: WindowState, sj: WindowState, f: ImuFactor, g: FloatArray, want_jac: bool
) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """15 whitened rows [rR, rv, rp, rbg, rba]; Jacobians wrt state i and j (15 × 15 each)."""
    pre = f.pre
    T = pre.dt
    dbg = si.bg - pre.bias_gyro
    dba = si.ba - pre.bias_accel
    corr = pre.J_R_bg @ dbg
    dRc = pre.delta_R @ so3_exp(corr)
    RiT = si.R.T
    E = dRc.T @ RiT @ sj.R
    rR = so3_log(E)
    dv_w = sj.v - si.v - g * T
    dp_w = sj.p - si.p - si.v * T - 0.5 * g * T * T
    rv = RiT @ dv_w - (pre.delta_v + pre.J_v_bg @ dbg + pre.J_v_ba @ dba)
    rp = RiT @ dp_w - (pre.delta_p + pre.J_p_bg @ dbg + pre.J_p_ba @ dba)
    r9 = np.concatenate([rR, rv, rp])
    rb = np.concatenate([sj.bg - si.bg, sj.ba - si.ba])
    r = np.concatenate([f.W @ r9, f.W_bias @ rb])
    if not want_jac:
        return r, None, None
    Ji = np.zeros((9, 15))
    Jj = np.zeros((9, 15))
    Jrinv = right_jacobian_inv(rR)
    Ji[0:3, 0:3] = -Jrinv @ sj.R.T @ si.R
    Jj[0:3, 0:3] = Jrinv
    Ji[0:3, 9:12] = -Jrinv @ E.T @ right_jacobian(corr) @ pre.J_R_bg
    Ji[3:6, 0:3] = hat(RiT @ dv_w)
    Ji[3:6, 6:9] = -RiT
    Jj[3:6, 6:9] = RiT
    Ji[3:6, 9:12] = -pre.J_v_bg
    Ji[3:6, 12:15] = -pre.J_v_ba
    Ji[6:9, 0:3] = hat(RiT @ dp_w)
    Ji[6:9, 3:6] = -RiT
    Jj[6:9, 3:6] = RiT
    Ji[6:9, 6:9] = -RiT * T
    Ji[6:9, 9:12] = -pre.J_p_bg
    Ji[6:9, 12:15] = -pre.J_p_ba
    Ji_full = np.zeros((15, 15))
    Jj_full = np.zeros((15, 15))
    Ji_full[:9] = f.W @ Ji
    Jj_full[:9] = f.W @ Jj
    Ji_full[9:, 9:] = -f.W_bias
    Jj_full[9:, 9:] = f.W_bias
    return r, Ji_full, Jj_full


def visual_residual(
    si: WindowState, sj: WindowState, f: VisualFactor, want_jac: bool
) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """6 whitened rows [rR, rp]; Jacobians wrt state i and j (6 × 15 each)."""
    RiT = si.R.T
    E = f.dR.T @ RiT @ sj.R
    rR = so3_log(E)
    d = sj.p - si.p
    rp = RiT @ d - f.dp
    r = f.W @ np.concatenate([rR, rp])
    if not want_jac:
        return r, None, None
    Ji = np.zeros((6, 15))
    Jj = np.zeros((6, 15))
    Jrinv = right_jacobian_inv(rR)
    Ji[0:3, 0:3] = -Jrinv @ sj.R.T @ si.R
    Jj[0:3, 0:3] = Jrinv
    Ji[3:6, 0:3] = hat(RiT @ d)
    Ji[3:6, 3:6] = -RiT
    Jj[3:6, 3:6] = RiT
    return r, f.W @ Ji, f.W @ Jj


def prior_residual(
    s: WindowState, prior: WindowPrior, want_jac: bool
) -> tuple[FloatArray, FloatArray | None]:
    m = prior.mean
    rR = so3_log(m.R.T @ s.R)
    e = np.concatenate([rR, s.p - m.p, s.v - m.v, s.bg - m.bg, s.ba - m.ba])
    r = prior.W @ e
    if not want_jac:
        return r, None
    J = np.eye(15)
    J[0:3, 0:3] = right_jacobian_inv(rR)
    return r, prior.W @ J


@dataclass
class StateStack:
    """Window states as arrays: ``R`` (n, 3, 3), ``p, v, bg, ba`` (n, 3)."""

    R: FloatArray
    p: FloatArray
    v: FloatArray
    bg: FloatArray
    ba: FloatArray

    @classmethod
    def of(cls, states: Sequence[WindowState]) -> StateStack:
        return cls(
            np.array([s.R for s in states]),
            np.array([s.p for s in states]),
            np.array([s.v for s in states]),
            np.array([s.bg for s in states]),
            np.array([s.ba for s in states]),
        )

    def retract(self, dx: FloatArray) -> StateStack:
        """Right perturbation by ``dx`` (n, 15) = [δθ, δp, δv, δb_g, δb_a] per state."""
        return StateStack(
            self.R @ so3_exp_batch(dx[:, 0:3]),
            self.p + dx[:, 3:6],
            self.v + dx[:, 6:9],
            self.bg + dx[:, 9:12],
            self.ba + dx[:, 12:15],
        )

    def states(self, times: Sequence[float]) -> list[WindowState]:
        return [
            WindowState(t, self.R[k], self.p[k], self.v[k], self.bg[k], self.ba[k])
            for k, t in enumerate(times)
        ]


class WindowProblem:
    """The window's least-squares problem with every factor evaluated at once.

    Same residuals and analytic Jacobians as :func:`prior_residual`,
    :func:`imu_residual` and :func:`visual_residual` (which stay the reference and
    serve the marginalisation), stacked over the window's ``K = n - 1`` IMU factors
    and its visual factors, and accumulated straight into the blocks of the
    block-tridiagonal normal equations.
    """

    def __init__(
        self,
        imu: Sequence[ImuFactor],
        vis: Sequence[VisualFactor | None],
        prior: WindowPrior,
        gravity: FloatArray,
        loss_scale: float,
        robust: bool,
    ) -> None:
        pres = [f.pre for f in imu]
        self.T = np.array([q.dt for q in pres])
        self.dR = np.array([q.delta_R for q in pres])
        self.dv = np.array([q.delta_v for q in pres])
        self.dp = np.array([q.delta_p for q in pres])
        self.bg0 = np.array([q.bias_gyro for q in pres])
        self.ba0 = np.array([q.bias_accel for q in pres])
        self.J_R_bg = np.array([q.J_R_bg for q in pres])
        self.J_v_bg = np.array([q.J_v_bg for q in pres])
        self.J_v_ba = np.array([q.J_v_ba for q in pres])
        self.J_p_bg = np.array([q.J_p_bg for q in pres])
        self.J_p_ba = np.array([q.J_p_ba for q in pres])
        self.W = np.array([f.W for f in imu])
        self.W_bias = np.array([f.W_bias for f in imu])
        self.vis_idx = np.array([k for k, f in enumerate(vis) if f is not None], dtype=int)
        present = [f for f in vis if f is not None]
        self.vis_dR = np.array([f.dR for f in present]).reshape(-1, 3, 3)
        self.vis_dp = np.array([f.dp for f in present]).reshape(-1, 3)
        self.vis_W = np.array([f.W for f in present]).reshape(-1, 6, 6)
        self.prior = prior
        self.g = gravity
        self.k_h = loss_scale
        self.robust = robust

    def linearise(self, X: StateStack) -> tuple[float, FloatArray, FloatArray, FloatArray]:
        """Robust cost and ``D (n, 15, 15), B (n-1, 15, 15), b (n, 15)`` as in
        :meth:`.SlidingWindowVIO._normal_equations`."""
        n = len(X.p)
        D = np.zeros((n, 15, 15))
        B = np.zeros((n - 1, 15, 15))
        b = np.zeros((n, 15))
        # prior on state 0
        s0 = WindowState(0.0, X.R[0], X.p[0], X.v[0], X.bg[0], X.ba[0])
        r0, J0 = prior_residual(s0, self.prior, True)
        assert J0 is not None
        cost = float(r0 @ r0)
        D[0] += J0.T @ J0
        b[0] += J0.T @ r0
        if n < 2:
            return cost, D, B, b
        # IMU factors k: states k → k + 1
        T, g = self.T, self.g
        Ri, Rj = X.R[:-1], X.R[1:]
        RiT = np.swapaxes(Ri, 1, 2)
        dbg = X.bg[:-1] - self.bg0
        dba = X.ba[:-1] - self.ba0
        corr = np.einsum("kij,kj->ki", self.J_R_bg, dbg)
        dRc = self.dR @ so3_exp_batch(corr)
        RiT_Rj = RiT @ Rj
        E = np.swapaxes(dRc, 1, 2) @ RiT_Rj
        rR = so3_log_batch(E)
        dv_w = X.v[1:] - X.v[:-1] - g * T[:, None]
        dp_w = X.p[1:] - X.p[:-1] - X.v[:-1] * T[:, None] - 0.5 * g * (T * T)[:, None]
        bv = np.einsum("kij,kj->ki", RiT, dv_w)
        bp = np.einsum("kij,kj->ki", RiT, dp_w)
        mv = lambda J, x: np.einsum("kij,kj->ki", J, x)  # noqa: E731
        rv = bv - (self.dv + mv(self.J_v_bg, dbg) + mv(self.J_v_ba, dba))
        rp = bp - (self.dp + mv(self.J_p_bg, dbg) + mv(self.J_p_ba, dba))
        r9 = np.concatenate([rR, rv, rp], axis=1)
        rb = np.concatenate([X.bg[1:] - X.bg[:-1], X.ba[1:] - X.ba[:-1]], axis=1)
        r = np.concatenate([mv(self.W, r9), mv(self.W_bias, rb)], axis=1)  # (K, 15)
        cost += float(np.sum(r * r))
        K = len(T)
        Ji = np.zeros((K, 9, 15))
        Jj = np.zeros((K, 9, 15))
        Jrinv = right_jacobian_inv_batch(rR)
        Ji[:, 0:3, 0:3] = -Jrinv @ np.swapaxes(RiT_Rj, 1, 2)
        Jj[:, 0:3, 0:3] = Jrinv
        Ji[:, 0:3, 9:12] = -Jrinv @ np.swapaxes(E, 1, 2) @ right_jacobian_batch(corr) @ self.J_R_bg
        Ji[:, 3:6, 0:3] = hat_batch(bv)
        Ji[:, 3:6, 6:9] = -RiT
        Jj[:, 3:6, 6:9] = RiT
        Ji[:, 3:6, 9:12] = -self.J_v_bg
        Ji[:, 3:6, 12:15] = -self.J_v_ba
        Ji[:, 6:9, 0:3] = hat_batch(bp)
        Ji[:, 6:9, 3:6] = -RiT
        Jj[:, 6:9, 3:6] = RiT
        Ji[:, 6:9, 6:9] = -RiT * T[:, None, None]
        Ji[:, 6:9, 9:12] = -self.J_p_bg
        Ji[:, 6:9, 12:15] = -self.J_p_ba
        Ji_f = np.zeros((K, 15, 15))
        Jj_f = np.zeros((K, 15, 15))
        Ji_f[:, :9] = self.W @ Ji
        Jj_f[:, :9] = self.W @ Jj
        Ji_f[:, 9:, 9:] = -self.W_bias
        Jj_f[:, 9:, 9:] = self.W_bias
        JiT, JjT = np.swapaxes(Ji_f, 1, 2), np.swapaxes(Jj_f, 1, 2)
        D[:-1] += JiT @ Ji_f
        D[1:] += JjT @ Jj_f
        B += JjT @ Ji_f
        b[:-1] += mv(JiT, r)
        b[1:] += mv(JjT, r)
        # visual factors (Huber-weighted blocks)
        idx = self.vis_idx
        if len(idx):
            Ri_v, Rj_v = X.R[idx], X.R[idx + 1]
            RiT_v = np.swapaxes(Ri_v, 1, 2)
            RiT_Rj_v = RiT_v @ Rj_v
            Ev = np.swapaxes(self.vis_dR, 1, 2) @ RiT_Rj_v
            rRv = so3_log_batch(Ev)
            bd = np.einsum("kij,kj->ki", RiT_v, X.p[idx + 1] - X.p[idx])
            rv6 = mv(self.vis_W, np.concatenate([rRv, bd - self.vis_dp], axis=1))
            nr = np.linalg.norm(rv6, axis=1)
            w = np.ones(len(idx))
            if self.robust:
                big = nr > self.k_h
                w = np.where(big, self.k_h / np.where(big, nr, 1.0), 1.0)
                cost += float(np.sum(np.where(big, 2.0 * self.k_h * nr - self.k_h**2, nr * nr)))
            else:
                cost += float(np.sum(nr * nr))
            M = len(idx)
            Jvi = np.zeros((M, 6, 15))
            Jvj = np.zeros((M, 6, 15))
            Jr_v = right_jacobian_inv_batch(rRv)
            Jvi[:, 0:3, 0:3] = -Jr_v @ np.swapaxes(RiT_Rj_v, 1, 2)
            Jvj[:, 0:3, 0:3] = Jr_v
            Jvi[:, 3:6, 0:3] = hat_batch(bd)
            Jvi[:, 3:6, 3:6] = -RiT_v
            Jvj[:, 3:6, 3:6] = RiT_v
            Jvi = self.vis_W @ Jvi
            Jvj = self.vis_W @ Jvj
            JviT = np.swapaxes(Jvi, 1, 2) * w[:, None, None]
            JvjT = np.swapaxes(Jvj, 1, 2) * w[:, None, None]
            D[idx] += JviT @ Jvi  # idx is unique: one visual factor per interval
            D[idx + 1] += JvjT @ Jvj
            B[idx] += JvjT @ Jvi
            b[idx] += mv(JviT, rv6)
            b[idx + 1] += mv(JvjT, rv6)
        return cost, D, B, b
