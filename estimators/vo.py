"""RGB-D visual odometry: features, graph matching, rigid registration.

The front end follows the classical RGB-D pipeline

1. detect and describe keypoints (SIFT, or ORB for speed) on the grey image;
2. match descriptors against the current key-frame with Lowe's ratio test;
3. reject outlier matches with Graph Transformation Matching (:func:`gtm_filter`);
4. back-project the matched keypoints with the depth image;
5. estimate the rigid motion with RANSAC over Kabsch fits (:func:`ransac_rigid`,
   :func:`kabsch_umeyama`), each pair weighted by its inverse depth variance,
   and refine it with point-to-point ICP (:func:`icp_point_to_point`);
6. chain the key-frame-relative motions into the camera trajectory; a frame
   becomes the next key-frame when the camera has moved or turned far enough or
   the inliers thin out.

Frames: ``camera`` is the optical frame (x right, y down, z forward), ``base``
the robot body (x forward, y left, z up), ``world`` the frame in which the
odometry starts. ``T_a_b`` is the 4×4 homogeneous transform that maps
coordinates in frame ``b`` to frame ``a`` (equivalently, the pose of ``b`` in
``a``). Lengths are in metres, angles in radians.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree
from scipy.spatial.distance import pdist, squareform

from realitygap.core.geometry import check_finite, transform_from_rt
from realitygap.estimators.base import CameraIntrinsics, Estimate, RGBDFrame

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.intp]
#: SIFT (N, 128) float32 or ORB (N, 32) uint8 descriptors.
Descriptors = npt.NDArray[np.integer[Any] | np.floating[Any]]

__all__ = [
    "T_BASE_CAMERA_FORWARD",
    "Detector",
    "RGBDVisualOdometry",
    "RegistrationError",
    "VOParams",
    "VOResult",
    "VOStatus",
    "check_transform",
    "gtm_filter",
    "icp_point_to_point",
    "kabsch_umeyama",
    "planar_motion_from_camera",
    "ransac_rigid",
]

#: Camera at the base origin looking along the base x axis: optical z = base x,
#: optical x = −base y, optical y = −base z.
T_BASE_CAMERA_FORWARD: FloatArray = np.array(
    [
        [0.0, 0.0, 1.0, 0.0],
        [-1.0, 0.0, 0.0, 0.0],
        [0.0, -1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
T_BASE_CAMERA_FORWARD.setflags(write=False)


class RegistrationError(RuntimeError):
    """A robust registration found no transform supported by enough inliers."""


# ----------------------------------------------------------------------------
# validation helpers
# ----------------------------------------------------------------------------


def _as_points(name: str, value: npt.ArrayLike, dim: int, min_count: int = 0) -> FloatArray:
    """Convert to a finite float array of shape (N, ``dim``) with N ≥ ``min_count``."""
    arr = check_finite(name, value)
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise ValueError(f"{name} must have shape (N, {dim}), got {arr.shape}")
    if arr.shape[0] < min_count:
        raise ValueError(f"{name} needs at least {min_count} points, got {arr.shape[0]}")
    return arr


def _check_rotation(name: str, value: npt.ArrayLike, atol: float = 1e-6) -> FloatArray:
    rot = check_finite(name, value, shape=(3, 3))
    if not np.allclose(rot.T @ rot, np.eye(3), atol=atol) or np.linalg.det(rot) < 0.0:
        raise ValueError(
            f"{name} must be a proper rotation matrix (RᵀR = I, det R = +1), got {rot!r}"
        )
    return rot


def check_transform(name: str, value: npt.ArrayLike, atol: float = 1e-6) -> FloatArray:
    """Validate a 4×4 rigid homogeneous transform and return it as a float array.

    Parameters
    ----------
    name : str
        Name used in the error message.
    value : array_like, shape (4, 4)
        Candidate transform ``[[R, t], [0, 0, 0, 1]]``.
    atol : float
        Tolerance on ``RᵀR = I`` and on the last row.

    Raises
    ------
    ValueError
        If the shape is not (4, 4), an entry is not finite, the last row is not
        ``[0, 0, 0, 1]`` or the upper-left block is not a proper rotation.
    """
    T = check_finite(name, value, shape=(4, 4))
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=atol):
        raise ValueError(f"{name} must have last row [0, 0, 0, 1], got {T[3]!r}")
    _check_rotation(f"{name}[:3, :3]", T[:3, :3], atol=atol)
    return T


def _inverse_transform(T: FloatArray) -> FloatArray:
    inv = np.eye(4)
    inv[:3, :3] = T[:3, :3].T
    inv[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return inv


def _rotation_angle(R: FloatArray) -> float:
    """Angle in rad of the axis–angle form of a rotation matrix."""
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


# ----------------------------------------------------------------------------
# Graph Transformation Matching
# ----------------------------------------------------------------------------


def gtm_filter(
    pts_p: npt.ArrayLike,
    pts_q: npt.ArrayLike,
    k: int | None = None,
    *,
    tolerance: float = 0.0,
) -> BoolArray:
    r"""Reject outlier matches with Graph Transformation Matching (GTM).

    Match ``i`` pairs ``pts_p[i]`` in image P with ``pts_q[i]`` in image Q. On
    each side a graph is built over the matched points, and matches are deleted
    one at a time until both graphs are identical.

    Without ``k`` (the default), vertices ``i`` and ``j`` are adjacent when

    .. math::

        \|p_i - p_j\| \le \eta_P, \qquad
        \eta_P = \frac{1}{m(m-1)} \sum_{i \ne j} \|p_i - p_j\|,

    the mean pairwise distance over the ``m`` matches still kept (likewise
    :math:`\eta_Q` in Q); the graph is invariant to a similarity transform of
    either image. With ``k``, the graph is the symmetrised k-nearest-neighbour
    graph: ``i–j`` when either is among the other's ``k`` nearest neighbours.

    With adjacency matrices :math:`A_P, A_Q` the residual is
    :math:`R = |A_P - A_Q|`; the match ``j* = argmaxⱼ Σᵢ Rᵢⱼ`` is deleted (first
    index on ties), the graphs are rebuilt on the remaining matches, and the
    loop stops when :math:`A_P = A_Q`. After an O(N²) set-up (pair distances,
    time and memory) both graph kinds are updated incrementally rather than
    rebuilt: a deletion costs about O(N) for the radius graph and O(k N) for the
    k-NN graph. Neighbours at exactly equal distances (duplicate keypoints)
    are ordered arbitrarily.

    Parameters
    ----------
    pts_p, pts_q : array_like, shape (N, 2)
        Pixel coordinates of the matched keypoints in images P and Q.
    k : int or None
        Neighbours per vertex of a k-NN graph; ``None`` for the mean-distance
        radius graph.
    tolerance : float
        Radius graph only: relative dead band :math:`\tau \in [0, 1)` around
        the threshold. An edge then counts as a disagreement only when it is
        clearly present in one image (:math:`d \le \eta (1 - \tau)`) and
        clearly absent in the other (:math:`d > \eta (1 + \tau)`). ``0`` is
        exact GTM; the exact radius graph flips edges near :math:`\eta` under
        keypoint noise, so a few per cent keeps inliers under real noise.

    Returns
    -------
    ndarray of bool, shape (N,)
        ``True`` for the matches kept (all of them when N < 3).

    Raises
    ------
    ValueError
        On mismatched or malformed point arrays, ``k < 1``, or ``tolerance``
        outside ``[0, 1)``, or ``tolerance`` given together with ``k``.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> p = rng.uniform(0, 300, (50, 2))
    >>> q = 1.1 * p + 5.0
    >>> q[:5] = rng.uniform(0, 300, (5, 2))  # five wrong matches
    >>> keep = gtm_filter(p, q)
    >>> bool(keep[5:].all()), int(keep[:5].sum())
    (True, 0)
    """
    p = _as_points("pts_p", pts_p, 2)
    q = _as_points("pts_q", pts_q, 2)
    if p.shape != q.shape:
        raise ValueError(f"pts_p and pts_q must have the same shape, got {p.shape} and {q.shape}")
    if k is not None:
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or k < 1:
            raise ValueError(f"k must be a positive integer or None, got {k!r}")
        if tolerance != 0.0:
            raise ValueError(f"tolerance applies to the radius graph (k=None) only, got k={k}")
    if not 0.0 <= tolerance < 1.0:
        raise ValueError(f"tolerance must lie in [0, 1), got {tolerance}")
    n = p.shape[0]
    if n < 3:
        return np.ones(n, dtype=bool)
    if k is None:
        return _gtm_radius(p, q, float(tolerance))
    return _gtm_knn(p, q, int(k))


_KEY_MAX = 65535


def _gtm_radius(p: FloatArray, q: FloatArray, tol: float) -> BoolArray:
    """GTM on mean-distance radius graphs, with incremental threshold updates.

    Pairs are kept sorted by distance in each image; when a deletion moves
    ``η``, only the pairs whose distance lies between the old and the new
    threshold(s) can change state, and only their residual entries are revised.
    """
    n = p.shape[0]
    dp, dq = pdist(p), pdist(q)  # condensed, pair (ia[c], ib[c]) for ia < ib
    ia, ib = np.triu_indices(n, 1)
    DP, DQ = squareform(dp), squareform(dq)
    sum_p, sum_q = DP.sum(axis=1), DQ.sum(axis=1)
    factors = (1.0,) if tol == 0.0 else (1.0 - tol, 1.0 + tol)

    def residual(d_p: FloatArray, d_q: FloatArray, eta_p: float, eta_q: float) -> BoolArray:
        on_p, off_p = d_p <= eta_p * (1.0 - tol), d_p > eta_p * (1.0 + tol)
        on_q, off_q = d_q <= eta_q * (1.0 - tol), d_q > eta_q * (1.0 + tol)
        return (on_p & off_q) | (off_p & on_q)

    m = n
    eta_p = float(sum_p.sum()) / (m * (m - 1))
    eta_q = float(sum_q.sum()) / (m * (m - 1))
    R = np.zeros((n, n), dtype=bool)
    r0 = residual(dp, dq, eta_p, eta_q)
    R[ia[r0], ib[r0]] = True
    R |= R.T
    col = R.sum(axis=0).astype(np.int64)
    # Pairs sorted by a 16-bit quantised distance (a linear-time radix sort);
    # a band of keys is a superset of the pairs between two thresholds, and
    # their residuals are recomputed from the exact distances.
    d_max_p, d_max_q = float(dp.max()), float(dq.max())
    scale_p = _KEY_MAX / d_max_p if d_max_p > 0.0 else 0.0  # all points coincide: one key
    scale_q = _KEY_MAX / d_max_q if d_max_q > 0.0 else 0.0
    key_p = (dp * scale_p).astype(np.uint16)
    key_q = (dq * scale_q).astype(np.uint16)
    order_p, order_q = np.argsort(key_p, kind="stable"), np.argsort(key_q, kind="stable")
    sorted_p, sorted_q = key_p[order_p], key_q[order_q]
    active = np.ones(n, dtype=bool)

    while m > 1:
        j = int(np.argmax(np.where(active, col, -1)))
        if col[j] <= 0:
            break
        active[j] = False
        col -= R[j]  # R, DP, DQ are symmetric: rows are contiguous
        R[j, :] = False
        R[:, j] = False
        m -= 1
        if m < 2:
            break
        sum_p -= DP[j]
        sum_q -= DQ[j]
        new_p = float(sum_p[active].sum()) / (m * (m - 1))
        new_q = float(sum_q[active].sum()) / (m * (m - 1))
        bands = []
        for srt, order, scale, old, new in (
            (sorted_p, order_p, scale_p, eta_p, new_p),
            (sorted_q, order_q, scale_q, eta_q, new_q),
        ):
            for f in factors:
                lo, hi = sorted((old * f * scale, new * f * scale))
                a = np.searchsorted(srt, np.uint16(min(int(lo), _KEY_MAX)), side="left")
                b = np.searchsorted(srt, np.uint16(min(int(hi), _KEY_MAX)), side="right")
                bands.append(order[a:b])
        eta_p, eta_q = new_p, new_q
        cand = np.unique(np.concatenate(bands))
        a_i, b_i = ia[cand], ib[cand]
        live = active[a_i] & active[b_i]
        cand, a_i, b_i = cand[live], a_i[live], b_i[live]
        if cand.size == 0:
            continue
        r_new = residual(dp[cand], dq[cand], eta_p, eta_q)
        changed = r_new != R[a_i, b_i]
        if not np.any(changed):
            continue
        a_c, b_c, r_c = a_i[changed], b_i[changed], r_new[changed]
        R[a_c, b_c] = r_c
        R[b_c, a_c] = r_c
        delta = np.where(r_c, 1, -1)
        col += np.bincount(a_c, weights=delta, minlength=n).astype(np.int64)
        col += np.bincount(b_c, weights=delta, minlength=n).astype(np.int64)
    return active


def _gtm_knn(p: FloatArray, q: FloatArray, k: int) -> BoolArray:
    """GTM on symmetrised k-NN graphs, updating only the rows a deletion touches."""
    n = p.shape[0]
    if k >= n - 1:
        return np.ones(n, dtype=bool)
    rows = np.arange(n)[:, None]
    graphs = []
    for pts in (p, q):
        D = squareform(pdist(pts))
        np.fill_diagonal(D, np.inf)
        order = np.argsort(D, axis=1)[:, : n - 1]  # self (inf) last, dropped
        K = np.zeros((n, n), dtype=bool)
        K[rows, order[:, :k]] = True
        graphs.append((order, K, K | K.T))
    (order_p, K_p, A_p), (order_q, K_q, A_q) = graphs
    R = A_p != A_q
    col = R.sum(axis=0).astype(np.int64)
    active = np.ones(n, dtype=bool)
    m = n

    while True:
        j = int(np.argmax(np.where(active, col, -1)))
        if col[j] <= 0:
            break
        active[j] = False
        col -= R[j]
        R[j, :] = False
        R[:, j] = False
        m -= 1
        if m - 1 <= k:  # complete graphs on both sides: consistent
            break
        touched = []
        for order, K, A in ((order_p, K_p, A_p), (order_q, K_q, A_q)):
            aff = np.flatnonzero(K[:, j] & active)
            K[j, :] = False
            K[:, j] = False
            A[j, :] = False
            A[:, j] = False
            if aff.size:
                nb = order[aff]
                act = active[nb]
                sel = act & (np.cumsum(act, axis=1) <= k)
                K[aff, :] = False
                K[np.broadcast_to(aff[:, None], nb.shape)[sel], nb[sel]] = True
            touched.append(aff)
        U = np.union1d(touched[0], touched[1])
        if U.size == 0:
            continue
        for K, A in ((K_p, A_p), (K_q, A_q)):
            A[U, :] = K[U, :] | K[:, U].T
            A[:, U] = A[U, :].T
        r_new = (A_p[U, :] != A_q[U, :]) & active[None, :]
        diff = r_new.astype(np.int64) - R[U, :]
        delta = diff.sum(axis=0)
        outside = np.ones(n, dtype=bool)
        outside[U] = False
        delta[U] += diff[:, outside].sum(axis=1)
        R[U, :] = r_new
        R[:, U] = r_new.T
        col += delta
    return active


# ----------------------------------------------------------------------------
# rigid registration
# ----------------------------------------------------------------------------


def kabsch_umeyama(
    P: npt.ArrayLike,
    Q: npt.ArrayLike,
    weights: npt.ArrayLike | None = None,
    with_scale: bool = False,
) -> tuple[FloatArray, FloatArray] | tuple[FloatArray, FloatArray, float]:
    r"""Least-squares rigid (or similarity) transform between corresponding points.

    Minimises

    .. math::

        \sum_i w_i \, \| s R P_i + t - Q_i \|^2

    over rotations :math:`R \in SO(3)`, translations :math:`t` and (with
    ``with_scale``) the scale :math:`s > 0`. With weighted centroids
    :math:`\bar P, \bar Q` and cross-covariance
    :math:`H = \sum_i w_i (P_i - \bar P)(Q_i - \bar Q)^\top = U \Sigma V^\top`,
    :math:`R = V \operatorname{diag}(1, 1, d) U^\top` with
    :math:`d = \operatorname{sign}\det(V U^\top)`,
    :math:`s = \operatorname{tr}(\Sigma D) / \sum_i w_i \|P_i - \bar P\|^2`
    and :math:`t = \bar Q - s R \bar P` (Umeyama 1991).

    Parameters
    ----------
    P, Q : array_like, shape (N, 3)
        Corresponding points, N ≥ 3, in the source and target frames [m].
    weights : array_like, shape (N,), optional
        Non-negative weights with a positive sum; uniform by default.
    with_scale : bool
        Also estimate the scale ``s``.

    Returns
    -------
    R : ndarray, shape (3, 3)
        Rotation, source → target.
    t : ndarray, shape (3,)
        Translation [m].
    s : float
        Scale; only returned when ``with_scale`` is true.

    Raises
    ------
    ValueError
        On malformed inputs or invalid weights.
    """
    P = _as_points("P", P, 3, min_count=3)
    Q = _as_points("Q", Q, 3, min_count=3)
    if P.shape != Q.shape:
        raise ValueError(f"P and Q must have the same shape, got {P.shape} and {Q.shape}")
    if weights is None:
        w = np.full(P.shape[0], 1.0 / P.shape[0])
    else:
        w = _check_weights(weights, P.shape[0])
        w = w / w.sum()
    mu_p, mu_q = w @ P, w @ Q
    Pc, Qc = P - mu_p, Q - mu_q
    H = (Pc * w[:, None]).T @ Qc
    U, S, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    D = np.array([1.0, 1.0, 1.0 if d == 0.0 else d])
    R = (Vt.T * D) @ U.T
    if not with_scale:
        return R, mu_q - R @ mu_p
    var_p = float(w @ np.einsum("ij,ij->i", Pc, Pc))
    if var_p <= 0.0:
        raise ValueError("P has no spread; the scale is undefined")
    s = float(S @ D) / var_p
    return R, mu_q - s * R @ mu_p, s


def _kabsch_batch(P: FloatArray, Q: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Unweighted Kabsch on a stack of samples, P, Q shape (B, n, 3)."""
    mu_p, mu_q = P.mean(axis=1), Q.mean(axis=1)
    H = np.einsum("bni,bnj->bij", P - mu_p[:, None], Q - mu_q[:, None])
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, 1, 2)
    d = np.sign(np.linalg.det(V @ np.swapaxes(U, 1, 2)))
    V[:, :, 2] *= np.where(d == 0.0, 1.0, d)[:, None]
    R = V @ np.swapaxes(U, 1, 2)
    t = mu_q - np.einsum("bij,bj->bi", R, mu_p)
    return R, t


