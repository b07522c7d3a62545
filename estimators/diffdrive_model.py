r"""Differential-drive kinematics: encoder ticks → planar motion.

This is the odometry integration used throughout :mod:`realitygap`.

Frames and conventions
----------------------
The robot's ``base`` frame has x forward, y to the left and θ counter-clockwise
(right-handed, z up). A planar pose is ``[x, y, θ]`` in m, m, rad. A wheel tick
count is positive when that wheel drives the robot forward.

For one control cycle the wheels travel

.. math::

    s_L = 2\pi r_L \, n_L / N, \qquad s_R = 2\pi r_R \, n_R / N,

with ``n`` the tick increments and ``N`` ticks per wheel revolution, so the base
moves by

.. math::

    \Delta s = \tfrac12 (s_R + s_L), \qquad \Delta\theta = (s_R - s_L) / b .

Assuming constant wheel speeds within the cycle the base follows a circular arc,
whose body-frame increment is exactly

.. math::

    \delta = \begin{bmatrix} \Delta s \, \frac{\sin\Delta\theta}{\Delta\theta} \\
    \Delta s \, \frac{1 - \cos\Delta\theta}{\Delta\theta} \\ \Delta\theta \end{bmatrix}
    = \begin{bmatrix} c \cos(\Delta\theta/2) \\ c \sin(\Delta\theta/2) \\
    \Delta\theta \end{bmatrix}, \qquad
    c = \Delta s \, \operatorname{sinc}(\Delta\theta / 2),

(``c`` is the chord), well defined at ``Δθ = 0``. A pose is advanced by
compounding, ``q_k = q_{k-1} ⊕ δ_k``; over a sequence this is a cumulative sum
of headings and of chord vectors, which :meth:`DiffDriveKinematics.integrate`
evaluates in vectorised form.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from realitygap.core.geometry import check_finite, wrap_angle
from realitygap.core.jit import KERNELS, compiled
from realitygap.estimators.base import DiffDriveMeasurement, Estimate, WheelTicks

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "UMBMARK_RATIO_BOUNDS",
    "DiffDriveKinematics",
    "OdometryNoise",
    "WheelOdometry",
    "arc_increment",
    "arc_increment_jacobian",
    "integrate_arcs",
    "propagate_pose",
    "se2_compose_jacobians",
]

_SERIES_LIMIT = 1e-2  # |Δθ| below which the arc derivatives use their Taylor series


def arc_increment(ds: npt.ArrayLike, dtheta: npt.ArrayLike) -> FloatArray:
    r"""Body-frame pose increment of a circular arc.

    Parameters
    ----------
    ds : array_like, shape (...)
        Arc length travelled by the base centre, m (negative when reversing).
    dtheta : array_like, shape (...)
        Heading change, rad.

    Returns
    -------
    delta : ndarray, shape (..., 3)
        ``[dx, dy, dθ]`` expressed in the base frame at the start of the arc.

    Notes
    -----
    .. math::

        \delta = [\Delta s\, f_1(\Delta\theta),\ \Delta s\, f_2(\Delta\theta),\
        \Delta\theta], \quad f_1 = \frac{\sin\theta}{\theta},\
        f_2 = \frac{1-\cos\theta}{\theta},

    evaluated as ``f1 = sinc(θ/π)`` and ``f2 = sin(θ/2) sinc(θ/2π)``, exact at 0.
    """
    ds_a = np.asarray(ds, dtype=float)
    th = np.asarray(dtheta, dtype=float)
    ds_a, th = np.broadcast_arrays(ds_a, th)
    f1 = np.sinc(th / np.pi)
    f2 = np.sin(0.5 * th) * np.sinc(th / (2.0 * np.pi))
    return np.stack([ds_a * f1, ds_a * f2, th.astype(float)], axis=-1)


def arc_increment_jacobian(ds: npt.ArrayLike, dtheta: npt.ArrayLike) -> FloatArray:
    """Jacobian of :func:`arc_increment` with respect to ``(Δs, Δθ)``.

    Parameters
    ----------
    ds, dtheta : array_like, shape (...)
        Arc length (m) and heading change (rad).

    Returns
    -------
    J : ndarray, shape (..., 3, 2)
        ``∂δ/∂(Δs, Δθ)``; Taylor series are used for ``|Δθ| < 1e-2`` so the
        result is accurate to machine precision everywhere.
    """
    ds_a = np.asarray(ds, dtype=float)
    th = np.asarray(dtheta, dtype=float)
    ds_a, th = np.broadcast_arrays(ds_a, th)
    f1 = np.sinc(th / np.pi)
    f2 = np.sin(0.5 * th) * np.sinc(th / (2.0 * np.pi))
    small = np.abs(th) < _SERIES_LIMIT
    th_safe = np.where(small, 1.0, th)
    th2 = th * th
    df1 = np.where(
        small,
        -th / 3.0 + th * th2 / 30.0 - th * th2 * th2 / 840.0,
        (th_safe * np.cos(th_safe) - np.sin(th_safe)) / (th_safe * th_safe),
    )
    df2 = np.where(
        small,
        0.5 - th2 / 8.0 + th2 * th2 / 144.0,
        (th_safe * np.sin(th_safe) - 1.0 + np.cos(th_safe)) / (th_safe * th_safe),
    )
    J = np.zeros((*th.shape, 3, 2))
    J[..., 0, 0] = f1
    J[..., 1, 0] = f2
    J[..., 0, 1] = ds_a * df1
    J[..., 1, 1] = ds_a * df2
    J[..., 2, 1] = 1.0
    return J


def se2_compose_jacobians(a: npt.ArrayLike, b: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    r"""Jacobians of the compound ``a ⊕ b`` with respect to ``a`` and ``b``.

    Parameters
    ----------
    a, b : array_like, shape (3,)
        Planar poses ``[x, y, θ]`` (m, m, rad).

    Returns
    -------
    J_a, J_b : ndarray, shape (3, 3)

    Notes
    -----
    .. math::

        J_a = \begin{bmatrix} 1 & 0 & -s_a b_x - c_a b_y \\ 0 & 1 & c_a b_x - s_a b_y \\
        0 & 0 & 1 \end{bmatrix}, \qquad
        J_b = \begin{bmatrix} c_a & -s_a & 0 \\ s_a & c_a & 0 \\ 0 & 0 & 1 \end{bmatrix}.
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    c, s = math.cos(a[2]), math.sin(a[2])
    J_a = np.array(
        [
            [1.0, 0.0, -s * b[0] - c * b[1]],
            [0.0, 1.0, c * b[0] - s * b[1]],
            [0.0, 0.0, 1.0],
        ]
    )
    J_b = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return J_a, J_b


