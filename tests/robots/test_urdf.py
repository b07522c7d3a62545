"""Reading URDFs: an arm's MDH table reproduces the URDF's kinematics, a base's wheels."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.estimators.arm.mdh import MDHTable, forward_kinematics
from realitygap.robots import urdf as urdf_module
from realitygap.robots.arm import ArmParams, urdf_from_arm_params
from realitygap.robots.diffdrive import DiffDriveParams
from realitygap.robots.urdf import (
    UrdfError,
    arm_from_urdf,
    parse_urdf,
    urdf_chain_pose,
    wheels_from_urdf,
)

DATA = Path(__file__).parent / "data"
UR10 = DATA / "ur10.urdf"
PANDA = DATA / "panda.urdf"
KOBUKI = DATA / "kobuki.urdf"
HUSKY = DATA / "husky.urdf"


def rot_z(angle: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", angle).as_matrix()
    return T


def random_q(n: int, count: int = 200, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-np.pi, np.pi, (count, n))


def fk_error(path, arm, q: np.ndarray) -> float:
    """Largest entry of |URDF pose − base · FK_MDH(q) · tool| over the configurations."""
    direct = urdf_chain_pose(path, q, base_link=arm.base_link, tip_link=arm.tip_link)
    via_mdh = forward_kinematics(arm.mdh, q, arm.base, arm.tool)
    return float(np.abs(direct - via_mdh).max())


# --------------------------------------------------------------------------- URDF writers
def origin_xml(T: np.ndarray) -> str:
    rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")  # URDF: R = Rz(y) Ry(p) Rx(r)
    xyz = " ".join(repr(float(v)) for v in T[:3, 3])
    return f'<origin xyz="{xyz}" rpy="{" ".join(repr(float(v)) for v in rpy)}"/>'


def row_constant(table: MDHTable, k: int) -> np.ndarray:
    """T_z(d_k) T_x(a_k) R_x(alpha_k) R_y(beta_k): row k after its R_z."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("XY", [table.alpha[k], table.beta[k]]).as_matrix()
    T[:3, 3] = [table.a[k], 0.0, table.d[k]]
    return T


def write_mdh_urdf(path: Path, table: MDHTable, mount: np.ndarray | None = None) -> Path:
    """A URDF whose joint origins are the MDH row transforms.

    Link ``link<k>`` is MDH frame ``k - 1`` turned by the joint about its z axis; joint
    ``k``'s origin is the constant part of row ``k - 1`` followed by :math:`R_z(\\theta_k)`;
    the ``flange`` is MDH frame n; ``mount`` places frame 0 in ``base_link``.
    """
    parts = ['<?xml version="1.0"?>', f'<robot name="{table.name}">', '<link name="base_link"/>']
    C = np.eye(4) if mount is None else mount
    parent = "base_link"
    for k in range(table.n_joints):
        parts.append(f'<link name="link{k + 1}"/>')
        parts.append(
            f'<joint name="joint{k + 1}" type="revolute"><parent link="{parent}"/>'
            f'<child link="link{k + 1}"/>{origin_xml(C @ rot_z(table.theta_offset[k]))}'
            '<axis xyz="0 0 1"/><limit lower="-6.3" upper="6.3" effort="1" velocity="1"/>'
            "</joint>"
        )
        parent = f"link{k + 1}"
        C = row_constant(table, k)
    parts.append('<link name="flange"/>')
    parts.append(
        f'<joint name="flange_joint" type="fixed"><parent link="{parent}"/>'
        f'<child link="flange"/>{origin_xml(C)}</joint>'
    )
    parts.append("</robot>")
    path.write_text("\n".join(parts) + "\n")
    return path


