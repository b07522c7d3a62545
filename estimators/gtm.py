"""Graph Transformation Matching: outlier rejection for keypoint matches between two images."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy.spatial.distance import pdist, squareform

from realitygap.estimators.registration import check_points

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

__all__ = ["gtm_filter"]


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
    p = check_points("pts_p", pts_p, 2)
    q = check_points("pts_q", pts_q, 2)
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