def integrate_arcs(
    pose0: npt.ArrayLike,
    ds: npt.ArrayLike,
    dtheta: npt.ArrayLike,
    *,
    wrap: bool = True,
) -> FloatArray:
    r"""Compound a sequence of arc increments onto a start pose.

    Parameters
    ----------
    pose0 : array_like, shape (3,)
        Start pose ``[x, y, θ]`` in the world frame (m, m, rad).
    ds, dtheta : array_like, shape (N,)
        Arc lengths (m) and heading changes (rad) of the ``N`` steps.
    wrap : bool, default True
        Wrap the headings to ``[-π, π)``; with ``False`` the heading is
        continuous (``θ0 + cumsum(Δθ)``), which is convenient for plotting and
        for comparing with unwrapped ground truth.

    Returns
    -------
    poses : ndarray, shape (N + 1, 3)
        ``poses[0] = pose0`` and ``poses[k]`` the pose after the first ``k`` steps.

    Notes
    -----
    Exact for piecewise-constant wheel speeds:

    .. math::

        \theta_k = \theta_0 + \sum_{j \le k} \Delta\theta_j, \quad
        p_k = p_0 + \sum_{j \le k} c_j
        \begin{bmatrix}\cos(\theta_{j-1} + \Delta\theta_j/2) \\
        \sin(\theta_{j-1} + \Delta\theta_j/2)\end{bmatrix}.
    """
    p0 = check_finite("pose0", pose0, (3,))
    ds_a = np.asarray(ds, dtype=float)
    th = np.asarray(dtheta, dtype=float)
    if ds_a.ndim != 1 or th.shape != ds_a.shape:
        raise ValueError(
            f"ds and dtheta must be 1-D arrays of equal length, got shapes {ds_a.shape} "
            f"and {th.shape}"
        )
    n = ds_a.shape[0]
    poses = np.empty((n + 1, 3))
    poses[0] = p0
    if n == 0:
        if wrap:
            poses[:, 2] = wrap_angle(poses[:, 2])
        return poses
    heading = p0[2] + np.concatenate(([0.0], np.cumsum(th)))
    mid = heading[:-1] + 0.5 * th
    chord = ds_a * np.sinc(th / (2.0 * np.pi))
    poses[1:, 0] = p0[0] + np.cumsum(chord * np.cos(mid))
    poses[1:, 1] = p0[1] + np.cumsum(chord * np.sin(mid))
    poses[:, 2] = wrap_angle(heading) if wrap else heading
    return poses