def write_random_chain(path: Path, rng: np.random.Generator, n: int = 6) -> Path:
    """A revolute chain with random origins and axes, fixed links in between, and special
    pairs: exactly parallel, nearly parallel (0.01 rad), intersecting and reversed axes."""
    parts = ['<?xml version="1.0"?>', '<robot name="random">', '<link name="world"/>']
    parent = "world"
    prev_axis = np.zeros(3)

    def add(name: str, jtype: str, xyz, rpy, axis=None) -> None:
        nonlocal parent
        parts.append(f'<link name="{name}"/>')
        ax = "" if axis is None else f'<axis xyz="{" ".join(repr(float(v)) for v in axis)}"/>'
        lim = '<limit lower="-3" upper="3" effort="1" velocity="1"/>' if jtype != "fixed" else ""
        parts.append(
            f'<joint name="{name}_joint" type="{jtype}"><parent link="{parent}"/>'
            f'<child link="{name}"/><origin xyz="{" ".join(repr(float(v)) for v in xyz)}" '
            f'rpy="{" ".join(repr(float(v)) for v in rpy)}"/>{ax}{lim}</joint>'
        )
        parent = name

    add("mount", "fixed", rng.normal(0, 0.3, 3), rng.uniform(-np.pi, np.pi, 3))
    for k in range(n):
        axis = rng.normal(size=3)
        if k == 2:  # parallel to the previous joint's axis (same axis in the same frame)
            axis = prev_axis
        elif k == 3:  # nearly parallel
            axis = prev_axis + 0.01 * np.cross(prev_axis, rng.normal(size=3))
        elif k == 4:  # reversed
            axis = -prev_axis + 0.5 * rng.normal(size=3)
        rpy = np.zeros(3) if k in (2, 3) else rng.uniform(-np.pi, np.pi, 3)
        xyz = np.zeros(3) if k == 5 else rng.normal(0, 0.2, 3)  # k = 5 intersects k = 4
        kind = "continuous" if k == 1 else "revolute"
        add(f"link{k + 1}", kind, xyz, rpy, axis)
        prev_axis = np.asarray(axis, dtype=float)
        if k == 1:  # a fixed link that does not turn: the next axis stays parallel
            add("spacer", "fixed", rng.normal(0, 0.1, 3), np.zeros(3))
    add("tip", "fixed", rng.normal(0, 0.1, 3), rng.uniform(-np.pi, np.pi, 3))
    parts.append("</robot>")
    path.write_text("\n".join(parts) + "\n")
    return path


