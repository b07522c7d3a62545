"""Camera pose from a partial view of the coded board, and hierarchical displacements.

Pipeline of :func:`measure_board` (pure OpenCV/numpy):

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
4. **Layout refinement (RANSAC)** — a homography from the integer grid to the
   undistorted corners (the printed layout is exact), fitted with RANSAC;
   outliers go, missing corners are searched at their predicted positions and
   the homography is refitted.
5. **Decoding** — every cell whose four corners were found is sampled at its
   centre and around it; the code bit is "centre has the opposite colour". The
   observed bit array is matched in all four rotations and all shifts against
   the board; the match must be nearly exact and clearly better than the
   runner-up, and the dark/light parity must agree. Otherwise the frame is
   rejected (``ok=False``), never mislabelled.
6. **Pose** — the cell under the optical axis (the principal point) is the
   *centre cell*; ``cv2.solvePnP`` (IPPE, then Levenberg–Marquardt) gives the
   camera pose with respect to that cell's corner frame from the local corner
   array, :math:`s\\,\\tilde p_k = K [R\\,|\\,t] P_k`.

Hierarchical displacement between two frames ``i`` and ``j``:

.. math::

    \\delta' = t + t', \\qquad
    t = s_{\\mathrm{cell}} \\begin{bmatrix} c_j - c_i \\\\ r_j - r_i \\\\ 0 \\end{bmatrix},
    \\qquad t' = {}^{\\mathrm{cell}_j}p_j - {}^{\\mathrm{cell}_i}p_i,

with :math:`(r, c)` the centre cell decoded from the code and :math:`{}^{\\mathrm{cell}}p`
the optical centre in its centre-cell frame from PnP: the large part comes from
the printed layout, only the in-cell part from the image.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

import cv2
import numpy as np
import numpy.typing as npt

from .coded_board import WINDOW, CodedBoard

FloatArray = npt.NDArray[np.float64]

__all__ = [
    "BoardMeasurementSettings",
    "BoardObservation",
    "HierarchicalDisplacement",
    "MeasurementStatus",
    "cell_under_optical_axis",
    "hierarchical_displacement",
    "measure_board",
    "transition_pose",
]


class MeasurementStatus(str, Enum):
    """Outcome of :func:`measure_board`."""

    OK = "ok"
    TOO_FEW_CORNERS = "too_few_corners"  #: fewer corners than needed anywhere in the chain
    NO_GRID = "no_grid"  #: the corners do not form a checkerboard lattice
    LOW_CONTRAST = "low_contrast"  #: dark and light cells are not told apart
    CODE_WINDOW_INCOMPLETE = "code_window_incomplete"  #: fewer than 8×8 readable cells
    CODE_NOT_FOUND = "code_not_found"  #: the bits match no place on the board well enough
    CODE_AMBIGUOUS = "code_ambiguous"  #: two places match about equally well
    PARITY_MISMATCH = "parity_mismatch"  #: decoded place contradicts the cell colours
    OPTICAL_AXIS_OFF_BOARD = "optical_axis_off_board"  #: no centre cell
    PNP_FAILED = "pnp_failed"  #: pose not found or reprojection error too large


@dataclass(frozen=True)
class BoardMeasurementSettings:
    """Settings of :func:`measure_board`.

    Attributes
    ----------
    min_corners : int
        Fewest inlier corners for a pose.
    smoothing_sigma_px : float
        Gaussian scale of the saddle detector (px).
    ransac_threshold_px : float
        Inlier threshold of the layout homography and of the PnP reprojection (px).
    subpix_window_fraction : float
        Half-window of ``cornerSubPix`` as a fraction of the local corner spacing;
        must stay below about 0.35 for the window to avoid the code dots.
    max_code_errors : int
        Most misread bits tolerated in the accepted placement.
    max_code_error_fraction : float
        ... or this fraction of the read bits, whichever is larger.
    min_code_margin : int
        The runner-up placement must disagree with at least this many more bits.
    min_bit_confidence : float
        Bits whose centre is not clearly closer to one colour (fraction of the
        dark/light contrast) are not used.
    pnp_window_cells : int or None
        Use only corners within this many cells of the centre cell for PnP
        (``None``: every inlier corner).
    max_reprojection_rms_px : float
        Reject the frame when the PnP reprojection RMS exceeds this.
    """

    min_corners: int = 20
    smoothing_sigma_px: float = 1.5
    ransac_threshold_px: float = 1.0
    subpix_window_fraction: float = 0.25
    max_code_errors: int = 2
    max_code_error_fraction: float = 0.03
    min_code_margin: int = 6
    min_bit_confidence: float = 0.25
    pnp_window_cells: int | None = None
    max_reprojection_rms_px: float = 1.0

    def __post_init__(self) -> None:
        if self.min_corners < 6:
            raise ValueError(f"min_corners must be >= 6 (PnP needs them), got {self.min_corners}")
        for nm in (
            "smoothing_sigma_px",
            "ransac_threshold_px",
            "max_reprojection_rms_px",
        ):
            v = getattr(self, nm)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{nm} must be positive, got {v!r}")
        if not 0.05 <= self.subpix_window_fraction <= 0.35:
            raise ValueError(
                "subpix_window_fraction must be in [0.05, 0.35] so that the cornerSubPix "
                f"window stays clear of the code dots, got {self.subpix_window_fraction!r}"
            )
        if self.max_code_errors < 0 or self.min_code_margin < 1:
            raise ValueError("max_code_errors must be >= 0 and min_code_margin >= 1")
        if self.pnp_window_cells is not None and self.pnp_window_cells < 1:
            raise ValueError(f"pnp_window_cells must be >= 1 or None, got {self.pnp_window_cells}")


def _nan_pose() -> FloatArray:
    return np.full((4, 4), np.nan)


@dataclass(frozen=True)
class BoardObservation:
    """One camera frame measured against the coded board.

    Attributes
    ----------
    ok : bool
        Whether a pose was measured; when False every array is NaN and
        ``cell_index`` is None.
    status : MeasurementStatus
        Why not, or ``OK``.
    cell_index : (int, int) or None
        ``(row, col)`` of the centre cell, the cell under the optical axis.
    T_camera_board : ndarray, shape (4, 4)
        Board pose in the camera frame (m).
    n_corners : int
        Corners used for the pose (or found, when it failed).
    reprojection_rms_px : float
        RMS reprojection error of the PnP solution (px).
    T_camera_cell : ndarray, shape (4, 4)
        Pose of the centre-cell frame (board axes, origin at the cell's corner
        ``(row, col)``) in the camera frame (m).
    code_mismatches : int
        Observed code bits that disagree with the board at the decoded place
        (-1 when not decoded).
    n_code_bits : int
        Code bits read.
    image_points : ndarray, shape (k, 2)
        Pixel positions of the corners used for the pose.
    corner_ids : ndarray of int, shape (k, 2)
        Their board corner indices ``(row, col)``.
    """

    ok: bool
    status: MeasurementStatus
    cell_index: tuple[int, int] | None
    T_camera_board: FloatArray
    n_corners: int
    reprojection_rms_px: float
    T_camera_cell: FloatArray = field(default_factory=_nan_pose)
    code_mismatches: int = -1
    n_code_bits: int = 0
    image_points: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    corner_ids: npt.NDArray[np.int64] = field(
        default_factory=lambda: np.zeros((0, 2), dtype=np.int64)
    )

    @property
    def T_board_camera(self) -> FloatArray:
        """Camera pose in the board frame, shape (4, 4)."""
        return _invert(self.T_camera_board)

    @property
    def camera_position_board(self) -> FloatArray:
        """Optical centre in the board frame (m), shape (3,)."""
        return self.T_board_camera[:3, 3].copy()

    @property
    def camera_position_cell(self) -> FloatArray:
        """Optical centre in the centre-cell frame (m), shape (3,)."""
        return _invert(self.T_camera_cell)[:3, 3].copy()


def _fail(
    status: MeasurementStatus, n: int = 0, mism: int = -1, nbits: int = 0
) -> BoardObservation:
    return BoardObservation(
        ok=False,
        status=status,
        cell_index=None,
        T_camera_board=_nan_pose(),
        n_corners=n,
        reprojection_rms_px=float("nan"),
        code_mismatches=mism,
        n_code_bits=nbits,
    )


def _invert(T: FloatArray) -> FloatArray:
    out = np.eye(4)
    R = T[:3, :3]
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ T[:3, 3]
    if not np.all(np.isfinite(T)):
        out[:] = np.nan
    return out


# =========================================================================== detection
def _to_gray(image: npt.ArrayLike) -> npt.NDArray[np.float32]:
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = cv2.cvtColor(img[..., :3].astype(np.float32), cv2.COLOR_RGB2GRAY)
    if img.ndim != 2:
        raise ValueError(f"image must have shape (H, W) or (H, W, 3), got {np.shape(image)}")
    if img.shape[0] < 16 or img.shape[1] < 16:
        raise ValueError(f"image is too small: {img.shape}")
    return np.ascontiguousarray(img, dtype=np.float32)


def _sample(gray: npt.NDArray[np.float32], pts: FloatArray) -> FloatArray:
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


def _ring_test(
    gray: npt.NDArray[np.float32], pts: FloatArray, radius: float | FloatArray, contrast: float
) -> npt.NDArray[np.bool_]:
    """True where the grey level on a circle looks like a checkerboard X-junction."""
    if len(pts) == 0:
        return np.zeros(0, dtype=bool)
    n = 32
    ang = np.arange(n) * 2 * np.pi / n
    rad = np.broadcast_to(np.asarray(radius, dtype=float), (len(pts),))
    ring = pts[:, None, :] + rad[:, None, None] * np.stack([np.cos(ang), np.sin(ang)], axis=1)[None]
    vals = _sample(gray, ring)
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


def _refine_by_scale(
    gray: npt.NDArray[np.float32], pts: FloatArray, spacing: FloatArray, fraction: float
) -> FloatArray:
    """``cornerSubPix`` with a half-window proportional to the local spacing."""
    half = np.maximum(2, np.round(fraction * spacing)).astype(int)
    out = pts.copy()
    for h in np.unique(half):
        sel = half == h
        out[sel] = _refine_subpix(gray, pts[sel], int(h))
    return out


def _detect_corners(
    gray: npt.NDArray[np.float32], settings: BoardMeasurementSettings
) -> tuple[FloatArray, float, float]:
    """Sub-pixel X-corners (N, 2) px at one global scale, their typical spacing (px) and
    the image contrast. Corners far from that scale are added later by the layout."""
    from scipy.spatial import cKDTree

    lo, hi = np.percentile(gray, [5, 95])
    contrast = float(hi - lo)
    if contrast < 10.0:
        return np.zeros((0, 2)), 0.0, contrast
    cand = _saddle_candidates(gray, settings.smoothing_sigma_px)
    first = cand[_ring_test(gray, cand, 3.0, contrast)]
    if len(first) < 5:
        return first, 0.0, contrast
    d, _ = cKDTree(first).query(first, k=2)
    spacing = float(np.median(d[:, 1]))
    radius = float(np.clip(0.28 * spacing, 2.5, 15.0))
    pts = cand[_ring_test(gray, cand, radius, contrast)]
    pts = _refine_by_scale(gray, pts, np.full(len(pts), spacing), settings.subpix_window_fraction)
    pts = pts[_dedupe_mask(pts, np.full(len(pts), 0.25 * spacing))]
    pts = pts[_ring_test(gray, pts, radius, contrast)]
    return pts, spacing, contrast


# =========================================================================== grid
def _grow_grid(points: FloatArray, centre: FloatArray) -> dict[tuple[int, int], int] | None:
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


# =========================================================================== camera helpers
def _undistort(px: FloatArray, K: FloatArray, dist: FloatArray | None) -> FloatArray:
    if len(px) == 0 or dist is None:
        return px.copy()
    out = cv2.undistortPoints(
        px.reshape(-1, 1, 2).astype(np.float64),
        K,
        dist,
        P=K,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10),
    )
    return np.asarray(out, dtype=np.float64).reshape(-1, 2)


def _distort(px_undist: FloatArray, K: FloatArray, dist: FloatArray | None) -> FloatArray:
    if len(px_undist) == 0 or dist is None:
        return px_undist.copy()
    xn = np.column_stack([px_undist, np.ones(len(px_undist))]) @ np.linalg.inv(K).T
    out, _ = cv2.projectPoints(xn.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, dist)
    return np.asarray(out, dtype=np.float64).reshape(-1, 2)


def _apply_h(H: FloatArray, xy: FloatArray) -> FloatArray:
    h = np.column_stack([xy, np.ones(len(xy))]) @ H.T
    return h[:, :2] / h[:, 2:3]


def _check_camera(
    K: npt.ArrayLike, dist: npt.ArrayLike | None
) -> tuple[FloatArray, FloatArray | None]:
    Km = np.asarray(K, dtype=float)
    if Km.shape != (3, 3) or not np.all(np.isfinite(Km)) or Km[0, 0] <= 0 or Km[1, 1] <= 0:
        raise ValueError(f"K must be a finite 3x3 camera matrix with fx, fy > 0, got {Km!r}")
    if dist is None:
        return Km, None
    d = np.asarray(dist, dtype=float).reshape(-1)
    if d.size not in (4, 5, 8, 12, 14) or not np.all(np.isfinite(d)):
        raise ValueError(
            f"dist must hold 4, 5, 8, 12 or 14 finite OpenCV coefficients, got {d.size}"
        )
    return Km, (None if not np.any(d) else d)


# =========================================================================== main entry
def measure_board(
    image: npt.ArrayLike,
    K: npt.ArrayLike,
    dist: npt.ArrayLike | None,
    board: CodedBoard,
    settings: BoardMeasurementSettings | None = None,
) -> BoardObservation:
    """Measure the camera pose from one image of part of a coded board.

    Parameters
    ----------
    image : array_like, shape (H, W) or (H, W, 3)
        Grey or RGB image (any numeric dtype, grey levels about 0..255).
    K : array_like, shape (3, 3)
        Camera matrix (px).
    dist : array_like or None
        OpenCV distortion coefficients of the camera.
    board : CodedBoard
        The board being looked at.
    settings : BoardMeasurementSettings, optional

    Returns
    -------
    BoardObservation
        ``ok=False`` with a :class:`MeasurementStatus` when the frame cannot be
        measured unambiguously.
    """
    s = settings or BoardMeasurementSettings()
    Km, d = _check_camera(K, dist)
    gray = _to_gray(image)
    h_img, w_img = gray.shape

    corners, _, contrast = _detect_corners(gray, s)
    if contrast < 10.0:
        return _fail(MeasurementStatus.LOW_CONTRAST)
    if len(corners) < s.min_corners:
        return _fail(MeasurementStatus.TOO_FEW_CORNERS, len(corners))
    und = _undistort(corners, Km, d)
    coords = _grow_grid(und, np.array([Km[0, 2], Km[1, 2]]))
    if coords is None or len(coords) < s.min_corners:
        return _fail(MeasurementStatus.NO_GRID, len(corners))
    keys = np.array(list(coords.keys()), dtype=float)  # (i, j)
    idx = np.array(list(coords.values()))
    src = keys[:, ::-1].copy()  # (x = j, y = i)
    H, mask = cv2.findHomography(src, und[idx], cv2.RANSAC, s.ransac_threshold_px)
    if H is None:
        return _fail(MeasurementStatus.NO_GRID, len(corners))
    inl = mask.ravel().astype(bool)
    grid: dict[tuple[int, int], FloatArray] = {
        (int(k[0]), int(k[1])): corners[i] for k, i, m in zip(keys, idx, inl) if m
    }

    # ---- layout refinement: look for every corner the layout predicts in view
    n_side = board.cells + 1
    for _ in range(2):
        ii = np.array([k[0] for k in grid])
        jj = np.array([k[1] for k in grid])
        I, J = np.meshgrid(
            np.arange(ii.max() - n_side + 1, ii.min() + n_side),
            np.arange(jj.max() - n_side + 1, jj.min() + n_side),
            indexing="ij",
        )
        ck = np.column_stack([I.ravel(), J.ravel()])
        ck = ck[[(int(a_), int(b_)) not in grid for a_, b_ in ck]]
        if len(ck) == 0:
            break
        xy = ck[:, ::-1].astype(float)
        pred_u = _apply_h(H, xy)
        step = np.minimum(
            np.linalg.norm(_apply_h(H, xy + np.array([1.0, 0.0])) - pred_u, axis=1),
            np.linalg.norm(_apply_h(H, xy + np.array([0.0, 1.0])) - pred_u, axis=1),
        )
        den = np.column_stack([xy, np.ones(len(xy))]) @ H[2]
        ok_u = (den > 0) & np.isfinite(step) & (step > 5.0)
        if d is not None:
            # stay where the distortion model is trustworthy
            ok_u &= np.linalg.norm(pred_u - Km[:2, 2], axis=1) < 1.2 * np.hypot(w_img, h_img) / 2
        ck, pred_u, step = ck[ok_u], pred_u[ok_u], step[ok_u]
        pred = _distort(pred_u, Km, d)
        margin = 0.5 * step + 2
        inside = (
            (pred[:, 0] > margin)
            & (pred[:, 1] > margin)
            & (pred[:, 0] < w_img - 1 - margin)
            & (pred[:, 1] < h_img - 1 - margin)
        )
        if not np.any(inside):
            break
        sp_in = step[inside]
        ref = _refine_by_scale(gray, pred[inside], sp_in, s.subpix_window_fraction)
        ring_ok = _ring_test(gray, ref, np.clip(0.28 * sp_in, 2.5, 15.0), contrast)
        ref_u = _undistort(ref, Km, d)
        close = np.linalg.norm(ref_u - pred_u[inside], axis=1) < 3 * s.ransac_threshold_px
        for key, p, good in zip(ck[inside], ref, ring_ok & close):
            if good:
                grid[(int(key[0]), int(key[1]))] = p
        gk = np.array(list(grid.keys()), dtype=float)
        gpu = _undistort(np.array(list(grid.values())), Km, d)
        H_new, _m = cv2.findHomography(gk[:, ::-1], gpu, 0)
        if H_new is None:
            return _fail(MeasurementStatus.NO_GRID, len(grid))
        H = np.asarray(H_new, dtype=np.float64)
        res = np.linalg.norm(_apply_h(H, gk[:, ::-1]) - gpu, axis=1)
        grid = {
            (int(k[0]), int(k[1])): p
            for k, p, r in zip(gk, grid.values(), res)
            if r < s.ransac_threshold_px
        }
    gk = np.array(list(grid.keys()), dtype=float)
    gp = np.array(list(grid.values()))
    gpu = _undistort(gp, Km, d)
    for _ in range(2):
        H_fit, _m = cv2.findHomography(gk[:, ::-1], gpu, 0)
        if H_fit is None:
            return _fail(MeasurementStatus.NO_GRID, len(grid))
        H = np.asarray(H_fit, dtype=np.float64)
        res = np.linalg.norm(_apply_h(H, gk[:, ::-1]) - gpu, axis=1)
        keep = res < s.ransac_threshold_px
        gk, gp, gpu = gk[keep], gp[keep], gpu[keep]
        if len(gk) < s.min_corners:
            return _fail(MeasurementStatus.TOO_FEW_CORNERS, len(gk))
    grid = {(int(k[0]), int(k[1])): p for k, p in zip(gk, gp)}

    # ---- read the code bits of every cell with four corners
    cells = [
        (i, j)
        for (i, j) in grid
        if (i + 1, j) in grid and (i, j + 1) in grid and (i + 1, j + 1) in grid
    ]
    if not cells:
        return _fail(MeasurementStatus.CODE_WINDOW_INCOMPLETE, len(grid))
    ca = np.array(cells)
    i0, j0 = ca.min(axis=0)
    hh, ww = ca.max(axis=0) - ca.min(axis=0) + 1
    centre_off = np.array([[0.0, 0.0], [0.07, 0.0], [-0.07, 0.0], [0.0, 0.07], [0.0, -0.07]])
    rr = 0.33
    dd = 0.27
    bg_off = np.array(
        [[rr, 0], [-rr, 0], [0, rr], [0, -rr], [dd, dd], [dd, -dd], [-dd, dd], [-dd, -dd]]
    )
    cxy = ca[:, ::-1] + 0.5  # (x = j + .5, y = i + .5)
    c_pts = (cxy[:, None, :] + centre_off[None]).reshape(-1, 2)
    b_pts = (cxy[:, None, :] + bg_off[None]).reshape(-1, 2)
    c_val = _sample(gray, _distort(_apply_h(H, c_pts), Km, d)).reshape(len(ca), -1)
    b_val = _sample(gray, _distort(_apply_h(H, b_pts), Km, d)).reshape(len(ca), -1)
    centre_v = np.nanmean(c_val, axis=1)
    back_v = np.nanmedian(b_val, axis=1)
    parity = (ca[:, 0] + ca[:, 1]) % 2
    if np.sum(parity == 0) == 0 or np.sum(parity == 1) == 0:
        return _fail(MeasurementStatus.CODE_WINDOW_INCOMPLETE, len(grid))
    lev = np.array([np.nanmedian(back_v[parity == 0]), np.nanmedian(back_v[parity == 1])])
    C = float(abs(lev[1] - lev[0]))
    if not np.isfinite(C) or C < 0.3 * contrast:
        return _fail(MeasurementStatus.LOW_CONTRAST, len(grid))
    dark_parity = int(np.argmin(lev))
    own = lev[parity]
    other = lev[1 - parity]
    # local estimate of the opposite colour from the four neighbours
    back_map = {c: v for c, v in zip(cells, back_v)}
    for n_, (i, j) in enumerate(cells):
        nb = [
            back_map[k] for k in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1)) if k in back_map
        ]
        nb = [v for v in nb if np.isfinite(v)]
        if nb:
            other[n_] = float(np.median(nb))
    colour_ok = np.abs(back_v - own) < 0.35 * C
    margin_bits = (np.abs(centre_v - back_v) - np.abs(centre_v - other)) / C
    bit = margin_bits > 0
    valid = colour_ok & np.isfinite(margin_bits) & (np.abs(margin_bits) > s.min_bit_confidence)
    bits = np.zeros((hh, ww), dtype=np.uint8)
    vmask = np.zeros((hh, ww), dtype=bool)
    bits[ca[:, 0] - i0, ca[:, 1] - j0] = bit
    vmask[ca[:, 0] - i0, ca[:, 1] - j0] = valid
    nbits = int(vmask.sum())
    if min(hh, ww) < WINDOW or nbits < WINDOW * WINDOW:
        return _fail(MeasurementStatus.CODE_WINDOW_INCOMPLETE, len(grid), nbits=nbits)
    if max(hh, ww) > board.cells or min(hh, ww) > board.cells:
        return _fail(MeasurementStatus.NO_GRID, len(grid), nbits=nbits)
    (r0, c0, k, mism), second = board.match_bits(bits, vmask)
    allowed = max(s.max_code_errors, int(s.max_code_error_fraction * nbits))
    if mism > allowed:
        return _fail(MeasurementStatus.CODE_NOT_FOUND, len(grid), mism, nbits)
    if second - mism < s.min_code_margin:
        return _fail(MeasurementStatus.CODE_AMBIGUOUS, len(grid), mism, nbits)

    # observed cell (i, j) -> board cell via the same rotation
    I, J = np.meshgrid(np.arange(hh) + i0, np.arange(ww) + j0, indexing="ij")
    Ir, Jr = np.rot90(I, k), np.rot90(J, k)
    # three non-collinear cell centres fix the (integer) affine map exactly:
    # [R, C] + 0.5 = [i + 0.5, j + 0.5, 1] @ M
    pick = [(0, 0), (1, 0), (0, 1)]
    obs3 = np.array([[Ir[a, b] + 0.5, Jr[a, b] + 0.5, 1.0] for a, b in pick])
    brd3 = np.array([[a + r0 + 0.5, b + c0 + 0.5] for a, b in pick])
    M = np.round(np.linalg.solve(obs3, brd3))
    # colour parity check: dark observed cells must land on dark board cells
    i_c, j_c = cells[0]
    rc = np.floor(np.array([i_c + 0.5, j_c + 0.5, 1.0]) @ M).astype(int)
    obs_dark = (i_c + j_c) % 2 == dark_parity
    if bool(board.cell_is_dark(rc[0], rc[1])) != obs_dark:
        return _fail(MeasurementStatus.PARITY_MISMATCH, len(grid), mism, nbits)

    # ---- board ids of the corners and the centre cell
    ids = np.round(np.column_stack([gk, np.ones(len(gk))]) @ M).astype(np.int64)  # (R, C)
    on_board = np.all((ids >= 0) & (ids <= board.cells), axis=1)
    ids, gp = ids[on_board], gp[on_board]
    pc = np.array([[Km[0, 2], Km[1, 2]]])
    gxy = _apply_h(np.linalg.inv(H), pc)[0]  # (x = j, y = i) continuous
    centre_rc = np.array([gxy[1], gxy[0], 1.0]) @ M
    cell = np.floor(centre_rc).astype(int)
    if not (0 <= cell[0] < board.cells and 0 <= cell[1] < board.cells):
        return _fail(MeasurementStatus.OPTICAL_AXIS_OFF_BOARD, len(ids), mism, nbits)

    # ---- PnP in the centre-cell frame
    cs = board.cell_size

    def solve(
        cell_rc: npt.NDArray[np.int_],
    ) -> tuple[FloatArray, float, npt.NDArray[np.bool_]] | None:
        use = np.ones(len(ids), dtype=bool)
        if s.pnp_window_cells is not None:
            w = s.pnp_window_cells
            use = np.all(np.abs(ids - cell_rc[None] - 0.5) <= w + 0.5, axis=1)
        if use.sum() < s.min_corners:
            return None
        obj = np.column_stack(
            [(ids[use, 1] - cell_rc[1]) * cs, (ids[use, 0] - cell_rc[0]) * cs, np.zeros(use.sum())]
        )
        img = gp[use].reshape(-1, 1, 2).astype(np.float64)
        dist_arg = np.zeros(5) if d is None else d
        okp, rvec, tvec = cv2.solvePnP(obj, img, Km, dist_arg, flags=cv2.SOLVEPNP_IPPE)
        if not okp:
            return None
        keep = np.ones(len(obj), dtype=bool)
        for _ in range(2):
            rvec, tvec = cv2.solvePnPRefineLM(
                obj[keep],
                img[keep],
                Km,
                dist_arg,
                rvec,
                tvec,
                criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-12),
            )
            proj, _ = cv2.projectPoints(obj, rvec, tvec, Km, dist_arg)
            err = np.linalg.norm(proj.reshape(-1, 2) - img.reshape(-1, 2), axis=1)
            new_keep = err < s.ransac_threshold_px
            if new_keep.sum() < s.min_corners:
                return None
            if np.array_equal(new_keep, keep):
                break
            keep = new_keep
        T = np.eye(4)
        T[:3, :3] = cv2.Rodrigues(rvec)[0]
        T[:3, 3] = np.asarray(tvec).reshape(3)
        rms = float(np.sqrt(np.mean(err[keep] ** 2)))
        full = np.zeros(len(ids), dtype=bool)
        full[np.nonzero(use)[0][keep]] = True
        return T, rms, full

    sol = solve(cell)
    if sol is None:
        return _fail(MeasurementStatus.PNP_FAILED, len(ids), mism, nbits)
    T_cam_cell, rms, used = sol
    T_cell_board = np.eye(4)
    T_cell_board[:3, 3] = [-cell[1] * cs, -cell[0] * cs, 0.0]
    T_cam_board = T_cam_cell @ T_cell_board
    # the centre cell from the pose itself (differs from the homography only at a cell edge)
    pose_cell = cell_under_optical_axis(_invert(T_cam_board), cs)
    if pose_cell is None or not (
        0 <= pose_cell[0] < board.cells and 0 <= pose_cell[1] < board.cells
    ):
        return _fail(MeasurementStatus.OPTICAL_AXIS_OFF_BOARD, len(ids), mism, nbits)
    if pose_cell != (int(cell[0]), int(cell[1])):
        cell = np.array(pose_cell)
        T_cell_board[:3, 3] = [-cell[1] * cs, -cell[0] * cs, 0.0]
        T_cam_cell = T_cam_board @ _invert(T_cell_board)
    if rms > s.max_reprojection_rms_px:
        return _fail(MeasurementStatus.PNP_FAILED, int(used.sum()), mism, nbits)
    return BoardObservation(
        ok=True,
        status=MeasurementStatus.OK,
        cell_index=(int(cell[0]), int(cell[1])),
        T_camera_board=T_cam_board,
        n_corners=int(used.sum()),
        reprojection_rms_px=rms,
        T_camera_cell=T_cam_cell,
        code_mismatches=int(mism),
        n_code_bits=nbits,
        image_points=gp[used].copy(),
        corner_ids=ids[used].copy(),
    )


# =========================================================================== displacements
def cell_under_optical_axis(
    T_board_camera: npt.ArrayLike, cell_size: float
) -> tuple[int, int] | None:
    """Cell ``(row, col)`` hit by the optical axis; ``None`` if the axis misses the plane.

    Parameters
    ----------
    T_board_camera : array_like, shape (4, 4)
        Camera pose in the board frame (m).
    cell_size : float
        Cell side (m).
    """
    T = np.asarray(T_board_camera, dtype=float)
    c = T[:3, 3]
    z = T[:3, 2]
    if abs(z[2]) < 1e-12:
        return None
    lam = -c[2] / z[2]
    if lam <= 0:
        return None
    p = c + lam * z
    return int(np.floor(p[1] / cell_size)), int(np.floor(p[0] / cell_size))


@dataclass(frozen=True)
class HierarchicalDisplacement:
    """Displacement of the optical centre between two frames, in the board frame (m).

    Attributes
    ----------
    t : ndarray, shape (3,)
        Coarse part: change of the centre cell times the cell size (exact, from the code).
    t_prime : ndarray, shape (3,)
        Fine part: change of the optical centre within its centre-cell frame (PnP).
    delta : ndarray, shape (3,)
        :math:`\\delta' = t + t'`.
    cell_shift : (int, int)
        Change of the centre cell ``(rows, cols)``.
    """

    t: FloatArray
    t_prime: FloatArray
    delta: FloatArray
    cell_shift: tuple[int, int]


def hierarchical_displacement(
    obs_from: BoardObservation, obs_to: BoardObservation, cell_size: float
) -> HierarchicalDisplacement:
    """Hierarchical displacement :math:`\\delta' = t + t'` between two measured frames.

    Parameters
    ----------
    obs_from, obs_to : BoardObservation
        Successful measurements (``ok``).
    cell_size : float
        Cell side of the board (m).

    Returns
    -------
    HierarchicalDisplacement
    """
    for name, o in (("obs_from", obs_from), ("obs_to", obs_to)):
        if not o.ok or o.cell_index is None:
            raise ValueError(f"{name} is not a successful measurement (status {o.status.value!r})")
    assert obs_from.cell_index is not None and obs_to.cell_index is not None
    dr = obs_to.cell_index[0] - obs_from.cell_index[0]
    dc = obs_to.cell_index[1] - obs_from.cell_index[1]
    t = np.array([dc * cell_size, dr * cell_size, 0.0])
    tp = obs_to.camera_position_cell - obs_from.camera_position_cell
    return HierarchicalDisplacement(t, tp, t + tp, (int(dr), int(dc)))


def transition_pose(
    T_board_camera_from: npt.ArrayLike, T_board_camera_to: npt.ArrayLike, cell_size: float
) -> tuple[FloatArray, tuple[int, int]]:
    """Transition pose between two camera poses that share no centre cell.

    The transition pose has the orientation of the target pose and is shifted
    from it by whole cells so that its optical axis meets the board in the start
    pose's centre cell, at the same place within the cell as the target's axis
    meets its own. Moving start → transition is then measured inside one cell's
    corner array (:math:`t'`), transition → target is a pure translation by whole
    cells (:math:`t`, exact by the printed layout).

    Parameters
    ----------
    T_board_camera_from, T_board_camera_to : array_like, shape (4, 4)
        Start and target camera poses in the board frame (m).
    cell_size : float
        Cell side (m).

    Returns
    -------
    T_board_camera_transition : ndarray, shape (4, 4)
    cell_shift : (int, int)
        ``(rows, cols)`` from the transition to the target centre cell.
    """
    A = np.asarray(T_board_camera_from, dtype=float)
    B = np.asarray(T_board_camera_to, dtype=float)
    ca = cell_under_optical_axis(A, cell_size)
    cb = cell_under_optical_axis(B, cell_size)
    if ca is None or cb is None:
        raise ValueError("the optical axis of a pose does not meet the board plane")
    dr, dc = cb[0] - ca[0], cb[1] - ca[1]
    T = B.copy()
    T[:3, 3] = B[:3, 3] - np.array([dc * cell_size, dr * cell_size, 0.0])
    return T, (int(dr), int(dc))
