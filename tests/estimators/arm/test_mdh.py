"""MDH tables, forward kinematics and the parameter Jacobian against closed forms."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from realitygap.estimators.arm.mdh import (
    TOOL_PARAM_NAMES,
    MDHTable,
    ParamSet,
    forward_kinematics,
    jacobian_params,
    joint_frames,
    resolve_param_names,
    tool_positions,
)


def _rz(a: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", a).as_matrix()
    return T


def _rx(a: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("x", a).as_matrix()
    return T


def _ry(a: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("y", a).as_matrix()
    return T


def _tz(d: float) -> np.ndarray:
    T = np.eye(4)
    T[2, 3] = d
    return T


def _tx(a: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = a
    return T


def _random_table(rng: np.random.Generator, n: int) -> MDHTable:
    return MDHTable(
        theta_offset=rng.uniform(-0.1, 0.1, n),
        d=rng.uniform(-0.3, 0.3, n),
        a=rng.uniform(-0.5, 0.5, n),
        alpha=rng.uniform(-np.pi, np.pi, n),
        beta=rng.uniform(-0.05, 0.05, n),
    )


def test_fk_is_the_product_of_elementary_transforms() -> None:
    rng = np.random.default_rng(0)
    table = _random_table(rng, 5)
    q = rng.uniform(-np.pi, np.pi, 5)
    T = np.eye(4)
    for i in range(5):
        T = (
            T
            @ _rz(q[i] + table.theta_offset[i])
            @ _tz(table.d[i])
            @ _tx(table.a[i])
            @ _rx(table.alpha[i])
            @ _ry(table.beta[i])
        )
    np.testing.assert_allclose(forward_kinematics(table, q)[0], T, atol=1e-14)


def test_fk_vectorised_base_and_tool() -> None:
    rng = np.random.default_rng(1)
    table = MDHTable.ur10()
    q = rng.uniform(-np.pi, np.pi, (7, 6))
    T_base = _rz(0.3) @ _tx(0.2) @ _rx(-0.1)
    T_tool = _tz(0.109) @ _ry(0.2)
    batch = forward_kinematics(table, q, T_base, T_tool)
    assert batch.shape == (7, 4, 4)
    for k in range(7):
        single = T_base @ forward_kinematics(table, q[k])[0] @ T_tool
        np.testing.assert_allclose(batch[k], single, atol=1e-14)
    frames = joint_frames(table, q, T_base)
    assert frames.shape == (7, 7, 4, 4)
    np.testing.assert_allclose(frames[:, 0], np.broadcast_to(T_base, (7, 4, 4)))


def test_ur10_nominal_and_home_pose() -> None:
    t = MDHTable.ur10()
    np.testing.assert_allclose(t.d, [0.1273, 0, 0, 0.163941, 0.1157, 0.0922])
    np.testing.assert_allclose(t.a, [0, -0.612, -0.5723, 0, 0, 0])
    assert t.parallel_rows.tolist() == [False, True, True, False, False, False]
    T = forward_kinematics(t, np.zeros(6))[0]
    # at q = 0: x = a2 + a3, y = -(d4 + d6), z = d1 - d5
    np.testing.assert_allclose(T[:3, 3], [-1.1843, -0.256141, 0.1273 - 0.1157], atol=1e-12)


def test_ur_like_has_three_parallel_axes() -> None:
    t = MDHTable.ur_like_6dof()
    frames = joint_frames(t, np.random.default_rng(2).uniform(-3, 3, 6))[0]
    z = frames[:, :3, 2]  # z_{i-1} is the axis of joint i
    for i, j in ((1, 2), (2, 3)):
        assert abs(abs(z[i] @ z[j]) - 1.0) < 1e-12
    assert abs(z[3] @ z[4]) < 1e-12


def test_franka_equals_published_craig_chain() -> None:
    # Franka's published proximal (Craig) parameters
    a = [0, 0, 0, 0.0825, -0.0825, 0, 0.088]
    d = [0.333, 0, 0.316, 0, 0.384, 0, 0]
    alpha = [0, -np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, np.pi / 2, np.pi / 2]
    rng = np.random.default_rng(3)
    table = MDHTable.franka_fr3()
    assert table.n_joints == 7
    for q in rng.uniform(-2.5, 2.5, (5, 7)):
        T = np.eye(4)
        for i in range(7):
            T = T @ _rx(alpha[i]) @ _tx(a[i]) @ _rz(q[i]) @ _tz(d[i])
        T = T @ _tz(0.107)
        np.testing.assert_allclose(forward_kinematics(table, q)[0], T, atol=1e-13)


def test_beta_tilts_the_next_parallel_axis_by_beta() -> None:
    eps = 1e-3
    t = MDHTable.ur_like_6dof().with_params([eps], ["beta2"])
    frames = joint_frames(t, np.random.default_rng(4).uniform(-3, 3, 6))[0]
    z2, z3 = frames[1, :3, 2], frames[2, :3, 2]  # axes of joints 2 and 3
    np.testing.assert_allclose(np.arccos(np.clip(z2 @ z3, -1, 1)), eps, rtol=1e-9)


@pytest.mark.parametrize("which", ["mdh", "dh"])
def test_jacobian_matches_finite_differences(which: str) -> None:
    rng = np.random.default_rng(5)
    for table in (MDHTable.ur10(), MDHTable.franka_fr3()):
        table = table.with_params(table.params() + rng.normal(0, 0.01, 5 * table.n_joints))
        q = rng.uniform(-np.pi, np.pi, (6, table.n_joints))
        tool = np.array([0.02, -0.01, 0.1])
        T_base = _rz(0.4) @ _tx(0.3) @ _ry(0.2)
        names = resolve_param_names(table, [*table.param_names(which), *TOOL_PARAM_NAMES])
        J = jacobian_params(table, q, names, tool=tool, T_base=T_base)
        assert J.shape == (6, 3, len(names))
        h = 1e-6
        for k, nm in enumerate(names):
            if nm in TOOL_PARAM_NAMES:
                e = np.zeros(3)
                e[TOOL_PARAM_NAMES.index(nm)] = h
                plus = tool_positions(table, q, tool + e, T_base)
                minus = tool_positions(table, q, tool - e, T_base)
            else:
                v = table.param_dict()[nm]
                plus = tool_positions(table.with_params([v + h], [nm]), q, tool, T_base)
                minus = tool_positions(table.with_params([v - h], [nm]), q, tool, T_base)
            np.testing.assert_allclose(J[:, :, k], (plus - minus) / (2 * h), atol=2e-9)


def test_param_vector_round_trip_and_dh_only() -> None:
    rng = np.random.default_rng(6)
    table = _random_table(rng, 7)
    assert table.params().shape == (35,)
    assert table.params(ParamSet.DH).shape == (28,)
    assert table.param_names()[:5] == ("theta1", "d1", "a1", "alpha1", "beta1")
    assert table.with_params(table.params()) == table
    assert np.all(table.dh_only().beta == 0)
    new = table.with_params([0.5, -0.2], ["d3", "beta7"])
    assert new.d[2] == 0.5 and new.beta[6] == -0.2
    assert new.isclose(table) is False
    with pytest.raises(ValueError, match="read-only"):
        table.d[0] = 1.0


def test_errors_are_clear() -> None:
    t = MDHTable.ur10()
    with pytest.raises(ValueError, match=r"shape \(N, 6\)"):
        forward_kinematics(t, np.zeros(5))
    with pytest.raises(ValueError, match="finite"):
        forward_kinematics(t, [0, 0, np.nan, 0, 0, 0])
    with pytest.raises(ValueError, match="4x4"):
        forward_kinematics(t, np.zeros(6), T_base=np.eye(3))
    with pytest.raises(ValueError, match="has 5 entries"):
        MDHTable(np.zeros(6), np.zeros(5), np.zeros(6), np.zeros(6), np.zeros(6))
    with pytest.raises(ValueError, match="unknown kinematic parameter 'dd2'"):
        t.with_params([1.0], ["dd2"])
    with pytest.raises(ValueError, match="joint 7"):
        t.with_params([1.0], ["d7"])
    with pytest.raises(ValueError, match="which must be one of"):
        jacobian_params(t, np.zeros(6), "full")
    with pytest.raises(ValueError, match="unique"):
        jacobian_params(t, np.zeros(6), ["d2", "d2"])
