"""Controllers that run a whole scripted drive on a pose estimate.

Each follows :class:`DriveController`: ``command(pose, t) -> (v, ω, done)``.
:class:`SquareDriver` drives Borenstein's UMBmark square;
:class:`PathFollower` tracks a timed path with the Kanayama law.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
import numpy.typing as npt

from realitygap.controllers.tracking import KanayamaTracker, TimedReference
from realitygap.core.geometry import check_finite, se2_between, wrap_angle

FloatArray = npt.NDArray[np.float64]

__all__ = ["DriveController", "PathFollower", "SquareDriver"]


class DriveController(Protocol):
    """A controller that runs a whole drive: it says when the drive is done."""

    def command(self, pose: FloatArray, t: float) -> tuple[float, float, bool]:
        """``(v, ω, done)`` in m/s, rad/s for the estimated pose ``[x, y, θ]`` at time ``t`` s."""
        ...


class SquareDriver:
    r"""Drive an ``L × L`` square by the odometry estimate, turning on the spot at the corners.

    The robot starts facing +x of its start frame; ``"cw"`` turns right (the
    square lies at ``y ≤ 0``), ``"ccw"`` left. Each leg is tracked with

    .. math::

        v = \min\big(v_c,\ \sqrt{2 a d},\ k_d d + v_0\big), \qquad
        \omega = -k_\perp v\, e_\perp - k_\theta \sin(\theta - \varphi),

    (``d`` the distance left along the leg, ``e_⊥`` the lateral offset, ``φ``
    the leg direction; ``k_d = 4/s``, ``v_0 = 1 cm/s``, ``k_⊥ = 4/m²``,
    ``k_θ = 3/s``) until ``d < 0.5 mm``, and each 90° turn with

    .. math::

        \omega = \operatorname{sign}(e) \min\big(\omega_c,\ \sqrt{2 \alpha |e|},\
        k_e |e| + \omega_0\big)

    (``k_e = 10/s``, ``ω_0 = 0.02 rad/s``) until the heading error ``e`` is
    below ``heading_tol``. After the fourth leg the robot turns back to its
    start heading and rests for half a second, as in Borenstein's UMBmark.

    Parameters
    ----------
    start : array_like, shape (3,)
        Start pose in the world, m, m, rad.
    side : float
        Side of the square, m.
    direction : {"cw", "ccw"}
    v_cruise, w_cruise : float
        Leg speed (m/s) and turn rate (rad/s).
    accel, alpha : float
        Deceleration used to approach a corner (m/s²) and a heading (rad/s²).
    heading_tol : float
        Heading tolerance of the turns, rad.
    """

    def __init__(
        self,
        start: npt.ArrayLike,
        side: float,
        direction: str,
        *,
        v_cruise: float = 0.25,
        w_cruise: float = 0.8,
        accel: float = 0.4,
        alpha: float = 1.5,
        heading_tol: float = 1.5e-3,
    ) -> None:
        if direction not in ("cw", "ccw"):
            raise ValueError(f"direction must be 'cw' or 'ccw', got {direction!r}")
        if not side > 0:
            raise ValueError(f"side must be a positive length in m, got {side!r}")
        self.start = check_finite("start", start, (3,))
        self.side = float(side)
        self.direction = direction
        sign = -1.0 if direction == "cw" else 1.0
        corners = np.array([[0, 0], [side, 0], [side, sign * side], [0, sign * side], [0, 0]])
        self._corners = corners.astype(float)
        # leg directions 0, ±π/2, ±π, ±3π/2 and the final heading ±2π ≡ 0 (start frame)
        self._headings = [sign * k * math.pi / 2.0 for k in range(5)]
        self.v_cruise, self.w_cruise = float(v_cruise), float(w_cruise)
        self.accel, self.alpha = float(accel), float(alpha)
        self.heading_tol = float(heading_tol)
        self._leg = 0
        self._turning = False
        self._rest = 0

    def command(self, pose: FloatArray, t: float) -> tuple[float, float, bool]:
        """``(v, ω, done)`` (m/s, rad/s) for the estimated world pose ``[x, y, θ]`` at ``t`` s."""
        x, y, th = se2_between(self.start, pose)
        if self._turning:
            err = float(wrap_angle(self._headings[self._leg] - th))
            if abs(err) < self.heading_tol:
                self._turning = False
                return 0.0, 0.0, False
            w = min(self.w_cruise, math.sqrt(2.0 * self.alpha * abs(err)), 10.0 * abs(err) + 0.02)
            return 0.0, math.copysign(w, err), False
        if self._leg >= 4:
            self._rest += 1
            return 0.0, 0.0, self._rest > 10
        a, b = self._corners[self._leg], self._corners[self._leg + 1]
        phi = self._headings[self._leg]
        u = np.array([math.cos(phi), math.sin(phi)])
        rel = np.array([x, y]) - a
        remaining = float(np.linalg.norm(b - a) - rel @ u)
        lateral = float(rel @ np.array([-u[1], u[0]]))
        if remaining < 5e-4:
            self._leg += 1
            self._turning = True
            return 0.0, 0.0, False
        v = min(self.v_cruise, math.sqrt(2.0 * self.accel * remaining), 4.0 * remaining + 0.01)
        w = -4.0 * v * lateral - 3.0 * math.sin(float(wrap_angle(th - phi)))
        return v, w, False


class PathFollower:
    """Track a :class:`~realitygap.controllers.tracking.TimedReference` with the Kanayama law.

    Parameters
    ----------
    reference : TimedReference
        Timed path in the world frame.
    settle_s : float
        Time (s) after the reference ends during which the tracker keeps
        correcting before the drive ends.
    """

    def __init__(self, reference: TimedReference, settle_s: float = 1.0) -> None:
        self.reference = reference
        self.tracker = KanayamaTracker()
        self.settle_s = float(settle_s)

    def command(self, pose: FloatArray, t: float) -> tuple[float, float, bool]:
        """``(v, ω, done)`` (m/s, rad/s) tracking the reference at ``t`` s from the pose ``[x, y, θ]``."""
        if t > self.reference.duration + self.settle_s:
            return 0.0, 0.0, True
        ref = self.reference.sample(t)
        v, w = self.tracker.command(pose, ref.pose, ref.v, ref.w)
        return v, w, False
