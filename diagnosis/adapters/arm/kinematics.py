r"""Closed-form kinematics of the arm's diagnosis: batched MDH forward kinematics, the
surrogate of every arm effect, the base tilt and the directions of motion (backlash), and
the windows of poses whose tool-point distances are the arm's features.

The surrogate is the arm's transmission and geometry in closed form, batched over
effect values: link angles

.. math:: q^{link} = q^{enc} / s - c\,\tau^g(q^{enc}) - \tfrac{b}{2}\,\mathrm{dir},

then vectorised 5-parameter MDH forward kinematics with the geometric effects
added to the table, the measured point moved by the tool errors, the base tilt
and the instrument's length scale applied to the points.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import numpy.typing as npt

from realitygap.diagnosis.problem.schemas import TOOL_DIST_COLUMNS
from realitygap.estimators.arm.mdh import MDHTable
from realitygap.robots.arm import flange_load_torques
from realitygap.robots.effects.arm import GEOMETRIC_TOLERANCE_PARAMS

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "POSES_PER_WINDOW",
    "TOOL_DIST_PAIRS",
    "backlash_directions",
    "base_tilt",
    "known_direction_poses",
    "pose_windows",
    "probe_positions",
    "reach_ratio",
    "spread_windows",
    "surrogate_points",
    "tool_distance_features",
]

POSES_PER_WINDOW = 4
"""Consecutive poses per window (their 6 pairwise distances are the features)."""

TOOL_DIST_PAIRS: tuple[tuple[int, int], ...] = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))
"""The pose pairs of a window behind
:data:`~realitygap.diagnosis.problem.schemas.TOOL_DIST_COLUMNS`, in their order."""
assert len(TOOL_DIST_PAIRS) == len(TOOL_DIST_COLUMNS)

_DIR_THRESHOLD = 1e-5
"""A reading change below this (rad) keeps the joint's last direction of motion."""


def backlash_directions(q: FloatArray, threshold: float = _DIR_THRESHOLD) -> FloatArray:
    """Direction of the last move of every joint at every pose: +1, -1, or 0 if unknown (N, 6).

    Nothing says how the first pose of a series was approached, so every joint
    starts unknown (0) and stays so until its first move larger than
    ``threshold``; after that a joint that moves less keeps its previous
    direction. A backlash model puts the link in the middle of its play where the
    direction is 0; :func:`known_direction_poses` tells which poses a
    direction-dependent fit may use.
    """
    q = np.asarray(q, dtype=float)
    out = np.zeros_like(q)
    for k in range(1, q.shape[0]):
        step = q[k] - q[k - 1]
        out[k] = np.where(step > threshold, 1.0, np.where(step < -threshold, -1.0, out[k - 1]))
    return out


def known_direction_poses(direction: FloatArray) -> npt.NDArray[np.bool_]:
    """Poses (N,) whose approach direction is known on every joint that moves in the series.

    A joint that never moves has no direction anywhere and excludes nothing (its
    play is a constant offset); a joint that moves later is unknown before its
    first move, and those poses are left out of direction-dependent fits.
    """
    d = np.asarray(direction, dtype=float)
    moves = np.any(d != 0.0, axis=0)
    return ~np.any((d == 0.0) & moves[None, :], axis=1)


def probe_positions(
    theta: FloatArray,
    d: FloatArray,
    a: FloatArray,
    alpha: FloatArray,
    beta: FloatArray,
    q_link: FloatArray,
    tool: FloatArray,
) -> FloatArray:
    """Tool points (B, N, 3) in the base frame for B tables (B, 6) and link angles (B, N, 6).

    ``tool`` is the point in the flange frame, (3,) or one per table (B, 3).

    The MDH transform of row i is :math:`R_z(q_i+θ_i) T_z(d_i) T_x(a_i) R_x(α_i) R_y(β_i)`
    (as :func:`realitygap.estimators.arm.mdh.forward_kinematics`).
    """
    th = q_link + theta[:, None, :]
    ct, st = np.cos(th), np.sin(th)
    ca, sa = np.cos(alpha)[:, None, :], np.sin(alpha)[:, None, :]
    cb, sb = np.cos(beta)[:, None, :], np.sin(beta)[:, None, :]
    B, N, n = th.shape
    # R = Rz(th) Rx(alpha) Ry(beta), written out
    r00 = ct * cb - st * sa * sb
    r01 = -st * ca
    r02 = ct * sb + st * sa * cb
    r10 = st * cb + ct * sa * sb
    r11 = ct * ca
    r12 = st * sb - ct * sa * cb
    r20 = -ca * sb
    r21 = sa * np.ones_like(ct)
    r22 = ca * cb
    R = np.stack(
        [
            np.stack([r00, r01, r02], axis=-1),
            np.stack([r10, r11, r12], axis=-1),
            np.stack([r20 * np.ones_like(ct), r21, r22 * np.ones_like(ct)], axis=-1),
        ],
        axis=-2,
    )  # (B, N, n, 3, 3)
    t = np.stack([a[:, None, :] * ct, a[:, None, :] * st, d[:, None, :] * np.ones_like(ct)], -1)
    # tool point backwards through the chain: p_{i-1} = R_i p_i + t_i
    tool = np.asarray(tool, dtype=float)
    p = np.broadcast_to(tool.reshape(-1, 1, 3) if tool.ndim == 2 else tool, (B, N, 3)).copy()
    for i in range(n - 1, -1, -1):
        p = np.einsum("bnij,bnj->bni", R[:, :, i], p) + t[:, :, i]
    return p