def _check_positive(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v) or v <= 0.0:
        raise ValueError(f"{name} must be a finite positive number, got {value!r}")
    return v


UMBMARK_RATIO_BOUNDS = (0.5, 2.0)
"""Physical bounds of the UMBmark ratios ``E_d`` and ``E_b`` (:meth:`DiffDriveKinematics.with_umbmark`).

Both are ratios of a true to a nominal length, near 1: a wheel twice the size of
the other, or a wheelbase half the nominal one, is another robot, not a
systematic odometry error."""


def _check_ratio(name: str, value: object, meaning: str) -> float:
    """``value`` as a ratio near 1 within :data:`UMBMARK_RATIO_BOUNDS` (dimensionless)."""
    low, high = UMBMARK_RATIO_BOUNDS
    fix = (
        f"Fix: pass {name} = {meaning} (unit 1; 1 when the robot is as declared); "
        "if a UMBmark result is this far from 1, check the errors' sign convention and units"
    )
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(
            f"{name} must be a finite positive number near 1 in [{low:g}, {high:g}], "
            f"got {value!r} ({type(value).__name__}). {fix}"
        )
    v = float(value)
    if not (math.isfinite(v) and low <= v <= high):
        raise ValueError(
            f"{name} must be a finite positive number near 1 in [{low:g}, {high:g}], "
            f"got {value!r}. {fix}"
        )
    return v


