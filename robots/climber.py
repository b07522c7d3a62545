"""A wheeled adsorption climber on the 8 m blade: bodies, adsorption, tether, IMU, camera.

Mounting (the choice of this simulation): the blade lies with its suction side up and
is pitched by ``ClimberParams.mount_pitch`` about the world y axis, tip up, so that
driving towards the tip climbs against gravity; near the leading and trailing edges
the surface is steeper still. The world frame is gravity-aligned (z up) and is also
the CAD frame handed to the estimators: :meth:`ClimberParams.cad_cloud` returns the
nominal CAD point cloud transformed by the mount.

Frames: ``world`` (= ``cad``), z up, m; ``blade`` (x along the span, z towards the
suction side, see :mod:`.blade_geometry`); ``body``: origin on the wheel axle midpoint,
x forward, y left, z away from the surface. The two sphere wheels (radius ``h`` =
wheel radius on the nominal robot) touch the surface where its normal passes
through their centres, so the *wheel centres* sit ``h`` above the surface; across a
convex curvature :math:`\\kappa` the axle is a chord and the body origin sits lower,
by :math:`\\approx b^2\\kappa/8` (track ``b``; up to 5 mm on the suction side). The
estimators model exactly this contact (:meth:`ClimberParams.constrained_config`).

Physics (PyBullet, 240 Hz): the blade is a static concave triangle mesh
(``GEOM_FORCE_CONCAVE_TRIMESH``) of the *real* surface (:func:`.deformed` when the
CAD-vs-real deviation is non-zero). The robot has two driven sphere wheels and two
frictionless sphere casters. An adsorption force along the local real surface normal
(nearest sample of a k-d tree on the real surface cloud) is applied at the body
origin on every physics sub-step,

.. math::

    F = F_0 \\exp\\left(-\\max(0, g) / \\lambda\\right), \\qquad
    g = n^\\top (p - q) - h_{true},

``g`` being the gap growth beyond the rolling height; gravity and wheel–surface
friction do the rest, so a weak force lets the robot slip or fall off.

The climber's sensors (IMU, tether, down-looking camera) are in
:mod:`realitygap.robots.climber_sensors`.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, fields, replace
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
import pybullet as p
from scipy.spatial import cKDTree

from realitygap.estimators.climb.constrained import ConstrainedConfig
from realitygap.estimators.climb.vio import VioConfig
from realitygap.robots.blade_geometry import (
    BladeParams,
    BladeSurface,
    blade_mesh,
    blade_texture,
    cad_point_cloud,
    deformed,
    write_obj,
)
from realitygap.robots.world import GRAVITY, World

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "BodyState",
    "ClimbFaults",
    "ClimbWorld",
    "ClimberParams",
    "ClimberRobot",
    "chart_pose",
]


def _rot_y(angle: float) -> FloatArray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _quat_xyzw_from_matrix(R: FloatArray) -> list[float]:
    from scipy.spatial.transform import Rotation

    return [float(v) for v in Rotation.from_matrix(R).as_quat()]


@dataclass(frozen=True)
class ClimbFaults:
    """Bad-input injection (rates and probabilities per reading; 0 disables).

    Attributes
    ----------
    tether_slack_rate
        Slack episodes per second (each 0.5–1.5 s, reading +2…5 cm).
    tether_jump_prob
        Probability per reading of a spurious jump of ±5…20 cm.
    tether_invalid_prob
        Probability per reading that the sensor flags it invalid.
    visual_dropout
        Probability per frame that visual tracking is lost.
    """

    tether_slack_rate: float = 0.0
    tether_jump_prob: float = 0.0
    tether_invalid_prob: float = 0.0
    visual_dropout: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"ClimbFaults.{f.name} must be ≥ 0, got {value!r}")
        for name in ("tether_jump_prob", "tether_invalid_prob", "visual_dropout"):
            if getattr(self, name) > 1:
                raise ValueError(f"ClimbFaults.{name} is a probability in [0, 1]")


@dataclass(frozen=True)
class ClimberParams:
    """Physical parameters of the climber, its sensors and the blade mount (SI units).

    Effects (:mod:`realitygap.robots.effects`, section "climber") change the fields
    marked *effect*; the nominal values describe the robot the estimator believes in.

    Attributes
    ----------
    blade
        Blade geometry (the CAD model).
    mount_pitch
        Tip-up pitch of the blade about world y, rad.
    mount_position
        Blade-frame origin (root, pitch axis) in the world, m.
    body_length, body_width, body_height, body_mass
        Chassis box, m and kg.
    wheel_radius, wheelbase, wheel_mass, wheel_friction
        Driven wheels: m, m (track width), kg, Coulomb coefficient.
    wheel_inertia
        Reflected inertia of motor and gearbox about the wheel axle, kg·m².
    caster_radius, caster_offset, caster_clearance
        Frictionless support spheres ahead of and behind the axle, m; they sit
        ``caster_clearance`` above the wheels' contact plane so that on the convex
        section the driven wheels carry the load. The chassis therefore rocks on them
        about the axle, resting on the front or the rear caster with the drive
        torque: :attr:`caster_pitch_limit` (3.9°) on a flat surface, more where the
        surface curves along the body x-axis (up to ≈ 10° while turning across the
        chord on the ``climb003`` paths).
    max_wheel_torque
        N·m.
    adsorption_force, adsorption_decay
        :math:`F_0` (N) and :math:`\\lambda` (m).
    gap_offset
        *effect*: extra ride height of the real robot (worn wheels / thicker skirt), m;
        the body sits higher and the suction is weaker by :math:`e^{-\\Delta/\\lambda}`.
    v_max, w_max
        Command limits, m/s and rad/s.
    anchor_blade
        Nominal tether anchor in the blade frame, m.
    anchor_offset
        *effect*: real anchor minus nominal, world frame, m.
    tether_sigma
        Length noise, m.
    tether_sag
        *effect*: extra length from sag, :math:`k_s L^2` (1/m).
    tether_stretch
        *effect*: strain of the tether under its working tension (–).
    spool_scale
        *effect*: reading / paid-out length (–).
    imu_rate
        Hz (divides the physics rate).
    gyro_noise_density, accel_noise_density
        rad/s/√Hz, m/s²/√Hz.
    gyro_bias_walk, accel_bias_walk
        rad/s/√s, m/s²/√s.
    gyro_bias_sigma, accel_bias_sigma
        Per-episode random turn-on bias, rad/s and m/s².
    gyro_bias, accel_bias
        *effect*: constant bias (body frame), rad/s and m/s².
    camera_rate, camera_fov_deg, camera_size_px
        Hz, full field of view (deg), square image edge (px).
    camera_xyz
        Camera centre in the body frame, m (looking along body −z).
    visual_rotation_sigma, visual_translation_sigma, visual_translation_rel,
    visual_scale_sigma, visual_scale_tau
        Fast-mode visual noise (rad, m, –, –, s).
    surface_deviation, surface_seed
        *effect*: largest CAD-vs-real normal deviation of the blade (m) and the seed of
        its shape.
    """

    blade: BladeParams = field(default_factory=BladeParams)
    mount_pitch: float = 0.35
    mount_position: tuple[float, float, float] = (0.0, 0.0, 1.0)
    body_length: float = 0.22
    body_width: float = 0.12
    body_height: float = 0.03
    body_mass: float = 2.0
    wheel_radius: float = 0.04
    wheelbase: float = 0.14
    wheel_mass: float = 0.15
    wheel_inertia: float = 0.002
    wheel_friction: float = 0.9
    caster_radius: float = 0.015
    caster_offset: float = 0.09
    caster_clearance: float = 0.006
    max_wheel_torque: float = 3.0
    adsorption_force: float = 60.0
    adsorption_decay: float = 0.01
    gap_offset: float = 0.0
    v_max: float = 0.2
    w_max: float = 1.0
    anchor_blade: tuple[float, float, float] = (-0.5, 0.2, 0.9)
    anchor_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tether_sigma: float = 2e-3
    tether_sag: float = 0.0
    tether_stretch: float = 0.0
    spool_scale: float = 1.0
    imu_rate: float = 120.0
    gyro_noise_density: float = 0.005
    accel_noise_density: float = 0.05
    gyro_bias_walk: float = 1e-4
    accel_bias_walk: float = 1e-3
    gyro_bias_sigma: float = 0.01
    accel_bias_sigma: float = 0.05
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    camera_rate: float = 10.0
    camera_fov_deg: float = 70.0
    camera_size_px: int = 96
    camera_xyz: tuple[float, float, float] = (0.08, 0.0, -0.01)
    visual_rotation_sigma: float = 2e-3
    visual_translation_sigma: float = 2e-4
    visual_translation_rel: float = 0.01
    visual_scale_sigma: float = 0.005
    visual_scale_tau: float = 20.0
    surface_deviation: float = 0.0
    surface_seed: int = 0

    def __post_init__(self) -> None:
        positive = (
            "body_length",
            "body_width",
            "body_height",
            "body_mass",
            "wheel_radius",
            "wheelbase",
            "wheel_mass",
            "wheel_inertia",
            "caster_radius",
            "max_wheel_torque",
            "adsorption_decay",
            "v_max",
            "w_max",
            "spool_scale",
            "imu_rate",
            "camera_rate",
            "camera_fov_deg",
        )
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"ClimberParams.{name} must be positive, got {value!r}")
        non_negative = (
            "adsorption_force",
            "wheel_friction",
            "tether_sigma",
            "tether_sag",
            "surface_deviation",
            "gyro_noise_density",
            "accel_noise_density",
            "gyro_bias_walk",
            "accel_bias_walk",
            "gyro_bias_sigma",
            "accel_bias_sigma",
        )
        for name in non_negative:
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"ClimberParams.{name} must be ≥ 0, got {value!r}")
        if not abs(self.mount_pitch) < 1.2:
            raise ValueError(
                f"ClimberParams.mount_pitch must be in rad with |pitch| < 1.2, got {self.mount_pitch!r}"
            )
        if self.caster_radius >= self.wheel_radius:
            raise ValueError("ClimberParams.caster_radius must be smaller than wheel_radius")
        if self.imu_rate < 5 * self.camera_rate:
            raise ValueError("ClimberParams.imu_rate must be at least 5 × camera_rate")
        if self.gap_offset <= -self.caster_radius:
            raise ValueError(
                f"ClimberParams.gap_offset must be > -caster_radius, got {self.gap_offset!r}"
            )
        for name in ("mount_position", "anchor_blade", "anchor_offset", "gyro_bias", "accel_bias"):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (3,) or not np.all(np.isfinite(value)):
                raise ValueError(f"ClimberParams.{name} must be 3 finite numbers, got {value!r}")

    def replace(self, **changes: Any) -> ClimberParams:
        """A copy with ``changes`` (validated)."""
        return replace(self, **changes)

    # ------------------------------------------------------------------ geometry
    @property
    def h(self) -> float:
        """Nominal height of the wheel centres above the surface (the wheel radius; the
        body origin's height on a flat surface), m."""
        return self.wheel_radius

    @property
    def h_true(self) -> float:
        """Height of the wheel centres above the surface with ``gap_offset``, m."""
        return self.wheel_radius + self.gap_offset

    @property
    def R_world_blade(self) -> FloatArray:
        """Rotation of the blade frame in the world (tip up by ``mount_pitch``)."""
        return _rot_y(-self.mount_pitch)

    @property
    def p_world_blade(self) -> FloatArray:
        """Blade-frame origin in the world, m."""
        return np.asarray(self.mount_position, dtype=float)

    def world_from_blade(self, x: npt.ArrayLike) -> FloatArray:
        """Points (..., 3) from the blade frame to the world frame."""
        return np.asarray(x, dtype=float) @ self.R_world_blade.T + self.p_world_blade

    def blade_from_world(self, x: npt.ArrayLike) -> FloatArray:
        """Points (..., 3) from the world frame to the blade frame."""
        return (np.asarray(x, dtype=float) - self.p_world_blade) @ self.R_world_blade

    @property
    def anchor_world(self) -> FloatArray:
        """Anchor in the world (= CAD) frame as the model believes it, m."""
        return self.world_from_blade(self.anchor_blade)

    @property
    def anchor_world_true(self) -> FloatArray:
        """Real anchor (with ``anchor_offset``), m."""
        return self.anchor_world + np.asarray(self.anchor_offset, dtype=float)

    def cad_cloud(self, spacing: float = 0.01) -> tuple[FloatArray, FloatArray]:
        """Nominal CAD point cloud with normals in the world (= CAD) frame."""
        pts, nrm = cad_point_cloud(self.blade, spacing)
        return self.world_from_blade(pts), nrm @ self.R_world_blade.T

    def real_surface(self) -> BladeSurface:
        """The real blade surface (blade frame), deformed by ``surface_deviation``."""
        if self.surface_deviation > 0:
            return deformed(
                self.blade, self.surface_deviation, np.random.default_rng(self.surface_seed)
            )
        return BladeSurface(self.blade)

    def vio_config(self, **changes: Any) -> VioConfig:
        """A :class:`.VioConfig` matching this robot's IMU noise and camera mount."""
        return VioConfig(
            gravity=GRAVITY,
            gyro_noise_density=max(self.gyro_noise_density, 1e-4),
            accel_noise_density=max(self.accel_noise_density, 1e-3),
            gyro_bias_walk=max(self.gyro_bias_walk, 1e-6),
            accel_bias_walk=max(self.accel_bias_walk, 1e-5),
            p_body_camera=(
                float(self.camera_xyz[0]),
                float(self.camera_xyz[1]),
                float(self.camera_xyz[2]),
            ),
            camera_height=self.h + float(self.camera_xyz[2]),
            **changes,
        )

    @property
    def caster_pitch_limit(self) -> float:
        """Largest pitch of the chassis about the axle on a flat surface, rad.

        The chassis turns about the wheel axle until a caster sphere (centre at
        ``(±caster_offset, 0, c_z)`` in the body frame, ``c_z = -(r - r_c) + clearance``)
        touches the wheels' contact plane ``z = -r``:
        :math:`\\pm a \\sin\\theta + c_z \\cos\\theta = r_c - r` with ``a = caster_offset``,
        i.e. :math:`\\theta = \\arcsin\\big((r - r_c)/\\sqrt{a^2 + c_z^2}\\big)
        - \\operatorname{atan2}(-c_z, a)` (≈ clearance / caster_offset).
        """
        r, rc = self.wheel_radius, self.caster_radius
        a = self.caster_offset
        cz = -(r - rc) + self.caster_clearance
        return math.asin(min(1.0, (r - rc) / math.hypot(a, cz))) - math.atan2(-cz, a)

    def constrained_config(self, **changes: Any) -> ConstrainedConfig:
        """A :class:`.ConstrainedConfig` for this robot's contact geometry.

        Two sphere wheels (radius ``h``) ``wheelbase`` apart on the axle; the chassis
        rests on one caster or the other depending on the drive torque, so its pitch
        about the axle relative to the surface is ±:attr:`caster_pitch_limit` (standard
        deviation of that two-point spread: the limit itself).
        """
        base = {"wheel_track": self.wheelbase, "pitch_sigma": self.caster_pitch_limit}
        return ConstrainedConfig(**{**base, **changes})

    def camera_intrinsics(self) -> FloatArray:
        """Pinhole matrix K (3, 3), pixels."""
        n = int(self.camera_size_px)
        f = (n / 2) / math.tan(math.radians(self.camera_fov_deg) / 2)
        return np.array([[f, 0, n / 2], [0, f, n / 2], [0, 0, 1.0]])

    def urdf(self) -> str:
        """URDF text of the climber (body origin on the axle midpoint)."""
        r, rc = self.h_true, self.caster_radius
        lx, ly, lz = self.body_length, self.body_width, self.body_height
        m, mw = self.body_mass, self.wheel_mass
        ixx = m / 12 * (ly**2 + lz**2)
        iyy = m / 12 * (lx**2 + lz**2)
        izz = m / 12 * (lx**2 + ly**2)
        iw = 0.4 * mw * r**2 + self.wheel_inertia
        cz = -(r - rc) + self.caster_clearance
        co = self.caster_offset
        half = self.wheelbase / 2

        def wheel(name: str, y: float) -> str:
            return f"""
  <link name="{name}">
    <inertial><origin xyz="0 0 0"/><mass value="{mw}"/>
      <inertia ixx="{iw}" iyy="{iw}" izz="{iw}" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><origin rpy="1.5708 0 0"/><geometry><cylinder radius="{r}" length="0.02"/></geometry>
      <material name="tyre"><color rgba="0.1 0.1 0.1 1"/></material></visual>
    <collision><geometry><sphere radius="{r}"/></geometry></collision>
  </link>
  <joint name="{name}_joint" type="continuous">
    <parent link="base"/><child link="{name}"/><origin xyz="0 {y} 0"/><axis xyz="0 1 0"/>
  </joint>"""

        return f"""<?xml version="1.0"?>
<robot name="climber">
  <link name="base">
    <inertial><origin xyz="0 0 0"/><mass value="{m}"/>
      <inertia ixx="{ixx}" iyy="{iyy}" izz="{izz}" ixy="0" ixz="0" iyz="0"/></inertial>
    <visual><origin xyz="0 0 {lz / 2}"/><geometry><box size="{lx} {ly} {lz}"/></geometry>
      <material name="shell"><color rgba="0.9 0.5 0.1 1"/></material></visual>
    <collision><origin xyz="{co} 0 {cz}"/><geometry><sphere radius="{rc}"/></geometry></collision>
    <collision><origin xyz="{-co} 0 {cz}"/><geometry><sphere radius="{rc}"/></geometry></collision>
  </link>{wheel("wheel_left", half)}{wheel("wheel_right", -half)}
</robot>
"""


def chart_pose(
    surface: BladeSurface, params: ClimberParams, x: float, xi: float, heading: float, h: float
) -> tuple[FloatArray, FloatArray]:
    """World pose of a body resting on the suction side at chart point ``(x, ξ)``.

    Parameters
    ----------
    surface
        Blade surface (blade frame).
    params
        Supplies the mount.
    x, xi
        Span position (m) and chord station ξ ∈ (0, 1) on the suction side.
    heading
        Angle of the body x-axis from the span direction about the normal, rad.
    h
        Height of the body origin above the surface, m.

    Returns
    -------
    position : (3,)
        World, m.
    R_world_body : (3, 3)
    """
    s = x / params.blade.length
    u = 1.0 - math.acos(math.sqrt(min(max(xi, 1e-6), 1.0))) / math.pi
    q = surface.position(s, u)
    n = surface.normal(s, u)
    e = np.array([1.0, 0.0, 0.0])
    t = e - (e @ n) * n
    t /= np.linalg.norm(t)
    y = np.cross(n, t)
    bx = math.cos(heading) * t + math.sin(heading) * y
    R_b = np.stack([bx, np.cross(n, bx), n], axis=1)
    R_w = params.R_world_blade @ R_b
    return params.world_from_blade(q + h * n), R_w


# --------------------------------------------------------------------------- world


class _LocalNearest:
    """Exact nearest-sample look-up for a query point that moves a little per call.

    Keeps the samples within ``radius`` of a centre ``c`` (one k-d tree ball query)
    and answers by brute force over them. That answer is exact while
    :math:`d + \\lVert q - c \\rVert \\le` ``radius`` (``d``: distance to the nearest
    kept sample): every sample outside the ball is then farther from ``q`` than
    ``d``. Otherwise the ball is re-centred on ``q`` (radius at least twice the
    distance to the nearest sample), so the adsorption force, called on every physics
    sub-step, does a ball query every few centimetres of travel instead of a tree
    query per call.

    Parameters
    ----------
    tree, points
        k-d tree over ``points`` (M, 3), m.
    radius
        Least ball radius, m.
    """

    def __init__(self, tree: cKDTree, points: FloatArray, radius: float = 0.1) -> None:
        self._tree = tree
        self._points = points
        self._radius0 = float(radius)
        self._centre = np.full(3, np.inf)
        self._radius = 0.0
        self._idx = np.zeros(0, dtype=np.intp)
        self._local = np.zeros((0, 3))

    def __call__(self, q: FloatArray) -> int:
        """Index of the sample nearest to ``q`` (3,)."""
        step = q - self._centre
        moved = math.sqrt(float(step @ step)) if len(self._idx) else math.inf
        if moved < self._radius:
            diff = self._local - q
            d2 = np.einsum("ij,ij->i", diff, diff)
            k = int(d2.argmin())
            if math.sqrt(float(d2[k])) + moved <= self._radius:
                return int(self._idx[k])
        d, i = self._tree.query(q)
        self._centre = q.copy()
        self._radius = max(self._radius0, 2.0 * float(d))
        self._idx = np.asarray(self._tree.query_ball_point(q, self._radius), dtype=np.intp)
        self._local = self._points[self._idx]
        return int(i)


class ClimbWorld:
    """The blade scene: a :class:`.World` with the real blade as a static concave mesh.

    Built once (mesh, OBJ, k-d tree of the real surface); the robot is added by
    :class:`ClimberRobot`.

    Parameters
    ----------
    params
        The *true* (effect-applied) parameters: the mesh is the real blade.
    physics_hz, n_substeps
        Passed to :class:`.World`.
    textured
        Load the speckle texture (image mode / rendering).
    texture_seed
        Seed of the texture.
    """

    def __init__(
        self,
        params: ClimberParams,
        *,
        physics_hz: float = 240.0,
        n_substeps: int = 12,
        textured: bool = False,
        texture_seed: int = 0,
    ) -> None:
        self.params = params
        self.world = World(physics_hz=physics_hz, n_substeps=n_substeps)
        self.surface = params.real_surface()
        c = self.world.bullet
        verts, faces, uv = blade_mesh(self.surface)
        verts_w = params.world_from_blade(verts)
        asset = self.world._asset_dir
        tex_name = None
        if textured:
            tex_name = "blade_texture.png"
            tex = blade_texture(np.random.default_rng(texture_seed), 512)
            cv2.imwrite(os.path.join(asset, tex_name), tex[..., ::-1])
        obj = write_obj(os.path.join(asset, "blade.obj"), verts_w, faces, uv, texture_file=tex_name)
        col = c.createCollisionShape(
            p.GEOM_MESH, fileName=str(obj), flags=p.GEOM_FORCE_CONCAVE_TRIMESH
        )
        vis = c.createVisualShape(p.GEOM_MESH, fileName=str(obj), rgbaColor=[1, 1, 1, 1])
        self.blade_id = c.createMultiBody(0.0, col, vis, [0, 0, 0])
        c.changeDynamics(self.blade_id, -1, lateralFriction=1.0, restitution=0.0)
        if textured and tex_name is not None:
            tid = c.loadTexture(os.path.join(asset, tex_name))
            c.changeVisualShape(self.blade_id, -1, textureUniqueId=tid)
        self.world.bodies["blade"] = self.blade_id
        pts, nrm = self.surface.point_cloud(0.02)
        self.real_points = params.world_from_blade(pts)
        self.real_normals = nrm @ params.R_world_blade.T
        self._tree = cKDTree(self.real_points)
        self._nearest = _LocalNearest(self._tree, self.real_points)

    def surface_at(self, position: npt.ArrayLike) -> tuple[FloatArray, FloatArray, float]:
        """Nearest real surface sample, its normal (world) and the signed height along it."""
        pos = np.asarray(position, dtype=float)
        idx = self._nearest(pos)
        q, n = self.real_points[idx], self.real_normals[idx]
        return q, n, float(n @ (pos - q))

    def close(self) -> None:
        """Release the simulation; safe to call twice."""
        self.world.close()


@dataclass(frozen=True)
class BodyState:
    """Ground truth of the body at one physics step (world frame, SI units)."""

    t: float
    position: FloatArray
    R: FloatArray
    velocity: FloatArray
    omega: FloatArray


class ClimberRobot:
    """The climber body in a :class:`ClimbWorld`, driven by wheel speeds.

    Parameters
    ----------
    scene
        The world.
    params
        True (effect-applied) parameters.
    """

    def __init__(self, scene: ClimbWorld, params: ClimberParams) -> None:
        self.scene = scene
        self.params = params
        c = scene.world.bullet
        self.body = scene.world.load_urdf("climber", params.urdf(), [0, 0, 5], [0, 0, 0, 1])
        self.wheels = [0, 1]
        for j in self.wheels:
            c.changeDynamics(
                self.body,
                j,
                lateralFriction=params.wheel_friction,
                rollingFriction=0.0,
                spinningFriction=0.002,
            )
        c.changeDynamics(self.body, -1, lateralFriction=0.0, rollingFriction=0.0)
        self._c = c
        # client methods bound once (each attribute look-up on the client builds a
        # new partial; these run on every physics sub-step)
        self._get_pose = c.getBasePositionAndOrientation
        self._get_velocity = c.getBaseVelocity
        self._matrix_of = c.getMatrixFromQuaternion
        self._apply_force = c.applyExternalForce
        # F0·exp(-gap_offset/λ): the adsorption force at the rolling height, N
        self._suction_at_contact = params.adsorption_force * math.exp(
            -max(0.0, params.gap_offset) / params.adsorption_decay
        )
        self.adsorption_scale = 1.0
        """Multiplier on the adsorption force (e.g. a pump failure in a test)."""
        self.last_force = 0.0
        self.last_height = params.h_true

    def remove(self) -> None:
        """Take the body out of the world (a new :class:`ClimberRobot` may then be built)."""
        self.scene.world.remove_body("climber")

    def reset(self, position: npt.ArrayLike, R_world_body: npt.ArrayLike) -> None:
        """Place the body at rest."""
        c = self._c
        c.resetBasePositionAndOrientation(
            self.body,
            np.asarray(position, dtype=float).tolist(),
            _quat_xyzw_from_matrix(np.asarray(R_world_body, dtype=float)),
        )
        c.resetBaseVelocity(self.body, [0, 0, 0], [0, 0, 0])
        for j in self.wheels:
            c.resetJointState(self.body, j, 0.0, 0.0)
        self.set_wheel_speeds(0.0, 0.0)
        self.last_force = 0.0
        self.last_height = self.params.h_true

    def set_wheel_speeds(self, left: float, right: float) -> None:
        """Target wheel rates, rad/s (velocity motors with ``max_wheel_torque``)."""
        self._c.setJointMotorControlArray(
            self.body,
            self.wheels,
            p.VELOCITY_CONTROL,
            targetVelocities=[left, right],
            forces=[self.params.max_wheel_torque] * 2,
        )

    def set_twist(self, v: float, w: float, nominal: ClimberParams) -> None:
        """Wheel speeds from a body twist with the *nominal* geometry (firmware)."""
        half = nominal.wheelbase / 2
        r = nominal.wheel_radius
        self.set_wheel_speeds((v - w * half) / r, (v + w * half) / r)

    def state(self, t: float) -> BodyState:
        """Ground truth now."""
        pos, quat = self._get_pose(self.body)
        lin, ang = self._get_velocity(self.body)
        R = np.array(self._matrix_of(quat)).reshape(3, 3)
        return BodyState(t, np.array(pos), R, np.array(lin), np.array(ang))

    def apply_adsorption(self) -> None:
        """Apply the adsorption force for the next physics step (world frame, at the body origin)."""
        pos, _ = self._get_pose(self.body)
        _, n, height = self.scene.surface_at(pos)
        prm = self.params
        gap = height - prm.h_true
        force = (
            self.adsorption_scale
            * self._suction_at_contact
            * math.exp(-max(0.0, gap) / prm.adsorption_decay)
        )
        self.last_force = force
        self.last_height = height
        self._apply_force(self.body, -1, (-force * n).tolist(), pos, p.WORLD_FRAME)

    def height_above_surface(self) -> float:
        """Signed height of the body origin above the real surface, m."""
        pos, _ = self._get_pose(self.body)
        return self.scene.surface_at(pos)[2]