_GEOMETRY: dict[str, tuple[str, int]] = {}
"""``"effect.param"`` → (MDH column, joint index) for the geometric effects."""
for _k in range(6):
    _GEOMETRY[f"arm_joint_offset.dtheta{_k + 1}"] = ("theta", _k)
for _nm in ("d1", "a2", "a3", "d4", "d5", "d6"):
    _GEOMETRY[f"arm_link_length.d{_nm}"] = (_nm[0], int(_nm[1]) - 1)
_GEOMETRY["arm_parallel_twist.beta2"] = ("beta", 1)
_GEOMETRY["arm_parallel_twist.beta3"] = ("beta", 2)
_GEOMETRY["arm_parallel_twist.dalpha2"] = ("alpha", 1)
_GEOMETRY["arm_parallel_twist.dalpha3"] = ("alpha", 2)
for _k in (1, 4, 5):
    _GEOMETRY[f"arm_twist_error.dalpha{_k}"] = ("alpha", _k - 1)
for _nm in GEOMETRIC_TOLERANCE_PARAMS:
    if not _nm.startswith("tool_"):
        _kind = _nm.rstrip("0123456789")
        _GEOMETRY[f"arm_geometric_tolerances.d{_nm}"] = (
            "theta" if _kind == "theta" else _kind,
            int(_nm[len(_kind) :]) - 1,
        )
_TOOL_KEYS = {
    **{f"arm_tool_offset.d{ax}": k for k, ax in enumerate("xyz")},
    **{f"arm_geometric_tolerances.dtool_{ax}": k for k, ax in enumerate("xyz")},
}


def _batch_size(values: Mapping[str, npt.ArrayLike]) -> int:
    sizes = {np.size(v) for v in values.values()}
    if len(sizes) > 1:
        raise ValueError(f"effect values of one batch must have one length, got {sorted(sizes)}")
    return sizes.pop() if sizes else 1