@dataclass(frozen=True)
class DiffDriveKinematics:
    """Wheel geometry of a differential drive.

    Parameters
    ----------
    wheel_radius_left, wheel_radius_right : float
        Effective rolling radii, m.
    wheelbase : float
        Effective distance between the wheel contact points, m.
    ticks_per_rev : float
        Encoder counts per wheel revolution (after any gearbox and quadrature
        decoding), so one tick is ``2π r / ticks_per_rev`` m of travel.

    Examples
    --------
    >>> kin = DiffDriveKinematics.from_diameters(0.084, 0.084, 0.2, 2796.8)
    >>> round(kin.meters_per_tick_left * 1e6, 2)  # µm per tick
    94.36
    """

    wheel_radius_left: float
    wheel_radius_right: float
    wheelbase: float
    ticks_per_rev: float

    def __post_init__(self) -> None:
        for name in ("wheel_radius_left", "wheel_radius_right", "wheelbase", "ticks_per_rev"):
            object.__setattr__(self, name, _check_positive(name, getattr(self, name)))

    @classmethod
    def from_diameters(
        cls,
        diameter_left: float,
        diameter_right: float,
        wheelbase: float,
        ticks_per_rev: float,
    ) -> DiffDriveKinematics:
        """Build from wheel diameters (m) instead of radii."""
        return cls(
            wheel_radius_left=0.5 * float(diameter_left),
            wheel_radius_right=0.5 * float(diameter_right),
            wheelbase=wheelbase,
            ticks_per_rev=ticks_per_rev,
        )

    @property
    def meters_per_tick_left(self) -> float:
        """Travel of the left wheel per tick, m."""
        return 2.0 * math.pi * self.wheel_radius_left / self.ticks_per_rev

    @property
    def meters_per_tick_right(self) -> float:
        """Travel of the right wheel per tick, m."""
        return 2.0 * math.pi * self.wheel_radius_right / self.ticks_per_rev

    def increment_from_ticks(
        self, d_left: npt.ArrayLike, d_right: npt.ArrayLike
    ) -> tuple[Any, Any]:
        r"""Base motion ``(Δs, Δθ)`` for tick increments.

        Parameters
        ----------
        d_left, d_right : float or array_like, shape (...)
            Tick increments of the left and right wheel.

        Returns
        -------
        ds : float or ndarray, shape (...)
            Arc length of the base centre, m.
        dtheta : float or ndarray, shape (...)
            Heading change, rad (counter-clockwise positive).

        Notes
        -----
        .. math::

            \Delta s = \tfrac12 (m_R n_R + m_L n_L), \qquad
            \Delta\theta = (m_R n_R - m_L n_L) / b .
        """
        if type(d_left) is float and type(d_right) is float:  # one step: plain float math
            return tick_increment(
                self.meters_per_tick_left,
                self.meters_per_tick_right,
                self.wheelbase,
                d_left,
                d_right,
            )
        s_left = self.meters_per_tick_left * np.asarray(d_left, dtype=float)
        s_right = self.meters_per_tick_right * np.asarray(d_right, dtype=float)
        ds = 0.5 * (s_right + s_left)
        dtheta = (s_right - s_left) / self.wheelbase
        if ds.ndim == 0:
            return float(ds), float(dtheta)
        return ds, dtheta

    def integrate(
        self,
        pose0: npt.ArrayLike,
        d_ticks_left: npt.ArrayLike,
        d_ticks_right: npt.ArrayLike,
        *,
        wrap: bool = True,
    ) -> FloatArray:
        """Dead-reckon a pose sequence from per-cycle tick increments.

        Parameters
        ----------
        pose0 : array_like, shape (3,)
            Start pose ``[x, y, θ]`` (m, m, rad) in the world frame.
        d_ticks_left, d_ticks_right : array_like, shape (N,)
            Tick increments per cycle.
        wrap : bool, default True
            Wrap headings to ``[-π, π)`` (see :func:`integrate_arcs`).

        Returns
        -------
        poses : ndarray, shape (N + 1, 3)
            ``poses[0] = pose0``; ``poses[k]`` after the first ``k`` increments.
        """
        d_l = np.asarray(d_ticks_left, dtype=float)
        d_r = np.asarray(d_ticks_right, dtype=float)
        if d_l.ndim != 1 or d_l.shape != d_r.shape:
            raise ValueError(
                "d_ticks_left and d_ticks_right must be 1-D arrays of equal length, got "
                f"shapes {d_l.shape} and {d_r.shape}"
            )
        if not (np.all(np.isfinite(d_l)) and np.all(np.isfinite(d_r))):
            raise ValueError("tick increments must be finite; found NaN or inf")
        ds, dtheta = self.increment_from_ticks(d_l, d_r)
        return integrate_arcs(pose0, ds, dtheta, wrap=wrap)

    def scaled(
        self, left: float = 1.0, right: float = 1.0, wheelbase: float = 1.0
    ) -> DiffDriveKinematics:
        """Kinematics with radii and wheelbase multiplied by the given factors."""
        return replace(
            self,
            wheel_radius_left=self.wheel_radius_left * float(left),
            wheel_radius_right=self.wheel_radius_right * float(right),
            wheelbase=self.wheelbase * float(wheelbase),
        )

    def with_umbmark(self, E_d: float, E_b: float) -> DiffDriveKinematics:
        """Kinematics corrected with Borenstein's UMBmark factors.

        Parameters
        ----------
        E_d : float
            Ratio of the actual right to left wheel diameter, relative to the
            nominal ratio (``D_R / D_L`` when the nominal wheels are equal).
        E_b : float
            Ratio of the actual to the nominal wheelbase.

        Returns
        -------
        DiffDriveKinematics
            Radii scaled by ``c_L = 2/(E_d + 1)`` and ``c_R = 2/(1/E_d + 1)``
            (their mean is 1, so the average wheel size, which UMBmark cannot
            observe, is unchanged) and wheelbase scaled by ``E_b``.

        Raises
        ------
        ValueError
            ``E_d`` or ``E_b`` is not finite or outside :data:`UMBMARK_RATIO_BOUNDS`
            (a ratio ``≤ 0`` has no wheel behind it).
        TypeError
            Not a real number.
        """
        e_d = _check_ratio("E_d", E_d, "D_R / D_L, the right over the left wheel diameter")
        e_b = _check_ratio("E_b", E_b, "the actual over the nominal wheelbase")
        c_left = 2.0 / (e_d + 1.0)
        c_right = 2.0 / (1.0 / e_d + 1.0)
        return self.scaled(left=c_left, right=c_right, wheelbase=e_b)


