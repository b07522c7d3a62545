"""A 6-DOF serial arm with a flange camera over an absolutely coded board.

The arm's body is generated as URDF from a 5-parameter MDH table
(:class:`~realitygap.estimators.arm.mdh.MDHTable`), so an arm with other
geometric parameters really is another body in the simulation. With the joint
reading :math:`q_i` frame ``i`` of the table is

.. math::

    T_{i-1,i} = R_z(q_i + \\theta_i)\\, T_z(d_i)\\, T_x(a_i)\\, R_x(\\alpha_i)\\, R_y(\\beta_i).

URDF layout. Link ``link<k>`` has the frame of MDH frame ``k-1`` turned by the
joint, :math:`T_{\\mathrm{base}, k-1} R_z(q_k + \\theta_k)`; the constant part
:math:`C_{k} = T_z(d_k) T_x(a_k) R_x(\\alpha_k) R_y(\\beta_k)` of row ``k`` is folded
into the origin of joint ``k+1`` together with :math:`R_z(\\theta_{k+1})`; the
``flange`` link (fixed to ``link6`` through :math:`C_6`) is MDH frame 6, and the
``camera`` link (fixed to the flange through the hand–eye transform) is the
camera's optical frame (OpenCV: x right, y down, z along the optical axis).

Drive and sensing. Each joint is position controlled by PyBullet's motor. The
joint encoders sit on the motor side of the gearbox, so what the link does and
what the encoder reads differ by the transmission:

.. math::

    q^{\\mathrm{link}}_i = \\frac{q^{\\mathrm{cmd}}_i}{s_i} - c_i\\, \\tau^{g}_i(q^{\\mathrm{link}})
        - \\frac{b_i}{2} \\operatorname{sign}(\\Delta q^{\\mathrm{cmd}}_i), \\qquad
    q^{\\mathrm{enc}}_i = s_i \\left(q^{\\mathrm{link}}_i + c_i \\tau^{g}_i
        + \\frac{b_i}{2} \\operatorname{sign}(\\Delta q^{\\mathrm{cmd}}_i)\\right)
        + \\text{noise, quantised},

with encoder scale :math:`s_i`, joint compliance :math:`c_i` (rad/(N·m)), the
torque :math:`\\tau^g` that holds the body against gravity (PyBullet inverse
dynamics; the gearbox spring carries it, so the link sags by :math:`c\\tau^g`), and
backlash :math:`b_i` (the link trails the motor by half the play in the
direction of the last move). For the nominal arm ``s = 1, c = 0, b = 0``.

The coded board and the flange camera that looks at it are in
:mod:`realitygap.robots.arm_cell`.

Frames: world z up; the table top is ``z = 0``; the arm's base frame 0 sits on
a pedestal at ``base_xyz``.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field, fields, replace
from enum import Enum
from typing import Any

import numpy as np
import numpy.typing as npt
import pybullet as p
from scipy.spatial.transform import Rotation

from realitygap.estimators.arm.mdh import MDHTable, joint_frames
from realitygap.robots.world import GRAVITY, World

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "ArmParams",
    "ArmRobot",
    "FlangeCameraParams",
    "MoveOutcome",
    "MoveResult",
    "arm_params_to_meta",
    "constant_transform",
    "flange_load_torques",
    "urdf_from_arm_params",
]

_N = 6


def _tuple(name: str, value: Any, n: int, positive: bool = False) -> tuple[float, ...]:
    arr = np.asarray(value, dtype=float).reshape(-1)
    if arr.size != n:
        raise ValueError(f"{name} must have {n} entries, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    if positive and np.any(arr <= 0):
        raise ValueError(f"{name} must be positive, got {arr.tolist()}")
    return tuple(float(v) for v in arr)


def constant_transform(table: MDHTable, row: int) -> FloatArray:
    """Constant part :math:`C_k = T_z(d_k) T_x(a_k) R_x(\\alpha_k) R_y(\\beta_k)` of row ``k``.

    Parameters
    ----------
    table : MDHTable
    row : int
        0-based row index ``k - 1``.

    Returns
    -------
    ndarray, shape (4, 4)
    """
    ca, sa = math.cos(table.alpha[row]), math.sin(table.alpha[row])
    cb, sb = math.cos(table.beta[row]), math.sin(table.beta[row])
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]])
    Ry = np.array([[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]])
    T = np.eye(4)
    T[:3, :3] = Rx @ Ry
    T[:3, 3] = [table.a[row], 0.0, table.d[row]]
    return T


def _rot_z4(angle: float) -> FloatArray:
    c, s = math.cos(angle), math.sin(angle)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    return T


def _origin_xml(T: FloatArray) -> str:
    with warnings.catch_warnings():
        # a pitch of ±90° (a joint axis turned onto another) has one free angle: scipy sets
        # the third to zero and says so; the rpy still give R exactly
        warnings.filterwarnings("ignore", message="Gimbal lock detected")
        rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")  # URDF rpy: R = Rz(y) Ry(p) Rx(r)
    xyz = " ".join(repr(float(v)) for v in T[:3, 3])
    return f'<origin xyz="{xyz}" rpy="{" ".join(repr(float(v)) for v in rpy)}"/>'


# =========================================================================== parameters
@dataclass(frozen=True)
class FlangeCameraParams:
    """Pinhole camera with OpenCV distortion, mounted on the flange.

    Attributes
    ----------
    width, height : int
        Image size (px).
    fx, fy, cx, cy : float
        Intrinsics (px); pixel centres at integer coordinates.
    dist : tuple of float
        OpenCV distortion ``(k1, k2, p1, p2, k3)``.
    mount_xyz : (float, float, float)
        Optical centre in the flange frame (m).
    mount_rpy : (float, float, float)
        Orientation of the optical frame in the flange frame, URDF roll-pitch-yaw (rad).
    noise_std : float
        Std of additive image noise (grey levels).
    blur_sigma_px : float
        Optical blur (px).
    supersample : int
        Sub-pixel samples per pixel side when rendering (anti-aliasing).
    corner_noise_px : float
        Std of the corner positions reported in ``"geometric"`` capture (px), about
        what the detector achieves on rendered frames.
    contrast : (float, float)
        Grey levels of the dark and the light print (the sensor neither clips nor
        saturates).
    near, far : float
        Clipping planes of the rendered view (m).
    """

    width: int = 640
    height: int = 480
    fx: float = 600.0
    fy: float = 600.0
    cx: float = 319.5
    cy: float = 239.5
    dist: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0)
    mount_xyz: tuple[float, float, float] = (0.0, -0.07, 0.05)
    mount_rpy: tuple[float, float, float] = (0.0, 0.0, math.pi / 2)
    noise_std: float = 2.0
    blur_sigma_px: float = 0.7
    supersample: int = 2
    corner_noise_px: float = 0.035
    contrast: tuple[float, float] = (20.0, 235.0)
    near: float = 0.03
    far: float = 3.0

    def __post_init__(self) -> None:
        if int(self.width) < 64 or int(self.height) < 64:
            raise ValueError(f"image must be at least 64x64 px, got {self.width}x{self.height}")
        for nm in ("fx", "fy"):
            v = getattr(self, nm)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"FlangeCameraParams.{nm} must be a positive focal length (px)")
        object.__setattr__(self, "dist", _tuple("dist", self.dist, len(self.dist)))
        if len(self.dist) not in (4, 5, 8):
            raise ValueError(f"dist must hold 4, 5 or 8 OpenCV coefficients, got {len(self.dist)}")
        object.__setattr__(self, "mount_xyz", _tuple("mount_xyz", self.mount_xyz, 3))
        object.__setattr__(self, "mount_rpy", _tuple("mount_rpy", self.mount_rpy, 3))
        if int(self.supersample) < 1:
            raise ValueError(f"supersample must be >= 1, got {self.supersample}")
        if not 0 < self.near < self.far:
            raise ValueError(f"need 0 < near < far, got {self.near}, {self.far}")

    @property
    def K(self) -> FloatArray:
        """Camera matrix (3, 3) (px)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_array(self) -> FloatArray | None:
        """Distortion coefficients, ``None`` when all are zero."""
        d = np.asarray(self.dist, dtype=float)
        return d if np.any(d) else None

    def T_flange_camera(self) -> FloatArray:
        """Pose (4, 4) of the optical frame in the flange frame (m)."""
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("xyz", self.mount_rpy).as_matrix()
        T[:3, 3] = self.mount_xyz
        return T

    def replace(self, **changes: Any) -> FlangeCameraParams:
        """A validated copy with ``changes``."""
        return replace(self, **changes)


