"""Nominal parameters read from a robot's URDF: a mobile base's wheels, an arm's MDH table.

:func:`wheels_from_urdf` finds the driven wheels of a wheeled base (their radii, the
track, differential drive or skid-steer) and :func:`arm_from_urdf` expresses the
revolute chain of an arm in the project's five-parameter modified DH form
(:class:`~realitygap.estimators.arm.mdh.MDHTable`) together with the constant base
and tool transforms that tie it to the URDF's links. :func:`urdf_chain_pose`
composes the URDF joint transforms directly, the reference the MDH form reproduces.

URDF conventions used here: a joint's ``<origin xyz rpy>`` places the joint frame in
the parent link frame with :math:`R = R_z(\\text{yaw}) R_y(\\text{pitch})
R_x(\\text{roll})`; the child link frame is the joint frame turned by the joint angle
about ``<axis>`` (default ``1 0 0``). Lengths in m, angles in rad.

Safety: a file is read only when it is a regular file of at most
:data:`MAX_URDF_BYTES`, and a document with a ``<!DOCTYPE>`` or ``<!ENTITY>``
declaration is refused before parsing (entity expansion is how an XML "bomb" grows
a few bytes into gigabytes; a URDF needs neither). Every problem is reported as a
:class:`UrdfError` (a ``ValueError``) that names the file, the element, what was
expected, what was found and how to fix it.

From axes to the MDH table (:func:`arm_from_urdf`)
--------------------------------------------------
At ``q = 0`` each revolute joint ``i`` is a line in the base-link frame, through the
joint origin along its (unit) axis. Row ``i`` of the table places frame ``i`` on the
axis of joint ``i + 1``, with its z axis along that joint's URDF axis, so the MDH and
URDF joint angles are the same numbers:

* axes not parallel (row is plain DH, ``beta = 0``): the origin of frame ``i`` is the
  foot on axis ``i + 1`` of the common normal, ``d_i`` the distance along axis ``i``
  from the origin of frame ``i - 1`` to the other foot, ``a_i`` the length of the
  normal (signed), ``x_i`` along it (along :math:`z_{i-1} \\times z_i` up to sign,
  also when the axes intersect) and ``alpha_i`` the twist about ``x_i``;
* axes parallel to within :data:`PARALLEL_AXIS_SIN` (the Hayati row of
  :mod:`~realitygap.estimators.arm.mdh`): ``d_i = 0``, the origin of frame ``i`` is
  where axis ``i + 1`` crosses the plane normal to axis ``i`` through the origin of
  frame ``i - 1``, ``a_i`` the distance to it, and ``alpha_i``, ``beta_i`` the tilt of
  axis ``i + 1``.

Each ``x_i`` may point either way along its line (``a``, ``alpha`` and ``beta`` change
sign, ``theta`` moves by π); the direction is chosen to keep ``theta_i`` in
(−π/2, π/2], which yields the published tables' zero offsets where they exist.

The free choices, absorbed by ``base`` and ``tool``:

* frame 0 has its z axis along axis 1, its origin at the foot on axis 1 of the base
  link's origin, and its x axis equal to ``x_1`` at ``q = 0`` (so ``theta_1 = 0``);
  ``x_1`` is :math:`z_0 \\times z_1` normalised (``0 < alpha_1 < π``) or, when axes 1
  and 2 are parallel, points from axis 1 to axis 2 (``a_1 >= 0``);
  ``base`` is the pose of frame 0 in the base link;
* the last frame ``n`` has its z axis along axis ``n``, its x axis that of frame
  ``n - 1`` at ``q = 0`` (``theta_n = a_n = alpha_n = beta_n = 0``) and its origin at
  the foot on axis ``n`` of the tip link's origin (``d_n`` the offset along the axis);
  ``tool`` is the pose of the tip link in frame ``n``: the tip's orientation and a
  translation normal to axis ``n``. A tip whose origin lies on the last axis, whose z
  axis is that axis and whose x axis is ``x_{n-1}`` (a UR ``tool0``) has ``tool = I``.

With these choices the published UR10 DH table comes out exactly, with ``base`` the
URDF's ``base`` frame (``base_link`` turned by π about z) and ``tool = I`` at
``tool0``.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Collection, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from xml.parsers import expat

import numpy as np
import numpy.typing as npt

from realitygap.estimators.arm.mdh import MDHTable, forward_kinematics

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "MAX_URDF_BYTES",
    "PARALLEL_AXIS_SIN",
    "UrdfArm",
    "UrdfError",
    "UrdfJoint",
    "UrdfLink",
    "UrdfModel",
    "UrdfShape",
    "UrdfWheels",
    "arm_from_urdf",
    "parse_urdf",
    "urdf_chain_pose",
    "wheels_from_urdf",
]

#: Largest URDF file read (bytes).
MAX_URDF_BYTES = 5 * 1024 * 1024
#: Consecutive joint axes with :math:`|\\sin\\angle| <` this (about 3°) get the Hayati row.
PARALLEL_AXIS_SIN = 0.05
#: A wheel's axis must lie within 45° of the base's y axis (|cos| of the angle above this).
_LATERAL_AXIS_COS = math.sqrt(0.5)
_LEN_EPS = 1e-12
_SIDE_EPS = 1e-6  # m: a wheel this close to y = 0 is on neither side
_AXLE_EPS = 1e-3  # m: same-side wheels closer than this along x share one axle

_REVOLUTE = ("revolute", "continuous")
_JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed", "floating", "planar")


class UrdfError(ValueError):
    """A URDF that cannot be read, or does not describe what was asked for."""


def _error(source: str, element: str, expected: str, got: str, fix: str) -> UrdfError:
    return UrdfError(f"{source}: {element}: expected {expected}, got {got}. Fix: {fix}")


# =========================================================================== model
@dataclass(frozen=True, eq=False)
class UrdfShape:
    """One ``<collision>`` or ``<visual>`` geometry of a link.

    Attributes
    ----------
    kind : str
        ``"cylinder"``, ``"sphere"``, ``"box"``, ``"mesh"``, ``"capsule"`` or another tag.
    radius : float
        m; NaN for shapes without one.
    length : float
        m (cylinder, capsule); NaN otherwise.
    origin : ndarray, shape (4, 4)
        Pose of the shape in the link frame (a cylinder's axis is its z axis).
    collision : bool
        True for ``<collision>``, False for ``<visual>``.
    """

    kind: str
    radius: float
    length: float
    origin: FloatArray
    collision: bool


@dataclass(frozen=True, eq=False)
class UrdfLink:
    """A ``<link>``: its mass (kg, 0 without ``<inertial>``) and geometries."""

    name: str
    mass: float
    shapes: tuple[UrdfShape, ...] = ()


@dataclass(frozen=True, eq=False)
class UrdfJoint:
    """A ``<joint>``.

    Attributes
    ----------
    name, type, parent, child : str
    origin : ndarray, shape (4, 4)
        Pose of the joint frame in the parent link frame.
    axis : ndarray, shape (3,)
        Unit axis in the joint frame.
    lower, upper : float
        Limits (rad or m); ±inf for a continuous joint or one without ``<limit>``.
    mimic : str or None
        Name of the joint this one mimics.
    """

    name: str
    type: str
    parent: str
    child: str
    origin: FloatArray
    axis: FloatArray
    lower: float
    upper: float
    mimic: str | None = None

    def transform(self, q: float = 0.0) -> FloatArray:
        """Pose of the child link in the parent link at joint position ``q`` (rad or m)."""
        T = self.origin.copy()
        if q != 0.0:
            if self.type in _REVOLUTE:
                T[:3, :3] = T[:3, :3] @ _axis_angle(self.axis, q)
            elif self.type == "prismatic":
                T[:3, 3] = T[:3, 3] + T[:3, :3] @ (self.axis * q)
        return T


@dataclass(frozen=True, eq=False)
class UrdfModel:
    """A parsed URDF: links and joints (document order) and the tree they form.

    Attributes
    ----------
    source : str
        The file it was read from (for messages).
    name : str
        The robot's name.
    links : dict of str to UrdfLink
    joints : dict of str to UrdfJoint
    root : str
        The one link that is no joint's child.
    """

    source: str
    name: str
    links: dict[str, UrdfLink]
    joints: dict[str, UrdfJoint]
    root: str
    _parent_joint: dict[str, UrdfJoint] = field(repr=False, default_factory=dict)
    _child_joints: dict[str, tuple[UrdfJoint, ...]] = field(repr=False, default_factory=dict)

    def parent_joint(self, link: str) -> UrdfJoint | None:
        """The joint whose child is ``link`` (None for the root)."""
        return self._parent_joint.get(link)

    def child_joints(self, link: str) -> tuple[UrdfJoint, ...]:
        """The joints whose parent is ``link``, in document order."""
        return self._child_joints.get(link, ())

    def path(self, base: str, tip: str) -> list[UrdfJoint]:
        """Joints from ``base`` down to ``tip`` (``tip`` must lie below ``base``)."""
        self._check_link(base, "base_link")
        self._check_link(tip, "tip_link")
        joints: list[UrdfJoint] = []
        link = tip
        while link != base:
            j = self._parent_joint.get(link)
            if j is None:
                raise _error(
                    self.source,
                    f"link '{tip}'",
                    f"a link below base link '{base}'",
                    f"a link on another branch (its chain from the root '{self.root}' does "
                    f"not pass through '{base}')",
                    "choose a base_link that is an ancestor of the tip link",
                )
            joints.append(j)
            link = j.parent
        return joints[::-1]

    def poses_at_zero(self) -> dict[str, FloatArray]:
        """Pose of every link in the root link's frame with every joint at 0."""
        poses = {self.root: np.eye(4)}
        stack = [self.root]
        while stack:
            link = stack.pop()
            for j in self.child_joints(link):
                poses[j.child] = poses[link] @ j.origin
                stack.append(j.child)
        return poses

    def _check_link(self, name: str, what: str) -> None:
        if name not in self.links:
            raise _error(
                self.source,
                f"{what} '{name}'",
                "the name of a <link> of this URDF",
                "no such link",
                f"use one of {_listing(self.links)}",
            )


def _unique_name(source: str, el: ET.Element, kind: str, seen: Collection[str]) -> str:
    """The ``name`` of a ``<link>`` or ``<joint>`` element, refused when absent or repeated."""
    name = el.get("name")
    if not name:
        raise _error(source, f"<{kind}>", "a name attribute", "none", f"name the {kind}")
    if name in seen:
        raise _error(
            source,
            f"{kind} '{name}'",
            f"a unique {kind} name",
            f"a second {kind} of that name",
            "rename or remove one of them",
        )
    return str(name)


def _listing(names: Iterable[str], limit: int = 40) -> str:
    items = list(names)
    shown = ", ".join(repr(n) for n in items[:limit])
    return f"[{shown}{', …' if len(items) > limit else ''}]"


def _rot_x(a: float) -> FloatArray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rot_y(a: float) -> FloatArray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rot_z(a: float) -> FloatArray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _axis_angle(axis: FloatArray, angle: float) -> FloatArray:
    """Rotation by ``angle`` about the unit ``axis`` (Rodrigues)."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def _pose(xyz: Sequence[float], rpy: Sequence[float]) -> FloatArray:
    T = np.eye(4)
    T[:3, :3] = _rot_z(rpy[2]) @ _rot_y(rpy[1]) @ _rot_x(rpy[0])
    T[:3, 3] = xyz
    return T


def _inv(T: FloatArray) -> FloatArray:
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


# =========================================================================== reading
def _read_bytes(path: str | Path) -> tuple[bytes, str]:
    p = Path(path)
    source = str(p)
    if not p.exists():
        raise _error(
            source, "file", "an existing URDF file", "no such file", "check the path and name"
        )
    if not p.is_file():
        raise _error(
            source,
            "file",
            "a regular file",
            "a directory" if p.is_dir() else "a special file",
            "pass the path of the .urdf file itself",
        )
    size = p.stat().st_size
    if size > MAX_URDF_BYTES:
        raise _error(
            source,
            "file",
            f"at most {MAX_URDF_BYTES} bytes",
            f"{size} bytes",
            "pass the URDF itself (meshes stay in their own files), or strip what it does not need",
        )
    with p.open("rb") as fh:
        data = fh.read(MAX_URDF_BYTES + 1)
    if len(data) > MAX_URDF_BYTES:
        raise _error(
            source,
            "file",
            f"at most {MAX_URDF_BYTES} bytes",
            "a file that grew while it was read",
            "read it once it is completely written",
        )
    return data, source


class _Declaration(Exception):
    pass


def _refuse_declarations(data: bytes, source: str) -> None:
    """Raise on any DOCTYPE or ENTITY declaration, before anything expands them."""

    def on_doctype(name: str, *_: object) -> None:
        raise _Declaration(f"<!DOCTYPE {name} …>")

    def on_entity(name: str, *_: object) -> None:
        raise _Declaration(f"<!ENTITY {name} …>")

    parser = expat.ParserCreate()
    parser.StartDoctypeDeclHandler = on_doctype
    parser.EntityDeclHandler = on_entity
    try:
        parser.Parse(data, True)
    except _Declaration as exc:
        raise _error(
            source,
            "document",
            "a URDF without DOCTYPE or ENTITY declarations",
            f"the declaration {exc}",
            "remove the declaration and write the values out (entity expansion is refused: "
            "it is how XML bombs work, and URDF does not use it)",
        ) from None
    except expat.ExpatError as exc:
        raise _error(
            source,
            f"XML at line {exc.lineno}, column {exc.offset}",
            "well-formed XML",
            expat.ErrorString(exc.code),
            "repair the file (run it through xacro or check_urdf)",
        ) from None


def _floats(
    source: str, element: str, text: str | None, n: int, default: Sequence[float]
) -> list[float]:
    if text is None:
        return list(default)
    parts = text.split()
    try:
        vals = [float(v) for v in parts]
    except ValueError:
        vals = []
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        hint = (
            "expand the xacro file first (`xacro model.urdf.xacro > model.urdf`)"
            if "$" in text
            else f"write {n} finite numbers separated by spaces"
        )
        raise _error(source, element, f"{n} finite numbers", repr(text), hint)
    return vals


def _origin(source: str, element: str, parent: ET.Element) -> FloatArray:
    o = parent.find("origin")
    if o is None:
        return np.eye(4)
    xyz = _floats(source, f"{element} <origin xyz>", o.get("xyz"), 3, (0.0, 0.0, 0.0))
    rpy = _floats(source, f"{element} <origin rpy>", o.get("rpy"), 3, (0.0, 0.0, 0.0))
    return _pose(xyz, rpy)


def _number(source: str, element: str, text: str | None, default: float) -> float:
    return _floats(source, element, text, 1, (default,))[0]


def _parse_link(source: str, el: ET.Element, name: str) -> UrdfLink:
    what = f"link '{name}'"
    mass = 0.0
    inertial = el.find("inertial")
    if inertial is not None:
        m = inertial.find("mass")
        if m is not None:
            mass = _number(source, f"{what} <mass value>", m.get("value"), 0.0)
            if mass < 0:
                raise _error(
                    source, f"{what} <mass>", "a mass >= 0 (kg)", repr(mass), "fix the sign"
                )
    shapes = []
    for tag in ("collision", "visual"):
        for g in el.findall(tag):
            geo = g.find("geometry")
            if geo is None or len(geo) == 0:
                continue
            shape = geo[0]
            kind = shape.tag
            radius = length = math.nan
            if kind in ("cylinder", "sphere", "capsule"):
                radius = _number(source, f"{what} <{tag}> <{kind} radius>", shape.get("radius"), 0)
                if not radius > 0:
                    raise _error(
                        source,
                        f"{what} <{tag}> <{kind}>",
                        "a radius > 0 (m)",
                        repr(shape.get("radius")),
                        "give the radius in metres",
                    )
            if kind in ("cylinder", "capsule"):
                length = _number(source, f"{what} <{tag}> <{kind} length>", shape.get("length"), 0)
            shapes.append(
                UrdfShape(
                    kind, radius, length, _origin(source, f"{what} <{tag}>", g), tag == "collision"
                )
            )
    return UrdfLink(name, mass, tuple(shapes))


def _parse_joint(source: str, el: ET.Element, name: str, links: dict[str, UrdfLink]) -> UrdfJoint:
    what = f"joint '{name}'"
    jtype = el.get("type")
    if jtype not in _JOINT_TYPES:
        raise _error(
            source,
            what,
            f"type one of {list(_JOINT_TYPES)}",
            repr(jtype),
            "set the joint's type attribute",
        )
    ends = {}
    for tag in ("parent", "child"):
        e = el.find(tag)
        link = None if e is None else e.get("link")
        if not link:
            raise _error(
                source,
                what,
                f'a <{tag} link="…"/> element',
                "none",
                f"add the {tag} link of the joint",
            )
        if link not in links:
            raise _error(
                source,
                f"{what} <{tag}>",
                "the name of a <link> of this URDF",
                f"link '{link}', which is not defined",
                f'define <link name="{link}"> or correct the name; links defined: '
                f"{_listing(links)}",
            )
        ends[tag] = link
    origin = _origin(source, what, el)
    axis_el = el.find("axis")
    axis = np.array(
        _floats(
            source,
            f"{what} <axis xyz>",
            None if axis_el is None else axis_el.get("xyz"),
            3,
            (1.0, 0.0, 0.0),
        )
    )
    norm = float(np.linalg.norm(axis))
    if jtype not in ("fixed", "floating") and norm < 1e-9:
        raise _error(
            source,
            f"{what} <axis>",
            "a non-zero axis vector",
            repr(axis_el.get("xyz") if axis_el is not None else None),
            'give the joint axis, e.g. <axis xyz="0 0 1"/>',
        )
    axis = axis / norm if norm > 0 else np.array([1.0, 0.0, 0.0])
    lower, upper = -math.inf, math.inf
    lim = el.find("limit")
    if jtype in ("revolute", "prismatic") and lim is not None:
        lower = _number(source, f"{what} <limit lower>", lim.get("lower"), 0.0)
        upper = _number(source, f"{what} <limit upper>", lim.get("upper"), 0.0)
        if lower > upper:
            raise _error(
                source,
                f"{what} <limit>",
                "lower <= upper",
                f"lower = {lower!r}, upper = {upper!r}",
                "swap the limits",
            )
    mimic_el = el.find("mimic")
    mimic = None if mimic_el is None else mimic_el.get("joint")
    return UrdfJoint(name, jtype, ends["parent"], ends["child"], origin, axis, lower, upper, mimic)


def parse_urdf(path: str | Path) -> UrdfModel:
    """Read a URDF file into a :class:`UrdfModel`.

    Parameters
    ----------
    path : str or Path
        The ``.urdf`` file (expanded: xacro macros are not evaluated).

    Returns
    -------
    UrdfModel

    Raises
    ------
    UrdfError
        If the file is missing, not a regular file, larger than :data:`MAX_URDF_BYTES`,
        declares a DOCTYPE or entity, is not well-formed, is not a ``<robot>``, or its
        links and joints do not form one tree.
    """
    data, source = _read_bytes(path)
    _refuse_declarations(data, source)
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise _error(source, "document", "well-formed XML", str(exc), "repair the file") from None
    if root.tag != "robot":
        raise _error(
            source,
            "root element",
            "<robot> (a URDF)",
            f"<{root.tag}>",
            "pass a URDF file; expand a .xacro with `xacro` and convert SDF/MJCF first",
        )
    links: dict[str, UrdfLink] = {}
    for el in root.findall("link"):
        name = _unique_name(source, el, "link", links)
        links[name] = _parse_link(source, el, name)
    if not links:
        raise _error(
            source,
            "<robot>",
            "at least one <link>",
            "none",
            "expand a xacro file first (`xacro model.urdf.xacro > model.urdf`)"
            if any("xacro" in str(el.tag) for el in root)
            else "pass a URDF that defines its links",
        )
    joints: dict[str, UrdfJoint] = {}
    parent_joint: dict[str, UrdfJoint] = {}
    child_joints: dict[str, list[UrdfJoint]] = {}
    for el in root.findall("joint"):
        name = _unique_name(source, el, "joint", joints)
        j = _parse_joint(source, el, name, links)
        if j.child in parent_joint:
            raise _error(
                source,
                f"joint '{name}'",
                f"link '{j.child}' to be the child of one joint",
                f"it is also the child of joint '{parent_joint[j.child].name}'",
                "a URDF is a tree; remove one of the joints (close loops are not URDF)",
            )
        joints[name] = j
        parent_joint[j.child] = j
        child_joints.setdefault(j.parent, []).append(j)
    roots = [n for n in links if n not in parent_joint]
    if len(roots) != 1:
        raise _error(
            source,
            "link tree",
            "exactly one root link (a link that is no joint's child)",
            f"{len(roots)} roots {_listing(roots)}" if roots else "a closed loop of joints",
            "connect the parts with joints so that one link is the root",
        )
    model = UrdfModel(
        source,
        root.get("name", ""),
        links,
        joints,
        roots[0],
        parent_joint,
        {k: tuple(v) for k, v in child_joints.items()},
    )
    reached = model.poses_at_zero()
    if len(reached) != len(links):
        loose = [n for n in links if n not in reached]
        raise _error(
            source,
            "link tree",
            f"every link below the root '{roots[0]}'",
            f"links in a closed loop {_listing(loose)}",
            "a URDF is a tree; break the loop",
        )
    return model


def _as_model(path_or_parsed: str | Path | UrdfModel) -> UrdfModel:
    if isinstance(path_or_parsed, UrdfModel):
        return path_or_parsed
    return parse_urdf(path_or_parsed)


# =========================================================================== wheels
@dataclass(frozen=True)
class UrdfWheels:
    """The driven wheels of a wheeled base, as read from its URDF.

    Attributes
    ----------
    source : str
        The URDF file.
    left_joint, right_joint : str
        The wheel joints of the pair: the only two of a differential drive, the
        front-most wheel of each side of a skid-steer.
    radius_left, radius_right : float
        Wheel radius (m) of each side: the cylinder (or sphere) radius of the wheel link,
        collision geometry preferred, else visual; averaged over a side's wheels.
    track : float
        Lateral distance (m) between the left and the right wheels' joint origins,
        measured along the wheel axis (the distance between the wheel planes); between
        the mean positions of the sides for a skid-steer.
    n_wheels : int
        Driven wheels found (2 for a differential drive, 4 or 6 for a skid-steer).
    drive : str
        ``"diffdrive"`` (all wheels on one axle) or ``"skid_steer"`` (≥ 2 wheels per
        side at different x).
    wheel_x : tuple of float
        x of every wheel's joint origin in the base frame (m), left wheels then right
        wheels, each side front to back; a skid-steer's wheel base is their spread.
    base_link : str
        The link whose frame x, y and the track are measured in.
    wheel_joints : tuple of str
        The wheel joints in the order of ``wheel_x``.
    """

    source: str
    left_joint: str
    right_joint: str
    radius_left: float
    radius_right: float
    track: float
    n_wheels: int
    drive: str
    wheel_x: tuple[float, ...]
    base_link: str
    wheel_joints: tuple[str, ...] = ()

    def params(self) -> dict[str, float]:
        """The values keyed as :class:`~realitygap.robots.diffdrive.DiffDriveParams` fields.

        For a skid-steer ``"wheelbase"`` is the geometric track; the effective track
        of a skidding base is larger and is fitted from motion, not read here.
        """
        return {
            "wheel_radius_left": float(self.radius_left),
            "wheel_radius_right": float(self.radius_right),
            "wheelbase": float(self.track),
        }


@dataclass(frozen=True, eq=False)
class _Wheel:
    joint: UrdfJoint
    radius: float  # NaN: no cylinder/sphere to read it from
    x: float
    y: float
    axis: FloatArray  # in the base frame
    center: FloatArray  # joint origin in the base frame


def _default_mobile_base(model: UrdfModel) -> str:
    if "base_link" in model.links:
        return "base_link"
    if "base_footprint" in model.links:
        kids = model.child_joints("base_footprint")
        if kids:
            return kids[0].child
    return model.root


def _wheel_radius(link: UrdfLink, axis: FloatArray, named: bool) -> float:
    """Radius of the wheel geometry whose axis is the joint axis (link frame); NaN if none."""
    for collision in (True, False):
        for s in link.shapes:
            if s.collision != collision:
                continue
            if s.kind == "sphere":
                return s.radius
            if s.kind == "cylinder":
                along = abs(float(s.origin[:3, 2] @ axis))
                if along > 1.0 - 1e-6 or named:
                    return s.radius
    return math.nan


def _describe_joints(model: UrdfModel, poses: dict[str, FloatArray], T_inv: FloatArray) -> str:
    rows = []
    for j in model.joints.values():
        y = float((T_inv @ poses[j.parent] @ j.origin)[1, 3])
        rows.append(f"'{j.name}' ({j.type}, {j.parent} -> {j.child}, y = {y:+.4g} m)")
    return "; ".join(rows) if rows else "none"


def wheels_from_urdf(
    path: str | Path | UrdfModel,
    *,
    base_link: str | None = None,
    left_joint: str | None = None,
    right_joint: str | None = None,
) -> UrdfWheels:
    """Wheel radii and track of a wheeled base from its URDF.

    A joint drives a wheel when it is ``continuous`` or ``revolute``, its axis lies
    within 45° of the base's y axis, neither it nor its child link is named
    ``*caster*``, and its child link carries a cylinder whose axis is the joint axis or
    a sphere, or the joint or link is named ``*wheel*`` (then any cylinder gives the
    radius). Fixed joints never drive a wheel. Left wheels have their joint origin at
    y > 0 in the base frame, right wheels at y < 0 (all joints at 0).

    Parameters
    ----------
    path : str or Path or UrdfModel
        The URDF (or an already parsed one).
    base_link : str, optional
        The base frame; default ``base_link`` if present, else the child of
        ``base_footprint``, else the root link.
    left_joint, right_joint : str, optional
        Name the pair instead of finding it (the other wheels found still decide
        ``n_wheels``, ``drive`` and ``wheel_x``).

    Returns
    -------
    UrdfWheels

    Raises
    ------
    UrdfError
        If the file cannot be read, no left/right pair is found (the message lists the
        joints seen), the sides have different numbers of wheels, or a wheel has no
        cylinder or sphere to read the radius from.
    """
    model = _as_model(path)
    src = model.source
    base = base_link if base_link is not None else _default_mobile_base(model)
    model._check_link(base, "base_link")
    poses = model.poses_at_zero()
    T_inv = _inv(poses[base])

    def wheel_of(j: UrdfJoint, named: bool) -> _Wheel:
        T = T_inv @ poses[j.parent] @ j.origin
        axis = T[:3, :3] @ j.axis
        radius = _wheel_radius(model.links[j.child], j.axis, named)
        return _Wheel(j, radius, float(T[0, 3]), float(T[1, 3]), axis, T[:3, 3].copy())

    wheels: list[_Wheel] = []
    centred: list[_Wheel] = []  # wheels on the base's axis: no side, no track
    for j in model.joints.values():
        if j.type not in _REVOLUTE:
            continue
        names = (j.name.lower(), j.child.lower())
        if any("caster" in n for n in names):
            continue
        w = wheel_of(j, any("wheel" in n for n in names))
        if abs(w.axis[1]) < _LATERAL_AXIS_COS:
            continue
        if math.isnan(w.radius) and not any("wheel" in n for n in names):
            continue
        if abs(w.y) <= _SIDE_EPS:
            centred.append(w)
            continue
        wheels.append(w)

    chosen: dict[str, _Wheel] = {}
    for side, name in (("left", left_joint), ("right", right_joint)):
        if name is None:
            continue
        joint = model.joints.get(name)
        if joint is None or joint.type not in _REVOLUTE:
            raise _error(
                src,
                f"{side}_joint '{name}'",
                "a continuous or revolute joint of this URDF",
                "no such joint" if joint is None else f"a {joint.type} joint",
                f"name one of the joints seen: {_describe_joints(model, poses, T_inv)}",
            )
        w = next((w for w in wheels if w.joint.name == name), None) or wheel_of(joint, True)
        sign = 1.0 if side == "left" else -1.0
        if not sign * w.y > _SIDE_EPS:
            raise _error(
                src,
                f"{side}_joint '{name}'",
                f"a joint origin at y {'>' if sign > 0 else '<'} 0 in base frame '{base}'",
                f"y = {w.y:+.6g} m",
                "swap left_joint and right_joint, or pass the base_link whose y axis "
                "points to the robot's left",
            )
        if not any(x is w for x in wheels):
            wheels.append(w)
        chosen[side] = w

    left = sorted((w for w in wheels if w.y > 0), key=lambda w: -w.x)
    right = sorted((w for w in wheels if w.y < 0), key=lambda w: -w.x)
    if not left or not right:
        track = (
            f" ({len(centred)} wheel joint(s) at y = 0: a track of 0 m, no differential drive)"
            if centred
            else ""
        )
        raise _error(
            src,
            f"wheels of base '{base}'",
            "a left/right pair of continuous or revolute wheel joints (child link with "
            "a cylinder along the joint axis or a sphere, or named *wheel*; not *caster*) "
            "on both sides of the base (y > 0 and y < 0)",
            f"{len(left)} left and {len(right)} right{track}; joints seen: "
            f"{_describe_joints(model, poses, T_inv)}",
            "pass left_joint= and right_joint=, or base_link= if the base frame is another "
            "link, or give the wheel links a <collision> cylinder",
        )
    if len(left) != len(right) and not (left_joint and right_joint):
        raise _error(
            src,
            f"wheels of base '{base}'",
            "the same number of wheels on both sides",
            f"left {[w.joint.name for w in left]}, right {[w.joint.name for w in right]}",
            "pass left_joint= and right_joint= to name the pair",
        )
    for w in left + right:
        if math.isnan(w.radius):
            raise _error(
                src,
                f"link '{w.joint.child}' (wheel joint '{w.joint.name}')",
                "a <collision> or <visual> cylinder or sphere to read the wheel radius from",
                f"only {[s.kind for s in model.links[w.joint.child].shapes] or 'no geometry'}",
                'add <collision><geometry><cylinder radius="…" length="…"/></geometry>'
                "</collision> to the wheel link",
            )
    wl = chosen.get("left", left[0])
    wr = chosen.get("right", right[0])
    axis = np.sum([w.axis * np.sign(w.axis[1]) for w in left + right], axis=0)
    axis = axis / np.linalg.norm(axis)
    if left_joint and right_joint:
        track = abs(float((wl.center - wr.center) @ axis))
    else:
        c_left = np.mean([w.center for w in left], axis=0)
        c_right = np.mean([w.center for w in right], axis=0)
        track = abs(float((c_left - c_right) @ axis))
    xs = [w.x for w in left + right]
    spread = max(max(w.x for w in side) - min(w.x for w in side) for side in (left, right))
    drive = "skid_steer" if min(len(left), len(right)) >= 2 and spread > _AXLE_EPS else "diffdrive"
    return UrdfWheels(
        source=src,
        left_joint=wl.joint.name,
        right_joint=wr.joint.name,
        radius_left=float(np.mean([w.radius for w in left])) if "left" not in chosen else wl.radius,
        radius_right=float(np.mean([w.radius for w in right]))
        if "right" not in chosen
        else wr.radius,
        track=track,
        n_wheels=len(left) + len(right),
        drive=drive,
        wheel_x=tuple(xs),
        base_link=base,
        wheel_joints=tuple(w.joint.name for w in left + right),
    )


# =========================================================================== arm
@dataclass(frozen=True, eq=False)
class UrdfArm:
    """A revolute arm read from its URDF, in the project's MDH form.

    The tip pose in the base link frame is, for joint angles ``q`` (the URDF's own),

    .. math::

        T_{\\mathrm{base\\_link},\\mathrm{tip}}(q) = B\\, \\mathrm{FK}_{\\mathrm{MDH}}(q)\\, T,

    with ``B = base`` and ``T = tool`` (see the module docstring for how the free
    choices of frame 0 and frame ``n`` are made).

    Attributes
    ----------
    source : str
        The URDF file.
    joint_names : tuple of str
        The revolute (or continuous) joints from base to tip, in order.
    lower, upper : tuple of float
        Joint limits (rad); ±inf for continuous joints.
    mdh : MDHTable
        The chain in the five-parameter MDH form (Hayati rows for parallel axes).
    base : ndarray, shape (4, 4)
        Pose of MDH frame 0 in the base link frame.
    tool : ndarray, shape (4, 4)
        Pose of the tip link in the last MDH frame.
    masses : tuple of float
        Mass (kg) of each moving body: the child link of each joint plus every link
        fixed to it (0 where no ``<inertial>`` is given).
    base_link, tip_link : str
    """

    source: str
    joint_names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    mdh: MDHTable
    base: FloatArray
    tool: FloatArray
    masses: tuple[float, ...]
    base_link: str = ""
    tip_link: str = ""

    def pose(self, q: npt.ArrayLike) -> FloatArray:
        """Tip pose(s) in the base link frame from the MDH form, (4, 4) or (N, 4, 4)."""
        qa = np.asarray(q, dtype=float)
        T = forward_kinematics(self.mdh, qa, self.base, self.tool)
        return T[0] if qa.ndim == 1 else T


def _default_tip(model: UrdfModel, base: str) -> str:
    """Leaf below ``base`` with the most revolute joints on its path (then the fewest other
    moving joints, then the deepest; the first in document order on a tie)."""
    best: tuple[int, int, int] | None = None
    tip = base
    stack: list[tuple[str, int, int, int]] = [(base, 0, 0, 0)]
    order = {n: i for i, n in enumerate(model.links)}
    leaves = []
    while stack:
        link, n_rev, n_other, depth = stack.pop()
        kids = model.child_joints(link)
        if not kids:
            leaves.append((order[link], link, (n_rev, -n_other, depth)))
        for j in kids:
            stack.append(
                (
                    j.child,
                    n_rev + (j.type in _REVOLUTE),
                    n_other + (j.type not in _REVOLUTE and j.type != "fixed"),
                    depth + 1,
                )
            )
    for _, link, key in sorted(leaves):
        if best is None or key > best:
            best, tip = key, link
    return tip


def _arm_chain(
    model: UrdfModel, base_link: str | None, tip_link: str | None
) -> tuple[str, str, list[UrdfJoint]]:
    src = model.source
    base = base_link if base_link is not None else model.root
    model._check_link(base, "base_link")
    tip = tip_link if tip_link is not None else _default_tip(model, base)
    chain = model.path(base, tip)
    for j in chain:
        if j.type not in _REVOLUTE and j.type != "fixed":
            raise _error(
                src,
                f"joint '{j.name}' (on the chain '{base}' -> '{tip}')",
                "revolute, continuous or fixed joints (revolute arms only)",
                f"a {j.type} joint",
                "pass a tip_link before that joint, or describe the arm without it",
            )
        if j.mimic is not None:
            raise _error(
                src,
                f"joint '{j.name}' (on the chain '{base}' -> '{tip}')",
                "independent joints",
                f"a joint that mimics '{j.mimic}'",
                "pass a tip_link before that joint",
            )
    if not any(j.type in _REVOLUTE for j in chain):
        raise _error(
            src,
            f"chain '{base}' -> '{tip}'",
            "at least one revolute or continuous joint",
            f"joints {[f'{j.name} ({j.type})' for j in chain] or 'none'}",
            "pass the base_link and tip_link of the arm",
        )
    return base, tip, chain


def _check_q(q: npt.ArrayLike, n: int, source: str) -> FloatArray:
    arr = np.asarray(q, dtype=float)
    if arr.ndim not in (1, 2) or arr.shape[-1] != n or not np.all(np.isfinite(arr)):
        raise _error(
            source,
            "joint angles",
            f"finite values of shape ({n},) or (N, {n})",
            f"shape {arr.shape}",
            "pass one angle (rad) per revolute joint of the chain, base to tip",
        )
    return arr


def urdf_chain_pose(
    path_or_parsed: str | Path | UrdfModel,
    q: npt.ArrayLike,
    *,
    base_link: str | None = None,
    tip_link: str | None = None,
) -> FloatArray:
    """Tip pose in the base link frame by composing the URDF joint transforms directly.

    Parameters
    ----------
    path_or_parsed : str or Path or UrdfModel
        The URDF.
    q : array_like, shape (n,) or (N, n)
        Angles (rad) of the chain's revolute joints, base to tip.
    base_link, tip_link : str, optional
        The chain's ends; the defaults of :func:`arm_from_urdf`.

    Returns
    -------
    ndarray, shape (4, 4) or (N, 4, 4)
    """
    model = _as_model(path_or_parsed)
    _, _, chain = _arm_chain(model, base_link, tip_link)
    moving = [j for j in chain if j.type in _REVOLUTE]
    qa = _check_q(q, len(moving), model.source)
    rows = qa[None, :] if qa.ndim == 1 else qa
    out = np.empty((rows.shape[0], 4, 4))
    for k, qk in enumerate(rows):
        T = np.eye(4)
        i = 0
        for j in chain:
            if j.type in _REVOLUTE:
                T = T @ j.transform(float(qk[i]))
                i += 1
            else:
                T = T @ j.origin
        out[k] = T
    return out[0] if qa.ndim == 1 else out


def _row_transform(theta: float, d: float, a: float, alpha: float, beta: float) -> FloatArray:
    """:math:`R_z(\\theta) T_z(d) T_x(a) R_x(\\alpha) R_y(\\beta)` as in ``mdh.py``."""
    T = np.eye(4)
    Rz = _rot_z(theta)
    T[:3, :3] = Rz @ _rot_x(alpha) @ _rot_y(beta)
    T[:3, 3] = Rz @ np.array([a, 0.0, d])
    return T


def _unit(v: FloatArray) -> FloatArray:
    return v / np.linalg.norm(v)


def _axis_row(
    F: FloatArray, p: FloatArray, u: FloatArray
) -> tuple[FloatArray | None, float, float, bool]:
    """Geometry of the row from frame ``F`` (z: axis i) to the line ``p + s u`` (axis i+1).

    Returns the direction ``x`` of the frame's x axis before the twists (None when it is
    undetermined: coincident axes), ``d``, the signed length ``a`` along ``x`` and whether
    the row is a Hayati (parallel) row. For non-parallel axes ``x`` is
    :math:`z \\times u / |z \\times u|` (the common normal), so ``a`` may be negative.
    """
    z, o = F[:3, 2], F[:3, 3]
    c = np.cross(z, u)
    s = float(np.linalg.norm(c))
    r = p - o
    if s < PARALLEL_AXIS_SIN:
        # Hayati: d = 0; frame i's origin where axis i+1 crosses the plane normal to z at o
        P = p - (float(r @ z) / float(u @ z)) * u
        v = P - o
        v = v - float(v @ z) * z
        a = float(np.linalg.norm(v))
        return (v / a if a > _LEN_EPS else None), 0.0, a, True
    b = float(z @ u)
    t = (float(r @ z) - b * float(r @ u)) / (1.0 - b * b)
    x = c / s
    return x, t, float(r @ x), False


def _angle_in(F: FloatArray, x: FloatArray) -> float:
    return math.atan2(float(x @ F[:3, 1]), float(x @ F[:3, 0]))


def _mdh_from_axes(
    points: list[FloatArray], dirs: list[FloatArray], T_tip: FloatArray, name: str
) -> tuple[MDHTable, FloatArray, FloatArray]:
    n = len(points)
    rows = np.zeros((n, 5))  # theta, d, a, alpha, beta
    # frame 0: z along axis 1, origin at the foot of the base origin on axis 1
    z0 = dirs[0]
    o0 = points[0] - float(points[0] @ z0) * z0
    F = np.eye(4)
    F[:3, 2] = z0
    F[:3, 3] = o0
    x0: FloatArray | None = None
    if n > 1:
        x0, *_ = _axis_row(F, points[1], dirs[1])
    if x0 is None:  # one joint, or axes 1 and 2 coincide: the base x axis, projected
        for cand in (np.eye(3)[0], np.eye(3)[1]):
            w = cand - float(cand @ z0) * z0
            if np.linalg.norm(w) > 1e-6:
                x0 = _unit(w)
                break
    assert x0 is not None
    F[:3, 0] = x0
    F[:3, 1] = np.cross(z0, x0)
    base = F.copy()
    for i in range(n - 1):
        xr, d, a, _ = _axis_row(F, points[i + 1], dirs[i + 1])
        if xr is None:  # coincident axes: keep the previous x
            xr = F[:3, 0].copy()
        theta = _angle_in(F, xr)
        if i > 0 and (math.cos(theta) < -1e-12 or (abs(math.cos(theta)) <= 1e-12 and theta < 0)):
            xr, a = -xr, -a
            theta = _angle_in(F, xr)
        if i == 0:
            theta = 0.0  # x0 was made equal to x1
        z = F[:3, 2]
        up = np.array([xr @ dirs[i + 1], np.cross(z, xr) @ dirs[i + 1], z @ dirs[i + 1]])
        beta = math.asin(max(-1.0, min(1.0, float(up[0]))))
        alpha = math.atan2(-float(up[1]), float(up[2]))
        rows[i] = (theta, d, a, alpha, beta)
        F = F @ _row_transform(theta, d, a, alpha, beta)
    # last frame: x as frame n-1's at q = 0 (theta_n = 0), origin at the foot of the tip
    # origin on axis n; the tool carries the tip's orientation about the axis
    d = float((T_tip[:3, 3] - F[:3, 3]) @ F[:3, 2])
    rows[n - 1] = (0.0, d, 0.0, 0.0, 0.0)
    F = F @ _row_transform(0.0, d, 0.0, 0.0, 0.0)
    tool = _inv(F) @ T_tip
    table = MDHTable(
        theta_offset=rows[:, 0],
        d=rows[:, 1],
        a=rows[:, 2],
        alpha=rows[:, 3],
        beta=rows[:, 4],
        name=name or "arm",
    )
    return table, base, tool


def arm_from_urdf(
    path: str | Path | UrdfModel,
    *,
    base_link: str | None = None,
    tip_link: str | None = None,
) -> UrdfArm:
    """A revolute arm's MDH table, base and tool transforms, limits and masses from its URDF.

    Parameters
    ----------
    path : str or Path or UrdfModel
        The URDF (or an already parsed one).
    base_link : str, optional
        The frame the arm is expressed in; default the root link.
    tip_link : str, optional
        The end of the chain (e.g. the flange or a TCP link); default the leaf with the
        most revolute joints on its path (on a tie the fewest prismatic joints, then the
        deepest, then the first in the file). Fixed joints after the last revolute joint
        are folded into ``tool``.

    Returns
    -------
    UrdfArm
        With ``arm.base @ forward_kinematics(arm.mdh, q) @ arm.tool`` equal to
        :func:`urdf_chain_pose` for every ``q``.

    Raises
    ------
    UrdfError
        If the file cannot be read, the links are not on one chain, or the chain holds a
        prismatic, planar, floating or mimic joint (revolute arms only).
    """
    model = _as_model(path)
    base, tip, chain = _arm_chain(model, base_link, tip_link)
    T = np.eye(4)
    points: list[FloatArray] = []
    dirs: list[FloatArray] = []
    moving: list[UrdfJoint] = []
    for j in chain:
        T = T @ j.origin
        if j.type in _REVOLUTE:
            points.append(T[:3, 3].copy())
            dirs.append(_unit(T[:3, :3] @ j.axis))
            moving.append(j)
    table, T_base, T_tool = _mdh_from_axes(points, dirs, T, model.name)

    def body_mass(link: str) -> float:
        m = model.links[link].mass
        for j in model.child_joints(link):
            if j.type == "fixed":
                m += body_mass(j.child)
        return m

    return UrdfArm(
        source=model.source,
        joint_names=tuple(j.name for j in moving),
        lower=tuple(-math.inf if j.type == "continuous" else j.lower for j in moving),
        upper=tuple(math.inf if j.type == "continuous" else j.upper for j in moving),
        mdh=table,
        base=T_base,
        tool=T_tool,
        masses=tuple(body_mass(j.child) for j in moving),
        base_link=base,
        tip_link=tip,
    )