@dataclass(frozen=True)
class OdometryNoise:
    r"""Growth of the dead-reckoning covariance per step.

    The wheel-odometry increment ``(Δs, Δθ)`` of one step is given the variances

    .. math::

        \sigma_s^2 = k_s |\Delta s| + \sigma_{s,0}^2, \qquad
        \sigma_\theta^2 = k_\theta |\Delta\theta| + k_{\theta s} |\Delta s|
        + \sigma_{\theta,0}^2,

    so the covariance grows in proportion to distance travelled and rotation.

    Attributes
    ----------
    distance_var_per_m : float
        ``k_s``, m²/m (1e-4: 1 cm standard deviation after 1 m).
    heading_var_per_rad : float
        ``k_θ``, rad²/rad.
    heading_var_per_m : float
        ``k_θs``, rad²/m (heading drift while driving straight).
    distance_var_floor, heading_var_floor : float
        ``σ_{s,0}²`` (m²) and ``σ_{θ,0}²`` (rad²) added every step.
    """

    distance_var_per_m: float = 1e-4
    heading_var_per_rad: float = 1e-3
    heading_var_per_m: float = 1e-4
    distance_var_floor: float = 0.0
    heading_var_floor: float = 0.0

    def __post_init__(self) -> None:
        for name in (
            "distance_var_per_m",
            "heading_var_per_rad",
            "heading_var_per_m",
            "distance_var_floor",
            "heading_var_floor",
        ):
            v = float(getattr(self, name))
            if not math.isfinite(v) or v < 0.0:
                raise ValueError(f"{name} must be finite and >= 0, got {v!r}")

    def variances(self, ds: float, dtheta: float) -> tuple[float, float]:
        """Variances ``(σ_s², σ_θ²)`` (m², rad²) of ``(Δs, Δθ)`` for one step."""
        return _increment_variances(*self.coefficients, ds, dtheta)

    @property
    def coefficients(self) -> tuple[float, float, float, float, float]:
        """``(k_s, k_θ, k_θs, σ_{s,0}², σ_{θ,0}²)`` as plain floats."""
        return (
            float(self.distance_var_per_m),
            float(self.heading_var_per_rad),
            float(self.heading_var_per_m),
            float(self.distance_var_floor),
            float(self.heading_var_floor),
        )

    def covariance(self, ds: float, dtheta: float) -> FloatArray:
        """2×2 covariance of ``(Δs, Δθ)`` for one step (diagonal: :meth:`variances`)."""
        return np.diag(self.variances(ds, dtheta))


def propagate_pose(
    pose: FloatArray, cov: FloatArray, ds: float, dtheta: float, noise: OdometryNoise
) -> tuple[FloatArray, FloatArray]:
    r"""Advance a pose and its covariance by one arc increment.

    .. math::

        q^+ = q \oplus \delta(\Delta s, \Delta\theta), \qquad
        P^+ = J_a P J_a^\top + (J_b J_\delta) Q (J_b J_\delta)^\top .
    """
    # scalar arithmetic throughout: this runs once per control step inside the envs
    ds, dtheta = float(ds), float(dtheta)
    q_s, q_th = noise.variances(ds, dtheta)
    (p00, p01, p02), (p10, p11, p12), (p20, p21, p22) = cov.tolist()
    x, y, th0 = pose.tolist()
    nx, ny, nth, n00, s01, s02, n11, s12, n22 = _propagate_scalars(
        x, y, th0, p00, p01, p02, p10, p11, p12, p20, p21, p22, ds, dtheta, q_s, q_th
    )
    return np.array([nx, ny, nth]), np.array([[n00, s01, s02], [s01, n11, s12], [s02, s12, n22]])


def _increment_variances(
    k_s: float, k_th: float, k_ths: float, floor_s: float, floor_th: float, ds: float, dtheta: float
) -> tuple[float, float]:
    """:meth:`OdometryNoise.variances` from its :attr:`~OdometryNoise.coefficients`."""
    return k_s * abs(ds) + floor_s, k_th * abs(dtheta) + k_ths * abs(ds) + floor_th


