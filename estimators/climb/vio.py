"""A small sliding-window visual-inertial odometry for a climbing robot with a down-looking camera.

:class:`SlidingWindowVIO` is a sliding-window least-squares estimator
(Levenberg–Marquardt on the block-sparse normal equations, or
:func:`scipy.optimize.least_squares`, robust loss) over poses, velocities and biases
with pre-integrated IMU factors (:mod:`.preintegration`), bias random walks, visual
relative-motion factors (:mod:`.frontend` or given :class:`.RelativeMotion`), and a
prior on the oldest state obtained by marginalisation (:mod:`.factors`);
:class:`VioConfig` holds its settings.

Frames: ``world`` is the VIO frame, gravity along :math:`-z`, its origin and yaw
those of the body at initialisation; ``body`` = IMU frame (x forward, z away from
the surface); ``camera`` is OpenCV's optical frame (z along the optical axis).
Rotations are matrices :math:`R_{wb}` (body → world); quaternions are xyzw.
The IMU measures angular rate :math:`\\omega` (rad/s) and specific force
:math:`f = R_{wb}^\\top (a - g)` (m/s²), :math:`g = (0, 0, -9.81)`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.linalg import solve_triangular
from scipy.optimize import least_squares

from realitygap.core.geometry import (
    hat,
    quat_xyzw_from_matrix,
)
from realitygap.estimators.climb.factors import (
    ImuFactor,
    StateStack,
    VisualFactor,
    WindowPrior,
    WindowProblem,
    WindowState,
    imu_residual,
    prior_residual,
    visual_residual,
    whitener,
)
from realitygap.estimators.climb.frontend import relative_motion_from_images
from realitygap.estimators.climb.measurements import (
    CameraFrame,
    ClimbEstimate,
    ImuSample,
    RelativeMotion,
)
from realitygap.estimators.climb.preintegration import Preintegration, StaticInit, static_initialise

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "SlidingWindowVIO",
    "VioConfig",
]


@dataclass(frozen=True)
class VioConfig:
    """Settings of :class:`SlidingWindowVIO` (SI units).

    Attributes
    ----------
    gravity
        m/s².
    gyro_noise_density, accel_noise_density
        rad/s/√Hz, m/s²/√Hz.
    gyro_bias_walk, accel_bias_walk
        Bias random-walk densities, rad/s²/√Hz and m/s³/√Hz.
    window_size
        Keyframes in the window (≥ 2).
    static_init_duration
        Seconds of still IMU data used by :func:`.static_initialise`.
    R_body_camera
        Rows of :math:`R_{bc}` (camera → body); default looks along body :math:`-z`.
    p_body_camera
        Camera centre in the body frame, m.
    camera_height
        Nominal distance of the camera centre from the surface, m.
    visual_rotation_sigma, visual_translation_sigma
        Per-frame noise assumed for image-based relative motion (rad, m) when the
        front-end's own covariance is smaller.
    solver
        ``"gauss_newton"``: Levenberg–Marquardt on the block-sparse normal equations
        with Huber re-weighting of the visual factors (fast); ``"scipy"``:
        :func:`scipy.optimize.least_squares` (``trf``) with ``loss`` applied to every
        whitened residual (dense SVD per step: slower, especially when BLAS threads
        compete for cores).
    loss, loss_scale
        Robust loss and its scale on whitened residuals (``"linear"``: none).
    max_iterations
        Iterations per window solve.
    cost_tolerance
        The window solve stops once a step lowers the whitened cost (a χ² with
        ≈ 15 residuals per keyframe, so a standard deviation of several units) by
        less than this fraction of it, or the linear model predicts less for the
        next step (–).
    prior_position_sigma, prior_yaw_sigma, prior_tilt_sigma, prior_velocity_sigma,
    prior_gyro_bias_sigma, prior_accel_bias_sigma
        Prior on the first state (m, rad, rad, m/s, rad/s, m/s²).
    """

    gravity: float = 9.81
    gyro_noise_density: float = 0.005
    accel_noise_density: float = 0.05
    gyro_bias_walk: float = 1e-4
    accel_bias_walk: float = 1e-3
    window_size: int = 8
    static_init_duration: float = 1.0
    R_body_camera: tuple[tuple[float, float, float], ...] = (
        (1.0, 0.0, 0.0),
        (0.0, -1.0, 0.0),
        (0.0, 0.0, -1.0),
    )
    p_body_camera: tuple[float, float, float] = (0.1, 0.0, -0.02)
    camera_height: float = 0.06
    visual_rotation_sigma: float = 2e-3
    visual_translation_sigma: float = 3e-4
    solver: str = "gauss_newton"
    loss: str = "huber"
    loss_scale: float = 3.0
    max_iterations: int = 6
    cost_tolerance: float = 1e-4
    prior_position_sigma: float = 1e-3
    prior_yaw_sigma: float = 1e-3
    prior_tilt_sigma: float = 0.01
    prior_velocity_sigma: float = 0.01
    prior_gyro_bias_sigma: float = 0.003
    prior_accel_bias_sigma: float = 0.1

    def __post_init__(self) -> None:
        positive = (
            "gravity",
            "gyro_noise_density",
            "accel_noise_density",
            "gyro_bias_walk",
            "accel_bias_walk",
            "static_init_duration",
            "camera_height",
            "visual_rotation_sigma",
            "visual_translation_sigma",
            "loss_scale",
            "cost_tolerance",
            "prior_position_sigma",
            "prior_yaw_sigma",
            "prior_tilt_sigma",
            "prior_velocity_sigma",
            "prior_gyro_bias_sigma",
            "prior_accel_bias_sigma",
        )
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"VioConfig.{name} must be positive, got {value!r}")
        if int(self.window_size) != self.window_size or self.window_size < 2:
            raise ValueError(
                f"VioConfig.window_size must be an integer ≥ 2, got {self.window_size!r}"
            )
        if int(self.max_iterations) != self.max_iterations or self.max_iterations < 1:
            raise ValueError(
                f"VioConfig.max_iterations must be an integer ≥ 1, got {self.max_iterations!r}"
            )
        if self.solver not in ("gauss_newton", "scipy"):
            raise ValueError(
                f"VioConfig.solver must be 'gauss_newton' or 'scipy', got {self.solver!r}"
            )
        losses = ("linear", "huber", "soft_l1", "cauchy", "arctan")
        if self.loss not in losses:
            raise ValueError(f"VioConfig.loss must be one of {losses}, got {self.loss!r}")
        R = np.asarray(self.R_body_camera, dtype=float)
        if (
            R.shape != (3, 3)
            or not np.allclose(R @ R.T, np.eye(3), atol=1e-6)
            or np.linalg.det(R) < 0
        ):
            raise ValueError("VioConfig.R_body_camera must be a proper rotation (3 rows of 3)")

    @property
    def R_bc(self) -> FloatArray:
        """:math:`R_{bc}` (3, 3)."""
        return np.asarray(self.R_body_camera, dtype=float)

    @property
    def p_bc(self) -> FloatArray:
        """Camera centre in the body frame (3,), m."""
        return np.asarray(self.p_body_camera, dtype=float)

    @property
    def gravity_vector(self) -> FloatArray:
        """:math:`g = (0, 0, -g)` in the world frame, m/s²."""
        return np.array([0.0, 0.0, -self.gravity])


class SlidingWindowVIO:
    """Sliding-window visual-inertial odometry (world = gravity-aligned VIO frame).

    Each keyframe state is :math:`x_k = (R_k, p_k, v_k, b_{g,k}, b_{a,k})`. A window of
    ``window_size`` keyframes minimises

    .. math::

        \\lVert r_0 \\rVert^2 + \\sum_k \\rho\\left(\\lVert r^{\\mathrm{imu}}_{k,k+1}
        \\rVert^2_{\\Sigma} + \\lVert b_{k+1} - b_k \\rVert^2_{\\Sigma_b}
        + \\lVert r^{\\mathrm{vis}}_{k,k+1} \\rVert^2_{\\Sigma_v}\\right)

    over right perturbations of all states, with analytic Jacobians and a robust
    loss :math:`\\rho` on the visual factors, by Levenberg–Marquardt on the
    block-sparse normal equations or by :func:`scipy.optimize.least_squares`
    (``VioConfig.solver``). The visual residual of a
    body-frame relative motion :math:`(\\Delta R_m, \\Delta p_m)` is
    :math:`[\\mathrm{Log}(\\Delta R_m^\\top R_k^\\top R_{k+1}),\\; R_k^\\top (p_{k+1} -
    p_k) - \\Delta p_m]`. When the window is full the oldest state is marginalised
    (Schur complement of its factors) into a Gaussian prior :math:`r_0` on the next.

    Feed measurements in time order through :meth:`update`: :class:`.ImuSample`
    (≥ 100 Hz), and either :class:`.CameraFrame` (images, processed by
    :func:`.relative_motion_from_images`) or :class:`.RelativeMotion` (geometric
    mode). The first ``static_init_duration`` seconds of IMU data must come from a
    still robot. A failed or missing visual motion adds an IMU-only keyframe
    (status ``"imu_only"``); the estimate never becomes NaN.

    Parameters
    ----------
    config
        :class:`VioConfig`.
    """

    def __init__(self, config: VioConfig | None = None) -> None:
        self.config = VioConfig() if config is None else config
        if not isinstance(self.config, VioConfig):
            raise TypeError(f"config must be VioConfig, got {type(self.config).__name__}")
        self.reset()

    # ---------------------------------------------------------------- public API

    def reset(self, initial: StaticInit | None = None) -> ClimbEstimate:
        """Start over; with ``initial`` the static phase is skipped (first keyframe at ``initial.t``)."""
        self._states: list[WindowState] = []
        self._imu_factors: list[ImuFactor] = []
        self._vis_factors: list[VisualFactor | None] = []
        self._prior: WindowPrior | None = None
        self._static: list[ImuSample] = []
        self._last_imu: ImuSample | None = None
        self._cursor: float | None = None
        self._pending: Preintegration | None = None
        self._prev_image: CameraFrame | None = None
        self._status = "initialising"
        self._lost = 0
        self._cov6 = np.zeros((6, 6))
        self._n_keyframes = 0
        self._last_t = -math.inf
        self.static_init: StaticInit | None = None
        if initial is not None:
            self._start(initial)
        return self.estimate()

    @property
    def initialised(self) -> bool:
        """True once the first keyframe exists."""
        return bool(self._states)

    @property
    def keyframe_count(self) -> int:
        """Keyframes created since :meth:`reset`."""
        return self._n_keyframes

    def update(self, measurement: ImuSample | CameraFrame | RelativeMotion | None) -> ClimbEstimate:
        """Consume one measurement (or ``None``) and return the current estimate."""
        if measurement is None:
            return self.estimate()
        if isinstance(measurement, ImuSample):
            self._on_imu(measurement)
        elif isinstance(measurement, RelativeMotion):
            self._on_motion(measurement)
        elif isinstance(measurement, CameraFrame):
            self._on_frame(measurement)
        else:
            raise TypeError(
                "measurement must be ImuSample, CameraFrame, RelativeMotion or None, "
                f"got {type(measurement).__name__}"
            )
        return self.estimate()

    def estimate(self) -> ClimbEstimate:
        """Latest state, IMU-propagated past the newest keyframe."""
        if not self._states:
            return ClimbEstimate(
                t=self._last_imu.t if self._last_imu is not None else 0.0,
                position=np.zeros(3),
                quat_xyzw=np.array([0.0, 0.0, 0.0, 1.0]),
                ok=False,
                status="initialising",
            )
        s = self._states[-1]
        R, p, v, t = s.R, s.p, s.v, s.t
        if self._pending is not None and self._pending.dt > 0:
            R, p, v = self._pending.predict(R, p, v, self.config.gravity_vector)
            t = t + self._pending.dt
        return ClimbEstimate(
            t=t,
            position=p.copy(),
            quat_xyzw=quat_xyzw_from_matrix(R),
            velocity=v.copy(),
            cov=self._cov6.copy(),
            ok=self._status == "ok",
            status=self._status,
            frame="world",
            extras=MappingProxyType(
                {
                    "bias_gyro": s.bg.copy(),
                    "bias_accel": s.ba.copy(),
                    "keyframes": self._n_keyframes,
                    "lost_frames": self._lost,
                }
            ),
        )

    def keyframe_estimate(self) -> ClimbEstimate:
        """The newest keyframe's state (no IMU propagation).

        ``extras["previous_keyframe"]`` is ``(t, position, R)`` of the keyframe before
        it *in the same window solution* (absent for the first keyframe): the
        relative motion between the two is the VIO's current best estimate, whereas
        the previous keyframe's own estimate at its creation has since been refined.
        """
        if not self._states:
            return self.estimate()
        s = self._states[-1]
        extras: dict[str, Any] = {"bias_gyro": s.bg.copy(), "bias_accel": s.ba.copy()}
        if len(self._states) > 1:
            q = self._states[-2]
            extras["previous_keyframe"] = (q.t, q.p.copy(), q.R.copy())
        return ClimbEstimate(
            t=s.t,
            position=s.p.copy(),
            quat_xyzw=quat_xyzw_from_matrix(s.R),
            velocity=s.v.copy(),
            cov=self._cov6.copy(),
            ok=self._status == "ok",
            status=self._status,
            frame="world",
            extras=MappingProxyType(extras),
        )

    # ---------------------------------------------------------------- measurements

    def _check_time(self, t: float) -> None:
        if t < self._last_t - 1e-9:
            raise ValueError(
                f"measurements must arrive in time order: got t={t!r} after t={self._last_t!r}"
            )
        self._last_t = max(self._last_t, t)

    def _on_imu(self, m: ImuSample) -> None:
        self._check_time(m.t)
        if not self._states:
            self._static.append(m)
            self._last_imu = m
            if (
                m.t - self._static[0].t >= self.config.static_init_duration
                and len(self._static) >= 10
            ):
                self._start(static_initialise(self._static, gravity=self.config.gravity))
            return
        self._advance_to(m.t)
        self._last_imu = m

    def _advance_to(self, t: float) -> None:
        """Integrate the held IMU reading up to time ``t``."""
        if self._last_imu is None or self._pending is None or self._cursor is None:
            return
        dt = t - self._cursor
        if dt > 0:
            self._pending.integrate(self._last_imu.gyro, self._last_imu.accel, dt)
            self._cursor = t

    def _start(self, init: StaticInit) -> None:
        cfg = self.config
        self.static_init = init
        s0 = WindowState(
            init.t,
            init.R_world_body.copy(),
            np.zeros(3),
            np.zeros(3),
            init.bias_gyro.copy(),
            init.bias_accel.copy(),
        )
        # prior: tilt in world axes → body perturbation
        cov_world_rot = np.diag(
            [cfg.prior_tilt_sigma**2, cfg.prior_tilt_sigma**2, cfg.prior_yaw_sigma**2]
        )
        cov = np.zeros((15, 15))
        cov[0:3, 0:3] = s0.R.T @ cov_world_rot @ s0.R
        cov[3:6, 3:6] = np.eye(3) * cfg.prior_position_sigma**2
        cov[6:9, 6:9] = np.eye(3) * cfg.prior_velocity_sigma**2
        cov[9:12, 9:12] = np.eye(3) * cfg.prior_gyro_bias_sigma**2
        cov[12:15, 12:15] = np.eye(3) * cfg.prior_accel_bias_sigma**2
        self._prior = WindowPrior(s0.copy(), whitener(cov))
        self._states = [s0]
        self._n_keyframes = 1
        self._cursor = init.t
        self._pending = self._new_preintegration(s0)
        if self._last_imu is None and self._static:
            self._last_imu = self._static[-1]
        self._static = []
        self._status = "ok" if init.still else "ok|init_motion_detected"
        self._cov6 = np.zeros((6, 6))
        self._cov6[0:3, 0:3] = np.eye(3) * cfg.prior_position_sigma**2
        self._cov6[3:6, 3:6] = cov_world_rot

    def _new_preintegration(self, s: WindowState) -> Preintegration:
        return Preintegration(
            s.bg,
            s.ba,
            gyro_noise_density=self.config.gyro_noise_density,
            accel_noise_density=self.config.accel_noise_density,
        )

    def _on_frame(self, frame: CameraFrame) -> None:
        self._check_time(frame.t)
        prev = self._prev_image
        self._prev_image = frame
        if not self._states or prev is None:
            if self._states:
                self._add_keyframe(frame.t, None)
            return
        motion = relative_motion_from_images(
            prev.image,
            frame.image,
            frame.K,
            self.config.camera_height,
            t0=prev.t,
            t1=frame.t,
            prior=self._predicted_camera_motion(prev.t, frame.t),
        )
        cfg = self.config
        if motion.ok:
            floor = np.diag(
                [cfg.visual_rotation_sigma**2] * 3 + [cfg.visual_translation_sigma**2] * 3
            )
            motion = RelativeMotion(
                motion.t0,
                motion.t1,
                motion.rotation,
                motion.translation,
                np.maximum(motion.cov, floor),
                ok=True,
                n_inliers=motion.n_inliers,
            )
        self._on_motion(motion)

    def _on_motion(self, m: RelativeMotion) -> None:
        self._check_time(m.t1)
        if not self._states:
            return
        last = self._states[-1]
        linked = m.ok and abs(m.t0 - last.t) < 1e-6
        self._add_keyframe(m.t1, m if linked else None, lost=not m.ok)

    def _predicted_camera_motion(
        self, t0: float, t1: float
    ) -> tuple[FloatArray, FloatArray] | None:
        """IMU-predicted camera motion from the newest keyframe (at ``t0``) to ``t1``."""
        if not self._states or self._pending is None or abs(self._states[-1].t - t0) > 1e-6:
            return None
        self._advance_to(t1)
        s = self._states[-1]
        R_j, p_j, _ = self._pending.predict(s.R, s.p, s.v, self.config.gravity_vector)
        dR = s.R.T @ R_j
        dp = s.R.T @ (p_j - s.p)
        R_bc, p_bc = self.config.R_bc, self.config.p_bc
        return R_bc.T @ dR @ R_bc, R_bc.T @ (dR @ p_bc + dp - p_bc)

    # ---------------------------------------------------------------- keyframes

    def _body_motion(self, m: RelativeMotion) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Camera-frame relative motion → body-frame ``(ΔR, Δp, cov)``."""
        R_bc, p_bc = self.config.R_bc, self.config.p_bc
        dR = R_bc @ m.rotation @ R_bc.T
        dp = R_bc @ m.translation + p_bc - dR @ p_bc
        J = np.zeros((6, 6))
        J[0:3, 0:3] = R_bc
        J[3:6, 3:6] = R_bc
        J[3:6, 0:3] = dR @ hat(p_bc) @ R_bc
        return dR, dp, J @ m.cov @ J.T

    def _add_keyframe(self, t: float, motion: RelativeMotion | None, lost: bool = False) -> None:
        assert self._pending is not None
        self._advance_to(t)
        pre = self._pending
        last = self._states[-1]
        if pre.dt <= 1e-9:
            return  # duplicate time
        cfg = self.config
        g = cfg.gravity_vector
        R_j, p_j, v_j = pre.predict(last.R, last.p, last.v, g)
        vis: VisualFactor | None = None
        if motion is not None:
            dR, dp, cov = self._body_motion(motion)
            vis = VisualFactor(dR, dp, whitener(cov))
            R_j = last.R @ dR
            p_j = last.p + last.R @ dp
        cov_b = np.zeros((6, 6))
        cov_b[0:3, 0:3] = np.eye(3) * cfg.gyro_bias_walk**2 * pre.dt
        cov_b[3:6, 3:6] = np.eye(3) * cfg.accel_bias_walk**2 * pre.dt
        factor = ImuFactor(pre, whitener(pre.cov + 1e-12 * np.eye(9)), whitener(cov_b))
        self._states.append(WindowState(t, R_j, p_j, v_j, last.bg.copy(), last.ba.copy()))
        self._imu_factors.append(factor)
        self._vis_factors.append(vis)
        self._n_keyframes += 1
        if lost:
            self._lost += 1
        self._optimise()
        if len(self._states) > cfg.window_size:
            self._marginalise()
        newest = self._states[-1]
        self._pending = self._new_preintegration(newest)
        self._cursor = t
        if vis is None and self._n_keyframes > 2:
            self._status = "imu_only"
        elif vis is not None:
            self._status = "ok"

    # ---------------------------------------------------------------- optimisation

    def _factors(
        self, states: list[WindowState], want_jac: bool
    ) -> list[tuple[FloatArray, list[tuple[int, FloatArray]], bool]]:
        """Whitened residual blocks ``(r, [(state index, ∂r/∂δx_k)], robust)``."""
        g = self.config.gravity_vector
        assert self._prior is not None
        out: list[tuple[FloatArray, list[tuple[int, FloatArray]], bool]] = []
        r, J = prior_residual(states[0], self._prior, want_jac)
        out.append((r, [(0, J)] if J is not None else [], False))
        for k in range(len(states) - 1):
            r, Ji, Jj = imu_residual(states[k], states[k + 1], self._imu_factors[k], g, want_jac)
            out.append(
                (r, [(k, Ji), (k + 1, Jj)] if Ji is not None and Jj is not None else [], False)
            )
            vf = self._vis_factors[k]
            if vf is not None:
                r, Ji, Jj = visual_residual(states[k], states[k + 1], vf, want_jac)
                jacs = [(k, Ji), (k + 1, Jj)] if Ji is not None and Jj is not None else []
                out.append((r, jacs, True))
        return out

    def _normal_equations(
        self, blocks: list[tuple[FloatArray, list[tuple[int, FloatArray]], bool]], n: int
    ) -> tuple[float, FloatArray, FloatArray, FloatArray]:
        """Robust cost and the block-tridiagonal :math:`H = J^\\top W J`, :math:`b = J^\\top W r`.

        Returns ``cost, D (n, 15, 15), B (n-1, 15, 15), b (n, 15)`` with ``D[k] = H_kk``
        and ``B[k] = H_{k+1,k}`` (every factor links at most two consecutive states).
        """
        k_h = self.config.loss_scale
        robust = self.config.loss != "linear"
        D = np.zeros((n, 15, 15))
        B = np.zeros((max(n - 1, 0), 15, 15))
        b = np.zeros((n, 15))
        cost = 0.0
        for r, jacs, is_robust in blocks:
            nr = float(np.linalg.norm(r))
            w = 1.0
            if robust and is_robust and nr > k_h:
                w = k_h / nr
                cost += 2.0 * k_h * nr - k_h * k_h
            else:
                cost += nr * nr
            for i, Ji in jacs:
                b[i] += w * (Ji.T @ r)
                D[i] += w * (Ji.T @ Ji)
            if len(jacs) == 2:
                (i, Ji), (j, Jj) = jacs
                if j == i + 1:
                    B[i] += w * (Jj.T @ Ji)
                else:
                    B[j] += w * (Ji.T @ Jj)
        return cost, D, B, b

    @staticmethod
    def _solve_block_tridiagonal(
        D: FloatArray, B: FloatArray, rhs: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """Solve :math:`H x = rhs` for the block-tridiagonal ``H`` (diagonal blocks ``D``,
        sub-diagonal blocks ``B``) by one dense Cholesky factorisation (for a window of
        ~8 states one LAPACK call beats a Python loop over the blocks); also return the
        last diagonal block of the factor (the newest state's information).

        Raises :class:`numpy.linalg.LinAlgError` if ``H`` is not positive definite.
        """
        n = len(D)
        H = np.zeros((n, 15, n, 15))
        k = np.arange(n)
        H[k, :, k, :] = D
        H[k[1:], :, k[:-1], :] = B
        H[k[:-1], :, k[1:], :] = np.swapaxes(B, 1, 2)
        L = np.linalg.cholesky(H.reshape(15 * n, 15 * n))
        y = solve_triangular(L, rhs.reshape(-1), lower=True, check_finite=False)
        x = solve_triangular(L.T, y, lower=False, check_finite=False)
        if not np.all(np.isfinite(x)):
            raise np.linalg.LinAlgError("non-finite solution of the window's normal equations")
        step: FloatArray = np.asarray(x, dtype=np.float64).reshape(n, 15)
        l_last: FloatArray = np.asarray(L[-15:, -15:], dtype=np.float64)
        return step, l_last

    def _optimise(self) -> None:
        n = len(self._states)
        if self.config.solver == "scipy":
            self._optimise_scipy()
            _, D, B, _ = self._normal_equations(self._factors(self._states, True), n)
        else:
            D, B = self._optimise_lm()
        try:
            D = D + 1e-12 * np.eye(15)
            _, L_last = self._solve_block_tridiagonal(D, B, np.zeros((n, 15)))
            L_inv = np.linalg.inv(L_last)
            cov = L_inv.T @ L_inv  # last diagonal block of H^{-1}
            R = self._states[-1].R
            c6 = np.zeros((6, 6))
            c6[0:3, 0:3] = cov[3:6, 3:6]
            c6[3:6, 3:6] = R @ cov[0:3, 0:3] @ R.T
            c6[0:3, 3:6] = cov[3:6, 0:3] @ R.T
            c6[3:6, 0:3] = c6[0:3, 3:6].T
            if np.all(np.isfinite(c6)):
                self._cov6 = 0.5 * (c6 + c6.T)
        except np.linalg.LinAlgError:
            pass

    def _optimise_lm(self) -> tuple[FloatArray, FloatArray]:
        """Levenberg–Marquardt with Huber IRLS weights on the visual factors; returns the
        blocks of :math:`H` at the solution. All factors are evaluated at once
        (:class:`.WindowProblem`); the previous solution warm-starts every state but
        the newest."""
        assert self._prior is not None
        times = [s.t for s in self._states]
        n = len(times)
        cfg = self.config
        problem = WindowProblem(
            self._imu_factors,
            self._vis_factors,
            self._prior,
            cfg.gravity_vector,
            cfg.loss_scale,
            cfg.loss != "linear",
        )
        X = StateStack.of(self._states)
        cost, D, B, b = problem.linearise(X)
        lam = 1e-6
        eye = np.eye(15)
        tol = cfg.cost_tolerance
        for it in range(cfg.max_iterations):
            diag = np.einsum("kii->ki", D)
            A = D + (lam * diag)[:, :, None] * eye + 1e-12 * eye
            try:
                dx, _ = self._solve_block_tridiagonal(A, B, -b)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            if it > 0:
                # decrease of ‖r‖² predicted by the linear model at X:
                # -2 bᵀdx - dxᵀ H dx with (H + λ diag) dx = -b
                predicted = float(-np.sum(b * dx) + lam * np.sum(diag * dx * dx))
                if predicted < tol * max(cost, 1.0):
                    break
            trial = X.retract(dx)
            new_cost, D_new, B_new, b_new = problem.linearise(trial)
            if np.isfinite(new_cost) and new_cost <= cost:
                decrease = cost - new_cost
                X, cost, D, B, b = trial, new_cost, D_new, B_new, b_new
                lam = max(lam / 10.0, 1e-9)
                if float(np.max(np.abs(dx))) < 1e-7 or decrease < tol * max(cost, 1.0):
                    break
            else:
                lam *= 10.0
                if lam > 1e6:
                    break
        self._states = X.states(times)
        assert len(self._states) == n
        return D, B

    def _optimise_scipy(self) -> None:
        """:func:`scipy.optimize.least_squares` (trust-region reflective, robust loss)."""
        base = [s.copy() for s in self._states]
        n = len(base)
        cache: dict[bytes, tuple[FloatArray, FloatArray]] = {}

        def states_at(x: FloatArray) -> list[WindowState]:
            return [s.retract(x[15 * k : 15 * k + 15]) for k, s in enumerate(base)]

        def evaluate(x: FloatArray) -> tuple[FloatArray, FloatArray]:
            key = x.tobytes()
            if key not in cache:
                blocks = self._factors(states_at(x), True)
                res = np.concatenate([r for r, _, _ in blocks])
                J = np.zeros((len(res), 15 * n))
                row = 0
                for r, jacs, _ in blocks:
                    for k, Jk in jacs:
                        J[row : row + len(r), 15 * k : 15 * k + 15] += Jk
                    row += len(r)
                cache.clear()
                cache[key] = (res, J)
            return cache[key]

        x0 = np.zeros(15 * n)
        try:
            sol = least_squares(
                lambda x: evaluate(x)[0],
                x0,
                jac=lambda x: evaluate(x)[1],
                method="trf",
                loss=self.config.loss,
                f_scale=self.config.loss_scale,
                max_nfev=self.config.max_iterations + 2,
                x_scale="jac",
                xtol=1e-8,
                ftol=1e-8,
                gtol=1e-8,
            )
            x = sol.x if np.all(np.isfinite(sol.x)) else x0
        except (np.linalg.LinAlgError, ValueError):
            x = x0
        self._states = states_at(x)

    def _marginalise(self) -> None:
        """Fold state 0 and its factors into a prior on state 1."""
        assert self._prior is not None
        s0, s1 = self._states[0], self._states[1]
        g = self.config.gravity_vector
        rs: list[FloatArray] = []
        Js: list[FloatArray] = []
        r, J = prior_residual(s0, self._prior, True)
        assert J is not None
        rs.append(r)
        Js.append(np.hstack([J, np.zeros((15, 15))]))
        r, Ji, Jj = imu_residual(s0, s1, self._imu_factors[0], g, True)
        assert Ji is not None and Jj is not None
        rs.append(r)
        Js.append(np.hstack([Ji, Jj]))
        vf = self._vis_factors[0]
        if vf is not None:
            r, Ji, Jj = visual_residual(s0, s1, vf, True)
            assert Ji is not None and Jj is not None
            rs.append(r)
            Js.append(np.hstack([Ji, Jj]))
        rr = np.concatenate(rs)
        JJ = np.vstack(Js)
        H = JJ.T @ JJ
        b = JJ.T @ rr
        Hmm, Hmr, Hrr = H[:15, :15], H[:15, 15:], H[15:, 15:]
        Hmm_inv = np.linalg.inv(Hmm + 1e-12 * np.eye(15))
        Lam = Hrr - Hmr.T @ Hmm_inv @ Hmr
        gvec = b[15:] - Hmr.T @ Hmm_inv @ b[:15]
        Lam = 0.5 * (Lam + Lam.T) + 1e-10 * np.eye(15)
        try:
            delta = -np.linalg.solve(Lam, gvec)
            L = np.linalg.cholesky(Lam)
        except np.linalg.LinAlgError:
            w, V = np.linalg.eigh(Lam)
            w = np.maximum(w, 1e-8)
            Lam = (V * w) @ V.T
            delta = -np.linalg.solve(Lam, gvec)
            L = np.linalg.cholesky(Lam)
        self._prior = WindowPrior(s1.retract(delta), L.T)
        self._states.pop(0)
        self._imu_factors.pop(0)
        self._vis_factors.pop(0)
