"""Checkerboard X-corners in an image and their integer lattice coordinates.

The first steps of :func:`~.board_measurement.measure_board`:

1. **Corner candidates** — saddle points of the Gaussian-smoothed image,
   :math:`\\det \\nabla^2 I < 0` (an X-junction is a saddle, a code dot is an
   extremum), non-maximum suppressed, then a ring test: on a circle around a
   checkerboard corner the grey level changes sign exactly four times and is
   point-symmetric.
2. **Sub-pixel refinement** — ``cv2.cornerSubPix``: at a point :math:`p` near the
   corner :math:`q` the image gradient is orthogonal to :math:`q - p`; the window
   is kept inside the cell so that it never reaches a dot.
3. **Grid** — integer coordinates by growing a lattice from the corner nearest
   the image centre (local steps predicted from the neighbours), with the board's
   handedness.
"""

from __future__ import annotations

import cv2
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "detect_corners",
    "grow_grid",
    "refine_by_scale",
    "ring_test",
    "sample_bilinear",
    "to_gray",
]


def to_gray(image: npt.ArrayLike) -> npt.NDArray[np.float32]:
    """Grey image (H, W) float32 of an (H, W) or RGB(A) (H, W, 3|4) image."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = cv2.cvtColor(img[..., :3].astype(np.float32), cv2.COLOR_RGB2GRAY)
    if img.ndim != 2:
        raise ValueError(f"image must have shape (H, W) or (H, W, 3), got {np.shape(image)}")
    if img.shape[0] < 16 or img.shape[1] < 16:
        raise ValueError(f"image is too small: {img.shape}")
    return np.ascontiguousarray(img, dtype=np.float32)


def sample_bilinear(gray: npt.NDArray[np.float32], pts: FloatArray) -> FloatArray:
    """Bilinear samples at pixel positions ``pts`` (..., 2); NaN outside the image."""
    shp = pts.shape[:-1]
    flat = pts.reshape(-1, 2).astype(np.float32)
    n = flat.shape[0]
    if n == 0:
        return np.zeros(shp)
    side = int(np.ceil(np.sqrt(n)))
    buf = np.full((side * side, 2), -10.0, dtype=np.float32)
    buf[:n] = flat
    mx = np.ascontiguousarray(buf[:, 0].reshape(side, side))
    my = np.ascontiguousarray(buf[:, 1].reshape(side, side))
    vals = cv2.remap(
        gray, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan
    )
    out = vals.reshape(-1)[:n].astype(float)
    h, w = gray.shape
    outside = (flat[:, 0] < 0) | (flat[:, 1] < 0) | (flat[:, 0] > w - 1) | (flat[:, 1] > h - 1)
    out[outside] = np.nan
    return out.reshape(shp)


def _saddle_candidates(gray: npt.NDArray[np.float32], sigma: float) -> FloatArray:
    G = cv2.GaussianBlur(gray, (0, 0), sigma)
    Ixx = cv2.Sobel(G, cv2.CV_32F, 2, 0, ksize=3)
    Iyy = cv2.Sobel(G, cv2.CV_32F, 0, 2, ksize=3)
    Ixy = cv2.Sobel(G, cv2.CV_32F, 1, 1, ksize=3)
    S = np.maximum(Ixy * Ixy - Ixx * Iyy, 0.0)
    if not np.any(S > 0):
        return np.zeros((0, 2))
    r = max(2, int(round(2 * sigma)))
    dil = cv2.dilate(S, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
    peaks = (S >= dil) & (S > 0.02 * float(S.max()))
    b = r + 2
    peaks[:b, :] = False
    peaks[-b:, :] = False
    peaks[:, :b] = False
    peaks[:, -b:] = False
    v, u = np.nonzero(peaks)
    return np.column_stack([u, v]).astype(float)


def ring_test(
    gray: npt.NDArray[np.float32], pts: FloatArray, radius: float | FloatArray, contrast: float
) -> npt.NDArray[np.bool_]:
    """True where the grey level on a circle looks like a checkerboard X-junction."""
    if len(pts) == 0:
        return np.zeros(0, dtype=bool)
    n = 32
    ang = np.arange(n) * 2 * np.pi / n
    rad = np.broadcast_to(np.asarray(radius, dtype=float), (len(pts),))
    ring = pts[:, None, :] + rad[:, None, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)[None]
    vals = sample_bilinear(gray, ring)
    ok = np.all(np.isfinite(vals), axis=1)
    vals = np.where(np.isfinite(vals), vals, 0.0)
    centred = vals - vals.mean(axis=1, keepdims=True)
    sgn = centred > 0
    changes = np.sum(sgn != np.roll(sgn, 1, axis=1), axis=1)
    amp = vals.max(axis=1) - vals.min(axis=1)
    sym = np.mean(np.abs(vals - np.roll(vals, n // 2, axis=1)), axis=1) / np.maximum(amp, 1e-6)
    anti = np.mean(np.abs(vals - np.roll(vals, n // 4, axis=1)), axis=1) / np.maximum(amp, 1e-6)
    return ok & (changes == 4) & (amp > 0.3 * contrast) & (sym < 0.3) & (anti > 0.35)


def _refine_subpix(gray: npt.NDArray[np.float32], pts: FloatArray, half_window: int) -> FloatArray:
    if len(pts) == 0:
        return pts
    c = pts.reshape(-1, 1, 2).astype(np.float32).copy()
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-4)
    cv2.cornerSubPix(gray, c, (half_window, half_window), (-1, -1), crit)
    return c.reshape(-1, 2).astype(float)


def _dedupe_mask(pts: FloatArray, min_dist: FloatArray) -> npt.NDArray[np.bool_]:
    """Keep one of every group of points closer than their ``min_dist`` (px)."""
    from scipy.spatial import cKDTree

    keep = np.ones(len(pts), dtype=bool)
    if len(pts) < 2:
        return keep
    tree = cKDTree(pts)
    for i, j in sorted(tree.query_pairs(float(np.max(min_dist)))):
        if keep[i] and keep[j] and np.linalg.norm(pts[i] - pts[j]) < min(min_dist[i], min_dist[j]):
            keep[j] = False
    return keep


def refine_by_scale(
    gray: npt.NDArray[np.float32], pts: FloatArray, spacing: FloatArray, fraction: float
) -> FloatArray:
    """``cornerSubPix`` with a half-window proportional to the local spacing."""
    half = np.maximum(2, np.round(fraction * spacing)).astype(int)
    out = pts.copy()
    for h in np.unique(half):
        sel = half == h
        out[sel] = _refine_subpix(gray, pts[sel], int(h))
    return out


def detect_corners(
    gray: npt.NDArray[np.float32], smoothing_sigma_px: float, subpix_window_fraction: float
) -> tuple[FloatArray, float, float]:
    """Sub-pixel X-corners (N, 2) px at one global scale, their typical spacing (px) and
    the image contrast. Corners far from that scale are added later by the layout.

    ``smoothing_sigma_px`` and ``subpix_window_fraction`` are those of
    :class:`~.board_measurement.BoardMeasurementSettings`."""
    from scipy.spatial import cKDTree

    lo, hi = np.percentile(gray, [5, 95])
    contrast = float(hi - lo)
    if contrast < 10.0:
        return np.zeros((0, 2)), 0.0, contrast
    cand = _saddle_candidates(gray, smoothing_sigma_px)
    first = cand[ring_test(gray, cand, 3.0, contrast)]
    if len(first) < 5:
        return first, 0.0, contrast
    d, _ = cKDTree(first).query(first, k=2)
    spacing = float(np.median(d[:, 1]))
    radius = float(np.clip(0.28 * spacing, 2.5, 15.0))
    pts = cand[ring_test(gray, cand, radius, contrast)]
    pts = refine_by_scale(gray, pts, np.full(len(pts), spacing), subpix_window_fraction)
    pts = pts[_dedupe_mask(pts, np.full(len(pts), 0.25 * spacing))]
    pts = pts[ring_test(gray, pts, radius, contrast)]
    return pts, spacing, contrast


# =========================================================================== grid
def grow_grid(points: FloatArray, centre: FloatArray) -> dict[tuple[int, int], int] | None:
    """Assign integer lattice coordinates ``(i, j)`` to points (undistorted px).

    ``j`` runs along one lattice direction, ``i`` along the other, oriented so that
    ``cross(e_j, e_i) > 0`` in image coordinates (the board's handedness). Seeds
    near ``centre`` with four lattice neighbours are tried; the largest lattice wins.
    """
    from scipy.spatial import cKDTree

    n = len(points)
    if n < 5:
        return None
    tree = cKDTree(points)
    order = np.argsort(np.linalg.norm(points - centre, axis=1))
    best: dict[tuple[int, int], int] | None = None
    tried = 0
    for seed in order[: min(40, n)]:
        _, idx = tree.query(points[seed], k=min(9, n))
        vecs = points[idx[1:]] - points[seed]
        cross = _seed_cross(vecs)
        if cross is None:
            continue
        e1, e2 = cross
        if e1[0] * e2[1] - e1[1] * e2[0] < 0:
            e1, e2 = e2, e1
        coords = _bfs(points, tree, int(seed), e1, e2)
        if best is None or len(coords) > len(best):
            best = coords
        tried += 1
        if len(best) > 0.5 * n or tried >= 4:
            break
    return best


def _seed_cross(vecs: FloatArray) -> tuple[FloatArray, FloatArray] | None:
    """Two lattice steps among neighbour vectors: both with an opposite partner,
    of similar length and clearly not parallel."""
    lens = np.linalg.norm(vecs, axis=1)
    pairs = []
    for a in range(len(vecs)):
        for b in range(a + 1, len(vecs)):
            s = vecs[a] + vecs[b]
            if np.linalg.norm(s) < 0.25 * min(lens[a], lens[b]):
                pairs.append(a)
    for ia, a in enumerate(pairs):
        for b in pairs[ia + 1 :]:
            cosang = float(vecs[a] @ vecs[b]) / (lens[a] * lens[b])
            if abs(cosang) < 0.6 and 0.5 < lens[b] / lens[a] < 2.0:
                return vecs[a], vecs[b]
    return None


def _bfs(
    points: FloatArray, tree: object, seed: int, e_j: FloatArray, e_i: FloatArray
) -> dict[tuple[int, int], int]:
    """Breadth-first lattice growth; points reached with two different coordinates are
    dropped (the layout RANSAC removes what remains inconsistent)."""
    from collections import deque

    assigned: dict[tuple[int, int], int] = {(0, 0): seed}
    owner = {seed: (0, 0)}
    basis = {seed: (e_j.copy(), e_i.copy())}
    queue = deque([seed])
    bad: set[int] = set()
    while queue:
        p = queue.popleft()
        i, j = owner[p]
        bj, bi = basis[p]
        tol = 0.3 * min(np.linalg.norm(bj), np.linalg.norm(bi))
        for di, dj, step in ((0, 1, bj), (0, -1, -bj), (1, 0, bi), (-1, 0, -bi)):
            dist, q = tree.query(points[p] + step)  # type: ignore[attr-defined]
            if not np.isfinite(dist) or dist > tol:
                continue
            key = (i + di, j + dj)
            q = int(q)
            if q in owner or key in assigned:
                if owner.get(q) != key:
                    bad.add(q)
                    if key in assigned:
                        bad.add(assigned[key])
                continue
            actual = points[q] - points[p]
            if dj != 0:
                nbj, nbi = actual * dj, bi
            else:
                nbj, nbi = bj, actual * di
            assigned[key] = q
            owner[q] = key
            basis[q] = (nbj, nbi)
            queue.append(q)
    return {k: v for k, v in assigned.items() if v not in bad}
