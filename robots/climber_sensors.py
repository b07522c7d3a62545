"""Sensors of the wheeled adsorption climber (:mod:`realitygap.robots.climber`).

:class:`ImuModel` (gyroscope + accelerometer from the body state, white noise,
random-walk and constant bias), :class:`TetherModel` (straight line to the anchor in
the nominal model; sag, stretch, spool scale and anchor error as effects; slack and
jump faults), :class:`CameraModel` (down-looking camera, small field of view; fast
geometric mode → :class:`.RelativeMotion`, image mode → :class:`.CameraFrame` rendered
with TinyRenderer from the textured mesh). All noise is drawn from the generator
handed down by the env.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import numpy.typing as npt
import pybullet as p

from realitygap.core.geometry import so3_exp, so3_log
from realitygap.estimators.climb.measurements import (
    CameraFrame,
    ImuSample,
    RelativeMotion,
    TetherReading,
)
from realitygap.estimators.climb.vio import VioConfig
from realitygap.robots.climber import (
    GRAVITY,
    BodyState,
    ClimberParams,
    ClimberRobot,
    ClimbFaults,
)
from realitygap.robots.sensors import SensorMode, check_sensor_mode

FloatArray = npt.NDArray[np.float64]

__all__ = ["CameraModel", "ImuModel", "TetherModel"]


def _gamma1_inv(theta: FloatArray) -> FloatArray:
    """Inverse of :math:`\\Gamma_1(\\theta) = \\int_0^1 \\mathrm{Exp}(\\sigma\\theta)d\\sigma`
    (the left Jacobian of SO(3)), in closed form:
    :math:`I - \\tfrac12 K + \\left(\\tfrac{1}{a^2} - \\tfrac{1 + \\cos a}{2 a \\sin a}\\right) K^2`,
    :math:`K = [\\theta]_\\times`, :math:`a = \\lVert\\theta\\rVert` (rad)."""
    a = math.sqrt(float(theta @ theta))
    K = np.array([[0, -theta[2], theta[1]], [theta[2], 0, -theta[0]], [-theta[1], theta[0], 0]])
    if a < 1e-4:
        return np.eye(3) - K / 2 + K @ K / 12
    return np.eye(3) - K / 2 + (1 / a**2 - (1 + math.cos(a)) / (2 * a * math.sin(a))) * K @ K


class ImuModel:
    """Gyroscope and accelerometer from consecutive body states.

    The reading over ``[t_k, t_{k+1})`` is the constant rate that turns :math:`R_k` into
    :math:`R_{k+1}` and the constant specific force that reproduces the velocity change
    under gravity (the pre-integration model), plus white noise, a random-walk bias, a
    per-episode turn-on bias and the constant bias of the params.

    Parameters
    ----------
    params
        True parameters.
    rng
        Episode generator.
    """

    def __init__(self, params: ClimberParams, rng: np.random.Generator) -> None:
        self.params = params
        self.rng = rng
        self.dt = 1.0 / params.imu_rate
        self.bias_gyro = np.asarray(params.gyro_bias, dtype=float) + rng.normal(
            0, params.gyro_bias_sigma, 3
        )
        self.bias_accel = np.asarray(params.accel_bias, dtype=float) + rng.normal(
            0, params.accel_bias_sigma, 3
        )
        self._g = np.array([0.0, 0.0, -GRAVITY])

    def _noisy(self, gyro: FloatArray, accel: FloatArray) -> tuple[FloatArray, FloatArray]:
        prm, rng, dt = self.params, self.rng, self.dt
        self.bias_gyro = self.bias_gyro + rng.normal(0, prm.gyro_bias_walk * math.sqrt(dt), 3)
        self.bias_accel = self.bias_accel + rng.normal(0, prm.accel_bias_walk * math.sqrt(dt), 3)
        g = gyro + self.bias_gyro + rng.normal(0, prm.gyro_noise_density / math.sqrt(dt), 3)
        a = accel + self.bias_accel + rng.normal(0, prm.accel_noise_density / math.sqrt(dt), 3)
        return g, a

    def sample(self, s0: BodyState, s1: BodyState) -> ImuSample:
        """The reading for the interval from ``s0`` to ``s1``."""
        dt = s1.t - s0.t
        theta = so3_log(s0.R.T @ s1.R)
        omega = theta / dt
        dv = s1.velocity - s0.velocity - self._g * dt
        accel = _gamma1_inv(theta) @ (s0.R.T @ dv) / dt  # solves R Γ1 dt · f = Δv
        g, a = self._noisy(omega, accel)
        return ImuSample(s0.t, g, a)

    def at_rest(self, R_world_body: FloatArray, t0: float, n: int) -> list[ImuSample]:
        """``n`` readings of the still robot from ``t0`` (for the static initialisation)."""
        f = R_world_body.T @ np.array([0.0, 0.0, GRAVITY])
        out = []
        for k in range(n):
            g, a = self._noisy(np.zeros(3), f)
            out.append(ImuSample(t0 + k * self.dt, g, a))
        return out


class TetherModel:
    """Tether length from the real anchor to the body origin.

    .. math::

        l = s\\,\\left(d + k_s d^2 + \\epsilon d\\right) + \\text{slack} + \\text{jump} + n,
        \\qquad d = \\lVert p - a_{true} \\rVert,

    with spool scale ``s``, sag ``k_s``, stretch ``ε``, noise ``n`` ~ N(0, σ²).
    """

    def __init__(
        self, params: ClimberParams, rng: np.random.Generator, faults: ClimbFaults
    ) -> None:
        self.params = params
        self.rng = rng
        self.faults = faults
        self.anchor = params.anchor_world_true
        self._slack_until = -1.0
        self._slack = 0.0

    def true_distance(self, position: npt.ArrayLike) -> float:
        """Straight-line distance from the real anchor, m."""
        return float(np.linalg.norm(np.asarray(position, dtype=float) - self.anchor))

    def read(self, t: float, position: npt.ArrayLike, dt: float) -> TetherReading:
        """One reading at time ``t`` (``dt``: time since the previous one, s)."""
        prm, rng, fl = self.params, self.rng, self.faults
        d = self.true_distance(position)
        length = prm.spool_scale * (d + prm.tether_sag * d * d + prm.tether_stretch * d)
        if fl.tether_slack_rate > 0 and t > self._slack_until:
            if rng.uniform() < fl.tether_slack_rate * dt:
                self._slack_until = t + rng.uniform(0.5, 1.5)
                self._slack = rng.uniform(0.02, 0.05)
        if t <= self._slack_until:
            length += self._slack
        if fl.tether_jump_prob > 0 and rng.uniform() < fl.tether_jump_prob:
            length += rng.choice([-1.0, 1.0]) * rng.uniform(0.05, 0.2)
        length += rng.normal(0, prm.tether_sigma)
        ok = not (fl.tether_invalid_prob > 0 and rng.uniform() < fl.tether_invalid_prob)
        return TetherReading(t, max(length, 0.0), ok)


class CameraModel:
    """Down-looking camera (optical axis along body −z), small field of view.

    ``FAST`` mode returns :class:`.RelativeMotion` between consecutive frames from the
    true camera motion with noise (rotation, translation ∝ step, slowly varying scale)
    and reports lost tracking when the robot has left the surface (height beyond
    three times the nominal) or on an injected dropout. ``IMAGE`` mode renders the
    textured blade with TinyRenderer and returns :class:`.CameraFrame`.
    """

    def __init__(
        self,
        robot: ClimberRobot,
        params: ClimberParams,
        mode: SensorMode | str,
        rng: np.random.Generator,
        faults: ClimbFaults,
    ) -> None:
        self.robot = robot
        self.params = params
        self.mode = check_sensor_mode(mode, (SensorMode.FAST, SensorMode.IMAGE))
        self.rng = rng
        self.faults = faults
        self.R_bc = VioConfig().R_bc
        self.p_bc = np.asarray(params.camera_xyz, dtype=float)
        self.K = params.camera_intrinsics()
        self._prev: tuple[float, FloatArray, FloatArray] | None = None
        self._scale = rng.normal(0, params.visual_scale_sigma)

    def camera_pose(self, s: BodyState) -> tuple[FloatArray, FloatArray]:
        """World rotation and centre of the camera."""
        return s.R @ self.R_bc, s.position + s.R @ self.p_bc

    def reset(self) -> None:
        """Forget the previous frame."""
        self._prev = None

    def capture(self, s: BodyState, height: float) -> RelativeMotion | CameraFrame | None:
        """A measurement at ``s.t`` (``None`` for the first fast-mode frame)."""
        R_c, p_c = self.camera_pose(s)
        if self.mode is SensorMode.IMAGE:
            return CameraFrame(s.t, self.render(R_c, p_c), self.K)
        prev, self._prev = self._prev, (s.t, R_c, p_c)
        if prev is None:
            return None
        t0, R0, p0 = prev
        prm, rng = self.params, self.rng
        dt = s.t - t0
        a = math.exp(-dt / prm.visual_scale_tau)
        self._scale = a * self._scale + math.sqrt(1 - a * a) * prm.visual_scale_sigma * float(
            rng.standard_normal()
        )
        R_rel = R0.T @ R_c
        p_rel = R0.T @ (p_c - p0)
        s_t = prm.visual_translation_sigma + prm.visual_translation_rel * float(
            np.linalg.norm(p_rel)
        )
        R_m = R_rel @ so3_exp(rng.normal(0, prm.visual_rotation_sigma, 3))
        p_m = (1.0 + self._scale) * p_rel + rng.normal(0, s_t, 3)
        cov = np.diag([prm.visual_rotation_sigma**2] * 3 + [s_t**2] * 3)
        lost = height > 3 * prm.h or height < 0
        dropped = self.faults.visual_dropout > 0 and rng.uniform() < self.faults.visual_dropout
        return RelativeMotion(t0, s.t, R_m, p_m, cov, ok=not (lost or dropped))

    def render(self, R_c: FloatArray, p_c: FloatArray) -> npt.NDArray[np.uint8]:
        """RGB image (n, n, 3) of the camera at world pose ``(R_c, p_c)`` (TinyRenderer)."""
        c = self.robot.scene.world.bullet
        n = int(self.params.camera_size_px)
        fwd, up = R_c[:, 2], -R_c[:, 1]
        view = c.computeViewMatrix(p_c.tolist(), (p_c + fwd).tolist(), up.tolist())
        proj = c.computeProjectionMatrixFOV(self.params.camera_fov_deg, 1.0, 0.005, 2.0)
        _, _, rgba, _, _ = c.getCameraImage(
            n, n, view, proj, renderer=p.ER_TINY_RENDERER, flags=p.ER_NO_SEGMENTATION_MASK
        )
        return np.asarray(rgba, dtype=np.uint8).reshape(n, n, 4)[..., :3].copy()


def tether_distance(length: float, params: ClimberParams) -> float:
    """The straight-line distance ``d`` whose noise-free reading is ``length`` under the
    tether model of ``params`` (:class:`TetherModel`): the non-negative root of
    :math:`s\\,(d + k_s d^2 + \\epsilon d) = l`, written in the form that stays exact as
    :math:`k_s \to 0`."""
    x = float(length) / params.spool_scale
    b = 1.0 + params.tether_stretch
    k = params.tether_sag
    if k <= 0.0:
        return x / b
    return 2.0 * x / (b + math.sqrt(b * b + 4.0 * k * x))


def calibrated_measurement(m: Any, params: ClimberParams) -> Any:
    """Measurement ``m`` as a driver calibrated to the sensor model of ``params`` reports it:
    a tether reading turned back into the distance (:func:`tether_distance`), an IMU sample
    without the constant biases; anything else as it is."""
    if isinstance(m, TetherReading):
        return dataclasses.replace(m, length=tether_distance(m.length, params))
    if isinstance(m, ImuSample):
        return dataclasses.replace(
            m,
            gyro=np.asarray(m.gyro, dtype=float) - np.asarray(params.gyro_bias, dtype=float),
            accel=np.asarray(m.accel, dtype=float) - np.asarray(params.accel_bias, dtype=float),
        )
    return m