@dataclass(frozen=True, eq=False)
class ArmParams:
    """Physical parameters of the arm, its drive, encoders and flange camera (SI units).

    Attributes
    ----------
    mdh : MDHTable
        Geometry (:meth:`MDHTable.ur_like_6dof` by default: joints 2, 3, 4 parallel).
    joint_lower, joint_upper : tuple of float
        Joint limits of the encoder readings (rad).
    link_masses : tuple of float
        Mass of links 1..6 (kg); UR5-like.
    camera_mass : float
        Camera and mount (kg).
    link_radius : tuple of float
        Radius of the links' collision capsules (m).
    max_joint_torque : tuple of float
        Motor torque limits (N·m).
    joint_compliance : tuple of float
        Gearbox compliance :math:`c_i` (rad/(N·m)); 0 is rigid.
    flange_load : float
        Mass at the flange (kg) beyond the declared body and tool, in the holding torques
        only (:func:`flange_load_torques`): a payload heavier (positive) or a wrist and tool
        lighter (negative) than declared. The body itself is not changed.
    backlash : tuple of float
        Full gear play :math:`b_i` (rad).
    encoder_scale : tuple of float
        Encoder scale :math:`s_i` (reading / motor angle).
    encoder_resolution : float
        One encoder count (rad).
    encoder_noise_std : float
        Std of the encoder noise before quantisation (rad).
    settle_steps : int
        Physics steps (240 Hz) the servo holds the target before the joints are read.
    base_xyz : (float, float, float)
        Position of base frame 0 in the world (m); the base is upright.
    camera : FlangeCameraParams
    """

    mdh: MDHTable = field(default_factory=MDHTable.ur_like_6dof)
    joint_lower: tuple[float, ...] = (-2 * math.pi,) * _N
    joint_upper: tuple[float, ...] = (2 * math.pi,) * _N
    link_masses: tuple[float, ...] = (3.7, 8.393, 2.275, 1.219, 1.219, 0.1879)
    camera_mass: float = 0.12
    link_radius: tuple[float, ...] = (0.045, 0.042, 0.036, 0.032, 0.032, 0.032)
    max_joint_torque: tuple[float, ...] = (150.0, 150.0, 150.0, 28.0, 28.0, 28.0)
    joint_compliance: tuple[float, ...] = (0.0,) * _N
    flange_load: float = 0.0
    backlash: tuple[float, ...] = (0.0,) * _N
    encoder_scale: tuple[float, ...] = (1.0,) * _N
    encoder_resolution: float = 2 * math.pi / 2**20
    encoder_noise_std: float = 2e-6
    settle_steps: int = 24
    base_xyz: tuple[float, float, float] = (0.0, 0.0, 0.15)
    camera: FlangeCameraParams = field(default_factory=FlangeCameraParams)

    def __post_init__(self) -> None:
        if not isinstance(self.mdh, MDHTable) or self.mdh.n_joints != _N:
            raise ValueError(f"ArmParams.mdh must be a {_N}-joint MDHTable")
        for nm in ("joint_lower", "joint_upper", "joint_compliance", "backlash"):
            object.__setattr__(self, nm, _tuple(nm, getattr(self, nm), _N))
        for nm in ("link_masses", "link_radius", "max_joint_torque", "encoder_scale"):
            object.__setattr__(self, nm, _tuple(nm, getattr(self, nm), _N, positive=True))
        if np.any(np.asarray(self.joint_lower) >= np.asarray(self.joint_upper)):
            raise ValueError("every joint_lower must be below its joint_upper")
        if np.any(np.asarray(self.joint_compliance) < 0) or np.any(np.asarray(self.backlash) < 0):
            raise ValueError("joint_compliance and backlash must be >= 0")
        for nm in ("encoder_resolution", "camera_mass"):
            v = getattr(self, nm)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"ArmParams.{nm} must be positive, got {v!r}")
        if not (math.isfinite(self.encoder_noise_std) and self.encoder_noise_std >= 0):
            raise ValueError("ArmParams.encoder_noise_std must be >= 0")
        if not math.isfinite(self.flange_load):
            raise ValueError(
                f"ArmParams.flange_load must be a finite mass (kg), got {self.flange_load!r}"
            )
        if int(self.settle_steps) < 0:
            raise ValueError("ArmParams.settle_steps must be >= 0")
        object.__setattr__(self, "base_xyz", _tuple("base_xyz", self.base_xyz, 3))

    def replace(self, **changes: Any) -> ArmParams:
        """A validated copy with ``changes``."""
        return replace(self, **changes)

    @property
    def T_world_base(self) -> FloatArray:
        """Pose (4, 4) of base frame 0 in the world (m)."""
        T = np.eye(4)
        T[:3, 3] = self.base_xyz
        return T

    def describe(self) -> dict[str, Any]:
        """JSON-able summary (for ``info`` and logs)."""
        out: dict[str, Any] = {"mdh": self.mdh.param_dict()}
        for f in fields(self):
            if f.name not in ("mdh", "camera"):
                out[f.name] = getattr(self, f.name)
        out["camera"] = {f.name: getattr(self.camera, f.name) for f in fields(self.camera)}
        return out


