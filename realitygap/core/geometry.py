"""Small, dependency-free rigid-body helpers shared by every layer: SE(2) poses,
SO(3) maps (exp, log, right Jacobians, quaternions; single and batched), transforms.

Poses in the plane are arrays ``[x, y, theta]`` (m, m, rad), angles wrapped to
``(-pi, pi]``. Compounding follows Smith–Self–Cheeseman: ``a ⊕ b`` is pose ``b``
expressed in frame ``a`` carried to the frame ``a`` lives in; ``⊖a`` is its
inverse, so ``⊖a ⊕ a = 0``.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]


def wrap_angle(angle: npt.ArrayLike) -> FloatArray | float:
    """Wrap angle(s) in rad to ``[-pi, pi)``.

    >>> round(wrap_angle(3 * np.pi / 2), 6)
    -1.570796
    """
    a = np.asarray(angle, dtype=float)
    wrapped = (a + np.pi) % (2.0 * np.pi) - np.pi
    return float(wrapped) if wrapped.ndim == 0 else wrapped


def se2_compose(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """Compound two planar poses, ``a ⊕ b``; both shape (3,) or broadcastable (..., 3)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = a[..., 0] + c * b[..., 0] - s * b[..., 1]
    y = a[..., 1] + s * b[..., 0] + c * b[..., 1]
    th = wrap_angle(a[..., 2] + b[..., 2])
    return np.stack([x, y, np.asarray(th, dtype=float)], axis=-1)