def axis_lines(path, tip_link: str | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """(point, unit direction) of every revolute axis at q = 0 in the base link frame."""
    model = parse_urdf(path)
    arm = arm_from_urdf(model, tip_link=tip_link)
    chain = model.path(arm.base_link, arm.tip_link)
    T = np.eye(4)
    lines = []
    for j in chain:
        T = T @ j.origin
        if j.type in ("revolute", "continuous"):
            lines.append((T[:3, 3].copy(), T[:3, :3] @ j.axis))
    return lines


def line_distance(l1, l2) -> float:
    (p1, u1), (p2, u2) = l1, l2
    c = np.cross(u1, u2)
    if np.linalg.norm(c) < 1e-12:
        r = p2 - p1
        return float(np.linalg.norm(r - (r @ u1) * u1))
    return float(abs((p2 - p1) @ c) / np.linalg.norm(c))


# --------------------------------------------------------------------------- arms
def test_ur10_urdf_gives_the_published_dh_table() -> None:
    arm = arm_from_urdf(UR10, tip_link="tool0")
    assert arm.joint_names == (
        "shoulder_pan_joint",
        "shoulder_lift_joint",
        "elbow_joint",
        "wrist_1_joint",
        "wrist_2_joint",
        "wrist_3_joint",
    )
    q = random_q(6)
    assert fk_error(UR10, arm, q) < 1e-9

    # The URDF spreads the offset along the parallel axes 2-4 over shoulder_offset
    # (0.220941), elbow_offset (-0.1719) and wrist_1_length (0.1149); the Hayati rows
    # keep d2 = d3 = 0 and sum them into d4 = 0.163941, as the published table does, and
    # the signs of a2, a3 (x pointing back along the arm) and alpha5 come out as published
    # because the x axes are chosen to keep theta at 0. So the whole table agrees.
    ur10 = MDHTable.ur10()
    assert arm.mdh.isclose(ur10, atol=1e-9)
    np.testing.assert_array_equal(arm.mdh.parallel_rows, [False, True, True, False, False, False])

    # The geometry itself: distances between consecutive axes from the URDF's lines equal
    # |a| of the published table (axes 1-2, 4-5, 5-6 intersect; 2-3 and 3-4 are parallel).
    lines = axis_lines(UR10, "tool0")
    dist = [line_distance(lines[i], lines[i + 1]) for i in range(5)]
    np.testing.assert_allclose(dist, np.abs(ur10.a[:5]), atol=1e-9)

    # Where the conventions differ: UR's DH frame 0 is not the URDF's base_link but the
    # ROS-Industrial 'base' frame (base_link turned by pi about z); that is the `base`
    # found, and the DH flange frame 6 is 'tool0', so the tool is the identity.
    T_base_link_base = parse_urdf(UR10).joints["base_link-base_fixed_joint"].origin
    np.testing.assert_allclose(arm.base, T_base_link_base, atol=1e-12)
    np.testing.assert_allclose(arm.tool, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(
        urdf_chain_pose(UR10, q, tip_link="tool0"),
        forward_kinematics(ur10, q, T_base_link_base),
        atol=1e-9,
    )

    np.testing.assert_allclose(arm.masses, [7.778, 12.93, 3.87, 1.96, 1.96, 0.202])
    assert arm.lower[2] == pytest.approx(-np.pi) and arm.upper[0] == pytest.approx(2 * np.pi)


def test_ur10_default_tip_folds_the_fixed_end_frame_into_the_tool() -> None:
    arm = arm_from_urdf(UR10)  # leaves ee_link and tool0 tie; the first in the file wins
    assert arm.base_link == "base_link" and arm.tip_link == "ee_link"
    assert arm.mdh.isclose(MDHTable.ur10(), atol=1e-9)
    model = parse_urdf(UR10)
    T_tool0_ee = (
        np.linalg.inv(model.joints["wrist_3_link-tool0_fixed_joint"].origin)
        @ model.joints["ee_fixed_joint"].origin
    )
    np.testing.assert_allclose(arm.tool, T_tool0_ee, atol=1e-12)
    assert fk_error(UR10, arm, random_q(6, seed=1)) < 1e-9


def test_franka_urdf_fk_equals_mdh_and_the_published_model() -> None:
    arm = arm_from_urdf(PANDA)
    # the fingers are prismatic: the default tip is the TCP, the deepest non-prismatic leaf
    assert arm.tip_link == "panda_hand_tcp"
    assert arm.joint_names == tuple(f"panda_joint{k}" for k in range(1, 8))
    q = random_q(7)
    assert fk_error(PANDA, arm, q) < 1e-9

    flange = arm_from_urdf(PANDA, tip_link="panda_link8")
    assert fk_error(PANDA, flange, q) < 1e-9
    # The fixture against the project's Franka table (link0 = frame 0, link8 = frame 7);
    # to 5e-7 because franka_description writes pi/2 as 1.5707963 (2.7e-8 rad short, six
    # times over).
    np.testing.assert_allclose(
        urdf_chain_pose(PANDA, q, tip_link="panda_link8"),
        forward_kinematics(MDHTable.franka_fr3(), q),
        atol=5e-7,
    )
    # Franka's table points x1 along +x of link0 (alpha1 = -pi/2); the reader's x1 is
    # z0 x z1 = -x (alpha1 = +pi/2). Every x axis is therefore mirrored: d and theta
    # agree, a and alpha change sign, and base and tool are turns by pi about z.
    fr3 = MDHTable.franka_fr3()
    np.testing.assert_allclose(flange.mdh.d, fr3.d, atol=1e-7)
    np.testing.assert_allclose(flange.mdh.a, -fr3.a, atol=1e-7)
    np.testing.assert_allclose(flange.mdh.alpha, -fr3.alpha, atol=1e-7)
    np.testing.assert_allclose(flange.mdh.theta_offset, 0.0, atol=1e-7)
    np.testing.assert_allclose(flange.base, rot_z(np.pi), atol=1e-7)
    np.testing.assert_allclose(flange.tool, rot_z(np.pi), atol=1e-7)

    # link7 carries link8 and the hand (fixed); the fingers move and are not counted
    np.testing.assert_allclose(arm.masses, [2.74, 2.74, 2.38, 2.38, 2.74, 1.55, 0.54 + 0.73])
    assert arm.lower[3] == pytest.approx(-3.0718) and arm.upper[5] == pytest.approx(3.7525)


def test_mdh_table_round_trips_through_urdf(tmp_path: Path) -> None:
    nominal = MDHTable.ur_like_6dof()
    # beta on both parallel rows, theta offsets, a tilted wrist: every value the reader's
    # conventions can hold exactly (d = 0 on parallel rows, theta1 = 0, last row z-only)
    delta = {
        "beta2": 0.004,
        "beta3": -0.003,
        "theta2": -0.002,
        "theta3": 0.01,
        "theta4": -0.005,
        "theta5": 0.012,
        "alpha4": 0.02,
        "alpha5": -0.01,
        "d4": 0.002,
        "d5": -0.003,
        "d6": 0.001,
        "a1": 0.001,
        "a2": 0.003,
        "a4": 0.002,
        "a5": -0.004,
    }
    values = nominal.param_dict()
    perturbed = nominal.with_params([values[k] + v for k, v in delta.items()], list(delta))
    assert perturbed.parallel_rows[1] and perturbed.beta[1] != 0.0
    for k, table in enumerate((nominal, perturbed)):
        path = write_mdh_urdf(tmp_path / f"arm{k}.urdf", table)
        arm = arm_from_urdf(path)
        assert arm.tip_link == "flange"
        assert arm.mdh.isclose(table, atol=1e-9), arm.mdh.params() - table.params()
        np.testing.assert_allclose(arm.base, np.eye(4), atol=1e-12)
        np.testing.assert_allclose(arm.tool, np.eye(4), atol=1e-12)
        q = random_q(6, seed=k)
        np.testing.assert_allclose(
            urdf_chain_pose(path, q), forward_kinematics(table, q), rtol=0, atol=1e-9
        )
        assert fk_error(path, arm, q) < 1e-9


def test_any_mdh_table_and_mount_give_the_same_fk(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    nominal = MDHTable.ur_like_6dof()
    for k in range(3):
        table = nominal.with_params(nominal.params() + rng.normal(0.0, 5e-3, 30))
        mount = np.eye(4)
        mount[:3, :3] = Rotation.random(random_state=k).as_matrix()
        mount[:3, 3] = rng.normal(0.0, 0.5, 3)
        path = write_mdh_urdf(tmp_path / f"arm{k}.urdf", table, mount)
        arm = arm_from_urdf(path)
        q = random_q(6, seed=10 + k)
        np.testing.assert_allclose(
            urdf_chain_pose(path, q), forward_kinematics(table, q, mount), atol=1e-9
        )
        assert fk_error(path, arm, q) < 1e-9


def test_simulated_arm_urdf_parses_back_to_its_table(tmp_path: Path) -> None:
    params = ArmParams()
    path = tmp_path / "arm.urdf"
    path.write_text(urdf_from_arm_params(params))
    arm = arm_from_urdf(path, tip_link="flange")
    assert arm.mdh.isclose(params.mdh, atol=1e-9)
    np.testing.assert_allclose(arm.masses[:5], params.link_masses[:5])
    assert fk_error(path, arm, random_q(6)) < 1e-9
    camera = arm_from_urdf(path)  # the camera link is the deepest leaf
    assert camera.tip_link == "camera"
    # the last frame moves along axis 6 to the foot of the camera's origin: the camera's
    # offset along the axis goes into d6, the tool keeps the rest
    T_flange_camera = params.camera.T_flange_camera()
    assert camera.mdh.d[5] == pytest.approx(params.mdh.d[5] + T_flange_camera[2, 3], abs=1e-12)
    expected_tool = T_flange_camera.copy()
    expected_tool[2, 3] = 0.0
    np.testing.assert_allclose(camera.tool, expected_tool, atol=1e-12)
    assert fk_error(path, camera, random_q(6)) < 1e-9


def test_random_chains_with_parallel_and_intersecting_axes(tmp_path: Path) -> None:
    for seed in range(5):
        path = write_random_chain(tmp_path / f"chain{seed}.urdf", np.random.default_rng(seed))
        arm = arm_from_urdf(path)
        assert arm.base_link == "world" and arm.tip_link == "tip"
        # axes 2-3 parallel and 3-4 nearly so: Hayati rows (d = 0), twists of 0 and ~0.01
        assert arm.mdh.d[1] == 0.0 and arm.mdh.d[2] == 0.0
        assert arm.mdh.parallel_rows[1]
        assert 1e-4 < np.hypot(arm.mdh.alpha[2], arm.mdh.beta[2]) < 0.05
        assert abs(arm.mdh.beta[0]) < 1e-12 and abs(arm.mdh.beta[3]) < 1e-12
        assert arm.lower[1] == -np.inf  # continuous
        assert fk_error(path, arm, random_q(6, seed=seed)) < 1e-9


def test_single_configuration_and_batch_agree() -> None:
    q = random_q(6, count=3)
    batch = urdf_chain_pose(UR10, q, tip_link="tool0")
    assert batch.shape == (3, 4, 4)
    np.testing.assert_allclose(urdf_chain_pose(UR10, q[1], tip_link="tool0"), batch[1])
    arm = arm_from_urdf(UR10, tip_link="tool0")
    np.testing.assert_allclose(arm.pose(q[1]), batch[1], atol=1e-12)
    with pytest.raises(ValueError, match=r"shape \(6,\)"):
        urdf_chain_pose(UR10, np.zeros(5), tip_link="tool0")


# --------------------------------------------------------------------------- wheels
def test_kobuki_differential_drive() -> None:
    wheels = wheels_from_urdf(KOBUKI)
    assert wheels.base_link == "base_link"
    assert (wheels.left_joint, wheels.right_joint) == ("wheel_left_joint", "wheel_right_joint")
    assert wheels.drive == "diffdrive" and wheels.n_wheels == 2  # casters excluded
    assert wheels.radius_left == pytest.approx(0.035, abs=1e-12)
    assert wheels.radius_right == pytest.approx(0.035, abs=1e-12)
    assert wheels.track == pytest.approx(0.230, abs=1e-12)
    np.testing.assert_allclose(wheels.wheel_x, [0.0, 0.0], atol=1e-12)
    params = wheels.params()
    assert params == pytest.approx(
        {"wheel_radius_left": 0.035, "wheel_radius_right": 0.035, "wheelbase": 0.230}
    )
    assert set(params) <= {f.name for f in dataclasses.fields(DiffDriveParams)}
    assert DiffDriveParams(**params).wheelbase == pytest.approx(0.230)
    # the footprint sits 0.0102 m below base_link: lateral measures do not change
    footprint = wheels_from_urdf(KOBUKI, base_link="base_footprint")
    assert footprint.track == pytest.approx(0.230) and footprint.radius_left == 0.035


def test_kobuki_with_unequal_wheels(tmp_path: Path) -> None:
    text = KOBUKI.read_text()
    left = '<cylinder length="0.0206" radius="0.035"/>'
    assert text.count(left) == 1  # the right wheel's is written 0.0350
    path = tmp_path / "kobuki_unequal.urdf"
    path.write_text(text.replace(left, '<cylinder length="0.0206" radius="0.0362"/>'))
    wheels = wheels_from_urdf(path)
    assert wheels.radius_left == pytest.approx(0.0362)
    assert wheels.radius_right == pytest.approx(0.035)
    assert wheels.track == pytest.approx(0.230)
    named = wheels_from_urdf(path, left_joint="wheel_left_joint", right_joint="wheel_right_joint")
    assert named.params() == pytest.approx(wheels.params())


def test_wheel_radius_from_visual_when_no_collision(tmp_path: Path) -> None:
    text = KOBUKI.read_text().replace(
        '<collision><geometry><cylinder length="0.0206" radius="0.0350"/></geometry>',
        '<visual><geometry><cylinder length="0.0206" radius="0.0345"/></geometry>',
    )
    # the closing tag of that element follows its origin
    text = text.replace(
        '<origin rpy="0 0 0" xyz="0 0 0"/></collision>\n    <inertial><mass value="0.01"/>'
        '<origin xyz="0 0 0"/>\n      <inertia ixx="0.001" ixy="0.0" ixz="0.0" iyy="0.001" '
        'iyz="0.0" izz="0.001"/></inertial>\n  </link>\n  <joint name="caster_front_joint"',
        '<origin rpy="0 0 0" xyz="0 0 0"/></visual>\n  </link>\n  <joint name="caster_front_joint"',
    )
    path = tmp_path / "kobuki_visual.urdf"
    path.write_text(text)
    assert wheels_from_urdf(path).radius_right == pytest.approx(0.0345)


def test_husky_skid_steer() -> None:
    wheels = wheels_from_urdf(HUSKY)
    assert wheels.drive == "skid_steer" and wheels.n_wheels == 4
    assert wheels.track == pytest.approx(0.5708, abs=1e-12)
    assert wheels.radius_left == pytest.approx(0.1651) and wheels.radius_right == 0.1651
    assert (wheels.left_joint, wheels.right_joint) == ("front_left_wheel", "front_right_wheel")
    assert sorted(wheels.wheel_x) == pytest.approx([-0.256, -0.256, 0.256, 0.256])
    assert max(wheels.wheel_x) - min(wheels.wheel_x) == pytest.approx(0.512)
    assert wheels.params()["wheelbase"] == pytest.approx(0.5708)


# --------------------------------------------------------------------------- errors
def write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_doctype_and_entities_are_refused(tmp_path: Path) -> None:
    bomb = (
        '<?xml version="1.0"?>\n<!DOCTYPE robot [<!ENTITY a "aaaaaaaaaa">'
        '<!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">]>\n'
        '<robot name="r"><link name="&b;"/></robot>\n'
    )
    path = write(tmp_path, "bomb.urdf", bomb)
    with pytest.raises(UrdfError, match=r"bomb\.urdf.*DOCTYPE"):
        parse_urdf(path)
    with pytest.raises(ValueError, match="DOCTYPE"):
        wheels_from_urdf(path)


def test_missing_directory_and_oversized_files(tmp_path: Path, monkeypatch) -> None:
    with pytest.raises(ValueError, match=r"nope\.urdf: file: expected an existing URDF file"):
        arm_from_urdf(tmp_path / "nope.urdf")
    with pytest.raises(ValueError, match="expected a regular file, got a directory"):
        parse_urdf(tmp_path)
    monkeypatch.setattr(urdf_module, "MAX_URDF_BYTES", 1000)
    with pytest.raises(ValueError, match="at most 1000 bytes"):
        parse_urdf(UR10)


def test_documents_that_are_not_urdf(tmp_path: Path) -> None:
    launch = write(tmp_path, "a.launch", '<launch><node pkg="x" type="y"/></launch>')
    with pytest.raises(ValueError, match=r"expected <robot> \(a URDF\), got <launch>"):
        parse_urdf(launch)
    broken = write(tmp_path, "broken.urdf", '<robot name="r"><link name="a"></robot>')
    with pytest.raises(ValueError, match="well-formed XML"):
        parse_urdf(broken)
    xacro = write(
        tmp_path,
        "x.urdf",
        '<robot name="r"><link name="a"/><link name="b"/><joint name="j" type="revolute">'
        '<parent link="a"/><child link="b"/><origin xyz="0 0 ${d1}"/></joint></robot>',
    )
    with pytest.raises(ValueError, match=r"joint 'j' <origin xyz>.*xacro"):
        parse_urdf(xacro)


def test_joint_with_missing_parent_link(tmp_path: Path) -> None:
    text = UR10.read_text().replace('<parent link="forearm_link"/>', '<parent link="forearm"/>')
    path = write(tmp_path, "ur10_bad.urdf", text)
    with pytest.raises(
        ValueError, match=r"joint 'wrist_1_joint' <parent>.*'forearm', which is not defined"
    ):
        arm_from_urdf(path)


def test_two_roots_are_refused(tmp_path: Path) -> None:
    path = write(tmp_path, "two.urdf", '<robot name="r"><link name="a"/><link name="b"/></robot>')
    with pytest.raises(ValueError, match=r"exactly one root link.*2 roots"):
        parse_urdf(path)


def test_no_wheel_pair_lists_the_joints(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"left/right pair.*'shoulder_pan_joint' \(revolute"):
        wheels_from_urdf(UR10)
    text = KOBUKI.read_text().replace(
        'type="continuous">\n    <parent link="base_link"/>\n    <child link="wheel_right_link"/>',
        'type="fixed">\n    <parent link="base_link"/>\n    <child link="wheel_right_link"/>',
    )
    path = write(tmp_path, "one_wheel.urdf", text)
    with pytest.raises(ValueError, match=r"1 left and 0 right.*'wheel_right_joint' \(fixed"):
        wheels_from_urdf(path)


def test_wrong_named_wheel_and_wheel_without_radius(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"left_joint 'wheel_right_joint'.*y = -0\.115"):
        wheels_from_urdf(KOBUKI, left_joint="wheel_right_joint")
    with pytest.raises(ValueError, match=r"left_joint 'nope'.*no such joint"):
        wheels_from_urdf(KOBUKI, left_joint="nope")
    text = HUSKY.read_text().replace(
        '<collision><origin xyz="0 0 0" rpy="1.5707963267948966 0 0"/>'
        '<geometry><cylinder length="0.1143" radius="0.1651"/></geometry></collision>',
        "",
        1,
    )
    path = write(tmp_path, "husky_mesh.urdf", text)
    with pytest.raises(ValueError, match=r"link 'front_left_wheel_link'.*cylinder or sphere"):
        wheels_from_urdf(path)


def test_prismatic_joint_in_the_chain(tmp_path: Path) -> None:
    text = (
        '<robot name="r"><link name="a"/><link name="b"/><link name="c"/><link name="d"/>'
        '<joint name="j1" type="revolute"><parent link="a"/><child link="b"/>'
        '<axis xyz="0 0 1"/><limit lower="-1" upper="1"/></joint>'
        '<joint name="slide" type="prismatic"><parent link="b"/><child link="c"/>'
        '<axis xyz="1 0 0"/><limit lower="0" upper="1"/></joint>'
        '<joint name="j3" type="revolute"><parent link="c"/><child link="d"/>'
        '<axis xyz="0 1 0"/><limit lower="-1" upper="1"/></joint></robot>'
    )
    path = write(tmp_path, "slide.urdf", text)
    with pytest.raises(ValueError, match=r"joint 'slide'.*revolute arms only.*prismatic"):
        arm_from_urdf(path)
    with pytest.raises(ValueError, match="revolute arms only"):
        urdf_chain_pose(path, np.zeros(2))
    assert arm_from_urdf(path, tip_link="b").joint_names == ("j1",)  # before the slide
    with pytest.raises(ValueError, match=r"tip_link 'zz'.*no such link"):
        arm_from_urdf(path, tip_link="zz")