def arm_params_to_meta(params: Any) -> dict[str, Any]:
    """The nominal-arm metadata of a log (``meta["params"]``) from an :class:`ArmParams`."""
    return {
        "mdh": params.mdh.param_dict(),
        "mdh_name": params.mdh.name,
        "link_masses": list(params.link_masses),
        "payload_mass": float(params.camera_mass),
        "joint_lower": list(params.joint_lower),
        "joint_upper": list(params.joint_upper),
    }


# =========================================================================== URDF
def flange_load_torques(table: MDHTable, q_link: npt.ArrayLike) -> FloatArray:
    r"""Holding torques (N, n) (N·m) of one kilogram at the flange, at link angles (N, n).

    The flange is the origin :math:`p` of the last frame of ``table``; joint :math:`j`
    turns about the z axis :math:`z_{j-1}` of frame :math:`j-1` through its origin
    :math:`o_{j-1}`. The weight :math:`(0, 0, -g)` of the kilogram is held by

    .. math:: \tau_j = z_{j-1} \cdot \big((p - o_{j-1}) \times (0, 0, g)\big)
              = g\,(z_x r_y - z_y r_x), \qquad r = p - o_{j-1},

    in the base frame (upright, gravity along its −z) — the convention of PyBullet's
    inverse dynamics (:meth:`ArmRobot.gravity_torques`).
    """
    F = joint_frames(table, q_link)
    z = F[:, :-1, :3, 2]
    r = F[:, -1:, :3, 3] - F[:, :-1, :3, 3]
    return GRAVITY * (z[..., 0] * r[..., 1] - z[..., 1] * r[..., 0])