def se2_inverse(a: npt.ArrayLike) -> FloatArray:
    """Inverse pose ``⊖a`` such that ``a ⊕ ⊖a = 0``."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    x = -c * a[..., 0] - s * a[..., 1]
    y = s * a[..., 0] - c * a[..., 1]
    return np.stack([x, y, np.asarray(wrap_angle(-a[..., 2]), dtype=float)], axis=-1)


def se2_between(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """Relative pose of ``b`` seen from ``a``: ``⊖a ⊕ b``."""
    return se2_compose(se2_inverse(a), b)


def reframe_track(
    track: npt.ArrayLike, frame: npt.ArrayLike, start: npt.ArrayLike | None = None
) -> FloatArray:
    """The track a body frame offset by ``frame`` records, from a track started at its record.

    A pose channel that tracks a frame ``F = (x, y, yaw)`` fixed to the body
    (a motion-capture rigid body defined a little off the axle centre) records
    ``A_k ⊕ F`` for body poses ``A_k``. A replay that starts the body at the
    first *recorded* pose ``R_0`` and moves it as the body moved produces
    ``A'_k = R_0 ⊕ A_0^{-1} ⊕ A_k``; the recorded track is then

    .. math::  R_k = (R_0 ⊕ F^{-1} ⊕ R_0^{-1}) ⊕ A'_k ⊕ F .

    Headings stay continuous (the rotation parts cancel).

    Parameters
    ----------
    track : array_like, shape (..., N, 3)
        ``A'_k``: x, y (m) and continuous heading (rad).
    frame : array_like, shape (..., 3)
        ``F`` per batch entry: x, y (m), yaw (rad).
    start : array_like, shape (..., 3), optional
        ``R_0``; default the track's first pose.

    Returns
    -------
    ndarray, shape (..., N, 3)
    """
    a = np.asarray(track, dtype=float)
    f = np.asarray(frame, dtype=float)
    r0 = a[..., 0, :] if start is None else np.broadcast_to(np.asarray(start, dtype=float), f.shape)
    left = se2_compose(se2_compose(r0, se2_inverse(f)), se2_inverse(r0))
    c, s = np.cos(a[..., 2]), np.sin(a[..., 2])
    mx, my = f[..., 0, None], f[..., 1, None]
    px = a[..., 0] + c * mx - s * my
    py = a[..., 1] + s * mx + c * my
    cl, sl = np.cos(left[..., 2])[..., None], np.sin(left[..., 2])[..., None]
    out = np.empty(np.broadcast_shapes(a.shape, f.shape[:-1] + a.shape[-2:]))
    out[..., 0] = left[..., 0, None] + cl * px - sl * py
    out[..., 1] = left[..., 1, None] + sl * px + cl * py
    out[..., 2] = a[..., 2]
    return out


def reframe_recorded(
    track: npt.ArrayLike, frame_from: npt.ArrayLike, frame_to: npt.ArrayLike
) -> FloatArray:
    """A track recorded under the body frame ``frame_from``, as ``frame_to`` would record it.

    The inverse of :func:`reframe_track` followed by it: the body poses the record
    implies (started at its first recorded pose) are recorded again under
    ``frame_to``. Headings are returned as given (a frame change leaves them unchanged).

    Parameters
    ----------
    track : array_like, shape (N, 3)
        Recorded x, y (m) and heading (rad).
    frame_from, frame_to : array_like, shape (3,)
        Body frames x, y (m), yaw (rad).

    Returns
    -------
    ndarray, shape (N, 3)
    """
    r = np.asarray(track, dtype=float)
    f = np.asarray(frame_from, dtype=float)
    if r.ndim != 2 or r.shape[1] != 3 or f.shape != (3,) or np.shape(frame_to) != (3,):
        raise ValueError(
            f"reframe_recorded: expected a track (N, 3) and frames (3,), got {r.shape}, "
            f"{f.shape} and {np.shape(frame_to)}"
        )
    r0 = r[0]
    # R_k = L ⊕ A_k ⊕ F with L = R_0 ⊕ F⁻¹ ⊕ R_0⁻¹, so A_k = L⁻¹ ⊕ R_k ⊕ F⁻¹
    left_inv = se2_compose(se2_compose(r0, f), se2_inverse(r0))
    body = se2_compose(se2_compose(left_inv, r), se2_inverse(f))
    body[:, 2] = r[:, 2]
    out = reframe_track(body, np.asarray(frame_to, dtype=float), start=r0)
    out[:, 2] = r[:, 2]
    return out


def yaw_from_quat_xyzw(quat_xyzw: npt.ArrayLike) -> float:
    """Heading (rotation about world z) in rad of a quaternion in PyBullet's xyzw order."""
    x, y, z, w = np.asarray(quat_xyzw, dtype=float)
    return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def rotation_2d(theta: float) -> FloatArray:
    """2×2 rotation matrix of the angle ``theta`` (rad)."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


SKEW_2D = np.array([[0.0, -1.0], [1.0, 0.0]])
"""Generator of planar rotations: d R(θ)/dθ = S R(θ) (read-only)."""
SKEW_2D.setflags(write=False)


def rot_z(angle: float) -> FloatArray:
    """3×3 rotation about z by ``angle`` rad."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def transform_from_rt(rotation: npt.ArrayLike, translation: npt.ArrayLike) -> FloatArray:
    """4×4 homogeneous transform from a 3×3 rotation and a 3-vector translation."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(rotation, dtype=float)
    T[:3, 3] = np.asarray(translation, dtype=float)
    return T


def check_finite(
    name: str, value: npt.ArrayLike, shape: tuple[int, ...] | None = None
) -> FloatArray:
    """Convert to a float array and raise ``ValueError`` naming ``name`` if it is not finite
    or (when ``shape`` is given) not of that shape."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be numeric, got {type(value).__name__}: {value!r}") from exc
    if shape is not None and arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr!r}")
    return arr


# --------------------------------------------------------------------------- SO(3)


def hat(v: npt.ArrayLike) -> FloatArray:
    """Skew-symmetric matrix :math:`[v]_\\times` of a 3-vector, so ``hat(a) @ b = a × b``."""
    x, y, z = np.asarray(v, dtype=float)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def so3_exp(phi: npt.ArrayLike) -> FloatArray:
    """Rotation matrix :math:`\\mathrm{Exp}(\\phi)` of a rotation vector (rad), Rodrigues."""
    phi = np.asarray(phi, dtype=float)
    angle = math.sqrt(float(phi @ phi))
    K = hat(phi)
    if angle < 1e-8:
        return np.eye(3) + K + 0.5 * K @ K
    return np.eye(3) + (math.sin(angle) / angle) * K + ((1.0 - math.cos(angle)) / angle**2) * K @ K


