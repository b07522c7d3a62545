"""Rotations and rigid transforms of realitygap.core.geometry against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from realitygap.core.geometry import (
    hat,
    hat_batch,
    rot_z,
    so3_exp,
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
