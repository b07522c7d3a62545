"""Rotations and rigid transforms of realitygap.core.geometry against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.core import geometry
from realitygap.core.geometry import (
    hat,
    hat_batch,
    matrix_from_quat_xyzw,
    quat_xyzw_from_matrix,
    right_jacobian,
    right_jacobian_inv,
    rot_z,
    rotation_2d,
    so3_exp,
    so3_log,
    transform_from_rt,
    transform_inverse,
)


def _random_transform(rng: np.random.Generator) -> np.ndarray:
    return transform_from_rt(so3_exp(rng.normal(size=3)), rng.normal(size=3))


@pytest.mark.parametrize("seed", range(5))
def test_rot_z_is_orthonormal_and_turns_x_by_the_angle(seed: int) -> None:
    angle = np.random.default_rng(seed).uniform(-np.pi, np.pi)
    R = rot_z(angle)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [np.cos(angle), np.sin(angle), 0.0])
    np.testing.assert_allclose(R @ [0.0, 0.0, 1.0], [0.0, 0.0, 1.0])


def test_transform_from_rt_places_rotation_and_translation() -> None:
    R = rot_z(0.3)
    T = transform_from_rt(R, [1.0, -2.0, 0.5])
    np.testing.assert_array_equal(T[:3, :3], R)
    np.testing.assert_array_equal(T[:3, 3], [1.0, -2.0, 0.5])
    np.testing.assert_array_equal(T[3], [0.0, 0.0, 0.0, 1.0])


@pytest.mark.parametrize("seed", range(5))
def test_transform_inverse_round_trip(seed: int) -> None:
    rng = np.random.default_rng(seed)
    T = _random_transform(rng)
    inv = transform_inverse(T)
    np.testing.assert_allclose(T @ inv, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(inv @ T, np.eye(4), atol=1e-12)
    np.testing.assert_allclose(inv, np.linalg.inv(T), atol=1e-12)
    np.testing.assert_allclose(transform_inverse(inv), T, atol=1e-12)
    p = rng.normal(size=3)
    q = T[:3, :3] @ p + T[:3, 3]
    np.testing.assert_allclose(inv[:3, :3] @ q + inv[:3, 3], p, atol=1e-12)
    np.testing.assert_array_equal(inv[3], [0.0, 0.0, 0.0, 1.0])


def test_transform_inverse_is_the_transposed_rotation_exactly() -> None:
    T = _random_transform(np.random.default_rng(7))
    inv = transform_inverse(T.tolist())
    np.testing.assert_array_equal(inv[:3, :3], T[:3, :3].T)
    np.testing.assert_array_equal(inv[:3, 3], -T[:3, :3].T @ T[:3, 3])


@pytest.mark.parametrize("seed", range(3))
def test_hat_is_the_cross_product_and_hat_batch_stacks_it(seed: int) -> None:
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(6, 3))
    b = rng.normal(size=3)
    for k in range(len(v)):
        np.testing.assert_allclose(hat(v[k]) @ b, np.cross(v[k], b), atol=1e-15)
        np.testing.assert_array_equal(hat(v[k]), -hat(v[k]).T)
    np.testing.assert_array_equal(hat_batch(v), np.stack([hat(x) for x in v]))


# ------------------------------------------------------------------ SO(3)


@pytest.mark.parametrize("seed", range(3))
def test_so3_exp_log_and_jacobians(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for phi in [
        rng.normal(size=3),
        1e-9 * rng.normal(size=3),
        (np.pi - 1e-4) * np.array([0.6, 0.0, 0.8]),
    ]:
        R = so3_exp(phi)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(R, Rotation.from_rotvec(phi).as_matrix(), atol=1e-12)
        np.testing.assert_allclose(so3_log(R), phi, atol=1e-8)
        np.testing.assert_allclose(
            right_jacobian_inv(phi) @ right_jacobian(phi), np.eye(3), atol=1e-9
        )
    phi = rng.normal(size=3)
    delta = 1e-6 * rng.normal(size=3)
    lhs = so3_exp(phi + delta)
    rhs = so3_exp(phi) @ so3_exp(right_jacobian(phi) @ delta)
    np.testing.assert_allclose(lhs, rhs, atol=1e-11)
    a, b = rng.normal(size=3), rng.normal(size=3)
    np.testing.assert_allclose(hat(a) @ b, np.cross(a, b))
    q = quat_xyzw_from_matrix(so3_exp(phi))
    assert q[3] >= 0
    np.testing.assert_allclose(matrix_from_quat_xyzw(q), so3_exp(phi), atol=1e-12)


def test_batched_so3_maps_match_the_scalar_ones() -> None:
    rng = np.random.default_rng(5)
    phi = np.vstack([rng.normal(0, s, (4, 3)) for s in (1e-9, 1e-5, 1e-2, 1.0)])
    phi = np.vstack([phi, [[0.0, 0.0, 3.1]]])  # near π: the scalar log's branch
    R = geometry.so3_exp_batch(phi)
    for k, v in enumerate(phi):
        np.testing.assert_allclose(R[k], so3_exp(v), atol=1e-14)
        np.testing.assert_allclose(geometry.so3_log_batch(R)[k], so3_log(so3_exp(v)), atol=1e-10)
        np.testing.assert_allclose(
            geometry.right_jacobian_batch(phi)[k], right_jacobian(v), atol=1e-12
        )
        np.testing.assert_allclose(
            geometry.right_jacobian_inv_batch(phi)[k], right_jacobian_inv(v), atol=1e-9
        )


@pytest.mark.parametrize("theta", [0.0, 0.3, -2.0, np.pi])
def test_rotation_2d_is_the_upper_block_of_rot_z(theta: float) -> None:
    np.testing.assert_allclose(rotation_2d(theta), rot_z(theta)[:2, :2], atol=1e-15)
    np.testing.assert_allclose(rotation_2d(theta) @ rotation_2d(-theta), np.eye(2), atol=1e-15)


def test_reframe_track_records_the_offset_frame_of_a_replay_started_at_the_record() -> None:
    from realitygap.core.geometry import reframe_track, se2_compose, se2_inverse

    rng = np.random.default_rng(3)
    heading = np.cumsum(rng.normal(0.0, 0.3, 40))
    body = np.column_stack([np.cumsum(rng.normal(0.0, 0.1, (40, 2)), axis=0), heading])
    frame = np.array([0.03, -0.02, 0.05])
    recorded = se2_compose(body, frame)
    recorded[:, 2] = heading + frame[2]  # continuous, as a channel records it
    # a replay starts the body at the first record and moves it as the body moved
    replay = se2_compose(se2_compose(recorded[0], se2_inverse(body[0])), body)
    replay[:, 2] = recorded[0, 2] + heading - heading[0]
    np.testing.assert_allclose(reframe_track(replay, frame), recorded, atol=1e-12)
    # batched: one frame per batch entry, the neutral frame changes nothing
    both = reframe_track(np.stack([replay, replay]), np.stack([frame, np.zeros(3)]))
    np.testing.assert_allclose(both[0], recorded, atol=1e-12)
    np.testing.assert_allclose(both[1], replay, atol=1e-15)
    # a heading offset alone: driving straight along the wheels' axis records a crab by yaw
    straight = np.column_stack([np.arange(5.0) * np.cos(0.1), np.arange(5.0) * np.sin(0.1)])
    track = np.column_stack([straight, np.full(5, 0.1)])
    np.testing.assert_allclose(
        reframe_track(track, [0.0, 0.0, 0.1]),
        np.column_stack([np.arange(5.0), np.zeros(5), np.full(5, 0.1)]),
        atol=1e-12,
    )