def so3_log(R: npt.ArrayLike) -> FloatArray:
    """Rotation vector :math:`\\mathrm{Log}(R)` (rad) of a rotation matrix, robust near π."""
    R = np.asarray(R, dtype=float)
    cos_a = min(1.0, max(-1.0, 0.5 * (np.trace(R) - 1.0)))
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    if cos_a > 1.0 - 1e-10:
        return 0.5 * w
    angle = math.acos(cos_a)
    if cos_a < -0.99:
        # near π: axis from the symmetric part
        M = 0.5 * (R + R.T) - cos_a * np.eye(3)
        k = int(np.argmax(np.diag(M)))
        axis = M[:, k] / math.sqrt(max(M[k, k], 1e-300))
        if axis @ w < 0:
            axis = -axis
        return angle * axis / np.linalg.norm(axis)
    return (angle / (2.0 * math.sin(angle))) * w


def right_jacobian(phi: npt.ArrayLike) -> FloatArray:
    """Right Jacobian :math:`J_r(\\phi)`: :math:`\\mathrm{Exp}(\\phi+\\delta) \\approx
    \\mathrm{Exp}(\\phi)\\mathrm{Exp}(J_r\\delta)`."""
    phi = np.asarray(phi, dtype=float)
    a = math.sqrt(float(phi @ phi))
    K = hat(phi)
    if a < 1e-6:
        return np.eye(3) - 0.5 * K + K @ K / 6.0
    return np.eye(3) - ((1 - math.cos(a)) / a**2) * K + ((a - math.sin(a)) / a**3) * K @ K


def right_jacobian_inv(phi: npt.ArrayLike) -> FloatArray:
    """Inverse right Jacobian :math:`J_r^{-1}(\\phi)`."""
    phi = np.asarray(phi, dtype=float)
    a = math.sqrt(float(phi @ phi))
    K = hat(phi)
    if a < 1e-6:
        return np.eye(3) + 0.5 * K + K @ K / 12.0
    coef = 1.0 / a**2 - (1 + math.cos(a)) / (2 * a * math.sin(a))
    return np.eye(3) + 0.5 * K + coef * K @ K


