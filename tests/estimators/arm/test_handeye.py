"""Hand–eye calibration: circle/plane fits, single-axis, two-axis and AX = XB."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.core.geometry import transform_from_rt
from realitygap.estimators.arm.handeye import (
    average_transforms,
    fit_circle_3d,
    fit_plane,
    handeye_single_axis,
    handeye_two_axis,
    solve_ax_xb,
)
from realitygap.estimators.arm.mdh import MDHTable, forward_kinematics

TABLE = MDHTable.ur_like_6dof()
Q0 = np.array([0.2, -1.2, 1.3, -1.6, -1.5, 0.3])


def _transform(rotvec, t) -> np.ndarray:
    return transform_from_rt(Rotation.from_rotvec(rotvec).as_matrix(), t)


X_TRUE = _transform([0.1, -0.2, 1.5], [0.06, -0.03, 0.05])  # T_flange_camera
T_BOARD_BASE = _transform([0.0, 0.0, 0.3], [-0.4, -0.2, 0.05])


def camera_poses(q: np.ndarray, rng=None, noise_m: float = 0.0) -> np.ndarray:
    T = T_BOARD_BASE @ forward_kinematics(TABLE, q) @ X_TRUE
    if noise_m > 0 and rng is not None:
        T = T.copy()
        T[:, :3, 3] += rng.normal(0.0, noise_m, (len(T), 3))
        for k in range(len(T)):
            dR = Rotation.from_rotvec(rng.normal(0.0, 3 * noise_m, 3)).as_matrix()
            T[k, :3, :3] = T[k, :3, :3] @ dR
    return T


def sweep(joint: int, angles: np.ndarray) -> np.ndarray:
    q = np.tile(Q0, (len(angles), 1))
    q[:, joint] = angles
    return q


def test_plane_and_circle_fits_are_exact() -> None:
    rng = np.random.default_rng(0)
    n = Rotation.from_rotvec([0.3, -0.5, 0.2]).apply([0, 0, 1.0])
    u = np.cross(n, [1.0, 0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    c = np.array([0.1, -0.2, 0.3])
    ang = np.sort(rng.uniform(-1.2, 1.5, 9))
    P = c + 0.07 * (np.cos(ang)[:, None] * u + np.sin(ang)[:, None] * v)
    _, normal, rms = fit_plane(P)
    assert abs(abs(normal @ n) - 1) < 1e-12 and rms < 1e-12
    fit = fit_circle_3d(P, ang)
    np.testing.assert_allclose(fit.centre, c, atol=1e-12)
    np.testing.assert_allclose(fit.normal, n, atol=1e-12)  # counter-clockwise about n
    assert fit.radius == pytest.approx(0.07, abs=1e-12)
    assert fit_circle_3d(P, -ang).normal @ n == pytest.approx(-1.0)
    with pytest.raises(ValueError, match="collinear"):
        fit_plane(np.outer(np.arange(5.0), [1.0, 2.0, 3.0]))


def test_single_axis_recovers_x_exactly() -> None:
    q6 = np.linspace(-1.5, 1.5, 9)
    q_zero = Q0.copy()
    q_zero[5] = 0.0
    F0 = T_BOARD_BASE @ forward_kinematics(TABLE, q_zero)[0]
    res = handeye_single_axis(camera_poses(sweep(5, q6)), q6, F0)
    np.testing.assert_allclose(res.T_flange_camera, X_TRUE, atol=1e-6)
    assert res.residual_translation_m < 1e-9
    assert res.axes[0].radius == pytest.approx(np.hypot(0.06, -0.03), abs=1e-9)


def test_two_axis_recovers_x_and_the_flange_without_the_board_pose() -> None:
    q5 = np.linspace(-2.2, -0.8, 7)
    q6 = np.linspace(-1.5, 1.5, 7)
    res = handeye_two_axis(
        camera_poses(sweep(4, q5)), q5, Q0[5], camera_poses(sweep(5, q6)), q6, Q0[4], TABLE
    )
    np.testing.assert_allclose(res.T_flange_camera, X_TRUE, atol=1e-6)
    F_ref = T_BOARD_BASE @ forward_kinematics(TABLE, Q0)[0]
    np.testing.assert_allclose(res.T_board_flange, F_ref, atol=1e-6)


def test_ax_xb_recovers_x_and_board_pose() -> None:
    rng = np.random.default_rng(1)
    q = rng.uniform(-2, 2, (12, 6))
    res = solve_ax_xb(forward_kinematics(TABLE, q), camera_poses(q), method="park")
    np.testing.assert_allclose(res.T_flange_camera, X_TRUE, atol=1e-6)
    np.testing.assert_allclose(res.T_base_board, np.linalg.inv(T_BOARD_BASE), atol=1e-6)
    if hasattr(cv2, "calibrateHandEye"):
        cv_res = solve_ax_xb(forward_kinematics(TABLE, q), camera_poses(q), "opencv_park")
        np.testing.assert_allclose(cv_res.T_flange_camera, X_TRUE, atol=1e-6)
    else:
        with pytest.raises(RuntimeError, match="calibrateHandEye"):
            solve_ax_xb(forward_kinematics(TABLE, q), camera_poses(q), "opencv_tsai")


@pytest.mark.parametrize("method", ["single", "two", "axxb"])
def test_noise_degrades_gracefully(method: str) -> None:
    errs = []
    for noise in (1e-5, 1e-4, 1e-3):
        rng = np.random.default_rng(2)
        q6 = np.linspace(-1.5, 1.5, 15)
        if method == "single":
            q_zero = Q0.copy()
            q_zero[5] = 0.0
            F0 = T_BOARD_BASE @ forward_kinematics(TABLE, q_zero)[0]
            X = handeye_single_axis(camera_poses(sweep(5, q6), rng, noise), q6, F0)
        elif method == "two":
            q5 = np.linspace(-2.2, -0.8, 15)
            X = handeye_two_axis(
                camera_poses(sweep(4, q5), rng, noise),
                q5,
                Q0[5],
                camera_poses(sweep(5, q6), rng, noise),
                q6,
                Q0[4],
                TABLE,
            )
        else:
            q = rng.uniform(-2, 2, (15, 6))
            X = solve_ax_xb(forward_kinematics(TABLE, q), camera_poses(q, rng, noise))
        errs.append(np.linalg.norm(X.T_flange_camera[:3, 3] - X_TRUE[:3, 3]))
    assert errs[0] < 1e-3 and errs[1] < 5e-3
    assert errs[0] < errs[1] < errs[2]  # error grows with the noise, no breakdown
    assert errs[2] < 0.05


def test_average_transforms_of_identical_poses() -> None:
    Ts = np.stack([X_TRUE] * 4)
    np.testing.assert_allclose(average_transforms(Ts), X_TRUE, atol=1e-14)


def test_errors() -> None:
    q6 = np.zeros(5)
    poses = camera_poses(sweep(5, q6))
    with pytest.raises(ValueError, match="must vary"):
        handeye_single_axis(poses, q6, np.eye(4))
    with pytest.raises(ValueError, match="one joint angle per pose"):
        handeye_single_axis(poses, np.zeros(4), np.eye(4))
    with pytest.raises(ValueError, match=r"\(N, 4, 4\)"):
        solve_ax_xb(np.zeros((5, 3, 3)), poses)
    with pytest.raises(ValueError, match="same number of poses"):
        solve_ax_xb(forward_kinematics(TABLE, sweep(5, np.zeros(4))), poses)
    with pytest.raises(ValueError, match="method must be one of"):
        solve_ax_xb(forward_kinematics(TABLE, sweep(5, q6)), poses, "shah")
    # rotations about a single axis only: AX = XB is degenerate
    qs = sweep(5, np.linspace(-1, 1, 5))
    with pytest.raises(ValueError, match="degenerate"):
        solve_ax_xb(forward_kinematics(TABLE, qs), camera_poses(qs), "park")
    parallel = MDHTable.ur_like_6dof().with_params([0.0], ["alpha5"])
    with pytest.raises(ValueError, match="parallel"):
        handeye_two_axis(poses, np.arange(5.0), 0, poses, np.arange(5.0), 0, parallel)
