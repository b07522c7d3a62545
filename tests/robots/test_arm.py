"""The simulated arm: body from the MDH table, drive and encoders, flange camera, effects."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.estimators.arm.board_displacement import cell_under_optical_axis
from realitygap.estimators.arm.board_measurement import measure_board
from realitygap.estimators.arm.coded_board import CodedBoard
from realitygap.estimators.arm.mdh import MDHTable, joint_frames
from realitygap.robots.arm import (
    ArmParams,
    ArmRobot,
    FlangeCameraParams,
    MoveOutcome,
    flange_load_torques,
    urdf_from_arm_params,
)
from realitygap.robots.arm_cell import BoardPlacement, build_arm_scene
from realitygap.robots.effects import EFFECTS, Reality, make_effect
from realitygap.robots.sensors import SensorMode
from realitygap.robots.world import GRAVITY, World

HOME = np.array([0.0, -1.3, 1.6, -1.87, -1.57, 0.0])
BOARD = CodedBoard()


def scene(params: ArmParams | None = None, textured: bool = False):
    w = World()
    robot, cam = build_arm_scene(
        w, params or ArmParams(), BOARD, BoardPlacement(), textured=textured
    )
    return w, robot, cam


def perturbed_table(rng: np.random.Generator) -> MDHTable:
    nom = MDHTable.ur_like_6dof()
    d = rng.normal(0.0, 2e-3, 30)
    return nom.with_params(nom.params() + d)


def test_body_link_frames_equal_mdh_forward_kinematics() -> None:
    rng = np.random.default_rng(0)
    table = perturbed_table(rng)  # every parameter off nominal, beta included
    params = ArmParams(mdh=table)
    w, robot, _ = scene(params)
    try:
        for _ in range(10):
            q = rng.uniform(-np.pi, np.pi, 6)
            robot.set_link_angles(q)
            expected = joint_frames(table, q, params.T_world_base)[0]
            np.testing.assert_allclose(robot.mdh_frames(), expected, atol=1e-6)
            np.testing.assert_allclose(robot.link_pose("flange"), expected[-1], atol=1e-6)
            np.testing.assert_allclose(
                robot.T_world_camera(),
                expected[-1] @ params.camera.T_flange_camera(),
                atol=1e-6,
            )
    finally:
        w.close()


@pytest.mark.parametrize(("beta2", "beta3"), [(0.0, 0.0), (4e-3, 0.0), (0.0, -3e-3)])
def test_beta_effect_tilts_the_parallel_axes_in_the_body(beta2: float, beta3: float) -> None:
    rng = np.random.default_rng(1)
    reality = Reality((make_effect("arm_parallel_twist", beta2=beta2, beta3=beta3),))
    params = reality.apply_params(ArmParams())
    assert params.mdh.beta[1] == beta2 and params.mdh.beta[2] == beta3
    w, robot, _ = scene(params)
    try:
        for _ in range(5):
            robot.set_link_angles(rng.uniform(-np.pi, np.pi, 6))
            # the URDF link<k> frame's z axis is the axis of joint k
            z2, z3, z4 = (robot.link_pose(f"link{k}")[:3, 2] for k in (2, 3, 4))
            ang23 = np.arctan2(np.linalg.norm(np.cross(z2, z3)), z2 @ z3)
            ang34 = np.arctan2(np.linalg.norm(np.cross(z3, z4)), z3 @ z4)
            assert ang23 == pytest.approx(abs(beta2), abs=2e-7)
            assert ang34 == pytest.approx(abs(beta3), abs=2e-7)
    finally:
        w.close()


def test_urdf_folds_constant_transforms_into_joint_origins() -> None:
    table = MDHTable.ur_like_6dof().with_params([0.01, 2e-3], ["theta2", "beta2"])
    text = urdf_from_arm_params(ArmParams(mdh=table))
    assert text.count('type="revolute"') == 6
    assert 'name="camera_joint" type="fixed"' in text and 'name="flange_joint"' in text
    assert "capsule" in text


@pytest.mark.parametrize("mode", ["image", "fast"])
def test_board_seen_from_a_known_pose_decodes_to_the_right_cell(mode: str) -> None:
    cam_params = FlangeCameraParams(supersample=2)
    w, robot, cam = scene(ArmParams(camera=cam_params), textured=(mode == "image"))
    try:
        assert robot.move_to(HOME + np.array([0.1, 0.05, -0.1, 0.05, 0.1, 0.7])).ok
        img = cam.capture(mode, np.random.default_rng(2))
        assert img.shape == (480, 640) and img.dtype == np.uint8
        obs = measure_board(img, cam_params.K, None, BOARD)
        assert obs.ok, obs.status
        T_board_camera = np.linalg.inv(cam.T_camera_board())
        assert obs.cell_index == cell_under_optical_axis(T_board_camera, BOARD.cell_size)
        assert obs.code_mismatches == 0
        err = np.linalg.norm(obs.camera_position_board - T_board_camera[:3, 3])
        assert err < 0.1e-3, err
    finally:
        w.close()


def test_geometric_capture_reports_the_projected_corners() -> None:
    w, robot, cam = scene(ArmParams(camera=FlangeCameraParams(corner_noise_px=0.0)))
    try:
        robot.reset(HOME)
        uv, ids = cam.visible_corners()
        assert len(uv) > 100 and ids.shape == (len(uv), 2)
        T = cam.T_camera_board()
        X = np.column_stack([ids[:, 1] * 0.02, ids[:, 0] * 0.02, np.zeros(len(ids))])
        Xc = X @ T[:3, :3].T + T[:3, 3]
        K = cam.params.K
        np.testing.assert_allclose(Xc[:, :2] / Xc[:, 2:] @ K[:2, :2].T + K[:2, 2], uv, atol=1e-6)
        with pytest.raises(ValueError, match="visible_corners"):
            cam.capture(SensorMode.GEOMETRIC, np.random.default_rng(0))
    finally:
        w.close()


def test_moves_out_of_reach_and_into_collision_are_refused() -> None:
    params = ArmParams(joint_upper=(2.0, 0.0, 2.5, 0.0, 0.0, 4.0))
    w, robot, _ = scene(params)
    try:
        robot.reset(HOME)
        out = robot.move_to(HOME + np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0]))
        assert out.outcome is MoveOutcome.OUT_OF_REACH and "joint(s) [3]" in out.message
        before = robot.joint_positions()
        hit = robot.move_to([0.0, -0.2, 1.6, -1.87, -1.57, 0.0])  # forearm into the table
        assert hit.outcome is MoveOutcome.COLLISION and "floor" in hit.message
        np.testing.assert_allclose(robot.joint_positions(), before, atol=1e-9)
        np.testing.assert_array_equal(robot.q_cmd, HOME)
        with pytest.raises(ValueError, match="finite"):
            robot.move_to([np.nan] * 6)
        with pytest.raises(ValueError, match=r"shape \(6,\)"):
            robot.move_to([0.0] * 5)
    finally:
        w.close()


def test_encoders_quantise_and_settle_on_the_command() -> None:
    params = ArmParams()
    w, robot, _ = scene(params)
    try:
        robot.reset(HOME)
        assert robot.move_to(HOME + 0.05).ok
        q = robot.read_encoders(np.random.default_rng(3))
        res = params.encoder_resolution
        np.testing.assert_allclose(q / res, np.round(q / res), atol=1e-6)
        # the servo holds the nominal arm within a few encoder counts of the command
        assert np.max(np.abs(q - (HOME + 0.05))) < 2e-5
        np.testing.assert_array_equal(robot.read_encoders(None), robot.read_encoders(None))
    finally:
        w.close()


def test_backlash_compliance_and_encoder_scale_are_realised() -> None:
    reality = Reality(
        (
            make_effect("arm_backlash", b2=2e-3),
            make_effect("arm_joint_compliance", c2=2e-5),
            make_effect("arm_encoder_scale", s4=1.001),
        )
    )
    params = reality.apply_params(ArmParams(encoder_noise_std=0.0))
    w, robot, _ = scene(params)
    try:
        target = HOME.copy()
        robot.reset(target - 0.1)
        assert robot.move_to(target).ok  # approach from below
        up = robot.joint_positions()
        robot.move_to(target + 0.1)
        assert robot.move_to(target).ok  # approach from above
        down = robot.joint_positions()
        tau = robot.gravity_torques(up)
        # backlash: same command, two link angles b apart on joint 2
        assert down[1] - up[1] == pytest.approx(2e-3, abs=2e-5)
        # compliance: the link sags by c * holding torque (plus half the play)
        assert abs(2e-5 * tau[1]) > 2e-4
        assert up[1] - target[1] == pytest.approx(-2e-5 * tau[1] - 1e-3, abs=2e-5)
        # encoder scale: the motor turns q / s for a reading q
        assert up[3] == pytest.approx(target[3] / 1.001, abs=2e-5)
        # the motor-side reading still equals the command
        np.testing.assert_allclose(robot.read_encoders(None), target, atol=3e-5)
    finally:
        w.close()


@pytest.mark.parametrize("table", [MDHTable.ur10(), MDHTable.ur_like_6dof()])
def test_flange_load_torques_are_the_gradient_of_the_loads_potential_energy(
    table: MDHTable,
) -> None:
    # a kilogram at the flange has potential energy g·z(q); the torque holding it is ∂U/∂q
    rng = np.random.default_rng(4)
    q = rng.uniform(-2.5, 2.5, (12, 6))
    tau = flange_load_torques(table, q)
    h = 1e-6
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = h
        z_up = joint_frames(table, q + dq)[:, -1, 2, 3]
        z_dn = joint_frames(table, q - dq)[:, -1, 2, 3]
        np.testing.assert_allclose(tau[:, j], GRAVITY * (z_up - z_dn) / (2 * h), atol=1e-6)
    assert np.all(tau[:, 0] == pytest.approx(0.0, abs=1e-9))  # the base axis is vertical


def test_a_flange_load_adds_its_torques_to_the_bodys_and_sags_a_compliant_joint() -> None:
    table = MDHTable.ur10()
    q = np.array([0.3, -0.4, 0.9, -1.2, 1.1, 0.2])
    w = World()
    try:
        bare = ArmRobot(w, ArmParams(mdh=table)).gravity_torques(q)
    finally:
        w.close()
    reality = Reality((make_effect("arm_joint_compliance", c2=2e-5, dm=3.0),))
    loaded = reality.apply_params(ArmParams(mdh=table))
    assert loaded.flange_load == 3.0 and loaded.joint_compliance[1] == 2e-5
    w = World()
    try:
        robot = ArmRobot(w, loaded)
        np.testing.assert_allclose(
            robot.gravity_torques(q) - bare, 3.0 * flange_load_torques(table, q)[0], atol=1e-9
        )
        sag = q - robot.link_target(q)
        assert sag[1] == pytest.approx(2e-5 * robot.gravity_torques(q - sag)[1], rel=1e-6)
    finally:
        w.close()
    with pytest.raises(ValueError, match="flange_load"):
        ArmParams(flange_load=float("nan"))


def test_handeye_and_intrinsics_effects_change_the_real_camera() -> None:
    nominal = ArmParams()
    he = make_effect("arm_handeye_error", dx=2e-3, drz=0.01)
    params = Reality((he,)).apply_params(nominal)
    delta = params.camera.T_flange_camera()[:3, 3] - nominal.camera.T_flange_camera()[:3, 3]
    np.testing.assert_allclose(delta, [2e-3, 0.0, 0.0], atol=1e-12)
    R = nominal.camera.T_flange_camera()[:3, :3].T @ params.camera.T_flange_camera()[:3, :3]
    assert np.arccos((np.trace(R) - 1) / 2) == pytest.approx(0.01, abs=1e-9)
    intr = make_effect("arm_camera_intrinsics", f_scale=1.01, k1=-0.1)
    cam = intr.apply_params(nominal).camera
    assert cam.fx == pytest.approx(606.0) and cam.dist[0] == pytest.approx(-0.1)
    assert intr.apply_params(nominal).mdh is nominal.mdh


def test_arm_effects_are_in_the_library_with_units_and_bounds() -> None:
    names = {n for n, cls in EFFECTS.items() if cls.robot == "arm"}
    assert {
        "arm_joint_offset",
        "arm_link_length",
        "arm_parallel_twist",
        "arm_twist_error",
        "arm_joint_compliance",
        "arm_backlash",
        "arm_encoder_scale",
        "arm_handeye_error",
        "arm_camera_intrinsics",
    } <= names
    for n in names:
        e = EFFECTS[n]()
        assert e.is_nominal() and e.description
        for s in e.specs:
            assert s.low <= s.nominal <= s.high and s.unit
        assert e.apply_params(ArmParams()).mdh.isclose(MDHTable.ur_like_6dof(), atol=0.0)
    with pytest.raises(TypeError, match="did you mean 'beta2'"):
        make_effect("arm_parallel_twist", beta_2=1e-3)


def test_params_validation() -> None:
    with pytest.raises(ValueError, match="6-joint MDHTable"):
        ArmParams(mdh=MDHTable.franka_fr3())
    with pytest.raises(ValueError, match="joint_lower must be below"):
        ArmParams(joint_lower=(1.0,) * 6, joint_upper=(0.0,) * 6)
    with pytest.raises(ValueError, match="backlash must be >= 0"):
        ArmParams(backlash=(-1e-3,) + (0.0,) * 5)
    with pytest.raises(ValueError, match="encoder_scale must have 6 entries"):
        ArmParams(encoder_scale=(1.0,) * 5)
    with pytest.raises(ValueError, match="fx must be a positive focal length"):
        FlangeCameraParams(fx=-1.0)
    with pytest.raises(ValueError, match="dist must hold 4, 5 or 8"):
        FlangeCameraParams(dist=(0.0, 0.0, 0.0))