def quat_xyzw_from_matrix(R: npt.ArrayLike) -> FloatArray:
    """Unit quaternion (x, y, z, w), ``w ≥ 0``, of a rotation matrix (Shepperd's method)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = np.asarray(R, dtype=float).tolist()
    tr = m00 + m11 + m22
    k = max(range(4), key=(tr, m00, m11, m22).__getitem__)
    if k == 0:
        w = 0.5 * math.sqrt(max(1.0 + tr, 0.0))
        f = 0.25 / w
        q = [(m21 - m12) * f, (m02 - m20) * f, (m10 - m01) * f, w]
    elif k == 1:
        x = 0.5 * math.sqrt(max(1.0 + 2 * m00 - tr, 0.0))
        f = 0.25 / x
        q = [x, (m01 + m10) * f, (m02 + m20) * f, (m21 - m12) * f]
    elif k == 2:
        y = 0.5 * math.sqrt(max(1.0 + 2 * m11 - tr, 0.0))
        f = 0.25 / y
        q = [(m01 + m10) * f, y, (m12 + m21) * f, (m02 - m20) * f]
    else:
        z = 0.5 * math.sqrt(max(1.0 + 2 * m22 - tr, 0.0))
        f = 0.25 / z
        q = [(m02 + m20) * f, (m12 + m21) * f, z, (m10 - m01) * f]
    scale = 1.0 / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[3] < 0:
        scale = -scale
    return np.array(q) * scale


def matrix_from_quat_xyzw(quat_xyzw: npt.ArrayLike) -> FloatArray:
    """Rotation matrix of a quaternion in xyzw order (normalised here)."""
    q = np.asarray(quat_xyzw, dtype=float)
    if q.shape != (4,):
        raise ValueError(f"quat_xyzw must be a finite non-zero (4,) array, got {quat_xyzw!r}")
    x, y, z, w = q.tolist()
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not (math.isfinite(n) and n >= 1e-12):
        raise ValueError(f"quat_xyzw must be a finite non-zero (4,) array, got {quat_xyzw!r}")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


# ------------------------------------------------------------- batched SO(3)
# The same maps over stacks of K vectors / matrices (shapes (K, 3), (K, 3, 3)); the
# window solver evaluates all its factors at once with them.


def hat_batch(v: FloatArray) -> FloatArray:
    """Skew matrices (K, 3, 3) of vectors (K, 3)."""
    K = np.zeros((len(v), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return K


def _series_n(
    phi: FloatArray, small: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """``(K, K², mask of angles below small, angle with 1 there)`` of rotation vectors (K, 3)."""
    a = np.linalg.norm(phi, axis=1)
    K = hat_batch(phi)
    K2 = K @ K
    tiny = a < small
    return K, K2, tiny, np.where(tiny, 1.0, a)


def so3_exp_batch(phi: FloatArray) -> FloatArray:
    """:func:`so3_exp` of rotation vectors (K, 3) → (K, 3, 3)."""
    K, K2, tiny, s = _series_n(phi, 1e-8)
    c1 = np.where(tiny, 1.0, np.sin(s) / s)
    c2 = np.where(tiny, 0.5, (1.0 - np.cos(s)) / s**2)
    return np.eye(3) + c1[:, None, None] * K + c2[:, None, None] * K2


def right_jacobian_batch(phi: FloatArray) -> FloatArray:
    """:func:`right_jacobian` of rotation vectors (K, 3) → (K, 3, 3)."""
    K, K2, tiny, s = _series_n(phi, 1e-6)
    c1 = np.where(tiny, 0.5, (1 - np.cos(s)) / s**2)
    c2 = np.where(tiny, 1.0 / 6.0, (s - np.sin(s)) / s**3)
    return np.eye(3) - c1[:, None, None] * K + c2[:, None, None] * K2


def right_jacobian_inv_batch(phi: FloatArray) -> FloatArray:
    """:func:`right_jacobian_inv` of rotation vectors (K, 3) → (K, 3, 3)."""
    K, K2, tiny, s = _series_n(phi, 1e-6)
    c = np.where(tiny, 1.0 / 12.0, 1.0 / s**2 - (1 + np.cos(s)) / (2 * s * np.sin(s)))
    return np.eye(3) + 0.5 * K + c[:, None, None] * K2


def so3_log_batch(R: FloatArray) -> FloatArray:
    """:func:`so3_log` of rotation matrices (K, 3, 3) → (K, 3) (near π: the scalar one)."""
    cos_a = np.clip(0.5 * (np.trace(R, axis1=1, axis2=2) - 1.0), -1.0, 1.0)
    w = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], 1)
    a = np.arccos(cos_a)
    near0 = cos_a > 1.0 - 1e-10
    f = np.where(near0, 0.5, a / (2.0 * np.sin(np.where(near0, 1.0, a))))
    out = f[:, None] * w
    for k in np.flatnonzero(cos_a < -0.99):
        out[k] = so3_log(R[k])
    return out


# ------------------------------------------------------------- homogeneous transforms


def transform_inverse(T: npt.ArrayLike) -> FloatArray:
    """Inverse of a rigid 4×4 transform in closed form, :math:`[R^\\top, -R^\\top t]`."""
    T = np.asarray(T, dtype=float)
    inv = np.eye(4)
    inv[:3, :3] = T[:3, :3].T
    inv[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return inv