def _inertia_rod(m: float, length: float, r: float, axis: int) -> tuple[float, float, float]:
    along = 0.5 * m * r * r
    across = m * (3 * r * r + length * length) / 12.0
    vals = [across, across, across]
    vals[axis] = along
    return vals[0], vals[1], vals[2]


def urdf_from_arm_params(params: ArmParams) -> str:
    """URDF text of the arm described by ``params`` (see the module docstring for frames).

    Each link ``link<k>`` carries two capsules: along its z axis from the joint to
    :math:`d_k`, then along its x axis to :math:`(a_k, 0, d_k)` (the origin of MDH
    frame ``k``); its mass sits at the middle of that path. The camera link is a
    small box behind the optical centre.
    """
    P = params
    t = P.mdh
    parts = [
        '<?xml version="1.0"?>',
        f'<robot name="{t.name}">',
        '  <link name="base_link">',
        '    <inertial><origin xyz="0 0 0"/><mass value="0"/>'
        '<inertia ixx="0" iyy="0" izz="0" ixy="0" ixz="0" iyz="0"/></inertial>',
        '    <visual><origin xyz="0 0 -0.01"/><geometry><cylinder radius="0.075" '
        'length="0.02"/></geometry><material name="steel"><color rgba="0.6 0.6 0.65 1"/>'
        "</material></visual>",
        "  </link>",
    ]
    parent = "base_link"
    C_prev = np.eye(4)
    for k in range(_N):
        name = f"link{k + 1}"
        r = P.link_radius[k]
        d, a = float(t.d[k]), float(t.a[k])
        geo = []
        if abs(d) > 1e-9:
            geo.append((f'<origin xyz="0 0 {d / 2!r}" rpy="0 0 0"/>', abs(d)))
        if abs(a) > 1e-9:
            geo.append((f'<origin xyz="{a / 2!r} 0 {d!r}" rpy="0 {math.pi / 2!r} 0"/>', abs(a)))
        if not geo:
            geo.append(('<origin xyz="0 0 0" rpy="0 0 0"/>', 0.0))
        m = P.link_masses[k] + (P.camera_mass if k == _N - 1 else 0.0)
        com = np.array([a / 2.0, 0.0, d / 2.0])
        length = abs(a) + abs(d) + 1e-3
        ixx, iyy, izz = _inertia_rod(m, length, r, 0 if abs(a) > abs(d) else 2)
        parts.append(f'  <link name="{name}">')
        parts.append(
            f'    <inertial><origin xyz="{com[0]!r} 0 {com[2]!r}"/><mass value="{m!r}"/>'
            f'<inertia ixx="{ixx:.6g}" iyy="{iyy:.6g}" izz="{izz:.6g}" ixy="0" ixz="0" '
            'iyz="0"/></inertial>'
        )
        for origin, ln in geo:
            parts.append(
                f'    <visual>{origin}<geometry><capsule radius="{r}" length="{ln!r}"/>'
                '</geometry><material name="arm"><color rgba="0.75 0.78 0.82 1"/></material>'
                "</visual>"
            )
            parts.append(
                f'    <collision>{origin}<geometry><capsule radius="{r}" length="{ln!r}"/>'
                "</geometry></collision>"
            )
        parts.append("  </link>")
        origin_T = C_prev @ _rot_z4(float(t.theta_offset[k]))
        lo, hi = P.joint_lower[k], P.joint_upper[k]
        parts.append(
            f'  <joint name="joint{k + 1}" type="revolute"><parent link="{parent}"/>'
            f'<child link="{name}"/>{_origin_xml(origin_T)}<axis xyz="0 0 1"/>'
            f'<limit lower="{lo!r}" upper="{hi!r}" effort="{P.max_joint_torque[k]!r}" '
            'velocity="3.2"/></joint>'
        )
        parent = name
        C_prev = constant_transform(t, k)
    tiny = (
        '<inertial><origin xyz="0 0 0"/><mass value="0.001"/>'
        '<inertia ixx="1e-7" iyy="1e-7" izz="1e-7" ixy="0" ixz="0" iyz="0"/></inertial>'
    )
    parts.append(f'  <link name="flange">{tiny}</link>')
    parts.append(
        '  <joint name="flange_joint" type="fixed"><parent link="link6"/>'
        f'<child link="flange"/>{_origin_xml(C_prev)}</joint>'
    )
    parts.append(
        f'  <link name="camera">{tiny}'
        '<visual><origin xyz="0 0 -0.03"/><geometry><box size="0.04 0.03 0.04"/></geometry>'
        '<material name="cam"><color rgba="0.1 0.1 0.1 1"/></material></visual>'
        '<collision><origin xyz="0 0 -0.03"/><geometry><box size="0.04 0.03 0.04"/></geometry>'
        "</collision></link>"
    )
    parts.append(
        '  <joint name="camera_joint" type="fixed"><parent link="flange"/>'
        f'<child link="camera"/>{_origin_xml(P.camera.T_flange_camera())}</joint>'
    )
    parts.append("</robot>")
    return "\n".join(parts) + "\n"