def ransac_rigid(
    P: npt.ArrayLike,
    Q: npt.ArrayLike,
    threshold_m: float,
    rng: np.random.Generator,
    max_iters: int = 500,
    min_inliers: int = 6,
    *,
    confidence: float = 0.999,
    weights: npt.ArrayLike | None = None,
) -> tuple[FloatArray, FloatArray, BoolArray]:
    r"""Robust rigid transform ``Q ≈ R P + t`` by RANSAC over 3-point Kabsch fits.

    Hypotheses come from random non-degenerate triples and are scored with the
    truncated quadratic (MSAC) cost
    :math:`\sum_i \min(\|R P_i + t - Q_i\|^2, \delta^2)`; the best one is refit on
    its inliers (:math:`\|R P_i + t - Q_i\| < \delta`) until the inlier set is
    stable. Sampling stops early once
    :math:`1 - (1 - w^3)^{n} \ge` ``confidence`` for inlier ratio ``w``.

    Parameters
    ----------
    P, Q : array_like, shape (N, 3)
        Putative correspondences [m].
    threshold_m : float
        Inlier distance :math:`\delta` [m], > 0.
    rng : numpy.random.Generator
        Source of the random samples.
    max_iters : int
        Upper bound on the hypotheses drawn.
    min_inliers : int
        Fewest inliers (≥ 3) for a valid result.
    confidence : float
        Stopping confidence in (0, 1).
    weights : array_like, shape (N,), optional
        Non-negative weights of the inlier refit (e.g. inverse noise variances);
        hypotheses are scored unweighted.

    Returns
    -------
    R : ndarray, shape (3, 3)
    t : ndarray, shape (3,)
    inliers : ndarray of bool, shape (N,)

    Raises
    ------
    ValueError
        On malformed inputs or parameters.
    RegistrationError
        When no hypothesis has ``min_inliers`` inliers.
    """
    P = _as_points("P", P, 3)
    Q = _as_points("Q", Q, 3)
    if P.shape != Q.shape:
        raise ValueError(f"P and Q must have the same shape, got {P.shape} and {Q.shape}")
    if not (np.isfinite(threshold_m) and threshold_m > 0.0):
        raise ValueError(f"threshold_m must be a positive finite distance in m, got {threshold_m}")
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if max_iters < 1:
        raise ValueError(f"max_iters must be ≥ 1, got {max_iters}")
    if min_inliers < 3:
        raise ValueError(f"min_inliers must be ≥ 3, got {min_inliers}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
    n = P.shape[0]
    w = None if weights is None else _check_weights(weights, n)
    if n < min_inliers:
        raise RegistrationError(f"{n} correspondences, fewer than min_inliers={min_inliers}")

    thr2 = threshold_m * threshold_m
    best_cost, best_R, best_t = np.inf, np.eye(3), np.zeros(3)
    best_count, drawn, needed, batch = 0, 0, float(max_iters), 64
    while drawn < min(max_iters, needed):
        b = min(batch, max_iters - drawn)
        drawn += b
        idx = (
            np.argsort(rng.random((b, n)), axis=1)[:, :3] if n < 64 else _sample_triples(rng, b, n)
        )
        Ps, Qs = P[idx], Q[idx]
        area = np.linalg.norm(np.cross(Ps[:, 1] - Ps[:, 0], Ps[:, 2] - Ps[:, 0]), axis=1)
        good = area > thr2
        if not np.any(good):
            continue
        Rb, tb = _kabsch_batch(Ps[good], Qs[good])
        res = np.einsum("bij,nj->bni", Rb, P) + tb[:, None, :] - Q[None]
        e2 = np.einsum("bni,bni->bn", res, res)
        cost = np.minimum(e2, thr2).sum(axis=1)
        i_best = int(np.argmin(cost))
        if cost[i_best] < best_cost:
            best_cost, best_R, best_t = float(cost[i_best]), Rb[i_best], tb[i_best]
            best_count = int(np.count_nonzero(e2[i_best] < thr2))
            ratio = best_count / n
            if ratio >= 1.0:
                needed = 0.0
            elif ratio > 0.0:
                needed = np.log(1.0 - confidence) / np.log1p(-(ratio**3))
    if best_count < min_inliers:
        raise RegistrationError(
            f"best hypothesis has {best_count} inliers within {threshold_m} m, "
            f"fewer than min_inliers={min_inliers}"
        )
    R, t = best_R, best_t
    mask = np.zeros(n, dtype=bool)
    for _ in range(5):
        e2 = np.sum((P @ R.T + t - Q) ** 2, axis=1)
        new_mask = e2 < thr2
        if new_mask.sum() < min_inliers or np.array_equal(new_mask, mask):
            break
        if w is not None and not np.any(w[new_mask] > 0.0):
            break
        mask = new_mask
        R, t = kabsch_umeyama(P[mask], Q[mask], None if w is None else w[mask])  # type: ignore[misc]
    mask = np.sum((P @ R.T + t - Q) ** 2, axis=1) < thr2
    if mask.sum() < min_inliers:
        raise RegistrationError(f"refit kept {int(mask.sum())} inliers, fewer than {min_inliers}")
    return R, t, mask


def _check_weights(weights: npt.ArrayLike, n: int) -> FloatArray:
    w = check_finite("weights", weights, shape=(n,))
    if np.any(w < 0.0) or not w.sum() > 0.0:
        raise ValueError("weights must be non-negative with a positive sum")
    return w


def _sample_triples(rng: np.random.Generator, b: int, n: int) -> IntArray:
    """``b`` triples of distinct indices in ``[0, n)`` (rejection of repeats)."""
    idx = rng.integers(0, n, size=(b, 3))
    while True:
        bad = (idx[:, 0] == idx[:, 1]) | (idx[:, 0] == idx[:, 2]) | (idx[:, 1] == idx[:, 2])
        if not np.any(bad):
            return idx
        idx[bad] = rng.integers(0, n, size=(int(bad.sum()), 3))


def icp_point_to_point(
    src: npt.ArrayLike,
    dst: npt.ArrayLike,
    R0: npt.ArrayLike | None = None,
    t0: npt.ArrayLike | None = None,
    max_iters: int = 30,
    tol: float = 1e-6,
    *,
    max_correspondence_m: float | None = None,
    weights: npt.ArrayLike | None = None,
) -> tuple[FloatArray, FloatArray, float, int]:
    r"""Point-to-point ICP aligning ``src`` to ``dst``: ``dst ≈ R src + t``.

    Each iteration pairs every transformed source point with its nearest
    destination point (k-d tree), drops pairs farther than
    ``max_correspondence_m``, and solves for the full transform with
    :func:`kabsch_umeyama` on the pairs. It stops when the RMS of the pair
    distances changes by less than ``tol``:

    .. math::

        \mathrm{rms}_k = \sqrt{\tfrac{1}{n_k} \textstyle\sum_i
        \| R_k\, s_i + t_k - d_{\pi(i)} \|^2 }, \qquad
        |\mathrm{rms}_{k-1} - \mathrm{rms}_k| < \varepsilon .

    Parameters
    ----------
    src : array_like, shape (N, 3)
        Source cloud [m], N ≥ 3.
    dst : array_like, shape (M, 3)
        Destination cloud [m], M ≥ 3.
    R0, t0 : array_like, shapes (3, 3) and (3,), optional
        Initial guess; identity and zero by default.
    max_iters : int
        Iteration cap, ≥ 1.
    tol : float
        RMS change ε [m] that ends the iteration, ≥ 0.
    max_correspondence_m : float, optional
        Reject pairs farther apart than this [m]; all pairs by default.
    weights : array_like, shape (N,), optional
        Non-negative weights of the source points in the Kabsch step (e.g.
        inverse noise variances). Zero-weight points are left out; the RMS is
        the unweighted RMS over the others.

    Returns
    -------
    R : ndarray, shape (3, 3)
    t : ndarray, shape (3,)
    rms : float
        RMS pair distance [m] at the returned transform.
    iterations : int
        Iterations run.

    Raises
    ------
    ValueError
        On malformed inputs, or when fewer than 3 pairs survive the gating.
    """
    src = _as_points("src", src, 3, min_count=3)
    dst = _as_points("dst", dst, 3, min_count=3)
    R = np.eye(3) if R0 is None else _check_rotation("R0", R0)
    t = np.zeros(3) if t0 is None else check_finite("t0", t0, shape=(3,))
    if max_iters < 1:
        raise ValueError(f"max_iters must be ≥ 1, got {max_iters}")
    if not tol >= 0.0:
        raise ValueError(f"tol must be ≥ 0 m, got {tol}")
    if max_correspondence_m is not None and not max_correspondence_m > 0.0:
        raise ValueError(f"max_correspondence_m must be > 0 m or None, got {max_correspondence_m}")
    w = np.ones(src.shape[0]) if weights is None else _check_weights(weights, src.shape[0])
    tree = cKDTree(dst)
    bound = np.inf if max_correspondence_m is None else float(max_correspondence_m)

    def pairs(R: FloatArray, t: FloatArray) -> tuple[FloatArray, IntArray, BoolArray]:
        d, nn = tree.query(src @ R.T + t, k=1, distance_upper_bound=bound)
        ok = np.isfinite(d) & (w > 0.0)
        if np.count_nonzero(ok) < 3:
            raise ValueError(
                f"ICP kept {int(np.count_nonzero(ok))} correspondences within "
                f"{max_correspondence_m} m; need at least 3 (improve the initial guess)"
            )
        return d, nn, ok

    d, nn, ok = pairs(R, t)
    rms = float(np.sqrt(np.mean(d[ok] ** 2)))
    iterations = 0
    for iterations in range(1, max_iters + 1):  # noqa: B007 - reported to the caller
        R_new, t_new = kabsch_umeyama(src[ok], dst[nn[ok]], w[ok])  # type: ignore[misc]
        d_new, nn_new, ok_new = pairs(R_new, t_new)
        rms_new = float(np.sqrt(np.mean(d_new[ok_new] ** 2)))
        converged = abs(rms - rms_new) < tol
        R, t, d, nn, ok, rms = R_new, t_new, d_new, nn_new, ok_new, rms_new
        if converged:
            break
    return R, t, rms, iterations


# ----------------------------------------------------------------------------
# visual odometry
# ----------------------------------------------------------------------------


class VOStatus(str, Enum):
    """Outcome of one :meth:`RGBDVisualOdometry.update`."""

    OK = "ok"
    """Motion estimated."""
    INITIALISED = "initialised"
    """First usable frame: it became the first key-frame."""
    RESET = "reset"
    """State after :meth:`RGBDVisualOdometry.reset`; no frame seen yet."""
    NO_FRAME = "no_frame"
    """``update(None)``: nothing measured this step."""
    NO_FEATURES = "no_features"
    """Too few keypoints (blank or blurred image)."""
    TOO_FEW_MATCHES = "too_few_matches"
    """Too few descriptor matches with the key-frame, or too few after GTM."""
    DEPTH_HOLES = "depth_holes"
    """Too few matched keypoints with valid depth."""
    RANSAC_FAILED = "ransac_failed"
    """No rigid motion explains enough matches."""
    REINITIALISED = "reinitialised"
    """Tracking was lost for too long; this frame starts a new key-frame at the
    last good pose (the motion since then is unknown)."""


class Detector(str, Enum):
    """Keypoint detector and descriptor."""

    SIFT = "sift"
    ORB = "orb"


@dataclass(frozen=True)
class VOParams:
    r"""Settings of :class:`RGBDVisualOdometry`.

    Attributes
    ----------
    detector : {"sift", "orb"}
        SIFT (128-D float descriptors, L2 matching) or ORB (256-bit binary,
        Hamming matching).
    max_features : int
        Keypoints kept per frame.
    ratio : float
        Lowe ratio test: keep a match when its distance is below ``ratio`` times
        the second-best.
    min_keypoints : int
        Fewer keypoints make the frame ``no_features``.
    min_matches : int
        Fewer matches after the ratio test (or after GTM) make the frame
        ``too_few_matches``.
    use_gtm : bool
        Reject outliers with :func:`gtm_filter` before RANSAC.
    gtm_k : int or None
        ``k`` of the GTM graph (``None``: mean-distance radius graph).
    gtm_tolerance : float
        Dead band of the radius graph (see :func:`gtm_filter`).
    ransac_threshold_m : float
        RANSAC inlier distance [m].
    ransac_max_iters : int
        RANSAC hypothesis cap.
    min_inliers : int
        Fewest RANSAC inliers for a valid motion.
    depth_weighting : bool
        Weight each correspondence in the refits by its inverse depth variance,
        :math:`w_i = 1 / (z_{i,\mathrm{prev}}^4 + z_{i,\mathrm{curr}}^4)`, for the
        :math:`\sigma_z \propto z^2` noise of RGB-D sensors.
    use_icp : bool
        Refine the RANSAC motion with point-to-point ICP on the inlier points.
    icp_max_iters : int
        ICP iteration cap.
    icp_tol_m : float
        ICP stopping RMS change [m].
    keyframe_min_inliers : int
        Start a new key-frame when fewer inliers than this remain.
    keyframe_translation_m : float
        Start a new key-frame after this camera translation [m] from the last.
    keyframe_rotation_rad : float
        Start a new key-frame after this camera rotation [rad] from the last.
    depth_min_m, depth_max_m : float
        Valid depth range [m] (Kinect V2: 0.5–8 m).
    depth_edge_ratio : float
        Reject a keypoint when its 2×2 depth neighbourhood spreads by more than
        this fraction of its depth (depth discontinuity).
    max_lost_frames : int
        After this many consecutive failed frames that still had features, the
        next such frame becomes a new key-frame (status ``reinitialised``).
    seed : int
        Seed of the RANSAC sampler (reset with :meth:`RGBDVisualOdometry.reset`).
    """

    detector: Detector | str = Detector.SIFT
    max_features: int = 500
    ratio: float = 0.75
    min_keypoints: int = 10
    min_matches: int = 8
    use_gtm: bool = True
    gtm_k: int | None = None
    gtm_tolerance: float = 0.05
    ransac_threshold_m: float = 0.04
    ransac_max_iters: int = 300
    min_inliers: int = 8
    depth_weighting: bool = True
    use_icp: bool = True
    icp_max_iters: int = 20
    icp_tol_m: float = 1e-5
    keyframe_min_inliers: int = 60
    keyframe_translation_m: float = 0.25
    keyframe_rotation_rad: float = float(np.deg2rad(15.0))
    depth_min_m: float = 0.5
    depth_max_m: float = 8.0
    depth_edge_ratio: float = 0.05
    max_lost_frames: int = 5
    seed: int = 0

    def __post_init__(self) -> None:
        try:
            object.__setattr__(
                self,
                "detector",
                Detector(str(getattr(self.detector, "value", self.detector)).lower()),
            )
        except ValueError:
            names = ", ".join(repr(d.value) for d in Detector)
            raise ValueError(f"detector must be one of {names}, got {self.detector!r}") from None
        positive_ints = (
            "max_features",
            "min_keypoints",
            "min_matches",
            "ransac_max_iters",
            "icp_max_iters",
        )
        for name in positive_ints:
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be ≥ 1, got {getattr(self, name)}")
        if self.min_inliers < 3:
            raise ValueError(f"min_inliers must be ≥ 3, got {self.min_inliers}")
        if not 0.0 < self.ratio <= 1.0:
            raise ValueError(f"ratio must lie in (0, 1], got {self.ratio}")
        if self.gtm_k is not None and self.gtm_k < 1:
            raise ValueError(f"gtm_k must be ≥ 1 or None, got {self.gtm_k}")
        if not 0.0 <= self.gtm_tolerance < 1.0:
            raise ValueError(f"gtm_tolerance must lie in [0, 1), got {self.gtm_tolerance}")
        for name in ("ransac_threshold_m", "keyframe_translation_m", "keyframe_rotation_rad"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if not 0.0 < self.depth_min_m < self.depth_max_m:
            raise ValueError(
                f"need 0 < depth_min_m < depth_max_m, got {self.depth_min_m} and {self.depth_max_m}"
            )
        if not self.depth_edge_ratio > 0.0:
            raise ValueError(f"depth_edge_ratio must be > 0, got {self.depth_edge_ratio}")
        if self.icp_tol_m < 0.0 or self.max_lost_frames < 0 or self.keyframe_min_inliers < 0:
            raise ValueError("icp_tol_m, max_lost_frames and keyframe_min_inliers must be ≥ 0")


@dataclass
class VOResult:
    """Output of :meth:`RGBDVisualOdometry.update`.

    The transforms always satisfy ``T_world_camera = T_world_keyframe @ T_prev_curr``
    and are never NaN; when ``ok`` is false they hold the last good estimate.

    Attributes
    ----------
    t : float
        Time stamp [s] of the frame (of the last frame for ``update(None)``).
    T_world_camera : ndarray, shape (4, 4)
        Camera pose in the world.
    T_prev_curr : ndarray, shape (4, 4)
        Camera motion from the reference key-frame to this frame (pose of this
        camera in the key-frame's camera frame).
    T_world_keyframe : ndarray, shape (4, 4)
        Pose of the reference key-frame.
    pose : ndarray, shape (3,)
        Planar base pose ``[x, y, theta]`` (m, m, rad) in the world, from
        ``T_world_camera`` and the camera mounting.
    ok : bool
        Whether this frame produced a motion estimate.
    status : str
        A :class:`VOStatus` value.
    n_keypoints, n_matches, n_gtm, n_depth, n_inliers : int
        Keypoints in the frame; matches after the ratio test; after GTM; with
        valid depth on both sides; RANSAC/ICP inliers.
    keyframe : bool
        This frame became the new key-frame.
    rms_m : float
        RMS 3-D residual of the inliers at the final motion [m] (``nan``-free;
        0 when no motion was estimated).
    inlier_indices : ndarray of int, shape (n, 2)
        Keypoint indices ``(key-frame, current)`` of the inlier matches.
    inlier_pixels_prev, inlier_pixels_curr : ndarray, shape (n, 2)
        Their pixel coordinates ``(u, v)``.
    inlier_points_prev, inlier_points_curr : ndarray, shape (n, 3)
        Their 3-D points in the key-frame and current camera frames [m].
    """

    t: float
    T_world_camera: FloatArray
    T_prev_curr: FloatArray
    T_world_keyframe: FloatArray
    pose: FloatArray
    ok: bool
    status: str
    n_keypoints: int = 0
    n_matches: int = 0
    n_gtm: int = 0
    n_depth: int = 0
    n_inliers: int = 0
    keyframe: bool = False
    rms_m: float = 0.0
    inlier_indices: npt.NDArray[np.intp] = field(default_factory=lambda: np.zeros((0, 2), np.intp))
    inlier_pixels_prev: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    inlier_pixels_curr: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    inlier_points_prev: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    inlier_points_curr: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))

    def to_estimate(self) -> Estimate:
        """This result as an :class:`~realitygap.estimators.base.Estimate`.

        ``pose`` is the planar base pose; ``extras["vo"]`` holds this result.
        """
        return Estimate(
            t=self.t, pose=self.pose.copy(), ok=self.ok, status=self.status, extras={"vo": self}
        )


