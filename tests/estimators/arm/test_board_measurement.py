"""Camera pose and hierarchical displacement from rendered images of the coded board."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.estimators.arm.board_displacement import (
    cell_under_optical_axis,
    hierarchical_displacement,
    transition_pose,
)
from realitygap.estimators.arm.board_measurement import (
    BoardMeasurementSettings,
    MeasurementStatus,
    measure_board,
)
from realitygap.estimators.arm.coded_board import CodedBoard, render_board_image

K = np.array([[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]])
SIZE = (640, 480)


@pytest.fixture(scope="module")
def board() -> CodedBoard:
    return CodedBoard()


def camera_pose(target_xy, distance, tilt, tilt_dir, spin) -> np.ndarray:
    """T_board_camera looking at board point ``target_xy`` from ``distance`` m.

    The optical axis points into the board (+z of the board frame)."""
    R = (
        Rotation.from_rotvec(tilt * np.array([np.cos(tilt_dir), np.sin(tilt_dir), 0.0]))
        * Rotation.from_euler("z", spin)
    ).as_matrix()
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.array([*target_xy, 0.0]) - distance * R[:, 2]
    return T


def render(board, T_board_camera, rng, dist=None, blur=1.0, noise=2.0) -> np.ndarray:
    return render_board_image(
        board,
        K,
        np.linalg.inv(T_board_camera),
        SIZE,
        dist,
        blur_sigma_px=blur,
        noise_std=noise,
        rng=rng,
    )


def test_pose_accuracy_at_0_3_m(board: CodedBoard) -> None:
    rng = np.random.default_rng(0)
    errors = []
    for _ in range(6):
        T = camera_pose(
            rng.uniform(0.2, 0.8, 2),
            0.3,
            rng.uniform(0, 0.4),
            rng.uniform(0, 6.3),
            rng.uniform(-3, 3),
        )
        obs = measure_board(render(board, T, rng), K, None, board)
        assert obs.ok, obs.status
        assert obs.cell_index == cell_under_optical_axis(T, board.cell_size)
        assert obs.n_corners > 100 and obs.reprojection_rms_px < 0.2
        assert obs.code_mismatches == 0
        errors.append(np.linalg.norm(obs.camera_position_board - T[:3, 3]))
        # the pose in the centre-cell frame is the same pose, shifted by whole cells
        r, c = obs.cell_index
        np.testing.assert_allclose(
            obs.camera_position_cell + np.array([c * 0.02, r * 0.02, 0.0]),
            obs.camera_position_board,
            atol=1e-12,
        )
    assert max(errors) < 0.2e-3


def test_pose_with_lens_distortion(board: CodedBoard) -> None:
    rng = np.random.default_rng(1)
    dist = np.array([-0.15, 0.06, 0.0005, -0.0004, 0.0])
    T = camera_pose((0.43, 0.61), 0.3, 0.3, 1.0, 0.7)
    obs = measure_board(render(board, T, rng, dist=dist), K, dist, board)
    assert obs.ok, obs.status
    assert np.linalg.norm(obs.camera_position_board - T[:3, 3]) < 0.2e-3
    # the same frame read without the distortion model is worse or rejected
    naive = measure_board(render(board, T, rng, dist=dist), K, None, board)
    if naive.ok:
        assert np.linalg.norm(naive.camera_position_board - T[:3, 3]) > 0.2e-3


def test_hierarchical_displacement_and_transition_pose(board: CodedBoard) -> None:
    rng = np.random.default_rng(2)
    T_a = camera_pose((0.313, 0.474), 0.3, 0.2, 0.5, 0.3)
    T_b = camera_pose((0.525, 0.386), 0.28, 0.25, 2.0, -0.4)
    oa = measure_board(render(board, T_a, rng), K, None, board)
    ob = measure_board(render(board, T_b, rng), K, None, board)
    assert oa.ok and ob.ok
    h = hierarchical_displacement(oa, ob, board.cell_size)
    # t is whole cells from the code, t' the in-cell part; together the displacement
    np.testing.assert_allclose(h.t[:2] / board.cell_size, np.round(h.t[:2] / board.cell_size))
    assert h.t[2] == 0.0
    np.testing.assert_allclose(h.delta, h.t + h.t_prime)
    np.testing.assert_allclose(
        h.delta, ob.camera_position_board - oa.camera_position_board, atol=1e-12
    )
    assert np.linalg.norm(h.delta - (T_b[:3, 3] - T_a[:3, 3])) < 0.2e-3
    assert h.cell_shift == (
        ob.cell_index[0] - oa.cell_index[0],
        ob.cell_index[1] - oa.cell_index[1],
    )

    # transition pose: attitude of the target, optical axis in the start cell
    T_t, shift = transition_pose(T_a, T_b, board.cell_size)
    np.testing.assert_allclose(T_t[:3, :3], T_b[:3, :3])
    assert shift == h.cell_shift
    assert cell_under_optical_axis(T_t, board.cell_size) == oa.cell_index
    ot = measure_board(render(board, T_t, rng), K, None, board)
    assert ot.ok and ot.cell_index == oa.cell_index
    via = hierarchical_displacement(oa, ot, board.cell_size).t_prime + np.array(
        [shift[1] * board.cell_size, shift[0] * board.cell_size, 0.0]
    )
    assert np.linalg.norm(via - (T_b[:3, 3] - T_a[:3, 3])) < 0.2e-3


def _plain_checkerboard_image() -> np.ndarray:
    import cv2

    ppc = 64
    i = np.arange(50 * ppc) // ppc
    plain = ((np.add.outer(i, i) % 2) * 215 + 20).astype(np.uint8)
    s = 0.02 / ppc
    A = np.array([[s, 0, 0.5 * s], [0, s, 0.5 * s], [0, 0, 1.0]])
    t = np.array([-0.5, -0.5, 0.3])  # board centre on the optical axis, 0.3 m away
    H = K @ np.column_stack([[1, 0, 0], [0, 1, 0], t]) @ A
    return cv2.warpPerspective(plain, H, SIZE, flags=cv2.INTER_AREA)


def test_frames_that_cannot_be_measured_are_rejected(board: CodedBoard) -> None:
    rng = np.random.default_rng(3)
    cases = {
        MeasurementStatus.LOW_CONTRAST: np.full((480, 640), 128, np.uint8),
        MeasurementStatus.TOO_FEW_CORNERS: rng.integers(0, 256, (480, 640)).astype(np.uint8),
        MeasurementStatus.CODE_NOT_FOUND: _plain_checkerboard_image(),
        # too close: only about 6 x 5 cells in view
        MeasurementStatus.CODE_WINDOW_INCOMPLETE: render(
            board, camera_pose((0.5, 0.5), 0.14, 0.0, 0.0, 0.0), rng
        ),
        # looking past the board's edge
        MeasurementStatus.OPTICAL_AXIS_OFF_BOARD: render(
            board, camera_pose((1.03, 0.5), 0.4, 0.0, 0.0, 0.3), rng
        ),
    }
    for status, img in cases.items():
        obs = measure_board(img, K, None, board)
        assert not obs.ok
        assert obs.status is status, (status, obs.status)
        assert obs.cell_index is None and np.all(np.isnan(obs.T_camera_board))


def test_damaged_code_is_read_correctly_or_rejected(board: CodedBoard) -> None:
    import cv2

    rng = np.random.default_rng(4)
    T = camera_pose((0.37, 0.66), 0.3, 0.15, 0.4, 1.1)
    T_cb = np.linalg.inv(T)
    truth = cell_under_optical_axis(T, board.cell_size)
    for n_damaged in (1, 2, 40, 120):
        img = render(board, T, rng)
        cells = rng.integers(0, 50, (n_damaged, 2))
        for r, c in cells:  # paint a random grey blob over the code dot
            p = T_cb[:3, :3] @ np.array([(c + 0.5) * 0.02, (r + 0.5) * 0.02, 0]) + T_cb[:3, 3]
            u, v = (K @ p)[:2] / p[2]
            if 0 <= u < 640 and 0 <= v < 480:
                cv2.circle(img, (int(u), int(v)), 6, int(rng.integers(0, 256)), -1)
        obs = measure_board(img, K, None, board)
        if n_damaged <= 2:
            assert obs.ok, obs.status
        if obs.ok:  # never a wrong cell
            assert obs.cell_index == truth
            assert np.linalg.norm(obs.camera_position_board - T[:3, 3]) < 0.5e-3


def test_local_pnp_window(board: CodedBoard) -> None:
    rng = np.random.default_rng(5)
    T = camera_pose((0.6, 0.25), 0.3, 0.2, 2.5, -1.0)
    img = render(board, T, rng)
    full = measure_board(img, K, None, board)
    local = measure_board(img, K, None, board, BoardMeasurementSettings(pnp_window_cells=4))
    assert full.ok and local.ok
    assert local.n_corners < full.n_corners
    assert local.cell_index == full.cell_index
    assert np.linalg.norm(local.camera_position_board - T[:3, 3]) < 0.5e-3


def test_input_validation(board: CodedBoard) -> None:
    img = np.zeros((480, 640), np.uint8)
    with pytest.raises(ValueError, match="3x3 camera matrix"):
        measure_board(img, np.eye(2), None, board)
    with pytest.raises(ValueError, match="OpenCV coefficients"):
        measure_board(img, K, np.zeros(3), board)
    with pytest.raises(ValueError, match=r"shape \(H, W\)"):
        measure_board(np.zeros((4, 480, 640)), K, None, board)
    with pytest.raises(ValueError, match="subpix_window_fraction"):
        BoardMeasurementSettings(subpix_window_fraction=0.5)
    with pytest.raises(ValueError, match="min_corners"):
        BoardMeasurementSettings(min_corners=3)
    bad = measure_board(img, K, None, board)
    with pytest.raises(ValueError, match="not a successful measurement"):
        hierarchical_displacement(bad, bad, board.cell_size)