# =========================================================================== robot
class MoveOutcome(str, Enum):
    """What happened to a commanded move (:meth:`ArmRobot.move_to`)."""

    OK = "ok"
    OUT_OF_REACH = "out_of_reach"  #: target outside the joint limits
    COLLISION = "collision"  #: self-collision or contact with the scenery at the target


@dataclass(frozen=True)
class MoveResult:
    """Result of :meth:`ArmRobot.move_to`.

    Attributes
    ----------
    outcome : MoveOutcome
    message : str
        Human-readable reason when not OK.
    q_link : ndarray, shape (6,)
        True joint (link) angles after the move (rad).
    contacts : tuple of (str, str)
        Colliding pairs ``(link, other)`` when ``outcome`` is COLLISION.
    """

    outcome: MoveOutcome
    message: str
    q_link: FloatArray
    contacts: tuple[tuple[str, str], ...] = ()

    @property
    def ok(self) -> bool:
        return self.outcome is MoveOutcome.OK


class ArmRobot:
    """The simulated arm: position-controlled joints, motor-side encoders, ground truth.

    Parameters
    ----------
    world : World
        The simulation to live in.
    params : ArmParams
        The physical (true) parameters; the body is generated from them.
    collision_margin : float
        Closer than this (m) counts as a collision.
    """

    LINK_NAMES: tuple[str, ...] = (
        "link1",
        "link2",
        "link3",
        "link4",
        "link5",
        "link6",
        "flange",
        "camera",
    )

    def __init__(self, world: World, params: ArmParams, collision_margin: float = 0.005):
        self.world = world
        self.params = params
        self.collision_margin = float(collision_margin)
        self.body = world.load_urdf(
            "arm", urdf_from_arm_params(params), params.base_xyz, [0.0, 0.0, 0.0, 1.0]
        )
        c = world.bullet
        by_name = {}
        for j in range(c.getNumJoints(self.body)):
            info = c.getJointInfo(self.body, j)
            by_name[info[12].decode()] = j
        self.link_index = {nm: by_name[nm] for nm in self.LINK_NAMES}
        self.joints = [self.link_index[f"link{k + 1}"] for k in range(_N)]
        for j in self.joints:
            c.changeDynamics(self.body, j, linearDamping=0.0, angularDamping=0.0, jointDamping=0.5)
        self._lower = np.asarray(params.joint_lower)
        self._upper = np.asarray(params.joint_upper)
        self._scale = np.asarray(params.encoder_scale)
        self._compliance = np.asarray(params.joint_compliance)
        self._backlash = np.asarray(params.backlash)
        self._forces = list(params.max_joint_torque)
        self._self_pairs = [
            (a, b)
            for i, a in enumerate(self.LINK_NAMES)
            for b in self.LINK_NAMES[i + 2 :]
            if not (a == "link6" and b == "camera")  # camera is fixed to link6 via the flange
            and not (a == "flange")
        ]
        self._scenery_links = [nm for nm in self.LINK_NAMES if nm not in ("link1", "flange")]
        self.q_cmd = np.zeros(_N)
        self.direction = np.ones(_N)

    # ------------------------------------------------------------------ state
    def reset(self, q_cmd: npt.ArrayLike) -> FloatArray:
        """Put the arm at rest at the link angles for command ``q_cmd`` (teleport).

        The backlash direction is reset to "approached from below" (+1) for every joint.
        Returns the link angles (rad).
        """
        q = self.check_command(q_cmd)
        self.direction = np.ones(_N)
        self.q_cmd = q.copy()
        target = self.link_target(q)
        self.set_link_angles(target)
        self._hold(target)
        return target

    def remove(self) -> None:
        """Take the arm body out of the world (a new :class:`ArmRobot` may then be built)."""
        self.world.remove_body("arm")

    def set_link_angles(self, q_link: npt.ArrayLike) -> None:
        """Teleport the joints to link angles ``q_link`` (6,) (rad) at rest (no servo change)."""
        c = self.world.bullet
        for j, v in zip(self.joints, np.asarray(q_link, dtype=float).reshape(_N)):
            c.resetJointState(self.body, j, float(v), 0.0)

    def collides_at(self, q_cmd: npt.ArrayLike) -> bool:
        """Whether the arm would collide at rest for command ``q_cmd`` (state is restored)."""
        saved = self.joint_positions()
        self.set_link_angles(self.link_target(self.check_command(q_cmd), np.ones(_N)))
        hit = bool(self.collisions())
        self.set_link_angles(saved)
        return hit

    def _hold(self, q_link: FloatArray) -> None:
        self.world.bullet.setJointMotorControlArray(
            self.body,
            self.joints,
            p.POSITION_CONTROL,
            targetPositions=q_link.tolist(),
            targetVelocities=[0.0] * _N,
            forces=self._forces,
            positionGains=[0.8] * _N,
            velocityGains=[1.0] * _N,
        )

    def joint_positions(self) -> FloatArray:
        """True link angles (6,) (rad)."""
        states = self.world.bullet.getJointStates(self.body, self.joints)
        return np.array([s[0] for s in states], dtype=float)

    def check_command(self, q_cmd: npt.ArrayLike) -> FloatArray:
        """Validate a joint command (6,) (rad): finite and of the right shape."""
        q = np.asarray(q_cmd, dtype=float).reshape(-1)
        if q.shape != (_N,):
            raise ValueError(f"a joint command must have shape ({_N},), got {np.shape(q_cmd)}")
        if not np.all(np.isfinite(q)):
            raise ValueError(f"a joint command must be finite, got {q.tolist()}")
        return q

    def within_limits(self, q_cmd: npt.ArrayLike) -> bool:
        """True when every command lies within the joint limits."""
        q = np.asarray(q_cmd, dtype=float)
        return bool(np.all(q >= self._lower) and np.all(q <= self._upper))

    # ------------------------------------------------------------------ drive
    def gravity_torques(self, q_link: npt.ArrayLike) -> FloatArray:
        """Joint torques (6,) (N·m) that hold the body at rest at ``q_link`` against gravity."""
        q = [float(v) for v in np.asarray(q_link, dtype=float)]
        tau = self.world.bullet.calculateInverseDynamics(self.body, q, [0.0] * _N, [0.0] * _N)
        out = np.asarray(tau, dtype=float)
        if self.params.flange_load != 0.0:
            out = out + self.params.flange_load * flange_load_torques(self.params.mdh, [q])[0]
        return out

    def link_target(self, q_cmd: FloatArray, direction: FloatArray | None = None) -> FloatArray:
        """Link angles (6,) (rad) at which the servo comes to rest for command ``q_cmd``.

        Solves :math:`q = q^{\\mathrm{cmd}}/s - c\\,\\tau^g(q) - \\tfrac{b}{2}\\,\\mathrm{dir}`
        by fixed-point iteration (the compliance term is tiny).
        """
        dirn = self.direction if direction is None else direction
        q_motor = q_cmd / self._scale
        q = q_motor - 0.5 * self._backlash * dirn
        if np.any(self._compliance > 0):
            for _ in range(3):
                q = (
                    q_motor
                    - 0.5 * self._backlash * dirn
                    - self._compliance * self.gravity_torques(q)
                )
        return q

    def link_angles_from_encoders(
        self, reading: npt.ArrayLike, params: ArmParams, direction: npt.ArrayLike | None = None
    ) -> FloatArray:
        """The link angles (6,) (rad) a controller whose model of the transmission is
        ``params`` infers from encoder ``reading``: :meth:`read_encoders` inverted under that
        model, :math:`q = r/s - c\\,\tau^g(q) - \tfrac{b}{2}\\,\\mathrm{dir}` (fixed-point
        iteration), :math:`\tau^g` from the body's declared masses plus the model's flange
        load. ``direction``: of the last move per joint (default: the robot's)."""
        dirn = self.direction if direction is None else np.asarray(direction, dtype=float)
        motor = np.asarray(reading, dtype=float) / np.asarray(params.encoder_scale, dtype=float)
        play = 0.5 * np.asarray(params.backlash, dtype=float) * dirn
        q = motor - play
        c = np.asarray(params.joint_compliance, dtype=float)
        if np.any(c > 0):
            for _ in range(3):
                qs = [float(v) for v in q]
                tau = np.asarray(
                    self.world.bullet.calculateInverseDynamics(
                        self.body, qs, [0.0] * _N, [0.0] * _N
                    ),
                    dtype=float,
                )
                if params.flange_load != 0.0:
                    tau = tau + params.flange_load * flange_load_torques(params.mdh, [q])[0]
                q = motor - play - c * tau
        return q

    def move_to(self, q_cmd: npt.ArrayLike) -> MoveResult:
        """Command the joints to ``q_cmd`` (encoder units, rad), let the servo settle.

        The servo brings the motor to the command; the links end where the
        transmission puts them (:meth:`link_target`). The move itself is not
        simulated step by step (the arm is placed at the target and held by the
        position controller for ``settle_steps`` physics steps). A target outside
        the joint limits is refused (``OUT_OF_REACH``); a target in collision is
        reported (``COLLISION``) and the arm returns to where it was.
        """
        q = self.check_command(q_cmd)
        if not self.within_limits(q):
            bad = [k + 1 for k in range(_N) if not self._lower[k] <= q[k] <= self._upper[k]]
            return MoveResult(
                MoveOutcome.OUT_OF_REACH,
                f"joint(s) {bad} outside the limits [{self._lower.round(3).tolist()}, "
                f"{self._upper.round(3).tolist()}] rad",
                self.joint_positions(),
            )
        prev_state = (self.q_cmd.copy(), self.direction.copy(), self.joint_positions())
        step = q - self.q_cmd
        new_dir = np.where(step > 0, 1.0, np.where(step < 0, -1.0, self.direction))
        target = self.link_target(q, new_dir)
        self.set_link_angles(target)
        contacts = self.collisions()
        if contacts:
            self.set_link_angles(prev_state[2])
            self._hold(prev_state[2])
            return MoveResult(
                MoveOutcome.COLLISION,
                "target configuration collides: " + ", ".join(f"{a}-{b}" for a, b in contacts[:3]),
                self.joint_positions(),
                tuple(contacts),
            )
        self.q_cmd = q
        self.direction = new_dir
        self._hold(target)
        for _ in range(int(self.params.settle_steps)):
            self.world.bullet.stepSimulation()
        return MoveResult(MoveOutcome.OK, "", self.joint_positions())

    def read_encoders(self, rng: np.random.Generator | None = None) -> FloatArray:
        """Encoder readings (6,) (rad) of the current state: motor side, noisy, quantised."""
        q = self.joint_positions()
        tau = self.gravity_torques(q) if np.any(self._compliance > 0) else 0.0
        motor = q + self._compliance * tau + 0.5 * self._backlash * self.direction
        reading = self._scale * motor
        if rng is not None and self.params.encoder_noise_std > 0:
            reading = reading + rng.normal(0.0, self.params.encoder_noise_std, _N)
        res = self.params.encoder_resolution
        return np.round(reading / res) * res

    # ------------------------------------------------------------------ truth
    def link_pose(self, name: str) -> FloatArray:
        """World pose (4, 4) of URDF link ``name`` (m)."""
        st = self.world.bullet.getLinkState(
            self.body, self.link_index[name], computeForwardKinematics=True
        )
        T = np.eye(4)
        T[:3, :3] = np.asarray(p.getMatrixFromQuaternion(st[5])).reshape(3, 3)
        T[:3, 3] = st[4]
        return T

    def mdh_frames(self) -> FloatArray:
        """World poses (7, 4, 4) of MDH frames 0..6 of the body as simulated."""
        out = np.empty((_N + 1, 4, 4))
        out[0] = self.params.T_world_base
        t = self.params.mdh
        for k in range(_N):
            out[k + 1] = self.link_pose(f"link{k + 1}") @ constant_transform(t, k)
        return out

    def T_world_camera(self) -> FloatArray:
        """True pose (4, 4) of the camera's optical frame in the world (m)."""
        return self.link_pose("camera")

    def collisions(self) -> list[tuple[str, str]]:
        """Colliding pairs at the current configuration: non-adjacent links and scenery."""
        c = self.world.bullet
        m = self.collision_margin
        out: list[tuple[str, str]] = []
        li = self.link_index
        for a, b in self._self_pairs:
            if c.getClosestPoints(self.body, self.body, m, li[a], li[b]):
                out.append((a, b))
        for name, body in self.world.bodies.items():
            if body == self.body:
                continue
            for a in self._scenery_links:
                if c.getClosestPoints(self.body, body, m, li[a], -1):
                    out.append((a, name))
        return out
