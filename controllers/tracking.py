r"""Velocity limits, timed references, a Kanayama path tracker and a polar point stabiliser.

All controllers here command a unicycle (differential drive) with forward speed
``v`` in m/s and yaw rate ``w`` in rad/s; poses are ``[x, y, theta]`` in m, m,
rad in the world frame.  The unicycle model is

.. math::

    \dot x = v \cos\theta, \qquad \dot y = v \sin\theta, \qquad \dot\theta = \omega .
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from realitygap.controllers.smoothing import SmoothPath
from realitygap.core.geometry import check_finite, wrap_angle

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "KanayamaTracker",
    "PolarStabiliser",
    "ReferenceSample",
    "TimedReference",
    "VelocityLimits",
    "polar_coordinates",
    "tracking_error",
    "unicycle_step",
]


def _check_pose(name: str, pose: npt.ArrayLike) -> FloatArray:
    return check_finite(name, pose, shape=(3,))


def _check_positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be finite and > 0, got {value!r}")


@dataclass(frozen=True)
class VelocityLimits:
    """Speed and acceleration limits of a differential-drive base.

    Defaults follow the Yujin Kobuki (0.70 m/s, 180 °/s) with realistic
    accelerations.

    Attributes
    ----------
    v_max : float
        Largest forward or backward speed in m/s.
    w_max : float
        Largest yaw rate in rad/s.
    a_max : float
        Largest forward acceleration in m/s².
    alpha_max : float
        Largest yaw acceleration in rad/s².
    """

    v_max: float = 0.70
    w_max: float = math.pi
    a_max: float = 1.0
    alpha_max: float = 4.0

    def __post_init__(self) -> None:
        for name in ("v_max", "w_max", "a_max", "alpha_max"):
            _check_positive(f"VelocityLimits.{name}", getattr(self, name))

    def saturate(self, v: float, w: float) -> tuple[float, float]:
        """Scale ``(v, w)`` jointly into the velocity box, keeping the curvature ``w / v``.

        .. math::

            (v, \\omega) \\leftarrow \\frac{(v, \\omega)}
                {\\max(1, |v| / v_\\max, |\\omega| / \\omega_\\max)}
        """
        scale = max(1.0, abs(v) / self.v_max, abs(w) / self.w_max)
        return v / scale, w / scale

    def clip(
        self, v: float, w: float, v_prev: float, w_prev: float, dt: float
    ) -> tuple[float, float]:
        """Limit a command ``(v, w)`` in velocity and in acceleration from ``(v_prev, w_prev)``.

        The command is first scaled into the velocity box (:meth:`saturate`).
        If the change from the previous command then exceeds
        ``a_max * dt`` or ``alpha_max * dt``, the command is scaled down along
        its own direction (keeping the curvature) to the largest factor in
        ``[0, 1]`` that satisfies both acceleration limits; when no such factor
        exists (e.g. when reversing), the command moves from the previous one
        straight towards the requested one as far as the limits allow.  A
        previous command outside the velocity box is treated as if it were
        saturated, so the result always respects the velocity limits.

        Parameters
        ----------
        v, w : float
            Requested speed (m/s) and yaw rate (rad/s).
        v_prev, w_prev : float
            Command of the previous control step.
        dt : float
            Control period in s (> 0).

        Returns
        -------
        v, w : float
            The limited command.
        """
        _check_positive("dt", dt)
        v, w = self.saturate(float(v), float(w))
        v_prev, w_prev = self.saturate(float(v_prev), float(w_prev))
        dv_max = self.a_max * dt
        dw_max = self.alpha_max * dt
        if abs(v - v_prev) <= dv_max and abs(w - w_prev) <= dw_max:
            return v, w
        low, high = 0.0, 1.0
        for requested, previous, step in ((v, v_prev, dv_max), (w, w_prev, dw_max)):
            if requested == 0.0:
                if abs(previous) > step:
                    low, high = 1.0, 0.0  # empty
                continue
            a = (previous - step) / requested
            b = (previous + step) / requested
            low, high = max(low, min(a, b)), min(high, max(a, b))
        if low <= high:
            return high * v, high * w
        dv, dw = v - v_prev, w - w_prev
        fraction = min(
            1.0,
            dv_max / abs(dv) if dv != 0.0 else math.inf,
            dw_max / abs(dw) if dw != 0.0 else math.inf,
        )
        return v_prev + fraction * dv, w_prev + fraction * dw


def unicycle_step(pose: npt.ArrayLike, v: float, w: float, dt: float) -> FloatArray:
    """Exact unicycle motion over ``dt`` s under a constant command (zero-order hold).

    .. math::

        \\theta^+ = \\theta + \\omega\\,\\Delta t, \\qquad
        \\begin{bmatrix} x^+ \\\\ y^+ \\end{bmatrix} =
        \\begin{bmatrix} x \\\\ y \\end{bmatrix} + \\frac{v}{\\omega}
        \\begin{bmatrix} \\sin\\theta^+ - \\sin\\theta \\\\
                         \\cos\\theta - \\cos\\theta^+ \\end{bmatrix}

    (the straight-line limit is used for :math:`|\\omega \\Delta t| < 10^{-9}`).

    Parameters
    ----------
    pose : array_like, shape (3,)
        ``[x, y, theta]`` in m, m, rad.
    v, w : float
        Speed in m/s and yaw rate in rad/s.
    dt : float
        Duration in s.

    Returns
    -------
    ndarray, shape (3,)
        The new pose, heading wrapped to ``[-pi, pi)``.
    """
    x, y, theta = _check_pose("pose", pose)
    turn = w * dt
    if abs(turn) < 1e-9:
        heading = theta + 0.5 * turn
        x += v * dt * math.cos(heading)
        y += v * dt * math.sin(heading)
    else:
        x += v / w * (math.sin(theta + turn) - math.sin(theta))
        y += v / w * (math.cos(theta) - math.cos(theta + turn))
    return np.array([x, y, float(wrap_angle(theta + turn))])


# -- timed reference ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ReferenceSample:
    """A point of a timed reference.

    Attributes
    ----------
    pose : ndarray, shape (3,)
        Reference pose ``[x_r, y_r, theta_r]`` (m, m, rad; heading wrapped).
    v : float
        Reference speed :math:`v_r` in m/s.
    w : float
        Reference yaw rate :math:`\\omega_r` in rad/s.
    s : float
        Arc length along the path in m.
    t : float
        Time since the start of the reference in s.
    """

    pose: FloatArray
    v: float
    w: float
    s: float
    t: float


class TimedReference:
    """Time-parameterisation of a :class:`SmoothPath` under velocity limits.

    The speed profile :math:`v(s)` is the largest one with

    .. math::

        v \\le f v_\\max, \\qquad |\\kappa| v \\le f \\omega_\\max, \\qquad
        \\left|\\frac{dv}{dt}\\right| = \\left|v \\frac{dv}{ds}\\right| \\le f a_\\max,

    a yaw acceleration :math:`|d(\\kappa v)/dt| \\le f \\alpha_\\max`
    (enforced approximately, by lowering the speed where it is exceeded) and
    the given start and end speeds, with :math:`f` = ``speed_fraction`` < 1
    leaving room for the feedback of the tracker.  It is found by the usual
    forward and backward passes over the samples of the path; between samples
    the acceleration is constant.

    Parameters
    ----------
    path : SmoothPath
        The path (dense samples; ``path.s`` increasing).
    limits : VelocityLimits, optional
        Robot limits.
    speed_fraction : float, optional
        :math:`f \\in (0, 1]`.
    start_speed, end_speed : float, optional
        Speeds in m/s at the first and last sample (>= 0).

    Attributes
    ----------
    t : ndarray, shape (N,)
        Time in s at each path sample.
    v : ndarray, shape (N,)
        Speed in m/s at each path sample.
    duration : float
        Time in s to traverse the path.
    """

    def __init__(
        self,
        path: SmoothPath,
        limits: VelocityLimits | None = None,
        *,
        speed_fraction: float = 0.8,
        start_speed: float = 0.0,
        end_speed: float = 0.0,
    ) -> None:
        self.path = path
        self.limits = limits if limits is not None else VelocityLimits()
        if not (0.0 < speed_fraction <= 1.0):
            raise ValueError(f"speed_fraction must lie in (0, 1], got {speed_fraction!r}")
        if not (start_speed >= 0.0 and end_speed >= 0.0):
            raise ValueError(
                f"start_speed and end_speed must be >= 0, got {start_speed}, {end_speed}"
            )
        s = np.asarray(path.s, dtype=float)
        xy = np.asarray(path.xy, dtype=float)
        heading = np.asarray(path.heading, dtype=float)
        if len(s) == 0 or xy.shape != (len(s), 2) or heading.shape != (len(s),):
            raise ValueError(
                f"path arrays must be non-empty with xy (N, 2), heading (N,), s (N,); got "
                f"xy {xy.shape}, heading {heading.shape}, s {s.shape}"
            )
        ds = np.diff(s)
        if np.any(ds <= 0.0):
            raise ValueError("path.s must be strictly increasing")
        self._s = s
        self._xy = xy
        self._heading = heading
        # Heading rate per metre on each interval: consistent with the interpolated poses and
        # not blind to a sharp turn that falls between two curvature samples.
        self._turn_rate = np.diff(heading) / ds if len(s) > 1 else np.zeros(0)
        self.v = self._speed_profile(speed_fraction, start_speed, end_speed)
        self.t = self._times()
        self.duration = float(self.t[-1])

    def _speed_profile(self, fraction: float, start_speed: float, end_speed: float) -> FloatArray:
        lim = self.limits
        s = self._s
        n = len(s)
        if n == 1:
            return np.zeros(1)
        ds = np.diff(s)
        curvature = np.abs(np.asarray(self.path.curvature, dtype=float))
        turn = np.abs(self._turn_rate)
        kappa = curvature.copy()
        kappa[:-1] = np.maximum(kappa[:-1], turn)
        kappa[1:] = np.maximum(kappa[1:], turn)
        cap = np.minimum(fraction * lim.v_max, fraction * lim.w_max / np.maximum(kappa, 1e-12))
        cap[0] = min(cap[0], start_speed)
        cap[-1] = min(cap[-1], end_speed)
        accel = fraction * lim.a_max
        alpha = fraction * lim.alpha_max
        v = cap.copy()
        for _ in range(60):
            for i in range(1, n):
                v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2.0 * accel * ds[i - 1]))
            for i in range(n - 2, -1, -1):
                v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2.0 * accel * ds[i]))
            # Yaw acceleration on each interval, with w = turn_rate * v.
            w_left = self._turn_rate * v[:-1]
            w_right = self._turn_rate * v[1:]
            if len(self._turn_rate) > 1:
                w_node = np.concatenate(
                    [[w_left[0]], 0.5 * (w_right[:-1] + w_left[1:]), [w_right[-1]]]
                )
            else:
                w_node = np.array([w_left[0], w_right[0]])
            dt = self._interval_times(v, ds, accel)
            excess = np.abs(np.diff(w_node)) / np.maximum(dt, 1e-12) / alpha
            bad = excess > 1.0 + 1e-9
            if not np.any(bad):
                break
            # The yaw rate scales with v, its rate of change with v², so shrink by the square root
            # of the excess (at least 2 %, at most half) and sweep again.
            shrink = np.clip(1.0 / np.sqrt(excess[bad]), 0.5, 0.98)
            index = np.nonzero(bad)[0]
            factor = np.ones(n)
            np.minimum.at(factor, index, shrink)
            np.minimum.at(factor, index + 1, shrink)
            v = v * factor
        return v

    @staticmethod
    def _interval_times(v: FloatArray, ds: FloatArray, accel: float) -> FloatArray:
        total = v[:-1] + v[1:]
        with np.errstate(divide="ignore"):
            dt = np.where(total > 1e-12, 2.0 * ds / np.maximum(total, 1e-300), 0.0)
        # An interval that starts and ends at rest: accelerate for half of it, brake for the rest.
        return np.where(total > 1e-12, dt, 2.0 * np.sqrt(ds / accel))

    def _times(self) -> FloatArray:
        if len(self._s) == 1:
            return np.zeros(1)
        dt = self._interval_times(self.v, np.diff(self._s), self.limits.a_max)
        return np.concatenate([[0.0], np.cumsum(dt)])

    @property
    def length(self) -> float:
        """Arc length of the path in m."""
        return float(self._s[-1])

    def sample(self, t: float) -> ReferenceSample:
        """Reference pose, speed and yaw rate at time ``t`` s (clamped to ``[0, duration]``)."""
        t = float(np.clip(t, 0.0, self.duration))
        if len(self._s) == 1:
            return self.sample_at_s(0.0)
        i = int(np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self._s) - 2))
        ds = self._s[i + 1] - self._s[i]
        v0, v1 = self.v[i], self.v[i + 1]
        tau = t - self.t[i]
        if v0 + v1 > 1e-12:
            acceleration = (v1**2 - v0**2) / (2.0 * ds)
            v = max(v0 + acceleration * tau, 0.0)
            travelled = min(v0 * tau + 0.5 * acceleration * tau**2, ds)
        else:
            half = 0.5 * (self.t[i + 1] - self.t[i])
            a = ds / half**2
            if tau <= half:
                v, travelled = a * tau, 0.5 * a * tau**2
            else:
                rest = self.t[i + 1] - self.t[i] - tau
                v, travelled = a * rest, ds - 0.5 * a * rest**2
        return self._at(i, self._s[i] + max(travelled, 0.0), v, t)

    def sample_at_s(self, s: float) -> ReferenceSample:
        """Reference at arc length ``s`` m (clamped), with the profile speed there."""
        s = float(np.clip(s, 0.0, self.length))
        if len(self._s) == 1:
            return ReferenceSample(
                np.array([*self._xy[0], float(wrap_angle(self._heading[0]))]), 0.0, 0.0, 0.0, 0.0
            )
        i = int(np.clip(np.searchsorted(self._s, s, side="right") - 1, 0, len(self._s) - 2))
        v = float(np.interp(s, self._s, self.v))
        return self._at(i, s, v, float(np.interp(s, self._s, self.t)))

    def _at(self, i: int, s: float, v: float, t: float) -> ReferenceSample:
        fraction = (s - self._s[i]) / (self._s[i + 1] - self._s[i])
        xy = self._xy[i] + fraction * (self._xy[i + 1] - self._xy[i])
        heading = self._heading[i] + fraction * (self._heading[i + 1] - self._heading[i])
        pose = np.array([xy[0], xy[1], float(wrap_angle(heading))])
        return ReferenceSample(pose, float(v), float(self._turn_rate[i] * v), float(s), float(t))

    def time_at(self, s: float) -> float:
        """Time in s at which the reference passes arc length ``s`` m (clamped)."""
        return float(np.interp(np.clip(s, 0.0, self.length), self._s, self.t))

    def project(
        self, xy: npt.ArrayLike, s_hint: float | None = None, window: float | None = None
    ) -> float:
        """Arc length in m of the point of the path nearest to ``xy``.

        Parameters
        ----------
        xy : array_like, shape (2,) or (3,)
            Position in m (a pose's heading is ignored).
        s_hint : float, optional
            Arc length near which to search; with ``window`` (m), only
            ``[s_hint - window, s_hint + window]`` is searched, which keeps the
            projection on the right branch where the path passes close to itself.
        window : float, optional
            Half-width in m of the search interval around ``s_hint``.

        Returns
        -------
        float
            Arc length of the nearest point, projected onto the segment between samples.
        """
        point = check_finite("xy", xy)
        if point.shape not in ((2,), (3,)):
            raise ValueError(f"xy must have shape (2,) or (3,), got {point.shape}")
        point = point[:2]
        if len(self._s) == 1:
            return 0.0
        lo, hi = 0, len(self._s) - 1
        if s_hint is not None and window is not None:
            lo = max(0, int(np.searchsorted(self._s, s_hint - window)) - 1)
            hi = min(len(self._s) - 1, int(np.searchsorted(self._s, s_hint + window)) + 1)
            hi = max(hi, lo + 1)
        a = self._xy[lo:hi]
        b = self._xy[lo + 1 : hi + 1]
        ab = b - a
        t = np.clip(np.einsum("ij,ij->i", point - a, ab) / np.einsum("ij,ij->i", ab, ab), 0.0, 1.0)
        distance = np.linalg.norm(a + t[:, None] * ab - point, axis=1)
        k = int(np.argmin(distance))
        return float(self._s[lo + k] + t[k] * (self._s[lo + k + 1] - self._s[lo + k]))


# -- tracking and point stabilisation ------------------------------------------------------------


def tracking_error(pose: npt.ArrayLike, ref_pose: npt.ArrayLike) -> FloatArray:
    """Reference pose seen from the robot: ``[e_x, e_y, e_theta]`` (m, m, rad).

    .. math::

        e_x = \\cos\\theta (x_r - x) + \\sin\\theta (y_r - y), \\quad
        e_y = -\\sin\\theta (x_r - x) + \\cos\\theta (y_r - y), \\quad
        e_\\theta = \\theta_r - \\theta

    with :math:`e_\\theta` wrapped to ``[-pi, pi)``.
    """
    x, y, theta = _check_pose("pose", pose)
    xr, yr, thr = _check_pose("ref_pose", ref_pose)
    c, s = math.cos(theta), math.sin(theta)
    dx, dy = xr - x, yr - y
    return np.array([c * dx + s * dy, -s * dx + c * dy, float(wrap_angle(thr - theta))])


class KanayamaTracker:
    """Kanayama's nonlinear trajectory-tracking law for a unicycle.

    .. math::

        v = v_r \\cos e_\\theta + k_x e_x, \\qquad
        \\omega = \\omega_r + v_r \\left(k_y e_y + k_\\theta \\sin e_\\theta\\right)

    with the errors of :func:`tracking_error`.  It is asymptotically stable
    for :math:`v_r > 0` and positive gains; linearised about the reference,
    the lateral error obeys :math:`\\ddot e_y + v_r k_\\theta \\dot e_y +
    v_r^2 k_y e_y = 0`, so :math:`k_\\theta = 2\\sqrt{k_y}` damps it critically.

    Parameters
    ----------
    kx : float, optional
        Along-track gain :math:`k_x` in 1/s.
    ky : float, optional
        Cross-track gain :math:`k_y` in 1/m².
    ktheta : float, optional
        Heading gain :math:`k_\\theta` in 1/m.

    Notes
    -----
    The law is returned unlimited; pass its output through
    :meth:`VelocityLimits.clip` before sending it to the robot.
    """

    def __init__(self, kx: float = 3.0, ky: float = 25.0, ktheta: float = 10.0) -> None:
        for name, value in (("kx", kx), ("ky", ky), ("ktheta", ktheta)):
            _check_positive(name, value)
        self.kx = float(kx)
        self.ky = float(ky)
        self.ktheta = float(ktheta)

    def command(
        self, pose: npt.ArrayLike, ref_pose: npt.ArrayLike, v_r: float, w_r: float
    ) -> tuple[float, float]:
        """Speed (m/s) and yaw rate (rad/s) that steer ``pose`` onto the moving ``ref_pose``.

        Parameters
        ----------
        pose : array_like, shape (3,)
            Robot pose ``[x, y, theta]`` (m, m, rad).
        ref_pose : array_like, shape (3,)
            Reference pose (m, m, rad).
        v_r, w_r : float
            Reference speed in m/s and yaw rate in rad/s.
        """
        e_x, e_y, e_theta = tracking_error(pose, ref_pose)
        v = v_r * math.cos(e_theta) + self.kx * e_x
        w = w_r + v_r * (self.ky * e_y + self.ktheta * math.sin(e_theta))
        return float(v), float(w)


def polar_coordinates(pose: npt.ArrayLike, goal_pose: npt.ArrayLike) -> tuple[float, float, float]:
    """Polar coordinates ``(rho, alpha, beta)`` of a goal pose seen from a robot pose.

    .. math::

        \\rho = \\lVert (x_g - x, y_g - y) \\rVert, \\quad
        \\alpha = \\operatorname{atan2}(y_g - y, x_g - x) - \\theta, \\quad
        \\beta = \\theta_g - \\operatorname{atan2}(y_g - y, x_g - x),

    angles wrapped to ``[-pi, pi)`` (m, rad, rad).  :math:`\\alpha` is the
    bearing of the goal from the robot's heading; :math:`\\beta` the
    remaining turn after facing it, so that the heading error is
    :math:`\\theta_g - \\theta = \\alpha + \\beta`.
    """
    x, y, theta = _check_pose("pose", pose)
    xg, yg, thg = _check_pose("goal_pose", goal_pose)
    bearing = math.atan2(yg - y, xg - x)
    rho = math.hypot(xg - x, yg - y)
    return rho, float(wrap_angle(bearing - theta)), float(wrap_angle(thg - bearing))


class PolarStabiliser:
    """Point stabiliser in polar coordinates (Astolfi; Siegwart, Nourbakhsh and Scaramuzza).

    With :func:`polar_coordinates` the law is

    .. math::

        v = k_\\rho \\rho, \\qquad \\omega = k_\\alpha \\alpha + k_\\beta \\beta,

    which drives :math:`(\\rho, \\alpha, \\beta) \\to 0` for :math:`k_\\rho > 0`,
    :math:`k_\\beta < 0`, :math:`k_\\alpha > k_\\rho`; the linearisation about the
    goal has the characteristic polynomial
    :math:`(s + k_\\rho)(s^2 + (k_\\alpha - k_\\rho) s - k_\\rho k_\\beta)`, so the
    defaults ``(1, 3, -1)`` are critically damped with all poles at -1/s.
    A goal behind the robot (:math:`|\\alpha| > \\pi/2`) is approached
    backwards: the law is applied to the reversed heading
    :math:`\\theta + \\pi` and goal heading :math:`\\theta_g + \\pi` with
    :math:`v = -k_\\rho \\rho`.  The direction is chosen when a goal is first
    commanded and kept (with hysteresis) until :meth:`reset` or a new goal.

    The command is scaled into the velocity box of ``limits`` jointly, which
    only slows the motion down and keeps its path.  Within ``align_radius``
    of the goal position the robot turns in place onto the goal heading with
    the smoothly saturated law

    .. math::

        \\omega = \\omega_a \\tanh\\!\\left(\\frac{k_a (\\theta_g - \\theta)}{\\omega_a}\\right),
        \\qquad v = k_\\rho \\, e_x ,

    where :math:`e_x` is the goal offset along the heading (so the distance
    can only shrink).

    Parameters
    ----------
    k_rho : float, optional
        :math:`k_\\rho` in 1/s (> 0).
    k_alpha : float, optional
        :math:`k_\\alpha` in 1/s (> ``k_rho``).
    k_beta : float, optional
        :math:`k_\\beta` in 1/s (< 0).
    limits : VelocityLimits, optional
        Velocity box the command is scaled into.
    align_radius : float, optional
        Distance in m below which only the heading is corrected.
    align_gain : float, optional
        :math:`k_a` in 1/s of the final turn.
    align_rate : float, optional
        :math:`\\omega_a` in rad/s, the yaw rate the final turn saturates to.
    allow_reverse : bool, optional
        Whether goals behind the robot are approached backwards.
    reverse_hysteresis : float, optional
        Margin in rad beyond :math:`\\pi/2` of the bearing before the latched
        direction is switched.
    """

    def __init__(
        self,
        k_rho: float = 1.0,
        k_alpha: float = 3.0,
        k_beta: float = -1.0,
        *,
        limits: VelocityLimits | None = None,
        align_radius: float = 1e-3,
        align_gain: float = 3.0,
        align_rate: float = 1.0,
        allow_reverse: bool = True,
        reverse_hysteresis: float = 0.3,
    ) -> None:
        _check_positive("k_rho", k_rho)
        if not (math.isfinite(k_beta) and k_beta < 0.0):
            raise ValueError(f"k_beta must be finite and < 0, got {k_beta!r}")
        if not (math.isfinite(k_alpha) and k_alpha > k_rho):
            raise ValueError(f"k_alpha must be finite and > k_rho = {k_rho}, got {k_alpha!r}")
        for name, value in (
            ("align_radius", align_radius),
            ("align_gain", align_gain),
            ("align_rate", align_rate),
        ):
            _check_positive(name, value)
        if not (math.isfinite(reverse_hysteresis) and 0.0 <= reverse_hysteresis < math.pi / 2):
            raise ValueError(
                f"reverse_hysteresis must lie in [0, pi/2), got {reverse_hysteresis!r}"
            )
        self.k_rho = float(k_rho)
        self.k_alpha = float(k_alpha)
        self.k_beta = float(k_beta)
        self.limits = limits if limits is not None else VelocityLimits()
        self.align_radius = float(align_radius)
        self.align_gain = float(align_gain)
        self.align_rate = float(align_rate)
        self.allow_reverse = bool(allow_reverse)
        self.reverse_hysteresis = float(reverse_hysteresis)
        self._direction = 0
        self._goal: FloatArray | None = None

    def reset(self) -> None:
        """Forget the latched driving direction."""
        self._direction = 0
        self._goal = None

    @property
    def direction(self) -> int:
        """Latched driving direction: +1 forwards, -1 backwards, 0 not chosen yet."""
        return self._direction

    def command(self, pose: npt.ArrayLike, goal_pose: npt.ArrayLike) -> tuple[float, float]:
        """Speed (m/s) and yaw rate (rad/s) towards ``goal_pose``.

        Parameters
        ----------
        pose, goal_pose : array_like, shape (3,)
            Robot and goal poses ``[x, y, theta]`` (m, m, rad), world frame.
        """
        pose = _check_pose("pose", pose)
        goal = _check_pose("goal_pose", goal_pose)
        if self._goal is None or not np.array_equal(goal, self._goal):
            self._goal = goal.copy()
            self._direction = 0
        rho, alpha, beta = polar_coordinates(pose, goal)
        if rho <= self.align_radius:
            heading_error = float(wrap_angle(goal[2] - pose[2]))
            w = self.align_rate * math.tanh(self.align_gain * heading_error / self.align_rate)
            # no faster than the robot can stop from within the turn that is left, at the
            # limits' deceleration: it arrives at rest, not turning past the goal heading
            w_stop = math.sqrt(2.0 * self.limits.alpha_max * abs(heading_error))
            w = max(-w_stop, min(w_stop, w))
            along = math.cos(pose[2]) * (goal[0] - pose[0]) + math.sin(pose[2]) * (
                goal[1] - pose[1]
            )
            return self.limits.saturate(self.k_rho * along, w)

        if self._direction == 0:
            forward = (not self.allow_reverse) or abs(alpha) <= math.pi / 2
            self._direction = 1 if forward else -1
        elif self.allow_reverse:
            current = alpha if self._direction > 0 else float(wrap_angle(alpha + math.pi))
            if abs(current) > math.pi / 2 + self.reverse_hysteresis:
                self._direction = -self._direction
        if self._direction < 0:
            alpha = float(wrap_angle(alpha + math.pi))
            beta = float(wrap_angle(beta + math.pi))
        v = self._direction * self.k_rho * rho
        w = self.k_alpha * alpha + self.k_beta * beta
        return self.limits.saturate(v, w)

    @staticmethod
    def done(
        pose: npt.ArrayLike,
        goal_pose: npt.ArrayLike,
        pos_tol: float = 2e-3,
        ang_tol: float = math.radians(0.3),
    ) -> bool:
        """Whether ``pose`` is within ``pos_tol`` m and ``ang_tol`` rad of ``goal_pose``."""
        pose = _check_pose("pose", pose)
        goal = _check_pose("goal_pose", goal_pose)
        distance = math.hypot(goal[0] - pose[0], goal[1] - pose[1])
        return distance <= pos_tol and abs(float(wrap_angle(goal[2] - pose[2]))) <= ang_tol