@dataclass
class _Keyframe:
    T_world_camera: FloatArray
    pixels: FloatArray  # (n, 2)
    descriptors: Descriptors
    points: FloatArray  # (n, 3), nan where depth is invalid


def planar_motion_from_camera(
    T_prev_curr: npt.ArrayLike, T_base_camera: npt.ArrayLike | None = None
) -> tuple[float, float, float]:
    r"""Planar base increment ``(dx, dy, dθ)`` from a camera motion.

    The base motion is the camera motion seen through the mounting,

    .. math::

        T_{b_0 b_1} = T_{bc}\, T_{c_0 c_1}\, T_{bc}^{-1},

    and the increment is its translation along base x (forward) and y (left)
    [m] and its rotation about base z [rad], :math:`\operatorname{atan2}(R_{10},
    R_{00})`. Out-of-plane components are dropped.

    Parameters
    ----------
    T_prev_curr : array_like, shape (4, 4)
        Pose of the current camera (optical frame) in the previous one.
    T_base_camera : array_like, shape (4, 4), optional
        Camera mounting on the base; :data:`T_BASE_CAMERA_FORWARD` by default.

    Returns
    -------
    tuple of float
        ``(dx, dy, dtheta)`` in the previous base frame.
    """
    T_cc = check_transform("T_prev_curr", T_prev_curr)
    T_bc = (
        T_BASE_CAMERA_FORWARD
        if T_base_camera is None
        else check_transform("T_base_camera", T_base_camera)
    )
    T_bb = T_bc @ T_cc @ _inverse_transform(T_bc)
    return float(T_bb[0, 3]), float(T_bb[1, 3]), float(np.arctan2(T_bb[1, 0], T_bb[0, 0]))


