"""Adsorption-constrained localisation on the CAD surface: VIO + tether + surface.

:class:`ConstrainedEstimator` is an error-state EKF over the body pose in the CAD
frame, :math:`(p, R)` with :math:`R = R_{gb}`, errors :math:`\\delta p` and
world-frame angles :math:`\\delta\\theta` (:math:`R_{true} = \\mathrm{Exp}(\\delta\\theta) R`).

*Prediction* with the VIO increment between consecutive VIO poses,
:math:`\\Delta R = R_{w,k-1}^\\top R_{w,k}`, :math:`\\Delta p = R_{w,k-1}^\\top
(p_{w,k} - p_{w,k-1})`, both poses taken from the VIO's *current* window solution
when it provides the previous keyframe (``extras["previous_keyframe"]`` of
:meth:`.SlidingWindowVIO.keyframe_estimate`): the previous keyframe's estimate at its
own creation has been refined since (by millimetres), and differencing against
that stale value would feed the refinement to the filter as motion:

.. math::

    R_k = R_{k-1} \\Delta R, \\quad p_k = p_{k-1} + R_{k-1} \\Delta p, \\quad
    F = \\begin{bmatrix} I & -[R_{k-1}\\Delta p]_\\times \\\\ 0 & I \\end{bmatrix}.

*Updates*:

* gravity (roll/pitch stay with the VIO): :math:`R^\\top e_z = R_{w,k}^\\top e_z`;
* tether: :math:`l = \\lVert p - a \\rVert` with the anchor :math:`a` in the CAD frame;
  innovations beyond a gate are down-weighted (Huber) and flagged as slack (tether
  longer than the straight line; beyond twice the gate such a reading only bounds
  the distance from above and is dropped) or short; a length step inconsistent with
  the motion is flagged as a jump and skipped;
* adsorption, **point contact** (``wheel_track = 0``; the body is a point ``h``
  above the surface whose z-axis is the normal):

  - position: with the projection :math:`\\pi` of :math:`p` along the body z-axis
    (:class:`.SurfaceModel`), :math:`n^\\top(\\pi(p) - p) = 0`;
  - direction: the body z-axis must be the surface normal. Roll and pitch stay with
    gravity, so the residual is on the horizontal parts,
    :math:`r = n_{xy}(p) - (R e_z)_{xy}`, with the attitude Jacobian restricted to yaw:
    its component along the normal's azimuth is the yaw residual
    (:math:`\\approx \\lVert n_{xy}\\rVert` times the angle between the horizontal
    parts), its radial component compares the tilt of the surface under the body
    with the body's (gravity-given) tilt and so locates the body along the
    curvature. The dependence of :math:`n(p)` on position is linearised by central
    differences; noise :math:`\\sigma_n` per component; innovations beyond twice the
    gate are rejected;

* adsorption, **two-wheel contact** (``wheel_track = b > 0``; a wheeled chassis
  whose two sphere wheels of radius ``h`` sit on the axle, the body y-axis, at
  :math:`c_\\pm = p \\pm \\tfrac{b}{2} R e_y`). A sphere touches the surface where the
  surface normal passes through its centre, so each wheel centre is ``h`` above the
  surface along its *own* contact normal (closest-point projection
  :math:`x_\\pm, n_\\pm`):

  .. math::  n_\\pm^\\top (c_\\pm - x_\\pm) = h, \\qquad
             H_\\pm = \\left[n_\\pm^\\top,\\; -n_\\pm^\\top [R\\,(\\pm\\tfrac{b}{2} e_y)]_\\times\\right].

  On a convex section the axle is a chord of the surface, so the body origin (the
  axle midpoint) sits *lower* than ``h`` (by :math:`\\approx b^2\\kappa/8` for a
  curvature :math:`\\kappa` along the axle), and the two residuals together also say
  that the axle is parallel to the surface (roll about the body x-axis). The
  chassis itself is free to rock about the axle until a caster touches, so the only
  direction residual is the pitch about the axle,
  :math:`(R e_x)^\\top \\bar n = 0` with :math:`\\bar n` the mean contact normal and
  noise ``pitch_sigma`` (the caster geometry's rocking range); it is not used to
  locate the body (no position Jacobian).

A surface residual beyond ``detach_threshold`` (and beyond 5 σ of its prediction)
is taken as the robot having left the surface: the adsorption updates are skipped
and ``status`` says ``detached``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import (
    hat,
    matrix_from_quat_xyzw,
    quat_xyzw_from_matrix,
    so3_exp,
    so3_log,
    wrap_angle,
)
from realitygap.estimators.climb.measurements import (
    ClimbEstimate,
    TetherReading,
)
from realitygap.estimators.climb.surface import SurfaceModel

FloatArray = npt.NDArray[np.float64]

__all__ = ["ConstrainedConfig", "ConstrainedEstimator"]

_E_Z = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class ConstrainedConfig:
    """Settings of :class:`ConstrainedEstimator` (SI units).

    Attributes
    ----------
    use_tether, use_surface, use_gravity
        Which updates run (``use_surface`` covers both adsorption residuals).
    odometry_translation_rel, odometry_translation_abs
        VIO translation noise per increment: ``rel · |Δp| + abs`` (–, m).
    odometry_rotation_rel
        VIO rotation noise per rad turned.
    odometry_yaw_walk
        VIO attitude random walk per √m travelled, rad/√m.
    odometry_rotation_time
        VIO attitude random walk per √s, rad/√s.
    gravity_sigma
        Roll/pitch accuracy of the VIO, rad.
    tether_sigma
        Tether length noise, m.
    tether_gate
        Normalised innovation beyond which the tether is down-weighted.
    tether_jump_threshold
        Length step inconsistent with the motion that counts as a jump, m.
    surface_sigma
        Height of the body above the CAD surface: noise (CAD deviation, suction
        compliance), m.
    normal_sigma
        Direction of the body z-axis vs the CAD normal, rad.
    tilt_constrains_position
        True: the whole horizontal-part difference :math:`n_{xy}(p) - (R e_z)_{xy}`
        (2 rows) is used, so the tilt of the surface under the body also locates it
        along the curvature; False: only its component along the normal's azimuth
        (the yaw residual alone).
    min_normal_tilt
        Least :math:`\\lVert n_{xy} \\rVert` for the yaw-only residual.
    normal_step
        Step of the central differences of the normal's azimuth over position, m.
    wheel_track
        Contact model, m. ``0``: point contact (the body origin ``h`` above the
        surface, z-axis along the normal; ``surface_sigma`` and ``normal_sigma``).
        ``> 0``: distance between the centres of two sphere wheels of radius ``h`` on
        the body y-axis (two height residuals with ``surface_sigma`` each, plus the
        pitch about the axle with ``pitch_sigma``).
    pitch_sigma
        Two-wheel contact: spread of the chassis pitch about the axle relative to
        the surface (it rocks between its casters), rad.
    detach_threshold
        Surface residual beyond which the robot counts as detached, m.
    gate
        Normalised innovation beyond which surface and gravity updates are
        down-weighted (Huber).
    """

    use_tether: bool = True
    use_surface: bool = True
    use_gravity: bool = True
    odometry_translation_rel: float = 0.02
    odometry_translation_abs: float = 2e-4
    odometry_rotation_rel: float = 0.01
    odometry_yaw_walk: float = 0.01
    odometry_rotation_time: float = 1e-4
    gravity_sigma: float = 3e-3
    tether_sigma: float = 3e-3
    tether_gate: float = 3.0
    tether_jump_threshold: float = 0.03
    surface_sigma: float = 3e-3
    normal_sigma: float = 0.01
    tilt_constrains_position: bool = True
    min_normal_tilt: float = 0.05
    normal_step: float = 0.01
    wheel_track: float = 0.0
    pitch_sigma: float = 0.07
    detach_threshold: float = 0.03
    gate: float = 4.0

    def __post_init__(self) -> None:
        for name in (
            "odometry_translation_rel",
            "odometry_translation_abs",
            "odometry_rotation_rel",
            "odometry_yaw_walk",
            "odometry_rotation_time",
            "gravity_sigma",
            "tether_sigma",
            "tether_gate",
            "tether_jump_threshold",
            "surface_sigma",
            "normal_sigma",
            "min_normal_tilt",
            "normal_step",
            "pitch_sigma",
            "detach_threshold",
            "gate",
        ):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"ConstrainedConfig.{name} must be positive, got {value!r}")
        if not (math.isfinite(self.wheel_track) and self.wheel_track >= 0):
            raise ValueError(
                f"ConstrainedConfig.wheel_track must be ≥ 0 m, got {self.wheel_track!r}"
            )


class ConstrainedEstimator:
    """EKF fusing VIO increments with tether and adsorption constraints (CAD frame).

    Parameters
    ----------
    surface
        CAD surface model (CAD frame, gravity along :math:`-z`).
    anchor_cad : (3,)
        Tether anchor in the CAD frame, m.
    h
        Height above the surface of the body origin (point contact) or of the wheel
        centres (two-wheel contact, ``ConstrainedConfig.wheel_track > 0``), m.
    config
        :class:`ConstrainedConfig`.

    Notes
    -----
    :meth:`update` takes the VIO's keyframe estimates (``frame="world"``) in time
    order, and :class:`.TetherReading` s in between. The first VIO estimate after
    :meth:`reset` only sets the reference: ``initial`` must be the CAD-frame pose at
    that instant.
    """

    def __init__(
        self,
        surface: SurfaceModel,
        anchor_cad: npt.ArrayLike,
        h: float,
        config: ConstrainedConfig | None = None,
    ) -> None:
        if not isinstance(surface, SurfaceModel):
            raise TypeError(f"surface must be a SurfaceModel, got {type(surface).__name__}")
        a = np.asarray(anchor_cad, dtype=float)
        if a.shape != (3,) or not np.all(np.isfinite(a)):
            raise ValueError(f"anchor_cad must be a finite (3,) array, got {anchor_cad!r}")
        if not (math.isfinite(h) and h >= 0):
            raise ValueError(f"h must be a non-negative height in m, got {h!r}")
        self.surface = surface
        self.anchor = a
        self.h = float(h)
        self.config = ConstrainedConfig() if config is None else config
        self.reset()

    def reset(
        self,
        initial: ClimbEstimate | None = None,
        cov: npt.ArrayLike | None = None,
        *,
        note: str | None = None,
    ) -> ClimbEstimate:
        """Start from ``initial`` (CAD frame) with covariance ``cov`` (6 × 6, [p, θ]).

        ``initial=None`` leaves the estimator waiting (``ok=False``) until reset again;
        ``note`` is a status flag kept until the next reset (e.g. ``"init_degraded"``).
        """
        self._p = np.zeros(3)
        self._R = np.eye(3)
        self._v = np.zeros(3)
        self._t = 0.0
        self._P = np.diag([1e-4] * 3 + [1e-4] * 3)
        self._ref: ClimbEstimate | None = None
        self._started = False
        self._last_tether: tuple[float, float, FloatArray] | None = None
        self._flags: set[str] = set()
        self._sticky: set[str] = set() if note is None else {note}
        self._extras: dict[str, float] = {}
        if initial is not None:
            if initial.frame != "cad":
                raise ValueError(
                    f"initial must be a CAD-frame estimate (frame='cad'), got frame={initial.frame!r}"
                )
            self._p = np.asarray(initial.position, dtype=float).copy()
            self._R = matrix_from_quat_xyzw(initial.quat_xyzw)
            self._t = float(initial.t)
            self._started = True
            if cov is not None:
                P = np.asarray(cov, dtype=float)
                if P.shape != (6, 6) or not np.all(np.isfinite(P)):
                    raise ValueError(f"cov must be a finite (6, 6) array, got shape {P.shape}")
                self._P = 0.5 * (P + P.T)
        return self.estimate()

    # ------------------------------------------------------------------ output

    def estimate(self) -> ClimbEstimate:
        """Current CAD-frame estimate."""
        flags = self._flags | self._sticky
        status = "ok" if not flags else "|".join(sorted(flags))
        if not self._started:
            status = "not_initialised"
        bad = {"detached", "off_surface", "not_initialised"}
        return ClimbEstimate(
            t=self._t,
            position=self._p.copy(),
            quat_xyzw=quat_xyzw_from_matrix(self._R),
            velocity=self._v.copy(),
            cov=self._P.copy(),
            ok=self._started and not (self._flags & bad) and "not_initialised" not in status,
            status=status,
            frame="cad",
            extras=MappingProxyType(dict(self._extras)),
        )

    # ------------------------------------------------------------------ updates

    def update(self, measurement: ClimbEstimate | TetherReading | None) -> ClimbEstimate:
        """Consume a VIO keyframe estimate (world frame), a tether reading, or ``None``."""
        if measurement is None or not self._started:
            return self.estimate()
        if isinstance(measurement, TetherReading):
            self._flags = {f for f in self._flags if not f.startswith("tether")}
            if self.config.use_tether:
                self._tether_update(measurement)
            return self.estimate()
        if isinstance(measurement, ClimbEstimate):
            if measurement.frame != "world":
                raise ValueError("VIO estimates must be in the world frame (frame='world')")
            self._flags = {f for f in self._flags if f.startswith("tether")}
            self._vio_update(measurement)
            return self.estimate()
        raise TypeError(
            "measurement must be ClimbEstimate (VIO), TetherReading or None, "
            f"got {type(measurement).__name__}"
        )

    def _vio_update(self, vio: ClimbEstimate) -> None:
        cfg = self.config
        R_w = vio.rotation
        if self._ref is None:
            self._ref = vio
            self._t = vio.t
            self._v = self._R @ R_w.T @ vio.velocity
        else:
            R_prev, p_prev = self._ref.rotation, self._ref.position
            prev_kf = vio.extras.get("previous_keyframe")
            if prev_kf is not None and abs(prev_kf[0] - self._ref.t) < 1e-9:
                # the increment within the VIO's current solution (see
                # SlidingWindowVIO.keyframe_estimate)
                _, p_prev, R_prev = prev_kf
            dR = R_prev.T @ R_w
            dp = R_prev.T @ (vio.position - p_prev)
            step = float(np.linalg.norm(dp))
            turn = float(np.linalg.norm(so3_log(dR)))
            dt = max(vio.t - self._ref.t, 0.0)
            Rdp = self._R @ dp
            F = np.eye(6)
            F[0:3, 3:6] = -hat(Rdp)
            s_p = cfg.odometry_translation_rel * step + cfg.odometry_translation_abs
            s_th2 = (
                (cfg.odometry_rotation_rel * turn) ** 2
                + cfg.odometry_yaw_walk**2 * step
                + cfg.odometry_rotation_time**2 * dt
            )
            Q = np.zeros((6, 6))
            Q[0:3, 0:3] = np.eye(3) * s_p**2
            Q[3:6, 3:6] = np.eye(3) * s_th2
            self._p = self._p + Rdp
            self._R = self._R @ dR
            self._P = F @ self._P @ F.T + Q
            self._t = vio.t
            self._v = self._R @ R_w.T @ vio.velocity
            self._ref = vio
        if cfg.use_gravity:
            self._gravity_update(R_w)
        if cfg.use_surface:
            self._surface_update()

    def _correct(
        self, r: FloatArray, H: FloatArray, Rn: FloatArray, gate: float, reject: float = math.inf
    ) -> float:
        """EKF correction with Huber down-weighting beyond ``gate`` and rejection beyond
        ``reject`` (normalised innovation); returns the weight applied (0: rejected)."""
        S = H @ self._P @ H.T + Rn
        try:
            Sinv = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            return 0.0
        m2 = float(r @ Sinv @ r)
        if m2 > reject**2:
            return 0.0
        weight = 1.0
        if m2 > gate**2:
            weight = gate / math.sqrt(m2)
            Rn = Rn / weight
            S = H @ self._P @ H.T + Rn
            Sinv = np.linalg.inv(S)
        K = self._P @ H.T @ Sinv
        dx = K @ r
        self._p = self._p + dx[0:3]
        self._R = so3_exp(dx[3:6]) @ self._R
        IKH = np.eye(6) - K @ H
        self._P = IKH @ self._P @ IKH.T + K @ Rn @ K.T
        self._P = 0.5 * (self._P + self._P.T)
        return weight

    def _gravity_update(self, R_w: FloatArray) -> None:
        z = R_w.T @ _E_Z
        r = z - self._R.T @ _E_Z
        H = np.zeros((3, 6))
        H[:, 3:6] = self._R.T @ hat(_E_Z)
        self._correct(r, H, np.eye(3) * self.config.gravity_sigma**2, self.config.gate)

    def _surface_update(self) -> None:
        if self.config.wheel_track > 0:
            self._wheel_contact_update()
        else:
            self._point_contact_update()

    def _wheel_contact_update(self) -> None:
        """Two sphere wheels on the axle: wheel-centre heights and the pitch about the axle."""
        cfg = self.config
        y_w = self._R[:, 1]
        levers = np.outer([0.5, -0.5], cfg.wheel_track * y_w)  # (2, 3): c± − p, world
        centres = self._p + levers
        pr = self.surface.project(centres, None, 0.0)
        if not np.all(pr.ok):
            self._flags.add("off_surface")
            return
        normals = np.asarray(pr.normal)
        heights = np.einsum("ij,ij->i", normals, centres - np.asarray(pr.incidence))
        r = self.h - heights
        H = np.zeros((2, 6))
        H[:, 0:3] = normals
        for i in range(2):
            H[i, 3:6] = -normals[i] @ hat(levers[i])
        Rn = np.eye(2) * cfg.surface_sigma**2
        s_pred = np.diag(H @ self._P @ H.T) + cfg.surface_sigma**2
        self._extras["surface_residual"] = float(np.mean(r))
        if np.any((np.abs(r) > cfg.detach_threshold) & (np.abs(r) > 5.0 * np.sqrt(s_pred))):
            self._flags.add("detached")
            return
        self._correct(r, H, Rn, cfg.gate)
        # pitch about the axle: the body x-axis lies in the tangent plane up to the
        # caster rocking; attitude only
        n_bar = normals.sum(axis=0)
        n_bar /= np.linalg.norm(n_bar)
        x_w = self._R[:, 0]
        r_pitch = -float(x_w @ n_bar)
        Hp = np.zeros((1, 6))
        Hp[0, 3:6] = -n_bar @ hat(x_w)  # d(x_w·n)/dδθ with x_w → x_w + δθ × x_w
        self._extras["pitch_residual"] = r_pitch
        self._correct(np.array([r_pitch]), Hp, np.array([[cfg.pitch_sigma**2]]), cfg.gate)

    def _point_contact_update(self) -> None:
        """Point contact: origin height along the body z-axis and the normal direction."""
        cfg = self.config
        bz = self._R @ _E_Z
        pr = self.surface.project(self._p, bz, self.h)
        if not pr.ok:
            self._flags.add("off_surface")
            return
        n = np.asarray(pr.normal)
        r_pos = float(n @ (np.asarray(pr.point) - self._p))
        H = np.zeros((1, 6))
        H[0, 0:3] = n  # h(p) = n·(p − π(p)), z = 0
        s_pred = float((H @ self._P @ H.T)[0, 0]) + cfg.surface_sigma**2
        self._extras["surface_residual"] = r_pos
        if abs(r_pos) > cfg.detach_threshold and abs(r_pos) > 5.0 * math.sqrt(s_pred):
            self._flags.add("detached")
            return
        self._correct(np.array([r_pos]), H, np.array([[cfg.surface_sigma**2]]), cfg.gate)
        # horizontal parts of the body z-axis and of the normal at p; the normal also
        # depends on where on the surface the body is (central differences)
        bz = self._R @ _E_Z
        eps = cfg.normal_step
        probes = self._p + np.vstack([np.zeros(3), eps * np.eye(3), -eps * np.eye(3)])
        prs = self.surface.project(probes, bz, self.h)
        if not np.all(prs.ok):
            return
        normals = np.asarray(prs.normal)
        n_xy = normals[0, :2]
        a_xy = bz[:2]
        dn_dp = (normals[1:4, :2] - normals[4:7, :2]).T / (2 * eps)  # (2, 3)
        da_dyaw = np.array([-a_xy[1], a_xy[0]])  # yaw only: roll/pitch stay with gravity
        tilt = float(np.hypot(*n_xy))
        if cfg.tilt_constrains_position:
            r = n_xy - a_xy
            H = np.zeros((2, 6))
            H[:, 0:3] = -dn_dp  # h = a_xy(ψ) - n_xy(p), z = 0
            H[:, 5] = da_dyaw
        else:
            if tilt < cfg.min_normal_tilt:
                return
            t_hat = np.array([-n_xy[1], n_xy[0]]) / tilt
            r = np.array([float(t_hat @ (n_xy - a_xy))])  # ≈ tilt · (angle of n - angle of a)
            H = np.zeros((1, 6))
            H[0, 0:3] = -(t_hat @ dn_dp)
            H[0, 5] = float(t_hat @ da_dyaw)
        self._extras["normal_residual"] = float(np.linalg.norm(r))
        self._extras["yaw_residual"] = (
            float(wrap_angle(math.atan2(n_xy[1], n_xy[0]) - math.atan2(a_xy[1], a_xy[0])))
            if tilt >= cfg.min_normal_tilt
            else 0.0
        )
        Rn = np.eye(len(r)) * cfg.normal_sigma**2
        if self._correct(r, H, Rn, cfg.gate, 2 * cfg.gate) == 0.0:
            self._flags.add("normal_rejected")

    def _tether_update(self, m: TetherReading) -> None:
        cfg = self.config
        if not m.ok:
            self._flags.add("tether_invalid")
            return
        # position at the reading's time from the current velocity
        p = self._p + self._v * (m.t - self._t)
        diff = p - self.anchor
        d = float(np.linalg.norm(diff))
        if d < 1e-6:
            return
        u = diff / d
        if self._last_tether is not None:
            _, l0, p0 = self._last_tether
            moved = float(np.linalg.norm(p - p0))
            if abs(m.length - l0) > moved + cfg.tether_jump_threshold:
                self._flags.add("tether_jump")
                self._last_tether = (m.t, m.length, p.copy())
                return
        self._last_tether = (m.t, m.length, p.copy())
        r = m.length - d
        H = np.zeros((1, 6))
        H[0, 0:3] = u
        # a slack tether is longer than the straight line and only bounds the distance
        # from above: far beyond the gate it carries no information
        reject = 2.0 * cfg.tether_gate if r > 0 else math.inf
        w = self._correct(
            np.array([r]), H, np.array([[cfg.tether_sigma**2]]), cfg.tether_gate, reject
        )
        self._extras["tether_residual"] = r
        self._extras["tether_weight"] = w
        if w < 1.0:
            self._flags.add("tether_slack" if r > 0 else "tether_short")
