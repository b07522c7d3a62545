r"""Extended Kalman filter fusing wheel odometry with visual odometry on a differential drive.

:class:`OdomVOFusionEKF` fuses wheel odometry (prediction) with the planar
motion of the base measured by visual odometry between key-frames
(relative-pose update by stochastic cloning) or with absolute poses. Non-finite
inputs are rejected and counted, and the filter reports when VO is lost and it
runs on odometry alone.

Conventions follow :mod:`realitygap.core.geometry`: poses ``[x, y, θ]`` (m, m, rad),
``a ⊕ b`` compounding and ``⊖a`` inversion (Smith–Self–Cheeseman). The base
frame has x forward, y left; the sensor frame is the planar frame in which the
sensor's ego-motion is reported (for a camera, its optical axis projected on
the floor plane).

References
----------
S. Roumeliotis, J. Burdick, "Stochastic cloning: a generalized framework for
processing relative state measurements", ICRA 2002.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import (
    SKEW_2D,
    check_finite,
    rotation_2d,
    se2_between,
    se2_compose,
    wrap_angle,
)
from realitygap.estimators.base import Estimate, WheelTicks
from realitygap.estimators.diffdrive_model import (
    DiffDriveKinematics,
    OdometryNoise,
    arc_increment,
    arc_increment_jacobian,
    se2_compose_jacobians,
)
from realitygap.estimators.kalman import all_finite, joseph_update

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "AbsolutePoseMeasurement",
    "FusionSettings",
    "FusionStep",
    "OdomVOFusionEKF",
    "OdometryIncrement",
    "RelativePoseMeasurement",
    "motion_jacobians",
    "relative_pose_jacobians",
]


@dataclass(frozen=True)
class OdometryIncrement:
    """Wheel-odometry motion of the base over one step.

    Attributes
    ----------
    t : float
        Time at the end of the step, s.
    ds : float
        Arc length travelled by the base centre, m.
    dtheta : float
        Heading change, rad.
    """

    t: float
    ds: float
    dtheta: float


@dataclass(frozen=True)
class RelativePoseMeasurement:
    """Planar motion of the base between a key-frame and now, from visual odometry.

    Attributes
    ----------
    t : float
        Time of the current frame, s.
    motion : ndarray, shape (3,)
        ``⊖q(t_k) ⊕ q(t)``: the base pose now expressed in the base frame at the
        key-frame time ``t_k`` (m, m, rad). For a camera, convert its ego-motion
        with the mounting first: ``l ⊕ z_cam ⊕ ⊖l``.
    cov : ndarray, shape (3, 3)
        Covariance of ``motion``.
    ok : bool
        False when VO failed (tracking lost); ``motion`` is then ignored.
    keyframe_t : float or None
        Time of the key-frame the motion refers to; ``None`` means "the
        filter's current key-frame".
    new_keyframe : bool
        The current frame becomes the reference of the next measurement.
    """

    t: float
    motion: FloatArray
    cov: FloatArray
    ok: bool = True
    keyframe_t: float | None = None
    new_keyframe: bool = True


@dataclass(frozen=True)
class AbsolutePoseMeasurement:
    """Pose of the base in the world frame (e.g. from a map or a tracker).

    Attributes
    ----------
    t : float
        Time, s.
    pose : ndarray, shape (3,)
        ``[x, y, θ]`` in m, m, rad.
    cov : ndarray, shape (3, 3)
        Covariance.
    ok : bool
        False when the source failed.
    """

    t: float
    pose: FloatArray
    cov: FloatArray
    ok: bool = True


@dataclass(frozen=True)
class FusionStep:
    """Everything that arrived at one control step.

    Attributes
    ----------
    t : float
        Time, s.
    odometry : OdometryIncrement, WheelTicks or None
        Wheel odometry; :class:`WheelTicks` are cumulative counts and need the
        filter's ``kinematics``.
    vo : RelativePoseMeasurement, AbsolutePoseMeasurement or None
        Visual odometry (``None``: no VO output this step, normal between
        key-frames).
    """

    t: float
    odometry: OdometryIncrement | WheelTicks | None = None
    vo: RelativePoseMeasurement | AbsolutePoseMeasurement | None = None


@dataclass(frozen=True)
class FusionSettings:
    """Settings of :class:`OdomVOFusionEKF`.

    Attributes
    ----------
    odometry_noise : OdometryNoise
        Variance growth of the odometry increments.
    vo_timeout : float
        If no valid VO update arrived for longer than this (s), the estimate is
        flagged ``vo_lost`` (``Estimate.ok = False``); ``inf`` disables the check.
    gate_chi2 : float or None
        Reject VO updates whose normalised innovation squared exceeds this
        (e.g. 16.27 = χ²₃ at 99.9 %); ``None`` disables gating.
    """

    odometry_noise: OdometryNoise = field(default_factory=OdometryNoise)
    vo_timeout: float = 1.0
    gate_chi2: float | None = None

    def __post_init__(self) -> None:
        if not self.vo_timeout >= 0:  # also rejects NaN; inf disables the timeout
            raise ValueError(f"vo_timeout must be >= 0 s (inf: never), got {self.vo_timeout!r}")
        if self.gate_chi2 is not None and not self.gate_chi2 > 0:
            raise ValueError(f"gate_chi2 must be > 0 or None, got {self.gate_chi2!r}")


def motion_jacobians(
    pose: npt.ArrayLike, ds: float, dtheta: float
) -> tuple[FloatArray, FloatArray]:
    r"""Jacobians of ``f(q, u) = q ⊕ δ(Δs, Δθ)`` (exact arc motion).

    Parameters
    ----------
    pose : array_like, shape (3,)
        Pose ``q`` before the step.
    ds, dtheta : float
        Odometry increment ``u = (Δs, Δθ)``.

    Returns
    -------
    F : ndarray, shape (3, 3)
        ``∂f/∂q``.
    G : ndarray, shape (3, 2)
        ``∂f/∂u``.
    """
    delta = arc_increment(ds, dtheta)
    J_a, J_b = se2_compose_jacobians(np.asarray(pose, dtype=float), delta)
    return J_a, J_b @ arc_increment_jacobian(ds, dtheta)


def relative_pose_jacobians(
    pose_now: npt.ArrayLike, pose_key: npt.ArrayLike
) -> tuple[FloatArray, FloatArray]:
    r"""Jacobians of ``h = ⊖q_k ⊕ q`` with respect to ``q`` (now) and ``q_k`` (key-frame).

    Notes
    -----
    With ``d = p - p_k`` and ``R_k = R(θ_k)``:

    .. math::

        h = \begin{bmatrix} R_k^\top d \\ \theta - \theta_k \end{bmatrix}, \quad
        H_q = \begin{bmatrix} R_k^\top & 0 \\ 0 & 1 \end{bmatrix}, \quad
        H_{q_k} = \begin{bmatrix} -R_k^\top & -R_k^\top S d \\ 0 & -1 \end{bmatrix},

    where ``S`` is the 2×2 rotation generator.
    """
    q = np.asarray(pose_now, dtype=float)
    qk = np.asarray(pose_key, dtype=float)
    Rt = rotation_2d(qk[2]).T
    d = q[:2] - qk[:2]
    H_now = np.eye(3)
    H_now[:2, :2] = Rt
    H_key = -np.eye(3)
    H_key[:2, :2] = -Rt
    H_key[:2, 2] = -Rt @ SKEW_2D @ d
    return H_now, H_key


class OdomVOFusionEKF:
    r"""Wheel odometry + visual odometry EKF on the base pose (an :class:`Estimator`).

    State: the base pose ``q = [x, y, θ]`` in the world frame, augmented with a
    clone ``q_k`` of the pose at the last VO key-frame (stochastic cloning):

    .. math::

        X = \begin{bmatrix} q \\ q_k \end{bmatrix}, \qquad
        P_X = \begin{bmatrix} P & P_{q q_k} \\ P_{q_k q} & P_{q_k} \end{bmatrix}.

    *Predict* (odometry ``u = (Δs, Δθ)``, exact arc):

    .. math::

        q^+ = q \oplus \delta(u), \quad P^+ = F P F^\top + G Q(u) G^\top,

    applied to the ``q`` block only (the clone stays, its cross-covariance is
    carried by ``F``). *Relative update* with a VO motion ``z ≈ ⊖q_k ⊕ q``:
    ``H = [H_q, H_{q_k}]`` (:func:`relative_pose_jacobians`), so the
    correlation between the key-frame pose and the current pose is accounted
    for exactly; afterwards the clone is reset to the current pose
    (``P_{q_k} = P_{q q_k} = P``) when the measurement opens a new key-frame.
    *Absolute update*: ``z ≈ q``, ``H = [I, 0]``.

    Robustness: any non-finite increment or measurement (or covariance) is
    rejected, counted in ``extras["n_rejected"]`` and named in ``status``; the
    state is left untouched, so the filter never produces NaN. When VO
    reports failure (``ok=False``) or no valid VO arrived for
    ``settings.vo_timeout`` s the filter runs on odometry alone and says so:
    ``Estimate.ok = False``, ``status = "vo_lost: odometry only"``.

    Parameters
    ----------
    kinematics : DiffDriveKinematics, optional
        Needed only to consume :class:`WheelTicks`.
    settings : FusionSettings, optional
    """

    def __init__(
        self,
        kinematics: DiffDriveKinematics | None = None,
        settings: FusionSettings | None = None,
    ):
        self.kinematics = kinematics
        self.settings = settings if settings is not None else FusionSettings()
        self.reset()

    # -- state access -----------------------------------------------------
    @property
    def x(self) -> FloatArray:
        """Current pose ``[x, y, θ]``, a copy."""
        return self._X[:3].copy()

    @property
    def P(self) -> FloatArray:
        """Current 3×3 pose covariance, a copy."""
        return self._P[:3, :3].copy()

    @property
    def keyframe_pose(self) -> FloatArray:
        """Cloned pose at the current key-frame, a copy."""
        return self._X[3:].copy()

    @property
    def vo_lost(self) -> bool:
        """True while the filter runs on odometry alone."""
        return self._vo_lost

    # -- Estimator protocol -----------------------------------------------
    def reset(self, initial: Any | None = None) -> Estimate:
        """Start from ``initial``: ``None`` (origin, zero covariance), a pose (3,), or an Estimate.

        The initial pose is also the first key-frame; its time is not known, so
        the first relative measurement is taken to refer to it whatever its
        ``keyframe_t``.
        """
        if initial is None:
            pose, cov = np.zeros(3), np.zeros((3, 3))
        elif isinstance(initial, Estimate):
            pose = check_finite("initial.pose", initial.pose, (3,)).copy()
            cov = check_finite("initial.cov", initial.cov, (3, 3)).copy()
        else:
            pose, cov = check_finite("initial", initial, (3,)).copy(), np.zeros((3, 3))
        pose[2] = wrap_angle(pose[2])
        self._X = np.concatenate([pose, pose])
        self._P = np.block([[cov, cov], [cov, cov]])
        self._t: float | None = None
        self._keyframe_t: float | None = None
        self._last_ticks: WheelTicks | None = None
        self._last_vo_t: float | None = None
        self._vo_lost = False
        self._n_rejected = 0
        self._n_outliers = 0
        self._n_vo_updates = 0
        self._last_rejection: str | None = None
        self._pending: list[str] = []
        self._estimate = self._make_estimate()
        return self._estimate

    def update(self, measurement: Any | None) -> Estimate:
        """Consume a measurement and return the current estimate.

        Accepts a :class:`FusionStep`, an :class:`OdometryIncrement`,
        :class:`WheelTicks`, a :class:`RelativePoseMeasurement`, an
        :class:`AbsolutePoseMeasurement`, or ``None`` (nothing measured: the
        last estimate is returned unchanged).
        """
        if measurement is None:
            return self._estimate
        if isinstance(measurement, FusionStep):
            self._advance_time(measurement.t)
            if measurement.odometry is not None:
                self._consume_odometry(measurement.odometry)
            if measurement.vo is not None:
                self._consume_vo(measurement.vo)
        elif isinstance(measurement, OdometryIncrement | WheelTicks):
            self._consume_odometry(measurement)
        elif isinstance(measurement, RelativePoseMeasurement | AbsolutePoseMeasurement):
            self._consume_vo(measurement)
        else:
            raise TypeError(
                "OdomVOFusionEKF.update expects FusionStep, OdometryIncrement, WheelTicks, "
                "RelativePoseMeasurement, AbsolutePoseMeasurement or None, got "
                f"{type(measurement).__name__}"
            )
        self._check_timeout()
        self._estimate = self._make_estimate()
        return self._estimate

    # -- filter operations ------------------------------------------------
    def predict(self, ds: float, dtheta: float, t: float | None = None) -> bool:
        """Propagate with an odometry increment; returns False (and counts) if rejected."""
        if not all_finite(ds, dtheta) or (t is not None and not all_finite(t)):
            self._reject(f"non-finite odometry increment (ds={ds!r}, dtheta={dtheta!r})")
            return False
        ds, dtheta = float(ds), float(dtheta)
        q = self._X[:3]
        F, G = motion_jacobians(q, ds, dtheta)
        Q = self.settings.odometry_noise.covariance(ds, dtheta)
        self._X[:3] = se2_compose(q, arc_increment(ds, dtheta))
        Fa = np.eye(6)
        Fa[:3, :3] = F
        P = Fa @ self._P @ Fa.T
        P[:3, :3] += G @ Q @ G.T
        self._P = 0.5 * (P + P.T)
        if t is not None:
            self._advance_time(float(t))
        return True

    def set_keyframe(self, t: float | None = None) -> None:
        """Clone the current pose as the reference of the next relative measurement."""
        self._X[3:] = self._X[:3]
        P = self._P[:3, :3].copy()
        self._P = np.block([[P, P], [P, P]])
        self._keyframe_t = self._t if t is None else float(t)

    def update_relative(
        self,
        motion: npt.ArrayLike,
        cov: npt.ArrayLike,
        *,
        new_keyframe: bool = True,
        t: float | None = None,
    ) -> bool:
        """Relative-pose update ``z = ⊖q_k ⊕ q``; returns False (and counts) if rejected."""
        if not all_finite(motion, cov) or np.shape(motion) != (3,) or np.shape(cov) != (3, 3):
            self._reject("non-finite or malformed VO relative motion / covariance")
            return False
        z = np.asarray(motion, dtype=float)
        R = np.asarray(cov, dtype=float)
        q, qk = self._X[:3], self._X[3:]
        H_now, H_key = relative_pose_jacobians(q, qk)
        H = np.hstack([H_now, H_key])
        innovation = z - se2_between(qk, q)
        innovation[2] = wrap_angle(innovation[2])
        ok = self._apply_update(innovation, H, R)
        if ok:
            self._vo_success(t)
        if new_keyframe:
            self.set_keyframe(t)
        return ok

    def update_absolute(
        self, pose: npt.ArrayLike, cov: npt.ArrayLike, *, t: float | None = None
    ) -> bool:
        """Absolute-pose update ``z = q``; returns False (and counts) if rejected."""
        if not all_finite(pose, cov) or np.shape(pose) != (3,) or np.shape(cov) != (3, 3):
            self._reject("non-finite or malformed absolute pose / covariance")
            return False
        z = np.asarray(pose, dtype=float)
        H = np.hstack([np.eye(3), np.zeros((3, 3))])
        innovation = z - self._X[:3]
        innovation[2] = wrap_angle(innovation[2])
        ok = self._apply_update(innovation, H, np.asarray(cov, dtype=float))
        if ok:
            self._vo_success(t)
        return ok

    # -- internals --------------------------------------------------------
    def _apply_update(self, innovation: FloatArray, H: FloatArray, R: FloatArray) -> bool:
        try:
            X, P, nis = joseph_update(self._X, self._P, innovation, H, R)
        except np.linalg.LinAlgError:
            self._reject("singular innovation covariance")
            return False
        if self.settings.gate_chi2 is not None and nis > self.settings.gate_chi2:
            self._n_outliers += 1
            self._last_rejection = f"VO outlier (NIS {nis:.1f} > {self.settings.gate_chi2})"
            self._pending.append(self._last_rejection)
            return False
        if not (np.all(np.isfinite(X)) and np.all(np.isfinite(P))):
            self._reject("update produced non-finite state")
            return False
        X[2] = wrap_angle(X[2])
        X[5] = wrap_angle(X[5])
        self._X, self._P = X, P
        self._n_vo_updates += 1
        return True

    def _reject(self, reason: str) -> None:
        self._n_rejected += 1
        self._last_rejection = reason
        self._pending.append(reason)

    def _vo_success(self, t: float | None) -> None:
        self._vo_lost = False
        self._last_vo_t = t if t is not None else self._t

    def _advance_time(self, t: float) -> None:
        if all_finite(t):
            t = float(t)
            if self._t is None or t >= self._t:
                self._t = t
            if self._last_vo_t is None:
                self._last_vo_t = t

    def _check_timeout(self) -> None:
        if self._t is not None and self._last_vo_t is not None:
            if self._t - self._last_vo_t > self.settings.vo_timeout:
                self._vo_lost = True

    def _consume_odometry(self, odo: OdometryIncrement | WheelTicks) -> None:
        if isinstance(odo, WheelTicks):
            if self.kinematics is None:
                raise ValueError(
                    "OdomVOFusionEKF got WheelTicks but has no kinematics; pass "
                    "kinematics=DiffDriveKinematics(...) or feed OdometryIncrement"
                )
            if not all_finite(odo.t, odo.left, odo.right, odo.ticks_per_rev) or not (
                odo.ticks_per_rev > 0
            ):
                self._reject("non-finite wheel ticks")
                return
            if self._last_ticks is None:
                self._last_ticks = odo
                self._advance_time(odo.t)
                return
            scale = self.kinematics.ticks_per_rev / float(odo.ticks_per_rev)
            ds, dtheta = self.kinematics.increment_from_ticks(
                (odo.left - self._last_ticks.left) * scale,
                (odo.right - self._last_ticks.right) * scale,
            )
            self._last_ticks = odo
            self.predict(ds, dtheta, t=odo.t)
        else:
            self.predict(odo.ds, odo.dtheta, t=odo.t)

    def _consume_vo(self, vo: RelativePoseMeasurement | AbsolutePoseMeasurement) -> None:
        if not all_finite(vo.t):
            self._reject("non-finite VO time stamp")
            return
        self._advance_time(vo.t)
        if isinstance(vo, AbsolutePoseMeasurement):
            if not vo.ok:
                self._vo_lost = True
                return
            self.update_absolute(vo.pose, vo.cov, t=vo.t)
            return
        if not vo.ok:
            self._vo_lost = True
            if vo.new_keyframe:
                self.set_keyframe(vo.t)
            return
        if (
            vo.keyframe_t is not None
            and self._keyframe_t is not None
            and abs(vo.keyframe_t - self._keyframe_t) > 1e-6
        ):
            self._reject(
                f"VO key-frame t={vo.keyframe_t} s does not match the cloned key-frame "
                f"t={self._keyframe_t} s"
            )
            if vo.new_keyframe:
                self.set_keyframe(vo.t)
            return
        self.update_relative(vo.motion, vo.cov, new_keyframe=vo.new_keyframe, t=vo.t)

    def _make_estimate(self) -> Estimate:
        parts = []
        if self._vo_lost:
            parts.append("vo_lost: odometry only")
        parts.extend(f"rejected: {n}" for n in self._pending)
        self._pending = []
        return Estimate(
            t=0.0 if self._t is None else self._t,
            pose=self._X[:3].copy(),
            cov=self._P[:3, :3].copy(),
            ok=not self._vo_lost,
            status="; ".join(parts) if parts else "ok",
            extras={
                "n_rejected": self._n_rejected,
                "n_outliers": self._n_outliers,
                "n_vo_updates": self._n_vo_updates,
                "last_rejection": self._last_rejection,
                "vo_lost": self._vo_lost,
                "keyframe_pose": self._X[3:].copy(),
                "keyframe_t": self._keyframe_t,
            },
        )
