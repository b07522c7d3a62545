"""Hand–eye calibration of a flange camera: rotation-axis methods and AX = XB.

Frames: ``board`` is the calibration board (see :mod:`.coded_board`), ``camera``
the optical frame (OpenCV: x right, y down, z forward), ``flange`` the last
joint frame of the :class:`~.mdh.MDHTable`, ``base`` the arm's frame 0. The
unknown is :math:`X = T_{\\mathrm{flange},\\mathrm{camera}}`. All lengths in m,
angles in rad.

Two methods need only the rotation of the last joints:

* **single-axis** — joint ``n`` alone turns; the optical centre runs on a
  circle about the joint axis. A plane and a circle fitted to the camera
  positions give that axis in the board frame; the flange origin is the foot
  of the modelled flange origin on it, the flange x axis the modelled one made
  orthogonal to it, and :math:`X` follows by undoing the joint rotation.
* **two-axis** — joints ``n-1`` and ``n`` turn one after the other. The two
  fitted axes give frame ``n-1`` completely: its origin is the foot of the
  common perpendicular on the last axis, its z axis the last axis and its x axis
  :math:`x = (z_{n-2} \\times z_{n-1}) / \\sin\\alpha_{n-1}`. The flange then
  follows from the last MDH row, with no knowledge of the board in the base.

The general solver :func:`solve_ax_xb` uses OpenCV's ``calibrateHandEye`` when
the installed OpenCV exposes it and otherwise the closed form of Park and Martin
(1994), which is what ``cv2.CALIB_HAND_EYE_PARK`` computes.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import cv2
import numpy as np
import numpy.typing as npt
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from realitygap.core.geometry import rot_z, transform_from_rt

from .mdh import MDHTable

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "AXXBMethod",
    "CircleFit",
    "HandEyeResult",
    "average_transforms",
    "fit_circle_3d",
    "fit_plane",
    "handeye_single_axis",
    "handeye_two_axis",
    "solve_ax_xb",
]


class AXXBMethod(str, Enum):
    """Solver for :func:`solve_ax_xb`."""

    AUTO = "auto"  #: OpenCV (Park) when available, else the numpy Park–Martin solver
    PARK = "park"  #: numpy Park–Martin closed form
    OPENCV_PARK = "opencv_park"
    OPENCV_TSAI = "opencv_tsai"
    OPENCV_DANIILIDIS = "opencv_daniilidis"


@dataclass(frozen=True)
class CircleFit:
    """A circle in space fitted to points.

    Attributes
    ----------
    centre : ndarray, shape (3,)
        Circle centre (m), a point on the rotation axis.
    normal : ndarray, shape (3,)
        Unit normal of the circle's plane, the rotation axis; oriented so that the
        points turn counter-clockwise about it with increasing joint angle when
        angles were given.
    radius : float
        Radius (m).
    rms : float
        Root-mean-square 3-D distance of the points from the fitted circle (m).
    n_points : int
        Number of points used.
    """

    centre: FloatArray
    normal: FloatArray
    radius: float
    rms: float
    n_points: int


@dataclass(frozen=True)
class HandEyeResult:
    """Result of a hand–eye calibration.

    Attributes
    ----------
    T_flange_camera : ndarray, shape (4, 4)
        Camera pose in the flange frame, :math:`X`.
    T_board_flange : ndarray, shape (4, 4) or None
        Flange pose in the board frame at the reference configuration of the
        axis methods (``None`` for AX = XB).
    T_base_board : ndarray, shape (4, 4) or None
        Board pose in the base frame (AX = XB only).
    axes : tuple of CircleFit
        Fitted rotation axes (empty for AX = XB).
    residual_rotation_rad, residual_translation_m : float
        RMS disagreement of the individual camera poses with the result.
    method : str
        Which method produced it.
    """

    T_flange_camera: FloatArray
    T_board_flange: FloatArray | None
    T_base_board: FloatArray | None
    axes: tuple[CircleFit, ...]
    residual_rotation_rad: float
    residual_translation_m: float
    method: str


# --------------------------------------------------------------------------- checks
def _check_points(name: str, points: npt.ArrayLike, min_points: int) -> FloatArray:
    arr = np.asarray(points, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3), got {arr.shape}")
    if arr.shape[0] < min_points:
        raise ValueError(f"{name} needs at least {min_points} points, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _check_poses(name: str, T: npt.ArrayLike, min_poses: int = 1) -> FloatArray:
    arr = np.asarray(T, dtype=float)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3 or arr.shape[1:] != (4, 4):
        raise ValueError(f"{name} must have shape (N, 4, 4), got {arr.shape}")
    if arr.shape[0] < min_poses:
        raise ValueError(f"{name} needs at least {min_poses} poses, got {arr.shape[0]}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _check_angles(name: str, q: npt.ArrayLike, n: int) -> FloatArray:
    arr = np.asarray(q, dtype=float).reshape(-1)
    if arr.size != n:
        raise ValueError(f"{name} must have one joint angle per pose ({n}), got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


# --------------------------------------------------------------------------- fits
def fit_plane(points: npt.ArrayLike) -> tuple[FloatArray, FloatArray, float]:
    """Least-squares plane through points (total least squares).

    Parameters
    ----------
    points : array_like, shape (N, 3), N >= 3

    Returns
    -------
    centroid : ndarray, shape (3,)
    normal : ndarray, shape (3,)
        Unit normal, the right singular vector of the smallest singular value.
    rms : float
        RMS distance of the points from the plane (m).
    """
    P = _check_points("points", points, 3)
    c = P.mean(axis=0)
    D = P - c
    w, V = np.linalg.eigh(np.einsum("ni,nj->ij", D, D))  # ascending
    if w[1] <= 1e-12 * max(w[2], 1e-300):
        raise ValueError("points are collinear; a plane is not defined")
    n = V[:, 0]
    return c, n, float(np.sqrt(max(w[0], 0.0) / P.shape[0]))


def fit_circle_3d(points: npt.ArrayLike, angles: npt.ArrayLike | None = None) -> CircleFit:
    """Fit a circle in space: plane (SVD), then an algebraic and a geometric 2-D fit.

    The algebraic (Kåsa) fit solves
    :math:`x^2 + y^2 = 2 c_x x + 2 c_y y + (r^2 - |c|^2)` linearly; the geometric
    fit then minimises :math:`\\sum_k (\\|p_k - c\\| - r)^2` in 3-D over centre,
    normal and radius.

    Parameters
    ----------
    points : array_like, shape (N, 3), N >= 3
        Points on the circle (m).
    angles : array_like, shape (N,), optional
        Joint angle (rad) of each point; orients the normal so that the rotation
        is counter-clockwise about it.

    Returns
    -------
    CircleFit
    """
    P = _check_points("points", points, 3)
    c0, n0, _ = fit_plane(P)
    u = np.cross(n0, [1.0, 0.0, 0.0])
    if np.linalg.norm(u) < 0.5:
        u = np.cross(n0, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(n0, u)
    x = (P - c0) @ u
    y = (P - c0) @ v
    A = np.column_stack([2 * x, 2 * y, np.ones_like(x)])
    sol = np.linalg.solve(np.einsum("ni,nj->ij", A, A), np.einsum("ni,n->i", A, x**2 + y**2))
    cx, cy = sol[0], sol[1]
    r0 = np.sqrt(max(sol[2] + cx**2 + cy**2, 0.0))
    centre0 = c0 + cx * u + cy * v
    scale = max(r0, 1e-9)

    def residual(p: FloatArray) -> FloatArray:
        c = centre0 + p[0] * u + p[1] * v
        nvec = n0 + p[2] * u + p[3] * v
        nvec = nvec / np.linalg.norm(nvec)
        rel = P - c
        h = rel @ nvec
        radial = np.linalg.norm(rel - h[:, None] * nvec, axis=1)
        return np.concatenate([radial - p[4], h]) / scale

    sol2 = least_squares(residual, np.array([0.0, 0.0, 0.0, 0.0, r0]), method="lm", xtol=1e-15)
    p = sol2.x
    centre = centre0 + p[0] * u + p[1] * v
    normal = n0 + p[2] * u + p[3] * v
    normal /= np.linalg.norm(normal)
    radius = float(abs(p[4]))
    if radius < 1e-9:
        raise ValueError("the points do not form a circle (radius ~ 0): is the camera on the axis?")
    rms = float(np.sqrt(np.mean((residual(p) * scale) ** 2) * 2))
    if angles is not None:
        q = _check_angles("angles", angles, P.shape[0])
        e1 = np.cross(normal, [1.0, 0.0, 0.0])
        if np.linalg.norm(e1) < 0.5:
            e1 = np.cross(normal, [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(normal, e1)
        phi = np.unwrap(np.arctan2((P - centre) @ e2, (P - centre) @ e1))
        order = np.argsort(q)
        slope = np.polyfit(q[order], phi[order], 1)[0] if np.ptp(q) > 0 else 1.0
        if slope < 0:
            normal = -normal
    return CircleFit(centre, normal, radius, rms, int(P.shape[0]))


# --------------------------------------------------------------------------- helpers
def _axis_rotation(axis: FloatArray, point: FloatArray, angle: float) -> FloatArray:
    """4×4 rotation by ``angle`` about the line through ``point`` along unit ``axis``."""
    R = Rotation.from_rotvec(axis * angle).as_matrix()
    return transform_from_rt(R, point - R @ point)


def average_transforms(T: npt.ArrayLike) -> FloatArray:
    """Chordal mean of rigid transforms: projected mean rotation, mean translation.

    Parameters
    ----------
    T : array_like, shape (N, 4, 4)

    Returns
    -------
    ndarray, shape (4, 4)
    """
    Ts = _check_poses("T", T)
    U, _, Vt = np.linalg.svd(Ts[:, :3, :3].sum(axis=0))
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    return transform_from_rt(R, Ts[:, :3, 3].mean(axis=0))


def _spread(Ts: FloatArray, mean: FloatArray) -> tuple[float, float]:
    rel = np.linalg.inv(mean)[None] @ Ts
    ang = np.linalg.norm(Rotation.from_matrix(rel[:, :3, :3]).as_rotvec(), axis=1)
    return float(np.sqrt(np.mean(ang**2))), float(
        np.sqrt(np.mean(np.sum((Ts[:, :3, 3] - mean[:3, 3]) ** 2, axis=1)))
    )


def _last_row_transform(table: MDHTable, q: float) -> FloatArray:
    """Transform of the last MDH row, frame n-1 to frame n, at joint reading ``q``."""
    i = table.n_joints - 1
    th = q + table.theta_offset[i]
    R = (
        Rotation.from_euler("x", table.alpha[i]).as_matrix()
        @ Rotation.from_euler("y", table.beta[i]).as_matrix()
    )
    t = [table.a[i] * np.cos(th), table.a[i] * np.sin(th), table.d[i]]
    return transform_from_rt(rot_z(th) @ R, t)


# --------------------------------------------------------------------------- methods
def handeye_single_axis(
    T_board_camera: npt.ArrayLike, q_last: npt.ArrayLike, T_board_flange_zero: npt.ArrayLike
) -> HandEyeResult:
    """Single-axis hand–eye: only the last joint turns.

    Parameters
    ----------
    T_board_camera : array_like, shape (N, 4, 4), N >= 3
        Measured camera poses in the board frame.
    q_last : array_like, shape (N,)
        Reading of the last joint at each pose (rad); the other joints are fixed.
    T_board_flange_zero : array_like, shape (4, 4)
        Modelled flange pose in the board frame with the last joint at 0 (from the
        kinematic model and the board's pose in the base): supplies the position
        along the axis and the phase about it, which a rotation about one axis
        cannot reveal.

    Returns
    -------
    HandEyeResult
        ``T_board_flange`` is the corrected flange pose at ``q_last = 0``.

    Notes
    -----
    With the axis :math:`(c, n)` from :func:`fit_circle_3d`, the flange frame at
    :math:`q = 0` is rebuilt as origin :math:`c + n\\,n^\\top(o_F - c)`, z axis
    :math:`n`, x axis the modelled one projected onto :math:`n^\\perp`; then
    :math:`X = \\operatorname{mean}_k\\, (F_0 R_z(q_k))^{-1} T_{\\mathrm{board},\\mathrm{camera},k}`.
    """
    Tc = _check_poses("T_board_camera", T_board_camera, 3)
    q = _check_angles("q_last", q_last, Tc.shape[0])
    F_model = _check_poses("T_board_flange_zero", T_board_flange_zero)[0]
    if np.ptp(q) < 1e-3:
        raise ValueError("q_last must vary: the single-axis method needs the last joint to turn")
    fit = fit_circle_3d(Tc[:, :3, 3], q)
    n = fit.normal
    o = fit.centre + n * float(n @ (F_model[:3, 3] - fit.centre))
    x = F_model[:3, 0] - n * float(n @ F_model[:3, 0])
    if np.linalg.norm(x) < 1e-6:
        raise ValueError("the modelled flange x axis is parallel to the fitted joint axis")
    x /= np.linalg.norm(x)
    F0 = np.eye(4)
    F0[:3, 0], F0[:3, 1], F0[:3, 2], F0[:3, 3] = x, np.cross(n, x), n, o
    Xs = np.stack(
        [
            np.linalg.inv(F0 @ transform_from_rt(rot_z(qk), np.zeros(3))) @ Tk
            for qk, Tk in zip(q, Tc)
        ]
    )
    X = average_transforms(Xs)
    rr, rt = _spread(Xs, X)
    return HandEyeResult(X, F0, None, (fit,), rr, rt, "single_axis")


def handeye_two_axis(
    T_board_camera_a: npt.ArrayLike,
    q_a: npt.ArrayLike,
    q_last_during_a: float,
    T_board_camera_b: npt.ArrayLike,
    q_b: npt.ArrayLike,
    q_prev_during_b: float,
    table: MDHTable,
) -> HandEyeResult:
    """Two-axis hand–eye: joint ``n-1`` turns (sweep a), then joint ``n`` (sweep b).

    Parameters
    ----------
    T_board_camera_a : array_like, shape (Na, 4, 4), Na >= 3
        Camera poses in the board frame while joint ``n-1`` turns.
    q_a : array_like, shape (Na,)
        Readings of joint ``n-1`` in sweep a (rad).
    q_last_during_a : float
        Fixed reading of joint ``n`` during sweep a (rad).
    T_board_camera_b : array_like, shape (Nb, 4, 4), Nb >= 3
        Camera poses while joint ``n`` turns.
    q_b : array_like, shape (Nb,)
        Readings of joint ``n`` in sweep b (rad).
    q_prev_during_b : float
        Fixed reading of joint ``n-1`` during sweep b (rad).
    table : MDHTable
        Supplies the twist :math:`\\alpha_{n-1}` (sign of the x axis, must not be 0)
        and the last row (frame ``n-1`` to the flange). Joints ``1..n-2`` are the
        same in both sweeps.

    Returns
    -------
    HandEyeResult
        ``T_board_flange`` is the flange at joint ``n-1`` = ``q_prev_during_b``,
        joint ``n`` = ``q_last_during_a``.

    Notes
    -----
    Frame ``n-1`` has its origin at the foot :math:`W` of the common perpendicular
    on the last axis :math:`(c_b, n_b)`, z axis :math:`n_b` and x axis
    :math:`(n_a \\times n_b)/\\sin\\alpha_{n-1}`; the axes' gap (ideally
    :math:`|a_{n-1}|`) is not used.
    """
    Ta = _check_poses("T_board_camera_a", T_board_camera_a, 3)
    Tb = _check_poses("T_board_camera_b", T_board_camera_b, 3)
    qa = _check_angles("q_a", q_a, Ta.shape[0])
    qb = _check_angles("q_b", q_b, Tb.shape[0])
    s_alpha = np.sin(table.alpha[-2])
    if abs(s_alpha) < 1e-3:
        raise ValueError(
            "the last two joint axes of the table are parallel (alpha_{n-1} = 0); use "
            "handeye_single_axis"
        )
    fa = fit_circle_3d(Ta[:, :3, 3], qa)
    fb = fit_circle_3d(Tb[:, :3, 3], qb)
    na, nb = fa.normal, fb.normal
    cross = np.cross(na, nb)
    if np.linalg.norm(cross) < 1e-6:
        raise ValueError("the two fitted axes are parallel; sweeps of joints n-1 and n expected")
    # foot of the common perpendicular on axis b
    w0 = fa.centre - fb.centre
    b_ = float(na @ nb)
    d_ = float(na @ w0)
    e_ = float(nb @ w0)
    denom = 1.0 - b_**2
    t_b = (e_ - b_ * d_) / denom
    W = fb.centre + t_b * nb
    x = cross / s_alpha
    x /= np.linalg.norm(x)
    z = nb
    F_prev = np.eye(4)  # frame n-1 at q_{n-1} = q_prev_during_b
    F_prev[:3, 0], F_prev[:3, 1], F_prev[:3, 2], F_prev[:3, 3] = x, np.cross(z, x), z, W
    Xs = [np.linalg.inv(F_prev @ _last_row_transform(table, qk)) @ Tk for qk, Tk in zip(qb, Tb)]
    for qk, Tk in zip(qa, Ta):
        F_k = _axis_rotation(na, fa.centre, qk - q_prev_during_b) @ F_prev
        Xs.append(np.linalg.inv(F_k @ _last_row_transform(table, q_last_during_a)) @ Tk)
    Xs_arr = np.stack(Xs)
    X = average_transforms(Xs_arr)
    rr, rt = _spread(Xs_arr, X)
    F_ref = F_prev @ _last_row_transform(table, q_last_during_a)
    return HandEyeResult(X, F_ref, None, (fa, fb), rr, rt, "two_axis")


def _park_martin(A: FloatArray, B: FloatArray) -> FloatArray:
    alpha = Rotation.from_matrix(A[:, :3, :3]).as_rotvec()
    beta = Rotation.from_matrix(B[:, :3, :3]).as_rotvec()
    M = np.einsum("ni,nj->ij", beta, alpha)
    w, V = np.linalg.eigh(M.T @ M)
    if w.min() <= 1e-12 * max(w.max(), 1e-300):
        raise ValueError(
            "AX = XB is degenerate: the relative motions need rotations about at least two "
            "non-parallel axes"
        )
    R = V @ np.diag(1.0 / np.sqrt(w)) @ V.T @ M.T
    U, _, Vt = np.linalg.svd(R)
    R = U @ Vt
    lhs = (A[:, :3, :3] - np.eye(3)).reshape(-1, 3)
    rhs = (np.einsum("ij,njk->nik", R, B[:, :3, 3:]).reshape(-1, 3) - A[:, :3, 3]).reshape(-1)
    t = np.linalg.solve(np.einsum("ni,nj->ij", lhs, lhs), np.einsum("ni,n->i", lhs, rhs))
    return transform_from_rt(R, t)


def solve_ax_xb(
    T_base_flange: npt.ArrayLike,
    T_board_camera: npt.ArrayLike,
    method: AXXBMethod | str = AXXBMethod.AUTO,
) -> HandEyeResult:
    """General hand–eye calibration from flange and camera poses, :math:`AX = XB`.

    With :math:`F_k = T_{\\mathrm{base},\\mathrm{flange},k}` and
    :math:`C_k = T_{\\mathrm{board},\\mathrm{camera},k}`, a fixed board gives
    :math:`F_k X C_k^{-1} = \\mathrm{const}`, hence for every pair

    .. math::

        (F_j^{-1} F_i)\\, X = X\\, (C_j^{-1} C_i).

    Parameters
    ----------
    T_base_flange : array_like, shape (N, 4, 4), N >= 3
        Flange poses in the base frame (kinematic model).
    T_board_camera : array_like, shape (N, 4, 4)
        Camera poses in the board frame (measured).
    method : AXXBMethod or str
        ``"auto"``, ``"park"`` or one of the ``"opencv_*"`` methods (these raise
        ``RuntimeError`` when the installed OpenCV lacks ``calibrateHandEye``).

    Returns
    -------
    HandEyeResult
        With ``T_base_board`` the mean of :math:`F_k X C_k^{-1}`.
    """
    F = _check_poses("T_base_flange", T_base_flange, 3)
    C = _check_poses("T_board_camera", T_board_camera, 3)
    if F.shape[0] != C.shape[0]:
        raise ValueError(
            f"T_base_flange and T_board_camera need the same number of poses, got "
            f"{F.shape[0]} and {C.shape[0]}"
        )
    try:
        m = AXXBMethod(method)
    except ValueError:
        raise ValueError(
            f"method must be one of {[v.value for v in AXXBMethod]}, got {method!r}"
        ) from None
    has_cv = hasattr(cv2, "calibrateHandEye")
    if m is AXXBMethod.AUTO:
        m = AXXBMethod.OPENCV_PARK if has_cv else AXXBMethod.PARK
    if m is AXXBMethod.PARK:
        i, j = np.triu_indices(F.shape[0], k=1)
        A = np.linalg.inv(F[j]) @ F[i]
        B = np.linalg.inv(C[j]) @ C[i]
        X = _park_martin(A, B)
    else:
        if not has_cv:
            raise RuntimeError(
                f"method {m.value!r} needs cv2.calibrateHandEye, which this OpenCV build "
                f"({cv2.__version__}) does not provide; use method='park'"
            )
        flag = {
            AXXBMethod.OPENCV_PARK: "CALIB_HAND_EYE_PARK",
            AXXBMethod.OPENCV_TSAI: "CALIB_HAND_EYE_TSAI",
            AXXBMethod.OPENCV_DANIILIDIS: "CALIB_HAND_EYE_DANIILIDIS",
        }[m]
        Cinv = np.linalg.inv(C)
        R, t = cv2.calibrateHandEye(  # type: ignore[attr-defined]
            list(F[:, :3, :3]),
            list(F[:, :3, 3]),
            list(Cinv[:, :3, :3]),
            list(Cinv[:, :3, 3]),
            method=getattr(cv2, flag),
        )
        X = transform_from_rt(R, np.asarray(t).reshape(3))
    Zs = F @ X[None] @ np.linalg.inv(C)
    Z = average_transforms(Zs)
    rr, rt = _spread(Zs, Z)
    return HandEyeResult(X, None, Z, (), rr, rt, m.value)