def surrogate_points(
    table: MDHTable,
    q_enc: FloatArray,
    tau_g: FloatArray,
    direction: FloatArray,
    tool: FloatArray,
    values: Mapping[str, npt.ArrayLike],
    max_elements: int = 400_000,
) -> FloatArray:
    """Tool points (B, N, 3) predicted for a batch of effect values ``{"effect.param": (B,)}``."""
    B = _batch_size(values)
    cols = {
        "theta": np.tile(table.theta_offset, (B, 1)),
        "d": np.tile(table.d, (B, 1)),
        "a": np.tile(table.a, (B, 1)),
        "alpha": np.tile(table.alpha, (B, 1)),
        "beta": np.tile(table.beta, (B, 1)),
    }
    scale = np.ones((B, 6))
    comp = np.zeros((B, 6))
    play = np.zeros((B, 6))
    tools = np.tile(np.asarray(tool, dtype=float).reshape(1, 3), (B, 1))
    length = np.ones(B)
    tilt = np.zeros(B)
    load = np.zeros(B)
    for key, v in values.items():
        arr = np.asarray(v, dtype=float).reshape(-1)
        if key in _GEOMETRY:
            kind, j = _GEOMETRY[key]
            cols[kind][:, j] += arr
        elif key in _TOOL_KEYS:
            tools[:, _TOOL_KEYS[key]] += arr
        elif key == "arm_measurement_scale.s":
            length = length * (1.0 + arr)
        elif key == "arm_base_compliance.k":
            tilt = tilt + arr
        elif key.startswith("arm_encoder_scale.s"):
            scale[:, int(key[-1]) - 1] = arr
        elif key == "arm_joint_compliance.dm":
            load = load + arr
        elif key.startswith("arm_joint_compliance.c"):
            comp[:, int(key[-1]) - 1] = arr
        elif key.startswith("arm_backlash.b"):
            play[:, int(key[-1]) - 1] = arr
        else:
            raise KeyError(f"the arm surrogate has no parameter {key!r}")
    N = q_enc.shape[0]
    out = np.empty((B, N, 3))
    # holding torques per batch row: the body's, plus the flange load the masses miss
    loaded = bool(np.any(load != 0.0))
    per_kg = flange_load_torques(table, q_enc) if loaded else None
    step = max(1, max_elements // max(N, 1))
    for lo in range(0, B, step):
        sl = slice(lo, min(B, lo + step))
        tau = tau_g[None] + load[sl, None, None] * per_kg[None] if loaded else tau_g[None]
        q_link = (
            q_enc[None] / scale[sl, None, :]
            - comp[sl, None, :] * tau
            - 0.5 * play[sl, None, :] * direction[None]
        )
        out[sl] = probe_positions(
            cols["theta"][sl],
            cols["d"][sl],
            cols["a"][sl],
            cols["alpha"][sl],
            cols["beta"][sl],
            q_link,
            tools[sl],
        )
    if np.any(tilt != 0.0):  # the base carries the same flange load as the joints
        tau2 = tau_g[None, :, 1] + load[:, None] * per_kg[None, :, 1] if loaded else tau_g[:, 1]
        out = base_tilt(out, table, q_enc, tau2, tilt)
    return out * length[:, None, None]


def base_tilt(
    points: FloatArray, table: MDHTable, q_enc: FloatArray, tau2: FloatArray, k: npt.ArrayLike
) -> FloatArray:
    r"""Tool points (B, N, 3) of a base tilted by :math:`-k\,\tau_2` about joint 2's axis.

    The axis is the direction of joint 2 at the readings (nominal ``table``),
    through the base origin; ``k`` is one value per batch row (rad/(N·m)),
    ``tau2`` the shoulder's holding torque per pose (N·m), (N,) or one row per batch
    row (B, N). Rodrigues' formula.
    """
    from realitygap.estimators.arm.mdh import joint_frames

    u = joint_frames(table, q_enc)[:, 1, :3, 2]  # (N, 3): joint 2 turns about z of frame 1
    phi = -np.asarray(k, dtype=float).reshape(-1, 1) * np.asarray(tau2, dtype=float)
    c, s = np.cos(phi)[..., None], np.sin(phi)[..., None]
    p = np.asarray(points, dtype=float)
    uxp = np.cross(u[None], p)
    udp = np.sum(u[None] * p, axis=-1, keepdims=True)
    return p * c + uxp * s + u[None] * udp * (1.0 - c)


# --------------------------------------------------------------------------- windows of poses
def tool_distance_features(points: FloatArray, bounds: npt.NDArray[np.int64]) -> FloatArray:
    """Pairwise distances (…, M, 6) of the tool points (…, N, 3) of every window."""
    a = bounds[:, 0]
    cols = [
        np.linalg.norm(points[..., a + i, :] - points[..., a + j, :], axis=-1)
        for i, j in TOOL_DIST_PAIRS
    ]
    return np.stack(cols, axis=-1)


def reach_ratio(table: MDHTable, q: FloatArray) -> FloatArray:
    """Horizontal distance of the wrist (frame 4) from the base axis over |a2| + |a3| (N,)."""
    from realitygap.estimators.arm.mdh import joint_frames

    frames = joint_frames(table, q)
    r = np.hypot(frames[:, 4, 0, 3], frames[:, 4, 1, 3])
    length = abs(float(table.a[1])) + abs(float(table.a[2]))
    return r / max(length, 1e-9)


def pose_windows(n: int) -> npt.NDArray[np.int64]:
    """Bounds (M, 2) of the consecutive windows of :data:`POSES_PER_WINDOW` of ``n`` poses."""
    m = n // POSES_PER_WINDOW
    a = np.arange(m) * POSES_PER_WINDOW
    return np.stack([a, a + POSES_PER_WINDOW], axis=1).astype(np.int64)


def spread_windows(n: int) -> npt.NDArray[np.int64]:
    """Rows (M, 4) of the poses of each window of a series of ``n`` poses.

    Window ``m`` holds poses ``m, m + M, m + 2M, m + 3M`` with ``M = n // 4``: its
    four poses lie a quarter of the series apart, so its tool-point distances span
    the workspace whatever order the poses were measured in (in a grid series
    neighbouring poses are a few centimetres apart, and a short distance hardly
    changes with the geometry: it would hide what the calibration sees).
    """
    m = n // POSES_PER_WINDOW
    return (np.arange(m)[:, None] + m * np.arange(POSES_PER_WINDOW)[None, :]).astype(np.int64)
