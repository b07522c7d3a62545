"""Rigid registration of 3-D point sets: Kabsch–Umeyama, RANSAC and point-to-point ICP.

:func:`kabsch_umeyama` is the weighted least-squares rigid fit of matched
points, :func:`ransac_rigid` wraps it in RANSAC over minimal triples, and
:func:`icp_point_to_point` refines a transform by iterative closest points.
:func:`check_transform` and :func:`check_points` validate the 4×4 transforms and
point arrays these functions take.

``T_a_b`` is the 4×4 homogeneous transform that maps coordinates in frame ``b``
to frame ``a``. Lengths are in metres, angles in radians.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from realitygap.core.geometry import check_finite

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
IntArray = npt.NDArray[np.intp]

__all__ = [
    "RegistrationError",
    "check_points",
    "check_transform",
    "icp_point_to_point",
    "kabsch_umeyama",
    "ransac_rigid",
    "rotation_angle",
]


class RegistrationError(RuntimeError):
    """A robust registration found no transform supported by enough inliers."""


# ----------------------------------------------------------------------------
# validation helpers
# ----------------------------------------------------------------------------


def check_points(name: str, value: npt.ArrayLike, dim: int, min_count: int = 0) -> FloatArray:
    """Convert to a finite float array of shape (N, ``dim``) with N ≥ ``min_count``.

    Raises
    ------
    ValueError
        On a non-finite entry, another shape, or fewer than ``min_count`` points.
    """
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


def rotation_angle(R: FloatArray) -> float:
    """Angle in rad of the axis–angle form of a rotation matrix."""
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


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
    P = check_points("P", P, 3, min_count=3)
    Q = check_points("Q", Q, 3, min_count=3)
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
    P = check_points("P", P, 3)
    Q = check_points("Q", Q, 3)
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
    src = check_points("src", src, 3, min_count=3)
    dst = check_points("dst", dst, 3, min_count=3)
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