def _planar_pose(T_world_base: FloatArray) -> FloatArray:
    return np.array(
        [T_world_base[0, 3], T_world_base[1, 3], np.arctan2(T_world_base[1, 0], T_world_base[0, 0])]
    )


class RGBDVisualOdometry:
    """Key-frame RGB-D visual odometry (see the module docstring for the pipeline).

    Each frame is registered against the current key-frame; a frame becomes
    the new key-frame when the inliers thin out or the camera has moved or
    turned far enough, which limits drift while the robot stands still.

    Parameters
    ----------
    params : VOParams, optional
        Settings; defaults if omitted.
    T_base_camera : array_like, shape (4, 4), optional
        Camera mounting on the base, used for :attr:`VOResult.pose` and as the
        default initial camera pose; :data:`T_BASE_CAMERA_FORWARD` by default.

    Examples
    --------
    >>> vo = RGBDVisualOdometry(VOParams(detector="orb"))
    >>> vo.update(None).status
    'no_frame'
    """

    def __init__(
        self, params: VOParams | None = None, T_base_camera: npt.ArrayLike | None = None
    ) -> None:
        self.params = VOParams() if params is None else params
        if not isinstance(self.params, VOParams):
            raise TypeError(f"params must be a VOParams, got {type(self.params).__name__}")
        self.T_base_camera = (
            T_BASE_CAMERA_FORWARD.copy()
            if T_base_camera is None
            else check_transform("T_base_camera", T_base_camera)
        )
        self._T_camera_base = _inverse_transform(self.T_base_camera)
        p = self.params
        self._detector: cv2.Feature2D
        if p.detector == Detector.SIFT:
            self._detector = cv2.SIFT.create(nfeatures=p.max_features)
            self._matcher = cv2.BFMatcher(cv2.NORM_L2)
        else:
            self._detector = cv2.ORB.create(nfeatures=p.max_features)
            self._matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
        self.reset()

    # -- state ---------------------------------------------------------------

    def reset(self, initial_T_world_camera: npt.ArrayLike | None = None) -> VOResult:
        """Forget all frames and start at ``initial_T_world_camera``.

        Parameters
        ----------
        initial_T_world_camera : array_like, shape (4, 4), optional
            Initial camera pose; by default the base starts at the world origin,
            i.e. the camera pose is ``T_base_camera``.

        Returns
        -------
        VOResult
            The initial state, status ``reset``.
        """
        T0 = (
            self.T_base_camera.copy()
            if initial_T_world_camera is None
            else check_transform("initial_T_world_camera", initial_T_world_camera)
        )
        self._rng = np.random.default_rng(self.params.seed)
        self._keyframe: _Keyframe | None = None
        self._T_world_kf = T0.copy()
        self._T_kf_curr = np.eye(4)
        self._t = 0.0
        self._lost = 0
        return self._result(VOStatus.RESET, ok=True)

    @property
    def T_world_camera(self) -> FloatArray:
        """Last good camera pose in the world, shape (4, 4)."""
        return self._T_world_kf @ self._T_kf_curr

    def _result(self, status: VOStatus, ok: bool, **counts: object) -> VOResult:
        T_wc = self._T_world_kf @ self._T_kf_curr
        return VOResult(
            t=self._t,
            T_world_camera=T_wc,
            T_prev_curr=self._T_kf_curr.copy(),
            T_world_keyframe=self._T_world_kf.copy(),
            pose=_planar_pose(T_wc @ self._T_camera_base),
            ok=ok,
            status=status.value,
            **counts,  # type: ignore[arg-type]
        )

    # -- per frame -----------------------------------------------------------

    def update(self, frame: RGBDFrame | None) -> VOResult:
        """Consume one RGB-D frame (or ``None``) and return the motion estimate.

        Never raises on image content: blank images, depth holes and failed
        registrations come back as ``ok=False`` with a :class:`VOStatus`.

        Parameters
        ----------
        frame : RGBDFrame or None
            Colour (H, W, 3) uint8 or grey (H, W) uint8 image, depth (H, W) [m]
            with ``nan`` for no return, and the intrinsics.

        Returns
        -------
        VOResult

        Raises
        ------
        TypeError, ValueError
            If ``frame`` is not an :class:`RGBDFrame` or its arrays do not match
            its intrinsics.
        """
        if frame is None:
            return self._result(VOStatus.NO_FRAME, ok=False)
        gray, depth = self._check_frame(frame)
        self._t = float(frame.t)
        p = self.params

        kps, raw = self._detector.detectAndCompute(gray, None)
        n_kp = 0 if raw is None else len(kps)
        if n_kp < p.min_keypoints:
            return self._result(VOStatus.NO_FEATURES, ok=False, n_keypoints=n_kp)
        desc: Descriptors = np.asarray(raw)
        pixels = np.array([kp.pt for kp in kps], dtype=float)
        points = self._back_project(pixels, depth, frame.intrinsics)
        valid_now = np.all(np.isfinite(points), axis=1)

        kf = self._keyframe
        if kf is None:
            if np.count_nonzero(valid_now) < p.min_inliers:
                return self._result(VOStatus.DEPTH_HOLES, ok=False, n_keypoints=n_kp)
            self._set_keyframe(pixels, desc, points, self._T_world_kf)
            return self._result(VOStatus.INITIALISED, ok=True, n_keypoints=n_kp, keyframe=True)

        counts: dict[str, object] = {"n_keypoints": n_kp}
        i_kf, i_cur = self._match(kf.descriptors, desc)
        counts["n_matches"] = counts["n_gtm"] = len(i_kf)
        if len(i_kf) < p.min_matches:
            return self._lost_frame(VOStatus.TOO_FEW_MATCHES, pixels, desc, points, counts)
        if p.use_gtm:
            keep = gtm_filter(
                kf.pixels[i_kf],
                pixels[i_cur],
                k=p.gtm_k,
                tolerance=0.0 if p.gtm_k else p.gtm_tolerance,
            )
            i_kf, i_cur = i_kf[keep], i_cur[keep]
            counts["n_gtm"] = len(i_kf)
            if len(i_kf) < p.min_matches:
                return self._lost_frame(VOStatus.TOO_FEW_MATCHES, pixels, desc, points, counts)
        has_depth = np.all(np.isfinite(kf.points[i_kf]), axis=1) & valid_now[i_cur]
        i_kf, i_cur = i_kf[has_depth], i_cur[has_depth]
        counts["n_depth"] = len(i_kf)
        if len(i_kf) < p.min_inliers:
            return self._lost_frame(VOStatus.DEPTH_HOLES, pixels, desc, points, counts)

        P_kf, P_cur = kf.points[i_kf], points[i_cur]
        # σ_z ∝ z² for RGB-D sensors: weight each pair by its inverse depth variance
        w = 1.0 / (P_kf[:, 2] ** 4 + P_cur[:, 2] ** 4) if p.depth_weighting else None
        try:
            R, t, inl = ransac_rigid(
                P_cur,
                P_kf,
                p.ransac_threshold_m,
                self._rng,
                p.ransac_max_iters,
                p.min_inliers,
                weights=w,
            )
        except RegistrationError:
            return self._lost_frame(VOStatus.RANSAC_FAILED, pixels, desc, points, counts)
        if p.use_icp:
            R, t = self._refine(P_cur[inl], P_kf[inl], R, t, None if w is None else w[inl])
        res = P_cur[inl] @ R.T + t - P_kf[inl]
        counts["rms_m"] = float(np.sqrt(np.mean(np.sum(res * res, axis=1))))
        n_inliers = int(np.count_nonzero(inl))
        counts["n_inliers"] = n_inliers
        i_kf, i_cur = i_kf[inl], i_cur[inl]
        counts["inlier_indices"] = np.stack([i_kf, i_cur], axis=1)
        counts["inlier_pixels_prev"] = kf.pixels[i_kf]
        counts["inlier_pixels_curr"] = pixels[i_cur]
        counts["inlier_points_prev"] = kf.points[i_kf]
        counts["inlier_points_curr"] = points[i_cur]

        self._lost = 0
        self._T_kf_curr = transform_from_rt(R, t)
        new_kf = (
            n_inliers < p.keyframe_min_inliers
            or float(np.linalg.norm(t)) > p.keyframe_translation_m
            or _rotation_angle(R) > p.keyframe_rotation_rad
        )
        result = self._result(VOStatus.OK, ok=True, keyframe=new_kf, **counts)
        if new_kf:
            self._set_keyframe(pixels, desc, points, result.T_world_camera)
        return result

    # -- helpers -------------------------------------------------------------

    def _check_frame(self, frame: RGBDFrame) -> tuple[npt.NDArray[np.uint8], FloatArray]:
        if not isinstance(frame, RGBDFrame):
            raise TypeError(f"frame must be an RGBDFrame or None, got {type(frame).__name__}")
        intr = frame.intrinsics
        if not isinstance(intr, CameraIntrinsics):
            raise TypeError(f"frame.intrinsics must be CameraIntrinsics, got {type(intr).__name__}")
        hw = (intr.height, intr.width)
        rgb = np.asarray(frame.rgb)
        if rgb.shape[:2] != hw or rgb.ndim not in (2, 3) or (rgb.ndim == 3 and rgb.shape[2] != 3):
            raise ValueError(f"frame.rgb must have shape {(*hw, 3)} or {hw}, got {rgb.shape}")
        depth = np.asarray(frame.depth, dtype=np.float64)
        if depth.shape != hw:
            raise ValueError(f"frame.depth must have shape {hw}, got {depth.shape}")
        if rgb.dtype != np.uint8:
            raise ValueError(f"frame.rgb must be uint8, got {rgb.dtype}")
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
        return np.ascontiguousarray(gray, dtype=np.uint8), depth

    def _back_project(
        self, pixels: FloatArray, depth: FloatArray, intr: CameraIntrinsics
    ) -> FloatArray:
        """3-D points (n, 3) in the camera frame; ``nan`` rows where depth is unusable.

        Depth is interpolated bilinearly from the 2×2 pixel neighbourhood; the
        keypoint is rejected when a neighbour is missing or out of range, or the
        neighbourhood spreads by more than ``depth_edge_ratio`` (an edge).
        """
        p = self.params
        h, w = depth.shape
        u, v = pixels[:, 0], pixels[:, 1]
        u0 = np.clip(np.floor(u).astype(np.intp), 0, w - 2)
        v0 = np.clip(np.floor(v).astype(np.intp), 0, h - 2)
        du, dv = np.clip(u - u0, 0.0, 1.0), np.clip(v - v0, 0.0, 1.0)
        z4 = np.stack([depth[v0, u0], depth[v0, u0 + 1], depth[v0 + 1, u0], depth[v0 + 1, u0 + 1]])
        finite = np.all(np.isfinite(z4), axis=0)
        z4 = np.where(finite, z4, 1.0)
        zmin, zmax = z4.min(axis=0), z4.max(axis=0)
        good = (
            finite
            & (zmin >= p.depth_min_m)
            & (zmax <= p.depth_max_m)
            & (zmax - zmin <= p.depth_edge_ratio * zmin)
        )
        z = (1 - dv) * ((1 - du) * z4[0] + du * z4[1]) + dv * ((1 - du) * z4[2] + du * z4[3])
        pts = np.stack([(u - intr.cx) * z / intr.fx, (v - intr.cy) * z / intr.fy, z], axis=1)
        pts[~good] = np.nan
        return pts

    def _match(self, desc_kf: Descriptors, desc: Descriptors) -> tuple[IntArray, IntArray]:
        """Ratio-test matches (key-frame index, current index), one per key-frame keypoint."""
        if len(desc_kf) < 2 or len(desc) < 1:
            return np.zeros(0, np.intp), np.zeros(0, np.intp)
        knn = self._matcher.knnMatch(desc, desc_kf, k=2)
        trip = np.array(
            [
                (m[0].trainIdx, m[0].queryIdx, m[0].distance, m[1].distance)
                for m in knn
                if len(m) == 2
            ],
            dtype=float,
        ).reshape(-1, 4)
        good = trip[:, 2] < self.params.ratio * trip[:, 3]
        trip = trip[good]
        # keep the best match per key-frame keypoint (many-to-one matches are ambiguous)
        order = np.lexsort((trip[:, 2], trip[:, 0]))
        trip = trip[order]
        first = np.ones(len(trip), dtype=bool)
        first[1:] = trip[1:, 0] != trip[:-1, 0]
        trip = trip[first]
        return trip[:, 0].astype(np.intp), trip[:, 1].astype(np.intp)

    def _refine(
        self,
        P_cur: FloatArray,
        P_kf: FloatArray,
        R: FloatArray,
        t: FloatArray,
        w: FloatArray | None,
    ) -> tuple[FloatArray, FloatArray]:
        """ICP on the inlier points; kept only if it does not raise the residual."""
        p = self.params
        try:
            R_icp, t_icp, _, _ = icp_point_to_point(
                P_cur,
                P_kf,
                R,
                t,
                p.icp_max_iters,
                p.icp_tol_m,
                max_correspondence_m=p.ransac_threshold_m,
                weights=w,
            )
        except ValueError:
            return R, t

        def cost(R: FloatArray, t: FloatArray) -> float:
            e2 = np.minimum(np.sum((P_cur @ R.T + t - P_kf) ** 2, axis=1), p.ransac_threshold_m**2)
            return float(e2.sum() if w is None else w @ e2)

        return (R_icp, t_icp) if cost(R_icp, t_icp) <= cost(R, t) else (R, t)

    def _set_keyframe(
        self,
        pixels: FloatArray,
        desc: Descriptors,
        points: FloatArray,
        T_world_camera: FloatArray,
    ) -> None:
        self._keyframe = _Keyframe(T_world_camera.copy(), pixels, desc, points)
        self._T_world_kf = T_world_camera.copy()
        self._T_kf_curr = np.eye(4)

    def _lost_frame(
        self,
        status: VOStatus,
        pixels: FloatArray,
        desc: Descriptors,
        points: FloatArray,
        counts: dict[str, object],
    ) -> VOResult:
        """Report a failed frame; after too many in a row, restart from this one."""
        self._lost += 1
        if (
            self._lost > self.params.max_lost_frames
            and np.count_nonzero(np.all(np.isfinite(points), axis=1)) >= self.params.min_inliers
        ):
            self._lost = 0
            self._set_keyframe(pixels, desc, points, self.T_world_camera)
            return self._result(VOStatus.REINITIALISED, ok=False, keyframe=True, **counts)
        return self._result(status, ok=False, **counts)
