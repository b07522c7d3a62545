"""Small, dependency-free rigid-body helpers shared by every layer.

Poses in the plane are arrays ``[x, y, theta]`` (m, m, rad), angles wrapped to
``(-pi, pi]``. Compounding follows Smith–Self–Cheeseman: ``a ⊕ b`` is pose ``b``
expressed in frame ``a`` carried to the frame ``a`` lives in; ``⊖a`` is its
inverse, so ``⊖a ⊕ a = 0``.
"""

from __future__ import annotations

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


def yaw_from_quat_xyzw(quat_xyzw: npt.ArrayLike) -> float:
    """Heading (rotation about world z) in rad of a quaternion in PyBullet's xyzw order."""
    x, y, z, w = np.asarray(quat_xyzw, dtype=float)
    return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


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