def _propagate_scalars(
    x: float,
    y: float,
    th0: float,
    p00: float,
    p01: float,
    p02: float,
    p10: float,
    p11: float,
    p12: float,
    p20: float,
    p21: float,
    p22: float,
    ds: float,
    dtheta: float,
    q_s: float,
    q_th: float,
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """:func:`propagate_pose` on floats: the new pose ``(x, y, θ)`` and the upper triangle of
    the new covariance ``(P00, P01, P02, P11, P12, P22)``, with the increment's variances
    ``q_s``, ``q_th``. One definition for the Python and the compiled path."""
    th = dtheta
    if abs(th) < _SERIES_LIMIT:
        th2 = th * th
        f1 = 1.0 - th2 / 6.0 + th2 * th2 / 120.0
        f2 = th / 2.0 - th * th2 / 24.0 + th * th2 * th2 / 720.0
        df1 = -th / 3.0 + th * th2 / 30.0 - th * th2 * th2 / 840.0
        df2 = 0.5 - th2 / 8.0 + th2 * th2 / 144.0
    else:
        st, ct = math.sin(th), math.cos(th)
        f1, f2 = st / th, (1.0 - ct) / th
        df1 = (th * ct - st) / (th * th)
        df2 = (th * st - 1.0 + ct) / (th * th)
    dx, dy = ds * f1, ds * f2
    c, s = math.cos(th0), math.sin(th0)
    nx = x + c * dx - s * dy
    ny = y + s * dx + c * dy
    nth = (th0 + dtheta + math.pi) % (2.0 * math.pi) - math.pi
    # J_a = ∂(a ⊕ δ)/∂a is the identity but for its last column (a, b, 1);
    # G = ∂(a ⊕ δ)/∂δ · ∂δ/∂(Δs, Δθ) has the rows (g00, g01), (g10, g11), (0, 1)
    a, b = -s * dx - c * dy, c * dx - s * dy
    g00, g01 = c * f1 - s * f2, ds * (c * df1 - s * df2)
    g10, g11 = s * f1 + c * f2, ds * (s * df1 + c * df2)
    # J_a P J_a^T, row by row: r_i = (J_a P)_i, then r_i J_a^T
    r00, r01, r02 = p00 + a * p20, p01 + a * p21, p02 + a * p22
    r10, r11, r12 = p10 + b * p20, p11 + b * p21, p12 + b * p22
    m00, m01, m02 = r00 + r02 * a, r01 + r02 * b, r02
    m10, m11, m12 = r10 + r12 * a, r11 + r12 * b, r12
    m20, m21, m22 = p20 + p22 * a, p21 + p22 * b, p22
    # + G Q G^T (Q diagonal)
    u0, u1 = g00 * q_s, g01 * q_th
    v0, v1 = g10 * q_s, g11 * q_th
    n00 = m00 + (u0 * g00 + u1 * g01)
    n01 = m01 + (u0 * g10 + u1 * g11)
    n02 = m02 + u1
    n10 = m10 + (v0 * g00 + v1 * g01)
    n11 = m11 + (v0 * g10 + v1 * g11)
    n12 = m12 + v1
    n20 = m20 + q_th * g01
    n21 = m21 + q_th * g11
    n22 = m22 + q_th
    # symmetric by construction up to rounding: average the two triangles
    s01, s02, s12 = 0.5 * (n01 + n10), 0.5 * (n02 + n20), 0.5 * (n12 + n21)
    return nx, ny, nth, n00, s01, s02, n11, s12, n22


_variances_kernel = compiled(_increment_variances) or _increment_variances
_propagate_kernel = compiled(_propagate_scalars) or _propagate_scalars


def propagate_pose_in_place(
    pose: FloatArray,
    cov: FloatArray,
    ds: float,
    dtheta: float,
    k_s: float,
    k_th: float,
    k_ths: float,
    floor_s: float,
    floor_th: float,
) -> None:
    """:func:`propagate_pose` writing into ``pose`` (3,) and ``cov`` (3, 3), with the
    noise given by :attr:`OdometryNoise.coefficients`; compiled as
    :data:`propagate_pose_in_place_compiled` (the same bits)."""
    q_s, q_th = _variances_kernel(k_s, k_th, k_ths, floor_s, floor_th, ds, dtheta)
    nx, ny, nth, n00, s01, s02, n11, s12, n22 = _propagate_kernel(
        pose[0],
        pose[1],
        pose[2],
        cov[0, 0],
        cov[0, 1],
        cov[0, 2],
        cov[1, 0],
        cov[1, 1],
        cov[1, 2],
        cov[2, 0],
        cov[2, 1],
        cov[2, 2],
        ds,
        dtheta,
        q_s,
        q_th,
    )
    pose[0], pose[1], pose[2] = nx, ny, nth
    cov[0, 0], cov[0, 1], cov[0, 2] = n00, s01, s02
    cov[1, 0], cov[1, 1], cov[1, 2] = s01, n11, s12
    cov[2, 0], cov[2, 1], cov[2, 2] = s02, s12, n22


propagate_pose_in_place_compiled = compiled(propagate_pose_in_place)
""":func:`propagate_pose_in_place` compiled by Numba; ``None`` without Numba."""


def tick_increment(
    m_left: float, m_right: float, wheelbase: float, d_left: float, d_right: float
) -> tuple[float, float]:
    """Base motion ``(Δs, Δθ)`` (m, rad) of tick increments ``d_left``, ``d_right`` for
    travels per tick ``m_left``, ``m_right`` (m) and ``wheelbase`` (m): the float form of
    :meth:`DiffDriveKinematics.increment_from_ticks`."""
    s_l = m_left * d_left
    s_r = m_right * d_right
    return 0.5 * (s_r + s_l), (s_r - s_l) / wheelbase


_tick_increment = compiled(tick_increment) or tick_increment
_propagate_pose_in_place = propagate_pose_in_place_compiled or propagate_pose_in_place
"""The compiled twins :func:`odometry_step_in_place` calls (a compiled kernel calls only
compiled functions); the functions themselves without Numba."""


def odometry_step_in_place(
    pose: FloatArray,
    cov: FloatArray,
    d_left: float,
    d_right: float,
    m_left: float,
    m_right: float,
    wheelbase: float,
    k_s: float,
    k_th: float,
    k_ths: float,
    floor_s: float,
    floor_th: float,
) -> float:
    """One wheel-odometry step: :func:`tick_increment` of the tick increments, then
    :func:`propagate_pose_in_place` of ``pose`` (3,) and ``cov`` (3, 3); returns ``Δs``
    (m). Compiled as :data:`odometry_step_in_place_compiled` (the same bits)."""
    ds, dtheta = _tick_increment(m_left, m_right, wheelbase, d_left, d_right)
    _propagate_pose_in_place(pose, cov, ds, dtheta, k_s, k_th, k_ths, floor_s, floor_th)
    return ds


odometry_step_in_place_compiled = compiled(odometry_step_in_place)
""":func:`odometry_step_in_place` compiled by Numba; ``None`` without Numba."""


class WheelOdometry:
    """Dead reckoning from cumulative wheel ticks (an :class:`Estimator`).

    Parameters
    ----------
    kinematics : DiffDriveKinematics
        Wheel radii and wheelbase used for integration.
    noise : OdometryNoise, optional
        Covariance growth model.

    Notes
    -----
    The first :class:`WheelTicks` after :meth:`reset` only sets the reference
    count. Tick increments are converted to wheel revolutions with the
    measurement's own ``ticks_per_rev`` (what the encoder reports) and to
    distance with the kinematics' radii. Measurements with non-finite counts,
    a non-positive resolution or a time earlier than the previous one are
    rejected: the estimate is kept, ``extras["n_rejected"]`` counts them and
    ``status`` says why.

    Examples
    --------
    >>> kin = DiffDriveKinematics(0.035, 0.035, 0.23, 1000.0)
    >>> odo = WheelOdometry(kin)
    >>> _ = odo.reset()
    >>> _ = odo.update(WheelTicks(t=0.0, left=0, right=0, ticks_per_rev=1000.0))
    >>> est = odo.update(WheelTicks(t=0.1, left=1000, right=1000, ticks_per_rev=1000.0))
    >>> round(float(est.pose[0]), 4)  # one wheel revolution = 2π·0.035 m
    0.2199
    """

    def __init__(self, kinematics: DiffDriveKinematics, noise: OdometryNoise | None = None):
        if not isinstance(kinematics, DiffDriveKinematics):
            raise TypeError(
                f"kinematics must be a DiffDriveKinematics, got {type(kinematics).__name__}"
            )
        self.kinematics = kinematics
        self.noise = noise if noise is not None else OdometryNoise()
        self._step_constants = self._constants()
        self._pose = np.zeros(3)
        self._cov = np.zeros((3, 3))
        self._last: WheelTicks | None = None
        self._t = 0.0
        self._n_rejected = 0
        self._distance = 0.0
        self._estimate = self._make_estimate("ok")

    @property
    def pose(self) -> FloatArray:
        """Current pose ``[x, y, θ]`` (m, m, rad), a copy."""
        return self._pose.copy()

    @property
    def cov(self) -> FloatArray:
        """Current 3×3 pose covariance, a copy."""
        return self._cov.copy()

    def reset(self, initial: Any | None = None) -> Estimate:
        """Start from ``initial``: ``None`` (origin), a pose (3,), or an :class:`Estimate`."""
        if initial is None:
            pose, cov = np.zeros(3), np.zeros((3, 3))
        elif isinstance(initial, Estimate):
            pose = check_finite("initial.pose", initial.pose, (3,)).copy()
            cov = check_finite("initial.cov", initial.cov, (3, 3)).copy()
        else:
            pose, cov = check_finite("initial", initial, (3,)).copy(), np.zeros((3, 3))
        pose[2] = wrap_angle(pose[2])
        self._pose, self._cov = pose, cov
        self._last = None
        self._t = 0.0
        self._n_rejected = 0
        self._distance = 0.0
        self._estimate = self._make_estimate("ok")
        return self._estimate

    def update(self, measurement: WheelTicks | None) -> Estimate:
        """Integrate the ticks since the previous measurement; ``None`` returns the last estimate."""
        if measurement is None:
            return self._estimate
        if type(measurement) is DiffDriveMeasurement:
            measurement = measurement.ticks
        elif not isinstance(measurement, WheelTicks) and isinstance(
            getattr(measurement, "ticks", None), WheelTicks
        ):
            measurement = measurement.ticks  # a sensor bundle such as DiffDriveMeasurement
        if not isinstance(measurement, WheelTicks):
            raise TypeError(
                f"WheelOdometry.update expects WheelTicks or None, got {type(measurement).__name__}"
            )
        reason = None
        isfinite = math.isfinite
        t, left, right = measurement.t, measurement.left, measurement.right
        ticks_per_rev, last = measurement.ticks_per_rev, self._last
        if not (isfinite(t) and isfinite(left) and isfinite(right) and isfinite(ticks_per_rev)):
            reason = "non-finite wheel ticks"
        elif ticks_per_rev <= 0:
            reason = f"ticks_per_rev must be > 0, got {ticks_per_rev}"
        elif last is not None and t < last.t:
            reason = f"time went backwards ({t} s < {last.t} s)"
        if reason is not None:
            self._n_rejected += 1
            self._estimate = self._make_estimate(f"rejected: {reason}")
            return self._estimate
        if last is not None:
            kin = self.kinematics
            scale = kin.ticks_per_rev / float(ticks_per_rev)
            d_left = (left - last.left) * scale
            d_right = (right - last.right) * scale
            if odometry_step_in_place_compiled is not None and KERNELS.on:
                # self._pose and self._cov are this estimator's own: updated in place
                consts = self._step_constants
                if consts[0] is not kin or consts[1] is not self.noise:  # replaced
                    consts = self._step_constants = self._constants()
                ds = odometry_step_in_place_compiled(
                    self._pose, self._cov, d_left, d_right, *consts[2:]
                )
            else:
                ds, dtheta = kin.increment_from_ticks(d_left, d_right)
                self._pose, self._cov = propagate_pose(
                    self._pose, self._cov, ds, dtheta, self.noise
                )
            self._distance += abs(ds)
        self._last = measurement
        self._t = float(t)
        self._estimate = self._make_estimate("ok")
        return self._estimate

    def _constants(self) -> tuple[Any, ...]:
        """The kinematics and noise model, then the constants
        :func:`odometry_step_in_place` takes from them (read once, not at every step)."""
        kin, noise = self.kinematics, self.noise
        return (
            kin,
            noise,
            kin.meters_per_tick_left,
            kin.meters_per_tick_right,
            kin.wheelbase,
            *noise.coefficients,
        )

    def _make_estimate(self, status: str) -> Estimate:
        # positional (t, pose, cov, ok, status, extras): cheaper than keywords, once per step
        return Estimate(
            self._t,
            self._pose.copy(),
            self._cov.copy(),
            True,
            status,
            {"n_rejected": self._n_rejected, "distance": self._distance},
        )
